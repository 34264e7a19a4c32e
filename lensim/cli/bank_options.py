"""The PSF-bank options of `psf bank`, `simulate` and `dataset make`, declared once with
BankSettings' defaults (the same options always name the same cached bank, which
lensim.psf.bank.get_bank finds or computes), and the bank given by --bank with the lens
that goes with it (lensim.psf.bank.bank_lens, its errors named by option).

Also the shooting-settings options (--fno, --object-m, --focus-m, --config;
lensim.optics.shooting), declared once: comma lists (grids) on `psf bank` and `dataset
make` (setting_list_option), single values on `psf compute`, `simulate`, `demo` and `lens
info/plot/spot/field` (setting_option, shooting_settings).

The options' defaults come from lensim.psf.defaults (plain Python): building the options
and the help loads no optics or PSF module; the functions that compute load them."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from lensim.errors import InputError, ParameterError
from lensim.psf.defaults import BANK_FIELDS, BANK_PUPIL_SAMPLES, DEFAULT_WAVELENGTHS_TEXT

if TYPE_CHECKING:
    from lensim.optics.lens import Lens
    from lensim.optics.shooting import ShootingSettings
    from lensim.psf.bank import BankSettings, GridBank, PSFBank
    from lensim.sensor.profile import SensorProfile


def fields_option() -> Any:
    return typer.Option(
        BANK_FIELDS,
        "--fields",
        help="Radial fields 0..1 of the bank (at least 2; sqrt-spaced: denser towards the edge).",
    )


def wavelengths_option() -> Any:
    return typer.Option(
        DEFAULT_WAVELENGTHS_TEXT,
        "--wavelengths-nm",
        help="Bank wavelengths in nm: START:STOP:STEP (STOP included when a step lands on it) or a comma list.",
    )


def pupil_samples_option() -> Any:
    return typer.Option(BANK_PUPIL_SAMPLES, "--pupil-samples", help="Pupil grid samples across the diameter.")


def workers_option() -> Any:
    return typer.Option(1, "--workers", help="Worker processes: a local Dask cluster when > 1 (one torch thread each).")


def scheduler_option() -> Any:
    return typer.Option(
        None,
        "--scheduler",
        help="Address of an existing Dask scheduler to compute on (e.g. tcp://10.0.0.5:8786) instead of local workers.",
    )


def setting_list_option(key: str) -> Any:
    """A comma list of one shooting setting (fno, focus_m, object_m, config): grids on `psf
    bank` and `dataset make` (lensim.psf.bank.grid)."""
    helps = {
        "fno": "F-number(s), image space at infinity; a comma list makes a grid of banks (e.g. 1.4,2,2.8).",
        "focus_m": "Focus distance(s) in m from the image plane, inf allowed; a comma list makes a grid (e.g. inf,3,1).",
        "object_m": "Object distance(s) in m from the image plane (default: the focus distance); a comma list makes "
        "a grid.",
        "config": "Lens configuration(s) (zoom positions), names or 1-based numbers; a comma list makes a grid.",
    }
    return typer.Option(None, setting_flag(key), help=helps[key])


def setting_flag(key: str) -> str:
    """The option of a shooting setting (fno -> --fno, focus_m -> --focus-m)."""
    return "--" + key.replace("_", "-")


_SINGLE_HELP = {
    "fno": "F-number: the stop is set for image-space F/N at infinity and keeps its size when focusing close "
    "(default: the lens file's aperture, the widest allowed).",
    "focus_m": "Focus distance in m from the image plane, or inf: the image plane (or the lens file's focus group) "
    "moves to focus there (default: --object-m, else as the lens file is).",
    "object_m": "Object distance in m from the image plane, or inf (default: --focus-m, else the lens file's).",
    "config": "Lens configuration (zoom position): its name or 1-based number.",
}


def setting_option(key: str) -> Any:
    """One shooting setting (fno, focus_m, object_m, config), a single value: commands
    that use the lens at one setting."""
    return typer.Option(None, setting_flag(key), help=_SINGLE_HELP[key])


def fno_option() -> Any:
    return setting_option("fno")


def object_m_option() -> Any:
    return setting_option("object_m")


def focus_m_option() -> Any:
    return setting_option("focus_m")


def config_option() -> Any:
    return setting_option("config")


def focus_mode_option() -> Any:
    """--focus-mode: how --focus-m focuses (lensim.optics.shooting.FOCUS_MODES)."""
    return typer.Option(
        None,
        "--focus-mode",
        help="How --focus-m focuses: calibrated (default: the image plane follows the on-axis best focus, "
        "minimum polychromatic RMS wavefront, keeping the lens file's own offset from it), best (on the best "
        "focus itself, as a centre-point autofocus) or paraxial (the file's offset from the paraxial image).",
    )


def shooting_settings(
    fno: str | None, object_m: str | None, focus_m: str | None, config: str | None, focus_mode: str | None = None
) -> ShootingSettings:
    """The ShootingSettings of the single-value options (checked; one-line errors naming
    the option; a comma list is refused: grids are psf bank's and dataset make's);
    focus_mode is --focus-mode's text (None: the default)."""
    from lensim.optics.shooting import ShootingSettings

    for key, text in (("fno", fno), ("object_m", object_m), ("focus_m", focus_m), ("config", config)):
        if text is not None and "," in str(text):
            raise InputError(
                "<command line>",
                setting_flag(key),
                f"expected one value, got the list {text!r} (grids of settings are made by psf bank and dataset make)",
            )
    return ShootingSettings.from_text(fno, object_m, focus_m, config, focus_mode)


def lens_and_record(lens_file: str, settings: ShootingSettings) -> tuple[Lens, dict | None]:
    """The lens file (or built-in name) at the shooting settings, and the settings as
    records keep them (lensim.optics.shooting.lens_and_record)."""
    from lensim.optics import shooting
    from lensim.optics.lens_file import load_lens

    return shooting.lens_and_record(load_lens(lens_file), settings)


def cache_option() -> Any:
    return typer.Option(None, "--cache", help="Bank cache folder (default $LENSIM_CACHE or ~/.cache/lensim).")


#: the command-line option of each BankSettings field, for error messages
OPTION_NAMES = {
    "fields": "--fields",
    "wavelengths_nm": "--wavelengths-nm",
    "pupil_samples": "--pupil-samples",
    "aiming": "--aiming",
    "kernel_pixels": "--kernel",
    "method": "--method",
    "max_spacing_um": "--max-spacing-um",
    "illuminant": "--illuminant",
}


def bank_settings(
    fields: int, wavelengths: str, pupil_samples: int, cache: Path | None = None, **more: Any
) -> BankSettings:
    """BankSettings from the command line's bank options (checked before any work; an
    error names the option)."""
    from lensim.psf.bank.settings import BankSettings, parse_wavelengths_nm

    try:
        return BankSettings(
            fields=fields,
            wavelengths_nm=parse_wavelengths_nm(wavelengths),
            pupil_samples=pupil_samples,
            cache_dir=cache,
            **more,
        )
    except InputError as e:
        if isinstance(e, ParameterError):  # the command shows the parameter as its option
            raise
        raise InputError("<command line>", OPTION_NAMES.get(e.field or "", e.field), e.message) from None


def check_response(
    settings: BankSettings, response: str | Path, illuminant: str = "E", sensor: SensorProfile | None = None
) -> None:
    """Refuse, before any work, a spectral response or illuminant the bank could not
    use: an error names the sensor profile that asked for the response (its
    spectral_response field), else the option (--response, --illuminant)."""
    from lensim.sensor.spectral import spectral_response

    try:
        spectral_response(list(settings.wavelengths_nm), response, illuminant)
    except InputError as e:
        if e.source is not None:  # the CSV table named itself
            raise
        if e.field == "illuminant":
            raise InputError("--illuminant", None, e.message) from None
        if sensor is not None and sensor.path:
            raise InputError(sensor.path, "spectral_response", e.message) from None
        raise InputError("--response" if sensor is None else f"sensor {sensor.name!r}", None, e.message) from None


def bank_for_lens(
    bank_dir: Path, lens_file: str | None, shooting: ShootingSettings | None = None
) -> tuple[PSFBank, Lens]:
    """The bank of ``--bank`` and the lens to simulate: the bank's own lens, or --lens
    (at the shooting settings) when given, which must then be the lens the bank was
    computed for (a bank of another lens would be used silently otherwise). Shooting
    settings without --lens are refused: the bank's lens is already set."""
    from lensim.cli.validate import input_folder
    from lensim.psf.bank import PSFBank

    bank = PSFBank.load(input_folder(bank_dir, "--bank", "bank folder"))
    if shooting is not None and not shooting.is_default:
        given = ", ".join(setting_flag(k) for k, v in shooting.to_dict().items() if v is not None)
        if lens_file is None:
            raise InputError(
                "<command line>",
                given,
                f"the bank {bank_dir} holds its lens at the settings it was "
                "computed for; expected --lens with these options, or none of them",
            )
    return bank, _lens_of(bank, bank_dir, lens_file, shooting)


def bank_or_grid_for_lens(bank_dir: Path, lens_file: str | None) -> tuple[PSFBank | GridBank, Lens]:
    """bank_for_lens, where the folder may also hold a grid of banks (lensim.psf.bank.grid;
    the lens is then its lens file's lens)."""
    from lensim.cli.validate import input_folder
    from lensim.psf.bank.grid import GridBank, is_grid

    folder = input_folder(bank_dir, "--bank", "bank folder")
    if not is_grid(folder):
        return bank_for_lens(bank_dir, lens_file)
    grid = GridBank.load(folder)
    return grid, _lens_of(grid, bank_dir, lens_file)


def _lens_of(
    bank: PSFBank | GridBank, bank_dir: Path, lens_file: str | None, shooting: ShootingSettings | None = None
) -> Lens:
    """The lens a bank's manifest stores, or --lens (at the shooting settings) checked
    against it (lensim.psf.bank.bank_lens, its errors named by option)."""
    from lensim.optics.shooting import ShootingSettings
    from lensim.psf.bank import bank_lens

    lens = None if lens_file is None else lens_and_record(lens_file, shooting or ShootingSettings())[0]
    try:
        return bank_lens(bank, lens)
    except InputError as e:
        if e.field != "lens":
            raise
        if lens is None:
            raise InputError(str(bank_dir), "lens", "the bank records no lens; expected --lens") from None
        at = "" if shooting is None or shooting.is_default else " at these settings"
        raise InputError("--lens", f"{lens_file}{at}", f"{e.message}, or no --lens") from None


def refuse_posed_bank(lens: Lens) -> None:
    """A --bank given for a lens with poses is refused in one line: such a lens renders
    through its posed banks (lensim.render.posed.sensor_banks), which the command computes."""
    if lens.has_poses:
        raise InputError(
            "--bank",
            None,
            "is a bank of a lens with poses, which renders through its posed banks (one per sensor "
            "quadrant and its mirrored lens's); expected --lens LENS without --bank (they are computed)",
        )
