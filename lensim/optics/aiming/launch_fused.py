"""Paraxially aimed rays of an object at infinity in one compiled loop (numba).

lensim.optics.aiming.rays._paraxial_rays runs it on the CPU for large batches without
gradients: the positions (the pupil points scaled to the entrance pupil, on its plane)
and the starting optical paths (the plane wavefront through the origin) of every
wavelength x field x pupil point, written once each, instead of the torch launch's
temporaries (a stacked position tensor, three products per path, the index product),
which with more than one torch thread ran in pieces so that no OpenMP region opened.
The arithmetic is the torch launch's, operation for operation (lensim.optics.aiming.launch:
``launch_at`` and ``object_rays``), without fused multiply-adds, so the rays are
bit-identical to it (tests/test_launch_fused.py). numba is imported with this module.
Lengths in mm.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: numba's options (as lensim.optics.trace_fused's): cached on disk, the GIL released,
#: C division, no reference counts, no fused multiply-adds
_JIT: dict = dict(cache=True, nogil=True, error_model="numpy", _nrt=False)


@njit(**_JIT)
def launch_infinite(
    pupil: np.ndarray,
    r_ep: float,
    z_ep: float,
    dirs: np.ndarray,
    n0: np.ndarray,
    pos: np.ndarray,
    opl: np.ndarray,
    valid: np.ndarray,
) -> None:
    """Rays through the points pupil (P, 2) (normalized) * r_ep (mm) of the plane z = z_ep
    (mm), in the directions dirs (F, 3) (one per field): writes positions pos (F, P, 3) mm,
    optical paths opl (W, F, P) mm = n0[w] * (position . direction) with the object-space
    indices n0 (W,), and validity valid (W, F, P) (all True)."""
    F, P, W = dirs.shape[0], pupil.shape[0], n0.shape[0]
    for f in range(F):
        d0, d1, d2 = dirs[f, 0], dirs[f, 1], dirs[f, 2]
        for p in range(P):
            x, y = pupil[p, 0] * r_ep, pupil[p, 1] * r_ep
            pos[f, p, 0], pos[f, p, 1], pos[f, p, 2] = x, y, z_ep
            s = x * d0 + y * d1 + z_ep * d2
            for w in range(W):
                opl[w, f, p] = n0[w] * s
                valid[w, f, p] = True
