"""Spot diagrams, RMS spot radii and the spot report (`lens spot --json`, the figures of
lensim.plots.lens.plot_spots): one home for the numbers both show."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lensim.errors import ParameterError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import generate_rays, object_field, trace_chief_rays
from lensim.optics.aiming.sampling import hexapolar
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.optics.trace import trace

SPOT_RINGS = 8  # hexapolar rings in spot diagrams: 217 rays per field and wavelength


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


def airy_radius_um(lens: Lens, para: ParaxialData | None = None) -> float:
    """Airy-disk radius 1.22 lambda N (um) at the primary wavelength, N the working F/#."""
    para = para or paraxial_data(lens)
    return 1.22 * lens.primary_wavelength_um * para.working_fno


def spot_summary(lens: Lens, spots: SpotDiagram, reference: str = "chief") -> list[dict]:
    """Per field: polychromatic RMS radius (um) and, per wavelength, the RMS radius (um),
    the chief-ray position on the image plane (mm) and how many rays reach the image.

    reference: 'chief' (the primary-wavelength chief ray for the polychromatic radius,
    each wavelength's own chief ray per wavelength) or 'centroid'.
    """
    if reference not in ("chief", "centroid"):
        raise ParameterError(None, "reference", f"expected 'chief' or 'centroid', got {reference!r}")
    poly = spots.rms_radius(reference, polychromatic=True) * 1000.0
    mono = spots.rms_radius(reference, polychromatic=False) * 1000.0
    out = []
    for fi, f in enumerate(spots.fields):
        per_wl = []
        for wi, w in enumerate(spots.wavelengths_um):
            n_valid = int(spots.valid[wi, fi].sum())
            per_wl.append(
                {
                    "wavelength_nm": round(w * 1000.0, 6),
                    "rms_radius_um": float(mono[wi, fi]) if n_valid else None,
                    "chief_x_mm": float(spots.chief[wi, fi, 0]),
                    "chief_y_mm": float(spots.chief[wi, fi, 1]),
                    "rays": int(spots.valid.shape[-1]),
                    "rays_reaching_image": n_valid,
                }
            )
        out.append(
            {
                "field": float(f),
                "field_unit": "deg" if lens.field_type == "angle" else "mm",
                "rms_radius_um": float(poly[fi]) if bool(spots.valid[:, fi].any()) else None,
                "wavelengths": per_wl,
            }
        )
    return out


def spot_report(lens: Lens, spots: SpotDiagram, aiming: Aiming, reference: str = "chief") -> dict:
    """The spot diagram of a lens as a JSON-ready dict: name, source, aiming, reference,
    airy_radius_um (1.22 lambda N at the primary wavelength, um), primary_wavelength_nm,
    image_z_mm (the image plane, first vertex at 0) and ``fields`` (spot_summary). ``spots``
    was traced with ``aiming``; reference: 'chief' or 'centroid'."""
    return {
        "name": lens.name,
        "source": lens.source,
        "aiming": aiming,
        "reference": reference,
        "airy_radius_um": airy_radius_um(lens),
        "primary_wavelength_nm": lens.primary_wavelength_um * 1000.0,
        "image_z_mm": float(lens.vertex_z()[-1]),
        "fields": spot_summary(lens, spots, reference),
    }
