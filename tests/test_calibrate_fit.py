"""As-built calibration recovers known perturbations from edge MTFs (lensim.calibrate.fit)."""

import dataclasses
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


def _element_one_case() -> tuple:
    """The Cooke triplet with focus, a sensor tilt and element 1 decentred: (lens, truth,
    its simulated observations with MTF noise 0.003, seed 2)."""
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.03, "image.tilt_x": 0.2, "e1.decentre_y": -0.04}
    edges = _edges()
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    rng = np.random.default_rng(2)
    measured = [m + rng.normal(0.0, 0.003, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    return lens, truth, Observations(edges, measured, None, wl, w, samples=16)


@pytest.mark.slow
def test_fitting_each_candidate_element_finds_the_one_the_linear_choice_misses():
    # with a sensor tilt and focus on top, the linear model at the nominal lens ranks
    # element 2 first for element 1's decentre, then element 3; fitting every candidate
    # in full keeps element 1 (the smallest residual)
    lens, truth, obs = _element_one_case()
    result = fit(lens, obs, candidates=3, ranking="linear")
    tried = result.lens.as_built["candidates"]
    assert [c["parameters"][-1] for c in tried] == ["e2.decentre_y", "e3.decentre_y", "e1.decentre_y"]
    assert tried[2]["rms"] < min(tried[0]["rms"], tried[1]["rms"])
    assert "e1.decentre_y" in result.values and "e2.decentre_x" not in result.values
    for name, value in truth.items():
        assert result.values[name] == pytest.approx(value, abs=max(4 * result.sigma[name], 0.004)), name
    assert result.rms_after == pytest.approx(tried[2]["rms"])


@pytest.mark.slow
def test_ranking_by_prefits_fits_the_element_the_linear_model_misses():
    # the case above with the defaults (one element fitted in full, ranked by prefits): the
    # linear model at the nominal lens still ranks element 2 first (recorded), the element
    # prefits rank element 1 first, and it is the one fitted
    lens, truth, obs = _element_one_case()
    result = fit(lens, obs)
    ranking = result.lens.as_built["ranking"]
    assert ranking["by"] == "prefit" and ranking["linear"][0]["move"] == "e2.decentre"
    prefits = ranking["prefits"]
    assert [p["move"] for p in prefits] == ["e1.decentre", *[p["move"] for p in prefits[1:]]]
    assert prefits[0]["cost"] < prefits[1]["cost"] and prefits[0]["rms"] < prefits[1]["rms"]
    assert "candidates" not in result.lens.as_built and "e1.decentre_y" in result.values
    for name, value in truth.items():
        assert result.values[name] == pytest.approx(value, abs=max(4 * result.sigma[name], 0.004)), name


def _observed(lens, truth, edges, seed, noise=0.003):
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    rng = np.random.default_rng(seed)
    measured = [m + rng.normal(0.0, noise, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    return Observations(edges, measured, None, wl, w, samples=16)


def test_a_fit_that_would_run_away_stays_within_its_bounds(monkeypatch):
    # a sensor tilted 1 deg (four times the manufacturing bound): without the bound the
    # fit follows it; with it, the tilt ends at the bound and is reported there
    from lensim.calibrate import bounds

    lens = load_lens("cooke_triplet", warn=False)
    obs = _observed(lens, {"image.focus": 0.01, "image.tilt_x": 1.0}, _edges(), 3)
    names = ["image.focus", "image.tilt_x", "image.tilt_y"]
    bounded = fit(lens, obs, names=names)
    assert bounded.values["image.tilt_x"] == pytest.approx(bounds.SENSOR_TILT_BOUND_DEG, rel=1e-3)
    # every value inside its bound (the other tilt may go to its bound too, to make up)
    record = bounded.lens.as_built
    assert all(abs(v) <= record["bounds"][n] * (1 + 1e-9) for n, v in bounded.values.items())
    assert "image.tilt_x" in record["at_bound"] and "image.focus" not in record["at_bound"]
    assert record["bounds"]["image.tilt_x"] == bounds.SENSOR_TILT_BOUND_DEG
    assert record["priors"]["image.tilt_x"] == pytest.approx(0.5 * bounds.SENSOR_TILT_BOUND_DEG)
    assert record["priors"]["image.focus"] is None and record["bounds"]["image.focus"] > 0.1
    monkeypatch.setattr(bounds, "SENSOR_TILT_BOUND_DEG", 5.0)
    free = fit(lens, obs, names=names)
    assert free.values["image.tilt_x"] == pytest.approx(1.0, abs=0.1) and free.lens.as_built["at_bound"] == []


def test_bounds_and_priors_scale_with_the_lens():
    from lensim.calibrate.bounds import bound_of, prior_sigma
    from lensim.calibrate.fit import parameter_scales

    edges = _edges()
    cooke = load_lens("cooke_triplet", warn=False)
    phone = load_lens("phone_wide", warn=False)
    obs = Observations(edges, [], None, [0.55], [1.0])
    k_cooke, k_phone = parameter_scales(cooke, obs), parameter_scales(phone, obs)
    # decentres: tens of micrometres, in proportion to the depth of focus of each lens
    assert 0.01 < bound_of("e1.decentre_x", k_phone) < 0.05 < bound_of("e1.decentre_x", k_cooke) < 0.3
    assert bound_of("e1.decentre_x", k_cooke) / bound_of("e1.decentre_x", k_phone) == pytest.approx(
        k_cooke["focus"] / k_phone["focus"]
    )
    # tilts: a manufacturing range in degrees, with a prior of half of it
    assert bound_of("image.tilt_y", k_phone) == bound_of("image.tilt_y", k_cooke) <= 0.5
    assert prior_sigma("e2.tilt_x", k_phone) == pytest.approx(0.5 * bound_of("e2.tilt_x", k_phone))


def test_what_the_chart_cannot_constrain_is_held_at_nominal_when_chosen():
    # edges on the y axis only: chosen automatically, image.tilt_y is held at nominal
    # (given by name it is refused: test_calibration_refuses_what_the_chart_cannot_see)
    lens = load_lens("cooke_triplet", warn=False)
    edges = _edges(radii=(0.0, 10.0), azimuths=(90.0, 270.0))
    result = fit(lens, _observed(lens, {"image.focus": 0.02}, edges, 4))
    held = [h["parameter"] for h in result.lens.as_built["held_at_nominal"]]
    assert "image.tilt_y" in held and "image.tilt_y" not in result.values
    assert all(
        h["reason"].startswith("the chart's edges cannot constrain it") for h in result.lens.as_built["held_at_nominal"]
    )
    assert result.values["image.focus"] == pytest.approx(0.02, abs=0.003)


def test_an_element_tilt_is_a_candidate_of_the_sensitivity_analysis():
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.02, "e2.tilt_x": 0.15}
    result = fit(lens, _observed(lens, truth, _edges(radii=(0.0, 6.0, 12.0)), 5))
    assert {"e2.tilt_x", "e2.tilt_y"} <= set(result.values)
    assert result.values["e2.tilt_x"] == pytest.approx(0.15, abs=max(4 * result.sigma["e2.tilt_x"], 0.02))
    assert abs(result.values["e2.tilt_y"]) < 0.03
    assert result.values["image.focus"] == pytest.approx(0.02, abs=0.004)


def test_the_pixel_sampled_model_is_the_transfer_of_lensims_pixel_kernel():
    # lensim renders with kernels sampled at the pixel pitch, so an edge's SFR in its
    # images is the transfer of that sampled kernel: the optical MTF times the pixel's
    # sinc plus its aliases (at 2 um phone_wide's MTF at 0.3-0.5 cycles/pixel is high).
    # Measured on the axis: 0.023 from the kernel with the aliases, 0.276 without.
    from lensim.psf.bank import BankSettings, get_bank

    lens, pitch = load_lens("phone_wide", warn=False), 2.0
    bank = get_bank(
        lens, pitch, BankSettings(fields=(0.0, 1.0), wavelengths_nm=(550.0,), pupil_samples=64), memory_only=True
    )
    f = np.array([0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45])
    kernel = bank.fields[0].rgb[1].astype(np.float64)
    for angle, lsf in ((0.0, kernel.sum(0)), (90.0, kernel.sum(1))):
        transfer = np.abs(np.exp(-2j * np.pi * np.outer(f, np.arange(lsf.size))) @ lsf) / lsf.sum()
        edge = Edge(0.0, 0.0, angle, tuple(f / (pitch * 1e-3)))
        sampled = edge_mtf(lens, dataclasses.replace(edge, pitch_um=pitch), [0.55], [1.0], samples=64, aiming="real")
        optical = edge_mtf(lens, edge, [0.55], [1.0], samples=64, aiming="real") * np.sinc(f)
        assert np.max(np.abs(sampled - transfer)) < 0.035
        assert np.max(np.abs(optical - transfer)) > 0.2


@pytest.mark.slow
def test_a_large_element_decentre_is_not_taken_as_focus_and_sensor_tilt():
    # benchmarks/calibration_validation.py's larger_decentre camera in the model world:
    # element 3 decentred 12 um changes the MTF little near nominal (second order), and a
    # fit started there ended at focus +16.4 um, sensor tilt_x -0.25 deg (its bound) and
    # the decentre (0.4, 7.2) um, RMS 0.074 for noise 0.01 (measured without the element
    # starts); the image prefit from +-ELEMENT_START decentres finds the truth's basin
    from lensim.optics.shooting import ShootingSettings, lens_at

    lens = lens_at(load_lens("phone_wide", warn=False), ShootingSettings(object_m=1.0, focus_m=1.0))
    pitch = 3.8266
    f = tuple((np.array([0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28, 0.32]) / (pitch * 1e-3)).tolist())
    edges = []
    for h in (0.0, 0.3, 0.5, 0.7, 0.9):
        for az in (-53.13, 53.13, 126.87, -126.87) if h else (0.0,):
            x, y = -h * 2.296 * math.sin(math.radians(az)), h * 2.296 * math.cos(math.radians(az))
            edges += [Edge(x, y, 0.0, f, pitch), Edge(x, y, 90.0, f, pitch)]
    truth = {"image.focus": 0.006, "e3.decentre_x": 0.012, "image.tilt_y": 0.05}
    wl, w = [0.45, 0.55, 0.65], [0.1, 0.7, 0.2]
    rng = np.random.default_rng(0)
    measured = [m + rng.normal(0, 0.01, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    names = ["image.focus", "image.tilt_x", "image.tilt_y", "e3.decentre_x", "e3.decentre_y"]
    result = fit(lens, Observations(edges, measured, None, wl, w, samples=16), names=names)
    assert result.values["image.focus"] == pytest.approx(0.006, abs=0.0015)
    assert result.values["e3.decentre_x"] == pytest.approx(0.012, abs=0.002)
    assert result.values["e3.decentre_y"] == pytest.approx(0.0, abs=0.002)
    assert result.rms_after < 0.013


def test_a_second_element_move_is_added_at_the_current_fit():
    # a unit with two elements off (as every element of benchmarks/calibration_validation.py's
    # held_out camera is): with elements_fitted=2 the first element is fitted (element 3,
    # ranked by prefits), then the move the linear model at that fit ranks first (element
    # 1's decentre) is added and the set fitted again; both are recovered, and one element
    # alone leaves a residual well above the noise (0.003)
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.02, "e1.decentre_y": -0.04, "e3.decentre_x": 0.04}
    obs = _observed(lens, truth, _edges(radii=(0.0, 6.0, 12.0)), 6)
    two = fit(lens, obs, elements_fitted=2)
    assert [s["move"] for s in two.lens.as_built["steps"]] == ["e1.decentre"]
    for name, value in {**truth, "e1.decentre_x": 0.0, "e3.decentre_y": 0.0}.items():
        assert two.values[name] == pytest.approx(value, abs=max(4 * two.sigma[name], 0.002)), name
    one = fit(lens, obs, names=["image.focus", "image.tilt_x", "image.tilt_y", "e3.decentre_x", "e3.decentre_y"])
    assert two.rms_after < 0.0035 and one.rms_after > 2 * two.rms_after
