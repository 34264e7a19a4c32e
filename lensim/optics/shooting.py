"""Shooting settings: aperture, focus distance, object distance and zoom position.

A camera sets a lens to an F-number, focuses it at a distance and (a zoom) picks a focal
length; the subject may stand at another distance than the one focused on. ShootingSettings
holds those four choices, ``None`` meaning "as the lens file has it", and
``lens_at(lens, settings)`` returns the lens at them:

1. ``config`` (a configuration name or 1-based number) is applied first
   (lensim.optics.configurations): a zoom position's thicknesses.
2. Focus at ``focus_m`` metres *from the image plane* (as cameras report it), ``math.inf``
   allowed, as a camera's autofocus does it. The best focus is the criterion of
   lensim.psf.best_focus (minimum polychromatic RMS wavefront error on axis, at the taking
   aperture). ``focus_mode`` "calibrated" (default): the image plane keeps the lens file's
   own offset from its best focus, so it follows the best focus as spherical aberration
   changes with the distance, and the file's own focus distance (infinity, for most files)
   leaves the file's image plane where it is (designers often balance the field there:
   the Cooke triplet's plane is 74 um inside its on-axis best focus). "best": the plane on
   the best focus itself (a centre-point autofocus), at infinity too. "paraxial" keeps the
   file's offset from the paraxial image (lensim before 2026-11; the best focus of a fast
   lens moves away from it at near distances). Unit focusing by default (the image plane
   moves); a lens file that names a
   focus group (native ``focus: {thickness: i[, compensator: j]}``) moves that group
   instead: thickness i is solved (thickness j changes by the opposite amount, so the
   group moves between the two gaps), and everything behind the gap(s), the image plane
   included, stays where it is relative to it. The distance is measured from the image
   plane of the *focused* lens, so the solve includes the lens's own change of length.
3. The aperture: ``fno`` N sets the physical stop so that the paraxial image-space
   F-number for an object at infinity, EFL / EPD of the lens focused at infinity, is N.
   The stop then keeps that size whatever the focus (a real iris does), so the working
   F-number at a near object is larger (``describe`` reports it). The lens file's own
   aperture (its stop size at the file's own settings, and the stop surface's clear
   semi-diameter where given) is the largest the iris opens: an N within 1/6 stop of it
   (a marking rounded to third stops) means wide open, with one UserWarning line saying
   so; a faster N is refused.
   Without ``fno`` the stop keeps the file's size.
4. The object at ``object_m`` metres from the image plane (math.inf: at infinity). Only
   one of object_m and focus_m given: the other equals it (the camera focused on its
   subject); both given and different: the object is out of focus.

Object-height fields are turned into the angles they subtend at the file's object
distance when the object moves (so the same part of the image is covered); angle and
image-height fields are kept. Lengths in mm inside lensim, distances of this module's
settings in metres.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from lensim.errors import InputError, LensimError, ParameterError
from lensim.jsonable import strict_json
from lensim.optics.configurations import apply_configuration, resolve_configuration
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data

#: the settings, as ShootingSettings' fields (and the parameters its errors name)
SETTINGS = ("fno", "object_m", "focus_m", "config")
#: how a focus distance is focused (the best focus: lensim.psf.best_focus's criterion, on
#: axis at the taking aperture): "calibrated" (default; the image plane keeps the lens
#: file's own offset from its best focus, so it follows the best focus as it moves with the
#: distance, and the file's own focus distance is the file's image plane), "best" (the
#: plane on the best focus itself: a centre-point autofocus), "paraxial" (the file's
#: offset from the paraxial image kept, lensim before 2026-11)
FOCUS_MODES = ("calibrated", "best", "paraxial")
#: how close (mm) the image plane must come to best focus
_BEST_TOLERANCE_MM = 1e-5
_BEST_ITERATIONS = 6
#: best focus solved before, by (the lens, the distance, the mode): lens_at runs again for records
_BEST_MEMO: dict[tuple[str, float, str], dict[int, float]] = {}
_MEMO_SIZE = 64
#: the largest finite distance (m) a setting may give: beyond it the object is at infinity for any camera lens
MAX_DISTANCE_M = 1.0e6
_NEWTON_STEPS = 60
_TOLERANCE_MM = 1e-9
#: how much faster than wide open (in stops) an fno may be and still mean wide open: marked
#: F-numbers are rounded to third stops (F/3.5 on a lens at F/3.56) and EXIF FNumber carries the marking
WIDE_OPEN_TOLERANCE_STOPS = 1.0 / 6.0


def _number(value: Any, key: str, allow_inf: bool) -> float:
    """A setting's number: a positive float (math.inf where allowed); a ParameterError naming the setting."""
    if isinstance(value, str) and value.strip().lower() in ("inf", "infinity", "+inf"):
        value = math.inf
    if isinstance(value, bool):
        raise ParameterError(None, key, f"expected a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ParameterError(None, key, f"expected a number, got {value!r}") from None
    if key == "fno":
        if not (math.isfinite(x) and x > 0):
            raise ParameterError(None, key, f"expected a positive, finite F-number, got {value!r}")
        return x
    if math.isnan(x) or x <= 0 or (math.isinf(x) and not allow_inf):
        raise ParameterError(None, key, f"expected a positive distance in metres or inf, got {value!r}")
    if math.isfinite(x) and x > MAX_DISTANCE_M:
        raise ParameterError(
            None,
            key,
            f"expected a distance up to {MAX_DISTANCE_M:g} m (give inf for infinity), got {x:g} m",
        )
    return x


@dataclass(frozen=True)
class ShootingSettings:
    """How the camera is set: fno (F-number at infinity, image space), object_m (object
    distance from the image plane, m, math.inf allowed), focus_m (focus distance from the
    image plane, m, math.inf allowed), config (configuration name or 1-based number, as a
    string). None: as the lens file has it. focus_mode (FOCUS_MODES): how a focus distance
    is focused, "calibrated" (default), "best" or "paraxial". Values are checked when made
    (a ParameterError naming the setting)."""

    fno: float | None = None
    object_m: float | None = None
    focus_m: float | None = None
    config: str | None = None
    focus_mode: str = "calibrated"

    def __post_init__(self) -> None:
        for key in ("fno", "object_m", "focus_m"):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, _number(value, key, allow_inf=key != "fno"))
        if self.config is not None:
            if isinstance(self.config, bool) or not str(self.config).strip():
                raise ParameterError(None, "config", f"expected a configuration name or number, got {self.config!r}")
            object.__setattr__(self, "config", str(self.config).strip())
        if self.focus_mode not in FOCUS_MODES:
            raise ParameterError(
                None, "focus_mode", f"expected one of {', '.join(FOCUS_MODES)}, got {self.focus_mode!r}"
            )

    @property
    def is_default(self) -> bool:
        """True when every setting is the lens file's (lens_at returns the lens as it is)."""
        return self.fno is None and self.object_m is None and self.focus_m is None and self.config is None

    def to_dict(self) -> dict[str, Any]:
        """{fno, object_m, focus_m, config}; None where not set, infinite distances as the
        string "inf" (strict JSON); focus_mode only where it is not the default "calibrated"."""
        out = {"fno": self.fno, "object_m": self.object_m, "focus_m": self.focus_m, "config": self.config}
        if self.focus_mode != "calibrated":
            out["focus_mode"] = self.focus_mode
        return strict_json(out)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ShootingSettings:
        """The settings to_dict wrote (missing keys: None; "inf" or a float for distances)."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            raise InputError(
                None, "settings", f"expected a mapping of fno, object_m, focus_m, config, got {type(data).__name__}"
            )
        keys = (*SETTINGS, "focus_mode")
        unknown = sorted(set(data) - set(keys))
        if unknown:
            raise InputError(
                None, "settings", f"unknown key(s) {', '.join(unknown)}; expected some of {', '.join(keys)}"
            )
        return cls(**{k: data.get(k) for k in SETTINGS}, focus_mode=data.get("focus_mode", "calibrated"))

    @classmethod
    def from_text(
        cls,
        fno: str | None = None,
        object_m: str | None = None,
        focus_m: str | None = None,
        config: str | None = None,
        focus_mode: str | None = None,
    ) -> ShootingSettings:
        """From text (as typed): numbers, distances also "inf"; None where not given
        (focus_mode: "calibrated")."""
        numbers = {
            k: None if v is None else _number(v, k, allow_inf=k != "fno")
            for k, v in (("fno", fno), ("object_m", object_m), ("focus_m", focus_m))
        }
        mode = "calibrated" if focus_mode is None else focus_mode.strip().lower()
        return cls(**numbers, config=config, focus_mode=mode)

    def distances_m(self) -> tuple[float | None, float | None]:
        """(object_m, focus_m) with one given for the other when only one is set."""
        obj = self.object_m if self.object_m is not None else self.focus_m
        foc = self.focus_m if self.focus_m is not None else self.object_m
        return obj, foc


# ---------------------------------------------------------------- focusing


def _with_thickness(lens: Lens, changes: dict[int, float]) -> Lens:
    surfaces = [
        dataclasses.replace(s, thickness=changes[i]) if i in changes else s for i, s in enumerate(lens.surfaces)
    ]
    return lens.with_changes(surfaces=surfaces)


def _image_z(lens: Lens) -> float:
    """z (mm) of the image plane (first vertex at 0)."""
    return float(lens.vertex_z()[-1])


def _focus_offset(lens: Lens) -> float:
    """The image plane's distance (mm) beyond the paraxial image: the designer's best-focus
    offset (image.defocus included)."""
    z = paraxial_data(lens).paraxial_image_z_mm
    if not math.isfinite(z):
        raise InputError(lens.source, "image", "the lens has no finite paraxial image (afocal); it cannot be focused")
    return _image_z(lens) - z


def _object_distance_mm(lens: Lens, distance_m: float, setting: str) -> float:
    """The object distance from the first vertex (mm) of an object distance_m metres from the
    image plane of `lens`; an object inside the lens is refused naming the setting
    (focus_m or object_m)."""
    if math.isinf(distance_m):
        return math.inf
    s = distance_m * 1000.0 - _image_z(lens)
    if not s > 0:
        raise ParameterError(
            None,
            setting,
            f"{distance_m:g} m from the image plane is inside the lens "
            f"(its first vertex is {_image_z(lens) / 1000.0:.4g} m in front "
            "of the image plane); expected a larger distance",
        )
    return s


def _focus_gaps(lens: Lens) -> tuple[int, int | None]:
    """(the gap focusing solves, its compensator): the focus group's, or the last surface's
    thickness (unit focusing: the image plane moves)."""
    if lens.focus_thickness is None:
        return lens.num_surfaces - 1, None
    return lens.focus_thickness, lens.focus_compensator


def _newton(residual: Callable[[float], float], t0: float) -> float | None:
    """A root of residual(t) by Newton's method with a numerical derivative from t0 (None if
    it does not converge or a step leaves the lens's valid range)."""
    t = t0
    for _ in range(_NEWTON_STEPS):
        try:
            r = residual(t)
            if abs(r) < _TOLERANCE_MM:
                return t
            h = 1e-6 * max(1.0, abs(t))
            slope = (residual(t + h) - r) / h
        except LensimError:
            return None
        if slope == 0 or not math.isfinite(slope):
            return None
        step = -r / slope
        t += step
    return None


def _solve_focus(work: Lens, focus_m: float, offset: float) -> dict[int, float]:
    """{surface index: thickness (mm)} that put the image plane of `work` offset mm (along
    z) beyond the paraxial image of an object focus_m metres from the image plane. An
    unreachable distance is a ParameterError naming focus_m."""
    gap, comp = _focus_gaps(work)
    total = work.surfaces[gap].thickness + (work.surfaces[comp].thickness if comp is not None else 0.0)

    def changes(t: float) -> dict[int, float]:
        return {gap: t} if comp is None else {gap: t, comp: total - t}

    def residual(t: float) -> float:
        moved = _with_thickness(work, changes(t))
        moved = moved.with_changes(object_distance=_object_distance_mm(moved, focus_m, "focus_m"))
        return _image_z(moved) - paraxial_data(moved).paraxial_image_z_mm - offset

    what = "its image plane" if work.focus_thickness is None else f"its focus group (surfaces[{gap}].thickness)"
    t = _newton(residual, work.surfaces[gap].thickness)
    if t is None:
        _object_distance_mm(work, focus_m, "focus_m")  # an object inside the lens: that message
        raise ParameterError(
            None,
            "focus_m",
            f"the lens cannot focus at {focus_m:g} m by moving {what}; expected a longer distance",
        )
    try:
        _with_thickness(work, changes(t))
    except InputError as e:
        raise ParameterError(
            None,
            "focus_m",
            f"focusing at {focus_m:g} m moves {what} to {t:.4g} mm, "
            f"which the lens cannot take ({e.field}: {e.message})",
        ) from None
    return changes(t)


def _best_offset(lens: Lens) -> float:
    """The best-focus plane's distance (mm, along z) beyond the paraxial image of the lens
    as it is (lensim.psf.best_focus)."""
    from lensim.psf.best_focus import best_focus_shift  # psf builds on optics

    best_z = _image_z(lens) + float(lens.directions()[-1]) * best_focus_shift(lens)
    return best_z - paraxial_data(lens).paraxial_image_z_mm


def _focused(work: Lens, changes: dict[int, float], focus_m: float) -> Lens:
    """The lens with these thicknesses and its object focus_m metres from its image plane."""
    moved = _with_thickness(work, changes)
    return moved.with_changes(object_distance=_object_distance_mm(moved, focus_m, "focus_m"))


def _best_changes(work: Lens, focus_m: float, focus_mode: str) -> dict[int, float]:
    """focus_changes for "best" and "calibrated": the plane that lands on the best focus
    (plus, calibrated, the file's own offset from its best focus), by a fixed point: the
    best focus moves little with the lens."""
    designer = _focus_offset(work)
    changes = _solve_focus(work, focus_m, designer)
    if focus_mode == "calibrated" and all(abs(t - work.surfaces[i].thickness) < 1e-9 for i, t in changes.items()):
        return {i: work.surfaces[i].thickness for i in changes}  # the file's own focus: as designed
    keep = designer - _best_offset(work) if focus_mode == "calibrated" else 0.0
    offset = designer
    for _ in range(_BEST_ITERATIONS):
        new = _best_offset(_focused(work, changes, focus_m)) + keep
        if abs(new - offset) < _BEST_TOLERANCE_MM:
            break
        offset = new
        changes = _solve_focus(work, focus_m, offset)
    return changes


def focus_changes(lens: Lens, focus_m: float, focus_mode: str = "calibrated") -> dict[int, float]:
    """{surface index: thickness (mm)} that focus the lens at focus_m metres from its image
    plane (math.inf: at infinity), by moving its image plane (unit focusing) or its focus
    group (FOCUS_MODES says how; the best focus is that of lensim.psf.best_focus at the
    lens's own aperture). An unreachable distance is a ParameterError naming focus_m."""
    if focus_mode not in FOCUS_MODES:
        raise ParameterError(None, "focus_mode", f"expected one of {', '.join(FOCUS_MODES)}, got {focus_mode!r}")
    work = lens.with_changes(configurations={}, field_type="angle", fields=[0.0])  # on axis only
    if focus_mode == "paraxial":
        return _solve_focus(work, focus_m, _focus_offset(work))
    key = (repr(work), float(focus_m), focus_mode)
    if key not in _BEST_MEMO:
        if len(_BEST_MEMO) >= _MEMO_SIZE:
            _BEST_MEMO.pop(next(iter(_BEST_MEMO)))
        _BEST_MEMO[key] = _best_changes(work, focus_m, focus_mode)
    return dict(_BEST_MEMO[key])


# ---------------------------------------------------------------- aperture


def _stop_at_fno(lens_inf: Lens, fno: float) -> float:
    """The stop semi-diameter (mm) giving image-space F/fno (EFL / EPD) to a lens whose
    object is at infinity."""
    return paraxial_data(lens_inf.with_changes(aperture_type="fno", aperture_value=fno)).stop_semi_diameter_mm


def _fno_of_stop(lens_inf: Lens, stop_mm: float) -> float:
    """The image-space F-number (EFL / EPD, object at infinity) of a stop semi-diameter (mm)."""
    para = paraxial_data(lens_inf.with_changes(aperture_type="stop_semi_diameter", aperture_value=stop_mm))
    return abs(para.efl_mm) / para.epd_mm


def max_stop_mm(lens: Lens) -> float:
    """The largest stop semi-diameter (mm): the lens file's own (at its own settings), within
    the stop surface's clear semi-diameter when it has one."""
    stop = paraxial_data(lens).stop_semi_diameter_mm
    clear = lens.surfaces[lens.stop_index].clear_radius
    return min(stop, clear) if clear is not None else stop


def _at_infinity(lens: Lens) -> Lens:
    """The lens focused at infinity (its focus group moved; the image plane's place changes
    neither EFL nor EPD), object at infinity, one field on axis."""
    probe = lens.with_changes(configurations={}, object_distance=math.inf, field_type="angle", fields=[0.0])
    if lens.infinite_object or lens.focus_thickness is None:
        return probe
    return _with_thickness(probe, focus_changes(lens, math.inf, "paraxial"))


# ---------------------------------------------------------------- the lens at settings


def _fields_for_object(file_lens: Lens, object_mm: float) -> dict[str, Any]:
    """Field changes for a new object distance: object heights become the angles they
    subtend from the file's entrance pupil (other field types are kept)."""
    if file_lens.field_type != "object_height" or object_mm == file_lens.object_distance:
        return {}
    z_ep = paraxial_data(file_lens).entrance_pupil_z_mm
    reach = file_lens.object_distance + z_ep
    return {"field_type": "angle", "fields": [math.degrees(math.atan2(h, reach)) for h in file_lens.fields]}


def _check_fno(lens_inf: Lens, fno: float, largest_mm: float) -> float:
    """The stop semi-diameter (mm) for F/fno at infinity. An fno faster than wide open by at
    most WIDE_OPEN_TOLERANCE_STOPS is wide open (lens markings and EXIF FNumber are rounded
    to third stops), said in one UserWarning line; a faster fno is refused naming fno."""
    stop = _stop_at_fno(lens_inf, fno)
    if stop > largest_mm * (1 + 1e-9):
        fastest = _fno_of_stop(lens_inf, largest_mm)
        stops = 2.0 * math.log2(fastest / fno)  # the F-number grows by sqrt(2) a stop
        if stops <= WIDE_OPEN_TOLERANCE_STOPS * (1 + 1e-9):
            warnings.warn(
                f"F/{fno:g} is {stops:.2f} stop faster than the lens's maximum aperture F/{fastest:.4g}, "
                f"within the 1/6 stop of a rounded marking: using F/{fastest:.4g} (wide open)",
                UserWarning,
                stacklevel=2,  # lens_at's line: lens_at and describe then say it once
            )
            return largest_mm
        raise ParameterError(
            None,
            "fno",
            f"F/{fno:g} is faster than the lens's maximum aperture "
            f"F/{fastest:.3g} by {stops:.2f} stop (more than the 1/6 stop of a rounded marking); "
            f"expected an `fno` of {fastest:.3g} or more",
        )
    return stop


def _configuration_key(lens: Lens, key: str) -> str:
    """The configuration's name (resolve_configuration); an unknown key names config."""
    try:
        return resolve_configuration(lens, key)
    except InputError as e:
        raise ParameterError(e.source, "config", e.message) from None


def lens_at(lens: Lens, settings: ShootingSettings | None) -> Lens:
    """The lens at these shooting settings (see the module docstring). The lens itself when
    every setting is None; otherwise a new Lens without configurations whose aperture is
    its physical stop (aperture_type "stop_semi_diameter")."""
    settings = settings or ShootingSettings()
    if settings.config is not None:
        lens = apply_configuration(lens, _configuration_key(lens, settings.config))
    if settings.fno is None and settings.object_m is None and settings.focus_m is None:
        return lens
    base = lens.with_changes(configurations={})
    object_m, focus_m = settings.distances_m()
    if settings.fno is None:
        stop = paraxial_data(base).stop_semi_diameter_mm
    else:
        stop = _check_fno(_at_infinity(base), settings.fno, max_stop_mm(base))
    focused = base
    if focus_m is not None:  # focused at the taking aperture (the paraxial solve ignores it)
        taking = base
        if settings.focus_mode != "paraxial":
            taking = base.with_changes(aperture_type="stop_semi_diameter", aperture_value=stop)
        focused = _with_thickness(base, focus_changes(taking, focus_m, settings.focus_mode))
    object_mm = base.object_distance if object_m is None else _object_distance_mm(focused, object_m, "object_m")
    return focused.with_changes(
        aperture_type="stop_semi_diameter",
        aperture_value=stop,
        object_distance=object_mm,
        **_fields_for_object(base, object_mm),
    )


def describe(lens: Lens, settings: ShootingSettings | None) -> dict[str, Any]:
    """The resolved settings, for records: {"fno": image-space F-number at infinity (EFL /
    EPD of the lens focused at infinity, with the set stop), "working_fno": the paraxial
    working F-number at the set object distance, "focus_m": focus distance from the image
    plane (m, math.inf allowed), "object_m": object distance from the image plane (m),
    "focal_mm": EFL of the configuration focused at infinity (mm), "config": the
    configuration's name or None}. Without focus or object settings the lens file's object
    distance is both."""
    settings = settings or ShootingSettings()
    config = _configuration_key(lens, settings.config) if settings.config is not None else None
    at = lens_at(lens, settings)
    inf = _at_infinity(at)
    object_m = math.inf if at.infinite_object else (at.object_distance + _image_z(at)) / 1000.0
    _, focus_m = settings.distances_m()
    para_inf = paraxial_data(inf)
    return {
        "fno": float(abs(para_inf.efl_mm) / para_inf.epd_mm),
        "working_fno": float(paraxial_data(at).working_fno),
        "focus_m": float(object_m if focus_m is None else focus_m),
        "object_m": float(object_m),
        "focal_mm": float(para_inf.efl_mm),
        "config": config,
    }


def record(described: Mapping[str, Any]) -> dict[str, Any]:
    """describe()'s dict for a JSON file (strict JSON): infinite distances as the string
    "inf" (float("inf") reads it back; so does lensim.restore.conditioning)."""
    return strict_json(dict(described))


def lens_and_record(lens: Lens, settings: ShootingSettings | None) -> tuple[Lens, dict[str, Any] | None]:
    """The lens at these shooting settings (lens_at) and the settings as records keep them
    (record(describe(...)): strict JSON); for the lens's own settings (None, or every
    setting None) the lens itself, unchanged, and None."""
    if settings is None or settings.is_default:
        return lens, None
    return lens_at(lens, settings), record(describe(lens, settings))
