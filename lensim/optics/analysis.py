"""Lens analyses: first-order summary, spot diagrams, distortion, relative illumination."""

from __future__ import annotations

from lensim.optics.aiming import Aiming, chief_ray_image_height, object_field
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
