"""The system transfer refreshed at the fitted lens: the outer loop of a calibration.

The fit (lensim.calibrate.fit) models a photo's SFR as the optical MTF times a per-edge
system transfer taken from a simulation of the nominal lens (lensim.calibrate.calibrate.
chart_data). Demosaicking and the tone curve act on the edge's profile, not on its
spectrum, so that transfer changes with the blur: at the true lens the product
over-predicts a photographed chart's SFRs (by 0.06 on the focus_decentre camera of
benchmarks/calibration_validation.py) and the fit absorbs the bias as extra focus or
sensor tilt.

refine() closes the loop. After a fit, the chart is simulated again through the fitted
lens (a Simulator; for photographed charts chart_simulator: simulate_chart without
noise, each quadrant of the frame through the bank of the lens turned to that quadrant's
diagonal when the lens has poses, as the validation photographs its cameras); each edge's
transfer becomes that simulation's SFR over the fitted lens's optical MTF as the fit
models it (refreshed_system), and the same parameters are fitted again from the current
values. At a fixed point the model equals the full simulation at the fitted lens, so the
fit matches the photo as lensim's simulation of the chart would. The rounds stop when no
parameter moves by more than its 1-sigma uncertainty, or after a given number.

The plain iteration converges linearly (one round moved focus_decentre's focus a third of
the way back to the truth). With accelerate, from the second round on the next lens is
the Anderson (depth 1) mix of the last two rounds, in units of the parameters' scales:
exact for a linear contraction, its step beyond the plain one at most EXTRAPOLATION times
the plain step, and not taken where the rounds do not look like a contraction
(next_start).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from lensim.calibrate.fit import Fit, Model, Observations, fit
from lensim.calibrate.tolerances import perturbed_lens
from lensim.optics.lens import Lens
from lensim.render.posed import compose_quadrants, posed_banks

if TYPE_CHECKING:
    from lensim.calibrate.calibrate import ChartData
    from lensim.calibrate.chart import ChartLayout
    from lensim.calibrate.chart_detect import ChartDetection
    from lensim.psf.bank import PSFBank
    from lensim.render.mapping import SensorMapping
    from lensim.sensor.profile import SensorProfile

#: a chart simulated through a lens: the SFR of every observed edge ((F_i,) each, on the
#: edge's frequencies; NaN where the simulation could not measure it)
Simulator = Callable[[Lens], list[np.ndarray]]
#: the largest accelerated step beyond the plain one, in plain steps (and the largest -theta)
EXTRAPOLATION = 4.0
#: below this optical MTF (the fitted lens's) an edge frequency keeps its previous transfer
MIN_OPTICAL_MTF = 0.08


@dataclass
class Refined:
    """A calibration after the transfer refreshes: values and 1-sigma uncertainties (mm or
    deg), the RMS SFR residual of the last refit, the as-built lens (its as_built record
    holds the rounds), the rounds (one dict each: start and fitted values, sigma, RMS
    at the start and after, the largest move in sigmas, seconds simulating and fitting,
    evaluations, traces, how the round's start was chosen) and whether they converged."""

    values: dict[str, float]
    sigma: dict[str, float]
    rms_after: float
    lens: Lens
    rounds: list[dict] = field(default_factory=list)
    converged: bool = False


def chart_simulator(
    photo: np.ndarray,
    layout: ChartLayout,
    detection: ChartDetection,
    data: ChartData,
    sensor: SensorProfile,
    mapping: SensorMapping,
    bank_of: Callable[[Lens], PSFBank],
    kelvin: float = 5000.0,
) -> Simulator:
    """The Simulator of one photographed chart: lensim.calibrate.compare.simulate_chart
    without noise through posed_banks of the lens (quadrants composed), measured at the
    regions of data's edges (lensim.calibrate.chart_measure.measure_chart), each SFR
    interpolated to its edge's frequencies. photo: (3, H, W) sRGB; bank_of: the bank of
    a lens at the photo's settings and the mapping's pitch."""
    from lensim.calibrate.chart_measure import measure_chart
    from lensim.calibrate.compare import simulate_chart

    def simulate(lens: Lens) -> list[np.ndarray]:
        images = {}
        for key, bank in posed_banks(lens, mapping, bank_of).items():
            images[key], _ = simulate_chart(photo, layout, detection, bank, sensor, mapping, noise=False, kelvin=kelvin)
        image = compose_quadrants(images, mapping)
        found = measure_chart(image, layout, detection.homography, data.pitch_um, regions=data.regions)
        p_mm = data.pitch_um * 1e-3
        out = []
        for m, edge in zip(found.edges, data.edges, strict=True):
            f = np.asarray(edge.frequencies_lp_mm) * p_mm
            out.append(np.full(f.shape, np.nan) if m.sfr is None else np.interp(f, m.sfr.freq_cy_px, m.sfr.mtf))
        return out

    return simulate


def refreshed_system(
    obs: Observations, lens: Lens, values: dict[str, float], simulated: np.ndarray
) -> list[np.ndarray]:
    """Each edge's system transfer taken at the lens perturbed by values: the simulated
    SFRs (concatenated, (sum F_i,)) over the optical MTFs the fit models there
    (lensim.calibrate.fit.Model without a transfer); where that MTF is below
    MIN_OPTICAL_MTF or the simulation gave no SFR, the previous transfer (or 1) stays."""
    bare = replace(obs, system=None)
    optical = Model(lens, bare).predict(values)
    sizes = [len(e.frequencies_lp_mm) for e in obs.edges]
    old = np.concatenate(obs.system) if obs.system is not None else np.ones(optical.shape)
    ok = (optical >= MIN_OPTICAL_MTF) & np.isfinite(simulated)
    new = np.where(ok, simulated / np.maximum(optical, 1e-12), old)
    return np.split(new, np.cumsum(sizes)[:-1])


def _vector(values: dict[str, float], names: Sequence[str], scales: dict[str, float]) -> np.ndarray:
    return np.array([values[n] / scales[n] for n in names])


def next_start(rounds: Sequence[dict], accelerate: bool = True) -> tuple[dict[str, float], str]:
    """Where the next round starts, and how it was chosen: the last round's fitted values
    ("plain"), or with accelerate and two rounds done with the same parameters their
    Anderson (depth 1) mix in units of the parameters' scales ("anderson": u = g1 - theta
    (g1 - g0), theta = f1.(f1 - f0) / |f1 - f0|^2, f = g - u the rounds' moves). For a
    linear map of rate rho in (-1, 1), theta = rho / (rho - 1) lies in (-inf, 0.5): a
    theta outside [-EXTRAPOLATION, 0.5) means the rounds do not contract alike in every
    parameter (a parameter drifting while another converges), and the plain start is
    taken; the step beyond the plain one is also limited to EXTRAPOLATION plain steps."""
    last = rounds[-1]
    same = len(rounds) >= 2 and len({frozenset(r[k]) for r in rounds[-2:] for k in ("start", "values")}) == 1
    if not accelerate or not same:
        return dict(last["values"]), "plain"
    names, scales = list(last["values"]), last["scales"]
    u1, g1 = _vector(last["start"], names, scales), _vector(last["values"], names, scales)
    u0, g0 = _vector(rounds[-2]["start"], names, scales), _vector(rounds[-2]["values"], names, scales)
    f1, df = g1 - u1, (g1 - u1) - (g0 - u0)
    theta = float(f1 @ df) / max(float(df @ df), 1e-300)
    if not -EXTRAPOLATION <= theta < 0.5:
        return dict(last["values"]), "plain"
    extra = -theta * (g1 - g0)
    limit = EXTRAPOLATION * float(np.linalg.norm(f1))
    norm = float(np.linalg.norm(extra))
    if norm > limit:
        extra *= limit / norm
    u = g1 + extra
    return {n: float(v * scales[n]) for n, v in zip(names, u, strict=True)}, "anderson"


def _moved_sigma(start: dict[str, float], values: dict[str, float], sigma: dict[str, float]) -> float:
    """The largest move of a parameter in its 1 sigma; inf when the parameters changed."""
    if set(start) != set(values):
        return math.inf
    return max(abs(values[n] - start[n]) / max(sigma[n], 1e-300) for n in start)


def _round(
    lens: Lens, obs: Observations, simulators: Sequence[Simulator], start: dict[str, float], options: dict
) -> dict:
    """One refresh: simulate through the lens at start, refresh the transfers, refit
    (options: where, and candidates: with more than 1, every round chooses the element
    again among that many, each fitted from start: lensim.calibrate.fit.fit)."""
    t0 = time.perf_counter()
    moved = perturbed_lens(lens, start)
    simulated = np.concatenate([s for sim in simulators for s in sim(moved)])
    system = refreshed_system(obs, lens, start, simulated)
    t_sim = time.perf_counter() - t0
    new = replace(obs, system=system)
    measured = np.concatenate(obs.measured)
    rms_start = float(np.sqrt(np.mean((Model(lens, new).predict(start) - measured) ** 2)))
    k = options.get("candidates", 1)
    where = options.get("where", "chart")
    result = fit(lens, new, list(start), where=where, start=start, candidates=k, add_moves=options.get("moves", 0))
    record = {
        "start": dict(start),
        "values": result.values,
        "sigma": result.sigma,
        "scales": result.lens.as_built["scales"],
        "rms_at_start": rms_start,
        "rms_after": result.rms_after,
        "moved_sigma": _moved_sigma(start, result.values, result.sigma),
        "simulate_s": t_sim,
        "fit_s": result.seconds,
        "evaluations": result.evaluations,
        "traces": result.traces,
    }
    for key in ("candidates", "at_bound", "held_at_nominal", "bounds", "priors", "steps"):
        if key in result.lens.as_built:
            record[key] = result.lens.as_built[key]
    return record


def refine(
    lens: Lens,
    obs: Observations,
    simulators: Sequence[Simulator],
    first: Fit,
    rounds: int = 4,
    where: str = "chart",
    accelerate: bool = True,
    done: Sequence[dict] = (),
    on_round: Callable[[list[dict]], None] | None = None,
    candidates: int = 1,
    moves: int = 0,
) -> Refined:
    """Refresh the system transfer at the fitted lens and refit, up to `rounds` times (the
    module docstring). lens: the nominal lens the fit perturbs; obs: the observations of
    the first fit (all photos, in the simulators' order); simulators: one per photo;
    first: the fit to start from (its parameters are kept). done: rounds recorded by an
    earlier call (on_round's list), continued from; on_round: called with the rounds
    after each one (a long calibration checkpoints them). candidates: with more than 1,
    each round fits that many elements' decentres (the best-ranked in the linear model,
    lensim.calibrate.fit.candidate_sets) from the current image values and keeps the
    smallest residual, so a choice the nominal transfer biased can change. moves: element
    moves added in the first round, after its transfer refresh (lensim.calibrate.fit.fit's
    add_moves): chosen at a refreshed transfer, not the nominal one the first fit had."""
    history = [dict(r) for r in done]
    converged = bool(history) and history[-1]["moved_sigma"] < 1.0
    while not converged and len(history) < rounds:
        start, how = next_start(history, accelerate) if history else (dict(first.values), "first fit")
        options = {"where": where, "candidates": candidates, "moves": moves if not history else 0}
        record = _round(lens, obs, simulators, start, options)
        history.append(record | {"round": len(history) + 1, "start_from": how})
        converged = record["moved_sigma"] < 1.0
        if on_round is not None:
            on_round(history)
    if not history:
        return Refined(first.values, first.sigma, first.rms_after, first.lens)
    end = history[-1]
    base = {k: v for k, v in first.lens.as_built.items() if k != "parameters"}
    record = base | {
        "uncertainties": end["sigma"],
        "rms_residual_after": end["rms_after"],
        "refresh": {"rounds": history, "converged": converged},
        **{k: end[k] for k in ("at_bound", "held_at_nominal", "bounds", "priors") if k in end},
    }
    as_built = perturbed_lens(lens, end["values"], record)
    return Refined(end["values"], end["sigma"], end["rms_after"], as_built, history, converged)
