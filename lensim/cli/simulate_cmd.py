"""`lensim simulate`: what the camera would photograph."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lensim import assets
from lensim.cli.bank_options import (
    bank_for_lens,
    bank_settings,
    cache_option,
    check_response,
    config_option,
    fields_option,
    fno_option,
    focus_m_option,
    focus_mode_option,
    lens_and_record,
    object_m_option,
    pupil_samples_option,
    refuse_posed_bank,
    shooting_settings,
    wavelengths_option,
)
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, choice, distinct_outputs, output_folder
from lensim.io import atomic_write_text

if TYPE_CHECKING:
    from lensim.optics.lens import Lens
    from lensim.psf.bank import BankSettings, PSFBank
    from lensim.sensor.profile import SensorProfile


def simulate_command(
    ctx: typer.Context,
    images: list[Path] = typer.Argument(..., help="Sharp sRGB photos (8/16-bit PNG, TIFF or JPEG)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    lens_file: str = typer.Option(
        None,
        "--lens",
        help=f"Lens file or built-in lens name (default: the bank's lens with --bank, else {assets.DEFAULT_LENS}).",
    ),
    sensor_file: str = typer.Option(
        None, "--sensor", help="Sensor profile file or built-in name (default: the built-in default)."
    ),
    bank_dir: Path = typer.Option(
        None, "--bank", help="A PSF bank at the image's effective pitch (default: computed and cached)."
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the colour temperature and noise draws."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add shot and read noise."),
    blur: bool = typer.Option(True, "--blur/--no-blur", help="Apply the lens's PSFs."),
    shading: bool = typer.Option(
        True, "--relative-illumination/--no-relative-illumination", help="Apply lens shading."
    ),
    distortion: bool = typer.Option(False, "--distortion/--no-distortion", help="Also warp by the lens's distortion."),
    demosaic: str = typer.Option("ahd", "--demosaic", help="ahd, malvar, menon or bilinear."),
    bits: int = typer.Option(8, "--bits", help="Output bit depth: 8 or 16."),
    fmt: str = typer.Option("png", "--format", help="Output file type: png or tif."),
    raw: bool = typer.Option(
        False,
        "--raw",
        help="Also write the noisy Bayer mosaic as a CFA DNG (OUT/<name>.dng) that LibRaw and raw converters open.",
    ),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    workers: int = typer.Option(1, "--workers", help="Processes for the bank."),
    cache: Path = cache_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print what was written and drawn as JSON."),
    fno: str = fno_option(),
    object_m: str = object_m_option(),
    focus_m: str = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str = config_option(),
) -> None:
    """Simulate what the camera (lens + sensor) would deliver for each sharp photo.

    Each image is mapped onto the whole sensor (centred, the limiting side spanning it), so
    every pixel has a physical field position; the PSF bank is computed at that effective
    pitch and cached (the bank options are those of `psf bank` and `dataset make`, with the
    same defaults). Writes OUT/<name>.png and OUT/<name>.json (the draws: colour
    temperature, noise levels, seed; with --fno/--object-m/--focus-m/--config, the resolved
    shooting settings). A lens with poses (an as-built lens from `lensim calibrate`) is
    simulated through its posed banks (one per sensor quadrant and its mirrored lens's: 8),
    each pixel through its own.

    Example: lensim simulate photo.png --lens cooke_triplet --sensor apsc_mirrorless -o sim/
    """
    import torch

    from lensim.images import read_image, write_image
    from lensim.render.kernels import check_bank_fits
    from lensim.render.mapping import map_to_sensor
    from lensim.render.pipeline import simulate
    from lensim.render.posed import sensor_banks
    from lensim.sensor.profile import load_sensor

    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    shooting = shooting_settings(fno, object_m, focus_m, config, focus_mode)
    _check_options(output, fmt, bits, demosaic, workers, cache)
    _check_photos(images, fmt)
    described = None
    if bank_dir is not None:
        given_bank, lens = bank_for_lens(bank_dir, lens_file, shooting)
        recorded = given_bank.manifest.get("shooting")  # a bank of one setting (psf bank --fno ...)
        described = recorded.get("resolved") if isinstance(recorded, dict) else None
    else:
        given_bank = None
        lens, described = lens_and_record(lens_file or assets.DEFAULT_LENS, shooting)
    _check_poses(lens, given_bank is not None, distortion)
    sensor = load_sensor(sensor_file)
    if given_bank is None and (blur or distortion):
        check_response(settings, sensor.spectral_response, sensor=sensor)
    banks: dict[tuple[int, int], PSFBank | dict[str, PSFBank]] = {}
    results = []
    for i, path in enumerate(images):
        img, in_bits = read_image(path)
        h, w = img.shape[1:]
        mapping = map_to_sensor(h, w, sensor)
        bank: PSFBank | dict[str, PSFBank] | None = None
        if blur or distortion:
            if given_bank is not None:
                check_bank_fits(given_bank, mapping, str(bank_dir))
                bank = given_bank
            else:
                if (h, w) not in banks:
                    pupil_given = ctx.get_parameter_source("pupil_samples").name != "DEFAULT"
                    # a lens with poses: its posed banks by source, each at the photo's pitch
                    bank_of = partial(
                        _photo_bank,
                        path,
                        (w, h),
                        mapping.pitch_um,
                        sensor=sensor,
                        settings=settings,
                        pupil_given=pupil_given,
                        workers=workers,
                        quiet=quiet or json_out,
                    )
                    banks[(h, w)] = sensor_banks(lens, sensor, bank_of)
                bank = banks[(h, w)]
        gen = torch.Generator().manual_seed(seed + i)
        raw_path = output / (path.stem + ".dng") if raw else None
        out, params = simulate(
            img,
            bank,
            sensor,
            gen,
            blur=blur,
            noise=noise,
            relative_illumination=shading,
            demosaic=demosaic,
            bits=bits,
            raw_path=raw_path,
            distortion=distortion,
        )
        target = output / f"{path.stem}.{fmt}"
        write_image(target, out, bits)
        info = {
            "input": str(path),
            "output": str(target),
            "seed": seed + i,
            "lens": lens.source,
            "sensor": sensor.name,
            "bank": None if bank is None else _folders(bank),
            **params.to_dict(),
        }
        if described is not None:
            info["settings"] = described
        atomic_write_text(output / (path.stem + ".json"), json.dumps(info, indent=2, default=str) + "\n")
        results.append(info)
        if not quiet and not json_out:
            console.print(f"wrote {target} (pitch {mapping.pitch_um:.3g} um, {params.kelvin:.0f} K)", highlight=False)
    if json_out:
        print_json(results)


def _check_poses(lens: Lens, bank_given: bool, distortion: bool) -> None:
    """A lens with poses is simulated through its posed banks (lensim.render.posed.sensor_banks,
    computed here), without distortion: one line naming --bank or --distortion otherwise."""
    from lensim.errors import InputError

    if bank_given:
        refuse_posed_bank(lens)
    if lens.has_poses and distortion:
        raise InputError(
            "--distortion", None, "through the posed banks of a lens with poses is not modelled; expected none"
        )


def _folders(bank: PSFBank | dict[str, PSFBank]) -> str | dict[str, str]:
    """A bank's folder, or a lens with poses' banks' folders by source (the photo's record)."""
    return {k: str(b.directory) for k, b in bank.items()} if isinstance(bank, dict) else str(bank.directory)


def _photo_bank(
    path: Path,
    size_wh: tuple[int, int],
    pitch_um: float,
    lens: Lens,
    sensor: SensorProfile,
    settings: BankSettings,
    pupil_given: bool,
    workers: int,
    quiet: bool,
) -> PSFBank:
    """The cached bank for a photo mapped onto the sensor at ``pitch_um`` (um per photo
    pixel), with the pupil sampling its kernel window needs (a small photo has coarse
    pixels: lensim.psf.bank.settings.with_enough_pupil_samples raises it, or names
    --pupil-samples when it was given)."""
    from lensim.psf.bank import get_bank
    from lensim.psf.bank.settings import with_enough_pupil_samples

    def bank(s: BankSettings) -> PSFBank:
        with progress_bar("PSF bank", "fields", quiet) as report:
            return get_bank(lens, pitch_um, s, response=sensor.spectral_response, workers=workers, progress=report)

    return with_enough_pupil_samples(
        bank,
        settings,
        fixed=pupil_given,
        source=str(path),
        context=f"a {size_wh[0]}x{size_wh[1]} photo maps onto the sensor at {pitch_um:.3g} um per pixel",
    )


def _check_options(output: Path, fmt: str, bits: int, demosaic: str, workers: int, cache: Path | None) -> None:
    """The command's options, before any work (one-line errors naming the option)."""
    from lensim.sensor.isp import DEMOSAIC_METHODS

    choice(fmt, ("png", "tif"), "--format")
    choice(bits, (8, 16), "--bits")
    choice(demosaic, DEMOSAIC_METHODS, "--demosaic")
    at_least(workers, 1, "--workers", what="a number of processes")
    output_folder(output)
    if cache is not None:
        output_folder(cache, "--cache")


def _check_photos(images: list[Path], fmt: str) -> None:
    """Every photo readable and no two writing the same OUT/<name>, before the first
    output (a bad last photo must not leave the earlier ones written)."""
    from lensim.images import read_image

    distinct_outputs(images, lambda p: f"{p.stem}.{fmt}")
    for path in images:
        read_image(path)
