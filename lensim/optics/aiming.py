"""Object-space ray generation and ray aiming.

A ray is named by its field (in the lens's field unit) and its normalized pupil
coordinates (px, py) in the unit disc. Paraxial aiming sends it through the point
(px, py) * EPD/2 of the paraxial entrance pupil; real aiming finds, by Newton
iteration, the ray that crosses the real stop surface at (px, py) * paraxial stop
semi-diameter (as Zemax's ray aiming does), so wide-angle lenses with pupil aberration
and distortion are traced right. The chief ray is (0, 0).

Object at infinity: rays of one field are parallel, direction (0, sin a, cos a) for
field angle a (Zemax's sign convention), starting on the entrance-pupil plane; their
OPL starts at the plane wavefront through the origin. Finite object: rays start at the
object point (0, h, -distance) with OPL 0.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch

from lensim.errors import InputError, RayTraceError
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data, paraxial_image_height
from lensim.optics.trace import DTYPE, STATUS_TEXT, Rays, media_indices, trace

Aiming = Literal["paraxial", "real"]
AIM_TOL_MM = 1e-10
AIM_MAX_ITER = 25


def _tensor(x, device=None) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=DTYPE, device=device)


def launch(lens: Lens, field: torch.Tensor, pupil_xy: torch.Tensor, para: ParaxialData) -> tuple[torch.Tensor, torch.Tensor]:
    """Object-space rays from field values (angle deg or object height mm, shape F[,...])
    through entrance-pupil-plane points pupil_xy (..., 2) in mm. Returns (position,
    direction) broadcast to (F, P, 3)."""
    z_ep = para.entrance_pupil_z_mm
    fld = field.reshape(-1, 1)
    ex, ey = pupil_xy[..., 0].unsqueeze(0), pupil_xy[..., 1].unsqueeze(0)
    if lens.infinite_object:
        a = torch.deg2rad(fld)
        dirs = torch.stack(torch.broadcast_tensors(torch.zeros_like(a), torch.sin(a), torch.cos(a)), -1)
        dirs = dirs.expand(ex.shape[0] * 0 + fld.shape[0], ex.shape[1], 3)
        pos = torch.stack(torch.broadcast_tensors(ex, ey, torch.full_like(ey, z_ep)), -1)
        pos = pos.expand(fld.shape[0], ex.shape[1], 3)
        return pos.clone(), dirs.clone()
    d = lens.object_distance
    if lens.field_type == "angle":
        h = -(d + z_ep) * torch.tan(torch.deg2rad(fld))
    else:
        h = fld
    src = torch.stack(torch.broadcast_tensors(torch.zeros_like(h), h, torch.full_like(h, -d)), -1)
    target = torch.stack(torch.broadcast_tensors(ex, ey, torch.full_like(ey, z_ep)), -1)
    src, target = torch.broadcast_tensors(src, target)
    v = target - src
    return src.clone(), v / torch.linalg.norm(v, dim=-1, keepdim=True)


def object_rays(lens: Lens, position: torch.Tensor, direction: torch.Tensor, n_object: torch.Tensor) -> Rays:
    """Rays with their starting OPL: plane wavefront through the origin for an object at
    infinity, zero at the object point otherwise."""
    if lens.infinite_object:
        opl = n_object * (position * direction).sum(-1)
    else:
        opl = torch.zeros(position.shape[:-1], dtype=DTYPE, device=position.device) + 0 * n_object
    valid = torch.ones(opl.shape, dtype=torch.bool, device=position.device)
    return Rays(position, direction, opl, valid)


def generate_rays(
    lens: Lens,
    field: torch.Tensor | float | list,
    pupil: torch.Tensor,
    wavelength_um: torch.Tensor | float | list,
    aiming: Aiming = "paraxial",
    para: ParaxialData | None = None,
) -> tuple[Rays, torch.Tensor]:
    """Rays for every wavelength x field x pupil point, shape (W, F, P).

    field: object-space field values (angle deg for an infinite object, object height mm
    or angle for a finite one; see object_field for image-height fields). pupil: (P, 2)
    normalized pupil coordinates. Returns (rays, wavelength tensor shaped (W, 1, 1)).
    """
    device = pupil.device
    para = para or paraxial_data(lens)
    fld = _tensor(np.atleast_1d(np.asarray(field, dtype=np.float64)), device)
    wl = _tensor(np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64)), device).reshape(-1, 1, 1)
    n = media_indices(lens, wl)
    r_ep = para.epd_mm / 2.0
    ep_xy = pupil.to(DTYPE) * r_ep
    W, F, P = wl.shape[0], fld.shape[0], pupil.shape[0]
    if aiming == "paraxial":
        pos, dirs = launch(lens, fld, ep_xy, para)
        pos = pos.unsqueeze(0).expand(W, F, P, 3)
        dirs = dirs.unsqueeze(0).expand(W, F, P, 3)
        return object_rays(lens, pos, dirs, n[0]), wl
    if aiming != "real":
        raise InputError(None, "aiming", f"expected 'paraxial' or 'real', got {aiming!r}")
    target = pupil.to(DTYPE) * para.stop_semi_diameter_mm  # (P, 2)
    guess = ep_xy.unsqueeze(0).unsqueeze(0).expand(W, F, P, 2).clone()
    solved, converged = _aim(lens, fld, guess, target, wl, n, para)
    pos, dirs = _launch_batched(lens, fld, solved, para)
    rays = object_rays(lens, pos, dirs, n[0])
    rays.valid = rays.valid & converged
    return rays, wl


def _launch_batched(lens, fld, ep_xy, para):
    """launch() for per-(W, F, P) pupil-plane points ep_xy (W, F, P, 2)."""
    W, F, P, _ = ep_xy.shape
    flat = ep_xy.permute(1, 0, 2, 3).reshape(F, W * P, 2)
    z_ep = para.entrance_pupil_z_mm
    fl = fld.reshape(F, 1)
    if lens.infinite_object:
        a = torch.deg2rad(fl)
        dirs = torch.stack([torch.zeros_like(a), torch.sin(a), torch.cos(a)], -1).expand(F, W * P, 3)
        pos = torch.cat([flat, torch.full_like(flat[..., :1], z_ep)], -1)
    else:
        d = lens.object_distance
        h = -(d + z_ep) * torch.tan(torch.deg2rad(fl)) if lens.field_type == "angle" else fl
        src = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -d)], -1).expand(F, W * P, 3)
        tgt = torch.cat([flat, torch.full_like(flat[..., :1], z_ep)], -1)
        v = tgt - src
        pos, dirs = src, v / torch.linalg.norm(v, dim=-1, keepdim=True)
    pos = pos.reshape(F, W, P, 3).permute(1, 0, 2, 3).contiguous()
    dirs = dirs.reshape(F, W, P, 3).permute(1, 0, 2, 3).contiguous()
    return pos, dirs


def _stop_xy(lens, fld, ep_xy, wl, n, para):
    pos, dirs = _launch_batched(lens, fld, ep_xy, para)
    rays = object_rays(lens, pos, dirs, n[0])
    res = trace(lens, rays, wl, end=lens.stop_index + 1, to_image=False, apertures=False, indices=n)
    return res.rays.position[..., :2], res.rays.valid


def _aim(lens, fld, guess, target, wl, n, para):
    """Newton iteration on the entrance-pupil-plane point so the ray meets the stop at target."""
    scale = max(para.epd_mm, 1e-3)
    h = 1e-7 * scale
    x = guess
    converged = torch.zeros(x.shape[:-1], dtype=torch.bool, device=x.device)
    for _ in range(AIM_MAX_ITER):
        s0, v0 = _stop_xy(lens, fld, x, wl, n, para)
        r = s0 - target
        converged = v0 & (r.abs().amax(-1) < AIM_TOL_MM * max(1.0, para.stop_semi_diameter_mm))
        if bool(converged.all()):
            break
        dx = torch.zeros_like(x)
        dx[..., 0] = h
        sx, vx = _stop_xy(lens, fld, x + dx, wl, n, para)
        dy = torch.zeros_like(x)
        dy[..., 1] = h
        sy, vy = _stop_xy(lens, fld, x + dy, wl, n, para)
        j00, j10 = (sx[..., 0] - s0[..., 0]) / h, (sx[..., 1] - s0[..., 1]) / h
        j01, j11 = (sy[..., 0] - s0[..., 0]) / h, (sy[..., 1] - s0[..., 1]) / h
        det = j00 * j11 - j01 * j10
        ok = v0 & vx & vy & (det.abs() > 1e-300)
        det = torch.where(ok, det, torch.ones_like(det))
        step_x = (j11 * r[..., 0] - j01 * r[..., 1]) / det
        step_y = (-j10 * r[..., 0] + j00 * r[..., 1]) / det
        step = torch.stack([step_x, step_y], -1)
        # damp large steps (far from the solution the map can be strongly non-linear)
        limit = 0.5 * scale
        norm = torch.linalg.norm(step, dim=-1, keepdim=True)
        step = torch.where(norm > limit, step * limit / norm, step)
        active = ok & ~converged
        if not bool(active.any()):
            break  # the rest cannot move: a ray that fails at its guess or its probes keeps it
        x = torch.where(active.unsqueeze(-1), x - step, x)
    return x, converged


def object_field(lens: Lens, value: float, aiming: Aiming = "paraxial", para: ParaxialData | None = None) -> float:
    """Convert a field in the lens's unit to what rays are launched with: an angle (deg)
    for an object at infinity, an object height (mm) for a finite object (or the angle,
    for angle fields).

    Image-height fields are solved for: paraxial image height exactly (it is linear in
    tan(angle), or in object height), real image height by secant iteration on the real
    chief ray (primary wavelength) from the paraxial solution.
    """
    para = para or paraxial_data(lens)
    if lens.field_type in ("angle", "object_height"):
        return float(value)
    if value == 0:
        return 0.0
    probe_lens = lens.launch_lens()
    # paraxial image height per unit of tan(angle) (infinite object) or object height
    unit = 1e-3
    probe = math.degrees(math.atan(unit)) if lens.infinite_object else unit
    per_unit = paraxial_image_height(probe_lens, probe, para) / unit
    if per_unit == 0:
        raise InputError(lens.source, "fields", "the lens forms no image (zero paraxial image height per field)")
    guess = math.degrees(math.atan(value / per_unit)) if lens.infinite_object else value / per_unit
    if lens.field_type == "paraxial_image_height":
        return guess

    def miss(f: float) -> float:
        return chief_ray_image_height(probe_lens, f, aiming=aiming, para=para) - value

    x0, x1 = guess * 0.95, guess
    f0, f1 = miss(x0), miss(x1)
    for _ in range(50):
        if abs(f1) < 1e-10 or f1 == f0:
            break
        x0, x1, f0 = x1, x1 - f1 * (x1 - x0) / (f1 - f0), f1
        f1 = miss(x1)
    if abs(f1) < 1e-8:
        return x1
    raise RayTraceError(f"{lens.source}: fields: no real chief ray reaches image height {value} mm")


def chief_ray_image_height(lens: Lens, field_value: float, aiming: Aiming = "real", para: ParaxialData | None = None,
                           wavelength_um: float | None = None) -> float:
    """Real chief-ray y (mm) on the image plane for a launch field value (angle or object height)."""
    para = para or paraxial_data(lens)
    wl = lens.primary_wavelength_um if wavelength_um is None else wavelength_um
    rays, wlt = generate_rays(lens, [field_value], torch.zeros(1, 2, dtype=DTYPE), [wl], aiming, para)
    res = trace(lens, rays, wlt)
    if not bool(res.rays.valid.all()):
        fail = res.first_failure()
        raise RayTraceError(describe_failure(lens, field_value, fail, "chief ray"))
    return float(res.rays.position[0, 0, 0, 1])


def describe_failure(lens: Lens, field_value: float, fail, what: str) -> str:
    """One line: which ray failed, where and how."""
    unit = "deg" if lens.launch_field_type == "angle" else "mm"
    if fail is None:
        return (f"{lens.source}: fields: the {what} at field {field_value:g} {unit} could not be aimed through the stop; "
                f"expected a field inside the lens's coverage")
    status, surf = fail
    where = "the image plane" if surf >= lens.num_surfaces else f"surfaces[{surf}] (surface {surf + 1} in lens info)"
    return (f"{lens.source}: fields: the {what} at field {field_value:g} {unit} {STATUS_TEXT[status]} at {where}; "
            f"expected a field inside the lens's coverage")
