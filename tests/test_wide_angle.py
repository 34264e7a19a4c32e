"""Real ray aiming at wide angles, against optiland and analytic truth.

The test lens is Laikin's 170 deg F/1.8 camera lens (tests/data/lenses/laikin_170deg.yaml,
85 deg half field). Its real entrance pupil runs far ahead of the paraxial one: rays
aimed at the paraxial pupil miss the lens beyond about 36 deg, and real aiming used to
fail there too. Truth for the chief-ray image heights: optiland 0.6.3's 'robust' ray
aiming on the same prescription with lensim's glass data (optiland_models), recorded
below and recomputed by the slow test; optiland's aim leaves the chief ray up to 8e-7
(of the stop radius) off the stop centre beyond 80 deg, lensim's 1e-15, which bounds the
agreement (1.3e-9 mm at 89.9 deg, 4e-14 mm or better up to 70 deg). Fields, tangential
and sagittal pupil rays are aimed up to 89.9 deg. A field beyond a lens's coverage gets
a one-line error naming the largest field that works (analytic case: a clear aperture).
"""

from __future__ import annotations

import math

import pytest
import torch

from lensim.errors import RayTraceError
from lensim.optics.aiming.rays import chief_ray_image_height, generate_rays, trace_chief_rays
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.paraxial import paraxial_data
from lensim.optics.spot import spot_diagram
from lensim.optics.surfaces import Surface
from lensim.optics.trace import trace
from reference_lenses import REFERENCE_LENSES

WL = 0.5876
# optiland 0.6.3, robust aiming, lensim's glasses (optiland_models.optiland_from_lens):
# chief-ray image height (mm) at 587.6 nm per field (deg)
OPTILAND_CHIEF_MM = {
    20.0: 0.07065371038076931,
    40.0: 0.13652770115229396,
    60.0: 0.19365793158627326,
    70.0: 0.21773714360025087,
    80.0: 0.23792184702268188,
    85.0: 0.24628227745242082,
    88.0: 0.2506849418702891,
    89.0: 0.25204629943495904,
    89.5: 0.2527067711349521,
    89.9: 0.25322539637871144,
}
AGREEMENT_MM = 5e-9


@pytest.fixture(scope="module")
def laikin() -> Lens:
    return load_lens(REFERENCE_LENSES / "laikin_170deg.yaml")


def _chief_heights(lens: Lens, fields: list[float]) -> list[float]:
    para = paraxial_data(lens)
    rays, wl = generate_rays(lens, fields, torch.zeros(1, 2, dtype=torch.float64), [WL], "real", para)
    res = trace_chief_rays(lens, rays, wl, fields, "real", para)
    return res.rays.position[0, :, 0, 1].tolist()


def test_chief_rays_aimed_to_89_9_deg_agree_with_optiland(laikin):
    fields = list(OPTILAND_CHIEF_MM)
    for f, y in zip(fields, _chief_heights(laikin, fields)):
        assert y == pytest.approx(OPTILAND_CHIEF_MM[f], abs=AGREEMENT_MM), f
    # the paraxial entrance pupil does not reach that far: the case is not trivial
    with pytest.raises(RayTraceError, match="chief ray at field 40 deg"):
        chief_ray_image_height(laikin, 40.0, aiming="paraxial")


@pytest.mark.parametrize("field", [60.0, 85.0, 89.9])
def test_tangential_and_sagittal_rays_hit_their_stop_points(laikin, field):
    para = paraxial_data(laikin)
    c = math.sqrt(0.5)
    pupil = torch.tensor(
        [[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0], [c, c], [-c, -c], [0.0, 0.5]], dtype=torch.float64
    )
    rays, wl = generate_rays(laikin, [field], pupil, laikin.wavelengths_um, "real", para)
    assert bool(rays.valid.all())
    at_stop = trace(laikin, rays, wl, end=laikin.stop_index + 1, to_image=False, apertures=False)
    miss = (at_stop.rays.position[..., :2] - pupil * para.stop_semi_diameter_mm).abs().max()
    assert float(miss) < 1e-9 * para.stop_semi_diameter_mm
    assert bool(trace(laikin, rays, wl).rays.valid.all())  # and they reach the image


def _clipped_lens() -> Lens:
    """The stop, 20 mm in front of a plano-convex lens whose plane face has a 5 mm clear
    radius: the chief ray (a straight line from the stop centre) meets that face at
    20 tan(a), so it reaches the image up to atan(5/20) = 14.036 deg exactly."""
    return Lens(
        [
            Surface(0.0, 20.0, is_stop=True),
            Surface(0.0, 2.0, ConstantIndex(1.5), clear_radius=5.0),
            Surface(-1 / 20.0, 30.0),
        ],
        aperture_value=2.0,
        fields=[0.0, 30.0],
        wavelengths_um=[0.55],
        source="clipped.yaml",
    )


def test_beyond_coverage_names_the_largest_field_that_works():
    limit = math.degrees(math.atan(5.0 / 20.0))
    with pytest.raises(RayTraceError) as info:
        spot_diagram(_clipped_lens(), aiming="real")
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(
        "clipped.yaml: fields: the chief ray at field 30 deg is vignetted by the aperture at surfaces[1]"
    )
    assert message.endswith(f"(its chief ray reaches the image up to {math.floor(limit * 100) / 100:g} deg)")


@pytest.mark.slow
def test_optiland_recomputed(laikin):
    import optiland.backend as be
    from optiland.samples.objectives import WideAngle170FOV

    from optiland_models import optiland_from_lens

    ours = optiland_from_lens(laikin, "real", fields_deg=[0.0, 89.9], wavelengths_um=[WL])
    ours.ray_tracer.set_aiming("robust")
    sample = WideAngle170FOV()  # optiland's own transcription and catalogue glasses
    for f, y in OPTILAND_CHIEF_MM.items():
        ours.trace_generic(Hx=0, Hy=f / 89.9, Px=0, Py=0, wavelength=WL)
        assert float(be.to_numpy(ours.surfaces.y[-1])[0]) == pytest.approx(y, abs=1e-12), f
        if f <= 85.0:
            sample.trace_generic(Hx=0, Hy=f / 85.0, Px=0, Py=0, wavelength=WL)
            assert float(be.to_numpy(sample.surfaces.y[-1])[0]) == pytest.approx(y, abs=AGREEMENT_MM), f
