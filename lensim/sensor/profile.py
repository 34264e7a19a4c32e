"""Sensor profiles: the camera side of the imaging simulation (geometry, colour, noise).

A profile is a JSON or YAML file (or a built-in name, see :func:`load_sensor`)::

    name: Full-frame DSLR-like sensor        # free text
    source: where each number comes from     # free text (also: description, notes)
    pixel_pitch_um: 5.97                     # micrometres, > 0
    resolution: [6000, 4000]                 # [width, height] in pixels
    bayer_pattern: RGGB                      # RGGB | BGGR | GRBG | GBRG: colours of the
                                             # pixels (0,0) (0,1) (1,0) (1,1), row-major,
                                             # (0,0) the top-left pixel of the image
    spectral_response: Nikon 5100 (NPL)      # a colour-science camera name (resolved by
                                             # lensim.sensor.spectral) or a CSV path
                                             # (wavelength_nm,r,g,b; relative to this file)
    ccm: [[...], [...], [...]]               # 3x3, white-balanced camera RGB -> linear
                                             # sRGB; every row sums to 1 (within 1e-3)
    white_balance:                           # gains per colour temperature (>= 1 entry,
      - {kelvin: 2856, r_gain: 1.51, b_gain: 2.33}   # kelvin strictly increasing);
      - {kelvin: 6504, r_gain: 2.76, b_gain: 1.24}   # green gain is 1
    kelvin_range: [2856, 7500]               # optional: colour temperatures drawn at
                                             # random (uniform in mired); default: the
                                             # white_balance table's range
    black_level: 512                         # digital numbers (DN)
    white_level: 16383                       # DN, > black_level, < 2**bit_depth
    bit_depth: 14                            # ADC bits, 8..16
    noise:                                   # normalized raw units (see below)
      shot: [1.0e-4, 1.2e-2]                 # a number, or [min, max] drawn log-uniformly
      read: 2.0e-3                           # a number or [min, max] (log-uniform), or
      # read_from_shot: {slope: 2.18, intercept: 1.20, sigma: 0.26}  (instead of read)

Noise units. Raw values are normalized: 0 at the black level, 1 at the white level
(x = (DN - black_level) / (white_level - black_level)). A pixel of mean signal x has
variance ``shot * x + read**2``: ``shot`` (dimensionless, the normalized signal per
photo-electron times the analogue gain, i.e. Brooks et al.'s lambda_shot) and ``read``
(the standard deviation of the signal-independent noise in normalized units; Brooks et
al.'s lambda_read is read**2). ``read_from_shot`` draws the read noise from the shot noise
with Brooks et al. 2019's log-linear fit: log(read**2) = slope * log(shot) + intercept +
N(0, sigma**2) (natural logarithms).

Every error is a one-line :class:`lensim.errors.InputError` naming the file, the field
and what was expected; unknown keys are refused.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lensim.assets import DEFAULT_SENSOR
from lensim.errors import InputError, LensimError
from lensim.io import read_text
from lensim.sensor.cfa import CfaPattern, cfa_pattern

SENSOR_DIR = Path(__file__).resolve().parents[1] / "assets" / "sensors"

TOP_KEYS = {
    "name",
    "source",
    "description",
    "notes",
    "pixel_pitch_um",
    "resolution",
    "bayer_pattern",
    "spectral_response",
    "ccm",
    "white_balance",
    "kelvin_range",
    "black_level",
    "white_level",
    "bit_depth",
    "noise",
}
REQUIRED_KEYS = (
    "name",
    "pixel_pitch_um",
    "resolution",
    "bayer_pattern",
    "spectral_response",
    "ccm",
    "white_balance",
    "black_level",
    "white_level",
    "bit_depth",
    "noise",
)
WB_KEYS = {"kelvin", "r_gain", "b_gain"}
NOISE_KEYS = {"shot", "read", "read_from_shot"}
READ_FROM_SHOT_KEYS = {"slope", "intercept", "sigma"}
CCM_ROW_SUM_TOL = 1e-3


@dataclass(frozen=True)
class WhiteBalancePoint:
    """White-balance gains (multipliers of camera R and B; G is 1) at a colour temperature (K)."""

    kelvin: float
    r_gain: float
    b_gain: float


@dataclass(frozen=True)
class NoiseModel:
    """Heteroscedastic Gaussian raw noise: variance = shot * x + read**2 (x normalized raw).

    shot, read: (min, max) ranges (min == max for a fixed value), drawn log-uniformly.
    read_from_shot: (slope, intercept, sigma) of Brooks et al. 2019's relation
    log(read**2) = slope * log(shot) + intercept + N(0, sigma**2); when set, ``read`` is None.
    """

    shot: tuple[float, float]
    read: tuple[float, float] | None
    read_from_shot: tuple[float, float, float] | None = None

    def sample(self, generator: torch.Generator | None = None) -> tuple[float, float]:
        """Draw (shot, read) with the generator (global torch RNG when None)."""
        u = torch.rand(2, generator=generator, dtype=torch.float64)
        shot = _log_uniform(self.shot, float(u[0]))
        if self.read_from_shot is not None:
            slope, intercept, sigma = self.read_from_shot
            z = float(torch.randn(1, generator=generator, dtype=torch.float64)[0])
            read = math.sqrt(math.exp(slope * math.log(shot) + intercept + sigma * z))
        else:
            assert self.read is not None
            read = _log_uniform(self.read, float(u[1]))
        return shot, read

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"shot": _range_out(self.shot)}
        if self.read_from_shot is not None:
            s, i, g = self.read_from_shot
            out["read_from_shot"] = {"slope": s, "intercept": i, "sigma": g}
        else:
            assert self.read is not None
            out["read"] = _range_out(self.read)
        return out


def _log_uniform(rng: tuple[float, float], u: float) -> float:
    lo, hi = rng
    if lo == hi:
        return lo
    if lo <= 0.0:  # a zero lower bound: uniform
        return lo + (hi - lo) * u
    return math.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * u)


def _range_out(r: tuple[float, float]) -> float | list[float]:
    return r[0] if r[0] == r[1] else [r[0], r[1]]


@dataclass(frozen=True)
class SensorProfile:
    """A validated sensor description. Build it with :func:`load_sensor` or
    :func:`sensor_from_dict`; the fields are described in the module docstring."""

    name: str
    pixel_pitch_um: float
    resolution: tuple[int, int]  # (width, height) px
    bayer_pattern: CfaPattern
    spectral_response: str
    ccm: tuple[tuple[float, float, float], ...]
    white_balance: tuple[WhiteBalancePoint, ...]
    kelvin_range: tuple[float, float]
    black_level: float
    white_level: float
    bit_depth: int
    noise: NoiseModel
    source: str = ""
    description: str = ""
    path: str | None = field(default=None, compare=False)

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    @property
    def sensor_size_mm(self) -> tuple[float, float]:
        """(width, height) of the active area in mm."""
        return (self.width * self.pixel_pitch_um * 1e-3, self.height * self.pixel_pitch_um * 1e-3)

    @property
    def half_diagonal_mm(self) -> float:
        w, h = self.sensor_size_mm
        return 0.5 * math.hypot(w, h)

    def wb_gains(self, kelvin: float) -> tuple[float, float]:
        """(r_gain, b_gain) at a colour temperature (K), linearly interpolated in mired
        (1e6 / K) between the table's entries and held constant beyond its ends."""
        if not (kelvin > 0 and math.isfinite(kelvin)):
            raise InputError(self.path, "kelvin", f"expected a positive colour temperature in K, got {kelvin!r}")
        pts = self.white_balance
        if len(pts) == 1:
            return pts[0].r_gain, pts[0].b_gain
        # mired decreases with kelvin: interpolate on increasing mired
        mired = np.array([1e6 / p.kelvin for p in pts])[::-1]
        r = np.array([p.r_gain for p in pts])[::-1]
        b = np.array([p.b_gain for p in pts])[::-1]
        m = 1e6 / kelvin
        return float(np.interp(m, mired, r)), float(np.interp(m, mired, b))

    def sample_kelvin(self, generator: torch.Generator | None = None) -> float:
        """A colour temperature (K) drawn uniformly in mired over kelvin_range."""
        lo, hi = self.kelvin_range
        u = float(torch.rand(1, generator=generator, dtype=torch.float64)[0])
        m_lo, m_hi = 1e6 / hi, 1e6 / lo
        return 1e6 / (m_lo + (m_hi - m_lo) * u)

    def sample_noise(self, generator: torch.Generator | None = None) -> tuple[float, float]:
        """(shot, read) drawn from the noise model (see :class:`NoiseModel`)."""
        return self.noise.sample(generator)

    def to_dict(self) -> dict:
        """The profile as a mapping in the file format (for manifests and round trips)."""
        out: dict[str, Any] = {
            "name": self.name,
            "pixel_pitch_um": self.pixel_pitch_um,
            "resolution": list(self.resolution),
            "bayer_pattern": self.bayer_pattern,
            "spectral_response": self.spectral_response,
            "ccm": [list(r) for r in self.ccm],
            "white_balance": [{"kelvin": p.kelvin, "r_gain": p.r_gain, "b_gain": p.b_gain} for p in self.white_balance],
            "kelvin_range": list(self.kelvin_range),
            "black_level": self.black_level,
            "white_level": self.white_level,
            "bit_depth": self.bit_depth,
            "noise": self.noise.to_dict(),
        }
        if self.source:
            out["source"] = self.source
        if self.description:
            out["description"] = self.description
        return out


# ---------------------------------------------------------------- validation helpers


#: the pixel pitches (um) a sensor may have: camera and phone sensors span about 0.5 to 10
#: um; a pitch far below the wavelength no lens resolves (1e-6 is a pitch in metres typed
#: as micrometres), and one of 100 um is a coarse thermal sensor's
PIXEL_PITCH_RANGE_UM = (0.1, 100.0)


def pitch_out_of_range(pitch_um: float) -> str:
    """What a pixel pitch outside PIXEL_PITCH_RANGE_UM is told (the message of the error
    naming the file's pixel_pitch_um or the --pixel-um option)."""
    low, high = PIXEL_PITCH_RANGE_UM
    hint = f" (in micrometres: {pitch_um:g} m would be {pitch_um * 1e6:g} um)" if pitch_um < 1e-3 else ""
    return f"expected a pixel pitch between {low:g} and {high:g} um, got {pitch_um:g} um{hint}"


def _number(src: str | None, fld: str, value: Any, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(src, fld, f"expected a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise InputError(src, fld, f"expected a finite number, got {value!r}")
    if positive and not x > 0:
        raise InputError(src, fld, f"expected a positive number, got {value!r}")
    if nonneg and x < 0:
        raise InputError(src, fld, f"expected a non-negative number, got {value!r}")
    return x


def _integer(src: str | None, fld: str, value: Any, lo: int, hi: int | None = None) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or float(value) != int(value)
    ):
        raise InputError(src, fld, f"expected an integer, got {value!r}")
    n = int(value)
    if n < lo or (hi is not None and n > hi):
        raise InputError(src, fld, f"expected an integer in [{lo}, {hi if hi is not None else 'inf'}], got {value!r}")
    return n


def _mapping(src: str | None, fld: str, data: Any, allowed: set[str]) -> dict:
    if not isinstance(data, dict):
        raise InputError(src, fld, f"expected a mapping, got {type(data).__name__}")
    unknown = sorted(str(k) for k in set(data) - allowed)
    if unknown:
        raise InputError(
            src,
            f"{fld}.{unknown[0]}" if fld else unknown[0],
            f"unknown key(s) {', '.join(unknown)}; expected some of {', '.join(sorted(allowed))}",
        )
    return data


def _range(src: str | None, fld: str, value: Any) -> tuple[float, float]:
    """A non-negative number or [min, max] with 0 <= min <= max."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise InputError(src, fld, f"expected a number or [min, max], got {value!r}")
        lo = _number(src, f"{fld}[0]", value[0], nonneg=True)
        hi = _number(src, f"{fld}[1]", value[1], nonneg=True)
        if hi < lo:
            raise InputError(src, fld, f"expected [min, max] with min <= max, got {value!r}")
        return lo, hi
    x = _number(src, fld, value, nonneg=True)
    return x, x


def _spectral(src: str | None, value: Any) -> str:
    fld = "spectral_response"
    if not isinstance(value, str) or not value.strip():
        raise InputError(src, fld, f"expected a colour-science camera name or a CSV path, got {value!r}")
    name = value.strip()
    if name.lower().endswith(".csv"):
        p = Path(name)
        if not p.is_absolute() and src is not None:
            p = Path(src).resolve().parent / p
        if not p.is_file():
            raise InputError(
                src, fld, f"CSV file {str(p)!r} not found (a relative path is taken from the profile's folder)"
            )
        from lensim.sensor.spectral import read_response_csv

        read_response_csv(p)  # raises InputError naming the CSV file, line and column
        return str(p)
    return name


def _ccm(src: str | None, ccm_raw: Any) -> tuple[tuple[float, float, float], ...]:
    """The 3x3 colour correction matrix (camera RGB -> linear sRGB): rows summing to 1,
    invertible."""
    if (
        not isinstance(ccm_raw, (list, tuple))
        or len(ccm_raw) != 3
        or any(not isinstance(r, (list, tuple)) or len(r) != 3 for r in ccm_raw)
    ):
        raise InputError(
            src, "ccm", f"expected a 3x3 matrix [[r_r, r_g, r_b], [g_r, ...], [b_r, ...]], got {ccm_raw!r}"
        )
    ccm = tuple(tuple(_number(src, f"ccm[{i}][{j}]", ccm_raw[i][j]) for j in range(3)) for i in range(3))
    for i, row in enumerate(ccm):
        if abs(sum(row) - 1.0) > CCM_ROW_SUM_TOL:
            raise InputError(
                src,
                f"ccm[{i}]",
                f"expected the row to sum to 1 (within {CCM_ROW_SUM_TOL:g}) so that white "
                f"stays white, got {sum(row):.6g}",
            )
    cond = float(np.linalg.cond(np.array(ccm)))
    if not cond < 1e4:
        raise InputError(src, "ccm", f"expected an invertible matrix (condition number < 1e4), got {cond:.3g}")
    return ccm


def _white_balance(src: str | None, data: dict) -> tuple[list[WhiteBalancePoint], tuple[float, float]]:
    """The white-balance table (strictly increasing kelvin) and the kelvin range drawn
    from (default: the table's ends)."""
    wb_raw = data["white_balance"]
    if not isinstance(wb_raw, (list, tuple)) or not wb_raw:
        raise InputError(src, "white_balance", "expected a non-empty list of {kelvin, r_gain, b_gain}")
    wb = []
    for i, e in enumerate(wb_raw):
        f = f"white_balance[{i}]"
        e = _mapping(src, f, e, WB_KEYS)
        for k in sorted(WB_KEYS):
            if k not in e:
                raise InputError(src, f"{f}.{k}", "missing (required)")
        wb.append(
            WhiteBalancePoint(
                kelvin=_number(src, f"{f}.kelvin", e["kelvin"], positive=True),
                r_gain=_number(src, f"{f}.r_gain", e["r_gain"], positive=True),
                b_gain=_number(src, f"{f}.b_gain", e["b_gain"], positive=True),
            )
        )
    for i in range(1, len(wb)):
        if not wb[i].kelvin > wb[i - 1].kelvin:
            raise InputError(
                src,
                f"white_balance[{i}].kelvin",
                f"expected strictly increasing colour temperatures, got {wb[i].kelvin:g} after {wb[i - 1].kelvin:g}",
            )

    if "kelvin_range" in data:
        kr = data["kelvin_range"]
        if not isinstance(kr, (list, tuple)) or len(kr) != 2:
            raise InputError(src, "kelvin_range", f"expected [min, max] in K, got {kr!r}")
        k_lo = _number(src, "kelvin_range[0]", kr[0], positive=True)
        k_hi = _number(src, "kelvin_range[1]", kr[1], positive=True)
        if k_hi < k_lo:
            raise InputError(src, "kelvin_range", f"expected min <= max, got {kr!r}")
        if k_lo < wb[0].kelvin - 1e-9 or k_hi > wb[-1].kelvin + 1e-9:
            raise InputError(
                src,
                "kelvin_range",
                f"expected a range inside the white_balance table ({wb[0].kelvin:g}-{wb[-1].kelvin:g} K), got {kr!r}",
            )
    else:
        k_lo, k_hi = wb[0].kelvin, wb[-1].kelvin

    return wb, (k_lo, k_hi)


def _levels(src: str | None, data: dict) -> tuple[int, float, float]:
    """(bit depth, black level, white level) in digital numbers."""
    bit_depth = _integer(src, "bit_depth", data["bit_depth"], 8, 16)
    black = _number(src, "black_level", data["black_level"], nonneg=True)
    white = _number(src, "white_level", data["white_level"], positive=True)
    if white > 2**bit_depth - 1:
        raise InputError(src, "white_level", f"expected at most 2**bit_depth - 1 = {2**bit_depth - 1}, got {white:g}")
    if not white > black:
        raise InputError(src, "white_level", f"expected more than black_level ({black:g}), got {white:g}")

    return bit_depth, black, white


def _noise(src: str | None, noise: Any) -> NoiseModel:
    """The noise model: shot range and either a read range or read-from-shot regression."""
    nz = _mapping(src, "noise", noise, NOISE_KEYS)
    if "shot" not in nz:
        raise InputError(src, "noise.shot", "missing (required)")
    shot = _range(src, "noise.shot", nz["shot"])
    if ("read" in nz) == ("read_from_shot" in nz):
        raise InputError(src, "noise.read", "expected exactly one of read or read_from_shot")
    read = None
    rfs = None
    if "read" in nz:
        read = _range(src, "noise.read", nz["read"])
    else:
        r = _mapping(src, "noise.read_from_shot", nz["read_from_shot"], READ_FROM_SHOT_KEYS)
        for k in sorted(READ_FROM_SHOT_KEYS):
            if k not in r:
                raise InputError(src, f"noise.read_from_shot.{k}", "missing (required)")
        if not shot[0] > 0:
            raise InputError(
                src, "noise.shot", "expected a positive shot noise with read_from_shot (its logarithm is taken)"
            )
        rfs = (
            _number(src, "noise.read_from_shot.slope", r["slope"]),
            _number(src, "noise.read_from_shot.intercept", r["intercept"]),
            _number(src, "noise.read_from_shot.sigma", r["sigma"], nonneg=True),
        )

    return NoiseModel(shot=shot, read=read, read_from_shot=rfs)


def sensor_from_dict(data: Any, source: str | None = None) -> SensorProfile:
    """Build and validate a :class:`SensorProfile` from the file format's mapping.
    ``source`` (the file name) is named in every error."""
    src = source
    data = _mapping(src, "", data, TOP_KEYS)
    for k in REQUIRED_KEYS:
        if k not in data:
            raise InputError(src, k, "missing (required)")
    name = data["name"]
    if not isinstance(name, str) or not name.strip():
        raise InputError(src, "name", f"expected a non-empty string, got {name!r}")
    for k in ("source", "description", "notes"):
        if k in data and not isinstance(data[k], (str, list)):
            raise InputError(src, k, f"expected text, got {type(data[k]).__name__}")

    pitch = _number(src, "pixel_pitch_um", data["pixel_pitch_um"], positive=True)
    low, high = PIXEL_PITCH_RANGE_UM
    if not low <= pitch <= high:
        raise InputError(src, "pixel_pitch_um", pitch_out_of_range(pitch))
    res = data["resolution"]
    if not isinstance(res, (list, tuple)) or len(res) != 2:
        raise InputError(src, "resolution", f"expected [width, height] in pixels, got {res!r}")
    w = _integer(src, "resolution[0]", res[0], 2)
    h = _integer(src, "resolution[1]", res[1], 2)
    if w % 2 or h % 2:
        raise InputError(src, "resolution", f"expected even width and height (whole Bayer quads), got {[w, h]}")

    pattern = cfa_pattern(data["bayer_pattern"], src)

    spectral = _spectral(src, data["spectral_response"])
    ccm = _ccm(src, data["ccm"])
    wb, (k_lo, k_hi) = _white_balance(src, data)
    bit_depth, black, white = _levels(src, data)
    noise = _noise(src, data["noise"])

    def _text(v: Any) -> str:
        return " ".join(str(x) for x in v) if isinstance(v, list) else str(v or "")

    return SensorProfile(
        name=name.strip(),
        pixel_pitch_um=pitch,
        resolution=(w, h),
        bayer_pattern=pattern,
        spectral_response=spectral,
        ccm=ccm,
        white_balance=tuple(wb),
        kelvin_range=(k_lo, k_hi),
        black_level=black,
        white_level=white,
        bit_depth=bit_depth,
        noise=noise,
        source=_text(data.get("source")).strip(),
        description=_text(data.get("description")).strip(),
        path=src,
    )


# ---------------------------------------------------------------- files and built-ins


def sensor_names() -> list[str]:
    """Names of the built-in sensor profiles."""
    return sorted(p.stem for p in SENSOR_DIR.glob("*.yaml"))


def sensor_path(name: str) -> Path | None:
    """Path of a built-in sensor profile by name (None if there is none)."""
    p = SENSOR_DIR / f"{name}.yaml"
    return p if p.is_file() else None


def _read(path: Path) -> Any:
    text = read_text(path, "sensor profile")
    try:
        if path.suffix.lower() == ".json":
            return json.loads(text)
        import yaml

        return yaml.safe_load(text)
    except Exception as e:  # json.JSONDecodeError, yaml.YAMLError
        if isinstance(e, LensimError):
            raise
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(str(path), "syntax", f"not valid {path.suffix[1:].upper()}: {msg}") from None


def load_sensor(name_or_path: str | Path | None = None) -> SensorProfile:
    """Load a sensor profile from a .json/.yaml/.yml file, or a built-in profile by name
    (``sensor_names()``; None gives DEFAULT_SENSOR). Raises a one-line InputError naming
    the file and the field on bad input."""
    if name_or_path is None:
        name_or_path = DEFAULT_SENSOR
    p = Path(name_or_path)
    if not p.exists():
        builtin = sensor_path(str(name_or_path))
        if builtin is None:
            raise InputError(
                str(name_or_path),
                None,
                f"no such file, and not a built-in sensor (built-ins: {', '.join(sensor_names())})",
            )
        p = builtin
    if p.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise InputError(str(p), None, "unknown sensor file type; expected .json, .yaml or .yml")
    data = _read(p)
    if not isinstance(data, dict):
        raise InputError(str(p), "sensor", "expected a mapping at the top level")
    return sensor_from_dict(data, source=str(p))
