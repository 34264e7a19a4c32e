"""The exit-pupil field of one object point at one wavelength.

A uniform grid over the (aimed) pupil is traced to the image space and carried on to the
exit-pupil reference sphere: centred on the real chief-ray image point, through the
chief ray's crossing of the paraxial exit-pupil plane. Each ray becomes a secondary
source with its position, direction, optical path length and power; the power of a ray
is the object-space étendue of its grid cell (so energy is conserved) and its area on
the sphere comes from the grid neighbours (so ray density sets the amplitude).

Central obscurations block their rays (an annular pupil of ratio eps transmits 1 - eps^2
of the power), never the chief ray, which is a reference ray
(lensim.optics.aiming.rays.trace_chief_rays): the sphere is centred on it whether or not an
obscuration covers the stop centre.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import torch

from lensim.errors import InputError, RayTraceError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import generate_rays, object_field, trace_chief_rays
from lensim.optics.aiming.sampling import square_grid_full
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.optics.trace import DTYPE, MISSED, OK, TIR, VIGNETTED, trace


@dataclass
class PupilField:
    """Secondary sources on the exit-pupil reference sphere (valid rays only).

    points (N, 3) mm on the sphere; directions (N, 3) unit ray directions there;
    opl (N,) mm total optical path from the object wavefront to the sphere, minus the
    chief ray's; power (N,) fraction of the unvignetted beam's power carried by each ray
    (sums to the transmitted fraction); area (N,) mm^2 of sphere per ray; pupil_xy (N, 2)
    normalized pupil coordinates; chief (3,) the chief-ray image point (sphere centre) and
    radius the sphere radius (mm); n_image the image-space index; wavelength_um.
    """

    points: torch.Tensor
    directions: torch.Tensor
    opl: torch.Tensor
    power: torch.Tensor
    area: torch.Tensor
    pupil_xy: torch.Tensor
    chief: torch.Tensor
    radius: float | torch.Tensor
    n_image: float
    wavelength_um: float
    transmission: float
    samples: int
    image_xy: torch.Tensor  # (N, 2) ray intercepts on the image plane (mm)
    aim: torch.Tensor | None = None  # real aiming's solution: the chief ray, then the traced cells (1, 1, 1 + K, 2), mm

    @property
    def wavelength_mm(self) -> float:
        return self.wavelength_um * 1e-3

    def to(self, device: torch.device | str) -> PupilField:
        """The same field with every tensor on ``device`` (the Huygens sum then runs there)."""
        moved: dict[str, Any] = {k: v.to(device) for k, v in vars(self).items() if isinstance(v, torch.Tensor)}
        return replace(self, **moved)

    def working_fno(self) -> float:
        """Effective image-space F-number from the beam's extent on the sphere."""
        u = (self.chief.unsqueeze(0) - self.points) / self.radius
        axis = -u.mean(0)
        axis = axis / torch.linalg.norm(axis)
        sin_max = torch.linalg.norm(torch.cross(u, axis.expand_as(u), dim=-1), dim=-1).max().item()
        return 1.0 / (2.0 * self.n_image * max(sin_max, 1e-12))


def _cell_measure(
    grid_vals: torch.Tensor, ok: torch.Tensor, h: float, cross_with: torch.Tensor | None = None
) -> torch.Tensor:
    """|d/dpx x d/dpy| * h^2 on an (n, n, 3) grid by central (or one-sided) differences
    between valid neighbours; cross_with projects onto a direction (étendue) instead.
    Returns NaN where no neighbour pair is valid."""

    def deriv(axis: int) -> torch.Tensor:
        v = grid_vals
        okf = ok
        fwd = torch.roll(v, -1, dims=axis) - v
        bwd = v - torch.roll(v, 1, dims=axis)
        okf_f = okf & torch.roll(okf, -1, dims=axis)
        okf_b = okf & torch.roll(okf, 1, dims=axis)
        n = v.shape[axis]
        idx = torch.arange(n)
        edge_hi = (idx == n - 1).reshape([-1 if a == axis else 1 for a in range(2)])
        edge_lo = (idx == 0).reshape([-1 if a == axis else 1 for a in range(2)])
        okf_f = okf_f & ~edge_hi
        okf_b = okf_b & ~edge_lo
        both = okf_f & okf_b
        d = torch.where(both.unsqueeze(-1), 0.5 * (fwd + bwd), torch.where(okf_f.unsqueeze(-1), fwd, bwd))
        has = okf_f | okf_b
        return torch.where(has.unsqueeze(-1), d, torch.full_like(d, float("nan")))

    # grid axis 0 is y (rows), axis 1 is x (columns)
    dx = deriv(1)
    dy = deriv(0)
    c = torch.cross(dx, dy, dim=-1)
    if cross_with is not None:
        return (c * cross_with).sum(-1).abs()
    return torch.linalg.norm(c, dim=-1)


def _fill(values: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """Replace NaN entries among ok cells by the median of the finite ones."""
    finite = ok & torch.isfinite(values)
    if not bool(finite.any()):
        raise RayTraceError("pupil sampling too coarse: no two neighbouring rays traced; increase the pupil samples")
    med = values[finite].median()
    return torch.where(finite, values, med)


@dataclass
class _ImageRays:
    """A samples x samples pupil grid traced to the image plane: the grid (pts, inside),
    the rays' launch positions and directions, their image-plane positions, directions,
    optical paths and validity, the chief ray's, and the image-space index."""

    pts: torch.Tensor
    inside: torch.Tensor
    start_pos: torch.Tensor
    start_dir: torch.Tensor
    pos: torch.Tensor
    dirs: torch.Tensor
    opl: torch.Tensor
    valid: torch.Tensor
    chief: torch.Tensor
    chief_dir: torch.Tensor
    chief_opl: torch.Tensor
    n_img: float
    samples: int
    aim: torch.Tensor | None
    status: torch.Tensor  # (N,) each ray's trace status (lensim.optics.trace: OK, MISSED, ...)
    failed_at: torch.Tensor  # (N,) the surface where a failed ray failed

    def moved(self, dz: float) -> _ImageRays:
        """The same rays on a plane dz (mm, along +z) from the image plane: each ray carried
        along its straight image-space path, its optical path with it."""
        t = dz / self.dirs[:, 2]
        tc = dz / self.chief_dir[2]
        return replace(
            self,
            pos=self.pos + t.unsqueeze(-1) * self.dirs,
            opl=self.opl + self.n_img * t,
            chief=self.chief + tc * self.chief_dir,
            chief_opl=self.chief_opl + self.n_img * tc,
        )


class _GridMap:
    """Which cells of an n x n pupil grid (pts (n*n, 2), inside the disc: inside) are
    traced, and where every cell's ray comes from. For a lens symmetric about the
    meridional plane x = 0 (no decentre or tilt, no gradient: `mirrored`) only the cells
    at px >= 0 are traced, and a cell at px < 0 takes its mirror cell's ray with x negated
    (the same ray to rounding, about half the tracing); otherwise every cell in the disc."""

    def __init__(self, pts: torch.Tensor, inside: torch.Tensor, n: int, mirrored: bool) -> None:
        index = torch.arange(n * n)
        right = pts[:, 0] >= 0 if mirrored else torch.ones(n * n, dtype=torch.bool)
        self.traced = inside & right
        self.source = torch.where(right, index, index.reshape(n, n).flip(1).reshape(-1))
        self.flip = ~right

    def unfold(self, values: torch.Tensor, fill: torch.Tensor, vector: bool = False) -> torch.Tensor:
        """Values (K, ...) of the traced cells on the whole grid (n * n, ...): mirrored
        where a cell takes its mirror's ray (vector: (K, 3) positions or directions, x
        negated), `fill` (a finite value, never used: every use of a cell is masked by the
        disc) outside the disc."""
        grid = fill.to(values.dtype).expand((self.traced.shape[0],) + values.shape[1:]).clone()
        grid[self.traced] = values
        grid = grid[self.source]
        if vector:
            sign = torch.tensor([-1.0, 1.0, 1.0], dtype=values.dtype)
            grid = torch.where(self.flip.unsqueeze(-1), grid * sign, grid)
        return grid


def _trace_grid(
    lens: Lens,
    field: float,
    wavelength_um: float,
    samples: int,
    aiming: Aiming,
    para: ParaxialData,
    start: torch.Tensor | None = None,
) -> _ImageRays:
    if samples < 8:
        raise InputError(lens.source, "pupil_samples", f"expected at least 8 pupil samples across, got {samples}")
    launch = object_field(lens, field, aiming, para)
    pts, inside = square_grid_full(samples)
    cells = _GridMap(pts, inside, samples, lens.meridional_mirror)
    all_pts = torch.cat([torch.zeros(1, 2, dtype=DTYPE), pts[cells.traced]])  # the chief ray, the traced cells
    if start is not None and start.shape[-2] != all_pts.shape[0]:
        start = None  # aimed on another grid
    rays, wl = generate_rays(lens, [launch], all_pts, [wavelength_um], aiming, para, start)
    ref = trace_chief_rays(lens, rays.select(0), wl, [launch], aiming, para).rays
    traced = trace(lens, rays.select(slice(1, None)), wl)
    out = traced.rays
    chief, chief_dir, chief_opl = ref.position[0, 0, 0], ref.direction[0, 0, 0], ref.opl[0, 0, 0]
    launched = rays.select(0)  # the chief ray as launched
    return _ImageRays(
        pts=pts,
        inside=inside,
        start_pos=cells.unfold(rays.position[0, 0, 1:], launched.position[0, 0, 0], vector=True),
        start_dir=cells.unfold(rays.direction[0, 0, 1:], launched.direction[0, 0, 0], vector=True),
        pos=cells.unfold(out.position[0, 0], chief, vector=True),
        dirs=cells.unfold(out.direction[0, 0], chief_dir, vector=True),
        opl=cells.unfold(out.opl[0, 0], chief_opl),
        valid=cells.unfold(out.valid[0, 0], torch.tensor(False)) & inside,
        chief=chief,
        chief_dir=chief_dir,
        chief_opl=chief_opl,
        n_img=float(lens.indices([wavelength_um])[-1, 0]),
        samples=samples,
        aim=rays.entrance_xy,
        status=cells.unfold(traced.status[0, 0], torch.tensor(OK)),
        failed_at=cells.unfold(traced.failed_at[0, 0], torch.tensor(0)),
    )


def pupil_field(
    lens: Lens,
    field: float,
    wavelength_um: float,
    samples: int = 128,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
    start: torch.Tensor | None = None,
) -> PupilField:
    """Trace a samples x samples pupil grid for one field (in the lens's field unit) and
    wavelength (um) to the exit-pupil reference sphere. start: with real aiming, the
    ``aim`` of a pupil field of the same field and sampling at another wavelength, where
    the aiming starts (faster; the same rays to rounding)."""
    para = para or paraxial_data(lens)
    traced = _trace_grid(lens, field, wavelength_um, samples, aiming, para, start)
    return _on_sphere(lens, traced, field, wavelength_um, para)


def pupil_fields_through_focus(
    lens: Lens,
    field: float,
    wavelength_um: float,
    shifts_mm: list[float],
    samples: int = 128,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
    start: torch.Tensor | None = None,
) -> list[PupilField]:
    """pupil_field with the image plane moved by each shift (mm, along the image-space
    light direction: positive away from the lens), from one trace: the same as tracing
    the lens with its image_defocus changed by that amount (times the direction)."""
    at = focus_stack(lens, field, wavelength_um, samples, aiming, para, start)
    return [at(dz) for dz in shifts_mm]


def focus_stack(
    lens: Lens,
    field: float,
    wavelength_um: float,
    samples: int = 128,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
    start: torch.Tensor | None = None,
) -> Callable[[float], PupilField]:
    """One trace of pupil_field's grid, kept: a function of an image-plane shift (mm, along
    the image-space light direction, positive away from the lens) giving the pupil field
    on the plane so moved (pupil_fields_through_focus, one shift at a time)."""
    para = para or paraxial_data(lens)
    traced = _trace_grid(lens, field, wavelength_um, samples, aiming, para, start)
    direction = float(lens.directions()[-1])

    def at(dz: float) -> PupilField:
        return _on_sphere(lens, traced.moved(direction * dz), field, wavelength_um, para)

    return at


#: the fewest pupil rays that must reach the image (and the reference sphere) for a PSF
MIN_RAYS = 16
#: what happened to the rays lost, by trace status
_LOST = {
    MISSED: "miss the surface",
    TIR: "are totally internally reflected",
    VIGNETTED: "are vignetted by its aperture",
}


def _too_few_rays(
    lens: Lens, tr: _ImageRays, reached: torch.Tensor, field: float, wavelength_um: float
) -> RayTraceError:
    """The one line for a pupil whose rays (nearly) all fail: how many reach the image and
    the surface that stops most of the others, with its clear semi-diameter (a stop or a
    surface with a tiny clear aperture is named, not the pupil sampling)."""
    n, k = int(tr.inside.sum()), int(reached.sum())
    lost = tr.inside & ~reached & (tr.status != OK)
    what = f"only {k} of the {n} pupil rays of field {field:g} at {wavelength_um * 1e3:g} nm reach the image"
    if not bool(lost.any()):
        return RayTraceError(f"{lens.source}: fields: {what}; expected at least {MIN_RAYS} (raise the pupil samples)")
    at = tr.failed_at[lost].long()
    surf = int(torch.bincount(at).argmax())
    status = int(torch.bincount(tr.status[lost].long()[at == surf]).argmax())
    others = f"the others {_LOST.get(status, 'fail')}"
    if surf >= lens.num_surfaces:
        return RayTraceError(f"{lens.source}: image: {what}, {others}; expected the beam to reach the image plane")
    s = lens.surfaces[surf]
    name = "the stop, " if s.is_stop else ""
    aperture = "no clear semi-diameter" if s.clear_radius is None else f"clear semi-diameter {s.clear_radius:g} mm"
    return RayTraceError(
        f"{lens.source}: surfaces[{surf}] ({name}surface {surf + 1} in lens info, {aperture}): {what}, "
        f"{others} there; expected a clear aperture that passes the beam of the lens's aperture "
        f"({lens.aperture_type} {lens.aperture_value:g})"
    )


def _on_sphere(lens: Lens, tr: _ImageRays, field: float, wavelength_um: float, para: ParaxialData) -> PupilField:
    """The traced grid carried to the exit-pupil reference sphere (the module docstring)."""
    pts, inside, n_img = tr.pts, tr.inside, tr.n_img
    chief, chief_dir, chief_opl = tr.chief, tr.chief_dir, tr.chief_opl
    pos, dirs, opl, valid = tr.pos, tr.dirs, tr.opl, tr.valid
    if int(valid.sum()) < MIN_RAYS:
        raise _too_few_rays(lens, tr, valid, field, wavelength_um)
    start_pos, start_dir = tr.start_pos, tr.start_dir
    # reference sphere: centre at the chief-ray image point, through the chief ray's
    # crossing of the paraxial exit-pupil plane
    z_xp = para.exit_pupil_z_mm
    dz = chief_dir[2]
    radius: float | torch.Tensor
    if not math.isfinite(z_xp) or abs(dz.item()) < 1e-12:
        radius = 1e3 * max(para.efl_mm, 1.0)  # telecentric: a large sphere
    else:
        radius = abs((z_xp - chief[2]) / dz)
        radius = radius if radius.requires_grad else radius.item()  # a tensor where gradients flow
    # carry every ray from the image plane back/forward to the sphere: |p + t d - C| = R,
    # root on the pupil side of the focus
    w = pos - chief
    b = (w * dirs).sum(-1)
    c = (w * w).sum(-1) - radius * radius
    disc = b * b - c
    valid = valid & (disc >= 0)
    t = -b - torch.sqrt(torch.clamp(disc, min=0.0))
    q = pos + t.unsqueeze(-1) * dirs
    opl_sphere = opl + n_img * t
    # the chief ray's own path to the sphere (t = -R along it)
    opl_ref = chief_opl - n_img * radius
    n = tr.samples
    h = 2.0 / n
    ok_grid = valid.reshape(n, n)
    area = _cell_measure(q.reshape(n, n, 3), ok_grid, h)
    # object-space power per cell: plane wave -> area perpendicular to the beam;
    # point source -> solid angle of the cell's directions
    launch_ok = inside.reshape(n, n)
    if lens.infinite_object:
        etendue = _cell_measure(start_pos.reshape(n, n, 3), launch_ok, h, cross_with=start_dir.reshape(n, n, 3))
    else:
        etendue = _cell_measure(start_dir.reshape(n, n, 3), launch_ok, h, cross_with=start_dir.reshape(n, n, 3))
    etendue = _fill(etendue, launch_ok).reshape(-1)
    total = etendue[inside].sum()
    power = etendue / total
    area = _fill(area, ok_grid).reshape(-1)
    sel = valid
    transmission = float(power[sel].sum())
    if int(sel.sum()) < MIN_RAYS:
        raise _too_few_rays(lens, tr, sel, field, wavelength_um)
    return PupilField(
        points=q[sel],
        directions=dirs[sel],
        opl=(opl_sphere - opl_ref)[sel],
        power=power[sel],
        area=area[sel],
        pupil_xy=pts[sel],
        chief=chief.clone(),
        radius=radius,
        n_image=n_img,
        wavelength_um=wavelength_um,
        transmission=transmission,
        samples=n,
        image_xy=pos[sel][:, :2],
        aim=tr.aim,
    )


def focus_stacks(
    lens: Lens,
    fields: list[float],
    wavelengths_um: list[float],
    samples: int = 32,
    aiming: Aiming = "paraxial",
    para: ParaxialData | None = None,
) -> list[list[Callable[[float], PupilField]]]:
    """focus_stack of every field (F, the lens's field unit) and wavelength (W, um) from
    one batched trace of the F x W pupil grids (and one of their chief rays): [f][w]
    functions of an image-plane shift dz (mm, positive away from the lens). The same rays
    as focus_stack one field and wavelength at a time; with many fields and wavelengths
    some ten times faster (the tracer's cost is mostly per call, not per ray)."""
    para = para or paraxial_data(lens)
    if samples < 8:
        raise InputError(lens.source, "pupil_samples", f"expected at least 8 pupil samples across, got {samples}")
    launches = [object_field(lens, f, aiming, para) for f in fields]
    pts, inside = square_grid_full(samples)
    all_pts = torch.cat([torch.zeros(1, 2, dtype=DTYPE), pts])
    rays, wl = generate_rays(lens, launches, all_pts, wavelengths_um, aiming, para)
    start_pos, start_dir = rays.position[..., 1:, :], rays.direction[..., 1:, :]
    ref = trace_chief_rays(lens, rays.select(0), wl, launches, aiming, para).rays
    traced = trace(lens, rays.select(slice(1, None)), wl)
    out, n_img = traced.rays, lens.indices(list(wavelengths_um))[-1]
    direction = float(lens.directions()[-1])
    stacks: list[list[Callable[[float], PupilField]]] = []
    for fi, f in enumerate(fields):
        row = []
        for wi, w in enumerate(wavelengths_um):
            tr = _ImageRays(
                pts=pts,
                inside=inside,
                start_pos=start_pos[wi, fi],
                start_dir=start_dir[wi, fi],
                pos=out.position[wi, fi],
                dirs=out.direction[wi, fi],
                opl=out.opl[wi, fi],
                valid=out.valid[wi, fi] & inside,
                chief=ref.position[wi, fi, 0],
                chief_dir=ref.direction[wi, fi, 0],
                chief_opl=ref.opl[wi, fi, 0],
                n_img=float(n_img[wi]),
                samples=samples,
                aim=None if rays.entrance_xy is None else rays.entrance_xy[wi : wi + 1, fi : fi + 1],
                status=traced.status[wi, fi],
                failed_at=traced.failed_at[wi, fi],
            )
            row.append(_stack_of(lens, tr, f, w, para, direction))
        stacks.append(row)
    return stacks


def _stack_of(
    lens: Lens, tr: _ImageRays, field: float, wavelength_um: float, para: ParaxialData, direction: float
) -> Callable[[float], PupilField]:
    def at(dz: float) -> PupilField:
        return _on_sphere(lens, tr.moved(direction * dz) if dz else tr, field, wavelength_um, para)

    return at
