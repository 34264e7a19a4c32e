"""PSF figures of merit: Strehl ratio, RMS spot radius, encircled energy, MTF."""

from __future__ import annotations

import numpy as np
import torch

from lensim.psf.huygens import ideal_peak
from lensim.psf.pupil_field import PupilField


def strehl_ratio(psf: torch.Tensor, pf: PupilField, spacing_um: float) -> float:
    """Sampled PSF peak over the aberration-free peak of the same pupil (same sampling)."""
    return float(psf.max() / ideal_peak(pf, spacing_um))


def rms_spot_radius_um(pf: PupilField) -> float:
    """Power-weighted RMS distance (um) of the ray intercepts from their centroid."""
    w = pf.power / pf.power.sum()
    c = (pf.image_xy * w.unsqueeze(-1)).sum(0)
    return float(torch.sqrt((((pf.image_xy - c) ** 2).sum(-1) * w).sum()) * 1e3)


def encircled_energy_radius(psf: np.ndarray, spacing_um: float, fraction: float) -> float:
    """Radius (um) around the PSF centroid holding `fraction` of the window's energy."""
    psf = np.asarray(psf, dtype=np.float64)
    n_y, n_x = psf.shape
    y, x = np.mgrid[0:n_y, 0:n_x].astype(np.float64)
    total = psf.sum()
    cx, cy = (psf * x).sum() / total, (psf * y).sum() / total
    r = np.hypot(x - cx, y - cy).ravel() * spacing_um
    order = np.argsort(r)
    cum = np.cumsum(psf.ravel()[order]) / total
    i = int(np.searchsorted(cum, fraction))
    return float(r[order][min(i, r.size - 1)])


def mtf(psf: np.ndarray, spacing_um: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frequencies in cycles/mm, sagittal MTF, tangential MTF) from a PSF whose rows
    are y (the meridional direction for fields along y): tangential = along y."""
    psf = np.asarray(psf, dtype=np.float64)
    otf = np.abs(np.fft.fft2(psf))
    otf /= otf[0, 0]
    n = psf.shape[0]
    freqs = np.fft.fftfreq(n, d=spacing_um * 1e-3)[: n // 2]
    sagittal = otf[0, : n // 2]
    tangential = otf[: n // 2, 0]
    return freqs, sagittal, tangential
