"""The system transfer refreshed at the fitted lens (lensim.calibrate.refresh): where the
nominal transfer biases the fit, the refreshed rounds bring it back to the truth."""

import math

import numpy as np
import pytest

from lensim.calibrate.fit import Observations, fit
from lensim.calibrate.model import Edge, model_mtfs
from lensim.calibrate.refresh import next_start, refine
from lensim.calibrate.tolerances import perturbed_lens
from lensim.optics.lens_file import load_lens
from lensim.render.mapping import SensorMapping
from lensim.render.posed import MIRROR, compose_quadrants, mirrored_pixels, quadrant_azimuths

FREQ = (10.0, 25.0, 40.0, 55.0, 70.0)
SAMPLES = 16


def _edges() -> list[Edge]:
    out = [Edge(0.0, 0.0, 0.0, FREQ), Edge(0.0, 0.0, 90.0, FREQ)]
    for r in (12.0,):
        for a in (45.0, 135.0, 225.0, 315.0):
            x, y = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
            out += [Edge(x, y, 0.0, FREQ), Edge(x, y, 90.0, FREQ)]
    return out


def _camera(lens, edges, wl, w):
    """A 'pipeline' whose SFR is not the optical MTF times a fixed transfer: a pixel-like
    factor times the optical MTF to the power 1.5 (a tone curve steepens blurred edges
    less than sharp ones)."""

    def simulate(moved):
        mtfs = model_mtfs(moved, edges, wl, w, SAMPLES)
        return [np.sinc(np.asarray(e.frequencies_lp_mm) / 300.0) * m**1.5 for e, m in zip(edges, mtfs, strict=True)]

    return simulate


@pytest.mark.parametrize("candidates", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_refreshed_transfer_removes_the_bias_of_the_nominal_one(candidates):
    lens = load_lens("cooke_triplet", warn=False)
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    edges = _edges()
    truth = {"image.focus": 0.03, "e2.decentre_x": 0.02}
    names = ["image.focus", "e2.decentre_x", "e2.decentre_y"]
    simulate = _camera(lens, edges, wl, w)
    measured = simulate(perturbed_lens(lens, truth))
    nominal_sim = simulate(lens)
    optical = model_mtfs(lens, edges, wl, w, SAMPLES)
    system = [s / np.maximum(o, 1e-12) for s, o in zip(nominal_sim, optical, strict=True)]
    obs = Observations(edges, measured, system, wl, w, samples=SAMPLES)
    first = fit(lens, obs, names)
    # the nominal transfer biases the fit (the case must be one where refreshing matters)
    assert abs(first.values["image.focus"] - truth["image.focus"]) > 0.004
    refined = refine(lens, obs, [simulate], first, rounds=6, candidates=candidates)
    assert refined.converged and 2 <= len(refined.rounds) <= 6
    # with candidates, every round tried that many elements' decentres and kept the true one
    assert all(len(r.get("candidates", [None])) == candidates for r in refined.rounds)
    assert all("e2.decentre_x" in r["values"] for r in refined.rounds)
    for name in names:
        assert refined.values[name] == pytest.approx(truth.get(name, 0.0), abs=0.002 if "focus" in name else 0.003), (
            name
        )
    assert refined.rms_after < 0.5 * first.rms_after
    record = refined.lens.as_built["refresh"]
    assert record["converged"] and len(record["rounds"]) == len(refined.rounds)
    assert refined.lens.as_built["parameters"] == pytest.approx(refined.values)
    assert all(r["simulate_s"] >= 0 and r["evaluations"] > 0 for r in refined.rounds)
    # resuming from the recorded rounds does no more work and gives the same answer
    again = refine(lens, obs, [lambda _: pytest.fail("simulated again")], first, rounds=6, done=refined.rounds)
    assert again.values == refined.values


def test_anderson_start_is_exact_for_a_linear_contraction():
    star, rho = np.array([0.006, 0.004]), 0.73
    names, scales = ["image.focus", "e3.decentre_x"], {"image.focus": 0.002, "e3.decentre_x": 0.002}
    u = np.array([0.0126, -0.001])
    rounds = []
    for _ in range(2):
        g = star + rho * (u - star)
        rounds.append(
            {
                "start": dict(zip(names, u.tolist(), strict=True)),
                "values": dict(zip(names, g.tolist(), strict=True)),
                "scales": scales,
            }
        )
        u = g
    start, how = next_start(rounds)
    assert how == "anderson"
    assert [start[n] for n in names] == pytest.approx(star.tolist(), abs=1e-12)
    plain, how = next_start(rounds, accelerate=False)
    assert how == "plain" and plain == rounds[-1]["values"]
    # a parameter that drifts by the same step each round is no contraction: plain start
    drift = [
        {"start": {"image.focus": 0.0}, "values": {"image.focus": 0.001}, "scales": {"image.focus": 0.002}},
        {"start": {"image.focus": 0.001}, "values": {"image.focus": 0.00205}, "scales": {"image.focus": 0.002}},
    ]
    assert next_start(drift)[1] == "plain"
    # a round that changed the element: plain start from its values
    switched = [
        {"start": {"e1.decentre_x": 0.0}, "values": {"e3.decentre_x": 0.005}, "scales": {"e3.decentre_x": 0.002}},
        {"start": {"e3.decentre_x": 0.005}, "values": {"e3.decentre_x": 0.004}, "scales": {"e3.decentre_x": 0.002}},
    ]
    assert next_start(switched) == ({"e3.decentre_x": 0.004}, "plain")


def test_quadrants_are_composed_where_their_azimuths_are():
    mapping = SensorMapping(4, 6, 1000.0, -3.0, -2.0)
    az = quadrant_azimuths(mapping)
    # upper-right corner (x > 0, y < 0 on the rows' axis) and the others, each in its own quadrant
    assert az["ur"] == pytest.approx(math.degrees(math.atan2(-2.0, -2.0)))
    assert az["ll"] == pytest.approx(math.degrees(math.atan2(3.0, 1.0)))
    images = {k: np.full((3, 4, 6), i, dtype=float) for i, k in enumerate(("ur", "lr", "ul", "ll"))}
    out = compose_quadrants(images)
    assert out[0, 0, 5] == 0 and out[0, 3, 5] == 1 and out[0, 0, 0] == 2 and out[0, 3, 0] == 3


def test_mirrored_halves_of_the_quadrants_come_from_the_mirrored_lens():
    # a bank along +y gives its kernel mirrored about +y where azimuth_turn says so (pixel
    # (3, 3): 71.6 deg from +x, 18.4 deg clockwise of +y); those pixels take the image of
    # the mirrored lens's bank (posed_banks), the others the lens's own
    mapping = SensorMapping(4, 6, 1000.0, -3.0, -2.0)
    mirrored = mirrored_pixels(mapping)
    assert mirrored[3, 3] and not mirrored[3, 2] and not mirrored[3, 5] and mirrored[0, 5]
    images = {k: np.full((3, 4, 6), i, dtype=float) for i, k in enumerate(("ur", "lr", "ul", "ll"))}
    images |= {k + MIRROR: np.full((3, 4, 6), 10 + i, dtype=float) for i, k in enumerate(("ur", "lr", "ul", "ll"))}
    out = compose_quadrants(images, mapping)
    assert out[0, 3, 3] == 11 and out[0, 3, 5] == 1 and out[0, 0, 5] == 10 and out[0, 3, 2] == 3
    with pytest.raises(ValueError):
        compose_quadrants(images)


def test_the_mirrored_lens_has_the_mirrored_psf():
    # x -> -x: the x decentres and the tilts about y change sign; measured NCC 1 - 3e-14
    # against the flipped PSF, 0.48 unflipped (a decentred, tilted lens on a tilted sensor)
    from lensim.calibrate.tolerance_report import mirrored_lens
    from lensim.psf.compute import compute_psf

    lens = load_lens("cooke_triplet", warn=False)
    posed = perturbed_lens(
        lens, {"e2.decentre_x": 0.05, "e2.decentre_y": 0.02, "e3.tilt_y": 0.3, "e1.tilt_x": 0.2, "image.tilt_y": 0.3}
    )

    def psf(x):
        return compute_psf(x, 0.75, 0.55, pupil_samples=32, grid=33, spacing_um=2.0, aiming="real").data.astype(float)

    a, m = psf(posed), psf(mirrored_lens(posed))
    assert np.max(np.abs(a[:, ::-1] - m)) < 1e-5 * a.max()
    assert np.max(np.abs(a - m)) > 0.1 * a.max()


def test_a_move_added_after_the_refresh_is_chosen_at_the_refreshed_transfer():
    # refine(moves=1): the first round refreshes the transfer, refits the first fit's set
    # and adds the move the linear model at that fit ranks first (element 1's decentre,
    # which the first fit did not have); the later rounds refit the grown set
    lens = load_lens("cooke_triplet", warn=False)
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    edges = _edges()
    truth = {"image.focus": 0.03, "e2.decentre_x": 0.02, "e1.decentre_y": -0.03}
    simulate = _camera(lens, edges, wl, w)
    optical = model_mtfs(lens, edges, wl, w, SAMPLES)
    system = [s / np.maximum(o, 1e-12) for s, o in zip(simulate(lens), optical, strict=True)]
    obs = Observations(edges, simulate(perturbed_lens(lens, truth)), system, wl, w, samples=SAMPLES)
    first = fit(lens, obs, ["image.focus", "e2.decentre_x", "e2.decentre_y"])
    refined = refine(lens, obs, [simulate], first, rounds=4, moves=1)
    assert [s["move"] for s in refined.rounds[0]["steps"]] == ["e1.decentre"]
    assert all("steps" not in r for r in refined.rounds[1:]) and len(refined.rounds) >= 2
    for name, value in truth.items():
        assert refined.values[name] == pytest.approx(value, abs=0.003), name
    assert refined.rms_after < 0.3 * first.rms_after
