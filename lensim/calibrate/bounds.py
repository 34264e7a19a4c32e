"""Physical bounds and priors of the as-built parameters, so that a fit cannot run away.

A chart photographed through a unit with errors the fit does not model (every element
tilted and spaced a little) can be matched by an absurd value of a parameter it does
model: the held-out camera of benchmarks/calibration_validation.py was fitted with a
sensor tilt of 1.2 deg (truth 0.05 deg). Every fitted parameter therefore has

- a hard bound |value| <= bound, the manufacturing range of that kind of error:
  decentres within DECENTRE_BOUND depths of focus of the lens (the parameter scale of
  lensim.calibrate.fit.parameter_scales: 2 lambda N^2; 27 um for the phone lens at F/2.2,
  about 130 um for an F/4.5 Cooke triplet), element tilts within ELEMENT_TILT_BOUND_DEG,
  the sensor's tilts within SENSOR_TILT_BOUND_DEG (a camera body's or module's sensor
  alignment), the image focus within FOCUS_BOUND depths of focus (a focus setting, not a
  manufacturing error: wide);
- a Gaussian prior centred on the nominal design (0) with sigma = bound * PRIOR_FRACTION,
  for every kind but the focus: residual rows NOISE_MTF * value / sigma beside the SFR
  residuals (the maximum a-posteriori fit at the assumed SFR noise).

The fit records bounds, priors and which parameters ended at a bound (whose value the
bound, not the chart, set) in the lens file's as_built record.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

#: image focus bound, in depths of focus
FOCUS_BOUND = 20.0
#: element decentre bound, in depths of focus
DECENTRE_BOUND = 5.0
#: element tilt bound (deg)
ELEMENT_TILT_BOUND_DEG = 0.25
#: sensor tilt bound (deg)
SENSOR_TILT_BOUND_DEG = 0.25
#: prior sigma as a fraction of the bound (none on the focus)
PRIOR_FRACTION = 0.5
#: a fitted value within this fraction of its bound's width from it is reported at the bound
AT_BOUND = 1e-3


def bound_of(name: str, scales: Mapping[str, float]) -> float:
    """The largest |value| (mm or deg) of a parameter name ("image.focus", "image.tilt_x",
    "e2.decentre_y", "e3.tilt_x"); scales: parameter_scales of the lens and chart."""
    target, _, kind = name.partition(".")
    if kind == "focus":
        return FOCUS_BOUND * scales["focus"]
    if kind.startswith("tilt"):
        return SENSOR_TILT_BOUND_DEG if target == "image" else ELEMENT_TILT_BOUND_DEG
    return DECENTRE_BOUND * scales[kind]


def prior_sigma(name: str, scales: Mapping[str, float]) -> float | None:
    """The prior's sigma (mm or deg) of a parameter, None for none (the image focus)."""
    if name == "image.focus":
        return None
    return PRIOR_FRACTION * bound_of(name, scales)


def limits(names: Sequence[str], units: np.ndarray, scales: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) bounds of the parameters in units of their fit units (units: (P,)
    the unit of each, mm or deg)."""
    b = np.array([bound_of(n, scales) for n in names]) / units
    return -b, b


def prior_weights(names: Sequence[str], units: np.ndarray, scales: Mapping[str, float], noise: float) -> np.ndarray:
    """(P,) the weight w of each parameter's prior row w * u (u in its fit unit): noise /
    sigma in fit units; 0 where there is no prior."""
    out = np.zeros(len(names))
    for i, n in enumerate(names):
        s = prior_sigma(n, scales)
        if s is not None:
            out[i] = noise * units[i] / s
    return out


def at_bounds(names: Sequence[str], u: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> list[str]:
    """The parameters whose value u lies at (within AT_BOUND of the range of) a bound."""
    tol = AT_BOUND * (upper - lower)
    rows = zip(names, u, lower, upper, tol, strict=True)
    return [n for n, x, lo, hi, t in rows if x <= lo + t or x >= hi - t]


def record(names: Sequence[str], scales: Mapping[str, float]) -> dict:
    """The bounds (+-, mm or deg) and prior sigmas (mm or deg; None: none) of the
    parameters, for the as_built record."""
    return {
        "bounds": {n: bound_of(n, scales) for n in names},
        "priors": {n: prior_sigma(n, scales) for n in names},
    }
