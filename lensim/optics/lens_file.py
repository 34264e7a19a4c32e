"""lensim's native lens file format (JSON or YAML) and the loader for every lens format.

    name: Cooke triplet
    units: mm                      # lengths in mm (the only unit accepted)
    object: {distance: infinity}   # or a distance in mm from the first vertex
    aperture: {type: epd, value: 10}           # epd (mm) | fno (image-space EFL/EPD) | stop_semi_diameter (mm)
    fields: {type: angle, values: [0, 14, 20]}
    # fields.type: angle (deg) | object_height | paraxial_image_height | real_image_height (mm)
    wavelengths: {nm: [480, 550, 650], weights: [1, 1, 1], primary: 1}   # primary: index into nm
    surfaces:                      # first surface to last surface before the image
      - {radius: 22.01359, thickness: 3.25896, material: J-SK16@Hikari}
      - {radius: -435.76044, thickness: 6.00755}          # material defaults to air
      - {radius: 20.29192, thickness: 4.75041, stop: true}
      - {radius: 5.6, conic: -0.8, asphere: {r4: 1.1e-5, r6: 1.8e-7}, clear_semi_diameter: 3.2}
      - {radius: -120, thickness: -30, mirror: true, obscuration: 5}
    image: {defocus: 0.0}          # optional tilt: [x, y] (deg), a tilted sensor
    configurations:                # optional: zoom/focus positions, chosen by name or 1-based number
      wide: {thicknesses: {1: 6.0, 4: 40.2}}   # 0-based surface index: thickness (mm)
      tele: {thicknesses: {1: 0.8, 4: 52.7}}
    focus: {thickness: 1, compensator: 4}   # optional: a focus group moving between gaps 1 and 4

Surface keys: radius (mm, 'infinity' or omitted for a plane) or curvature (1/mm),
thickness (mm to the next vertex; negative after a mirror, or in air to place a stop
or dummy surface behind the next vertex, as in Zemax), material (glass name,
name@Catalog, air, {nd, vd[, dpgf][, model: true]} model glass or {n} constant index;
a bare {nd, vd} pair that matches a catalogue glass within its rounding is that glass
unless `model: true`), conic, asphere
({r1..r20: coefficient}; even powers only: an even asphere, any odd power: an odd
asphere), clear_semi_diameter (vignetting), obscuration (central
obscuration radius), semi_diameter (drawing only), stop, mirror, comment, and for an
as-built or toleranced lens decentre ([x, y] mm) and tilt ([x, y] deg about the vertex;
lensim.optics.pose). as_built: the record of a tolerance draw or a calibration (free form,
kept with the lens).
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path
from typing import Any

from lensim.errors import InputError
from lensim.io import atomic_write_text, read_text
from lensim.optics.lens import Lens
from lensim.optics.materials import (
    Air,
    Material,
    ModelGlass,
    catalogue_twin,
    material_from_spec,
    nearest_catalog_glass,
    twin_note,
)
from lensim.optics.surfaces import MAX_ASPHERE_POWER, Surface

TOP_KEYS = {
    "name",
    "description",
    "units",
    "object",
    "aperture",
    "fields",
    "wavelengths",
    "surfaces",
    "image",
    "notes",
    "source",
    "configurations",
    "focus",
    "as_built",
}
FOCUS_KEYS = {"thickness", "compensator"}
CONFIGURATION_KEYS = {"thicknesses"}
SURFACE_KEYS = {
    "radius",
    "curvature",
    "thickness",
    "material",
    "conic",
    "asphere",
    "clear_semi_diameter",
    "obscuration",
    "semi_diameter",
    "stop",
    "mirror",
    "comment",
    "decentre",
    "tilt",
}


class LensNoteWarning(UserWarning):
    """Something about a loaded lens file the user must know (a setting not applied,
    an assumption made)."""


class GlassSubstitutionWarning(LensNoteWarning):
    """A glass was not found exactly as named and a stated substitute was used."""


def _number(src: str, field: str, value: Any, allow_inf: bool = False) -> float:
    if isinstance(value, str) and value.strip().lower() in ("inf", "infinity", "+inf") and allow_inf:
        return math.inf
    if isinstance(value, bool):
        raise InputError(src, field, f"expected a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(src, field, f"expected a number, got {value!r}") from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise InputError(src, field, f"expected a finite number, got {value!r}")
    return x


#: the largest thickness or finite object distance (mm) a lens file may give: 1 km; beyond
#: it a value is a typo, and an object that far is at infinity for any camera lens
MAX_LENGTH_MM = 1.0e6


def _length(src: str, field: str, value: Any, allow_inf: bool = False) -> float:
    """A length in mm within +-MAX_LENGTH_MM (or infinity where allowed)."""
    x = _number(src, field, value, allow_inf=allow_inf)
    if math.isfinite(x) and abs(x) > MAX_LENGTH_MM:
        hint = "; give infinity for an object at infinity" if allow_inf else ""
        raise InputError(src, field, f"expected a length within +-{MAX_LENGTH_MM:g} mm, got {x:g} mm{hint}")
    return x


def _check_keys(src: str, field: str, data: Any, allowed: set[str]) -> dict:
    if not isinstance(data, dict):
        raise InputError(src, field, f"expected a mapping, got {type(data).__name__}")
    unknown = sorted(str(k) for k in set(data) - allowed)  # YAML keys may be numbers
    if unknown:
        raise InputError(
            src, field, f"unknown key(s) {', '.join(unknown)}; expected some of {', '.join(sorted(allowed))}"
        )
    return data


def lens_from_dict(data: dict, source: str = "<lens>") -> Lens:
    """Build and validate a Lens from the native format's mapping."""
    src = source
    data = _check_keys(src, "lens", data, TOP_KEYS)
    units = data.get("units", "mm")
    if units != "mm":
        raise InputError(src, "units", f"expected 'mm', got {units!r}")
    obj = _check_keys(src, "object", data.get("object", {}), {"distance", "material"})
    distance = _length(src, "object.distance", obj.get("distance", "infinity"), allow_inf=True)
    ap = _check_keys(src, "aperture", data.get("aperture", {}), {"type", "value"})
    if "value" not in ap:
        raise InputError(src, "aperture.value", "missing; expected the aperture size")
    flds = _check_keys(src, "fields", data.get("fields", {"values": [0]}), {"type", "values"})
    values = flds.get("values", [0])
    if not isinstance(values, list):
        raise InputError(src, "fields.values", f"expected a list of numbers, got {values!r}")
    nm, weights, primary = _wavelengths_from_data(src, data.get("wavelengths", {"nm": [587.5618]}))
    surfaces_data = data.get("surfaces")
    if not isinstance(surfaces_data, list) or not surfaces_data:
        raise InputError(src, "surfaces", "expected a non-empty list of surfaces")
    notes = data.get("notes", [])
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise InputError(src, "notes", f"expected a list of texts, got {notes!r}")
    notes = list(notes)
    surfaces = [_surface_from_data(src, i, sd, notes) for i, sd in enumerate(surfaces_data)]
    image = _check_keys(src, "image", data.get("image", {}) or {}, {"defocus", "clear_semi_diameter", "tilt"})
    as_built = data.get("as_built", {}) or {}
    if not isinstance(as_built, dict):
        raise InputError(src, "as_built", f"expected a mapping, got {type(as_built).__name__}")
    lens = Lens(
        surfaces=surfaces,
        aperture_type=str(ap.get("type", "epd")),
        aperture_value=_number(src, "aperture.value", ap["value"]),
        field_type=str(flds.get("type", "angle")),
        fields=[_number(src, f"fields.values[{i}]", v) for i, v in enumerate(values)],
        wavelengths_um=[v / 1000.0 for v in nm],
        wavelength_weights=[_number(src, f"wavelengths.weights[{i}]", v) for i, v in enumerate(weights)],
        primary=primary,
        object_distance=distance,
        object_material=material_from_spec(obj.get("material", "air")),
        image_defocus=_number(src, "image.defocus", image.get("defocus", 0.0)),
        image_clear_radius=(
            None
            if image.get("clear_semi_diameter") is None
            else _number(src, "image.clear_semi_diameter", image["clear_semi_diameter"])
        ),
        name=str(data.get("name", "")),
        source=source,
        notes=notes,
        configurations=_configurations_from_data(src, data.get("configurations", {})),
        **_focus_from_data(src, data.get("focus")),
        image_tilt=_pair(src, "image.tilt", image.get("tilt", [0.0, 0.0])),
        as_built=as_built,
    )
    return lens


def _pair(src: str, field: str, value: Any) -> tuple[float, float]:
    """An [x, y] pair of numbers (a decentre in mm or a tilt in degrees)."""
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise InputError(src, field, f"expected a pair [x, y] of numbers, got {value!r}")
    x, y = (_number(src, f"{field}[{i}]", v) for i, v in enumerate(value))
    if abs(x) > MAX_POSE or abs(y) > MAX_POSE:
        raise InputError(src, field, f"expected values within +-{MAX_POSE:g} (mm or deg), got [{x:g}, {y:g}]")
    return x, y


#: the largest decentre (mm) or tilt (deg) a lens file may give: beyond it the "as-built"
#: lens is another lens (and a tilt near 90 deg would turn a surface edge-on)
MAX_POSE = 45.0


def _wavelengths_from_data(src: str, data: Any) -> tuple[list[float], list, int]:
    """The ``wavelengths`` block {nm: [...], weights: [...], primary: i}: (wavelengths in
    nm, the weights as given (one list; Lens checks them), the 0-based primary index)."""
    wls = _check_keys(src, "wavelengths", data, {"nm", "weights", "primary"})
    nm = wls.get("nm")
    if not isinstance(nm, list) or not nm:
        raise InputError(src, "wavelengths.nm", f"expected a non-empty list of wavelengths in nm, got {nm!r}")
    nm = [_number(src, f"wavelengths.nm[{i}]", v) for i, v in enumerate(nm)]
    weights = wls.get("weights", [1.0] * len(nm))
    if not isinstance(weights, list):
        raise InputError(src, "wavelengths.weights", "expected a list of numbers")
    primary = wls.get("primary", 0)
    if not isinstance(primary, int) or isinstance(primary, bool):
        raise InputError(src, "wavelengths.primary", f"expected an integer index, got {primary!r}")
    return nm, weights, primary


def _curvature_from_data(src: str, f: str, sd: dict) -> float:
    """A surface's curvature (1/mm) from its radius or curvature key (a plane without either)."""
    if "radius" in sd and "curvature" in sd:
        raise InputError(src, f, "give either radius or curvature, not both")
    if "curvature" in sd:
        return _number(src, f + ".curvature", sd["curvature"])
    r = _number(src, f + ".radius", sd.get("radius", "infinity"), allow_inf=True)
    if r == 0:
        raise InputError(src, f + ".radius", "expected a non-zero radius (use infinity for a plane)")
    return 0.0 if math.isinf(r) else 1.0 / r


def _asphere_from_data(src: str, f: str, raw: Any) -> dict[int, float]:
    """A surface's ``asphere`` block {rN: coefficient} as {N: coefficient}."""
    raw = raw or {}
    if not isinstance(raw, dict):
        raise InputError(src, f + ".asphere", "expected a mapping like {r4: 1e-5, r6: -2e-8}")
    asphere = {}
    for k, v in raw.items():
        ks = str(k).lower().lstrip("ra")
        if not ks.isdigit() or not 1 <= int(ks) <= MAX_ASPHERE_POWER:
            raise InputError(
                src,
                f"{f}.asphere.{k}",
                f"expected a key r1, r2, ... r{MAX_ASPHERE_POWER} "
                "(even powers: an even asphere; any odd power: an odd asphere)",
            )
        asphere[int(ks)] = _number(src, f"{f}.asphere.{k}", v)
    return asphere


# optional surface keys that are numbers: native key -> Surface attribute
_SURFACE_NUMBERS = (
    ("clear_semi_diameter", "clear_radius"),
    ("obscuration", "obscuration_radius"),
    ("semi_diameter", "semi_diameter"),
)


def _surface_from_data(src: str, i: int, sd: Any, notes: list[str]) -> Surface:
    """surfaces[i] of a native file as a Surface (glass notes are appended to ``notes``)."""
    f = f"surfaces[{i}]"
    sd = _check_keys(src, f, sd, SURFACE_KEYS)
    curv = _curvature_from_data(src, f, sd)
    asphere = _asphere_from_data(src, f, sd.get("asphere", {}))
    try:
        material = material_from_spec(sd.get("material", "air"), notes=notes)
    except InputError as e:
        raise InputError(src, f + ".material", e.message) from None
    opt = {attr: _number(src, f"{f}.{key}", sd[key]) for key, attr in _SURFACE_NUMBERS if sd.get(key) is not None}
    for key in ("stop", "mirror"):
        if key in sd and not isinstance(sd[key], bool):
            raise InputError(src, f"{f}.{key}", f"expected true or false, got {sd[key]!r}")
    return Surface(
        curvature=curv,
        thickness=_length(src, f + ".thickness", sd.get("thickness", 0.0)),
        material=material,
        conic=_number(src, f + ".conic", sd.get("conic", 0.0)),
        asphere=asphere,
        is_stop=bool(sd.get("stop", False)),
        is_mirror=bool(sd.get("mirror", False)),
        comment=str(sd.get("comment", "")),
        pose=(
            *_pair(src, f + ".decentre", sd.get("decentre", [0.0, 0.0])),
            *_pair(src, f + ".tilt", sd.get("tilt", [0.0, 0.0])),
        ),
        **opt,
    )


def _focus_from_data(src: str, data: Any) -> dict[str, int | None]:
    """The ``focus`` block {thickness: i[, compensator: j]}: the focus group's gap (0-based
    surface index) and the gap that compensates it. The Lens checks the indices."""
    if data is None:
        return {}
    data = _check_keys(src, "focus", data, FOCUS_KEYS)
    if "thickness" not in data:
        raise InputError(
            src,
            "focus.thickness",
            "missing; expected the 0-based index of the surface whose thickness (an air gap) the focus group changes",
        )
    out: dict[str, int | None] = {}
    for key, attr in (("thickness", "focus_thickness"), ("compensator", "focus_compensator")):
        value = data.get(key)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(src, f"focus.{key}", f"expected a 0-based surface index (an integer), got {value!r}")
        out[attr] = value
    return out


def _configurations_from_data(src: str, data: Any) -> dict[str, dict[int, float]]:
    """The ``configurations`` block: {name: {thicknesses: {surface index: mm}}} (indices
    0-based, as integers or digit strings, JSON's keys being strings). The Lens checks the
    indices' range and each configuration's lens."""
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(
            src,
            "configurations",
            f"expected a mapping of configuration name: {{thicknesses: ...}}, got {type(data).__name__}",
        )
    out: dict[str, dict[int, float]] = {}
    for name, conf in data.items():
        fld = f"configurations.{name}"
        conf = _check_keys(src, fld, conf if conf is not None else {}, CONFIGURATION_KEYS)
        thick = conf.get("thicknesses", {})
        if not isinstance(thick, dict):
            raise InputError(
                src, f"{fld}.thicknesses", f"expected a mapping of surface index: thickness (mm), got {thick!r}"
            )
        values: dict[int, float] = {}
        for index, value in thick.items():
            text = str(index).strip()
            if isinstance(index, bool) or not text.isdigit():
                raise InputError(
                    src, f"{fld}.thicknesses", f"expected 0-based surface indices (as in surfaces[i]), got {index!r}"
                )
            values[int(text)] = _length(src, f"{fld}.thicknesses.{text}", value)
        out[str(name)] = values
    return out


def _material_spec(m: Material):
    if isinstance(m, Air):
        return "air"
    return m.spec()


def _surface_to_dict(s: Surface) -> dict[str, Any]:
    """One surface in the native format (keys left out where they hold their default)."""
    d: dict[str, Any] = {"radius": "infinity" if s.curvature == 0 else 1.0 / s.curvature, "thickness": s.thickness}
    if not isinstance(s.material, Air) and not s.is_mirror:
        d["material"] = _material_spec(s.material)
    if s.conic:
        d["conic"] = s.conic
    if s.asphere:
        d["asphere"] = {f"r{p}": v for p, v in sorted(s.asphere.items()) if v}
    for key, attr in _SURFACE_NUMBERS:
        if getattr(s, attr) is not None:
            d[key] = getattr(s, attr)
    d.update({key: True for key, on in (("stop", s.is_stop), ("mirror", s.is_mirror)) if on})
    if s.comment:
        d["comment"] = s.comment
    if s.pose[:2] != (0.0, 0.0):
        d["decentre"] = [float(v) for v in s.pose[:2]]
    if s.pose[2:] != (0.0, 0.0):
        d["tilt"] = [float(v) for v in s.pose[2:]]
    return d


def lens_to_dict(lens: Lens) -> dict:
    """The native-format mapping of a lens (round-trips through lens_from_dict)."""
    surfaces = [_surface_to_dict(s) for s in lens.surfaces]
    out: dict[str, Any] = {
        "name": lens.name,
        "units": "mm",
        "object": {"distance": "infinity" if lens.infinite_object else lens.object_distance},
        "aperture": {"type": lens.aperture_type, "value": lens.aperture_value},
        "fields": {"type": lens.field_type, "values": list(lens.fields)},
        "wavelengths": {
            "nm": [round(w * 1000.0, 6) for w in lens.wavelengths_um],
            "weights": list(lens.wavelength_weights or []),
            "primary": lens.primary,
        },
        "surfaces": surfaces,
        "image": {"defocus": lens.image_defocus},
    }
    if not isinstance(lens.object_material, Air):
        out["object"]["material"] = _material_spec(lens.object_material)
    if lens.image_clear_radius is not None:
        out["image"]["clear_semi_diameter"] = lens.image_clear_radius
    if any(lens.image_tilt):
        out["image"]["tilt"] = [float(v) for v in lens.image_tilt]
    if lens.as_built:
        out["as_built"] = lens.as_built
    if lens.notes:
        out["notes"] = list(lens.notes)
    if lens.configurations:
        out["configurations"] = {
            name: {"thicknesses": dict(sorted(t.items()))} for name, t in lens.configurations.items()
        }
    if lens.focus_thickness is not None:
        out["focus"] = {"thickness": lens.focus_thickness}
        if lens.focus_compensator is not None:
            out["focus"]["compensator"] = lens.focus_compensator
    return out


def match_glasses(lens: Lens, makers: list[str] | None = None) -> tuple[Lens, list[dict]]:
    """Replace every model glass (nd/Vd/dPgF) of a lens by its nearest catalogue glass.

    Nearest: the smallest RMS index difference over 400-700 nm (materials.nearest_catalog_glass),
    searched in `makers`' catalogues (default every catalogue). Returns the new lens, with a
    note per replaced surface, and one record per replaced surface: surface (0-based index),
    model {nd, vd, dpgf}, glass, catalog, nd, vd, rms_index_difference.
    """
    surfaces, matches, notes = [], [], list(lens.notes)
    found: dict[ModelGlass, tuple] = {}
    for i, s in enumerate(lens.surfaces):
        m = s.material
        if not isinstance(m, ModelGlass) or s.is_mirror:
            surfaces.append(s)
            continue
        if m not in found:
            found[m] = nearest_catalog_glass(m, makers)
        glass, rms = found[m]
        surfaces.append(dataclasses.replace(s, material=glass))
        matches.append(
            {
                "surface": i,
                "model": {"nd": m.nd_value, "vd": m.vd_value, "dpgf": m.dpgf_value},
                "glass": glass.name,
                "catalog": glass.catalog,
                "nd": glass.nd,
                "vd": glass.vd,
                "rms_index_difference": rms,
            }
        )
        notes.append(
            f"surfaces[{i}]: model glass nd {m.nd_value:.5f}, Vd {m.vd_value:.2f}, dPgF {m.dpgf_value:+.4f} "
            f"replaced by the nearest catalogue glass {glass.name} ({glass.catalog}; nd {glass.nd:.5f}, "
            f"Vd {glass.vd:.2f}; RMS index difference {rms:.1e} over 400-700 nm)"
        )
    return lens.with_changes(surfaces=surfaces, notes=notes), matches


def use_catalogue_twins(lens: Lens, makers: list[str] | None = None) -> tuple[Lens, list[dict]]:
    """Replace each bare nd/Vd pair (a patent's glass: a model glass with dPgF 0, not forced)
    by the catalogue glass it matches within its rounding (materials.catalogue_twin), so that
    the glass keeps its partial dispersion; pairs that match nothing stay model glasses.
    Returns the new lens, with one note line for all the replacements, and one record per
    replaced surface: surface (0-based index), model {nd, vd}, glass, catalog, nd, vd, dpgf."""
    key = tuple(makers) if makers else None
    surfaces, records = [], []
    replaced: dict[tuple[ModelGlass, Material], list[int]] = {}
    for i, s in enumerate(lens.surfaces):
        m = s.material
        twin = catalogue_twin(m, key) if isinstance(m, ModelGlass) and not s.is_mirror else None
        if twin is None or not isinstance(m, ModelGlass):
            surfaces.append(s)
            continue
        surfaces.append(dataclasses.replace(s, material=twin))
        replaced.setdefault((m, twin), []).append(i)
        records.append(
            {
                "surface": i,
                "model": {"nd": m.nd_value, "vd": m.vd_value},
                "glass": twin.name,
                "catalog": twin.catalog,
                "nd": twin.nd,
                "vd": twin.vd,
                "dpgf": twin.dpgf,
            }
        )
    if not records:
        return lens, []
    note = twin_note([(idx, m, g) for (m, g), idx in replaced.items()])  # type: ignore[misc]
    return lens.with_changes(surfaces=surfaces, notes=[*lens.notes, note]), records


def keep_model_glasses(lens: Lens) -> Lens:
    """The lens with each bare nd/Vd pair marked to stay a model glass (``forced``: written
    ``model: true``), where use_catalogue_twins would take a catalogue glass."""
    surfaces = [
        dataclasses.replace(s, material=dataclasses.replace(s.material, forced=True))
        if isinstance(s.material, ModelGlass) and s.material.dpgf_value == 0.0
        else s
        for s in lens.surfaces
    ]
    return lens.with_changes(surfaces=surfaces)


def save_lens(lens: Lens, path: str | Path) -> None:
    """Write a lens in the native format (.json, or .yaml/.yml), atomically."""
    path = Path(path)
    # numpy scalars (a lens at shooting settings carries them) as plain numbers: YAML's safe dumper refuses them
    data = json.loads(json.dumps(lens_to_dict(lens), default=lambda v: v.item()))
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    elif path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        raise InputError(str(path), "path", "expected a .json, .yaml or .yml file name for a native lens file")
    atomic_write_text(path, text)


def _read_native(path: Path) -> dict:
    """Parse a native JSON/YAML file; syntax errors name the line and what was expected."""
    import yaml

    text = read_text(path, "lens file")
    try:
        if path.suffix.lower() == ".json":
            return json.loads(text)
        return yaml.safe_load(text)
    except json.JSONDecodeError as e:
        raise InputError(str(path), f"line {e.lineno} column {e.colno}", f"not valid JSON: {e.msg}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1} column {mark.column + 1}" if mark is not None else "syntax"
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        context = getattr(e, "context", None)
        msg = f"not valid YAML: {problem}" + (f" ({context})" if context else "")
        raise InputError(str(path), where, msg) from None


def load_lens(path: str | Path, warn: bool = True, model_glasses: bool = False) -> Lens:
    """Load a lens from a native .json/.yaml file, a Zemax .zmx or a CODE V .seq file,
    or a built-in lens by name (see lensim.assets). A bare nd/Vd pair (a patent's glass)
    that matches a catalogue glass within its rounding becomes that glass
    (use_catalogue_twins; one note says which); with model_glasses every pair stays a model
    glass on the normal line (keep_model_glasses). Every note (kept in lens.notes) is also
    issued as a LensNoteWarning; glass substitutions as GlassSubstitutionWarning."""
    from lensim import assets

    p = Path(path)
    if not p.exists():
        builtin = assets.lens_path(str(path))
        if builtin is None:
            raise InputError(
                str(path), None, f"no such file, and not a built-in lens (built-ins: {', '.join(assets.lens_names())})"
            )
        p = builtin
    suffix = p.suffix.lower()
    if suffix in (".json", ".yaml", ".yml"):
        data = _read_native(p)
        if not isinstance(data, dict):
            raise InputError(str(p), "lens", "expected a mapping at the top level")
        lens = lens_from_dict(data, source=str(p))
    elif suffix == ".zmx":
        from lensim.optics.zemax import read_zmx

        lens = read_zmx(p)
    elif suffix == ".seq":
        from lensim.optics.codev import read_seq

        lens = read_seq(p)
    else:
        raise InputError(str(p), None, "unknown lens file type; expected .json, .yaml, .yml, .zmx or .seq")
    lens = keep_model_glasses(lens) if model_glasses else use_catalogue_twins(lens)[0]
    if warn:
        for note in lens.notes:
            category = GlassSubstitutionWarning if note.startswith("glass ") else LensNoteWarning
            warnings.warn(f"{p}: {note}", category, stacklevel=2)
    return lens
