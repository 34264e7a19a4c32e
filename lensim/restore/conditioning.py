"""Shooting-settings conditioning: one restoration network for every F-number, focus
distance and focal length it was trained across (issue 16).

A pairs record made across a grid of settings carries ``"settings"`` =
lensim.optics.shooting.describe(...): {"fno": working F-number at infinity, "focus_m":
focus distance from the image plane in metres (math.inf allowed), "object_m", "focal_mm":
effective focal length in mm, "config"}. Three of them shape the blur and condition the
network, each through a *feature* in which equal steps mean roughly equal changes of the
PSF:

==========  =============================  ==========================================
key         feature                         why
==========  =============================  ==========================================
fno         log2(N), stops                  the aperture's area halves per stop
focus_m     1 / focus distance, dioptres    defocus is linear in dioptres; inf -> 0
focal_mm    log2(f), "zoom stops"           a zoom's aberrations change by ratios
==========  =============================  ==========================================

:class:`Conditioning` holds the range of each feature over the training records (kept in
natural units: F-number, metres, mm; in checkpoints and RUN/config.json). The settings
that *vary* over the training records are the network's inputs (``keys``, in the order
above); each maps linearly to [-1, 1] over its trained range, so the settings vector has
``settings_dim = len(keys)`` entries. A setting that is the same in every record is not
an input but its value is still checked.

Range check (:meth:`Conditioning.check`), per key, by the distance ``d`` of a photo's
feature outside the trained range (0 inside):

* ``d <= TOLERANCE`` (1/6 stop, 0.05 dioptre, 2 % of focal length): fine. Cameras round
  what they record (f/5.6 is 2^2.5 = 5.66, thirds of stops, coarse focus distances).
* beyond it: a one-line warning (returned; the CLI prints it): the network extrapolates.
* beyond ``refuse_margin(key) = max(REFUSE[key], span / 4)`` (span: the trained range in
  feature units; REFUSE: 1 stop, 0.5 dioptre, 25 % of focal length): a one-line
  InputError for a conditioned network (``refuse=True``), whose settings inputs there
  lie far outside anything it saw. An unconditioned network (trained at one setting, or
  with the settings ignored) only warns: it does not read the settings.

:func:`settings_planes` broadcasts settings vectors to constant image channels, the form
networks take them in at their input. :func:`photo_vector` is the settings vector of one
photo (developed or raw): its EXIF's settings, each replaced by a value given for it,
checked against the trained ranges.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from lensim.errors import InputError, ParameterError

#: The settings a network can be conditioned on, in vector order.
SETTINGS_KEYS: tuple[str, ...] = ("fno", "focus_m", "focal_mm")
#: Human names and units for messages.
LABELS = {"fno": ("F-number", ""), "focus_m": ("focus distance", " m"), "focal_mm": ("focal length", " mm")}
#: The EXIF tag that records each setting.
EXIF_TAGS = {"fno": "FNumber", "focus_m": "SubjectDistance", "focal_mm": "FocalLength"}
#: Feature-space distance outside the trained range that passes without a word.
TOLERANCE = {"fno": 1.0 / 6.0, "focus_m": 0.05, "focal_mm": math.log2(1.02)}
#: Least feature-space distance outside the trained range at which a conditioned network refuses.
REFUSE = {"fno": 1.0, "focus_m": 0.5, "focal_mm": math.log2(1.25)}


def feature(key: str, value: float) -> float:
    """The conditioning feature of one setting: log2(F-number), dioptres (1 / metres; inf
    -> 0), log2(focal length in mm)."""
    if key == "fno":
        return math.log2(value)
    if key == "focus_m":
        return 0.0 if math.isinf(value) else 1.0 / value
    if key == "focal_mm":
        return math.log2(value)
    raise KeyError(f"unknown setting {key!r}; expected one of {', '.join(SETTINGS_KEYS)}")


def check_value(key: str, value: Any, source: str | None, where: str | None) -> float:
    """A setting's value as a float: fno and focal_mm positive and finite, focus_m
    positive (inf allowed: focused at infinity); a one-line InputError otherwise."""
    name, unit = LABELS[key]
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    ok = x > 0 and (math.isfinite(x) or (key == "focus_m" and x == math.inf))
    if not ok or isinstance(value, bool):
        allowed = "inf or " if key == "focus_m" else ""
        raise InputError(
            source,
            where,
            f"expected the {name}{' in' + unit if unit else ''} as {allowed}a positive number, got {value!r}",
        )
    return x


def record_settings(settings: Any, source: str | None = None, where: str = "settings") -> dict[str, float]:
    """The conditioning settings of a record's ``settings`` dict (describe's format):
    {key: value} for the keys of SETTINGS_KEYS it holds (None values are left out), each
    checked by :func:`check_value`; other keys (object_m, config) are ignored."""
    if not isinstance(settings, Mapping):
        raise InputError(
            source,
            where,
            f"expected a mapping of shooting settings (fno, focus_m, focal_mm), got {type(settings).__name__}",
        )
    return {
        k: check_value(k, settings[k], source, f"{where}.{k}") for k in SETTINGS_KEYS if settings.get(k) is not None
    }


def given_settings(
    fno: float | None = None, focus_m: float | None = None, focal_mm: float | None = None
) -> dict[str, float]:
    """The settings given for photos (None: not given) as {key: value}, those given, each
    checked by :func:`check_value` (a ParameterError naming the setting)."""
    out: dict[str, float] = {}
    for key, value in (("fno", fno), ("focus_m", focus_m), ("focal_mm", focal_mm)):
        if value is not None:
            try:
                out[key] = check_value(key, value, None, key)
            except InputError as e:
                raise ParameterError(None, key, e.message) from None
    return out


def _show(key: str, value: float) -> str:
    name, unit = LABELS[key]
    if key == "fno":
        return f"f/{value:.3g}"
    return f"{'inf' if math.isinf(value) else f'{value:.4g}'}{unit}"


def _show_range(key: str, low: float, high: float) -> str:
    return _show(key, low) if low == high else f"{_show(key, low)} to {_show(key, high)}"


@dataclass(frozen=True)
class Conditioning:
    """The settings a network was trained across: ``ranges`` {key: (smallest, largest)} in natural
    units (F-number, metres with inf allowed, mm) for every key the training records
    carried, ``keys`` the ones that are network inputs (vector order; see the module
    docstring). ``Conditioning()`` (no ranges): trained without settings."""

    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    keys: tuple[str, ...] = ()

    @classmethod
    def from_records(cls, settings: Iterable[Mapping[str, float] | None], use: bool = True) -> Conditioning:
        """From the training records' settings (record_settings output, or None for a record
        without): ranges over them; inputs are the keys whose feature varies (none when
        ``use`` is False: the network is not conditioned, the ranges are still kept). A key
        held by only some records is not used (a ValueError for mixed records is the
        manifest reader's business)."""
        values: dict[str, list[float]] = {}
        n = 0
        for s in settings:
            n += 1
            for k, v in (s or {}).items():
                values.setdefault(k, []).append(float(v))
        ranges = {k: (min(v), max(v)) for k, v in values.items() if len(v) == n and k in SETTINGS_KEYS}
        ranges = {k: ranges[k] for k in SETTINGS_KEYS if k in ranges}
        keys = tuple(k for k in ranges if use and feature(k, ranges[k][0]) != feature(k, ranges[k][1]))
        return cls(ranges, keys)

    @classmethod
    def from_dict(cls, data: Any, source: str | None = None) -> Conditioning:
        """From :meth:`to_dict`'s output (None or {}: no conditioning); one-line InputError
        naming ``source`` when malformed."""
        if not data:
            return cls()
        try:
            ranges = {
                str(k): (
                    check_value(k, v[0], source, f"conditioning.ranges.{k}"),
                    check_value(k, v[1], source, f"conditioning.ranges.{k}"),
                )
                for k, v in dict(data.get("ranges") or {}).items()
                if k in SETTINGS_KEYS
            }
            keys = tuple(str(k) for k in data.get("keys") or ())
        except (TypeError, IndexError, AttributeError, ValueError, KeyError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(
                source, "conditioning", f"expected {{keys, ranges}} as lensim train writes it ({e})"
            ) from None
        if any(k not in ranges for k in keys):
            raise InputError(
                source, "conditioning.keys", f"expected keys among the ranges {sorted(ranges)}, got {list(keys)}"
            )
        return cls(ranges, keys)

    def to_dict(self) -> dict[str, Any]:
        """{"keys": [...], "ranges": {key: [low, high]}} (JSON and weights_only-safe)."""
        return {"keys": list(self.keys), "ranges": {k: [float(a), float(b)] for k, (a, b) in self.ranges.items()}}

    @property
    def dim(self) -> int:
        """Number of settings inputs (the network's settings_dim)."""
        return len(self.keys)

    def describe(self) -> str:
        """The trained settings in words, e.g. 'f/2 to f/8, focus distance 1 m to inf'."""
        return ", ".join(_show_range(k, *self.ranges[k]) for k in self.ranges) or "no recorded settings"

    def vector(self, settings: Mapping[str, float], source: str | None = None) -> torch.Tensor:
        """(dim,) float32 settings vector: each key's feature mapped linearly from its
        trained range to [-1, 1]. A missing input key is a one-line InputError naming it."""
        missing = [k for k in self.keys if settings.get(k) is None]
        if missing:
            raise InputError(
                source,
                "settings",
                f"this network is conditioned on {', '.join(self.keys)} and "
                f"needs them; missing {', '.join(missing)} (give {', '.join(f'`{k}`' for k in missing)})",
            )
        out = []
        for k in self.keys:
            lo, hi = (feature(k, v) for v in self.ranges[k])
            out.append(2.0 * (feature(k, float(settings[k])) - lo) / (hi - lo) - 1.0)
        return torch.tensor(out, dtype=torch.float32)

    def refuse_margin(self, key: str) -> float:
        """Feature-space distance outside the trained range beyond which a conditioned
        network refuses (module docstring)."""
        lo, hi = (feature(key, v) for v in self.ranges[key])
        return max(REFUSE[key], abs(hi - lo) / 4.0)

    def check(self, settings: Mapping[str, float], source: str | None = None, refuse: bool | None = None) -> list[str]:
        """Compare a photo's settings with the trained ranges; returns one-line warnings
        (empty when all are within tolerance). ``refuse`` (default: whether the network is
        conditioned) turns a setting beyond :meth:`refuse_margin` into a ParameterError
        naming the setting. Settings the photo does not give are not checked."""
        refuse = self.dim > 0 if refuse is None else refuse
        warnings: list[str] = []
        for k, (low, high) in self.ranges.items():
            if settings.get(k) is None:
                continue
            x = feature(k, float(settings[k]))
            lo, hi = sorted((feature(k, low), feature(k, high)))
            d = max(lo - x, x - hi, 0.0)
            if d <= TOLERANCE[k]:
                continue
            name = LABELS[k][0]
            what = f"{name} {_show(k, float(settings[k]))} is outside the trained range ({_show_range(k, low, high)})"
            if refuse and d > self.refuse_margin(k):
                raise ParameterError(
                    source,
                    k,
                    f"{what}, too far to extrapolate; expected a photo within the "
                    "range (or a network trained across it)",
                )
            warnings.append(f"{source + ': ' if source else ''}{what}; the restoration may be wrong")
        return warnings


def photo_vector(
    conditioning: Conditioning,
    exif: Mapping[str, float | None],
    given: Mapping[str, float],
    source: str,
    warn: bool = True,
) -> torch.Tensor | None:
    """The settings vector (:meth:`Conditioning.vector`) of one photo for a network trained
    across ``conditioning`` (None when the network is not conditioned): the photo's EXIF
    settings ``exif`` ({fno, focus_m, focal_mm}; missing or None: not recorded), each
    replaced by the value ``given`` for it (:func:`given_settings`), checked against the
    trained ranges (:meth:`Conditioning.check`: a UserWarning beyond the tolerance when
    ``warn``, a ParameterError far outside). A setting the network needs that neither
    gives is a ParameterError naming the photo (``source``), the setting(s) and the EXIF
    tag(s) that would record it."""
    shot = {k: float(v) for k, v in {**exif, **given}.items() if v is not None}
    for text in conditioning.check(shot, source):
        if warn:
            warnings.warn(text, UserWarning, stacklevel=2)
    if not conditioning.dim:
        return None
    missing = [k for k in conditioning.keys if k not in shot]
    if missing:
        raise ParameterError(
            source,
            ", ".join(missing),
            f"the network was trained across shooting settings ({conditioning.describe()}) and needs the "
            f"photo's {', '.join(conditioning.keys)}; its EXIF has no {', '.join(EXIF_TAGS[k] for k in missing)}; "
            f"give {', '.join(f'`{k}`' for k in missing)}",
        )
    return conditioning.vector(shot, source)


def checkpoint_conditioning(info: Mapping[str, Any], settings_dim: int, source: str | None = None) -> Conditioning:
    """The Conditioning a checkpoint records (its ``conditioning``, else its train_config's;
    none in checkpoints from before conditioning), checked against the network's
    settings_dim: a one-line InputError naming ``source`` when they disagree."""
    data = info.get("conditioning")
    if data is None:
        data = (info.get("train_config") or {}).get("conditioning")
    cond = Conditioning.from_dict(data, source)
    if cond.dim != settings_dim:
        raise InputError(
            source,
            "conditioning",
            f"records {cond.dim} settings inputs ({', '.join(cond.keys)}) for a "
            f"network with settings_dim={settings_dim}; expected a checkpoint written by lensim train",
        )
    return cond


def settings_planes(settings: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """(B, k) settings vectors -> (B, k, h, w) constant channels (an expanded view)."""
    if settings.dim() != 2:
        raise ValueError(f"settings must be (B, k), got {tuple(settings.shape)}")
    return settings[:, :, None, None].expand(-1, -1, h, w)


def batch_settings(
    settings: torch.Tensor | Sequence[float] | None, batch: int, dim: int, like: torch.Tensor
) -> torch.Tensor | None:
    """A network's settings argument as (B, dim) in ``like``'s dtype and device: (dim,) is
    broadcast over the batch; None only when dim is 0 (else a ValueError naming what to
    pass)."""
    if dim == 0:
        if settings is not None and torch.as_tensor(settings).numel():
            raise ValueError("this model takes no settings (settings_dim=0); pass settings=None")
        return None
    if settings is None:
        raise ValueError(
            f"this model was built with settings_dim={dim}: pass the settings vector "
            "(lensim.restore.conditioning.Conditioning.vector)"
        )
    s = torch.as_tensor(settings).to(device=like.device, dtype=like.dtype)
    if s.dim() == 1:
        s = s.unsqueeze(0).expand(batch, -1)
    if s.shape != (batch, dim):
        raise ValueError(f"settings must be ({batch}, {dim}) or ({dim},), got {tuple(s.shape)}")
    return s


__all__ = [
    "EXIF_TAGS",
    "LABELS",
    "REFUSE",
    "SETTINGS_KEYS",
    "TOLERANCE",
    "Conditioning",
    "batch_settings",
    "check_value",
    "checkpoint_conditioning",
    "feature",
    "given_settings",
    "photo_vector",
    "record_settings",
    "settings_planes",
]
