"""Batched real-ray tracing in float64 PyTorch.

Rays are tensors of any batch shape (typically wavelengths x fields x pupil samples).
Each surface: transfer to the vertex plane, exact conic intersection (Newton for
aspheres), clear-aperture / obscuration test, vector Snell refraction or reflection.
Failures (miss, total internal reflection, vignetting) become per-ray validity masks
with a status code and the surface where they happened; no NaN reaches the caller.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lensim.optics.lens import Lens
from lensim.optics.surfaces import Surface

DTYPE = torch.float64

# status codes (per ray)
OK = 0
MISSED = 1  # the ray does not meet the surface (or travels backwards to it)
TIR = 2  # total internal reflection
VIGNETTED = 3  # blocked by a clear aperture or obscuration
STATUS_TEXT = {OK: "ok", MISSED: "misses the surface", TIR: "is totally internally reflected", VIGNETTED: "is vignetted by the aperture"}


@dataclass
class Rays:
    """A batch of rays: position (...,3) mm, unit direction (...,3), optical path length
    (...) mm accumulated from the reference (wavefront plane or object point), validity."""

    position: torch.Tensor
    direction: torch.Tensor
    opl: torch.Tensor
    valid: torch.Tensor

    @property
    def shape(self) -> torch.Size:
        return self.opl.shape


@dataclass
class TraceResult:
    """Rays after the last traced surface, why rays failed, and (optionally) every
    surface intersection (S, ..., 3) for plots and surface-by-surface checks."""

    rays: Rays
    status: torch.Tensor
    failed_at: torch.Tensor
    surface_positions: torch.Tensor | None = None

    def first_failure(self, mask: torch.Tensor | None = None) -> tuple[int, int] | None:
        """(status, surface index) of the first failed ray (within mask), or None."""
        bad = self.status != OK
        if mask is not None:
            bad = bad & mask
        if not bool(bad.any()):
            return None
        idx = torch.nonzero(bad.reshape(-1))[0, 0]
        return int(self.status.reshape(-1)[idx]), int(self.failed_at.reshape(-1)[idx])


def media_indices(lens: Lens, wavelength_um: torch.Tensor) -> torch.Tensor:
    """Index of each medium (N+1, *wavelength_um.shape) as a float64 tensor."""
    wl = wavelength_um.detach().cpu().numpy().astype(np.float64)
    n = lens.indices(wl.reshape(-1)).reshape((lens.num_surfaces + 1,) + wl.shape)
    return torch.as_tensor(n, dtype=DTYPE, device=wavelength_um.device)


def _refract(d: torch.Tensor, normal: torch.Tensor, n1: torch.Tensor, n2: torch.Tensor):
    """Vector Snell's law. Returns (new direction, TIR mask)."""
    cos_i = (d * normal).sum(-1)
    sign = torch.where(cos_i < 0, -1.0, 1.0).to(d.dtype)
    nrm = normal * sign.unsqueeze(-1)
    cos_i = cos_i * sign
    mu = n1 / n2
    sin2_t = mu * mu * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = torch.sqrt(torch.clamp(1.0 - sin2_t, min=0.0))
    new = mu.unsqueeze(-1) * d + (cos_t - mu * cos_i).unsqueeze(-1) * nrm
    new = new / torch.linalg.norm(new, dim=-1, keepdim=True)
    return new, tir


def _reflect(d: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    return d - 2.0 * (d * normal).sum(-1, keepdim=True) * normal


def trace_surface(
    surf: Surface,
    z_vertex: float,
    rays: Rays,
    n_before: torch.Tensor,
    n_after: torch.Tensor,
    allow_backwards: bool = False,
    apertures: bool = True,
    interact: bool = True,
):
    """Propagate rays to one surface and refract/reflect there.

    Returns (new rays, status code for rays that failed here (OK otherwise)).
    """
    pos, d = rays.position, rays.direction
    dz = d[..., 2]
    ok_dir = dz.abs() > 1e-12
    safe_dz = torch.where(ok_dir, dz, torch.ones_like(dz))
    local = pos.clone()
    local[..., 2] = local[..., 2] - z_vertex
    t0 = -local[..., 2] / safe_dz
    p1 = local + t0.unsqueeze(-1) * d
    t1, hit = surf.intersect(p1, d)
    t = torch.where(ok_dir & hit, t0 + t1, torch.zeros_like(t0))
    hit = hit & ok_dir
    if not allow_backwards:
        hit = hit & (t > -1e-9)
    new_local = local + t.unsqueeze(-1) * d
    x, y = new_local[..., 0], new_local[..., 1]
    status = torch.where(rays.valid & ~hit, MISSED, OK)
    valid = rays.valid & hit
    if apertures:
        inside = surf.passes_aperture(x, y)
        status = torch.where(valid & ~inside, VIGNETTED, status)
        valid = valid & inside
    opl = rays.opl + n_before * t
    if interact:
        normal = surf.normal(x, y)
        if surf.is_mirror:
            new_d = _reflect(d, normal)
        else:
            new_d, tir = _refract(d, normal, n_before, n_after)
            status = torch.where(valid & tir, TIR, status)
            valid = valid & ~tir
    else:
        new_d = d
    new_pos = new_local.clone()
    new_pos[..., 2] = new_pos[..., 2] + z_vertex
    # keep invalid rays finite and inert
    new_pos = torch.where(valid.unsqueeze(-1), new_pos, pos)
    new_d = torch.where(valid.unsqueeze(-1), new_d, d)
    opl = torch.where(valid, opl, rays.opl)
    return Rays(new_pos, new_d, opl, valid), status


def trace(
    lens: Lens,
    rays: Rays,
    wavelength_um: torch.Tensor,
    start: int = 0,
    end: int | None = None,
    to_image: bool = True,
    record: bool = False,
    apertures: bool = True,
    indices: torch.Tensor | None = None,
) -> TraceResult:
    """Trace rays (in the medium before surface `start`) through surfaces start..end-1 and,
    if to_image and end is the last surface, on to the image plane.

    wavelength_um must broadcast against the rays' batch shape.
    """
    end = lens.num_surfaces if end is None else end
    n = media_indices(lens, wavelength_um) if indices is None else indices
    zv = lens.vertex_z()
    status = torch.zeros(rays.shape, dtype=torch.int8, device=rays.opl.device)
    failed_at = torch.full(rays.shape, -1, dtype=torch.int16, device=rays.opl.device)
    positions = []
    for i in range(start, end):
        rays, st = trace_surface(
            lens.surfaces[i], float(zv[i]), rays, n[i], n[i + 1], allow_backwards=(i == start), apertures=apertures
        )
        newly = (st != OK) & (status == OK)
        status = torch.where(newly, st.to(status.dtype), status)
        failed_at = torch.where(newly, torch.as_tensor(i, dtype=failed_at.dtype), failed_at)
        if record:
            positions.append(rays.position)
    if to_image and end == lens.num_surfaces:
        image = Surface(clear_radius=lens.image_clear_radius)
        rays, st = trace_surface(image, float(zv[-1]), rays, n[-1], n[-1], apertures=apertures, interact=False)
        newly = (st != OK) & (status == OK)
        status = torch.where(newly, st.to(status.dtype), status)
        failed_at = torch.where(newly, torch.as_tensor(end, dtype=failed_at.dtype), failed_at)
        if record:
            positions.append(rays.position)
    surface_positions = torch.stack(positions) if record and positions else None
    return TraceResult(rays, status, failed_at, surface_positions)
