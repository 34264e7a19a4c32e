"""Transverse ray aberration fans and field curves (sagittal and tangential field curvature).

Ray fans: for each field and wavelength, rays across the pupil's y axis (the tangential
fan, px = 0, py from -1 to 1) and across its x axis (the sagittal fan, py = 0); each ray's
transverse aberration on the image plane is its intercept minus the primary wavelength's
chief-ray intercept: ey for the tangential fan, ex for the sagittal fan (um), as Zemax
and optiland plot them. Rays that are vignetted are NaN.

Field curves: for each field and wavelength, a pair of rays at pupil coordinates +-delta
around the chief ray in the tangential plane (py) and another in the sagittal plane (px);
where each pair crosses (in the y-z or x-z plane) is the tangential or sagittal focus of
the chief ray's neighbourhood (the Coddington foci, to O(delta^2)). Each is given as its
distance from the image plane along z (mm), positive away from the lens, so a lens with
the image plane at its paraxial focus reads 0 on axis; astigmatism is T - S.

Fields in the lens's field unit (lensim.optics.aiming.rays.object_field), along +y.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import generate_rays, object_field, trace_chief_rays
from lensim.optics.field_analysis import _default_fields, _field_unit
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.trace import DTYPE, Rays, trace


def _trace_pattern(
    lens: Lens, fields: Sequence[float], wavelengths_um: Sequence[float], pupil: torch.Tensor, aiming: Aiming
) -> tuple[Rays, torch.Tensor]:
    """(image-plane rays (W, F, P), chief-ray intercepts (W, F, 2) mm) of a pupil pattern."""
    para = paraxial_data(lens)
    launch = [object_field(lens, f, aiming, para) for f in fields]
    pts = torch.cat([torch.zeros(1, 2, dtype=DTYPE), pupil.to(DTYPE)])
    rays, wl = generate_rays(lens, launch, pts, list(wavelengths_um), aiming, para)
    chief = trace_chief_rays(lens, rays.select(0), wl, launch, aiming, para)
    out = trace(lens, rays.select(slice(1, None)), wl).rays
    return out, chief.rays.position[..., 0, :2]


@dataclass
class RayFans:
    """pupil (P,) normalized pupil coordinate along each fan; tangential_um (W, F, P): ey
    of the tangential fan; sagittal_um (W, F, P): ex of the sagittal fan; both relative to
    the primary wavelength's chief ray, NaN where vignetted."""

    pupil: np.ndarray
    tangential_um: np.ndarray
    sagittal_um: np.ndarray
    fields: list[float]
    field_unit: str
    wavelengths_um: list[float]
    primary: int
    aiming: str

    def to_dict(self) -> dict:
        """JSON-ready: per field, per wavelength (nm) the two fans in um (null: vignetted)."""
        wl_nm = [w * 1000.0 for w in self.wavelengths_um]
        return {
            "field_unit": self.field_unit,
            "wavelengths_nm": wl_nm,
            "primary_wavelength_nm": wl_nm[self.primary],
            "aiming": self.aiming,
            "reference": "chief ray at the primary wavelength",
            "pupil": [float(p) for p in self.pupil],
            "fields": [
                {
                    "field": f,
                    "tangential_ey_um": [_nulls(self.tangential_um[w, i]) for w in range(len(wl_nm))],
                    "sagittal_ex_um": [_nulls(self.sagittal_um[w, i]) for w in range(len(wl_nm))],
                }
                for i, f in enumerate(self.fields)
            ],
        }


def _nulls(values: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def ray_fans(
    lens: Lens,
    fields: Sequence[float] | None = None,
    points: int = 41,
    aiming: Aiming = "real",
    wavelengths_um: Sequence[float] | None = None,
) -> RayFans:
    """Tangential and sagittal ray fans of `points` rays from pupil -1 to 1 at each field
    (lens units; default the lens's fields) and wavelength (um; default the lens's)."""
    flds = list(lens.fields) if fields is None else [float(f) for f in fields]
    wls = list(lens.wavelengths_um) if wavelengths_um is None else [float(w) for w in wavelengths_um]
    primary = lens.primary if wavelengths_um is None else 0
    p = torch.linspace(-1.0, 1.0, points, dtype=DTYPE)
    zeros = torch.zeros_like(p)
    pupil = torch.cat([torch.stack([zeros, p], -1), torch.stack([p, zeros], -1)])
    rays, chief = _trace_pattern(lens, flds, wls, pupil, aiming)
    ref = chief[primary].unsqueeze(0).unsqueeze(2)  # (1, F, 1, 2)
    d = torch.where(rays.valid.unsqueeze(-1), rays.position[..., :2] - ref, torch.nan) * 1e3
    return RayFans(
        pupil=p.numpy(),
        tangential_um=d[:, :, :points, 1].numpy(),
        sagittal_um=d[:, :, points:, 0].numpy(),
        fields=flds,
        field_unit=_field_unit(lens),
        wavelengths_um=wls,
        primary=primary,
        aiming=aiming,
    )


@dataclass
class FieldCurves:
    """tangential_mm, sagittal_mm (W, F): the foci's distance from the image plane along z
    (positive away from the lens); fields in field_unit; wavelengths_um."""

    fields: list[float]
    field_unit: str
    wavelengths_um: list[float]
    tangential_mm: np.ndarray
    sagittal_mm: np.ndarray
    primary: int
    aiming: str

    def to_dict(self) -> dict:
        """JSON-ready: per wavelength (nm), the tangential and sagittal foci and their
        difference (astigmatism) at each field, mm."""
        return {
            "field_unit": self.field_unit,
            "fields": self.fields,
            "aiming": self.aiming,
            "primary_wavelength_nm": self.wavelengths_um[self.primary] * 1000.0,
            "wavelengths": [
                {
                    "wavelength_nm": wl * 1000.0,
                    "tangential_mm": _nulls(self.tangential_mm[w]),
                    "sagittal_mm": _nulls(self.sagittal_mm[w]),
                    "astigmatism_mm": _nulls(self.tangential_mm[w] - self.sagittal_mm[w]),
                }
                for w, wl in enumerate(self.wavelengths_um)
            ],
        }


def _crossing(a: Rays, b: Rays, axis: int) -> torch.Tensor:
    """z distance from the rays' common plane to where rays a and b cross in the
    (axis, z) plane (mm, along z)."""
    pa, pb, da, db = a.position, b.position, a.direction, b.direction
    num = db[..., axis] * (pa[..., 2] - pb[..., 2]) - db[..., 2] * (pa[..., axis] - pb[..., axis])
    den = da[..., axis] * db[..., 2] - db[..., axis] * da[..., 2]
    return num / den * da[..., 2]


def field_curves(
    lens: Lens,
    fields: Sequence[float] | np.ndarray | None = None,
    aiming: Aiming = "real",
    wavelengths_um: Sequence[float] | None = None,
    delta: float = 1e-4,
) -> FieldCurves:
    """Tangential and sagittal foci against the field (lens units; default 21 fields from
    0 to the maximum) at each wavelength (um; default the lens's)."""
    flds = _default_fields(lens, fields)
    wls = list(lens.wavelengths_um) if wavelengths_um is None else [float(w) for w in wavelengths_um]
    pupil = torch.tensor([[0.0, -delta], [0.0, delta], [-delta, 0.0], [delta, 0.0]], dtype=DTYPE)
    rays, _ = _trace_pattern(lens, flds, wls, pupil, aiming)
    sign = float(lens.directions()[-1])
    tan = _crossing(rays.select(0), rays.select(1), 1)[..., 0] * sign
    sag = _crossing(rays.select(2), rays.select(3), 0)[..., 0] * sign
    ok = rays.valid.all(-1)
    return FieldCurves(
        fields=flds,
        field_unit=_field_unit(lens),
        wavelengths_um=wls,
        tangential_mm=torch.where(ok, tan, torch.nan).numpy(),
        sagittal_mm=torch.where(ok, sag, torch.nan).numpy(),
        primary=lens.primary if wavelengths_um is None else 0,
        aiming=aiming,
    )
