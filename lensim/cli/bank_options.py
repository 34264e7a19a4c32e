"""The PSF-bank options of `psf bank`, `simulate` and `dataset make`, declared once with
BankSettings' defaults, and the cached bank `simulate` and `dataset make` ask for: the same
options always name the same cached bank."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from lensim.cli.common import progress_bar
from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.psf.bank import PSFBank
from lensim.psf.bank.settings import DEFAULT_WAVELENGTHS_TEXT, BankSettings, parse_wavelengths_nm
from lensim.render.bank_cache import ensure_bank
from lensim.sensor.profile import SensorProfile


def fields_option() -> Any:
    return typer.Option(BankSettings.fields, "--fields", help="Radial fields 0..1 of the bank (at least 2; "
                        "sqrt-spaced: denser towards the edge).")


def wavelengths_option() -> Any:
    return typer.Option(DEFAULT_WAVELENGTHS_TEXT, "--wavelengths-nm", help="Bank wavelengths in nm: START:STOP:STEP "
                        "(STOP included when a step lands on it) or a comma list.")


def pupil_samples_option() -> Any:
    return typer.Option(BankSettings.pupil_samples, "--pupil-samples", help="Pupil grid samples across the diameter.")


def cache_option() -> Any:
    return typer.Option(None, "--cache", help="Bank cache folder (default $LENSIM_CACHE or ~/.cache/lensim).")


#: the command-line option of each BankSettings field, for error messages
OPTION_NAMES = {"fields": "--fields", "wavelengths_nm": "--wavelengths-nm", "pupil_samples": "--pupil-samples",
                "aiming": "--aiming", "kernel_pixels": "--kernel"}


def bank_settings(fields: int, wavelengths: str, pupil_samples: int, cache: Path | None = None,
                  **more: Any) -> BankSettings:
    """BankSettings from the command line's bank options (checked before any work; an
    error names the option)."""
    try:
        return BankSettings(fields=fields, wavelengths_nm=parse_wavelengths_nm(wavelengths),
                            pupil_samples=pupil_samples, cache_dir=cache, **more)
    except InputError as e:
        if e.source == "<command line>":
            raise
        raise InputError("<command line>", OPTION_NAMES.get(e.field or "", e.field), e.message) from None


def cached_bank(lens: Lens, pitch_um: float, sensor: SensorProfile, settings: BankSettings, workers: int,
                quiet: bool) -> PSFBank:
    """The lens's bank at this pitch (um) with the sensor's spectral response, from the
    cache or computed into it, with a progress bar unless quiet."""
    prog, cb = progress_bar("PSF bank", "fields", quiet)
    if prog:
        prog.start()
    try:
        return ensure_bank(lens, pitch_um, settings, response=sensor.spectral_response, workers=workers, progress=cb)
    finally:
        if prog:
            prog.stop()
