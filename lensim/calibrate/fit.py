"""As-built calibration: fit the image plane, sensor tilt and the decentre of the most
sensitive elements to slanted-edge MTFs measured on a chart.

The model of an observed SFR is the lens's optical MTF across the edge
(lensim.calibrate.model.edge_mtf) times the system's own transfer at those frequencies
(pixel aperture, demosaicking, the develop chain: what the simulation of the nominal lens
adds to the nominal optical MTF, so it cancels out; 1 when the observations are optical
MTFs). Parameters are perturbation names (lensim.calibrate.tolerances): "image.focus"
(mm), "image.tilt_x" / "image.tilt_y" (deg), "eK.decentre_x" / "eK.decentre_y" (mm),
"eK.tilt_x" / "eK.tilt_y" (deg).

The search is scipy.optimize.least_squares (trust region reflective) with forward-
difference Jacobians (Model): a change of an element traces the lens again (one batched
trace of every edge's point, lensim.calibrate.model.trace_points: about 2 s for 17 points
and 3 wavelengths), a change of the image plane only moves and turns the sensor on the
last trace (no trace; lensim.calibrate.model.mtfs_from, about 0.4 s). The MTF alone
hardly tells a focus shift's sign, so the image parameters are first fitted alone from
both signs of focus (and with each element parameter at +-ELEMENT_START: a decentre changes
the MTF at second order near nominal) and the full fit runs from the best start of each
sign, the smaller residual kept (lensim.calibrate.search). The element fitted is the one
whose prefits leave the smallest objective (search.prefit_ranking; the linear model at
the nominal lens, element_ranking, is recorded beside it). Further element moves (with
elements_fitted above 1: a unit whose every element is a little off) are added one after
another, each the decentre or tilt, of any element, that the linear model at the current
fit ranks first (_add_moves: there a move acts at first order), and the set is fitted
again from the current values (as_built.steps records them). Uncertainties come from the
Jacobian at the optimum: cov = s^2 (J^T J)^-1, s^2 the residual variance. Before
fitting, a parameter the chart's edges cannot constrain (its predicted 1-sigma
uncertainty at the assumed noise is above its scale) is refused with a CoverageError
naming it (and the parameter it is tied to); pairs correlated beyond DEGENERATE are
reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from lensim.calibrate.bounds import record as bounds_record
from lensim.calibrate.model import Edge, mtfs_from, trace_points
from lensim.calibrate.search import IMAGE_PARAMETERS, NOISE_MTF, Run, prefit_ranking, solve, starts
from lensim.calibrate.tolerances import elements, perturbed_lens
from lensim.errors import InputError
from lensim.optics.lens import Lens

#: element tilt scale (deg); the other scales follow the lens (parameter_scales)
ELEMENT_TILT_DEG = 0.05
KINDS = ("focus", "tilt_x", "tilt_y", "decentre_x", "decentre_y")
#: the parameters of each element the fit may move
ELEMENT_KINDS = ("decentre_x", "decentre_y", "tilt_x", "tilt_y")
#: how an element may move in the fit (each with its _x and _y parameter)
ELEMENT_MOVES = ("decentre", "tilt")
#: an element's tilt is fitted instead of its decentre when it leaves less than this
#: fraction of the decentre's residual in the linear model (element_ranking)
TILT_PREFERENCE = 0.9
#: |correlation| above which two fitted parameters are reported as a degenerate pair
DEGENERATE = 0.9

Progress = Callable[[int, int], None]


class CoverageError(InputError):
    """The chart's edges cannot constrain a parameter (names it and why)."""


@dataclass
class Observations:
    """What the chart gave: edges, their measured SFRs (each (F,)) and the system transfer
    (each (F,), or None for 1); wavelengths (um) and weights of the camera."""

    edges: list[Edge]
    measured: list[np.ndarray]
    system: list[np.ndarray] | None
    wavelengths_um: list[float]
    weights: list[float]
    samples: int = 32
    aiming: str = "paraxial"


@dataclass
class Fit:
    """A calibration: fitted values and 1-sigma uncertainties per parameter (mm or deg),
    the sensitivity table used to pick them, RMS residuals before and after (MTF), the
    as-built lens, function evaluations and seconds."""

    values: dict[str, float]
    sigma: dict[str, float]
    sensitivity: list[dict]
    rms_before: float
    rms_after: float
    lens: Lens
    evaluations: int
    seconds: float
    correlation: list[list[float]] = field(default_factory=list)
    degenerate: list[dict] = field(default_factory=list)
    traces: int = 0


def parameter_scales(lens: Lens, obs: Observations) -> dict[str, float]:
    """The scale of each parameter kind: the size of an as-built error that matters.
    focus and decentres: the depth of focus 2 lambda N^2 (mm, working F-number, mean
    wavelength); the sensor's tilts: the angle (deg) that defocuses the outermost edge by
    that much; element tilts: ELEMENT_TILT_DEG."""
    import math

    from lensim.optics.paraxial import paraxial_data

    wl = sum(w * x for w, x in zip(obs.weights, obs.wavelengths_um, strict=True)) / max(sum(obs.weights), 1e-300)
    dof = 2.0 * wl * 1e-3 * paraxial_data(lens).working_fno ** 2
    r = max([e.radius_mm for e in obs.edges] + [1e-6])
    return {
        "focus": dof,
        "decentre_x": dof,
        "decentre_y": dof,
        "sensor_tilt": math.degrees(math.atan(dof / r)),
        "element_tilt": ELEMENT_TILT_DEG,
    }


def scale_of(name: str, scales: dict[str, float]) -> float:
    """The scale (mm or deg) of a parameter name (scales: parameter_scales)."""
    target, _, kind = name.partition(".")
    if kind not in KINDS:
        raise InputError(None, "parameters", f"expected kinds {', '.join(KINDS)}, got {name!r}")
    if kind.startswith("tilt"):
        return scales["sensor_tilt" if target == "image" else "element_tilt"]
    return scales[kind]


class Model:
    """The model SFRs of the observations for parameter values (name -> mm or deg): the
    element parameters change the traced lens (one batched trace of the edges' points,
    lensim.calibrate.model.trace_points, kept for the last CACHE value sets), the image
    ones only move and turn the sensor on that trace (lensim.calibrate.model.mtfs_from,
    no trace). Counts traces and evaluations."""

    CACHE = 8

    def __init__(self, lens: Lens, obs: Observations) -> None:
        self.lens, self.obs = lens, obs
        self.traces = 0
        self.evaluations = 0
        self._stacks: dict[tuple, dict] = {}

    def _traced(self, element: dict[str, float]) -> dict:
        key = tuple(sorted(element.items()))
        if key not in self._stacks:
            moved = perturbed_lens(self.lens, element) if element else self.lens
            if len(self._stacks) >= self.CACHE:
                self._stacks.pop(next(iter(self._stacks)))
            o = self.obs
            self._stacks[key] = trace_points(moved, o.edges, o.wavelengths_um, o.samples, o.aiming)
            self.traces += 1
        return self._stacks[key]

    def predict(self, values: dict[str, float]) -> np.ndarray:
        """The model SFRs of every edge, concatenated ((sum F_i,))."""
        self.evaluations += 1
        element = {n: v for n, v in values.items() if not n.startswith("image.") and v != 0.0}
        image = tuple(values.get(n, 0.0) for n in IMAGE_PARAMETERS)
        o = self.obs
        mtfs = mtfs_from(self._traced(element), o.edges, o.weights, image)
        if o.system is not None:
            mtfs = [m * s for m, s in zip(mtfs, o.system, strict=True)]
        return np.concatenate(mtfs)


def sensitivity_table(
    model: Model, base: np.ndarray, scales: dict[str, float], progress: Progress | None = None
) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Every candidate parameter (image focus and tilts, each element's decentre and tilt)
    with the RMS change of the model SFRs it makes at its scale, largest first; and each
    one's change (the Jacobian column in units of its scale)."""
    names = list(IMAGE_PARAMETERS)
    for k in range(1, len(elements(model.lens)) + 1):
        names += [f"e{k}.{kind}" for kind in ELEMENT_KINDS]
    rows, columns = [], {}
    for i, name in enumerate(names):
        step = scale_of(name, scales)
        columns[name] = model.predict({name: step}) - base
        rows.append({"parameter": name, "scale": step, "rms_change": float(np.sqrt(np.mean(columns[name] ** 2)))})
        if progress:
            progress(i + 1, len(names))
    return sorted(rows, key=lambda r: -r["rms_change"]), columns


def _move_cost(gap: np.ndarray, columns: dict[str, np.ndarray], chosen: Sequence[str], move: str) -> float:
    """The squared residual of gap that a move ("e2.decentre": its x and y) leaves when
    fitted with `chosen` in the linear model (the columns)."""
    a = np.stack([columns[n] for n in [*chosen, f"{move}_x", f"{move}_y"]], axis=1)
    coef, *_ = np.linalg.lstsq(a, gap, rcond=None)
    return float(np.sum((a @ coef - gap) ** 2))


def element_costs(gap: np.ndarray, columns: dict[str, np.ndarray], chosen: Sequence[str]) -> list[tuple[float, str]]:
    """(squared residual, move) of each element not yet in `chosen`, smallest first: the
    move ("e2.decentre" or "e2.tilt": that element's x and y parameters) is the one of
    ELEMENT_MOVES whose columns are known and leave the smaller residual of gap =
    measured - nominal model when fitted with `chosen` in the linear model; ties keep the
    elements' order. A tilt is chosen over the decentre only when its residual is below
    TILT_PREFERENCE times the decentre's: at the nominal lens the two moves of a thin
    element change the edges nearly alike."""
    targets = sorted({n.partition(".")[0] for n in columns if n.startswith("e")}, key=lambda t: int(t[1:]))
    costs = []
    for t in targets:
        if any(n.partition(".")[0] == t for n in chosen):
            continue
        cost = {
            m: _move_cost(gap, columns, chosen, f"{t}.{m}")
            for m in ELEMENT_MOVES
            if f"{t}.{m}_x" in columns and f"{t}.{m}_y" in columns
        }
        if not cost:
            continue
        tilt = "decentre" not in cost or cost.get("tilt", np.inf) < TILT_PREFERENCE * cost["decentre"]
        move = "tilt" if tilt else "decentre"
        costs.append((cost[move], f"{t}.{move}"))
    return sorted(costs, key=lambda c: c[0])


def move_costs(gap: np.ndarray, columns: dict[str, np.ndarray], chosen: Sequence[str]) -> list[tuple[float, str]]:
    """(squared residual, move) of every element move ("e2.decentre", "e1.tilt": its x and
    y parameters) whose columns are known and that is not in `chosen`, the tilt of a chosen
    element's decentre included, fitted with `chosen` in the linear model; smallest first
    (ties keep the elements' order, decentre before tilt)."""
    moves = {n.rpartition("_")[0] for n in columns if n.startswith("e") and n not in chosen}
    known = [
        m
        for m in sorted(moves, key=lambda m: (int(m[1 : m.index(".")]), m))
        if f"{m}_x" in columns and f"{m}_y" in columns and f"{m}_x" not in chosen and f"{m}_y" not in chosen
    ]
    return sorted(((_move_cost(gap, columns, chosen, m), m) for m in known), key=lambda c: c[0])


def element_ranking(gap: np.ndarray, columns: dict[str, np.ndarray], chosen: Sequence[str]) -> list[str]:
    """The element moves of element_costs (one per element not in `chosen`), ordered by
    the residual they leave in the linear model at the nominal lens, smallest first."""
    return [m for _, m in element_costs(gap, columns, chosen)]


def choose_parameters(
    gap: np.ndarray,
    columns: dict[str, np.ndarray],
    elements_fitted: int,
    first: str | None = None,
    image: Sequence[str] = IMAGE_PARAMETERS,
) -> list[str]:
    """The image parameters (default: focus and tilts), and the decentres or tilts (x, y)
    of the `elements_fitted` elements that, fitted with them in the linear model (the
    columns), leave the smallest residual of gap (measured - nominal model), chosen one
    after the other (element_ranking); first: the first element's move ("e2.decentre"),
    when it is given."""
    chosen = list(image)
    for i in range(elements_fitted):
        ranking = [first] if i == 0 and first is not None else element_ranking(gap, columns, chosen)
        if not ranking:
            break
        chosen += [f"{ranking[0]}_x", f"{ranking[0]}_y"]
    return chosen


def candidate_sets(
    gap: np.ndarray,
    columns: dict[str, np.ndarray],
    elements_fitted: int,
    candidates: int,
    image: Sequence[str] = IMAGE_PARAMETERS,
    firsts: Sequence[str] | None = None,
) -> list[list[str]]:
    """The parameter sets fitted in full: choose_parameters with each of the `candidates`
    best-ranked first elements' moves (firsts, best first; default element_ranking: the
    linear model), the further elements chosen by the linear model."""
    if elements_fitted < 1:
        return [choose_parameters(gap, columns, elements_fitted, image=image)]
    ranked = list(element_ranking(gap, columns, image) if firsts is None else firsts)
    if not ranked:
        return [choose_parameters(gap, columns, elements_fitted, image=image)]
    return [choose_parameters(gap, columns, elements_fitted, t, image) for t in ranked[: max(candidates, 1)]]


def _ranked_firsts(model: Model, gap: np.ndarray, image: Sequence[str], context: dict) -> list[str]:
    """The first element's moves, best first: by the linear model at the nominal lens
    (element_costs) when context["ranking"] is "linear" or the image focus is not fitted;
    else by their image prefits (lensim.calibrate.search.prefit_ranking; every element
    prefitted). Records both rankings in context["ranking_record"]: per move the linear
    model's residual RMS (MTF) and, by prefits, each one's objective and RMS (MTF), and
    the prefits' seconds, traces and model evaluations."""
    linear = element_costs(gap, context["columns"], image)
    record: dict = {"by": "linear", "linear": [{"move": m, "rms": float(np.sqrt(c / gap.size))} for c, m in linear]}
    context["ranking_record"] = record
    if context["ranking"] == "linear" or "image.focus" not in image or not linear:
        return [m for _, m in linear]
    t0, traces, evaluations = time.perf_counter(), model.traces, model.evaluations
    rows = prefit_ranking(model, [m for _, m in linear], image, context, lambda n: scale_of(n, context["kinds"]))
    record.update(by="prefit", prefits=rows, seconds=time.perf_counter() - t0, traces=model.traces - traces)
    record["evaluations"] = model.evaluations - evaluations
    return [r["move"] for r in rows]


def _parameter_sets(
    model: Model, names: Sequence[str] | None, elements_fitted: int, candidates: int, context: dict
) -> tuple[list[dict], list[list[str]]]:
    """The sensitivity table (empty when names are given and candidates is 1) and the
    parameter sets to fit: names as given; or candidate_sets of the first element's move
    ranked by _ranked_firsts, with the image parameters of names when they are given; the
    further moves (elements_fitted - 1, or those of names beyond the first: the moves are
    chosen again) are added after the fit by _add_moves (context["further_moves"])."""
    if names is not None and candidates <= 1:
        return [], [list(names)]
    table, context["columns"] = sensitivity_table(model, context["base"], context["kinds"], context.get("progress"))
    image = IMAGE_PARAMETERS if names is None else [n for n in names if n.startswith("image.")]
    count = elements_fitted if names is None else len({n.rpartition("_")[0] for n in names if n not in image})
    context["further_moves"] = max(count - 1, 0)
    gap = context["measured"] - context["base"]
    firsts = _ranked_firsts(model, gap, image, context) if count >= 1 else None
    return table, candidate_sets(gap, context["columns"], min(count, 1), candidates, image, firsts)


def _covariance(jac: np.ndarray, noise: float) -> np.ndarray:
    """(J^T J / noise^2)^-1 with a tiny ridge (a parameter that changes nothing keeps an
    enormous variance); inf where singular."""
    info = jac.T @ jac / noise**2
    try:
        return np.linalg.inv(info + 1e-9 * np.eye(info.shape[0]))
    except np.linalg.LinAlgError:
        return np.full(info.shape, np.inf)


def degenerate_pairs(names: Sequence[str], cov: np.ndarray, limit: float = DEGENERATE) -> list[dict]:
    """The pairs of parameters whose estimates correlate beyond +-limit (cov: their
    covariance): {"pair": [a, b], "correlation": r}, strongest first."""
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = cov / np.outer(d, d)
    pairs = [
        {"pair": [names[i], names[j]], "correlation": round(float(corr[i, j]), 4)}
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if np.isfinite(corr[i, j]) and abs(corr[i, j]) > limit
    ]
    return sorted(pairs, key=lambda p: -abs(p["correlation"]))


def check_coverage(names: Sequence[str], jac: np.ndarray, where: str, scales: dict[str, float]) -> list[dict]:
    """Refuse (CoverageError) a parameter whose predicted 1-sigma uncertainty at NOISE_MTF,
    with the others fitted too, exceeds its scale (J in units of the scales); return the
    degenerate pairs (degenerate_pairs) of those that pass."""
    cov = _covariance(jac, NOISE_MTF)
    for i, name in enumerate(names):
        sigma = float(np.sqrt(max(cov[i, i], 0.0))) if np.isfinite(cov[i, i]) else np.inf
        alone = float(np.sqrt(np.sum(jac[:, i] ** 2)))
        if not sigma <= 1.0 or alone == 0.0:
            worst = degenerate_pairs(names, cov, 0.0)
            partner = next((p["pair"] for p in worst if name in p["pair"]), None)
            tied = "" if partner is None else f", tied to {[n for n in partner if n != name][0]}"
            raise CoverageError(
                where,
                name,
                f"the chart's edges cannot constrain it (predicted uncertainty {sigma:.3g} x its scale "
                f"{scale_of(name, scales):.3g} at MTF noise {NOISE_MTF:g}; its own effect {alone:.3g}{tied}); "
                "expected edges at fields where it acts (both sides of the centre, and off both axes for tilts)",
            )
    return degenerate_pairs(names, cov)


def _rms(run: Run) -> float:
    return float(np.sqrt(np.mean(run.data**2)))


def _run_summary(run: Run, names: list[str], units: np.ndarray) -> dict:
    """One start's outcome: the image focus it ended at (mm, 0 when not fitted), its RMS
    SFR residual and the parameters it left at a bound."""
    k = names.index("image.focus") if "image.focus" in names else None
    focus = 0.0 if k is None else float(run.x[k] * units[k])
    return {"focus": focus, "rms": _rms(run), "at_bound": run.at_bound}


@dataclass
class _Outcome:
    """One parameter set fitted: its names, units (scales), degenerate pairs, the runs (one
    per start) and the parameters held at nominal (the chart cannot constrain them)."""

    names: list[str]
    scales: np.ndarray
    degenerate: list[dict]
    runs: list[Run]
    held: list[dict] = field(default_factory=list)

    @property
    def best(self) -> Run:
        return min(self.runs, key=lambda r: r.cost)


def _columns(model: Model, names: Sequence[str], context: dict) -> np.ndarray:
    """The Jacobian columns ((N, P), per scale) of the names: known ones, the others computed."""
    kinds, base, known = context["kinds"], context["base"], context["columns"]
    cols = [known.get(n) for n in names]
    cols = [
        c if c is not None else model.predict({n: scale_of(n, kinds)}) - base for n, c in zip(names, cols, strict=True)
    ]
    return np.stack(cols, axis=1)


def _constrained(model: Model, names: list[str], context: dict, hold: bool) -> tuple[list[str], list[dict], list[dict]]:
    """check_coverage of a parameter set: (names kept, degenerate pairs, held); with hold,
    a parameter the chart cannot constrain is held at nominal (dropped, recorded with the
    reason) and the rest checked again; without, it is refused (CoverageError)."""
    held: list[dict] = []
    while True:
        try:
            jac = _columns(model, names, context)
            return names, check_coverage(names, jac, context["where"], context["kinds"]), held
        except CoverageError as e:
            if not hold or e.field not in names or len(names) == 1:
                raise
            held.append({"parameter": e.field, "reason": e.message})
            names = [n for n in names if n != e.field]


def _fit_set(model: Model, names: list[str], context: dict, start: dict[str, float] | None, hold: bool) -> _Outcome:
    """Check the coverage of one parameter set (_constrained) and fit it from each start
    (lensim.calibrate.search.starts, or `start`); context: kinds (scales by kind),
    columns (known Jacobian columns), base (nominal model), measured, where."""
    names, degenerate, held = _constrained(model, names, context, hold)
    units = np.array([scale_of(n, context["kinds"]) for n in names])
    if start is None:
        origins = starts(model, names, units, context)
    else:
        origins = [np.array([start.get(n, 0.0) for n in names]) / units]
    return _Outcome(names, units, degenerate, [solve(model, names, units, context, u0) for u0 in origins], held)


def _fit_sets(
    model: Model, sets: list[list[str]], context: dict, start: dict[str, float] | None, hold: bool
) -> list[_Outcome]:
    """_fit_set of each set; a set after the first that the chart cannot constrain is skipped."""
    out = []
    for i, names in enumerate(sets):
        try:
            out.append(_fit_set(model, names, context, start, hold))
        except CoverageError:
            if i == 0:
                raise
    return out


def _columns_at(model: Model, values: dict[str, float], context: dict) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The model at values and its change (per scale) for each fitted parameter and every
    element's decentre and tilt: the linear model at a fitted lens (one trace per element
    parameter), where a further element's move acts at first order."""
    kinds = context["kinds"]
    base = model.predict(values)
    names = list(values)
    for k in range(1, len(elements(model.lens)) + 1):
        names += [f"e{k}.{kind}" for kind in ELEMENT_KINDS if f"e{k}.{kind}" not in values]
    columns = {}
    for n in names:
        moved = dict(values)
        moved[n] = moved.get(n, 0.0) + scale_of(n, kinds)
        columns[n] = model.predict(moved) - base
    return base, columns


def _add_moves(model: Model, outcome: _Outcome, context: dict, count: int) -> tuple[_Outcome, list[dict]]:
    """Add up to `count` element moves to a fitted set, one after another: the move that
    leaves the smallest residual in the linear model at the current fit (move_costs on
    _columns_at; a chosen element's tilt beside its decentre included) and that the chart
    can constrain with the others (check_coverage; a move it cannot, such as the last
    element's tilt tied to the sensor's, is skipped with the reason) is added and the set
    fitted again from the current values. Returns the last outcome and one record per
    step: the move, its linear-model RMS, the fitted RMS (MTF) and the moves skipped."""
    steps: list[dict] = []
    for _ in range(count):
        values = dict(zip(outcome.names, (outcome.best.x * outcome.scales).tolist(), strict=True))
        base, columns = _columns_at(model, values, context)
        gap = context["measured"] - base
        skipped, step = [], None
        for cost, move in move_costs(gap, columns, outcome.names):
            try:
                step = _fit_set(model, [*outcome.names, f"{move}_x", f"{move}_y"], context, values, hold=False)
            except CoverageError as e:
                skipped.append({"move": move, "parameter": e.field, "reason": e.message})
                continue
            steps.append({"move": move, "linear_rms": float(np.sqrt(cost / gap.size)), "rms": _rms(step.best)})
            steps[-1]["skipped"] = skipped
            break
        if step is None:
            break
        outcome = replace(step, held=outcome.held)
    return outcome, steps


def _record(chosen: _Outcome, outcomes: list[_Outcome], context: dict, sigma: dict[str, float]) -> dict:
    """The as_built record of a fit (lensim.calibrate.fit.fit's docstring)."""
    names, units, run = chosen.names, chosen.scales, chosen.best
    record = {
        "kind": "calibration",
        "uncertainties": sigma,
        "rms_residual_before": float(np.sqrt(np.mean((context["base"] - context["measured"]) ** 2))),
        "rms_residual_after": _rms(run),
        "edges": context["edges"],
        "scales": {n: float(v) for n, v in zip(names, units, strict=True)},
        "degenerate": chosen.degenerate,
        "starts": [_run_summary(r, names, units) for r in chosen.runs],
        **bounds_record(names, context["kinds"]),
        "prior_noise_mtf": NOISE_MTF,
        "at_bound": run.at_bound,
        "held_at_nominal": chosen.held,
    }
    if "ranking_record" in context:
        record["ranking"] = context["ranking_record"]
    if context.get("steps"):
        record["steps"] = context["steps"]
    if len(outcomes) > 1:
        record["candidates"] = [{"parameters": o.names, "rms": _rms(o.best), "held": o.held} for o in outcomes]
    return record


def fit(
    lens: Lens,
    obs: Observations,
    names: Sequence[str] | None = None,
    elements_fitted: int = 1,
    where: str = "chart",
    progress: Progress | None = None,
    start: dict[str, float] | None = None,
    candidates: int = 1,
    ranking: str = "prefit",
    add_moves: int = 0,
) -> Fit:
    """Fit the parameters `names` (default: choose_parameters from the sensitivity table,
    which is then reported; given names skip it) to the observations, from each start of
    lensim.calibrate.search.starts, keeping the smallest objective; every parameter stays within its physical
    bound and has a prior towards nominal (lensim.calibrate.bounds). Returns the Fit with
    the as-built lens (its as_built record holds the values, uncertainties, residuals,
    degenerate pairs, bounds, priors, the parameters at a bound and those held at
    nominal). where: the source named in a CoverageError: a given name the chart cannot
    constrain is refused, a chosen one held at nominal. start: values (mm or deg) to
    start from instead of those starts (a refit near a known solution; missing ones start at
    0). candidates: the number of first elements fitted in full, the best-ranked
    (candidate_sets), the smallest objective kept (each candidate's RMS in
    as_built.candidates); with names, their image parameters and number of element moves
    are kept and the moves chosen again. elements_fitted: the element moves (each an
    element's decentre or tilt, x and y) fitted: the first as above, the others added one
    at a time (_add_moves). ranking: how the first elements are ranked,
    "prefit" (by their image prefits, lensim.calibrate.search.prefit_ranking: about 8
    traces and 11 image fits per element) or "linear" (the linear model at the nominal
    lens, element_ranking: it can rank the wrong element first); both rankings are
    recorded in as_built.ranking. add_moves: element moves added (_add_moves) after the
    given names are fitted (a refresh round adds them at a refreshed transfer)."""
    t0 = time.perf_counter()
    model = Model(lens, obs)
    measured = np.concatenate(obs.measured)
    base = model.predict({})
    kinds = parameter_scales(lens, obs)
    if ranking not in ("prefit", "linear"):
        raise InputError(where, "ranking", f"expected prefit or linear, got {ranking!r}")
    context: dict[str, Any] = {"kinds": kinds, "columns": {}, "base": base, "measured": measured}
    context.update(where=where, progress=progress)
    context["ranking"] = ranking
    context["edges"] = len(obs.edges)
    table, sets = _parameter_sets(model, names, elements_fitted, candidates, context)
    outcomes = _fit_sets(model, sets, context, start, hold=names is None or candidates > 1)
    chosen = min(outcomes, key=lambda o: o.best.cost)
    context["further_moves"] = context.get("further_moves", 0) + add_moves
    if context["further_moves"]:
        chosen, context["steps"] = _add_moves(model, chosen, context, context["further_moves"])
    names, units, run = chosen.names, chosen.scales, chosen.best
    dof = max(measured.size - len(names), 1)
    cov = np.linalg.pinv(run.jac.T @ run.jac) * max(float(np.sum(run.data**2)) / dof, 1e-300)
    sigma_u = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    values = {n: float(v) for n, v in zip(names, run.x * units, strict=True)}
    sigma = {n: float(s) for n, s in zip(names, sigma_u * units, strict=True)}
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    as_built = perturbed_lens(lens, values, _record(chosen, outcomes, context, sigma))
    return Fit(
        values, sigma, table, float(np.sqrt(np.mean((base - measured) ** 2))),
        _rms(run), as_built, model.evaluations, time.perf_counter() - t0,
        (cov / np.outer(d, d)).round(3).tolist(), chosen.degenerate, model.traces,
    )  # fmt: skip
