"""Lens analyses: first-order summary, spot diagrams, distortion, relative illumination;
the fields to analyse, given in any of three ways (fields_to_show)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from lensim.errors import ParameterError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import chief_ray_image_height, object_field
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data


def first_order_summary(lens: Lens, aiming: Aiming = "real") -> dict:
    """The numbers a lens designer reads first (mm, um, deg), as a JSON-ready dict.

    z positions are global (first surface vertex at z = 0). image_height_mm is the real
    chief-ray height on the image plane at the maximum field, primary wavelength.
    """
    para = paraxial_data(lens)
    max_field = lens.max_field
    launch = object_field(lens, max_field, aiming, para)
    image_height = abs(chief_ray_image_height(lens, launch, aiming, para))
    unit = "deg" if lens.field_type == "angle" else "mm"
    return {
        "name": lens.name,
        "source": lens.source,
        "efl_mm": float(para.efl_mm),
        "bfl_mm": float(para.bfl_mm),
        "fno": float(para.fno),
        "working_fno": float(para.working_fno),
        "epd_mm": float(para.epd_mm),
        "entrance_pupil_z_mm": float(para.entrance_pupil_z_mm),
        "exit_pupil_z_mm": float(para.exit_pupil_z_mm),
        "exit_pupil_diameter_mm": float(para.exit_pupil_diameter_mm),
        "exit_pupil_to_image_mm": float(para.exit_pupil_to_image_mm),
        "stop_semi_diameter_mm": float(para.stop_semi_diameter_mm),
        "paraxial_image_z_mm": float(para.paraxial_image_z_mm),
        "image_z_mm": float(lens.vertex_z()[-1]),
        "total_track_mm": float(lens.total_track),
        "object_distance_mm": None if lens.infinite_object else float(lens.object_distance),
        "max_field": max_field,
        "field_type": lens.field_type,
        "field_unit": unit,
        "fields": list(lens.fields),
        "wavelengths_um": list(lens.wavelengths_um),
        "wavelength_weights": list(lens.wavelength_weights),
        "primary_wavelength_um": lens.primary_wavelength_um,
        "image_height_mm": float(image_height),
        "aiming": aiming,
        "notes": list(lens.notes),
    }


def fields_to_show(
    lens: Lens,
    field: Sequence[float] | None = None,
    field_deg: Sequence[float] | None = None,
    image_height_mm: Sequence[float] | None = None,
) -> tuple[Lens, list[float] | None]:
    """The lens to trace and its field values for fields given one of three ways, at most
    one of them: ``field`` normalized (0..1 of the maximum field, returned in the lens's own
    unit), ``field_deg`` object-space angles (deg, below 90: the lens is returned with
    angle fields) or ``image_height_mm`` real chief-ray image heights (mm: the lens is
    returned with real-image-height fields, solved for when traced). (lens, None) when none
    is given: the lens's own fields. A ParameterError names the parameter at fault."""
    from lensim.psf.compute import field_in_lens_units

    ways = (("field", field), ("field_deg", field_deg), ("image_height_mm", image_height_mm))
    given = [name for name, values in ways if values]
    if len(given) > 1:
        raise ParameterError(
            None,
            given[1],
            f"expected one of `field`, `field_deg`, `image_height_mm`, got {' and '.join(f'`{g}`' for g in given)}",
        )
    if field:
        return lens, [field_in_lens_units(lens, f) for f in field]
    if field_deg:
        if any(not (math.isfinite(f) and abs(f) < 90.0) for f in field_deg):
            raise ParameterError(
                None, "field_deg", f"expected angles below 90 deg, got {', '.join(f'{f:g}' for f in field_deg)}"
            )
        return lens.with_changes(field_type="angle", fields=list(field_deg)), list(field_deg)
    if image_height_mm:
        if any(not math.isfinite(f) for f in image_height_mm):
            raise ParameterError(None, "image_height_mm", "expected finite image heights (mm)")
        return lens.with_changes(field_type="real_image_height", fields=list(image_height_mm)), list(image_height_mm)
    return lens, None
