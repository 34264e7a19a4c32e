"""Tolerances and perturbed (as-built) lenses.

A tolerance file gives Zemax-style +-ranges per element (or rigid group of elements) and
for the image plane:

    distribution: uniform          # uniform in +-range (default), or normal (sigma = range / 2,
                                   # truncated at +-range, Zemax's default Monte Carlo)
    elements:                      # 1-based element numbers in the order light meets them
      all: {decentre_mm: 0.01, tilt_deg: 0.02, thickness_mm: 0.01, spacing_mm: 0.01}
      "2": {decentre_mm: 0.03}     # element 2: these keys replace the 'all' ones
      "3-4": {tilt_deg: 0.05}      # elements 3 and 4 as one rigid group
    image: {focus_mm: 0.01, tilt_deg: 0.03}

An element is a run of surfaces with glass between them (a cemented doublet is one
element); a stop or dummy surface in air belongs to none. decentre_mm: each of x and y;
tilt_deg: about x and y, about the element's (group's) axial centre; thickness_mm: each
glass thickness inside; spacing_mm: the air gap after the element (group); image focus_mm:
the image plane along the axis; image tilt_deg: the sensor about x and y.

A perturbation is a flat mapping of parameter name -> value: "e2.decentre_x" (mm),
"e2.tilt_y" (deg), "e3-4.spacing" (mm), "e1.thickness" (mm, every glass thickness of the
element), "image.focus" (mm), "image.tilt_x" (deg). perturbed_lens applies one.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.optics.materials import Air
from lensim.optics.pose import compose, element_poses

ELEMENT_KEYS = {"decentre_mm": ("decentre_x", "decentre_y"), "tilt_deg": ("tilt_x", "tilt_y")}
ELEMENT_KEYS_1D = {"thickness_mm": "thickness", "spacing_mm": "spacing"}
IMAGE_KEYS = {"focus_mm": ("focus",), "tilt_deg": ("tilt_x", "tilt_y")}
TOP_KEYS = {"distribution", "elements", "image", "description"}
DISTRIBUTIONS = ("uniform", "normal")
#: the largest range a tolerance may give (mm or deg): beyond it the draw is another lens
MAX_RANGE = 5.0


def elements(lens: Lens) -> list[list[int]]:
    """The lens's elements: each a list of 0-based surface indices with glass between
    consecutive ones (a mirror in air is an element of one surface)."""
    media = lens.media()
    out: list[list[int]] = []
    cur: list[int] = []
    for i, s in enumerate(lens.surfaces):
        glass_after = not isinstance(media[i + 1], Air)
        if cur or glass_after or s.is_mirror:
            cur.append(i)
        if cur and not glass_after:
            out.append(cur)
            cur = []
    if cur:
        out.append(cur)
    return out


@dataclass
class Tolerances:
    """Ranges per target: {"e2": {"decentre_x": 0.03, ...}, "e3-4": {...}, "image": {...}}
    (mm or deg, as the parameter names say); distribution 'uniform' or 'normal'."""

    ranges: dict[str, dict[str, float]]
    distribution: str = "uniform"
    source: str = "<tolerances>"

    def parameters(self) -> dict[str, float]:
        """Every toleranced parameter name ("e2.decentre_x") -> its range."""
        return {f"{t}.{k}": r for t, ks in self.ranges.items() for k, r in ks.items() if r > 0}


def _range(src: str, fld: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(src, fld, f"expected a number (the +- range), got {value!r}")
    if not 0 <= value <= MAX_RANGE:
        raise InputError(src, fld, f"expected a range between 0 and {MAX_RANGE:g}, got {value:g}")
    return float(value)


def _check_keys(src: str, fld: str, data: Any, known: set[str]) -> dict:
    if not isinstance(data, dict):
        raise InputError(src, fld, f"expected a mapping, got {type(data).__name__}")
    unknown = sorted(str(k) for k in set(data) - known)
    if unknown:
        raise InputError(src, f"{fld}.{unknown[0]}", f"unknown key; expected one of {', '.join(sorted(known))}")
    return data


def _element_ranges(src: str, fld: str, data: Any) -> dict[str, float]:
    data = _check_keys(src, fld, data or {}, set(ELEMENT_KEYS) | set(ELEMENT_KEYS_1D))
    out: dict[str, float] = {}
    for key, value in data.items():
        r = _range(src, f"{fld}.{key}", value)
        for name in ELEMENT_KEYS.get(key, (ELEMENT_KEYS_1D.get(key, key),)):
            out[name] = r
    return out


def _target(src: str, key: Any, count: int) -> tuple[int, int]:
    """An element key "2" or group "3-4" -> (first, last), 1-based, checked against count."""
    text = str(key).strip()
    parts = text.split("-")
    if not (1 <= len(parts) <= 2 and all(p.strip().isdigit() for p in parts)):
        raise InputError(src, f"elements.{text}", "expected 'all', an element number like 2 or a group like 3-4")
    a, b = int(parts[0]), int(parts[-1])
    if not 1 <= a <= b <= count:
        raise InputError(src, f"elements.{text}", f"expected element numbers 1..{count} (first <= last)")
    return a, b


def tolerances_from_dict(data: Any, lens: Lens, source: str = "<tolerances>") -> Tolerances:
    """Check a tolerance mapping against a lens (its element count) and build Tolerances."""
    src = source
    data = _check_keys(src, "tolerances", data if data is not None else {}, TOP_KEYS)
    dist = data.get("distribution", "uniform")
    if dist not in DISTRIBUTIONS:
        raise InputError(src, "distribution", f"expected one of {', '.join(DISTRIBUTIONS)}, got {dist!r}")
    count = len(elements(lens))
    els = _check_keys(src, "elements", data.get("elements", {}) or {}, set(data.get("elements", {}) or {}))
    default = _element_ranges(src, "elements.all", els.get("all"))
    ranges: dict[str, dict[str, float]] = {}
    covered: set[int] = set()
    for key, value in els.items():
        if str(key) == "all":
            continue
        a, b = _target(src, key, count)
        if covered & set(range(a, b + 1)):
            raise InputError(src, f"elements.{key}", "expected each element in one entry only (it is in another)")
        covered |= set(range(a, b + 1))
        ranges[f"e{a}" if a == b else f"e{a}-{b}"] = {**default, **_element_ranges(src, f"elements.{key}", value)}
    for k in range(1, count + 1):
        if k not in covered and default:
            ranges[f"e{k}"] = dict(default)
    image = _check_keys(src, "image", data.get("image", {}) or {}, set(IMAGE_KEYS))
    ranges["image"] = {n: _range(src, f"image.{k}", v) for k, v in image.items() for n in IMAGE_KEYS[k]}
    return Tolerances({t: r for t, r in ranges.items() if r}, dist, src)


def load_tolerances(path: str | Path, lens: Lens) -> Tolerances:
    """Read a tolerance YAML/JSON file for a lens (one-line InputError on a bad file)."""
    import yaml

    from lensim.io import read_text

    p = Path(path)
    text = read_text(p, "tolerance file")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "syntax"
        raise InputError(str(p), where, f"not valid YAML: {getattr(e, 'problem', None) or e}") from None
    return tolerances_from_dict(data, lens, str(p))


@dataclass
class Draw:
    """One seeded draw: its seed and index, and the perturbation (parameter -> value)."""

    seed: int
    index: int
    values: dict[str, float] = field(default_factory=dict)


def draw(tol: Tolerances, seed: int, index: int) -> Draw:
    """Draw `index` of the sequence `seed`: the same values whatever the number of draws
    (each draw has its own generator, seeded by (seed, index))."""
    rng = np.random.default_rng([int(seed), int(index)])
    values = {}
    for name, r in sorted(tol.parameters().items()):
        if tol.distribution == "normal":
            v = float(np.clip(rng.normal(0.0, r / 2.0), -r, r))
        else:
            v = float(rng.uniform(-r, r))
        values[name] = v
    return Draw(int(seed), int(index), values)


def _element_span(target: str, groups: list[list[int]]) -> list[int]:
    """The 0-based surfaces of a target "e2" / "e3-4"."""
    a, _, b = target[1:].partition("-")
    first, last = int(a), int(b or a)
    if not 1 <= first <= last <= len(groups):
        raise InputError(None, "perturbation", f"expected elements 1..{len(groups)}, got {target}")
    return [i for g in groups[first - 1 : last] for i in g]


def _split(values: dict[str, float]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for name, v in values.items():
        target, _, kind = name.partition(".")
        out.setdefault(target, {})[kind] = float(v)
    return out


def perturbed_lens(lens: Lens, values: dict[str, float], record: dict | None = None) -> Lens:
    """The lens with a perturbation applied (parameter names in the module docstring):
    element decentres and tilts as surface poses (rigid about the element's axial centre),
    thicknesses and spacings added, the image plane moved and tilted. record: stored in
    the lens's as_built (with the values)."""
    groups = elements(lens)
    surfaces = list(lens.surfaces)
    zv = lens.vertex_z()
    defocus, tilt = lens.image_defocus, lens.image_tilt
    for target, kinds in _split(values).items():
        if target == "image":
            defocus += kinds.get("focus", 0.0)
            tilt = (tilt[0] + kinds.get("tilt_x", 0.0), tilt[1] + kinds.get("tilt_y", 0.0))
            continue
        if not target.startswith("e"):
            raise InputError(None, "perturbation", f"expected targets like e2, e3-4 or image, got {target!r}")
        span = _element_span(target, groups)
        poses = element_poses(
            (kinds.get("decentre_x", 0.0), kinds.get("decentre_y", 0.0)),
            (kinds.get("tilt_x", 0.0), kinds.get("tilt_y", 0.0)),
            [float(zv[i]) for i in span],
            0.5 * float(zv[span[0]] + zv[span[-1]]),
        )
        for i, p in zip(span, poses, strict=True):
            s = surfaces[i]
            extra = kinds.get("thickness", 0.0) if i != span[-1] and not isinstance(s.material, Air) else 0.0
            extra += kinds.get("spacing", 0.0) if i == span[-1] else 0.0
            surfaces[i] = dataclasses.replace(s, pose=compose(s.pose, p), thickness=s.thickness + extra)
    as_built = dict(record or {})
    as_built["parameters"] = {k: float(v) for k, v in sorted(values.items())}
    return lens.with_changes(surfaces=surfaces, image_defocus=defocus, image_tilt=tilt, as_built=as_built)


def drawn_lens(lens: Lens, tol: Tolerances, seed: int, index: int) -> Lens:
    """perturbed_lens of draw(tol, seed, index), its record naming the tolerances, seed and draw."""
    d = draw(tol, seed, index)
    record = {"kind": "tolerance draw", "tolerances": tol.source, "seed": d.seed, "draw": d.index}
    out = perturbed_lens(lens, d.values, record)
    return out.with_changes(name=f"{lens.name} (tolerance draw {d.index}, seed {d.seed})".strip())
