"""The search of lensim.calibrate.fit: the bounded least-squares solve, the image prefits
the full fit starts from, and the ranking of the candidate elements by those prefits.

Parameters are in units of their scales (u; lensim.calibrate.fit.parameter_scales):
values in mm or deg are u times the scales. The model is lensim.calibrate.fit.Model:
a change of an element traces the lens again (about 2 s), a change of the image plane
only moves the sensor on the last trace (about 0.4 s).

Ranking by prefits: at the nominal lens a decentre changes the MTF at second order, so
the linear model there (lensim.calibrate.fit.element_ranking) can rank the wrong element
first (benchmarks/results/calibration/v3/candidates1: element 1 for a 12 um decentre of
element 3). Each candidate element is instead prefitted as the full fit's starts are
(the image parameters fitted alone with the element's x or y parameter held at
+-ELEMENT_START: one trace each, no element fitted), and the elements are ranked by the
smallest prefit objective; the chosen set's starts are then those prefits (kept in a memo).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lensim.calibrate.bounds import at_bounds, limits, prior_weights

if TYPE_CHECKING:
    from lensim.calibrate.fit import Model

IMAGE_PARAMETERS = ("image.focus", "image.tilt_x", "image.tilt_y")
#: the image focus (in its scale) the fit also starts from, with both signs
FOCUS_START = 1.5
#: the element decentre or tilt (in its scale) the image prefit also starts from (starts)
ELEMENT_START = 2.0
#: forward-difference step of the Jacobian, in each parameter's scale
STEP = 0.05
#: least_squares' ftol and xtol of the image prefits (the full fit's: 1e-8): a start and a ranking
#: need no more (larger_decentre in the model world: the same fit, half the prefit evaluations)
PREFIT_TOLERANCE = 1e-3
#: the MTF noise a chart measurement is assumed to have (coverage check, priors)
NOISE_MTF = 0.01


@dataclass
class Run:
    """One start's outcome: the fitted u (in units of the scales), the data residuals
    ((N,), MTF), the objective (half the sum of squares of data and prior rows), the
    Jacobian of every row ((N + P, P)) and the parameters ended at a bound."""

    x: np.ndarray
    data: np.ndarray
    cost: float
    jac: np.ndarray
    at_bound: list[str]


def solve(
    model: Model,
    names: list[str],
    units: np.ndarray,
    context: dict,
    start: np.ndarray,
    fixed: dict | None = None,
    tolerance: float = 1e-8,
) -> Run:
    """scipy least_squares (trust region reflective) in units of the scales from start
    (clipped into the bounds), within lensim.calibrate.bounds' limits and with its prior
    rows, the Jacobian by forward differences of STEP (image columns need no trace);
    context: measured ((N,)) and kinds (parameter_scales); fixed: other parameters' values
    (mm or deg) held while these are fitted; tolerance: least_squares' ftol and xtol."""
    from scipy.optimize import least_squares

    measured, kinds = context["measured"], context["kinds"]
    lower, upper = limits(names, units, kinds)
    weights = prior_weights(names, units, kinds, NOISE_MTF)
    memo: dict[bytes, np.ndarray] = {}
    held = dict(fixed or {})

    def values(u: np.ndarray) -> dict[str, float]:
        return held | dict(zip(names, (u * units).tolist(), strict=True))

    def data(u: np.ndarray) -> np.ndarray:
        key = u.tobytes()
        if key not in memo:
            memo.clear()
            memo[key] = model.predict(values(u)) - measured
        return memo[key]

    def jac(u: np.ndarray) -> np.ndarray:
        f0 = data(u)
        cols = []
        for i, name in enumerate(names):
            v = values(u)
            v[name] += STEP * units[i]
            cols.append((model.predict(v) - measured - f0) / STEP)
        return np.concatenate([np.stack(cols, axis=1), np.diag(weights)])

    u0 = np.clip(start, lower, upper)
    res = least_squares(
        lambda u: np.concatenate([data(u), weights * u]),
        u0,
        jac=jac,
        bounds=(lower, upper),
        x_scale=1.0,
        max_nfev=60,
        ftol=tolerance,
        xtol=tolerance,
    )
    return Run(res.x, data(res.x), float(res.cost), res.jac, at_bounds(names, res.x, lower, upper))


def element_offsets(names: list[str]) -> list[np.ndarray]:
    """The element starts (u, in scales; image parameters 0) the image prefit is also run
    from: each element parameter at +-ELEMENT_START, one at a time."""
    out = []
    for i, name in enumerate(names):
        if name in IMAGE_PARAMETERS:
            continue
        for sign in (-1.0, 1.0):
            u = np.zeros(len(names))
            u[i] = sign * ELEMENT_START
            out.append(u)
    return out


def prefit(
    model: Model, names: list[str], units: np.ndarray, context: dict, u0: np.ndarray
) -> tuple[float, np.ndarray, float]:
    """The image parameters fitted alone from u0 (in scales), the element ones held at
    u0's: (objective with every prior row, u with the fitted image values, RMS of the
    data residuals in MTF). Memoized in context["prefits"] by the image names and start
    and the held values (mm or deg), so a set fitted after the ranking reuses its prefits."""
    image = [i for i, n in enumerate(names) if n in IMAGE_PARAMETERS]
    rest = [i for i in range(len(names)) if i not in image]
    fixed = {names[i]: float(u0[i] * units[i]) for i in rest if u0[i] != 0.0}
    key = (tuple(names[i] for i in image), tuple(sorted(fixed.items())), np.round(u0[image], 12).tobytes())
    memo = context.setdefault("prefits", {})
    if key not in memo:
        res = solve(model, [names[i] for i in image], units[image], context, u0[image], fixed, PREFIT_TOLERANCE)
        memo[key] = (res.cost, res.x, float(np.sqrt(np.mean(res.data**2))))
    cost, x, rms = memo[key]
    u = np.array(u0, dtype=np.float64)
    u[image] = x
    prior = prior_weights([names[i] for i in rest], units[rest], context["kinds"], NOISE_MTF) * u[rest]
    return cost + 0.5 * float(np.sum(prior**2)), u, rms


def best_prefits(
    model: Model, names: list[str], units: np.ndarray, context: dict, both_signs: bool = True
) -> dict[int, tuple[float, np.ndarray, float]]:
    """The best prefit (prefit's objective, u, RMS) of each sign of the image focus: the
    image parameters fitted alone from image focus +-FOCUS_START and 0 scales (no trace),
    then each sign's best (only the better sign's without both_signs) also with each
    element parameter at +-ELEMENT_START (element_offsets: one trace each). names must
    hold "image.focus"."""
    k = names.index("image.focus")
    best: dict[int, tuple[float, np.ndarray, float]] = {}

    def keep(cost: float, u: np.ndarray, rms: float) -> None:
        sign = 1 if u[k] >= 0 else -1
        if sign not in best or cost < best[sign][0]:
            best[sign] = (cost, u, rms)

    for f0 in (-FOCUS_START, 0.0, FOCUS_START):
        u0 = np.zeros(len(names))
        u0[k] = f0
        keep(*prefit(model, names, units, context, u0))
    image_starts = sorted(best.values(), key=lambda t: t[0])[: 2 if both_signs else 1]
    for _, image_start, _ in image_starts:
        for offset in element_offsets(names):
            keep(*prefit(model, names, units, context, image_start + offset))
    return best


def starts(model: Model, names: list[str], units: np.ndarray, context: dict) -> list[np.ndarray]:
    """Where the full fit starts. The MTF alone hardly tells a focus shift's sign, so the
    image parameters are fitted first (no trace: cheap) from image focus +-FOCUS_START and
    0 scales; and an element's decentre or tilt changes the MTF little near nominal (an
    odd aberration changes the MTF at second order), where a fit started there stays and
    takes a large error of the element as focus and sensor tilt: each sign's best image
    start is also prefitted with each element parameter at +-ELEMENT_START (one trace
    each; best_prefits). The best start of each focus sign is kept (one when both agree)."""
    if "image.focus" not in names:
        return [np.zeros(len(names))]
    best = best_prefits(model, names, units, context)
    out = [u for _, u, _ in sorted(best.values(), key=lambda t: t[0])]
    if len(out) == 2 and np.allclose(out[0], out[1], atol=0.05):
        out = out[:1]
    return out


def prefit_ranking(
    model: Model, moves: Sequence[str], image: Sequence[str], context: dict, scale: Callable[[str], float]
) -> list[dict]:
    """The element moves ("e3.decentre": its x and y parameters) ranked by their best
    prefit with the image parameters (best_prefits from the better focus sign's image
    start only: 4 prefits of one trace each per move; smallest objective first, ties keep
    the order of moves). Each row: move, cost (the objective: half the sum of squares of
    the MTF residuals and prior rows), rms (its MTF residuals) and the element values it
    was held at (mm or deg). scale: a parameter name's scale (mm or deg)."""
    rows = []
    for move in moves:
        names = [*image, f"{move}_x", f"{move}_y"]
        units = np.array([scale(n) for n in names])
        best = best_prefits(model, names, units, context, both_signs=False)
        cost, u, rms = min(best.values(), key=lambda t: t[0])
        held = {n: float(v * s) for n, v, s in zip(names, u, units, strict=True) if n not in IMAGE_PARAMETERS}
        rows.append({"move": move, "cost": float(cost), "rms": rms, "held": held})
    return sorted(rows, key=lambda r: r["cost"])
