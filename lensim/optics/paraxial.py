"""First-order (paraxial) optics: y-nu ray traces, focal lengths, pupils, image heights.

Signed-index convention: after a mirror the index changes sign and thicknesses are
negative, so reduced thickness t/n stays positive and the y-nu equations hold unchanged:
    refraction:  n'u' = n u - y c (n' - n)        transfer:  y' = y + t (n'u') / n'
All z positions are global (first surface vertex at z = 0), lengths in mm.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch

from lensim.errors import InputError
from lensim.optics.lens import Lens


def signed_indices(lens: Lens, wavelength_um: float) -> np.ndarray:
    """Index of each medium (N+1) with the sign flipped after every mirror."""
    n = lens.indices([wavelength_um])[:, 0]
    return n * lens.directions()


def trace_yu(lens: Lens, y: float, nu: float, wavelength_um: float, start: int = 0, end: int | None = None):
    """Paraxial trace of a ray given at surface `start`'s vertex plane, in the medium before
    it, with height y and reduced slope nu = n u. Refracts at surfaces start..end-1 and
    returns (heights at each of those surfaces, reduced slope after the last one)."""
    n = signed_indices(lens, wavelength_um)
    end = lens.num_surfaces if end is None else end
    heights = []
    for i in range(start, end):
        s = lens.surfaces[i]
        if i > start:
            prev = lens.surfaces[i - 1]
            y = y + prev.thickness * nu / n[i]
        heights.append(y)
        power = s.curvature * (n[i + 1] - n[i]) + 2.0 * s.asphere.get(2, 0.0) * (n[i + 1] - n[i])
        nu = nu - y * power
    if any(isinstance(h, torch.Tensor) for h in heights):  # a lens parameter requires grad
        return torch.stack([torch.as_tensor(h, dtype=torch.float64) for h in heights]), nu
    return np.asarray(heights), nu


@dataclass
class ParaxialData:
    """First-order properties at one wavelength (mm; z global, first vertex at 0)."""

    wavelength_um: float
    efl_mm: float
    bfl_mm: float
    fno: float
    working_fno: float
    epd_mm: float
    entrance_pupil_z_mm: float
    exit_pupil_z_mm: float
    exit_pupil_diameter_mm: float
    exit_pupil_to_image_mm: float
    stop_semi_diameter_mm: float
    paraxial_image_z_mm: float
    magnification: float

    def as_dict(self) -> dict:
        return asdict(self)


def _stop_map(lens: Lens, wl: float) -> tuple[float, float]:
    """Height at the stop of a ray given at the first vertex plane: y_stop = A y0 + B nu0."""
    k = lens.stop_index
    if k == 0:
        return 1.0, 0.0
    n = signed_indices(lens, wl)
    ya, nua = trace_yu(lens, 1.0, 0.0, wl, 0, k)
    yb, nub = trace_yu(lens, 0.0, 1.0, wl, 0, k)
    t = lens.surfaces[k - 1].thickness / n[k]
    return ya[-1] + t * nua, yb[-1] + t * nub


def paraxial_data(lens: Lens, wavelength_um: float | None = None) -> ParaxialData:
    """EFL, BFL, F-numbers, pupils and the paraxial image plane of a lens."""
    wl = lens.primary_wavelength_um if wavelength_um is None else wavelength_um
    n = signed_indices(lens, wl)
    n_obj = n[0]
    zv = lens.vertex_positions() if lens.requires_grad else lens.vertex_z()
    last = lens.num_surfaces - 1
    ys, nu = trace_yu(lens, 1.0, 0.0, wl)
    power = -nu / ys[0]
    efl = math.inf if power == 0 else 1.0 / power
    bfl = -ys[-1] * n[-1] / nu if nu != 0 else math.inf
    # entrance pupil: image of the stop in object space
    a, b = _stop_map(lens, wl)
    z_ep = b / a * n_obj
    if lens.aperture_type == "epd":
        epd = lens.aperture_value
    elif lens.aperture_type == "fno":
        epd = abs(efl) / lens.aperture_value
    else:
        epd = 2.0 * lens.aperture_value / abs(a)
    stop_r = abs(a) * epd / 2.0
    # exit pupil: image of the stop in image space
    k = lens.stop_index
    cols = []
    for y0, nu0 in ((0.0, 1.0), (stop_r, 0.0)):
        yk, nuk = y0, nu0
        ys2, nu2 = trace_yu(lens, yk, nuk, wl, k, lens.num_surfaces)
        cols.append((ys2[-1], nu2))
    (yc, nuc), (ym, num) = cols
    z_xp_rel = -yc * n[-1] / nuc if nuc != 0 else math.inf
    xp_radius = abs(ym + num / n[-1] * z_xp_rel) if math.isfinite(z_xp_rel) else math.inf
    z_xp = zv[last] + z_xp_rel
    # marginal ray from the axial object point, through the pupil edge
    if lens.infinite_object:
        y0, nu0 = epd / 2.0, 0.0
    else:
        u0 = (epd / 2.0) / (lens.object_distance + z_ep)
        y0, nu0 = u0 * lens.object_distance, n_obj * u0
    ysm, num_ = trace_yu(lens, y0, nu0, wl)
    image_rel = -ysm[-1] * n[-1] / num_ if num_ != 0 else math.inf
    working = abs(1.0 / (2.0 * num_)) if num_ != 0 else math.inf
    fno = abs(efl) / epd if lens.infinite_object else working
    if lens.infinite_object:
        mag = 0.0
    else:
        # chief-ray-free magnification: ray from object height 1 parallel to the axis is not
        # enough; use the Lagrange invariant: m = (n u) / (n' u') of the marginal ray.
        mag = (nu0) / num_ if num_ != 0 else math.inf
    return ParaxialData(
        wavelength_um=wl,
        efl_mm=efl,
        bfl_mm=bfl,
        fno=fno,
        working_fno=working,
        epd_mm=epd,
        entrance_pupil_z_mm=z_ep,
        exit_pupil_z_mm=z_xp,
        exit_pupil_diameter_mm=2.0 * xp_radius,
        exit_pupil_to_image_mm=z_xp - zv[-1],
        stop_semi_diameter_mm=stop_r,
        paraxial_image_z_mm=zv[last] + image_rel,
        magnification=mag,
    )


def paraxial_chief_ray_start(lens: Lens, field_value: float, para: ParaxialData) -> tuple[float, float]:
    """(y, n u) at the first vertex plane of the paraxial chief ray of a field given as
    an angle (deg) or object height (mm)."""
    n_obj = lens.object_material.index(para.wavelength_um).item()
    z_ep = para.entrance_pupil_z_mm
    if lens.infinite_object:
        u = math.tan(math.radians(field_value))
        return -z_ep * u, n_obj * u
    d = lens.object_distance
    if lens.field_type == "angle":
        u = math.tan(math.radians(field_value))
    else:
        u = -field_value / (d + z_ep)
    return -z_ep * u, n_obj * u


def paraxial_image_height(lens: Lens, field_value: float, para: ParaxialData | None = None) -> float:
    """Paraxial chief-ray height (mm) on the image plane for a field given as an angle
    (deg) or an object height (mm)."""
    para = para or paraxial_data(lens)
    n = signed_indices(lens, para.wavelength_um)
    y0, nu0 = paraxial_chief_ray_start(lens, field_value, para)
    ys, nu = trace_yu(lens, y0, nu0, para.wavelength_um)
    return float(ys[-1] + (lens.surfaces[-1].thickness + lens.image_defocus) * nu / n[-1])


def paraxial_focus_thickness(lens: Lens) -> float:
    """The last surface's thickness (mm) that puts the image plane (before defocus) at the
    paraxial focus of the primary wavelength, where the paraxial marginal ray crosses the
    axis (CODE V's PIM solve; refocusing after the object distance changes)."""
    para = paraxial_data(lens)
    z_last = float(lens.vertex_z()[lens.num_surfaces - 1])
    distance = para.paraxial_image_z_mm - z_last
    if not math.isfinite(distance):
        raise InputError(lens.source, "image", "the lens has no finite paraxial image (afocal)")
    return float(distance)
