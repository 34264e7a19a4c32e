"""`lensim develop`: camera raw files -> sRGB photos with the simulator's own chain."""

from __future__ import annotations

from pathlib import Path

import typer

from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import choice as choose
from lensim.cli.validate import output_folder
from lensim.io import folder_lock


def develop_command(
    files: list[Path] = typer.Argument(..., help="Raw files (DNG, CR2/CR3, NEF, ARW, ...) or folders of them."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder: OUT/<name>.tif (or .png)."),
    sensor_file: str = typer.Option(
        None,
        "--sensor",
        help="Sensor profile (file or built-in name) for the CCM and "
        "white-balance table (default: derived from each raw's colour matrix).",
    ),
    wb: str = typer.Option(
        "as-shot",
        "--wb",
        help="as-shot, a preset (tungsten, fluorescent, daylight, flash, "
        "cloudy, shade, d65) or a colour temperature such as 5000K.",
    ),
    bits: int = typer.Option(16, "--bits", help="Output bit depth: 8 or 16."),
    fmt: str = typer.Option("tif", "--format", help="Output file type: tif or png."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print what was written (and the settings used) as JSON."),
) -> None:
    """Develop raw files with the simulation's own chain and no sharpening or denoising:
    per-CFA black/white level normalization, white balance, AHD demosaic, CCM, sRGB
    curve, orientation. Writes sRGB-tagged OUT/<name>.tif (16-bit by default); a rerun
    skips outputs that exist. Every input is checked before the first output is written.

    Example: lensim develop shots/ -o developed/ --wb as-shot
    """
    from lensim.raw import develop_files, raw_files
    from lensim.raw.develop import parse_wb, plan_outputs
    from lensim.sensor.profile import load_sensor

    choose(bits, (8, 16), "--bits")
    choose(fmt, ("tif", "png"), "--format")
    output_folder(output)
    sensor = load_sensor(sensor_file) if sensor_file is not None else None
    choice = parse_wb(wb)
    paths = raw_files(list(files))
    plan_outputs(paths, output, fmt)
    with progress_bar("develop", "files", quiet or json_out) as callback, folder_lock(output):  # one writer at a time
        records = develop_files(paths, output, sensor, choice, bits, fmt, progress=callback)
    if json_out:
        print_json(records)
    elif not quiet:
        done = sum(not r["skipped"] for r in records)
        console.print(f"developed {done} file(s) into {output}, {len(records) - done} already there", highlight=False)
