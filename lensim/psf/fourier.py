"""Reference PSFs: Fourier optics (Fraunhofer) and geometric ray histogram.

Fourier-optics PSF: the pupil function A exp(i k W) on the regular pupil grid (W: optical
path difference to the reference sphere) is Fourier transformed to the image plane. The
pupil-to-direction-cosine scale is fitted to the traced rays (separately in x and y, so
the off-axis pupil's anamorphism is kept). The transform is evaluated as a matrix Fourier
transform (a zero-padded DFT whose output lands exactly on the requested sample spacing,
Soummer et al. 2007) instead of an FFT followed by interpolation.
"""

from __future__ import annotations

import math

import torch

from lensim.psf.huygens import _amplitudes, plane_obliquity, sample_offsets
from lensim.psf.pupil_field import PupilField


def direction_scale(pf: PupilField) -> tuple[float, float]:
    """Least-squares slopes du_x/dp_x and du_y/dp_y of the image-space direction cosines
    (towards the chief-ray point) against normalized pupil coordinates."""
    u = (pf.chief.unsqueeze(0) - pf.points) / pf.radius
    out = []
    for axis in (0, 1):
        p = pf.pupil_xy[:, axis]
        pc = p - p.mean()
        uc = u[:, axis] - u[:, axis].mean()
        out.append(float((pc * uc).sum() / (pc * pc).sum()))
    return out[0], out[1]


def pupil_indices(pf: PupilField) -> tuple[torch.Tensor, torch.Tensor]:
    """(row, column) of each ray's cell on the samples x samples pupil grid (rows are y)."""
    h = 2.0 / pf.samples
    ix = torch.round((pf.pupil_xy[:, 0] + 1.0) / h - 0.5).long()
    iy = torch.round((pf.pupil_xy[:, 1] + 1.0) / h - 0.5).long()
    return iy, ix


def pupil_function(pf: PupilField) -> torch.Tensor:
    """The complex pupil function on the (samples, samples) pupil grid (rows are y): each
    ray's amplitude over the sphere radius times exp(i k OPL), 0 where no ray passes."""
    k_vac = 2.0 * math.pi / pf.wavelength_mm
    iy, ix = pupil_indices(pf)
    pupil = torch.zeros(pf.samples, pf.samples, dtype=torch.complex128)
    pupil[iy, ix] = (_amplitudes(pf) / pf.radius).to(torch.complex128) * torch.exp(1j * k_vac * pf.opl)
    return pupil


def fft_psf(pf: PupilField, grid: int, spacing_um: float, offset_mm: tuple[float, float] = (0.0, 0.0)) -> torch.Tensor:
    """Fourier-optics PSF (grid x grid, energy per sample), same framing as huygens_psf."""
    s = spacing_um * 1e-3
    kn = 2.0 * math.pi / pf.wavelength_mm * pf.n_image
    ax, ay = direction_scale(pf)
    n = pf.samples
    h = 2.0 / n
    pupil = pupil_function(pf)
    pc = (torch.arange(n, dtype=torch.float64) + 0.5) * h - 1.0
    dx = sample_offsets(grid, s) + offset_mm[0]
    dy = sample_offsets(grid, s) + offset_mm[1]
    fx = torch.exp(1j * kn * ax * dx.unsqueeze(1) * pc.unsqueeze(0))  # (grid, n)
    fy = torch.exp(1j * kn * ay * dy.unsqueeze(1) * pc.unsqueeze(0))
    e = fy @ pupil @ fx.T
    return (e.real**2 + e.imag**2) * s * s * plane_obliquity(pf)


def geometric_psf(
    pf: PupilField, grid: int, spacing_um: float, offset_mm: tuple[float, float] = (0.0, 0.0)
) -> torch.Tensor:
    """Ray histogram: each ray's power binned into the sample cell it lands in."""
    s = spacing_um * 1e-3
    rel = pf.image_xy - pf.chief[:2].unsqueeze(0) - torch.tensor(offset_mm, dtype=torch.float64)
    ix = torch.floor(rel[:, 0] / s + 0.5).long() + grid // 2
    iy = torch.floor(rel[:, 1] / s + 0.5).long() + grid // 2
    ok = (ix >= 0) & (ix < grid) & (iy >= 0) & (iy < grid)
    out = torch.zeros(grid * grid, dtype=torch.float64)
    out.index_add_(0, iy[ok] * grid + ix[ok], pf.power[ok])
    return out.reshape(grid, grid)
