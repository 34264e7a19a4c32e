"""Spot diagrams and RMS spot radius."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lensim.optics.aiming import Aiming, generate_rays, object_field, trace_chief_rays
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.optics.pupil import hexapolar
from lensim.optics.trace import trace


@dataclass
class SpotDiagram:
    """Image-plane ray intercepts for each wavelength and field.

    xy: (W, F, P, 2) mm; valid: (W, F, P); chief: (W, F, 2) chief-ray intercepts (mm);
    fields: the fields in the lens's unit; wavelengths_um: (W,).
    """

    xy: torch.Tensor
    valid: torch.Tensor
    chief: torch.Tensor
    fields: list[float]
    wavelengths_um: list[float]
    weights: list[float]

    def rms_radius(self, reference: str = "centroid", polychromatic: bool = True) -> torch.Tensor:
        """RMS spot radius (mm) per field (polychromatic, weighted) or (W, F).

        reference: 'centroid' (of the valid rays, over all wavelengths when
        polychromatic) or 'chief' (the primary-wavelength chief ray for polychromatic,
        each wavelength's chief ray otherwise).
        """
        v = self.valid.to(self.xy.dtype)
        w = torch.as_tensor(self.weights, dtype=self.xy.dtype).reshape(-1, 1, 1) * v
        if polychromatic:
            if reference == "centroid":
                c = (self.xy * w.unsqueeze(-1)).sum((0, 2)) / w.sum((0, 2)).clamp_min(1e-300).unsqueeze(-1)
            else:
                c = self.chief[self.primary]
            d2 = ((self.xy - c.unsqueeze(0).unsqueeze(2)) ** 2).sum(-1)
            return torch.sqrt((d2 * w).sum((0, 2)) / w.sum((0, 2)).clamp_min(1e-300))
        if reference == "centroid":
            c = (self.xy * v.unsqueeze(-1)).sum(2) / v.sum(2).clamp_min(1).unsqueeze(-1)
        else:
            c = self.chief
        d2 = ((self.xy - c.unsqueeze(2)) ** 2).sum(-1)
        return torch.sqrt((d2 * v).sum(2) / v.sum(2).clamp_min(1))

    primary: int = 0


def spot_diagram(
    lens: Lens,
    fields: list[float] | None = None,
    wavelengths_um: list[float] | None = None,
    pupil: torch.Tensor | None = None,
    aiming: Aiming = "paraxial",
    para: ParaxialData | None = None,
) -> SpotDiagram:
    """Trace a pupil pattern (default: hexapolar, 6 rings) for each field (lens units;
    default the lens's fields) and wavelength (default the lens's) to the image plane.
    Obscured rays are invalid; the chief ray is a reference ray that obscurations do not
    block (aiming.trace_chief_rays)."""
    para = para or paraxial_data(lens)
    fields = list(lens.fields) if fields is None else list(fields)
    wls = list(lens.wavelengths_um) if wavelengths_um is None else list(wavelengths_um)
    weights = list(lens.wavelength_weights) if wavelengths_um is None else [1.0] * len(wls)
    primary = lens.primary if wavelengths_um is None else 0
    pupil = hexapolar(6) if pupil is None else pupil
    launch = [object_field(lens, f, aiming, para) for f in fields]
    pts = torch.cat([torch.zeros(1, 2, dtype=pupil.dtype), pupil.to(torch.float64)])
    rays, wl = generate_rays(lens, launch, pts, wls, aiming, para)
    chief = trace_chief_rays(lens, rays.select(0), wl, launch, aiming, para)
    res = trace(lens, rays.select(slice(1, None)), wl)
    return SpotDiagram(
        xy=res.rays.position[..., :2],
        valid=res.rays.valid,
        chief=chief.rays.position[..., 0, :2],
        fields=fields,
        wavelengths_um=wls,
        weights=weights,
        primary=primary,
    )


def rms_spot_radius(
    lens: Lens,
    field: float,
    wavelength_um: float | None = None,
    rings: int = 6,
    aiming: Aiming = "paraxial",
    reference: str = "centroid",
) -> float:
    """Monochromatic (or, with wavelength_um None, polychromatic) RMS spot radius in mm."""
    wls = None if wavelength_um is None else [wavelength_um]
    sd = spot_diagram(lens, [field], wls, hexapolar(rings), aiming)
    return float(sd.rms_radius(reference, polychromatic=True)[0])
