"""The built-in phone lens `phone_wide` and its pairing with the `phone` sensor.

The lens is US 10,101,561 B2 (Newmax Technology), Embodiment 3: Table 5 (lens data) and
Table 6 (aspheric coefficients). The patent states f = 3.35 mm, Fno = 2.2, FOV = 84 deg
and no image height; its thicknesses add up to a total track of 3.916 mm. The stop is the
patent's: a dummy plane at lens 1's vertex, then the stop with thickness -0.160 mm (0.160
mm behind lens 1's vertex, traced sequentially as in Zemax). The asset's description says
why its fields stop at 36 deg (the 42 deg chief ray does not trace) and where the one
clear aperture comes from; the tests below pin those facts.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from lensim.assets import lens_names
from lensim.errors import InputError, RayTraceError
from lensim.optics.aiming.rays import chief_ray_image_height, generate_rays
from lensim.optics.aiming.sampling import hexapolar
from lensim.optics.analysis import first_order_summary
from lensim.optics.lens_file import load_lens
from lensim.optics.materials import WAVELENGTH_D_UM, Air, ModelGlass
from lensim.optics.paraxial import paraxial_data
from lensim.optics.trace import trace
from lensim.render.kernels import check_bank_fits
from lensim.render.mapping import SensorMapping, map_to_sensor
from lensim.sensor.profile import load_sensor
from optiland_models import assert_agrees_with_optiland  # imports optiland only when used

# the patent's stated values (Table 5)
PATENT_EFL_MM = 3.35
PATENT_FNO = 2.2
PATENT_TRACK_MM = 3.916  # sum of Table 5's thicknesses, stop dummy (+0.160 - 0.160) included
PATENT_THICKNESSES = (
    0.160,
    -0.160,
    0.479,
    0.030,
    0.195,
    0.295,
    0.290,
    0.491,
    0.586,
    0.205,
    0.330,
    0.380,
    0.210,
    0.425,
)  # dummy plane, stop, lens 1 ... IR filter
STOP_SURFACE = 1
MAX_FIELD_DEG = 36.0
IMAGE_HEIGHT_MM = 2.4906  # lensim's real chief ray at 36 deg (optiland: the same to 1e-6)
CLEAR_SURFACE = 3  # rear of lens 1, the one clear aperture (0.75 mm)
WAVELENGTHS_UM = (0.48, 0.55, 0.65)


@pytest.fixture(scope="module")
def lens():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a built-in lens loads without notes or substitutions
        return load_lens("phone_wide")


def test_asset_is_listed_and_loads(lens):
    assert "phone_wide" in lens_names()
    assert "10,101,561" in lens.name and "Embodiment 3" in lens.name
    assert lens.fields == [0.0, 25.2, MAX_FIELD_DEG] and lens.field_type == "angle"
    assert [s.thickness for s in lens.surfaces] == list(PATENT_THICKNESSES)
    # the stop lies 0.160 mm behind lens 1's front vertex, reached by a negative thickness
    assert lens.stop_index == STOP_SURFACE and lens.surfaces[STOP_SURFACE].thickness == -0.160
    zv = lens.vertex_z()
    assert zv[STOP_SURFACE] - zv[STOP_SURFACE + 1] == pytest.approx(0.160, abs=1e-12)
    assert zv[STOP_SURFACE + 1] == 0.0  # lens 1's vertex, where the dummy plane is


def test_first_order_data_match_the_patent(lens):
    para = paraxial_data(lens)
    # EFL within 0.5 % of the stated 3.35 mm (lensim: 3.35530 mm at 587.6 nm, +0.16 %)
    assert para.efl_mm == pytest.approx(PATENT_EFL_MM, rel=5e-3)
    assert para.efl_mm == pytest.approx(3.35530, abs=1e-5)
    # F/2.2 (the aperture is given as the F-number), and the on-axis working F-number
    assert para.fno == pytest.approx(PATENT_FNO, rel=1e-12)
    assert para.working_fno == pytest.approx(PATENT_FNO, rel=1e-3)
    assert para.epd_mm == pytest.approx(para.efl_mm / PATENT_FNO, rel=1e-12)
    assert lens.total_track == pytest.approx(PATENT_TRACK_MM, abs=1e-9)
    # the entrance pupil is the stop itself (in object space), 0.160 mm behind lens 1's vertex
    assert para.entrance_pupil_z_mm == pytest.approx(0.160, abs=1e-12)
    # the image plane is the table's, 4.6 um behind the paraxial focus
    assert lens.total_track - para.paraxial_image_z_mm == pytest.approx(0.0046, abs=2e-4)


def test_image_height_at_the_full_field(lens):
    s = first_order_summary(lens, aiming="real")
    assert s["image_height_mm"] == pytest.approx(IMAGE_HEIGHT_MM, abs=2e-4)
    # 2.2 % more than f tan(36 deg): a few per cent of distortion, as phone lenses have
    assert s["image_height_mm"] / (s["efl_mm"] * math.tan(math.radians(MAX_FIELD_DEG))) == pytest.approx(1.0, abs=0.03)
    # the stop is in object space, so real and paraxial aiming are the same rays
    assert first_order_summary(lens, aiming="paraxial")["image_height_mm"] == pytest.approx(
        s["image_height_mm"], abs=1e-9
    )


def test_the_stated_84_degree_field_does_not_trace(lens):
    # why the fields stop at 36 deg: with the patent's own stop position the 42 deg chief
    # ray is totally internally reflected at the rear of lens 5 (surfaces[11]); chief rays
    # trace up to 41.74 deg
    with pytest.raises(RayTraceError, match=r"totally internally reflected at surfaces\[11\]"):
        chief_ray_image_height(lens, 42.0, "real")
    assert chief_ray_image_height(lens, 41.7, "real") == pytest.approx(3.370, abs=1e-3)


def test_even_aspheres_and_model_glasses(lens):
    aspheres = [s for s in lens.surfaces if s.is_aspheric]
    assert len(aspheres) == 10  # both sides of the five lenses
    for s in aspheres:
        assert sorted(s.asphere) == [4, 6, 8, 10, 12, 14] and s.conic != 0.0
    glasses = [s.material for s in lens.surfaces if not isinstance(s.material, Air)]
    models = [(m.nd_value, m.vd_value) for m in glasses if isinstance(m, ModelGlass)]
    assert models == [(1.544, 56.0), (1.650, 21.4), (1.650, 21.4), (1.544, 56.0), (1.544, 56.0)]  # plastics
    # the IR-cut filter's patent pair 1.517 / 64.167 is N-BK7's (what loading the pair gives)
    assert (glasses[-1].name, glasses[-1].catalog) == ("N-BK7", "Schott")
    for s in lens.surfaces:
        if isinstance(s.material, ModelGlass):
            assert float(s.material.index(WAVELENGTH_D_UM)) == pytest.approx(s.material.nd_value, abs=1e-12)
            assert s.material.vd == pytest.approx(s.material.vd_value, rel=1e-9)
    # lens 5's rear surface: the patent's last row of Table 6
    assert lens.surfaces[11].conic == -5.7726 and lens.surfaces[11].asphere[14] == 3.91e-5


@pytest.mark.parametrize("wavelength_um", WAVELENGTHS_UM)
@pytest.mark.parametrize("field_deg", [0.0, 25.2, MAX_FIELD_DEG])
def test_rays_trace_to_the_image(lens, field_deg, wavelength_um):
    para = paraxial_data(lens)
    rays, wl = generate_rays(lens, [field_deg], hexapolar(6), [wavelength_um], "real", para)
    res = trace(lens, rays, wl)
    status, failed_at = res.status.flatten(), res.failed_at.flatten()
    assert int(status[0]) == 0  # the chief ray reaches the image
    assert bool(torch.isfinite(res.rays.position[res.rays.valid]).all())
    lost = status != 0
    # the only rays lost are those outside lens 1's rear clear aperture (vignetted there,
    # or beyond its conic's domain r < 0.85 mm); no ray misses any other surface
    assert set(failed_at[lost].tolist()) <= {CLEAR_SURFACE}
    kept = 1.0 - lost.to(torch.float64).mean().item()
    assert kept == 1.0 if field_deg == 0.0 else kept > 0.8  # 0.87 at 25.2 and 36 deg


def test_phone_sensor_fits_the_image_circle(lens):
    from lensim.psf.bank import BankSettings, get_bank

    sensor = load_sensor("phone")
    w_mm, h_mm = sensor.sensor_size_mm
    assert math.hypot(w_mm, h_mm) / 2 == pytest.approx(2.2973, abs=1e-4)  # IMX219 geometry
    assert math.hypot(w_mm, h_mm) / 2 < IMAGE_HEIGHT_MM
    # a small bank at the phone's pitch covers the whole sensor (the check simulate runs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        settings = BankSettings(
            fields=(0.0, 1.0), wavelengths_nm=(480.0, 550.0, 650.0), pupil_samples=32, kernel_pixels=31
        )
        bank = get_bank(lens, sensor.pixel_pitch_um, settings, memory_only=True)
    assert float(bank.radii_mm[-1]) == pytest.approx(IMAGE_HEIGHT_MM, abs=2e-4)
    check_bank_fits(bank, map_to_sensor(sensor.height, sensor.width, sensor))
    assert bank.fields[0].strehl > 0.8  # 0.83 on axis at 587.6 nm; 0.27 at 36 deg
    # the profile's former 4.8 x 3.6 mm geometry (half-diagonal 3.0 mm) is not covered
    p = sensor.pixel_pitch_um
    big = SensorMapping(round(3.6e3 / p), round(4.8e3 / p), p, -2.4, -1.8)
    with pytest.raises(InputError, match="expected a lens covering the sensor diagonal"):
        check_bank_fits(bank, big)


# ---------------------------------------------------------------- optiland


@pytest.mark.filterwarnings("ignore")
def test_efl_and_rms_spot_agree_with_optiland(lens):
    """optiland 0.6.3 (even aspheres, the negative stop thickness, paraxial aiming; the
    stop is in object space, so every aiming is the same), built by
    optiland_models.optiland_from_lens with lensim's index functions (so the comparison is
    of the tracing, not of two Cauchy fits) and the same clear aperture: EFL, F-number and
    entrance pupil to 1e-9; RMS spot radius at 0 / 0.7 / 1.0 field (its definition: per
    wavelength, about the primary-wavelength chief ray, 6 hexapolar rings) within 1e-4
    (measured 2.3e-5), with the same rays vignetted."""
    pytest.importorskip("optiland")
    ours = assert_agrees_with_optiland(lens, rms_rtol=1e-4)  # (F, W) mm
    # a phone-lens spot: about 1 um on axis, 3.4-3.9 um at 0.7 field, 7.4-9.2 um at full field
    assert ours[0].max() < 1.2e-3 and ours[1].max() < 4.5e-3 and ours[2].max() < 1e-2
