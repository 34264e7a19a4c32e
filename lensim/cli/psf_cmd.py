"""`lensim psf ...`: compute single PSFs (and PSF banks)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lensim.cli.bank_options import (
    bank_settings,
    check_response,
    config_option,
    fields_option,
    fno_option,
    focus_m_option,
    focus_mode_option,
    lens_and_record,
    object_m_option,
    pupil_samples_option,
    scheduler_option,
    setting_list_option,
    shooting_settings,
    wavelengths_option,
    workers_option,
)
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import (
    AIMINGS,
    at_least,
    choice,
    in_range,
    input_folder,
    output_file,
    output_folder,
    pixel_pitch_um,
    positive,
    scheduler_address,
)
from lensim.cli.validate import wavelength_nm as wavelength_nm_checked
from lensim.errors import InputError
from lensim.io import atomic_write_bytes
from lensim.jsonable import jsonable
from lensim.psf.defaults import METHODS, psf_method

if TYPE_CHECKING:
    import numpy as np

    from lensim.optics.lens import Lens
    from lensim.psf.bank import BankSettings
    from lensim.psf.bank.grid import GridAxes

psf_app = typer.Typer(help="Point spread functions: single PSFs, banks, pictures.", no_args_is_help=True)


@psf_app.command("compute")
def compute(
    lens_file: str = typer.Argument(..., help="Lens file or built-in lens name."),
    field: float = typer.Option(0.0, "--field", help="Normalized field, 0..1 of the lens's max field along +y."),
    wavelength_nm: float = typer.Option(550.0, "--wavelength-nm", help="Wavelength in nm."),
    method: str = typer.Option("huygens", "--method", help=f"One of {', '.join(METHODS)}."),
    pupil_samples: int = typer.Option(128, "--pupil-samples", help="Pupil grid samples across the diameter."),
    grid: int = typer.Option(128, "--grid", help="PSF window size in samples (grid x grid)."),
    spacing_um: float = typer.Option(0.5, "--spacing-um", help="PSF sample spacing in um."),
    aiming: str = typer.Option("real", "--aiming", help="Ray aiming: real or paraxial."),
    output: Path = typer.Option(None, "-o", "--output", help="Write the PSF array (.npy, energy per sample)."),
    json_out: bool = typer.Option(
        False, "--json", help="Print the figures (Strehl, RMS spot, EE50/EE80, chief-ray position) as JSON."
    ),
    fno: str = fno_option(),
    object_m: str = object_m_option(),
    focus_m: str = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str = config_option(),
) -> None:
    """One PSF: grid x grid samples at spacing_um, centred on the real chief-ray image point;
    the array sums to the transmitted fraction (inside the window). --fno, --object-m,
    --focus-m and --config set the lens first (--json prints them resolved as "settings").

    Example: lensim psf compute cooke_triplet --field 0.7 --wavelength-nm 550 -o psf.npy --json
    """
    from lensim.psf.compute import compute_psf

    in_range(field, 0.0, 1.0, "--field", what="a normalized field")
    wavelength_nm_checked(wavelength_nm)
    kind = psf_method(method, "--method", None)
    choice(aiming, AIMINGS, "--aiming")
    at_least(pupil_samples, 2, "--pupil-samples", what="a number of pupil samples")
    at_least(grid, 2, "--grid", "samples", "a PSF window")
    positive(spacing_um, "--spacing-um", "um", "a sample spacing")
    if output is not None:
        output_file(output, suffixes=(".npy",))
    lens, described = lens_and_record(lens_file, shooting_settings(fno, object_m, focus_m, config, focus_mode))
    psf = compute_psf(lens, field, wavelength_nm / 1000.0, kind, pupil_samples, grid, spacing_um, aiming)
    if output is not None:
        _save_npy(output, psf.data)
    info = {
        "lens": lens.source,
        "field": field,
        "field_value": psf.field_value,
        "field_type": lens.field_type,
        "wavelength_nm": wavelength_nm,
        "method": method,
        "grid": grid,
        "spacing_um": spacing_um,
        "pupil_samples": pupil_samples,
        "aiming": aiming,
        **psf.figures,
    }
    if described is not None:
        info["settings"] = described
    if json_out:
        print_json(info)
        return
    for k, v in info.items():
        console.print(f"{k:22s} {v}", highlight=False)
    if output is not None:
        console.print(f"wrote {output}")


def _save_npy(path: Path, data: np.ndarray) -> None:
    """``data`` as a .npy file, written atomically."""
    import io

    import numpy as np

    buf = io.BytesIO()
    np.save(buf, data)
    atomic_write_bytes(path, buf.getvalue())


@psf_app.command("bank")
def bank(
    lens_file: str = typer.Argument(None, help="Lens file or built-in lens name (or use --lens)."),
    lens_opt: str = typer.Option(None, "--lens", help="Lens file or built-in lens name (same as the argument)."),
    sensor: str = typer.Option(
        None, "--sensor", help="Sensor profile (file or built-in name): sets the pixel pitch and the spectral response."
    ),
    pixel_um: float = typer.Option(None, "--pixel-um", help="Sensor pixel pitch in um (instead of --sensor)."),
    kernel: int = typer.Option(0, "--kernel", help="Kernel size in pixels (odd; 0: sized from the lens's spots)."),
    fields: int = fields_option(),
    wavelengths_nm: str = wavelengths_option(),
    response: str = typer.Option(
        None,
        "--response",
        help="Camera spectral sensitivities: a colour-science camera name or a CSV file "
        "(wavelength_nm,r,g,b). Default: the sensor's, else Nikon 5100 (NPL).",
    ),
    illuminant: str = typer.Option("E", "--illuminant", help="E (equal energy), D65, A, ... (colour-science names)."),
    method: str = typer.Option("huygens", "--method", help=f"One of {', '.join(METHODS)}."),
    pupil_samples: int = pupil_samples_option(),
    max_spacing_um: float = typer.Option(
        None,
        "--max-spacing-um",
        help="Largest fine PSF spacing in um (default: half the Airy radius at the shortest wavelength).",
    ),
    aiming: str = typer.Option("real", "--aiming", help="Ray aiming: real or paraxial."),
    fno: str = setting_list_option("fno"),
    focus_m: str = setting_list_option("focus_m"),
    object_m: str = setting_list_option("object_m"),
    config: str = setting_list_option("config"),
    workers: int = workers_option(),
    scheduler: str = scheduler_option(),
    output: Path = typer.Option(
        ..., "-o", "--output", help="Bank directory (created; an existing bank with the same settings is resumed)."
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON (no progress output)."),
) -> None:
    """A PSF bank: RGB pixel kernels at radial fields, weighted by the camera's spectral
    response and the lens's relative illumination, stored as OUTPUT/manifest.json and one
    OUTPUT/field_XXXX.npz per field. Rerun the same command to resume after an interruption.

    The bank options and their defaults are those of `simulate` and `dataset make`
    (lensim.psf.bank.BankSettings).

    Shooting settings (--fno, --focus-m, --object-m, --config): single values give one bank
    of the lens at that setting; comma lists give a grid, OUTPUT/manifest.json listing every
    setting and one bank per setting in OUTPUT/s000, s001, ... (lensim.psf.bank.grid).

    The fields are computed here (--workers 1), on a local Dask cluster (--workers N) or on
    an existing one (--scheduler ADDRESS); the parent writes every field file.

    Example: lensim psf bank --lens cooke_triplet --sensor apsc_mirrorless --fields 64 --workers 2 -o bank/

    Example: lensim psf bank --lens double_gauss --sensor full_frame --fno 2,2.8,4 --focus-m inf,3 -o grid/
    """
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank.grid import GridAxes
    from lensim.sensor.profile import load_sensor
    from lensim.sensor.spectral import DEFAULT_CAMERA

    if lens_file and lens_opt and lens_file != lens_opt:
        raise InputError("<command line>", "lens", f"given twice ({lens_file!r} and --lens {lens_opt!r}); expected one")
    name = lens_file or lens_opt
    if not name:
        raise InputError(
            "<command line>", "lens", "missing; expected a lens file or built-in name (argument or --lens)"
        )
    if (sensor is None) == (pixel_um is None):
        raise InputError("<command line>", "--sensor/--pixel-um", "expected exactly one of them")
    _check_bank_options(pixel_um, kernel, method, max_spacing_um, workers, output)
    scheduler_address(scheduler)
    settings = bank_settings(
        fields,
        wavelengths_nm,
        pupil_samples,
        aiming=aiming,
        kernel_pixels=kernel or None,
        method=method,
        max_spacing_um=max_spacing_um,
        illuminant=illuminant,
    )
    axes = GridAxes.from_options(fno, focus_m, object_m, config)
    lens = load_lens(name)
    profile = load_sensor(sensor) if sensor is not None else None
    pitch = profile.pixel_pitch_um if profile is not None else float(pixel_um)
    from_profile = response is None and profile is not None
    response = response or (profile.spectral_response if profile is not None else DEFAULT_CAMERA)
    check_response(settings, response, illuminant, profile if from_profile else None)
    where = {"workers": workers, "scheduler": scheduler}
    with progress_bar("PSF bank", "fields", quiet or json_out) as report:
        info = _compute_bank(lens, pitch, settings, axes, response, output, where, report)
    info["sensor"] = sensor
    if json_out:
        print_json(info)
    elif not quiet:
        grid = f"{info['settings']} settings x " if "settings" in info else ""
        console.print(
            f"wrote {output}: {grid}{info['fields']} fields x {info['wavelengths']} wavelengths, "
            f"{info['kernel_pixels']}x{info['kernel_pixels']} px of {info['pixel_pitch_um']:g} um, fine grid "
            f"{info['oversampling']}x per pixel ({info['fine_spacing_um']:.4g} um), response {info['response']} "
            f"under {info['illuminant']}, {info['seconds']:.1f} s",
            highlight=False,
        )


def _compute_bank(
    lens: Lens,
    pitch: float,
    settings: BankSettings,
    axes: GridAxes,
    response: str,
    output: Path,
    where: dict,
    report: Callable[[float, float], None] | None,
) -> dict:
    """Compute psf bank's bank, one-setting bank or grid (lensim.psf.bank.get_bank); its
    summary (--json's)."""
    import time

    from lensim.psf.bank import get_bank

    t0 = time.time()
    extra: dict = {}
    if axes.is_grid:
        grid = get_bank(
            lens, pitch, settings, response=response, shooting=axes, out_dir=output, progress=report, **where
        )
        m = grid.bank(0).manifest
        extra = {"settings": len(grid), "grid": [jsonable(r) for r in grid.manifest["settings"]]}
    else:
        shot = axes.settings()[0] if axes.given else None
        m = get_bank(
            lens, pitch, settings, response=response, shooting=shot, out_dir=output, progress=report, **where
        ).manifest
        if shot is not None:
            extra = {"shooting": m["shooting"]["resolved"]}
    oversampling = m["oversampling"]
    return {
        "bank": str(output),
        "lens": lens.source,
        "fields": len(m["fields"]),
        "wavelengths": len(m["wavelengths_nm"]),
        "kernel_pixels": m["kernel_pixels"],
        "pixel_pitch_um": m["pixel_pitch_um"],
        "oversampling": oversampling,
        "fine_spacing_um": m["fine_spacing_um"],
        "response": m["response"]["name"],
        "illuminant": m["response"]["illuminant"],
        **extra,
        "seconds": time.time() - t0,
    }


def _check_bank_options(
    pixel_um: float | None, kernel: int, method: str, max_spacing_um: float | None, workers: int, output: Path
) -> None:
    """psf bank's numbers, method and output folder, before any work."""
    if pixel_um is not None:
        pixel_pitch_um(pixel_um)
    if kernel:
        at_least(kernel, 1, "--kernel", "px", "a kernel size")
    psf_method(method, "--method", None)
    if max_spacing_um is not None:
        positive(max_spacing_um, "--max-spacing-um", "um", "a PSF spacing")
    at_least(workers, 1, "--workers", what="a number of processes")
    output_folder(output)


@psf_app.command("show")
def show(
    bank_dir: Path = typer.Argument(..., help="A bank directory written by `lensim psf bank` (or a grid of banks)."),
    output: Path = typer.Option(..., "-o", "--output", help="Folder for the PNG figures."),
    gamma: float = typer.Option(
        0.5, "--gamma", help="Display gamma of the kernel pictures (smaller shows fainter tails)."
    ),
    setting: int = typer.Option(
        None,
        "--setting",
        help="For a grid of banks: the setting to show (0-based, the "
        "order of its manifest.json; default: every setting, each in OUTPUT/sNNN).",
    ),
) -> None:
    """Figures of a PSF bank: psf_map.png (kernels over the sensor), strehl.png,
    mtf.png (sagittal/tangential at four fields) and relative_illumination.png.

    Example: lensim psf show bank/ -o bank_figures/
    """
    from lensim.plots.bank import write_bank_figures
    from lensim.psf.bank import PSFBank
    from lensim.psf.bank.grid import GridBank, is_grid

    positive(gamma, "--gamma", what="a display gamma")
    input_folder(bank_dir, what="bank folder")
    output_folder(output)
    if not is_grid(bank_dir):
        if setting is not None:
            raise InputError("--setting", None, f"{bank_dir} is a single bank, not a grid; expected no --setting")
        for p in write_bank_figures(PSFBank.load(bank_dir), output, gamma=gamma):
            console.print(f"wrote {p}", highlight=False)
        return
    grid = GridBank.load(bank_dir)
    if setting is not None:
        in_range(setting, 0, len(grid) - 1, "--setting", what=f"a setting of the grid's {len(grid)}")
    for i in range(len(grid)) if setting is None else [setting]:
        out = output if setting is not None else output / grid.names[i]
        console.print(f"setting {i} ({grid.label(i)}):", highlight=False)
        for p in write_bank_figures(grid.bank(i), out, gamma=gamma):
            console.print(f"wrote {p}", highlight=False)
