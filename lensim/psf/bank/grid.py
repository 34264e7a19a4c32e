"""Banks over a grid of shooting settings: one PSF bank per setting under one manifest.

A grid is the product of lists of F-numbers, focus distances, object distances and
configurations (lensim.optics.shooting; an axis not given keeps the lens file's value).
On disk a grid is a folder::

    GRID/manifest.json        format "lensim-psf-grid": the lens file's lens, the axes, the
                              bank options every setting shares, and per setting its
                              sub-folder, the settings asked for (ShootingSettings.to_dict)
                              and the resolved numbers (lensim.optics.shooting.describe)
    GRID/s000/, s001/, ...    one ordinary PSF bank each (lensim.psf.bank), of the lens at
                              that setting (lens_at)

Every setting's bank shares the pixel pitch, kernel size (by default the largest any
setting's spots ask for), normalized fields, wavelengths and spectral response, so their
kernels can be compared and blended; each bank is exactly the bank `lensim psf bank` makes
for that one setting with that kernel size. The fields of every setting are computed as one
list of jobs (lensim.psf.bank.get_bank, on Dask when asked), each written as it finishes, so
a killed grid resumes where it stopped and a cluster computes the whole grid.

Distances are in metres from the image plane (math.inf allowed; "inf" in JSON), F-numbers
image-space at infinity. Interpolation between settings: lensim.psf.bank.grid_interp.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lensim.errors import InputError, ParameterError
from lensim.io import atomic_write_text
from lensim.jsonable import from_strict, strict_json
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_to_dict
from lensim.optics.shooting import ShootingSettings, describe, lens_at, record
from lensim.psf.bank.compute import BankPlan, _plan_bank
from lensim.psf.bank.settings import BankSettings, suggest_kernel_pixels
from lensim.psf.bank.store import FORMAT as BANK_FORMAT
from lensim.psf.bank.store import MANIFEST, lensim_version, manifest_differences
from lensim.psf.bank.types import PSFBank
from lensim.sensor.spectral import SpectralResponse

GRID_FORMAT = "lensim-psf-grid"
GRID_FORMAT_VERSION = 1
#: the grid's axes, outermost first (the order of the settings in a grid)
AXES = ("config", "fno", "focus_m", "object_m")


def setting_dir(index: int) -> str:
    """The sub-folder of setting `index` inside a grid folder."""
    return f"s{index:03d}"


def resolved_numbers(d: dict[str, Any]) -> dict[str, Any]:
    """A resolved-settings dict read from JSON with "inf" turned back into math.inf."""
    return {k: from_strict(v) for k, v in d.items()}


def parse_setting_list(text: str | None, key: str) -> tuple[Any, ...] | None:
    """A comma list of one setting, as typed (key: fno, focus_m, object_m or config;
    distances may be 'inf'): the values in the order given, or None when ``text`` is None.
    Empty items, bad numbers (0, negative, NaN, ...) and duplicates are one-line
    ParameterErrors naming the setting."""
    if text is None:
        return None
    items = [p.strip() for p in str(text).split(",")]
    if not items or any(not p for p in items):
        raise ParameterError(None, key, f"expected a comma list of values without empty items, got {text!r}")
    values = tuple(getattr(ShootingSettings(**{key: p}), key) for p in items)  # type: ignore[arg-type]  # checked
    seen: set[Any] = set()
    for v in values:
        if v in seen:
            raise ParameterError(None, key, f"{strict_json(v)!s} is given twice in {text!r}; expected distinct values")
        seen.add(v)
    return values


@dataclass(frozen=True)
class GridAxes:
    """The values of each setting a grid spans (None: the lens file's value only)."""

    fno: tuple[float, ...] | None = None
    focus_m: tuple[float, ...] | None = None
    object_m: tuple[float, ...] | None = None
    config: tuple[str, ...] | None = None

    @classmethod
    def from_options(
        cls, fno: str | None = None, focus_m: str | None = None, object_m: str | None = None, config: str | None = None
    ) -> GridAxes:
        """The axes from the command line's comma lists (parse_setting_list)."""
        return cls(
            parse_setting_list(fno, "fno"),
            parse_setting_list(focus_m, "focus_m"),
            parse_setting_list(object_m, "object_m"),
            parse_setting_list(config, "config"),
        )

    @property
    def given(self) -> bool:
        """Whether any axis is given."""
        return any(getattr(self, k) is not None for k in AXES)

    @property
    def is_grid(self) -> bool:
        """Whether any axis holds more than one value (else: one setting)."""
        return any(len(getattr(self, k) or ()) > 1 for k in AXES)

    def settings(self) -> list[ShootingSettings]:
        """Every setting of the grid: the product of the axes, config outermost, then fno,
        focus_m, object_m, each in the order given."""
        lists = [getattr(self, k) or (None,) for k in AXES]
        return [ShootingSettings(**dict(zip(AXES, combo, strict=True))) for combo in itertools.product(*lists)]

    def to_dict(self) -> dict[str, Any]:
        """{axis: list of values or None} for JSON (distances "inf" where infinite)."""
        return {k: None if getattr(self, k) is None else strict_json(getattr(self, k)) for k in AXES}


def setting_label(settings: ShootingSettings) -> str:
    """A short label of a setting for messages, e.g. 'F/2.8, focus 3 m, config tele'."""
    parts = []
    if settings.fno is not None:
        parts.append(f"F/{settings.fno:g}")
    for key, word in (("focus_m", "focus"), ("object_m", "object")):
        v = getattr(settings, key)
        if v is not None:
            parts.append(f"{word} {'inf' if math.isinf(v) else f'{v:g} m'}")
    if settings.config is not None:
        parts.append(f"config {settings.config}")
    return ", ".join(parts) or "as the lens file has it"


def _grid_manifest(
    lens: Lens, axes: GridAxes, settings: list[ShootingSettings], resolved: list[dict], bank_manifest: dict
) -> dict:
    """The grid's manifest; `bank_manifest` is the first setting's bank manifest, whose
    shared options (not its lens) are recorded once."""
    shared = {
        k: bank_manifest[k]
        for k in (
            "pixel_pitch_um",
            "kernel_pixels",
            "fields",
            "wavelengths_nm",
            "primary_wavelength_nm",
            "response",
            "method",
            "pupil_samples",
            "ri_samples",
            "aiming",
        )
    }
    return {
        "format": GRID_FORMAT,
        "format_version": GRID_FORMAT_VERSION,
        "lens_file": lens.source,
        "lens": lens_to_dict(lens),
        "axes": axes.to_dict(),
        "bank": shared,
        "settings": [
            {"bank": setting_dir(i), "request": s.to_dict(), "resolved": record(r)}
            for i, (s, r) in enumerate(zip(settings, resolved, strict=True))
        ],
        "lensim_version": lensim_version(),
    }


def read_grid_manifest(directory: str | Path) -> dict | None:
    """The manifest of a grid folder; None when the folder has no manifest or holds a
    single bank. A manifest of a grid that is not one is a one-line InputError."""
    p = Path(directory) / MANIFEST
    if not p.is_file():
        return None
    try:
        m = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(str(p), None, f"not valid JSON: {e}") from None
    if not isinstance(m, dict) or m.get("format") != GRID_FORMAT:
        return None
    if m.get("format_version") != GRID_FORMAT_VERSION:
        raise InputError(str(p), "format_version", f"expected {GRID_FORMAT_VERSION}, got {m.get('format_version')!r}")
    if not isinstance(m.get("settings"), list) or not m["settings"]:
        raise InputError(str(p), "settings", "expected a non-empty list of settings")
    return m


def is_grid(directory: str | Path) -> bool:
    """Whether a folder holds a grid of banks (its manifest's format)."""
    return read_grid_manifest(directory) is not None


def open_grid_directory(directory: Path, manifest: dict) -> None:
    """Write the grid's manifest, or check it against the one there: a folder holding a
    single bank, or a grid of other settings with banks already started, is refused."""
    p = directory / MANIFEST
    if p.is_file():
        old = read_grid_manifest(directory)
        if old is None:
            raise InputError(
                str(p),
                "format",
                f"the folder holds a single PSF bank ({BANK_FORMAT}); expected a new folder for a grid of banks",
            )
        diff = manifest_differences(old, manifest)
        started = any(directory.glob("s[0-9][0-9][0-9]/field_*.npz"))
        if diff and started:
            raise InputError(
                str(p),
                ", ".join(diff),
                "the grid on disk was made with different settings; expected "
                "the same settings to resume, or a new output folder",
            )
        if not diff:
            return
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write_text(p, json.dumps(manifest, indent=2) + "\n")


def grid_kernel_pixels(lenses: Sequence[Lens], pitch_um: float, settings: BankSettings) -> int:
    """The kernel size (pixels) of every bank of a grid: settings.kernel_pixels, or the
    largest any setting's lens asks for (suggest_kernel_pixels, at most kernel_limit)."""
    if settings.kernel_pixels:
        return settings.kernel_pixels
    return max(suggest_kernel_pixels(lens, pitch_um, settings.kernel_limit) for lens in lenses)


def _plan_grid(
    lens: Lens,
    pixel_pitch_um: float,
    axes: GridAxes,
    settings: BankSettings,
    response: str | Path | SpectralResponse | None,
    out_dir: Path,
) -> tuple[list[BankPlan], dict]:
    """The plans of the grid of banks `axes` spans for this lens at this pixel pitch (um),
    one per setting in out_dir/s000, s001, ... (their kernel size, when settings give none,
    the largest any setting asks for), and the grid's manifest; nothing computed or written.

    Raises InputError for settings the lens cannot take (a ParameterError naming the
    setting), and for axes without a value."""
    if not axes.given:
        raise ParameterError(None, "shooting", "expected at least one setting list for a grid")
    shots = axes.settings()
    lenses = [lens_at(lens, s) for s in shots]
    resolved = [describe(lens, s) for s in shots]
    kernel = grid_kernel_pixels(lenses, pixel_pitch_um, settings)
    plans = [
        _plan_bank(at, pixel_pitch_um, kernel, settings, response, out_dir / setting_dir(i), setting_label(s))
        for i, (at, s) in enumerate(zip(lenses, shots, strict=True))
    ]
    for plan, s, r in zip(plans, shots, resolved, strict=True):
        plan.manifest["shooting"] = {"request": s.to_dict(), "resolved": record(r)}
    return plans, _grid_manifest(lens, axes, shots, resolved, plans[0].manifest)


class GridBank:
    """A grid of banks on disk (see the module docstring).

    settings: the ShootingSettings of each bank as asked for; resolved: their resolved
    numbers (describe(): fno, working_fno, focus_m, object_m, focal_mm, config; math.inf
    for infinite distances); bank(i): setting i's PSFBank (loaded once); nearest(...): the
    index of the setting nearest given values; interpolated(...): a bank blended between
    the settings around given values (lensim.psf.bank.grid_interp)."""

    def __init__(self, directory: str | Path, manifest: dict) -> None:
        self.directory = Path(directory)
        self.manifest = manifest
        source = str(self.directory / MANIFEST)
        try:
            self.settings = [ShootingSettings.from_dict(e["request"]) for e in manifest["settings"]]
            self.resolved = [resolved_numbers(e["resolved"]) for e in manifest["settings"]]
            self.names = [str(e["bank"]) for e in manifest["settings"]]
        except (KeyError, TypeError) as e:
            raise InputError(source, "settings", f"expected entries with bank, request and resolved ({e})") from None
        except InputError as e:
            raise InputError(source, "settings", e.message) from None
        if any(Path(n).name != n or n in ("", ".", "..") for n in self.names):
            raise InputError(source, "settings", "expected sub-folder names for the banks")
        self._banks: dict[int, PSFBank] = {}

    @classmethod
    def load(cls, directory: str | Path) -> GridBank:
        """The grid in a folder; a one-line InputError when it holds none."""
        m = read_grid_manifest(directory)
        if m is None:
            raise InputError(
                str(directory),
                MANIFEST,
                "not a grid of PSF banks; expected a folder written by "
                "compute_grid (`lensim psf bank` with lists of settings)",
            )
        return cls(directory, m)

    def __len__(self) -> int:
        return len(self.settings)

    @property
    def lens(self) -> dict:
        """The lens file's lens (a native-format mapping) the grid was computed from."""
        return self.manifest["lens"]

    @property
    def axes(self) -> dict[str, list | None]:
        """{axis: its values (math.inf for infinite distances) or None}."""
        return {k: None if v is None else [from_strict(x) for x in v] for k, v in self.manifest["axes"].items()}

    def bank(self, index: int) -> PSFBank:
        """The bank of setting `index` (0-based), loaded once."""
        if not 0 <= index < len(self):
            raise InputError(str(self.directory), "setting", f"expected a setting 0..{len(self) - 1}, got {index}")
        if index not in self._banks:
            self._banks[index] = PSFBank.load(self.directory / self.names[index])
        return self._banks[index]

    def bank_dir(self, index: int) -> Path:
        """The folder of setting `index`'s bank."""
        return self.directory / self.names[index]

    def label(self, index: int) -> str:
        """Setting `index` in words (setting_label)."""
        return setting_label(self.settings[index])

    def nearest(
        self,
        fno: float | None = None,
        focus_m: float | None = None,
        object_m: float | None = None,
        config: str | None = None,
    ) -> int:
        """The index of the setting nearest the given values (grid_interp.nearest_setting)."""
        from lensim.psf.bank.grid_interp import nearest_setting

        return nearest_setting(self, {"fno": fno, "focus_m": focus_m, "object_m": object_m, "config": config})

    def interpolated(
        self,
        fno: float | None = None,
        focus_m: float | None = None,
        object_m: float | None = None,
        config: str | None = None,
    ) -> PSFBank:
        """A bank at the given values blended from the settings around them
        (grid_interp.interpolate_bank); values outside the grid are refused."""
        from lensim.psf.bank.grid_interp import interpolate_bank

        return interpolate_bank(self, {"fno": fno, "focus_m": focus_m, "object_m": object_m, "config": config})
