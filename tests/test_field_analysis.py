"""Distortion and relative illumination (lensim.optics.field_analysis); tolerances per test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensim.optics.field_analysis import distortion, relative_illumination
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.materials import Air, ConstantIndex
from lensim.optics.paraxial import paraxial_data
from lensim.optics.surfaces import Surface
from reference_lenses import REFERENCE_LENSES

pytestmark = pytest.mark.filterwarnings("ignore::numba.core.errors.NumbaIRAssumptionWarning")


def _symmetric_unit_magnification() -> Lens:
    """Two identical meniscus-ish singlets mirrored about a central stop, object and
    image planes at the same distance: a system symmetric under (y, z) -> (-y, -z)."""
    glass = ConstantIndex(1.62)
    d = 120.0
    surfaces = [
        Surface(1 / 30.0, 6.0, glass),
        Surface(1 / 80.0, 8.0),
        Surface(0.0, 8.0, is_stop=True),
        Surface(-1 / 80.0, 6.0, glass),
        Surface(-1 / 30.0, d),
    ]
    return Lens(
        surfaces,
        aperture_type="epd",
        aperture_value=6.0,
        field_type="object_height",
        fields=[0.0, 10.0, 20.0],
        wavelengths_um=[0.55],
        object_distance=d,
    )


def _thin_lens(thickness: float, epd: float) -> Lens:
    """A plano-convex singlet, f = 100 mm, stop on its first surface, image at the BFL."""
    lens = Lens(
        [Surface(1 / 50.0, thickness, ConstantIndex(1.5), is_stop=True), Surface(0.0, 100.0)],
        aperture_value=epd,
        fields=[0.0, 30.0],
        wavelengths_um=[0.55],
    )
    lens.surfaces[-1].thickness = paraxial_data(lens).bfl_mm
    return lens


# ---------------------------------------------------------------- distortion


def test_distortion_vanishes_for_symmetric_lens_at_unit_magnification():
    # By the symmetry the real chief ray (through the stop centre) leaves as the point
    # reflection of its way in, and so does the paraxial one: both land at -h exactly.
    # Limit: the aiming tolerance (1e-10 mm at the stop), far below 1e-7 percentage points.
    lens = _symmetric_unit_magnification()
    d = distortion(lens, [0.0, 5.0, 10.0, 20.0], aiming="real")
    np.testing.assert_allclose(d["paraxial_height_mm"], [0.0, -5.0, -10.0, -20.0], atol=1e-12)
    np.testing.assert_allclose(d["real_height_mm"], [0.0, -5.0, -10.0, -20.0], atol=1e-8)
    assert np.abs(d["distortion_percent"]).max() < 1e-7


def test_distortion_sign_follows_stop_position():
    # textbook: a positive lens with the stop in front gives barrel (negative) distortion,
    # with the stop behind pincushion (positive); both grow with the field
    front = Lens(
        [Surface(0.0, 20.0, is_stop=True), Surface(1 / 50.0, 4.0, ConstantIndex(1.5)), Surface(0.0, 95.0)],
        aperture_value=4.0,
        fields=[0.0, 20.0],
        wavelengths_um=[0.55],
    )
    behind = Lens(
        [Surface(1 / 50.0, 4.0, ConstantIndex(1.5)), Surface(0.0, 20.0), Surface(0.0, 75.0, is_stop=True)],
        aperture_value=4.0,
        fields=[0.0, 20.0],
        wavelengths_um=[0.55],
    )
    fields = [5.0, 10.0, 20.0]
    barrel = distortion(front, fields)["distortion_percent"]
    pincushion = distortion(behind, fields)["distortion_percent"]
    assert all(v < 0 for v in barrel) and barrel[0] > barrel[1] > barrel[2]
    assert all(v > 0 for v in pincushion) and pincushion[0] < pincushion[1] < pincushion[2]


def test_distortion_defaults_and_image_height_fields():
    lens = load_lens("cooke_triplet")
    d = distortion(lens)
    assert d["fields"] == pytest.approx(list(np.linspace(0.0, 20.0, 21)), abs=1e-12)
    assert d["distortion_percent"][0] == 0.0 and d["field_unit"] == "deg"
    assert d["wavelength_um"] == lens.primary_wavelength_um and d["aiming"] == "real"
    # fields given as real image heights: the real chief ray lands on them (1e-8 mm: the
    # field solve's tolerance), the launch values are angles in degrees
    zmx = load_lens(REFERENCE_LENSES / "US08427765-1.zmx", warn=False)
    dz = distortion(zmx, [4.0, 8.0, 13.6], aiming="real")
    np.testing.assert_allclose(dz["real_height_mm"], [4.0, 8.0, 13.6], atol=1e-8)
    assert dz["field_unit"] == "mm" and 20.0 < dz["launch"][-1] < 30.0


@pytest.mark.parametrize("aiming", ["paraxial", "real"])
def test_distortion_matches_optiland_cooke(aiming):
    # optiland's 'paraxial' distortion model: real chief ray against a plate scale taken
    # from a near-axis chief ray, times tan(angle) (f-tan), chief ray aimed as the optic
    # says (its 'iterative' aimer puts the chief ray through the stop centre, as lensim's
    # 'real' does). optiland's own Cooke sample uses its own SK16/F2 data (index within
    # 1e-5 of lensim's); the brief's tolerance is 0.01 percentage points, measured 1.7e-5
    # (1e-7 with lensim's glass data in optiland).
    import optiland.backend as be
    from optiland.analysis.distortion_strategies import create_distortion_model
    from optiland.samples.objectives import CookeTriplet

    op = CookeTriplet()
    op.ray_tracer.set_aiming("paraxial" if aiming == "paraxial" else "iterative")
    frac = np.array([0.1, 0.3, 0.5, 0.7, 0.85, 1.0])
    model = create_distortion_model("paraxial", distortion_type="f-tan")
    result = model.compute(op, be.zeros(len(frac)), be.array(frac), 0.55)
    ref = be.to_numpy(model.percent(result, signed=True))
    ours = distortion(load_lens("cooke_triplet"), frac * 20.0, aiming=aiming)["distortion_percent"]
    np.testing.assert_allclose(ours, ref, atol=0.01)
    assert max(abs(v) for v in ours) > 0.05  # not trivially zero: 0.062 % (paraxial), 0.076 % (real)


# ---------------------------------------------------------------- relative illumination


def test_relative_illumination_is_one_on_axis():
    lens = load_lens("cooke_triplet")
    r = relative_illumination(lens, [0.0, 10.0, 20.0], samples=32)
    assert r["relative_illumination"][0] == 1.0
    # without the axis among the fields it is traced for the normalization all the same
    r2 = relative_illumination(lens, [10.0, 20.0], samples=32)
    np.testing.assert_allclose(r2["relative_illumination"], r["relative_illumination"][1:], rtol=1e-12)
    assert 0.8 < r["relative_illumination"][2] < r["relative_illumination"][1] < 1.0


@pytest.mark.parametrize("aiming", ["paraxial", "real"])
def test_thin_lens_with_stop_at_lens_approaches_cos4(aiming):
    # A thin lens with the stop on it and a small aperture: the exit pupil is the lens
    # itself, seen from the image point at angle theta, so RI = cos^4(theta). The residual
    # comes from the lens's thickness (exit pupil and chief ray displaced): measured
    # 6.5e-5 at 30 deg for a 0.02 mm thick lens, 1.6e-3 for 0.5 mm. Tolerance 2e-4.
    angles = [0.0, 10.0, 20.0, 30.0]
    cos4 = np.cos(np.radians(angles)) ** 4
    thin = relative_illumination(_thin_lens(0.02, 0.2), angles, aiming=aiming)["relative_illumination"]
    np.testing.assert_allclose(thin, cos4, rtol=2e-4)
    thick = relative_illumination(_thin_lens(0.5, 0.2), angles, aiming=aiming)["relative_illumination"]
    assert abs(thick[-1] / cos4[-1] - 1) > 10 * abs(thin[-1] / cos4[-1] - 1)  # it approaches cos^4


def _circle_overlap(a: float, b: float, d: float) -> float:
    """Area common to circles of radii a and b whose centres are d apart."""
    if d >= a + b:
        return 0.0
    if d <= abs(a - b):
        return math.pi * min(a, b) ** 2
    alpha = math.acos((d * d + a * a - b * b) / (2 * d * a))
    beta = math.acos((d * d + b * b - a * a) / (2 * d * b))
    return a * a * (alpha - math.sin(2 * alpha) / 2) + b * b * (beta - math.sin(2 * beta) / 2)


def test_clear_aperture_lowers_relative_illumination_by_blocked_fraction():
    # A window with a 5.5 mm clear radius 20 mm in front of a 10 mm stop on a weak lens
    # (f = 1000 mm, so the image-space map is nearly linear over the pupil): the beam of
    # field theta meets the window as the stop disc shifted by 20 tan(theta), and the
    # unblocked fraction is the two discs' overlap. The ratio of the vignetted to the
    # unvignetted RI must equal it; tolerance 2e-3 (64 cells across the pupil with 2 x 2
    # vignetting subsamples, and the 1 % variation of the map's Jacobian over the pupil).
    def system(clear):
        lens = Lens(
            [
                Surface(0.0, 20.0, Air(), clear_radius=clear),
                Surface(1 / 500.0, 0.5, ConstantIndex(1.5), is_stop=True),
                Surface(0.0, 1000.0),
            ],
            aperture_value=10.0,
            fields=[0.0, 15.0],
            wavelengths_um=[0.55],
        )
        lens.surfaces[-1].thickness = 995.0
        return lens

    angles = [0.0, 5.0, 10.0, 15.0]
    free = relative_illumination(system(None), angles)
    vig = relative_illumination(system(5.5), angles)
    expected = [_circle_overlap(5.0, 5.5, 20.0 * math.tan(math.radians(a))) / (math.pi * 25.0) for a in angles]
    assert expected[-1] < 0.45  # a real cut
    ratio = np.array(vig["relative_illumination"]) / np.array(free["relative_illumination"])
    np.testing.assert_allclose(ratio, expected, rtol=2e-3)
    np.testing.assert_allclose(vig["unvignetted_fraction"], expected, rtol=2e-3)
    np.testing.assert_allclose(free["unvignetted_fraction"], 1.0, rtol=1e-12)


def test_relative_illumination_result_fields():
    lens = load_lens(REFERENCE_LENSES / "US08427765-1.zmx", warn=False)
    r = relative_illumination(lens, [0.0, 13.6], samples=24)
    assert r["field_unit"] == "mm" and r["wavelength_um"] == lens.primary_wavelength_um
    # the fields are real image heights: the chief ray lands on them (1e-8 mm)
    np.testing.assert_allclose(r["image_height_mm"], [0.0, 13.6], atol=1e-8)
    n_img = 1.0
    np.testing.assert_allclose(r["n2_projected_solid_angle_sr"], np.array(r["projected_solid_angle_sr"]) * n_img**2)
    # on axis the beam fills the F/2.1 cone: projected solid angle ~ pi / (4 N^2) (8 % slack
    # for the rim rays the clear apertures cut and the working F-number's difference)
    assert r["projected_solid_angle_sr"][0] == pytest.approx(math.pi / (4 * 2.1**2), rel=0.08)
    assert r["relative_illumination"][1] < 0.5  # strongly vignetted at full field


def test_relative_illumination_spectrum_equals_one_wavelength_at_a_time():
    # the bank's form (all wavelengths traced together) against relative_illumination per
    # wavelength: the same to rounding
    from lensim.optics.field_analysis import relative_illumination, relative_illumination_spectrum

    lens = load_lens("cooke_triplet")
    wavelengths = [0.45, 0.55, 0.65]
    field = 0.9 * lens.max_field
    together = relative_illumination_spectrum(lens, field, wavelengths, samples=16)
    one_by_one = [relative_illumination(lens, [field], wl, 16)["relative_illumination"][0] for wl in wavelengths]
    assert together.shape == (3,)
    assert np.allclose(together, one_by_one, rtol=0, atol=1e-12)
    assert 0.3 < together.min() < 1.0
    assert np.array_equal(relative_illumination_spectrum(lens, 0.0, wavelengths, samples=16), np.ones(3))


def test_relative_illumination_spectrum_with_a_shared_axis_is_the_same():
    # the bank traces the on-axis normalization once for all its fields: the same values
    from lensim.optics.field_analysis import axis_solid_angles, relative_illumination_spectrum

    lens = load_lens("cooke_triplet")
    wavelengths = [0.45, 0.55, 0.65]
    axis = axis_solid_angles(lens, wavelengths, samples=16)
    assert axis.shape == (3,) and (axis > 0).all()
    for f in (0.5, 0.9):
        field = f * lens.max_field
        alone = relative_illumination_spectrum(lens, field, wavelengths, samples=16)
        shared = relative_illumination_spectrum(lens, field, wavelengths, samples=16, axis=axis)
        assert np.allclose(shared, alone, rtol=1e-13, atol=0)
        assert not np.allclose(shared, 1.0)


def test_relative_illumination_mirrored_half_equals_the_whole_pupil(monkeypatch):
    # a symmetric lens: the pupil points at px >= 0 traced and mirrored give the values of
    # the whole pupil traced, to rounding (what the bank's fields use)
    from lensim.optics.field_analysis import relative_illumination_spectrum
    from lensim.optics.lens import Lens

    lens = load_lens("cooke_triplet")
    wavelengths = [0.45, 0.65]
    assert lens.meridional_mirror
    half = relative_illumination_spectrum(lens, 0.9 * lens.max_field, wavelengths, samples=16)
    monkeypatch.setattr(Lens, "meridional_mirror", property(lambda self: False))
    whole = relative_illumination_spectrum(lens, 0.9 * lens.max_field, wavelengths, samples=16)
    assert np.allclose(half, whole, rtol=1e-12, atol=0)
    assert half.min() < 0.95
