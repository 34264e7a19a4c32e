"""PSF figures of merit: Strehl ratio, RMS spot radius, encircled and ensquared energy, MTF."""

from __future__ import annotations

import math

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


def encircled_energy_radii(
    psf: np.ndarray, spacing_um: float, fractions: tuple[float, ...], band_limited: bool = True
) -> tuple[float, ...]:
    """Radii (um) around the PSF centroid holding each of `fractions` of the window's
    energy, from one enclosed_energy curve (every 1/8 sample; band_limited as there)."""
    psf = np.asarray(psf, dtype=np.float64)
    radii = np.arange(0.0, 0.5 * math.hypot(*psf.shape) + 1.0, 0.125) * spacing_um
    curve = enclosed_energy(psf, spacing_um, radii, "circle", band_limited=band_limited)
    found = [size_at_fraction(radii, curve, f) for f in fractions]
    return tuple(float(radii[-1]) if r is None else r for r in found)


def _sub_samples(
    psf: np.ndarray, spacing_um: float, sub: int, band_limited: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x (columns) and y (rows) axes (um, from the window's centre sample grid//2) of
    sub x sub points per sample, and their energy (rows y, columns x), the total energy
    kept. band_limited: the PSF read as samples of a band-limited irradiance (a
    diffraction PSF sampled finer than lambda N / 2, as lensim's are), Fourier-interpolated
    onto the points (zero-padded FFT); otherwise (a ray histogram) each sample's energy
    shared evenly over the points inside its cell."""
    n_y, n_x = psf.shape
    if band_limited:  # the spectrum zero-padded about frequency 0, in FFT order
        rows = np.fft.fftfreq(n_y, 1.0 / n_y).astype(np.int64) % (n_y * sub)
        cols = np.fft.fftfreq(n_x, 1.0 / n_x).astype(np.int64) % (n_x * sub)
        big = np.zeros((n_y * sub, n_x * sub), dtype=np.complex128)
        big[np.ix_(rows, cols)] = np.fft.fft2(psf)
        e = np.clip(np.fft.ifft2(big).real, 0.0, None)
        fx, fy = np.arange(n_x * sub) / sub, np.arange(n_y * sub) / sub  # in samples
    else:
        e = np.repeat(np.repeat(psf, sub, axis=0), sub, axis=1)
        off = (np.arange(sub) + 0.5) / sub - 0.5
        fx = (np.arange(n_x)[:, None] + off[None, :]).ravel()
        fy = (np.arange(n_y)[:, None] + off[None, :]).ravel()
    e = e * (psf.sum() / e.sum()) if e.sum() > 0 else e
    return (fx - n_x // 2) * spacing_um, (fy - n_y // 2) * spacing_um, e


def psf_centroid_um(psf: np.ndarray, spacing_um: float) -> tuple[float, float]:
    """(x, y) of the PSF's centroid, um from the window's centre sample (grid//2)."""
    psf = np.asarray(psf, dtype=np.float64)
    n_y, n_x = psf.shape
    total = psf.sum()
    cx = float((psf.sum(0) * (np.arange(n_x) - n_x // 2)).sum() / total) * spacing_um
    cy = float((psf.sum(1) * (np.arange(n_y) - n_y // 2)).sum() / total) * spacing_um
    return cx, cy


def enclosed_energy(
    psf: np.ndarray,
    spacing_um: float,
    sizes_um: np.ndarray,
    shape: str = "circle",
    centre_um: tuple[float, float] | None = None,
    total: float | None = None,
    sub: int = 4,
    band_limited: bool = True,
) -> np.ndarray:
    """Fraction of the energy inside a circle of each radius (shape 'circle': encircled
    energy) or a square of each half-width (shape 'square': ensquared energy), um, around
    centre_um ((x, y) um from the window's centre sample; default the PSF's centroid).

    Each sample stands for sub x sub points (_sub_samples: Fourier-interpolated when
    band_limited, a diffraction PSF; shared evenly otherwise, a ray histogram). total: the
    energy the fractions are of (default the window's sum; give the transmitted energy to
    count what falls outside the window as lost)."""
    psf = np.asarray(psf, dtype=np.float64)
    cx, cy = psf_centroid_um(psf, spacing_um) if centre_um is None else centre_um
    x, y, e = _sub_samples(psf, spacing_um, sub, band_limited)
    if shape == "circle":
        d = np.sqrt(((x - cx) ** 2)[None, :] + ((y - cy) ** 2)[:, None])
    elif shape == "square":
        d = np.maximum(np.abs(x - cx)[None, :], np.abs(y - cy)[:, None])
    else:
        raise ValueError(f"expected shape 'circle' or 'square', got {shape!r}")
    # each point's energy spread evenly over +-h/2 in distance (h the point spacing), so
    # that the curve does not step with the lattice: EE(r) = (A(r + h/2) - A(r - h/2)) / h,
    # A(t) = sum_i e_i max(t - d_i, 0) = t E(t) - D(t), with E and D the sums of e_i and
    # e_i d_i over d_i <= t: binned at the sorted distinct t (no sort of the points)
    d, e = d.ravel(), e.ravel()
    h = spacing_um / sub
    r = np.asarray(sizes_um, dtype=np.float64)
    t_all = np.concatenate([r + h / 2, np.maximum(r - h / 2, 0.0)])
    ts = np.unique(t_all)
    first = np.searchsorted(ts, d, side="left")  # the first t with d_i <= t
    cum_e = np.cumsum(np.bincount(first, weights=e, minlength=ts.size + 1))[: ts.size]
    cum_ed = np.cumsum(np.bincount(first, weights=e * d, minlength=ts.size + 1))[: ts.size]
    area = ts * cum_e - cum_ed
    a_hi, a_lo = np.split(area[np.searchsorted(ts, t_all)], 2)
    enclosed = np.where(r > 0, (a_hi - a_lo) / h, 0.0)
    return enclosed / (psf.sum() if total is None else total)


def size_at_fraction(sizes: np.ndarray, fractions: np.ndarray, fraction: float) -> float | None:
    """The smallest size (radius or half-width) whose enclosed fraction reaches
    `fraction`, interpolated linearly; None when the curve never reaches it."""
    fractions = np.asarray(fractions, dtype=np.float64)
    above = np.nonzero(fractions >= fraction)[0]
    if above.size == 0:
        return None
    i = int(above[0])
    if i == 0:
        return float(sizes[0])
    f0, f1 = fractions[i - 1], fractions[i]
    return float(sizes[i - 1] + (fraction - f0) / (f1 - f0) * (sizes[i] - sizes[i - 1]))


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
