"""`lensim dataset make`: aligned training pairs from a folder of sharp photos."""
from __future__ import annotations

from pathlib import Path

import typer

from lensim import assets
from lensim.cli.bank_options import (bank_settings, cache_option, cached_bank, fields_option, pupil_samples_option,
                                     wavelengths_option)
from lensim.cli.common import console, print_json, progress_bar
from lensim.data.pairs import make_dataset
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import PSFBank
from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

dataset_app = typer.Typer(help="Training data: aligned (aberrated, sharp) pairs.", no_args_is_help=True)


@dataset_app.command("make")
def make(
    sharp_dir: Path = typer.Argument(..., help="Folder of sharp photos (PNG, TIFF, JPEG)."),
    output: Path = typer.Option(..., "-o", "--output", help="Dataset folder (resumes if it exists with the same settings)."),
    lens_file: str = typer.Option(assets.DEFAULT_LENS, "--lens", help="Lens file or built-in lens name."),
    sensor_file: str = typer.Option(DEFAULT_SENSOR, "--sensor", help="Sensor profile file or built-in name."),
    crops: int = typer.Option(8, "--crops", help="Crops per photo and placement."),
    placements: int = typer.Option(1, "--placements", help="Sensor positions per photo, stratified by field radius "
                                   "(3: centre, middle and edge zones)."),
    size: int = typer.Option(256, "--size", help="Crop size in pixels (even)."),
    seed: int = typer.Option(0, "--seed", help="Seed of every random draw (placement, colour temperature, noise, crops)."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add shot and read noise."),
    demosaic: str = typer.Option("ahd", "--demosaic", help="ahd, malvar, menon or bilinear."),
    bank_dir: Path = typer.Option(None, "--bank", help="A PSF bank at the sensor's pitch (default: computed and cached)."),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    workers: int = typer.Option(1, "--workers", help="Worker processes (a local Dask cluster when > 1)."),
    scheduler: str = typer.Option(None, "--scheduler", help="Address of an existing Dask scheduler to run on."),
    cache: Path = cache_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON."),
) -> None:
    """Place each photo on the sensor at native scale (--placements seeded random positions,
    stratified by field radius), simulate the camera at each, and cut aligned crops: DATASET/pairs/*_input.png (camera) and *_target.png
    (sharp), with every crop's sensor position and every random draw in
    DATASET/manifest.json.

    Example: lensim dataset make photos/ --lens cooke_triplet --sensor apsc_mirrorless -o data/ --crops 8 --size 256 --placements 3
    """
    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    lens = load_lens(lens_file)
    sensor = load_sensor(sensor_file)
    quiet = quiet or json_out
    if bank_dir is not None:
        bank = PSFBank.load(bank_dir)
    else:
        bank = cached_bank(lens, sensor.pixel_pitch_um, sensor, settings, workers, quiet)
    prog, cb = progress_bar("pairs", "photos", quiet)
    if prog:
        prog.start()
    try:
        manifest = make_dataset(sharp_dir, output, bank, sensor_file, sensor, crops=crops, size=size, seed=seed,
                                placements=placements, noise=noise, demosaic=demosaic, workers=workers, scheduler=scheduler, progress=cb)
    finally:
        if prog:
            prog.stop()
    summary = {"output": str(output), "photos": len(manifest["records"]), "pairs": manifest["pairs"],
               "bank": str(bank.directory), "seed": seed}
    if json_out:
        print_json(summary)
    elif not quiet:
        console.print(f"wrote {summary['pairs']} pairs from {summary['photos']} photos to {output}", highlight=False)
