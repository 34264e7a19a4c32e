"""Field-dependent analyses: distortion, lateral colour, relative illumination and a
per-field report of all three (the lens-level outputs of `lensim lens field`).

Fields are given in the lens's field unit (degrees for angle fields, mm for object or
image heights) and default to 21 equal steps from 0 to the lens's maximum field.
Lengths in mm, wavelengths in um.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from lensim.errors import InputError, RayTraceError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import (
    chief_ray_image_height,
    describe_failure,
    generate_rays,
    object_field,
    trace_chief_rays,
)
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data, paraxial_image_height
from lensim.optics.trace import DTYPE, Rays, TraceResult, trace

DEFAULT_FIELD_STEPS = 21


def _default_fields(lens: Lens, fields) -> list[float]:
    if fields is None:
        return [float(f) for f in np.linspace(0.0, lens.max_field, DEFAULT_FIELD_STEPS)]
    out = [float(f) for f in np.atleast_1d(np.asarray(fields, dtype=np.float64))]
    if not out:
        raise InputError(lens.source, "fields", "expected at least one field value")
    return out


def _field_unit(lens: Lens) -> str:
    return "deg" if lens.field_type == "angle" else "mm"


def distortion(
    lens: Lens,
    fields: list[float] | np.ndarray | None = None,
    aiming: Aiming = "real",
    wavelength_um: float | None = None,
) -> dict:
    """Distortion of the real chief ray against the paraxial chief ray on the image plane.

    distortion_percent = (real - paraxial) / paraxial * 100, defined as 0 at zero field
    (its limit). The real chief ray is aimed as `aiming` says ('real': through the centre
    of the stop; 'paraxial': through the centre of the paraxial entrance pupil). The
    paraxial height is the paraxial chief ray's height on the same (possibly defocused)
    image plane, so it is linear in tan(field angle) or object height. Wavelength: the
    primary unless given (um).

    Returns a dict: fields (lens unit), field_unit, launch (deg or mm: what rays start
    with), real_height_mm, paraxial_height_mm, distortion_percent, wavelength_um, aiming.
    """
    flds = _default_fields(lens, fields)
    para = paraxial_data(lens)
    wl = lens.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
    para_wl = para if wl == para.wavelength_um else paraxial_data(lens, wl)
    probe = lens.launch_lens()
    launch, real, parax, dist = [], [], [], []
    for f in flds:
        lv = object_field(lens, f, aiming, para)
        y_real = chief_ray_image_height(probe, lv, aiming=aiming, para=para, wavelength_um=wl)
        y_par = paraxial_image_height(probe, lv, para_wl)
        launch.append(lv)
        real.append(y_real)
        parax.append(y_par)
        dist.append(0.0 if lv == 0 or y_par == 0 else (y_real - y_par) / y_par * 100.0)
    return {
        "fields": flds,
        "field_unit": _field_unit(lens),
        "launch": launch,
        "real_height_mm": real,
        "paraxial_height_mm": parax,
        "distortion_percent": dist,
        "wavelength_um": wl,
        "aiming": aiming,
    }


def _disc_fraction(edges: torch.Tensor, fine: int = 16) -> torch.Tensor:
    """Fraction of each grid cell (n, n) lying inside the unit disc, by fine x fine
    point sampling of each cell (geometry only; error below 1/fine^2 of a cell)."""
    n = edges.numel() - 1
    h = float(edges[1] - edges[0])
    sub = (torch.arange(fine, dtype=DTYPE) + 0.5) / fine * h
    cx = edges[:-1].reshape(1, n, 1, 1) + sub.reshape(1, 1, 1, fine)
    cy = edges[:-1].reshape(n, 1, 1, 1) + sub.reshape(1, 1, fine, 1)
    return ((cx * cx + cy * cy) <= 1.0).to(DTYPE).mean((-1, -2))


def _quad_areas(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Areas of the quadrilaterals spanned by neighbouring nodes of (..., n+1, n+1) maps."""
    a, b, c, d = (u[..., :-1, :-1], u[..., :-1, 1:], u[..., 1:, 1:], u[..., 1:, :-1])
    A, B, C, D = (v[..., :-1, :-1], v[..., :-1, 1:], v[..., 1:, 1:], v[..., 1:, :-1])
    return 0.5 * ((a * B - b * A) + (b * C - c * B) + (c * D - d * C) + (d * A - a * D)).abs()


class _PupilCells:
    """The pupil grid of :func:`relative_illumination`: n x n cells over [-1, 1]^2, the
    corner nodes of the cells that touch the unit disc (nodes, (K, 2)), and s x s
    subsample points in each such cell (sub, (S, 2); points outside the disc moved
    radially onto its rim) with the cell each belongs to (cell_of_sub, (S,))."""

    def __init__(self, n: int, s: int) -> None:
        self.n = n
        edges = torch.linspace(-1.0, 1.0, n + 1, dtype=DTYPE)
        gy, gx = torch.meshgrid(edges, edges, indexing="ij")
        all_nodes = torch.stack([gx.reshape(-1), gy.reshape(-1)], -1)  # (n+1)^2, row = y
        fine = (torch.arange(n * s, dtype=DTYPE) + 0.5) * (2.0 / n / s) - 1.0
        fy, fx = torch.meshgrid(fine, fine, indexing="ij")
        sub = torch.stack([fx.reshape(-1), fy.reshape(-1)], -1)
        r = torch.linalg.norm(sub, dim=-1, keepdim=True)
        sub = torch.where(r > 1.0, sub * ((1.0 - 1e-12) / r), sub)
        self.disc = _disc_fraction(edges)  # (n, n) fraction of each cell inside the disc
        used = self.disc > 0
        # only the subsample points of cells that touch the disc are traced
        cell_of_sub = (torch.arange(n * s).reshape(-1, 1) // s * n + torch.arange(n * s).reshape(1, -1) // s).reshape(
            -1
        )
        keep = used.reshape(-1)[cell_of_sub]
        self.sub, self.cell_of_sub = sub[keep], cell_of_sub[keep]
        # only the corners of those cells are traced (the far corners of the square need not aim)
        node_used = torch.zeros(n + 1, n + 1, dtype=torch.bool)
        for dy in (0, 1):
            for dx in (0, 1):
                node_used[dy : dy + n, dx : dx + n] |= used
        self.node_idx = torch.nonzero(node_used.reshape(-1))[:, 0]
        self.nodes = all_nodes[self.node_idx]

    def cell_areas(self, free: TraceResult, z_xp: float) -> torch.Tensor:
        """(F, n, n) area of each cell in image-space direction-cosine space (L, M), from a
        trace without apertures of [chief ray, nodes...] per field; zero where a corner
        failed. Directions run from the ray's crossing of the exit-pupil plane at z_xp to
        the chief ray's image point (the ray directions themselves when z_xp is infinite)."""
        n = self.n
        pos, dirs = free.rays.position[0], free.rays.direction[0]  # (F, 1 + nodes, 3)
        P, X, D = pos[:, :1, :], pos[:, 1:], dirs[:, 1:]
        if math.isfinite(z_xp):
            t = (z_xp - X[..., 2]) / torch.where(D[..., 2].abs() > 1e-300, D[..., 2], torch.ones_like(D[..., 2]))
            to_image = P - (X + t.unsqueeze(-1) * D)
            u = to_image / torch.linalg.norm(to_image, dim=-1, keepdim=True).clamp_min(1e-300)
        else:
            u = D
        F = pos.shape[0]
        L = torch.zeros(F, (n + 1) ** 2, dtype=DTYPE)
        M = torch.zeros(F, (n + 1) ** 2, dtype=DTYPE)
        node_ok = torch.zeros(F, (n + 1) ** 2, dtype=torch.bool)
        L[:, self.node_idx], M[:, self.node_idx], node_ok[:, self.node_idx] = (
            u[..., 0],
            u[..., 1],
            free.rays.valid[0, :, 1:],
        )
        L, M, node_ok = (v.reshape(F, n + 1, n + 1) for v in (L, M, node_ok))
        cell_ok = node_ok[:, :-1, :-1] & node_ok[:, :-1, 1:] & node_ok[:, 1:, 1:] & node_ok[:, 1:, :-1]
        return torch.where(cell_ok, _quad_areas(L, M), torch.zeros((), dtype=DTYPE))

    def passed_fraction(self, blocked: TraceResult) -> torch.Tensor:
        """(F, n, n) fraction of each cell's subsample rays that pass every aperture."""
        n = self.n
        passed = blocked.rays.valid[0].to(DTYPE)  # (F, n_sub)
        counts = torch.zeros(n * n, dtype=DTYPE).index_add_(
            0, self.cell_of_sub, torch.ones(self.cell_of_sub.shape[0], dtype=DTYPE)
        )
        frac = torch.zeros(passed.shape[0], n * n, dtype=DTYPE).index_add_(1, self.cell_of_sub, passed)
        return (frac / counts.clamp_min(1.0)).reshape(-1, n, n)


def _by_field(res: TraceResult) -> TraceResult:
    """A (W, F, P) trace as (1, W * F, P): each wavelength's fields as more fields."""

    def flat(x: torch.Tensor) -> torch.Tensor:
        return x.reshape(1, -1, *x.shape[2:])

    r = res.rays
    return TraceResult(
        Rays(flat(r.position), flat(r.direction), flat(r.opl), flat(r.valid)), flat(res.status), flat(res.failed_at)
    )


class _MirrorHalf:
    """Pupil points (P, 2) symmetric about px = 0, of which only those at px >= 0 are
    traced (`traced`, (K, 2)) for a lens whose rays mirror about the meridional plane
    (`mirror`; every point otherwise): each point's ray is its own or its mirror image's
    with x negated (the same ray to rounding)."""

    def __init__(self, points: torch.Tensor, mirror: bool) -> None:
        keep = points[:, 0] >= 0 if mirror else torch.ones(points.shape[0], dtype=torch.bool)
        self.traced = points[keep]
        order, keys = torch.sort(self._keys(self.traced))
        mirrored = torch.stack([points[:, 0].abs(), points[:, 1]], -1)
        self.source = keys[torch.searchsorted(order, self._keys(mirrored))]
        self.flip = ~keep

    @staticmethod
    def _keys(points: torch.Tensor) -> torch.Tensor:
        """One int64 per pupil point (coordinates in [-1, 1], to 1e-9): equal for equal points."""
        ix, iy = torch.round(points.to(DTYPE) * 1e9).to(torch.int64).unbind(-1)
        return ix * (2_000_000_001) + (iy + 1_000_000_000)

    def unfold(self, res: TraceResult, skip: int = 0) -> TraceResult:
        """A (1, B, skip + K) trace of the traced points (after `skip` other rays, kept) as
        one of all P points, (1, B, skip + P)."""
        index = torch.cat([torch.arange(skip), skip + self.source])
        flip = torch.cat([torch.zeros(skip, dtype=torch.bool), self.flip]).unsqueeze(-1)
        sign = torch.tensor([-1.0, 1.0, 1.0], dtype=DTYPE)
        r = res.rays

        def mirrored(v: torch.Tensor) -> torch.Tensor:
            v = v[:, :, index]
            return torch.where(flip, v * sign, v)

        rays = Rays(mirrored(r.position), mirrored(r.direction), r.opl[:, :, index], r.valid[:, :, index])
        return TraceResult(rays, res.status[:, :, index], res.failed_at[:, :, index])


def _beam_solid_angles(
    lens: Lens,
    launch: list[float],
    wavelengths_um: list[float],
    samples: int,
    subsamples: int,
    aiming: Aiming,
    para: ParaxialData,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """relative_illumination's measure at launch fields (F,) and wavelengths (W,), traced
    together: the projected solid angles (W, F) (sr), the unvignetted fractions of the pupil
    disc (W, F) and the chief-ray image points (W, F, 3) (mm)."""
    cells = _PupilCells(samples, subsamples)
    mirror = lens.meridional_mirror  # trace the points at x >= 0, mirror the others
    nodes, subs = _MirrorHalf(cells.nodes, mirror), _MirrorHalf(cells.sub, mirror)
    pupil = torch.cat([torch.zeros(1, 2, dtype=DTYPE), nodes.traced, subs.traced])
    rays, wlt = generate_rays(lens, launch, pupil, wavelengths_um, aiming, para)
    n_nodes = nodes.traced.shape[0]
    free = nodes.unfold(_by_field(trace(lens, rays.select(slice(0, 1 + n_nodes)), wlt, apertures=False)), 1)
    blocked = subs.unfold(_by_field(trace(lens, rays.select(slice(1 + n_nodes, None)), wlt)))
    chief_ok = free.rays.valid[0, :, 0]
    if not bool(chief_ok.all()):
        fi = int(torch.nonzero(~chief_ok)[0, 0])
        mask = torch.zeros_like(free.rays.valid)
        mask[0, fi, 0] = True
        failure = free.first_failure(mask)
        raise RayTraceError(describe_failure(lens, launch[fi % len(launch)], failure, "chief ray"))
    area = cells.cell_areas(free, para.exit_pupil_z_mm)
    weight = cells.disc.unsqueeze(0) * cells.passed_fraction(blocked)
    W, F = len(wavelengths_um), len(launch)
    solid = (area * weight).sum((-1, -2)).reshape(W, F)
    unvignetted = (weight.sum((-1, -2)) / cells.disc.sum()).reshape(W, F)
    return solid, unvignetted, free.rays.position[0, :, 0].reshape(W, F, 3)


def axis_solid_angles(
    lens: Lens,
    wavelengths_um: list[float],
    samples: int = 64,
    aiming: Aiming = "real",
    subsamples: int = 2,
    para: ParaxialData | None = None,
) -> np.ndarray:
    """The on-axis beam's projected solid angle (sr) at each wavelength (um), (W,) float64:
    the normalization of :func:`relative_illumination_spectrum`, traced once for many fields."""
    para = para or paraxial_data(lens)
    solid, _, _ = _beam_solid_angles(lens, [0.0], list(wavelengths_um), samples, subsamples, aiming, para)
    return solid[:, 0].numpy()


def relative_illumination_spectrum(
    lens: Lens,
    field: float,
    wavelengths_um: list[float],
    samples: int = 64,
    aiming: Aiming = "real",
    subsamples: int = 2,
    para: ParaxialData | None = None,
    axis: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`relative_illumination` of one field (lens units) at several wavelengths (um),
    each normalized on axis at its own wavelength, all traced together: (W,) float64.
    axis: the on-axis solid angles (:func:`axis_solid_angles` of the same sampling), so that
    only this field is traced (the same values)."""
    para = para or paraxial_data(lens)
    launch = object_field(lens, field, aiming, para)
    if launch == 0.0:
        return np.ones(len(wavelengths_um))
    if axis is not None:
        solid, _, _ = _beam_solid_angles(lens, [launch], list(wavelengths_um), samples, subsamples, aiming, para)
        return solid[:, 0].numpy() / axis
    solid, _, _ = _beam_solid_angles(lens, [0.0, launch], list(wavelengths_um), samples, subsamples, aiming, para)
    return (solid[:, 1] / solid[:, 0]).numpy()


def relative_illumination(
    lens: Lens,
    fields: list[float] | np.ndarray | None = None,
    wavelength_um: float | None = None,
    samples: int = 64,
    aiming: Aiming = "real",
    subsamples: int = 2,
    para: ParaxialData | None = None,
) -> dict:
    """Relative illumination: image irradiance at each field relative to the axis, for a
    Lambertian (uniform radiance) object, with vignetting.

    Method (Zemax's definition): n'^2 times the projected solid angle of the exit pupil
    as seen from the image point, i.e. the area it covers in image-space direction-cosine
    space (L, M). A samples x samples grid of cells over the (aimed) pupil is traced; each
    ray's image-space line meets the paraxial exit-pupil plane at X, and the unit vector
    from X to the chief ray's image point P gives its (L, M). Each cell's area is the
    quadrilateral spanned by its four corner rays (traced without apertures, so the map is
    smooth), weighted by the fraction of the cell inside the unit pupil disc and by the
    fraction of subsamples x subsamples points in the cell that pass every clear aperture
    (points outside the disc are moved radially onto its rim). For an aberration-free
    beam this is exactly the area of the beam's ray directions; for an aberrated one it
    is the cone P actually receives light from (the beam of a single object point is not
    what lights P when the image is astigmatic). An exit pupil at infinity (image-space
    telecentric) uses the ray directions themselves.

    fields: lens units (default 0..max in 21 steps); wavelength_um: default the primary.
    Returns a dict: fields, field_unit, wavelength_um, aiming, relative_illumination
    (1 on axis), projected_solid_angle_sr (area in (L, M) space), n2_projected_solid_angle_sr
    (times the image-space index squared), unvignetted_fraction (the fraction of the pupil
    disc whose rays reach the image) and image_height_mm (chief ray).
    """
    if samples < 4:
        raise InputError(lens.source, "samples", f"expected at least 4 pupil samples across, got {samples}")
    if subsamples < 1:
        raise InputError(lens.source, "subsamples", f"expected a positive number, got {subsamples}")
    flds = _default_fields(lens, fields)
    para = para or paraxial_data(lens)
    wl = lens.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
    launch = [object_field(lens, f, aiming, para) for f in flds]
    off = 0 if 0.0 in launch else 1  # the on-axis beam is traced once, for the normalization
    all_launch = [0.0] * off + launch
    axis_index = all_launch.index(0.0)

    solid, unvignetted_wf, P = _beam_solid_angles(lens, all_launch, [wl], samples, subsamples, aiming, para)
    solid, P, unvignetted = solid[0], P[0], unvignetted_wf[0].tolist()
    n_img = float(lens.indices([wl])[-1, 0])
    ri = (solid / solid[axis_index]).tolist()
    pick = slice(off, off + len(launch))
    return {
        "fields": flds,
        "field_unit": _field_unit(lens),
        "wavelength_um": wl,
        "aiming": aiming,
        "relative_illumination": ri[pick],
        "projected_solid_angle_sr": solid.tolist()[pick],
        "n2_projected_solid_angle_sr": (solid * n_img * n_img).tolist()[pick],
        "unvignetted_fraction": unvignetted[pick],
        "image_height_mm": P[:, 1].tolist()[pick],
    }


def chief_ray_heights(
    lens: Lens,
    launch: list[float],
    wavelengths_um: list[float] | np.ndarray,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
) -> np.ndarray:
    """Real chief-ray image heights y (mm), shape (W, F), for launch field values (angle
    deg or object height mm, lens.launch_field_type) at each wavelength (um), each chief
    ray aimed at its own wavelength. Raises RayTraceError naming the first failed ray."""
    para = para or paraxial_data(lens)
    probe = lens.launch_lens()
    rays, wlt = generate_rays(probe, launch, torch.zeros(1, 2, dtype=DTYPE), list(wavelengths_um), aiming, para)
    res = trace_chief_rays(probe, rays, wlt, list(launch), aiming, para)  # a reference ray: obscurations pass it
    return res.rays.position[:, :, 0, 1].numpy().copy()


def lateral_colour(
    lens: Lens,
    fields: list[float] | np.ndarray | None,
    wavelengths_nm: np.ndarray,
    channel_weights: np.ndarray,
    aiming: Aiming = "real",
) -> dict:
    """Lateral colour as a sensor sees it: per field, the real chief-ray height at every
    wavelength and its average over each colour channel weighted by the channel's spectral
    response (e.g. lensim.sensor.spectral.SpectralResponse: wavelengths_nm (W,), weights
    (3, W), rows R, G, B, each summing to 1).

    fields: lens units (default 0..max in 21 steps). Returns a dict: fields, field_unit,
    launch, wavelengths_nm, real_height_mm (F, W), channel_height_mm (F, 3: R, G, B) and
    lateral_colour_um (F, 3): each channel's height minus green's, in um (G is 0).
    """
    flds = _default_fields(lens, fields)
    weights = np.asarray(channel_weights, dtype=np.float64)
    wl_nm = np.asarray(wavelengths_nm, dtype=np.float64).reshape(-1)
    if weights.shape != (3, wl_nm.size):
        raise InputError(lens.source, "channel_weights", f"expected (3, {wl_nm.size}) weights, got {weights.shape}")
    para = paraxial_data(lens)
    launch = [object_field(lens, f, aiming, para) for f in flds]
    heights = chief_ray_heights(lens, launch, wl_nm / 1000.0, aiming, para).T  # (F, W)
    channel = heights @ (weights / weights.sum(axis=1, keepdims=True)).T  # (F, 3)
    return {
        "fields": flds,
        "field_unit": _field_unit(lens),
        "launch": launch,
        "wavelengths_nm": wl_nm.tolist(),
        "real_height_mm": heights.tolist(),
        "channel_height_mm": channel.tolist(),
        "lateral_colour_um": ((channel - channel[:, 1:2]) * 1000.0).tolist(),
    }


def field_report(
    lens: Lens,
    fields: list[float] | np.ndarray | None,
    wavelengths_nm: np.ndarray,
    channel_weights: np.ndarray,
    aiming: Aiming = "real",
    ri_samples: int = 32,
) -> dict:
    """Lens-level outputs per field: real chief-ray height at each wavelength, paraxial
    height and distortion (primary wavelength), channel-weighted heights and lateral colour
    (see lateral_colour) and relative illumination (primary wavelength, ri_samples pupil
    samples across). Returns a dict: name, source, aiming, field_unit, wavelengths_nm,
    primary_wavelength_nm and fields, a list of one record per field (field, launch,
    real_height_mm {nm: mm}, paraxial_height_mm, distortion_percent, channel_height_mm and
    lateral_colour_um {r, g, b}, relative_illumination)."""
    flds = _default_fields(lens, fields)
    dist = distortion(lens, flds, aiming)
    colour = lateral_colour(lens, flds, wavelengths_nm, channel_weights, aiming)
    ri = relative_illumination(lens, flds, samples=ri_samples, aiming=aiming)
    records = []
    for i, f in enumerate(flds):
        records.append(
            {
                "field": f,
                "launch": dist["launch"][i],
                "real_height_mm": {f"{w:g}": h for w, h in zip(colour["wavelengths_nm"], colour["real_height_mm"][i])},
                "paraxial_height_mm": dist["paraxial_height_mm"][i],
                "distortion_percent": dist["distortion_percent"][i],
                "channel_height_mm": dict(zip("rgb", colour["channel_height_mm"][i])),
                "lateral_colour_um": dict(zip("rgb", colour["lateral_colour_um"][i])),
                "relative_illumination": ri["relative_illumination"][i],
            }
        )
    return {
        "name": lens.name,
        "source": lens.source,
        "aiming": aiming,
        "field_unit": _field_unit(lens),
        "launch_unit": "deg" if lens.launch_field_type == "angle" else "mm",
        "wavelengths_nm": colour["wavelengths_nm"],
        "primary_wavelength_nm": lens.primary_wavelength_um * 1000.0,
        "fields": records,
    }
