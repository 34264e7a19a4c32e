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
    """x, y (um, from the window's centre sample grid//2) and energy of sub x sub points
    per sample, the total energy kept. band_limited: the PSF read as samples of a
    band-limited irradiance (a diffraction PSF sampled finer than lambda N / 2, as
    lensim's are), Fourier-interpolated onto the points (zero-padded FFT); otherwise (a
    ray histogram) each sample's energy shared evenly over the points inside its cell."""
    n_y, n_x = psf.shape
    if band_limited:
        spec = np.fft.fftshift(np.fft.fft2(psf))
        big = np.zeros((n_y * sub, n_x * sub), dtype=np.complex128)
        y0, x0 = n_y * sub // 2 - n_y // 2, n_x * sub // 2 - n_x // 2
        big[y0 : y0 + n_y, x0 : x0 + n_x] = spec
        e = np.clip(np.fft.ifft2(np.fft.ifftshift(big)).real, 0.0, None)
        fx, fy = np.arange(n_x * sub) / sub, np.arange(n_y * sub) / sub  # in samples
    else:
        e = np.repeat(np.repeat(psf, sub, axis=0), sub, axis=1)
        off = (np.arange(sub) + 0.5) / sub - 0.5
        fx = (np.arange(n_x)[:, None] + off[None, :]).ravel()
        fy = (np.arange(n_y)[:, None] + off[None, :]).ravel()
    e = e * (psf.sum() / e.sum()) if e.sum() > 0 else e
    x = np.broadcast_to(((fx - n_x // 2) * spacing_um)[None, :], e.shape)
    y = np.broadcast_to(((fy - n_y // 2) * spacing_um)[:, None], e.shape)
    return x.ravel(), y.ravel(), e.ravel()


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
        d = np.hypot(x - cx, y - cy)
    elif shape == "square":
        d = np.maximum(np.abs(x - cx), np.abs(y - cy))
    else:
        raise ValueError(f"expected shape 'circle' or 'square', got {shape!r}")
    # each point's energy spread evenly over +-h/2 in distance (h the point spacing), so
    # that the curve does not step with the lattice: EE(r) = (A(r + h/2) - A(r - h/2)) / h,
    # A(t) = sum_i e_i max(t - d_i, 0)
    order = np.argsort(d)
    d, e = d[order], e[order]
    cum_e = np.concatenate([[0.0], np.cumsum(e)])
    cum_ed = np.concatenate([[0.0], np.cumsum(e * d)])
    h = spacing_um / sub

    def antiderivative(t: np.ndarray) -> np.ndarray:
        k = np.searchsorted(d, t, side="right")
        return t * cum_e[k] - cum_ed[k]

    r = np.asarray(sizes_um, dtype=np.float64)
    enclosed = (antiderivative(r + h / 2) - antiderivative(np.maximum(r - h / 2, 0.0))) / h
    enclosed = np.where(r > 0, enclosed, 0.0)
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
