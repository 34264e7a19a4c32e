"""Lens plots: 2-D layout (y-z cross-section with meridional ray fans) and spot diagrams.

Matplotlib figures built without pyplot (an Agg canvas each), so nothing global is
touched and nothing is shown. Every function returns the Figure; given a path it also
saves it atomically (lensim.plots.figure.save_figure), in the format
the file name's extension names (png, pdf, svg, ...).

Units: lengths in mm on the layout, um on spot diagrams; wavelengths in um in arguments,
nm on the plots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from lensim.errors import InputError, RayTraceError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import generate_rays, object_field, trace_chief_rays
from lensim.optics.aiming.sampling import hexapolar
from lensim.optics.lens import Lens
from lensim.optics.materials import Air
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.optics.spot import SPOT_RINGS, SpotDiagram, airy_radius_um, spot_diagram, spot_summary
from lensim.optics.surfaces import Surface
from lensim.optics.trace import DTYPE, MISSED, OK, Rays, media_indices, trace_surface
from lensim.plots.figure import new_figure, save_figure

FIELD_COLORS = (
    "tab:blue",
    "tab:green",
    "tab:red",
    "tab:orange",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
    "tab:gray",
)


# ---- shared helpers -------------------------------------------------------------------
def lens_title(lens: Lens) -> str:
    """The lens's name, or its file's stem."""
    return lens.name or Path(lens.source).stem or "lens"


def field_label(lens: Lens, value: float) -> str:
    """A field value with its unit (deg for angles, mm for heights)."""
    if lens.field_type == "angle":
        return f"{value:g}\N{DEGREE SIGN}"
    return f"{value:g} mm"


def wavelength_color(wavelength_um: float) -> tuple[float, float, float]:
    """An RGB colour for a wavelength: the spectral hue between 380 and 780 nm (darkened
    a little for a white background), violet below and dark red above."""
    nm = wavelength_um * 1000.0
    if nm < 380:
        return (0.45, 0.0, 0.55)
    if nm > 780:
        return (0.45, 0.0, 0.0)
    if nm < 440:
        r, g, b = (440 - nm) / 60, 0.0, 1.0
    elif nm < 490:
        r, g, b = 0.0, (nm - 440) / 50, 1.0
    elif nm < 510:
        r, g, b = 0.0, 1.0, (510 - nm) / 20
    elif nm < 580:
        r, g, b = (nm - 510) / 70, 1.0, 0.0
    elif nm < 645:
        r, g, b = 1.0, (645 - nm) / 65, 0.0
    else:
        r, g, b = 1.0, 0.0, 0.0
    # fade towards the ends of the visible range, then darken for contrast on white
    fade = 0.4 + 0.6 * (nm - 380) / 40 if nm < 420 else (0.4 + 0.6 * (780 - nm) / 80 if nm > 700 else 1.0)
    k = 0.8 * fade
    return (r * k, g * k * 0.85, b * k)


def _wavelength_colors(wavelengths_um: list[float]) -> list:
    cols = [wavelength_color(w) for w in wavelengths_um]
    if len(set(cols)) < len(cols):  # outside the visible range several would look alike
        from matplotlib import colormaps

        cmap = colormaps["viridis"]
        order = np.argsort(wavelengths_um)
        cols = [None] * len(wavelengths_um)
        for rank, i in enumerate(order):
            cols[i] = cmap(rank / max(1, len(order) - 1) * 0.9)
    return cols


# ---- layout ---------------------------------------------------------------------------
@dataclass
class RayPaths:
    """Meridional ray paths for a layout.

    points: (F, P, S+3, 2) (z, y) in mm: the start point, the intercept with every surface,
    the image-plane intercept; reached: (F, P, S+3) which of those points the ray reaches
    (a ray blocked by a clear aperture or reflected internally reaches the surface it is
    stopped at; a ray that misses a surface ends at the surface before).
    """

    points: np.ndarray
    reached: np.ndarray


def _launch_start(lens: Lens, rays: Rays, z_start: float | None) -> torch.Tensor:
    """The points rays are drawn from: the object point for a finite object drawn in full,
    else where each ray crosses the plane z = z_start."""
    pos, d = rays.position, rays.direction
    if z_start is None:
        return pos
    t = (z_start - pos[..., 2]) / d[..., 2]
    return pos + t.unsqueeze(-1) * d


def trace_ray_paths(
    lens: Lens,
    launch_fields: list[float],
    pupil_y: np.ndarray,
    aiming: Aiming,
    para: ParaxialData,
    z_start: float | None,
) -> tuple[RayPaths, Rays, torch.Tensor, torch.Tensor]:
    """Trace meridional rays (pupil points (0, py)) at the primary wavelength surface by
    surface, keeping the point where each failing ray is stopped.

    Returns the paths, the final rays, the per-ray status and the surface each failed at
    (the image plane is index S).
    """
    wl_um = lens.primary_wavelength_um
    pupil = torch.zeros(len(pupil_y), 2, dtype=DTYPE)
    pupil[:, 1] = torch.as_tensor(pupil_y, dtype=DTYPE)
    rays, wl = generate_rays(lens, launch_fields, pupil, [wl_um], aiming, para)
    n = media_indices(lens, wl)
    zv = lens.vertex_z()
    start = _launch_start(lens, rays, z_start)
    pts = [start[0, ..., 1:3].flip(-1)]
    reached = [rays.valid[0].clone()]
    status = torch.zeros(rays.shape, dtype=torch.int8)
    failed_at = torch.full(rays.shape, -1, dtype=torch.int16)
    surfaces = list(lens.surfaces) + [Surface(clear_radius=lens.image_clear_radius)]
    backwards = lens.virtual_steps()
    backwards[0] = True  # rays start anywhere
    for i, surf in enumerate(surfaces):
        is_image = i == lens.num_surfaces
        n1, n2 = (n[-1], n[-1]) if is_image else (n[i], n[i + 1])
        # where each live ray meets the surface, ignoring apertures and refraction
        geo, _ = trace_surface(
            surf, float(zv[i]), rays, n1, n2, allow_backwards=bool(backwards[i]), apertures=False, interact=False
        )
        rays_after, st = trace_surface(
            surf, float(zv[i]), rays, n1, n2, allow_backwards=bool(backwards[i]), interact=not is_image
        )
        newly = (st != OK) & (status == OK)
        status = torch.where(newly, st.to(status.dtype), status)
        failed_at = torch.where(newly, torch.as_tensor(i, dtype=failed_at.dtype), failed_at)
        pts.append(geo.position[0, ..., 1:3].flip(-1))
        reached.append((rays_after.valid | (newly & (st != MISSED) & geo.valid))[0])
        rays = rays_after
    points = torch.stack(pts, dim=2).numpy()
    return RayPaths(points, torch.stack(reached, dim=2).numpy()), rays, status, failed_at


def _profile(surf: Surface, z0: float, sd: float, num: int = 161) -> tuple[np.ndarray, np.ndarray]:
    """(z, y) of a surface's meridional profile from -sd to +sd (mm)."""
    y = np.linspace(-sd, sd, num)
    z = z0 + surf.geometry.sag(torch.as_tensor(y * y, dtype=DTYPE)).numpy()
    return z, y


def plot_layout(
    lens: Lens,
    fields: list[float] | None = None,
    rays_per_field: int = 7,
    aiming: Aiming = "real",
    path: str | Path | None = None,
) -> Figure:
    """2-D layout: the y-z cross-section with meridional ray fans.

    Every surface is drawn as its sag profile out to its semi-diameter (semi_diameter if
    set, else clear_radius, else 5% beyond the highest traced ray); glass elements are
    closed with flat edges; the stop is marked, mirrors are drawn bold and hatched on the
    back, the image plane is drawn. Each field (lens units; default the lens's fields)
    gets a fan of rays_per_field rays across the pupil (primary wavelength) in its own
    colour; a ray blocked by an aperture (or totally internally reflected) ends on the
    surface that stops it, a ray that misses a surface ends at the surface before. A plane
    between air and air bends no ray: a stop there is drawn only as its diaphragm, any
    other such (dummy) surface dashed grey. Raises RayTraceError if a chief ray does not
    reach the image, unless a central obscuration blocks it. Lengths in mm.
    """
    if rays_per_field < 1:
        raise InputError(None, "rays_per_field", f"expected at least 1 ray per field, got {rays_per_field}")
    para = paraxial_data(lens)
    fields = list(lens.fields) if fields is None else [float(f) for f in fields]
    if not fields:
        raise InputError(lens.source, "fields", "expected at least one field to draw")
    launch = [object_field(lens, f, aiming, para) for f in fields]
    zv = lens.vertex_z()
    pupil_y = np.linspace(-1.0, 1.0, rays_per_field) if rays_per_field > 1 else np.zeros(1)
    pupil_y = np.concatenate([[0.0], pupil_y])  # index 0: the chief ray, checked, not drawn

    # First pass (rays from their launch points) to size the surfaces and the plot.
    paths, _, _, _ = trace_ray_paths(lens, launch, pupil_y, aiming, para, None)
    _check_chief_rays(lens, launch, aiming, para, paths)
    sizes = _LayoutSizes(lens, paths, para)

    # where rays are drawn from
    z_surf = [float(zv[i]) + s.geometry.sag_at(sizes.sds[i]) for i, s in enumerate(lens.surfaces)] + list(zv)
    z_lo, z_hi = min(z_surf), max(z_surf)
    extent = max(z_hi - z_lo, 2 * sizes.ymax)
    z_start: float | None = z_lo - 0.15 * extent
    if not lens.infinite_object and lens.object_distance <= 1.5 * extent:
        z_start = None  # draw the rays from the object point
    paths, _, _, _ = trace_ray_paths(lens, launch, pupil_y, aiming, para, z_start)

    z_all = [
        z_lo,
        z_hi,
        float(np.nanmin(paths.points[..., 0][paths.reached])),
        float(np.nanmax(paths.points[..., 0][paths.reached])),
    ]
    width = max(z_all) - min(z_all)
    fig_w = 11.0
    fig_h = float(np.clip(fig_w * 2 * sizes.ymax / max(width, 1e-9) + 1.6, 3.2, 9.0))
    fig = new_figure((fig_w, fig_h), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    handles = _draw_ray_fans(ax, lens, fields, paths, len(pupil_y))
    _draw_surfaces(ax, lens, sizes)
    _draw_glass_edges(ax, lens, sizes.sds)
    _draw_stop_and_image(ax, lens, sizes)

    ax.axhline(0.0, color="0.6", lw=0.6, ls=(0, (8, 3, 2, 3)), zorder=1)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("z (mm)")
    ax.set_ylabel("y (mm)")
    unit = "field angle" if lens.field_type == "angle" else lens.field_type.replace("_", " ")
    ax.legend(
        handles=handles,
        title=unit,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        fontsize=8,
        title_fontsize=8,
        frameon=False,
    )
    efl = para.efl_mm
    efl_text = "afocal" if not math.isfinite(efl) else f"EFL {efl:.4g} mm"
    ax.set_title(
        f"{lens_title(lens)}\n{efl_text}, F/{para.fno:.3g}, {aiming} ray aiming, "
        f"{lens.primary_wavelength_um * 1000:.1f} nm",
        fontsize=10,
    )
    ax.grid(True, color="0.92", lw=0.5, zorder=0)
    if path is not None:
        save_figure(fig, path)
    return fig


def _check_chief_rays(lens: Lens, launch: list[float], aiming: Aiming, para: ParaxialData, paths: RayPaths) -> None:
    """Raise RayTraceError when a field's chief ray does not reach the image (a reference
    ray: central obscurations do not block it, see aiming.trace_chief_rays), or when no
    ray passes the stop."""
    rays, wl = generate_rays(lens, launch, torch.zeros(1, 2, dtype=DTYPE), [lens.primary_wavelength_um], aiming, para)
    trace_chief_rays(lens, rays, wl, launch, aiming, para)
    if not bool(paths.reached[:, :, 0].any()):
        raise RayTraceError(f"{lens.source}: aperture: no ray could be aimed through the stop")


class _LayoutSizes:
    """How large the layout draws each surface (mm): sds, the semi-diameter of every
    surface; stop_r, the stop's opening; image_h, the image plane's half height; ymax,
    the largest of these (the plot's half height)."""

    def __init__(self, lens: Lens, paths: RayPaths, para: ParaxialData) -> None:
        S = lens.num_surfaces
        heights = np.zeros(S + 1)
        for i in range(S + 1):
            ok = paths.reached[:, :, i + 1]
            if ok.any():
                heights[i] = np.abs(paths.points[:, :, i + 1, 1][ok]).max()
        stop_r = para.stop_semi_diameter_mm  # the opening the aperture setting gives the stop
        stop_clear = lens.surfaces[lens.stop_index].clear_radius
        if stop_clear is not None:
            stop_r = min(stop_r, stop_clear)
        sds = []
        for i, s in enumerate(lens.surfaces):
            sd = s.semi_diameter or s.clear_radius
            if sd is None:
                sd = 1.05 * max(heights[i], stop_r if s.is_stop else 0.0)
                sd = sd if sd > 0 else 0.05 * max(1.0, float(np.max(heights)))
            sds.append(min(sd, s.geometry.max_radius * (1 - 1e-9)))
        self.sds, self.stop_r = sds, stop_r
        self.image_h = lens.image_clear_radius or 1.05 * heights[S]
        self.ymax = max(max(sds), self.image_h, 1e-3)


def _draw_ray_fans(ax, lens: Lens, fields: list[float], paths: RayPaths, n_pupil: int) -> list[Line2D]:
    """Draw each field's fan (pupil indices 1..n_pupil-1) in its colour; legend handles."""
    handles = []
    S = lens.num_surfaces
    media = lens.media()
    # a ray's point on a surface that bends no ray lies on its straight path, and may lie
    # behind the next surface (a stop placed by a negative thickness): it is left out of
    # the drawn path unless the ray ends there
    bends = np.array([True] + [not lens.is_dummy(k, media) for k in range(S)] + [True])
    for fi, f in enumerate(fields):
        color = FIELD_COLORS[fi % len(FIELD_COLORS)]
        for p in range(1, n_pupil):
            r = paths.reached[fi, p]
            if not r[0]:
                continue
            upto = np.argmin(r) if not r.all() else r.size  # first point not reached
            keep = bends[:upto].copy()
            keep[upto - 1] = True
            seg = paths.points[fi, p, :upto][keep]
            ax.plot(seg[:, 0], seg[:, 1], color=color, lw=0.8, alpha=0.9, zorder=2)
        handles.append(Line2D([], [], color=color, lw=1.5, label=field_label(lens, f)))
    return handles


def _draw_surfaces(ax, lens: Lens, sizes: _LayoutSizes) -> None:
    """Draw every surface's sag profile: mirrors bold and hatched on the back, planes
    between air and air (dummies) dashed grey, stops there left to the diaphragm."""
    zv = lens.vertex_z()
    dirs = lens.directions()
    media = lens.media()
    for i, s in enumerate(lens.surfaces):
        z, y = _profile(s, float(zv[i]), sizes.sds[i])
        if s.is_mirror:
            ax.plot(z, y, color="black", lw=2.2, zorder=4, solid_capstyle="butt")
            # hatch the back: the side light would reach if it went on
            back = float(dirs[i])
            k = np.linspace(0, len(z) - 1, 15).astype(int)
            hl = 0.045 * sizes.ymax
            for j in k:
                ax.plot([z[j], z[j] + back * hl], [y[j], y[j] + hl], color="black", lw=0.8, zorder=4)
        elif isinstance(media[i], Air) and isinstance(media[i + 1], Air) and s.curvature == 0 and not s.is_aspheric:
            # a plane between air and air bends no ray: a stop or a dummy surface
            if not s.is_stop:
                ax.plot(z, y, color="0.6", lw=0.7, ls=(0, (3, 3)), zorder=3)
        else:
            ax.plot(z, y, color="black", lw=1.2, zorder=3)


def _draw_glass_edges(ax, lens: Lens, sds: list[float]) -> None:
    """Close each glass element (a run of surfaces with glass between them) at a common
    edge height with flat edges."""
    zv = lens.vertex_z()
    media = lens.media()
    S = lens.num_surfaces
    i = 0
    while i < S:
        if isinstance(media[i + 1], Air) or i + 1 >= S:
            i += 1
            continue
        j = i + 1
        while j < S - 1 and not isinstance(media[j + 1], Air):
            j += 1
        group = list(range(i, j + 1))
        edge = max(sds[k] for k in group)
        ends = []
        for k in group:
            zk = float(zv[k]) + lens.surfaces[k].geometry.sag_at(sds[k])
            if sds[k] < edge:
                for sgn in (1, -1):
                    ax.plot([zk, zk], [sgn * sds[k], sgn * edge], color="black", lw=1.2, zorder=3)
            ends.append(zk)
        for a, b in zip(ends[:-1], ends[1:]):
            for sgn in (1, -1):
                ax.plot([a, b], [sgn * edge, sgn * edge], color="black", lw=1.2, zorder=3)
        i = j + 1


def _draw_stop_and_image(ax, lens: Lens, sizes: _LayoutSizes) -> None:
    """Mark the stop's diaphragm and the image plane."""
    zv = lens.vertex_z()
    stop_r, ymax, image_h = sizes.stop_r, sizes.ymax, sizes.image_h
    s = lens.surfaces[lens.stop_index]
    zs = float(zv[lens.stop_index]) + s.geometry.sag_at(min(stop_r, s.geometry.max_radius * (1 - 1e-9)))
    outer = stop_r + max(0.25 * stop_r, 0.08 * ymax)
    for sgn in (1, -1):
        ax.plot([zs, zs], [sgn * stop_r, sgn * outer], color="black", lw=3.0, zorder=5, solid_capstyle="butt")
    ax.annotate("STOP", (zs, outer), xytext=(0, 3), textcoords="offset points", ha="center", va="bottom", fontsize=8)
    ax.plot([zv[-1], zv[-1]], [-image_h, image_h], color="black", lw=1.6, zorder=3)
    ax.annotate(
        "IMAGE", (zv[-1], image_h), xytext=(0, 3), textcoords="offset points", ha="center", va="bottom", fontsize=8
    )


# ---- spot diagrams --------------------------------------------------------------------
def plot_spots(
    lens: Lens,
    fields: list[float] | None = None,
    aiming: Aiming = "paraxial",
    path: str | Path | None = None,
    reference: str = "chief",
    rings: int = SPOT_RINGS,
    spots: SpotDiagram | None = None,
) -> Figure:
    """Spot diagrams: one panel per field (lens units; default the lens's fields), every
    wavelength in its own colour (legend in nm), axes in um centred on the
    primary-wavelength chief ray (reference='chief') or on the polychromatic centroid
    (reference='centroid'), one common scale for all panels. Each panel shows the
    Airy-disk radius 1.22 lambda N at the primary wavelength (dashed circle) and the
    polychromatic RMS spot radius about the same reference. Hexapolar pupil sampling with
    `rings` rings, unless `spots` (a spot diagram already traced for this lens with this
    aiming) is given: then it is drawn as it is and `fields` and `rings` are not used.
    """
    if reference not in ("chief", "centroid"):
        raise InputError(None, "reference", f"expected 'chief' or 'centroid', got {reference!r}")
    para = paraxial_data(lens)
    if spots is None:
        spots = spot_diagram(lens, fields, None, hexapolar(rings), aiming, para)
    summary = spot_summary(lens, spots, reference)
    xy = spots.xy.numpy() * 1000.0  # um
    valid = spots.valid.numpy()
    w = np.asarray(spots.weights, dtype=np.float64)[:, None, None] * valid
    if reference == "chief":
        centre = spots.chief[spots.primary].numpy() * 1000.0  # (F, 2)
        centre_text = "centred on the primary-wavelength chief ray"
    else:
        centre = (xy * w[..., None]).sum((0, 2)) / np.maximum(w.sum((0, 2)), 1e-300)[:, None]
        centre_text = "centred on the polychromatic centroid"
    rel = xy - centre[None, :, None, :]
    airy = airy_radius_um(lens, para)
    reach = [np.abs(rel[:, fi][valid[:, fi]]).max() if valid[:, fi].any() else 0.0 for fi in range(len(spots.fields))]
    half = 1.12 * max(max(reach), airy)
    half = float(_nice_ceiling(half))

    F = len(spots.fields)
    ncols = min(F, 3)
    nrows = math.ceil(F / ncols)
    fig = new_figure((3.6 * ncols + 0.4, 3.6 * nrows + 1.1), layout="constrained")
    colors = _wavelength_colors(spots.wavelengths_um)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for fi in range(F):
        ax = axes[fi // ncols][fi % ncols]
        for wi in range(len(spots.wavelengths_um)):
            m = valid[wi, fi]
            ax.scatter(rel[wi, fi, m, 0], rel[wi, fi, m, 1], s=3, color=colors[wi], linewidths=0, zorder=3)
        ax.add_patch(Circle((0.0, 0.0), airy, fill=False, ls="--", lw=0.9, color="black", zorder=4))
        ax.set_xlim(-half, half)
        ax.set_ylim(-half, half)
        ax.set_aspect("equal")
        ax.axhline(0, color="0.85", lw=0.5, zorder=1)
        ax.axvline(0, color="0.85", lw=0.5, zorder=1)
        ax.set_xlabel("x (um)")
        ax.set_ylabel("y (um)")
        chief_y = summary[fi]["wavelengths"][spots.primary]["chief_y_mm"]
        ax.set_title(f"field {field_label(lens, spots.fields[fi])}   (chief y = {chief_y:.4g} mm)", fontsize=9)
        rms = summary[fi]["rms_radius_um"]
        lines = [f"RMS radius {_fmt_um(rms)} um" if rms is not None else "no ray reaches the image"]
        total = valid.shape[-1] * valid.shape[0]
        got = int(valid[:, fi].sum())
        if got < total:
            lines.append(f"vignetted {100.0 * (total - got) / total:.0f}%")
        ax.text(
            0.03,
            0.97,
            "\n".join(lines),
            transform=ax.transAxes,
            ha="left",
            va="top",
            fontsize=8,
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "0.8", "alpha": 0.9},
            zorder=5,
        )
    for k in range(F, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    handles = [
        Line2D(
            [],
            [],
            ls="",
            marker="o",
            ms=5,
            color=colors[wi],
            label=f"{w_ * 1000:.1f} nm" + (" (primary)" if wi == spots.primary else ""),
        )
        for wi, w_ in enumerate(spots.wavelengths_um)
    ]
    handles.append(
        Line2D(
            [],
            [],
            ls="--",
            color="black",
            lw=0.9,
            label=f"Airy radius {airy:.3g} um (1.22 \N{GREEK SMALL LETTER LAMDA} N)",
        )
    )
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 4), fontsize=8, frameon=False)
    fig.suptitle(
        f"{lens_title(lens)}: spot diagrams, {centre_text}\n"
        f"{aiming} ray aiming, F/{para.working_fno:.3g}, scale \u00b1{half:g} um",
        fontsize=10,
    )
    if path is not None:
        save_figure(fig, path)
    return fig


def _nice_ceiling(x: float) -> float:
    """The smallest of 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 x 10^k that is >= x."""
    if x <= 0 or not math.isfinite(x):
        return 1.0
    e = 10.0 ** math.floor(math.log10(x))
    for m in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * e >= x * (1 - 1e-12):
            return m * e
    return 10.0 * e


def _fmt_um(x: float) -> str:
    """Three significant digits, without an exponent for large values."""
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"
