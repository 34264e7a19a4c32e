"""Kernels at other azimuths than the bank's own direction, turned while the PSF is still
finely sampled (issue 25, defect 5).

A bank computes each field's PSF along one radial direction. An image point at another
azimuth sees that PSF turned about its reference point (a rotationally symmetric lens).
Turning the pixel kernel itself interpolates a function sampled at the pixel pitch: at a
coarse pitch (a small photo mapped onto a whole sensor, 23 um) a 45 degree turn spread a
green kernel's peak pixel from 0.953 of the energy to 0.613. So the bank also stores, per
field, the kernels at the azimuth offsets AZIMUTHS_DEG (7.5 to 45 degrees), each the fine
PSF (energy per fine sample, pitch / k apart) turned by a cubic spline and then integrated
over pixels (lensim.psf.pixels.integrate_pixels), exactly as the bank's own kernel is.

Any other azimuth is reached with the pixel grid's exact symmetries: turns by multiples of
90 degrees (np.rot90) and the mirror about the bank's direction (the PSF of a field on
that line is symmetric about it), which bring every azimuth offset to 0..45 degrees. The
nearest stored kernel is then turned by what is left (at most 3.75 degrees) with the
pixel-level spline of lensim.render.rotation, where a turn that small moves no sample by
more than a small fraction of a pixel within a few pixels of the centre.

Angles in degrees, counter-clockwise from +x towards +y; kernels (..., P, P) with rows
along +y and columns along +x.
"""

from __future__ import annotations

import math

import numpy as np

from lensim.psf.pixels import integrate_pixels

#: the azimuth offsets (deg) from the bank's direction at which fields store kernels
AZIMUTH_STEP_DEG = 3.75
AZIMUTHS_DEG = tuple(AZIMUTH_STEP_DEG * i for i in range(1, 13))  # 3.75 ... 45


def azimuth_kernels(rgb_fine: np.ndarray, k: int) -> np.ndarray:
    """(A, 3, P, P) pixel kernels at AZIMUTHS_DEG from rgb_fine, the (3, kP, kP) fine RGB
    PSF of one field (energy per fine sample; kP = k P, the centre sample on the reference
    point): each channel turned on the fine grid, then integrated over k x k blocks. Each
    keeps its channel's sum (energy leaving the window is given back in proportion)."""
    from lensim.render.rotation import rotate_kernel  # the one home of the spline turn

    fine = np.asarray(rgb_fine, dtype=np.float64)
    return np.stack([integrate_pixels(rotate_kernel(fine, a), k) for a in AZIMUTHS_DEG])


def _mirror_axis(reference_deg: float) -> int | None:
    """The array axis whose flip mirrors about the bank's direction (-1: columns, for a
    direction along +-y; -2: rows, along +-x); None for other directions."""
    r = reference_deg % 180.0
    if abs(r - 90.0) < 1e-9:
        return -1
    if r < 1e-9 or abs(r - 180.0) < 1e-9:
        return -2
    return None


def supported(reference_deg: float) -> bool:
    """True when stored azimuth kernels can be used for a bank along this direction."""
    return _mirror_axis(reference_deg) is not None


def azimuth_turn(offset_deg: float) -> tuple[int, float, bool, int]:
    """How the kernel at an azimuth offset_deg (deg) from the bank's direction is reached:
    (i, rest, mirrored, quarter): start from stored kernel i (0: the bank's own, i >= 1:
    AZIMUTHS_DEG[i - 1]), turn it by rest degrees (|rest| <= AZIMUTH_STEP_DEG / 2), mirror
    it about the bank's direction when mirrored, then turn it by quarter x 90 degrees."""
    alpha = math.remainder(offset_deg, 360.0)  # -180..180
    quarter = round(alpha / 90.0)
    beta = alpha - 90.0 * quarter  # -45..45
    i = round(abs(beta) / AZIMUTH_STEP_DEG)
    return i, abs(beta) - AZIMUTH_STEP_DEG * i, beta < 0, quarter


def mirrored_at(offset_deg: np.ndarray) -> np.ndarray:
    """azimuth_turn's ``mirrored`` for an array of azimuth offsets (deg), elementwise (bool,
    the same shape): the same arithmetic in numpy (a 24 MP frame's pixels in about 1 s
    instead of 30 s of azimuth_turn calls)."""
    offset = np.asarray(offset_deg, dtype=np.float64)
    alpha = offset - 360.0 * np.round(offset / 360.0)  # math.remainder: -180..180
    return alpha - 90.0 * np.round(alpha / 90.0) < 0  # np.round, like round, halves to even


def finish_turn(kernel: np.ndarray, mirrored: bool, quarter: int, reference_deg: float) -> np.ndarray:
    """The last steps of :func:`azimuth_turn` on a (3, P, P) kernel: the mirror about the
    bank's direction (reference_deg, along +-x or +-y), then the quarter turns."""
    axis = _mirror_axis(reference_deg)
    if axis is None:
        raise ValueError(f"azimuth kernels need a bank direction along x or y, got {reference_deg} deg")
    k = np.flip(kernel, axis) if mirrored else kernel  # K(-b) = M K(b): the mirror about the bank's direction
    return np.ascontiguousarray(np.rot90(k, -quarter, axes=(-2, -1)))  # np.rot90(., -1): +90 deg


def kernel_at_azimuth(stack: np.ndarray, offset_deg: float, reference_deg: float) -> np.ndarray:
    """(3, P, P) float64 kernel at an azimuth offset_deg from the bank's direction
    (reference_deg, along +-x or +-y: see ``supported``), from stack (1 + A, 3, P, P): the
    bank's own kernel and those at AZIMUTHS_DEG (radially interpolated alike)."""
    from lensim.render.rotation import rotate_kernel

    if _mirror_axis(reference_deg) is None:
        raise ValueError(f"azimuth kernels need a bank direction along x or y, got {reference_deg} deg")
    i, rest, mirrored, quarter = azimuth_turn(offset_deg)
    k = np.asarray(stack[i], dtype=np.float64)
    if abs(rest) > 1e-9:
        k = rotate_kernel(k, rest)
    return finish_turn(k, mirrored, quarter, reference_deg)
