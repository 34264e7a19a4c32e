"""Library-level analyses the `lens` commands print: the fields to analyse given one of
three ways (lensim.optics.analysis.fields_to_show) and the spot report
(lensim.optics.spot.spot_report, what `lens spot --json` prints), checked against
independent numbers: the triplet's 20 deg full field, the Airy radius 1.22 lambda N, the
spot diagram's own RMS radii and a real chief ray landing at the asked image height."""

from __future__ import annotations

import math

import pytest

from lensim.errors import ParameterError
from lensim.optics.aiming.sampling import hexapolar
from lensim.optics.analysis import fields_to_show
from lensim.optics.lens_file import load_lens
from lensim.optics.spot import SPOT_RINGS, spot_diagram, spot_report


@pytest.fixture(scope="module")
def triplet():
    return load_lens("cooke_triplet")  # F/5, fields 0, 14, 20 deg, 480/550/650 nm


def test_fields_are_given_normalized_as_angles_or_as_image_heights(triplet) -> None:
    assert fields_to_show(triplet) == (triplet, None)  # the lens's own fields
    lens, values = fields_to_show(triplet, field=[0.0, 0.5, 1.0])
    assert lens is triplet and values == [0.0, 10.0, 20.0]
    lens, values = fields_to_show(triplet, field_deg=[7.5])
    assert lens.field_type == "angle" and lens.fields == [7.5] and values == [7.5]
    lens, values = fields_to_show(triplet, image_height_mm=[12.5])
    assert lens.field_type == "real_image_height" and values == [12.5]
    spots = spot_diagram(lens, values, None, hexapolar(1), "real")
    assert float(spots.chief[lens.primary, 0, 1]) == pytest.approx(12.5, abs=1e-8)  # solved for


@pytest.mark.parametrize(
    "given, parameter",
    [
        ({"field": [1.0], "field_deg": [20.0]}, "field_deg"),
        ({"field_deg": [90.0]}, "field_deg"),
        ({"field_deg": [math.nan]}, "field_deg"),
        ({"image_height_mm": [math.inf]}, "image_height_mm"),
    ],
)
def test_bad_fields_name_the_parameter(triplet, given: dict, parameter: str) -> None:
    with pytest.raises(ParameterError) as e:
        fields_to_show(triplet, **given)
    assert e.value.parameter == parameter and "\n" not in str(e.value) and "--" not in str(e.value)


def test_the_spot_report_holds_the_spot_diagram_s_numbers(triplet) -> None:
    spots = spot_diagram(triplet, None, None, hexapolar(SPOT_RINGS), "paraxial")
    report = spot_report(triplet, spots, "paraxial", "centroid")
    assert (report["name"], report["aiming"], report["reference"]) == (triplet.name, "paraxial", "centroid")
    assert report["airy_radius_um"] == pytest.approx(1.22 * 0.55 * 5.0, rel=1e-3)  # 1.22 lambda N at F/5
    assert report["primary_wavelength_nm"] == pytest.approx(550.0)
    assert report["image_z_mm"] == pytest.approx(float(triplet.vertex_z()[-1]))
    poly = spots.rms_radius("centroid", polychromatic=True) * 1000.0
    mono = spots.rms_radius("centroid", polychromatic=False) * 1000.0
    assert [f["field"] for f in report["fields"]] == [0.0, 14.0, 20.0]
    for fi, f in enumerate(report["fields"]):
        assert f["rms_radius_um"] == pytest.approx(float(poly[fi]), rel=1e-12)
        assert [w["rms_radius_um"] for w in f["wavelengths"]] == pytest.approx(mono[:, fi].tolist(), rel=1e-12)
        assert all(w["rays"] == w["rays_reaching_image"] == 217 for w in f["wavelengths"])
    with pytest.raises(ParameterError, match="^reference: "):
        spot_report(triplet, spots, "paraxial", "median")
