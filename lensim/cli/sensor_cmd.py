"""`lensim sensor ...`: sensor profiles for real cameras."""

from __future__ import annotations

from pathlib import Path

import typer

from lensim.cli.common import console, print_json
from lensim.cli.validate import output_file, pixel_pitch_um

sensor_app = typer.Typer(help="Sensor profiles for real cameras.", no_args_is_help=True)


@sensor_app.command("from-raw")
def from_raw(
    file: Path = typer.Argument(..., help="A raw file from the camera (DNG, CR2/CR3, NEF, ARW, ...)."),
    output: Path = typer.Option(..., "-o", "--output", help="Profile to write (.yaml, .yml or .json)."),
    pixel_um: float = typer.Option(
        None,
        "--pixel-um",
        help="Pixel pitch in micrometres (required when the file's "
        "EXIF has no FocalPlaneXResolution; overrides it otherwise).",
    ),
    dark: Path = typer.Option(None, "--dark", help="A dark frame (lens cap on, same ISO): read noise."),
    flat: list[Path] = typer.Option(
        None,
        "--flat",
        help="Flat fields (evenly lit, unsaturated; repeat for several exposures): shot noise by photon transfer.",
    ),
    name: str = typer.Option(None, "--name", help="Profile name (default: the camera's make and model)."),
    json_out: bool = typer.Option(False, "--json", help="Print the profile as JSON."),
) -> None:
    """Write a sensor profile for the camera that took FILE: geometry (active area x
    pixel pitch), CFA pattern, black and white levels, CCM and white-balance table from
    the file's colour matrix, and noise (from --dark/--flat frames, else lensim's
    defaults). It works wherever --sensor is accepted.

    Example: lensim sensor from-raw IMG_0001.dng --pixel-um 3.92 -o mycam.yaml
    """
    from lensim.errors import InputError
    from lensim.io import atomic_write_text
    from lensim.raw import read_raw
    from lensim.raw.noise import noise_from_frames
    from lensim.raw.profile import profile_dict_from_raw
    from lensim.sensor.profile import sensor_from_dict

    suffix = output.suffix.lower()
    if suffix not in (".yaml", ".yml", ".json"):
        raise InputError(str(output), None, "expected a .yaml, .yml or .json file name for the profile")
    output_file(output)
    if pixel_um is not None:
        pixel_pitch_um(pixel_um)
    raw = read_raw(file)
    noise = noise_from_frames(raw, read_raw(dark) if dark else None, [read_raw(f) for f in flat or []])
    data = profile_dict_from_raw(raw, pixel_um, noise, name)
    sensor_from_dict(data, source=str(output))  # the profile validates before it is written
    if suffix == ".json":
        import json

        text = json.dumps(data, indent=1) + "\n"
    else:
        import yaml

        text = yaml.safe_dump(data, sort_keys=False, width=100)
    atomic_write_text(output, text)
    if json_out:
        print_json(data)
    else:
        console.print(
            f"wrote {output}: {data['name']}, {data['resolution'][0]} x {data['resolution'][1]} px at "
            f"{data['pixel_pitch_um']:.4g} um, {data['bayer_pattern']}",
            highlight=False,
        )
