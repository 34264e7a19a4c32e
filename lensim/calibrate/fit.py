"""As-built calibration: fit the image plane, sensor tilt and the decentre of the most
sensitive elements to slanted-edge MTFs measured on a chart.

The model of an observed SFR is the lens's optical MTF across the edge
(lensim.calibrate.model.edge_mtf) times the system's own transfer at those frequencies
(pixel aperture, demosaicking, the develop chain: what the simulation of the nominal lens
adds to the nominal optical MTF, so it cancels out; 1 when the observations are optical
MTFs). Parameters are perturbation names (lensim.calibrate.tolerances): "image.focus"
(mm), "image.tilt_x" / "image.tilt_y" (deg), "eK.decentre_x" / "eK.decentre_y" (mm),
"eK.tilt_x" / "eK.tilt_y" (deg).

The search is derivative-free on the lens: scipy.optimize.least_squares (trust region
reflective) with forward-difference Jacobians, each column one trace of the edges' fields
(the differentiable tracer would give the same Jacobian, but the MTF goes through FFTs and
the pupil grid's vignetting; finite differences at a tenth of each parameter's scale are
exact enough for a fit whose noise is 1e-2 in MTF). Uncertainties come from the Jacobian
at the optimum: cov = s^2 (J^T J)^-1, s^2 the residual variance. Before fitting, a
parameter the chart's edges cannot constrain (its predicted 1-sigma uncertainty at the
assumed noise is above its scale) is refused with a CoverageError naming it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from lensim.calibrate.model import Edge, model_mtfs
from lensim.calibrate.tolerances import elements, perturbed_lens
from lensim.errors import InputError
from lensim.optics.lens import Lens

#: element tilt scale (deg); the other scales follow the lens (parameter_scales)
ELEMENT_TILT_DEG = 0.05
KINDS = ("focus", "tilt_x", "tilt_y", "decentre_x", "decentre_y")
#: the MTF noise a chart measurement is assumed to have when coverage is checked
NOISE_MTF = 0.01

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


def _predict(lens: Lens, values: dict[str, float], obs: Observations) -> np.ndarray:
    """The model SFRs of every edge, concatenated."""
    moved = perturbed_lens(lens, values) if values else lens
    mtfs = model_mtfs(moved, obs.edges, obs.wavelengths_um, obs.weights, obs.samples, obs.aiming)
    if obs.system is not None:
        mtfs = [m * s for m, s in zip(mtfs, obs.system, strict=True)]
    return np.concatenate(mtfs)


def jacobian(
    lens: Lens, names: Sequence[str], obs: Observations, base: np.ndarray, scales: dict[str, float]
) -> np.ndarray:
    """d(model)/d(parameter / scale) at the lens as given, by forward differences of a
    tenth of each scale (scales: parameter_scales): (observations, parameters)."""
    cols = []
    for name in names:
        step = 0.1 * scale_of(name, scales)
        cols.append((_predict(lens, {name: step}, obs) - base) / 0.1)
    return np.stack(cols, axis=1)


IMAGE_PARAMETERS = ("image.focus", "image.tilt_x", "image.tilt_y")


def sensitivity_table(
    lens: Lens, obs: Observations, base: np.ndarray, scales: dict[str, float], progress: Progress | None = None
) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Every candidate parameter (image focus and tilts, each element's decentre and tilt)
    with the RMS change of the model SFRs it makes at its scale, largest first; and each
    one's change (the Jacobian column in units of its scale)."""
    names = list(IMAGE_PARAMETERS)
    for k in range(1, len(elements(lens)) + 1):
        names += [f"e{k}.{kind}" for kind in ("decentre_x", "decentre_y", "tilt_x", "tilt_y")]
    rows, columns = [], {}
    for i, name in enumerate(names):
        step = scale_of(name, scales)
        columns[name] = _predict(lens, {name: step}, obs) - base
        rows.append({"parameter": name, "scale": step, "rms_change": float(np.sqrt(np.mean(columns[name] ** 2)))})
        if progress:
            progress(i + 1, len(names))
    return sorted(rows, key=lambda r: -r["rms_change"]), columns


def choose_parameters(gap: np.ndarray, columns: dict[str, np.ndarray], elements_fitted: int) -> list[str]:
    """The image focus and tilts, and the decentres (x, y) of the `elements_fitted`
    elements that, fitted with the image parameters in the linear model (the columns),
    leave the smallest residual of gap (measured - nominal model); ties go to the more
    sensitive element."""
    targets = sorted({n.partition(".")[0] for n in columns if n.startswith("e")}, key=lambda t: int(t[1:]))
    chosen = list(IMAGE_PARAMETERS)
    for _ in range(elements_fitted):
        best, best_cost = None, np.inf
        for t in targets:
            if f"{t}.decentre_x" in chosen:
                continue
            names = [*chosen, f"{t}.decentre_x", f"{t}.decentre_y"]
            a = np.stack([columns[n] for n in names], axis=1)
            coef, *_ = np.linalg.lstsq(a, gap, rcond=None)
            cost = float(np.sum((a @ coef - gap) ** 2))
            if cost < best_cost:
                best, best_cost = t, cost
        if best is None:
            break
        chosen += [f"{best}.decentre_x", f"{best}.decentre_y"]
    return chosen


def check_coverage(names: Sequence[str], jac: np.ndarray, where: str, scales: dict[str, float]) -> None:
    """Refuse (CoverageError) a parameter whose predicted 1-sigma uncertainty at NOISE_MTF,
    with the others fitted too, exceeds its scale (J in units of the scales)."""
    info = jac.T @ jac / NOISE_MTF**2
    try:  # a tiny ridge keeps a parameter that changes nothing at an enormous uncertainty
        cov = np.linalg.inv(info + 1e-9 * np.eye(len(names)))
    except np.linalg.LinAlgError:
        cov = np.full(info.shape, np.inf)
    for i, name in enumerate(names):
        sigma = float(np.sqrt(max(cov[i, i], 0.0))) if np.isfinite(cov[i, i]) else np.inf
        alone = float(np.sqrt(np.sum(jac[:, i] ** 2)))
        if not sigma <= 1.0 or alone == 0.0:
            raise CoverageError(
                where,
                name,
                f"the chart's edges cannot constrain it (predicted uncertainty {sigma:.3g} x its scale "
                f"{scale_of(name, scales):.3g} at MTF noise {NOISE_MTF:g}; its own effect {alone:.3g}); expected edges "
                "at fields where it acts (both sides of the centre, and off both axes for tilts)",
            )


def fit(
    lens: Lens,
    obs: Observations,
    names: Sequence[str] | None = None,
    elements_fitted: int = 1,
    where: str = "chart",
    progress: Progress | None = None,
) -> Fit:
    """Fit the parameters `names` (default: choose_parameters from the sensitivity table,
    which is then reported; given names skip it) to the observations; returns the Fit
    with the as-built lens (its as_built record holds the values, uncertainties and
    residuals). where: the source named in a CoverageError."""
    from scipy.optimize import least_squares

    start = time.perf_counter()
    measured = np.concatenate(obs.measured)
    base = _predict(lens, {}, obs)
    kinds = parameter_scales(lens, obs)
    table: list[dict] = []
    columns: dict[str, np.ndarray] = {}
    if names is None:
        table, columns = sensitivity_table(lens, obs, base, kinds, progress)
    names = list(names) if names is not None else choose_parameters(measured - base, columns, elements_fitted)
    scales = np.array([scale_of(n, kinds) for n in names])
    cols = [columns[n] if n in columns else jacobian(lens, [n], obs, base, kinds)[:, 0] for n in names]
    check_coverage(names, np.stack(cols, axis=1), where, kinds)
    calls = [0]

    def residual(u: np.ndarray) -> np.ndarray:
        calls[0] += 1
        return _predict(lens, dict(zip(names, (u * scales).tolist(), strict=True)), obs) - measured

    res = least_squares(residual, np.zeros(len(names)), diff_step=0.1 / 3.0, bounds=(-20.0, 20.0), x_scale=1.0)
    jac = res.jac
    dof = max(measured.size - len(names), 1)
    s2 = 2.0 * res.cost / dof
    cov = np.linalg.pinv(jac.T @ jac) * s2
    sigma_u = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    values = {n: float(v) for n, v in zip(names, res.x * scales, strict=True)}
    sigma = {n: float(s) for n, s in zip(names, sigma_u * scales, strict=True)}
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = (cov / np.outer(d, d)).round(3).tolist()
    rms_before = float(np.sqrt(np.mean((base - measured) ** 2)))
    rms_after = float(np.sqrt(np.mean(res.fun**2)))
    record = {
        "kind": "calibration",
        "uncertainties": sigma,
        "rms_residual_before": rms_before,
        "rms_residual_after": rms_after,
        "edges": len(obs.edges),
        "scales": {n: float(v) for n, v in zip(names, scales, strict=True)},
    }
    as_built = perturbed_lens(lens, values, record)
    seconds = time.perf_counter() - start
    return Fit(values, sigma, table, rms_before, rms_after, as_built, calls[0], seconds, corr)
