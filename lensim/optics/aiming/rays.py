"""Rays of fields and pupil points (paraxial or real aiming), and the chief ray as a reference ray.

A ray is named by its field (in the lens's field unit) and its normalized pupil
coordinates (px, py) in the unit disc. Paraxial aiming sends it through the point
(px, py) * EPD/2 of the paraxial entrance pupil; real aiming (lensim.optics.aiming.real)
finds the ray that crosses the real stop surface at (px, py) * paraxial stop
semi-diameter (as Zemax's ray aiming does), so wide-angle lenses with pupil aberration
and distortion are traced right, up to the field where the chief ray stops existing.
The chief ray is (0, 0). Where rays start: lensim.optics.aiming.launch.

The chief ray is a reference ray: it is traced through unobscured(lens), so a central
obscuration (a Cassegrain's secondary, a mirror-backed secondary spot, the shadow of a
spider hub) never rejects a field, while every real ray is still blocked by it. A field
whose chief ray fails is named in a one-line error with the largest field that works.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch

from lensim.errors import InputError, RayTraceError
from lensim.optics.aiming.launch import launch, launch_at, object_rays
from lensim.optics.aiming.modes import Aiming
from lensim.optics.aiming.real import aim_real
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data, paraxial_image_height
from lensim.optics.trace import (
    DTYPE,
    STATUS_TEXT,
    Rays,
    TraceResult,
    host_empty,
    media_indices,
    trace,
)


def _tensor(x, device=None) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=DTYPE, device=device)


def generate_rays(
    lens: Lens,
    field: torch.Tensor | float | list,
    pupil: torch.Tensor,
    wavelength_um: torch.Tensor | float | list,
    aiming: Aiming = "paraxial",
    para: ParaxialData | None = None,
    start: torch.Tensor | None = None,
) -> tuple[Rays, torch.Tensor]:
    """Rays for every wavelength x field x pupil point, shape (W, F, P).

    field: object-space field values (angle deg for an infinite object, object height mm
    or angle for a finite one; see object_field for image-height fields). pupil: (P, 2)
    normalized pupil coordinates. Returns (rays, wavelength tensor shaped (W, 1, 1)).
    start: with real aiming, a nearby solution of the aim (the ``entrance_xy`` of rays
    aimed before, e.g. at a neighbouring wavelength) to start from
    (lensim.optics.aiming.real.aim_real). Real-aimed rays carry their aim as
    ``rays.entrance_xy`` (W, F, P, 2).
    """
    device = pupil.device
    para = para or paraxial_data(lens)
    fld = _tensor(np.atleast_1d(np.asarray(field, dtype=np.float64)), device)
    wl = _tensor(np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64)), device).reshape(-1, 1, 1)
    n = media_indices(lens, wl)
    W, F = wl.shape[0], fld.shape[0]
    if aiming == "paraxial":
        return _paraxial_rays(lens, fld, pupil, para, n[0], W), wl
    if aiming != "real":
        raise InputError(None, "aiming", f"expected 'paraxial' or 'real', got {aiming!r}")
    solved, converged = aim_real(lens, fld, pupil, wl, n, para, start)
    pos, dirs = launch_at(lens, fld.reshape(1, F, 1), solved, para.entrance_pupil_z_mm)
    rays = object_rays(lens, pos, dirs, n[0])
    rays.valid = rays.valid & converged
    rays.entrance_xy = solved
    return rays, wl


#: pupil points x fields x wavelengths per piece of a paraxial launch with more than one
#: torch thread: its largest tensor (the positions, 3 values a point) stays below torch's
#: grain size (32768), so each operation runs on one core (no OpenMP region whose threads
#: spin while another process holds a core); with one thread the launch runs whole
LAUNCH_PIECE = 10922


def _paraxial_rays(
    lens: Lens, fld: torch.Tensor, pupil: torch.Tensor, para: ParaxialData, n0: torch.Tensor, W: int
) -> Rays:
    """Paraxially aimed rays (W, F, P) of fields fld (F,) through pupil points (P, 2),
    launched and given their starting OPL (media index n0, (W, 1, 1)): by the compiled
    loop for an object at infinity (at least FUSED_LAUNCH_MIN rays on the CPU, no
    gradients), else by torch in pieces of the pupil of LAUNCH_PIECE elements (whole,
    where gradients flow, off the CPU, or with one torch thread, which opens no parallel
    region)."""
    F, P = fld.shape[0], pupil.shape[0]
    r_ep = para.epd_mm / 2.0
    if _fused_launch_applies(lens, fld, pupil, para, n0, W):
        return _fused_paraxial_rays(lens, fld, pupil, para, n0, W)
    step = max(1, LAUNCH_PIECE // (W * F))
    whole = P <= step or pupil.device.type != "cpu" or pupil.requires_grad or torch.get_num_threads() == 1
    if whole or isinstance(para.entrance_pupil_z_mm, torch.Tensor):
        p_all, d_all = launch(lens, fld, pupil.to(DTYPE) * r_ep, para)
        return object_rays(lens, p_all.unsqueeze(0).expand(W, F, P, 3), d_all.unsqueeze(0).expand(W, F, P, 3), n0)
    pos = torch.empty(F, P, 3, dtype=DTYPE)
    opl = torch.empty(W, F, P, dtype=DTYPE)
    valid = torch.empty(W, F, P, dtype=torch.bool)
    dirs: torch.Tensor | None = None
    for a in range(0, P, step):
        b = min(a + step, P)
        pp, dd = launch(lens, fld, pupil[a:b].to(DTYPE) * r_ep, para)
        if dirs is None:  # one direction per field (an object at infinity) stays expanded
            dirs = dd[:, :1].expand(F, P, 3) if dd.stride(-2) == 0 else torch.empty(F, P, 3, dtype=DTYPE)
        if dirs.stride(-2) != 0:
            dirs[:, a:b].copy_(dd)
        pos[:, a:b].copy_(pp)
        piece = object_rays(lens, pp.unsqueeze(0).expand(W, F, b - a, 3), dd.unsqueeze(0).expand(W, F, b - a, 3), n0)
        opl[..., a:b].copy_(piece.opl)
        valid[..., a:b].fill_(True)
    assert dirs is not None
    return Rays(pos.unsqueeze(0).expand(W, F, P, 3), dirs.unsqueeze(0).expand(W, F, P, 3), opl, valid)


#: the smallest paraxial launch (wavelengths x fields x pupil points) that runs the compiled
#: loop (lensim.optics.aiming.launch_fused): smaller ones (chief rays, fans) need not import
#: numba; the same threshold as the tracer's (lensim.optics.trace.FUSED_MIN_BATCH)
FUSED_LAUNCH_MIN = 4096


def _fused_launch_applies(
    lens: Lens, fld: torch.Tensor, pupil: torch.Tensor, para: ParaxialData, n0: torch.Tensor, W: int
) -> bool:
    """Whether the compiled launch covers these rays: an object at infinity, CPU tensors,
    no gradients, at least FUSED_LAUNCH_MIN rays, the kernel not turned off."""
    from lensim.optics import trace as trace_mod

    values: tuple[object, ...] = (fld, pupil, n0, para.epd_mm, para.entrance_pupil_z_mm)
    return (
        lens.infinite_object
        and trace_mod.fused_kernels_allowed()
        and W * fld.shape[0] * pupil.shape[0] >= FUSED_LAUNCH_MIN
        and all(not isinstance(v, torch.Tensor) or (v.device.type == "cpu" and not v.requires_grad) for v in values)
    )


def _fused_paraxial_rays(
    lens: Lens, fld: torch.Tensor, pupil: torch.Tensor, para: ParaxialData, n0: torch.Tensor, W: int
) -> Rays:
    """_paraxial_rays of an object at infinity by the compiled loop: the same rays, bit for
    bit; the one direction of each field comes from launch() and is expanded over the
    points, as there."""
    from lensim.optics.aiming.launch_fused import launch_infinite

    F, P = fld.shape[0], pupil.shape[0]
    r_ep = float(para.epd_mm) / 2.0
    _, d_one = launch(lens, fld, pupil[:1].to(DTYPE) * r_ep, para)  # (F, 1, 3)
    cpu = torch.device("cpu")
    pos, opl, valid = (
        host_empty((F, P, 3), DTYPE, cpu),
        host_empty((W, F, P), DTYPE, cpu),
        host_empty((W, F, P), torch.bool, cpu),
    )
    launch_infinite(
        pupil.to(DTYPE).contiguous().numpy(),
        r_ep,
        float(para.entrance_pupil_z_mm),
        d_one[:, 0].contiguous().numpy(),
        n0.expand(W, 1, 1).reshape(W).to(DTYPE).contiguous().numpy(),
        pos.numpy(),
        opl.numpy(),
        valid.numpy(),
    )
    dirs = d_one.expand(F, P, 3)
    return Rays(pos.unsqueeze(0).expand(W, F, P, 3), dirs.unsqueeze(0).expand(W, F, P, 3), opl, valid)


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


def chief_ray_image_height(
    lens: Lens,
    field_value: float,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
    wavelength_um: float | None = None,
) -> float:
    """Real chief-ray y (mm) on the image plane for a launch field value (angle or object height)."""
    para = para or paraxial_data(lens)
    wl = lens.primary_wavelength_um if wavelength_um is None else wavelength_um
    rays, wlt = generate_rays(lens, [field_value], torch.zeros(1, 2, dtype=DTYPE), [wl], aiming, para)
    res = trace_chief_rays(lens, rays, wlt, [field_value], aiming, para)
    return float(res.rays.position[0, 0, 0, 1])


def unobscured(lens: Lens) -> Lens:
    """The lens without its central obscurations: what reference rays (chief rays) are
    traced through. Clear apertures still apply."""
    if all(s.obscuration_radius is None for s in lens.surfaces):
        return lens
    return lens.with_changes(surfaces=[replace(s, obscuration_radius=None) for s in lens.surfaces])


def trace_chief_rays(
    lens: Lens, rays: Rays, wavelength_um: torch.Tensor, launch_fields: list[float], aiming: Aiming, para: ParaxialData
) -> TraceResult:
    """Trace chief rays (W, F, 1) to the image as reference rays (central obscurations do
    not block them). launch_fields: the F launch values (deg or mm) the rays were made
    with. Raises RayTraceError naming the first field whose chief ray fails, and the
    largest field whose chief ray reaches the image."""
    res = trace(unobscured(lens), rays, wavelength_um)
    bad = ~res.rays.valid
    if bool(bad.any()):
        wi, fi = (int(v) for v in torch.nonzero(bad)[0, :2])
        mask = torch.zeros_like(bad)
        mask[wi, fi] = bad[wi, fi]
        wl = float(wavelength_um.reshape(-1)[wi if wavelength_um.numel() > 1 else 0])
        coverage = largest_chief_field(lens, launch_fields[fi], aiming, para, wl)
        raise RayTraceError(describe_failure(lens, launch_fields[fi], res.first_failure(mask), "chief ray", coverage))
    return res


def _chief_reaches_image(lens: Lens, field_value: float, aiming: Aiming, para: ParaxialData, wl: float) -> bool:
    rays, wlt = generate_rays(lens, [field_value], torch.zeros(1, 2, dtype=DTYPE), [wl], aiming, para)
    return bool(trace(unobscured(lens), rays, wlt).rays.valid.all())


def largest_chief_field(
    lens: Lens, field_value: float, aiming: Aiming, para: ParaxialData, wavelength_um: float, resolution: float = 0.005
) -> float | None:
    """The largest launch field between 0 and field_value (same sign; deg or mm) whose chief
    ray (aimed as `aiming` says) reaches the image, by bisection to `resolution` (deg or
    mm); None when not even the axial chief ray does."""
    if not _chief_reaches_image(lens, 0.0, aiming, para, wavelength_um):
        return None
    lo, hi = 0.0, float(field_value)
    for _ in range(max(1, math.ceil(math.log2(max(abs(hi) / resolution, 2.0))))):
        mid = 0.5 * (lo + hi)
        if _chief_reaches_image(lens, mid, aiming, para, wavelength_um):
            lo = mid
        else:
            hi = mid
    return lo


def describe_failure(lens: Lens, field_value: float, fail, what: str, coverage: float | None = None) -> str:
    """One line: which ray failed, where and how; coverage: the largest field that works
    (launch units), named when given."""
    unit = "deg" if lens.launch_field_type == "angle" else "mm"
    expected = "expected a field inside the lens's coverage"
    if coverage is not None:
        largest = math.copysign(math.floor(abs(coverage) * 100) / 100, coverage)  # rounded towards the axis
        expected += f" (its chief ray reaches the image up to {largest:g} {unit})"
    ray = f"{lens.source}: fields: the {what} at field {field_value:g} {unit}"
    if fail is None:
        return f"{ray} could not be aimed through the stop; {expected}"
    status, surf = fail
    where = "the image plane" if surf >= lens.num_surfaces else f"surfaces[{surf}] (surface {surf + 1} in lens info)"
    return f"{ray} {STATUS_TEXT[status]} at {where}; {expected}"
