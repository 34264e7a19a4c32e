"""Synthetic slanted-edge targets: an ideal straight edge, exactly area-sampled, optionally
blurred by a PSF (the geometry and sign conventions of lensim.evaluate.slanted_edge)."""

from __future__ import annotations

import math

import numpy as np

from lensim.errors import InputError
from lensim.evaluate.slanted_edge import Orientation


def _box_sum_cdf(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """CDF at t of U1 + U2, U1 ~ U(-a/2, a/2), U2 ~ U(-b/2, b/2) (a, b >= 0): the fraction
    of an a x b-projected cell on the positive side of a line at signed distance t."""
    if a < b:
        a, b = b, a
    if b <= 1e-9 * a:
        return np.clip(t / a + 0.5, 0.0, 1.0)
    hp, hm = (a + b) / 2.0, (a - b) / 2.0

    def r2(s: np.ndarray) -> np.ndarray:
        return 0.5 * np.maximum(s, 0.0) ** 2

    return np.clip((r2(t + hp) - r2(t + hm) - r2(t - hm) + r2(t - hp)) / (a * b), 0.0, 1.0)


def make_slanted_edge(
    size: int | tuple[int, int],
    angle_deg: float,
    low: float = 0.2,
    high: float = 0.8,
    psf: np.ndarray | None = None,
    oversample: int = 8,
    *,
    orientation: Orientation = "vertical",
    offset_px: float = 0.0,
) -> np.ndarray:
    """A synthetic slanted-edge target: an ideal straight edge, area-sampled, optionally
    blurred by a PSF.

    size: pixels, square or (rows, cols). angle_deg: slant (degrees, sign as in the module
    docstring). low/high: values on the two sides (image units; high on the side the normal
    points to). offset_px: shift of the edge along the normal from the region centre,
    pixels. The edge is rendered on a fine grid of `oversample` x `oversample` cells per
    pixel, each cell holding the exact area fraction it has on the high side (so the result
    is exact area sampling, not point sampling), convolved with `psf` there, and summed to
    pixels. psf: a 2-D kernel sampled every 1/oversample pixel (oversample=1: on the pixel
    grid), normalized here to unit sum, its centre sample at index (rows // 2, cols // 2),
    oriented like the image (row index = y); None for a perfectly sharp edge. Returns a
    float64 (rows, cols) array.
    """
    dims = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
    if len(dims) != 2 or not all(isinstance(v, (int, np.integer)) for v in dims):
        raise InputError(None, "size", f"expected an int or (rows, cols) ints, got {size!r}")
    rows, cols = int(dims[0]), int(dims[1])
    if rows < 1 or cols < 1:
        raise InputError(None, "size", f"expected positive sizes, got {size}")
    if int(oversample) != oversample or oversample < 1:
        raise InputError(None, "oversample", f"expected a positive integer, got {oversample}")
    if orientation not in ("vertical", "horizontal"):
        raise InputError(None, "orientation", f"expected 'vertical' or 'horizontal', got {orientation!r}")
    if not abs(angle_deg) < 45:
        raise InputError(None, "angle_deg", f"expected |angle| < 45 deg, got {angle_deg}")
    k = int(oversample)
    kern = None
    if psf is not None:
        kern = np.asarray(psf, dtype=np.float64)
        if kern.ndim != 2 or not np.all(np.isfinite(kern)) or not kern.sum() > 0:
            raise InputError(None, "psf", f"expected a finite 2-D kernel with positive sum, got shape {kern.shape}")
        kern = kern / kern.sum()
        if orientation == "horizontal":
            kern = kern.T
    # Render the vertical-frame target (transpose at the end for a horizontal edge).
    n_y, n_x = (rows, cols) if orientation == "vertical" else (cols, rows)
    pad_t = pad_b = pad_l = pad_r = 0
    if kern is not None:
        ph, pw = kern.shape
        pad_t, pad_b = ph - 1 - ph // 2, ph // 2
        pad_l, pad_r = pw - 1 - pw // 2, pw // 2
    h = 1.0 / k
    # Fine cell centres in pixel-centre coordinates.
    fy = (np.arange(-pad_t, n_y * k + pad_b) + 0.5) * h - 0.5
    fx = (np.arange(-pad_l, n_x * k + pad_r) + 0.5) * h - 0.5
    t = math.radians(angle_deg)
    yc, xc = (n_y - 1) / 2.0, (n_x - 1) / 2.0
    dist = (fx[None, :] - xc) * math.cos(t) - (fy[:, None] - yc) * math.sin(t) - offset_px
    cover = _box_sum_cdf(dist, h * abs(math.cos(t)), h * abs(math.sin(t)))
    fine = low + (high - low) * cover
    if kern is not None:
        from scipy.signal import fftconvolve  # here: scipy.signal takes ~1 s to import

        fine = fftconvolve(fine, kern, mode="valid")
    img = fine.reshape(n_y, k, n_x, k).mean(axis=(1, 3))
    return img if orientation == "vertical" else np.ascontiguousarray(img.T)
