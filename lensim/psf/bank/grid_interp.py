"""Kernels between a grid's settings: the nearest setting, and a bank blended from the
settings around a requested one.

Coordinates: an F-number N is placed at 2 log2(N) (stops: N grows by sqrt(2) a stop), a
distance d at 1/d (dioptres;
infinity at 0): defocus blur grows linearly in dioptres, and stops are the camera's own
scale. A requested setting inside the grid is bracketed on every axis the grid spans and
the kernels of the 2^k surrounding settings (k axes) are blended with multilinear weights
in those coordinates, field by field (the grid's banks share fields, kernel size and
wavelengths). Values outside an axis's range are refused: kernels are not extrapolated.
Configurations are names: a request must name one of the grid's (no blending across them).

Where it is sound (benchmarks/grid_bank.py, Cooke triplet on APS-C; docs/psf.md has the
table): focus distance, linear in dioptres, is close to exact (4 m from infinity and 2 m:
worst kernel NCC 0.9993, blurred photos agree to 79 dB and more), as defocus is linear in
dioptres. F-number is an approximation: a blur of one size blended with a blur of another
is not the blur of the size between. F/6.7 from F/5.6 and F/8 (one stop apart) gives a
worst kernel NCC of 0.96 (either neighbour alone 0.92); F/8 from F/5.6 and F/11 (two
stops) 0.91. Blending across F-numbers more than one stop apart therefore warns
(GridInterpolationWarning): make the grid denser in F-number instead.
"""

from __future__ import annotations

import itertools
import math
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from lensim.errors import ParameterError
from lensim.jsonable import strict_json
from lensim.psf.bank.types import BankField, PSFBank

if TYPE_CHECKING:
    from lensim.psf.bank.grid import GridBank

NUMERIC_AXES = ("fno", "focus_m", "object_m")
#: the widest F-number step (stops) blended without a warning
FNO_STEP_STOPS = 1.0


class GridInterpolationWarning(UserWarning):
    """Kernels blended between settings too far apart to stand for the setting between."""


def coordinate(key: str, value: float) -> float:
    """Where a value sits on its axis: stops, 2 log2(F-number), for fno; dioptres (1/m,
    inf -> 0) for distances."""
    if key == "fno":
        return 2.0 * math.log2(value)
    return 0.0 if math.isinf(value) else 1.0 / value


def _show(key: str, value: float) -> str:
    if key == "fno":
        return f"F/{value:g}"
    return "inf" if math.isinf(value) else f"{value:g} m"


def _axis_value(grid: GridBank, key: str, query: Any) -> float | str | None:
    """The query's value on one axis, checked: the grid's single value when the query
    gives none, refused when the grid spans several values and the query gives none."""
    values = grid.axes.get(key)
    if values is None:
        if query is not None:
            raise ParameterError(
                str(grid.directory),
                key,
                f"the grid does not vary {key} (the lens file's value throughout); expected no `{key}`",
            )
        return None
    if query is None:
        if len(values) > 1:
            shown = ", ".join(str(v) if key == "config" else _show(key, v) for v in values)
            raise ParameterError(str(grid.directory), key, f"the grid spans {shown}; expected a value")
        return values[0]
    return query if key == "config" else float(query)


def _bracket(key: str, values: list[float], q: float, where: str) -> list[tuple[float, float]]:
    """[(axis value, weight), ...] of the one or two grid values around q (linear in the
    axis coordinate); q outside the values is refused."""
    coords = sorted((coordinate(key, v), v) for v in values)
    c = coordinate(key, q)
    lo, hi = coords[0][0], coords[-1][0]
    tol = 1e-9 * max(1.0, abs(lo), abs(hi))
    if not lo - tol <= c <= hi + tol:
        span = f"{_show(key, coords[0][1])} .. {_show(key, coords[-1][1])}"
        raise ParameterError(
            where,
            key,
            f"{_show(key, q)} is outside the grid ({span}); expected a value inside it (kernels are not extrapolated)",
        )
    for (c0, v0), (c1, v1) in zip(coords, coords[1:], strict=False):
        if c0 - tol <= c <= c1 + tol:
            t = min(1.0, max(0.0, (c - c0) / (c1 - c0)))
            if not 0.0 < t < 1.0:
                return [(v1 if t >= 1.0 else v0, 1.0)]
            if key == "fno" and c1 - c0 > FNO_STEP_STOPS + 0.1:  # nominal F-numbers: F/5.6 to F/8 is 1.03
                warnings.warn(
                    f"{where}: F/{q:g} blended from F/{v0:g} and F/{v1:g}, {c1 - c0:.2g} stops apart: the "
                    f"kernels are an approximation (a grid at most {FNO_STEP_STOPS:g} stop apart keeps "
                    "kernel NCC about 0.96 or better)",
                    GridInterpolationWarning,
                    stacklevel=5,
                )
            return [(v0, 1.0 - t), (v1, t)]
    return [(coords[0][1], 1.0)]  # a single value


def _index(grid: GridBank) -> dict[tuple, int]:
    return {tuple(getattr(s, k) for k in ("config", *NUMERIC_AXES)): i for i, s in enumerate(grid.settings)}


def setting_weights(grid: GridBank, query: dict[str, Any]) -> list[tuple[int, float]]:
    """[(setting index, weight), ...] (weights sum to 1) that blend the grid's kernels at
    the queried values {fno, focus_m, object_m, config} (None: not asked)."""
    where = str(grid.directory)
    axes = grid.axes
    config = _axis_value(grid, "config", query.get("config"))
    configs = axes["config"] or []
    if config is not None and config not in configs:
        raise ParameterError(
            where, "config", f"{config!r} is not one of the grid's configurations ({', '.join(map(str, configs))})"
        )
    per_axis: list[list[tuple[Any, float]]] = []
    for key in NUMERIC_AXES:
        q = _axis_value(grid, key, query.get(key))
        per_axis.append([(None, 1.0)] if q is None else _bracket(key, axes[key] or [], float(q), where))
    index = _index(grid)
    weights: dict[int, float] = {}
    for corner in itertools.product(*per_axis):
        w = math.prod(p[1] for p in corner)
        if w > 0:
            i = index[(config, *(p[0] for p in corner))]
            weights[i] = weights.get(i, 0.0) + w
    return sorted(weights.items())


def nearest_setting(grid: GridBank, query: dict[str, Any]) -> int:
    """The index of the grid's setting nearest the queried values: the same configuration,
    and the smallest sum of squared differences in axis coordinates, each over its axis's
    span (values outside the grid allowed)."""
    config = query.get("config")
    best, best_d = -1, math.inf
    for i, s in enumerate(grid.settings):
        if config is not None and s.config != config:
            continue
        d = 0.0
        for key in NUMERIC_AXES:
            q, v, values = query.get(key), getattr(s, key), grid.axes.get(key)
            if q is None or v is None or not values:
                continue
            coords = [coordinate(key, x) for x in values]
            span = (max(coords) - min(coords)) or 1.0
            d += ((coordinate(key, float(q)) - coordinate(key, v)) / span) ** 2
        if d < best_d:
            best, best_d = i, d
    if best < 0:
        raise ParameterError(str(grid.directory), "config", f"{config!r} is not one of the grid's configurations")
    return best


def _blend_field(fields: list[BankField], w: list[float]) -> BankField:
    """One field blended from the same field of several banks (weights w)."""

    def mix(name: str) -> Any:
        return sum(wi * np.asarray(getattr(f, name), dtype=np.float64) for wi, f in zip(w, fields, strict=True))

    top = fields[int(np.argmax(w))]
    fine_same = all(f.primary_fine.shape == top.primary_fine.shape for f in fields)
    return BankField(
        index=top.index,
        field=top.field,
        field_value=float(mix("field_value")),
        rgb=mix("rgb").astype(np.float32),
        reference_xy_mm=mix("reference_xy_mm"),
        paraxial_xy_mm=mix("paraxial_xy_mm"),
        chief_offsets_mm=mix("chief_offsets_mm"),
        relative_illumination=mix("relative_illumination"),
        transmission=mix("transmission"),
        window_energy=mix("window_energy"),
        strehl=float(mix("strehl")),
        working_fno=float(mix("working_fno")),
        primary_fine=(mix("primary_fine") if fine_same else top.primary_fine).astype(np.float32),
        rgb_azimuths=mix("rgb_azimuths").astype(np.float32)
        if all(f.rgb_azimuths is not None for f in fields)
        else None,
    )


def interpolate_bank(grid: GridBank, query: dict[str, Any]) -> PSFBank:
    """A bank (in memory) at the queried values blended from the grid's settings around
    them (setting_weights); exactly a setting's bank at a grid point."""
    weights = setting_weights(grid, query)
    banks = [grid.bank(i) for i, _ in weights]
    w = [x for _, x in weights]
    if len(banks) == 1:
        return banks[0]
    fields = [_blend_field([b.fields[j] for b in banks], w) for j in range(len(banks[0].fields))]
    top = banks[int(np.argmax(w))]
    manifest = {
        **top.manifest,
        "interpolated": {
            "request": strict_json(query),
            "from": [{"bank": grid.names[i], "weight": x} for i, x in weights],
        },
    }
    manifest.pop("shooting", None)
    return PSFBank(manifest, fields, None)
