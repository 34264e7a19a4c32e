"""`lensim simulate`: what the camera would photograph."""
from __future__ import annotations

import json
from pathlib import Path

import torch
import typer

from lensim import assets
from lensim.cli.bank_options import (bank_settings, cache_option, cached_bank, fields_option, pupil_samples_option,
                                     wavelengths_option)
from lensim.cli.common import console, print_json
from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.io import atomic_write_text
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import PSFBank
from lensim.render.kernels import check_bank_fits
from lensim.render.mapping import map_to_sensor
from lensim.render.pipeline import simulate
from lensim.sensor.profile import load_sensor


def simulate_command(
    images: list[Path] = typer.Argument(..., help="Sharp sRGB photos (8/16-bit PNG, TIFF or JPEG)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    lens_file: str = typer.Option(assets.DEFAULT_LENS, "--lens", help="Lens file or built-in lens name."),
    sensor_file: str = typer.Option(None, "--sensor", help="Sensor profile file or built-in name (default: the built-in default)."),
    bank_dir: Path = typer.Option(None, "--bank", help="A PSF bank at the image's effective pitch (default: computed and cached)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the colour temperature and noise draws."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add shot and read noise."),
    blur: bool = typer.Option(True, "--blur/--no-blur", help="Apply the lens's PSFs."),
    shading: bool = typer.Option(True, "--relative-illumination/--no-relative-illumination", help="Apply lens shading."),
    distortion: bool = typer.Option(False, "--distortion/--no-distortion", help="Also warp by the lens's distortion."),
    demosaic: str = typer.Option("ahd", "--demosaic", help="ahd, malvar, menon or bilinear."),
    bits: int = typer.Option(8, "--bits", help="Output bit depth: 8 or 16."),
    fmt: str = typer.Option("png", "--format", help="Output file type: png or tif."),
    raw: bool = typer.Option(False, "--raw", help="Also write the noisy Bayer mosaic as a CFA DNG (OUT/<name>.dng) "
                             "that LibRaw and raw converters open."),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    workers: int = typer.Option(1, "--workers", help="Processes for the bank."),
    cache: Path = cache_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print what was written and drawn as JSON."),
) -> None:
    """Simulate what the camera (lens + sensor) would deliver for each sharp photo.

    Each image is mapped onto the whole sensor (centred, the limiting side spanning it), so
    every pixel has a physical field position; the PSF bank is computed at that effective
    pitch and cached (the bank options are those of `psf bank` and `dataset make`, with the
    same defaults). Writes OUT/<name>.png and OUT/<name>.json (the draws: colour
    temperature, noise levels, seed).

    Example: lensim simulate photo.png --lens cooke_triplet --sensor apsc_mirrorless -o sim/
    """
    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    if fmt not in ("png", "tif"):
        raise InputError("--format", None, f"expected png or tif, got {fmt!r}")
    lens = load_lens(lens_file)
    sensor = load_sensor(sensor_file)
    banks: dict[tuple[int, int], PSFBank] = {}
    results = []
    for i, path in enumerate(images):
        img, in_bits = read_image(path)
        h, w = img.shape[1:]
        mapping = map_to_sensor(h, w, sensor)
        bank = None
        if blur or distortion:
            if bank_dir is not None:
                bank = banks.setdefault((h, w), PSFBank.load(bank_dir))
                check_bank_fits(bank, mapping, str(bank_dir))
            elif (h, w) not in banks:
                banks[(h, w)] = cached_bank(lens, mapping.pitch_um, sensor, settings, workers, quiet or json_out)
            bank = banks.get((h, w), bank)
        gen = torch.Generator().manual_seed(seed + i)
        raw_path = output / (path.stem + ".dng") if raw else None
        out, params = simulate(img, bank, sensor, gen, blur=blur, noise=noise, relative_illumination=shading,
                               demosaic=demosaic, bits=bits, raw_path=raw_path, distortion=distortion)
        target = output / f"{path.stem}.{fmt}"
        write_image(target, out, bits)
        info = {"input": str(path), "output": str(target), "seed": seed + i, "lens": lens.source, "sensor": sensor.name,
                "bank": None if bank is None else str(bank.directory), **params.to_dict()}
        atomic_write_text(output / (path.stem + ".json"), json.dumps(info, indent=2, default=str) + "\n")
        results.append(info)
        if not quiet and not json_out:
            console.print(f"wrote {target} (pitch {mapping.pitch_um:.3g} um, {params.kelvin:.0f} K)", highlight=False)
    if json_out:
        print_json(results)
