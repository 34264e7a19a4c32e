"""Lens.launch_lens: what rays are launched with, for every object distance and field type
the four former copies of the rule handled (field analysis, ray aiming, PSF, PSF bank)."""

from __future__ import annotations

import math

import pytest

from lensim.errors import InputError
from lensim.optics.aiming.rays import object_field
from lensim.optics.lens import Lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.paraxial import paraxial_image_height
from lensim.optics.surfaces import Surface

F_MM = 100.0  # plano-convex, R = 50 mm, n = 1.5: EFL = R / (n - 1), whatever the thickness


def _singlet(field_type: str, fields: list[float], object_distance: float, image_distance: float) -> Lens:
    """A thin plano-convex singlet (0.01 mm thick), stop on its first surface."""
    return Lens(
        [Surface(1 / 50.0, 0.01, ConstantIndex(1.5), is_stop=True), Surface(0.0, image_distance)],
        aperture_value=5.0,
        field_type=field_type,
        fields=fields,
        wavelengths_um=[0.55],
        object_distance=object_distance,
    )


CASES = [  # (field type, object distance mm, expected launch type)
    ("angle", math.inf, "angle"),
    ("paraxial_image_height", math.inf, "angle"),
    ("real_image_height", math.inf, "angle"),
    ("angle", 300.0, "angle"),
    ("object_height", 300.0, "object_height"),
    ("paraxial_image_height", 300.0, "object_height"),
    ("real_image_height", 300.0, "object_height"),
]


@pytest.mark.parametrize("field_type, distance, expected", CASES)
def test_launch_type_for_every_field_type_and_object(field_type, distance, expected):
    lens = _singlet(field_type, [0.0, 5.0], distance, 150.0)
    probe = lens.launch_lens()
    assert lens.launch_field_type == expected and probe.field_type == expected
    assert (probe is lens) == (field_type == expected)  # a copy only when the type changes
    assert probe.surfaces is lens.surfaces and probe.object_distance == lens.object_distance
    assert lens.field_type == field_type and lens.fields == [0.0, 5.0]  # the original is untouched


def test_image_heights_beyond_90_mm_are_not_read_as_angles():
    lens = _singlet("real_image_height", [0.0, 95.0], math.inf, F_MM)
    assert lens.launch_lens().field_type == "angle"  # formerly: "field angles must be below 90 degrees"


def test_object_height_fields_need_a_finite_object():
    # the one case where the old copies disagreed (angle in the PSF code, object height in
    # field analysis) cannot be built: the lens is refused
    with pytest.raises(InputError, match="object_height"):
        _singlet("object_height", [0.0, 5.0], math.inf, 100.0)


def test_launch_values_are_read_as_angles_and_object_heights():
    # infinite object, paraxial image height 10 mm: the launch angle is atan(10 / f)
    lens = _singlet("paraxial_image_height", [0.0, 10.0], math.inf, F_MM)
    angle = object_field(lens, 10.0)
    assert abs(abs(angle) - math.degrees(math.atan(10.0 / F_MM))) < 1e-3
    assert abs(abs(paraxial_image_height(lens.launch_lens(), angle)) - 10.0) < 1e-9
    # object 300 mm away, image at 150 mm (1/300 + 1/150 = 1/f): magnification -1/2, so an
    # image height of 10 mm is an object height of 20 mm
    lens = _singlet("paraxial_image_height", [0.0, 10.0], 300.0, 150.0)
    height = object_field(lens, 10.0)
    assert abs(abs(height) - 20.0) < 0.02
    assert abs(abs(paraxial_image_height(lens.launch_lens(), height)) - 10.0) < 1e-9
