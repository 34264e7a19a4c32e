"""Pixel integration: PSFs on the sensor's pixel grid by exact area integration.

The PSF is computed on a fine grid whose spacing is pixel_pitch / k for an odd integer
k, so every pixel holds exactly k x k fine samples (no rounded ratio) and the centre
pixel's centre is the centre fine sample (the reference point). Each fine sample stands
for the energy of its cell, so summing k x k blocks is the exact area integral of the
sampled irradiance over the pixel.
"""

from __future__ import annotations

import math

import numpy as np

from lensim.errors import InputError


def oversampling_factor(pixel_pitch_um: float, max_spacing_um: float) -> int:
    """Smallest odd k with pixel_pitch / k <= max_spacing."""
    if pixel_pitch_um <= 0 or max_spacing_um <= 0:
        raise InputError(
            None, "pixel_pitch", f"expected positive pitch and spacing, got {pixel_pitch_um}, {max_spacing_um}"
        )
    k = max(1, math.ceil(pixel_pitch_um / max_spacing_um))
    return k if k % 2 else k + 1


def integrate_pixels(fine: np.ndarray, k: int) -> np.ndarray:
    """Sum k x k blocks of a (k*P, k*P) fine PSF (P odd) into a (P, P) pixel PSF."""
    fine = np.asarray(fine)
    n = fine.shape[-1]
    if n % k or fine.shape[-2] % k:
        raise InputError(None, "grid", f"fine grid {fine.shape} is not a multiple of the oversampling {k}")
    p = n // k
    return fine.reshape(*fine.shape[:-2], fine.shape[-2] // k, k, p, k).sum(axis=(-3, -1))
