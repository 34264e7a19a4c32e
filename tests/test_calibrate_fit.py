"""As-built calibration recovers known perturbations from edge MTFs (lensim.calibrate.fit)."""

import math

import numpy as np
import pytest

from lensim.calibrate.fit import CoverageError, Observations, fit
from lensim.calibrate.model import Edge, edge_mtf, model_mtfs
from lensim.calibrate.tolerances import perturbed_lens
from lensim.optics.lens_file import load_lens
from lensim.psf.mtf import field_otf

FREQ = (10.0, 25.0, 40.0, 55.0, 70.0)


def _edges(radii=(0.0, 10.0), azimuths=(45.0, 135.0, 225.0, 315.0)) -> list[Edge]:
    out = []
    for r in radii:
        for a in azimuths if r else (0.0,):
            x, y = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
            out += [Edge(x, y, 0.0, FREQ), Edge(x, y, 90.0, FREQ)]
    return out


def test_edge_mtf_matches_the_sagittal_and_tangential_mtf():
    lens = load_lens("cooke_triplet", warn=False)
    wl, w = lens.wavelengths_um, lens.wavelength_weights
    probe = lens.with_changes(field_type="paraxial_image_height", fields=[12.0])
    sag, tan = field_otf(probe, 12.0, wl, w, 32, "paraxial").mtf(FREQ)
    # the same MTF through two tracers (the fast one and the calibration model's), whose
    # rays agree to 5e-13 mm: to 7e-12 measured
    assert edge_mtf(lens, Edge(0.0, 12.0, 0.0, FREQ), wl, w) == pytest.approx(sag, abs=1e-10)
    assert edge_mtf(lens, Edge(0.0, 12.0, 90.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-10)
    # on the x axis the radial direction is x; on the diagonal the radial one is 45 deg
    assert edge_mtf(lens, Edge(12.0, 0.0, 0.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-9)
    d = 12.0 / math.sqrt(2.0)
    assert edge_mtf(lens, Edge(-d, d, 135.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-9)


def test_calibration_recovers_a_focus_offset_and_an_element_decentre():
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.025, "e2.decentre_x": 0.02, "e2.decentre_y": -0.01}
    edges = _edges()
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    rng = np.random.default_rng(1)
    measured = [m + rng.normal(0.0, 0.003, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    obs = Observations(edges, measured, None, wl, w, samples=16)
    result = fit(lens, obs, names=list(truth))
    for name, value in truth.items():
        assert result.values[name] == pytest.approx(value, abs=max(4 * result.sigma[name], 0.002)), name
        assert 0 < result.sigma[name] < 0.005
    assert result.rms_after < 0.006 < result.rms_before
    assert result.lens.as_built["parameters"] == pytest.approx(result.values)
    assert result.lens.as_built["uncertainties"] == pytest.approx(result.sigma)


def test_calibration_refuses_what_the_chart_cannot_see():
    # edges on the y axis only: a sensor tilt about y changes nothing there
    lens = load_lens("cooke_triplet", warn=False)
    edges = _edges(radii=(0.0, 10.0), azimuths=(90.0, 270.0))
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    obs = Observations(edges, model_mtfs(lens, edges, wl, w, 16), None, wl, w, samples=16)
    with pytest.raises(CoverageError) as e:
        fit(lens, obs, names=["image.focus", "image.tilt_y"], where="photo.png")
    assert e.value.field == "image.tilt_y" and str(e.value).startswith("photo.png: image.tilt_y: ")
    assert "\n" not in str(e.value)


def test_batched_trace_is_the_single_field_trace():
    from lensim.psf.pupil_field import focus_stacks, pupil_field

    lens = perturbed_lens(load_lens("cooke_triplet", warn=False), {"e2.decentre_x": 0.02})
    probe = lens.with_changes(field_type="paraxial_image_height", fields=[12.0])
    stacks = focus_stacks(probe, [5.0, 12.0], [0.5, 0.6], 16)
    for f, row in zip((5.0, 12.0), stacks, strict=True):
        for w, at in zip((0.5, 0.6), row, strict=True):
            a, b = at(0.0), pupil_field(probe, f, w, 16, "paraxial")
            assert float((a.opl - b.opl).abs().max()) < 1e-12 and float((a.chief - b.chief).abs().max()) < 1e-12


def test_sensor_change_without_a_trace_matches_the_tilted_sensor():
    # the image focus and tilts move the sensor on one trace; the truth traces to the tilted plane
    lens = load_lens("cooke_triplet", warn=False)
    edges = _edges()
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    nominal = np.concatenate(model_mtfs(lens, edges, wl, w, 16))
    for image in ((0.02, 0.1, -0.15), (0.0, 0.3, -0.4)):
        names = ("image.focus", "image.tilt_x", "image.tilt_y")
        exact = np.concatenate(model_mtfs(perturbed_lens(lens, dict(zip(names, image, strict=True))), edges, wl, w, 16))
        fast = np.concatenate(model_mtfs(lens, edges, wl, w, 16, image=image))
        assert np.abs(exact - nominal).max() > 0.05  # the change matters
        assert np.abs(exact - fast).max() < 0.1 * np.abs(exact - nominal).max()
    # the tilts' signs: turned the other way they miss by as much as they change
    flipped = np.concatenate(model_mtfs(lens, edges, wl, w, 16, image=(0.0, -0.3, 0.4)))
    assert np.abs(exact - flipped).max() > 0.5 * np.abs(exact - nominal).max()


def test_degenerate_pairs_are_reported():
    from lensim.calibrate.fit import degenerate_pairs

    cov = np.array([[1.0, 0.95, 0.0], [0.95, 1.0, 0.1], [0.0, 0.1, 1.0]])
    assert degenerate_pairs(["a", "b", "c"], cov) == [{"pair": ["a", "b"], "correlation": 0.95}]


@pytest.mark.slow
def test_fitting_each_candidate_element_finds_the_one_the_linear_choice_misses():
    # with a sensor tilt and focus on top, the linear model at the nominal lens ranks
    # element 2 first for element 1's decentre, then element 3; fitting every candidate
    # in full keeps element 1 (the smallest residual)
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.03, "image.tilt_x": 0.2, "e1.decentre_y": -0.04}
    edges = _edges()
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    rng = np.random.default_rng(2)
    measured = [m + rng.normal(0.0, 0.003, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    result = fit(lens, Observations(edges, measured, None, wl, w, samples=16), candidates=3)
    tried = result.lens.as_built["candidates"]
    assert [c["parameters"][-1] for c in tried] == ["e2.decentre_y", "e3.decentre_y", "e1.decentre_y"]
    assert tried[2]["rms"] < min(tried[0]["rms"], tried[1]["rms"])
    assert "e1.decentre_y" in result.values and "e2.decentre_x" not in result.values
    for name, value in truth.items():
        assert result.values[name] == pytest.approx(value, abs=max(4 * result.sigma[name], 0.004)), name
    assert result.rms_after == pytest.approx(tried[2]["rms"])
