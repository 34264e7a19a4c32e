"""`lensim chart make` and `lensim chart compare`: the printable test chart and the paper's
chart check (lensim.calibrate: chart, chart_draw, chart_detect, chart_measure, compare)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from lensim import assets
from lensim.cli.bank_options import (
    bank_settings,
    cache_option,
    config_option,
    fields_option,
    fno_option,
    focus_m_option,
    pupil_samples_option,
    shooting_settings,
    wavelengths_option,
)
from lensim.cli.common import console, print_json
from lensim.cli.validate import at_least, in_range, input_file, output_file, output_folder, positive
from lensim.errors import InputError

if TYPE_CHECKING:
    import numpy as np

    from lensim.calibrate.chart import ChartLayout
    from lensim.optics.lens import Lens
    from lensim.sensor.profile import SensorProfile

chart_app = typer.Typer(
    help="Printable test charts, and the paper's chart check: a photographed chart against lensim's simulation.",
    no_args_is_help=True,
)

#: library field -> option, for errors raised by lensim.calibrate
_OPTIONS = {"print_width_mm": "--print-width-mm", "frame": "--sensor", "dpi": "--dpi"}


def _named(e: InputError) -> InputError:
    """A library error whose field is one of this command's parameters, named by its option."""
    if e.source is None and e.field in _OPTIONS:
        return InputError(_OPTIONS[e.field], None, e.message)
    return e


def _magnification(lens: Lens, distance_m: float) -> float:
    """|paraxial magnification| of the lens focused at distance_m (from the image plane)."""
    from lensim.optics.paraxial import paraxial_data

    m = abs(paraxial_data(lens).magnification)
    if not (math.isfinite(m) and m > 0):
        raise InputError("--distance-m", None, f"the lens forms no real image of an object {distance_m} m away")
    return m


@chart_app.command("make")
def make_command(
    output: Path = typer.Option(..., "-o", "--output", help="The printable chart: a .pdf or .png file."),
    lens_file: str = typer.Option(assets.DEFAULT_LENS, "--lens", help="Lens file or built-in lens name."),
    sensor_file: str = typer.Option(None, "--sensor", help="Sensor profile file or built-in name (default: built-in)."),
    distance_m: float = typer.Option(
        ..., "--distance-m", help="Shooting distance in m, chart to image plane (the lens is focused there)."
    ),
    print_width_mm: float = typer.Option(..., "--print-width-mm", help="Width of the printed chart in mm."),
    dpi: float = typer.Option(300.0, "--dpi", help="Print resolution in dots per inch."),
    config: str = config_option(),
    quiet: bool = typer.Option(False, "--quiet", help="Print nothing."),
    json_out: bool = typer.Option(False, "--json", help="Print what was written as JSON."),
) -> None:
    """Write a printable chart that fills the frame of this lens and sensor at this distance:
    slanted-edge squares (5 deg) from the centre to both right-hand corners, checkerboard
    patches towards the left-hand corners, and eight ArUco markers for registration. Also
    writes its layout (every position in mm) as OUT.json, which `chart compare` reads.
    Print at 100 % ("actual size").

    Example: lensim chart make --lens cooke_triplet --distance-m 2 --print-width-mm 900 -o chart.pdf
    """
    from lensim.calibrate.chart import chart_to_dict, design_chart
    from lensim.calibrate.chart_draw import write_page
    from lensim.cli.bank_options import lens_and_record
    from lensim.io import atomic_write_json
    from lensim.sensor.profile import load_sensor

    output_file(output, "--output", (".pdf", ".png"))
    positive(distance_m, "--distance-m", "m", "a distance")
    positive(print_width_mm, "--print-width-mm", "mm", "a width")
    in_range(dpi, 50.0, 2400.0, "--dpi", "", "a print resolution")
    sensor = load_sensor(sensor_file)
    lens, described = lens_and_record(lens_file, shooting_settings(None, str(distance_m), str(distance_m), config))
    mag = _magnification(lens, distance_m)
    frame = (sensor.sensor_size_mm[0] / mag, sensor.sensor_size_mm[1] / mag)
    design = {"lens": lens.source, "sensor": sensor.name, "distance_m": distance_m, "magnification": mag,
              "print_width_mm": print_width_mm, "dpi": dpi, "settings": described}  # fmt: skip
    try:
        layout = design_chart(frame, print_width_mm, design)
    except InputError as e:
        raise _named(e) from None
    sidecar = output.with_suffix(".json")
    write_page(layout, output, dpi)
    atomic_write_json(sidecar, chart_to_dict(layout))
    info = {"chart": str(output), "layout": str(sidecar), "width_mm": layout.width_mm, "height_mm": layout.height_mm,
            "frame_mm": list(frame)}  # fmt: skip
    if json_out:
        print_json(info)
    elif not quiet:
        console.print(
            f"wrote {output} ({layout.width_mm:.0f} x {layout.height_mm:.0f} mm; the frame at {distance_m:g} m spans "
            f"{frame[0]:.0f} x {frame[1]:.0f} mm) and {sidecar}",
            highlight=False,
        )


def _read_photo(path: Path, sensor: SensorProfile, wb: str) -> tuple[np.ndarray, float, str]:
    """(sRGB (3, H, W) float64, colour temperature to simulate at (K), 'raw' | 'image'):
    a PNG/TIFF/JPEG as stored, a raw file developed with lensim's own chain (as-shot
    white balance, or --wb) in the sensor's orientation (the EXIF turn is not applied: the
    photo maps onto the sensor as it was read out)."""
    from lensim.images import READ_SUFFIXES, read_image

    input_file(path, None, "photo")
    if path.suffix.lower() in READ_SUFFIXES:
        img, _ = read_image(path)
        return img.double().numpy(), 5000.0, "image"
    from lensim.raw import read_raw
    from lensim.raw.develop import develop_raw, parse_wb

    raw = read_raw(path)
    img, params = develop_raw(raw, sensor, parse_wb(wb), orient=False)  # the sensor's own orientation
    kelvin = params.kelvin if math.isfinite(params.kelvin) else 5000.0
    return img.double().numpy(), kelvin, "raw"


@chart_app.command("compare")
def compare_command(
    ctx: typer.Context,
    photo: Path = typer.Argument(..., help="Photo of the chart: a raw file (DNG, CR2, NEF, ARW, ...) or PNG/TIFF."),
    chart: Path = typer.Option(..., "--chart", help="The chart's layout (the .json `chart make` wrote)."),
    lens_file: str = typer.Option(assets.DEFAULT_LENS, "--lens", help="Lens file or built-in lens name."),
    sensor_file: str = typer.Option(None, "--sensor", help="Sensor profile file or built-in name (default: built-in)."),
    output: Path = typer.Option(None, "-o", "--output", help="Output folder (default: the photo's folder)."),
    wb: str = typer.Option("as-shot", "--wb", help="Raw photos: white balance to develop with (as in `develop`)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulation's noise draws."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Simulate noise (matched to the photo's level)."),
    fno: str = fno_option(),
    focus_m: str = focus_m_option(),
    object_m: str = typer.Option(
        None, "--object-m", help="Chart distance in m from the image plane (default: estimated from the photo)."
    ),
    config: str = config_option(),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    workers: int = typer.Option(1, "--workers", help="Processes for the bank."),
    cache: Path = cache_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print the comparison as JSON."),
) -> None:
    """Compare a photographed chart with lensim's simulation of it (the paper's Table 1):
    find the chart's markers, estimate its pose (distance, tilt), simulate the chart at that
    pose through the full pipeline (PSF bank, mosaic, noise, the develop chain), and report
    per field zone the MTF area (SFR integral to Nyquist) of photo and simulation, their
    ratio simulation/photo, MTF50, lateral colour and checkerboard-crop PSNR. Writes
    OUT/<photo>_chart.json, OUT/<photo>_chart.png (SFR curves per zone) and
    OUT/<photo>_sim.png (the simulation).

    Example: lensim chart compare IMG_0001.dng --lens my_lens.yaml --sensor my_camera.yaml --chart chart.json -o check/
    """
    from lensim.sensor.profile import load_sensor

    t0 = time.perf_counter()
    out_dir = output_folder(output if output is not None else photo.parent)
    at_least(workers, 1, "--workers", what="a number of processes")
    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    given = shooting_settings(fno, object_m, focus_m, config)
    from lensim.calibrate.chart import load_chart

    layout = load_chart(input_file(chart, "--chart", "chart layout"))
    sensor = load_sensor(sensor_file)
    img, kelvin, kind = _read_photo(photo, sensor, wb)
    source = ctx.get_parameter_source("pupil_samples")
    pupil_given = source is not None and source.name != "DEFAULT"
    record = _compare(photo, img, kind, kelvin, layout, lens_file, sensor, given, settings, pupil_given,
                      seed, noise, workers, quiet or json_out, out_dir)  # fmt: skip
    record["run_time_s"] = time.perf_counter() - t0
    _write_json(out_dir / f"{photo.stem}_chart.json", record)
    if json_out:
        print_json(record)
    elif not quiet:
        _print_table(record)


def _compare(
    photo: Path,
    img: np.ndarray,
    kind: str,
    kelvin: float,
    layout: ChartLayout,
    lens_file: str,
    sensor: SensorProfile,
    given: Any,
    settings: Any,
    pupil_given: bool,
    seed: int,
    noise: bool,
    workers: int,
    quiet: bool,
    out_dir: Path,
) -> dict[str, Any]:
    """Detection, pose, bank, simulation and comparison; writes the figure and the
    simulated image; returns the JSON record (written last by the caller)."""
    from dataclasses import replace

    import torch

    from lensim.calibrate.chart_detect import check_coverage, detect_chart, estimate_pose
    from lensim.calibrate.compare import PixelDistortion, compare_chart, report, undistorted
    from lensim.cli.bank_options import lens_and_record
    from lensim.cli.simulate_cmd import _photo_bank
    from lensim.images import write_image
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import lens_at
    from lensim.plots.chart import chart_comparison_figure
    from lensim.plots.figure import save_figure
    from lensim.render.mapping import map_to_sensor

    src = str(photo)
    detection = detect_chart(img, layout, src)
    check_coverage(layout, detection, src)
    rows, cols = detection.shape
    mapping = map_to_sensor(rows, cols, sensor)
    lens0 = lens_at(load_lens(lens_file), replace(given, object_m=None, focus_m=None))
    pose = estimate_pose(detection, lens0, mapping.pitch_um, guess_m=given.object_m or 2.0)
    object_m = given.object_m if given.object_m is not None else pose.distance_m
    shooting = replace(given, object_m=object_m, focus_m=given.focus_m if given.focus_m is not None else object_m)
    lens, described = lens_and_record(lens_file, shooting)
    bank = _photo_bank(photo, (cols, rows), mapping.pitch_um, lens, sensor, settings, pupil_given, workers, quiet)
    # the pose again from the corners without the lens's distortion (the bank stays: its
    # distance changes by about the distortion's percentage, its focus far less)
    pose = estimate_pose(undistorted(detection, PixelDistortion.from_bank(bank, mapping)), lens0, mapping.pitch_um,
                         guess_m=pose.distance_m)  # fmt: skip
    cmp = compare_chart(img, layout, detection, bank, sensor, mapping, seed=seed, noise=noise, kelvin=kelvin)
    fig = chart_comparison_figure(cmp, f"{photo.name}: photo vs lensim ({lens.source})")
    save_figure(fig, out_dir / f"{photo.stem}_chart.png")
    write_image(out_dir / f"{photo.stem}_sim.png", torch.from_numpy(cmp.simulated).float(), 8)
    head = {"photo": src, "path": kind, "lens": lens.source, "sensor": sensor.name, "settings": described,
            "pitch_um": mapping.pitch_um, "kelvin": kelvin, "bank": str(bank.directory)}  # fmt: skip
    return head | report(cmp, detection, pose)


def _write_json(path: Path, record: dict) -> None:
    from lensim.io import atomic_write_json
    from lensim.jsonable import jsonable

    atomic_write_json(path, jsonable(record))


def _print_table(record: dict) -> None:
    from rich.table import Table

    pose, det = record["pose"], record["detection"]
    console.print(
        f"chart at {pose['distance_m']:.3f} m, tilted {pose['tilt_deg']:.1f} deg; markers "
        f"{len(det['marker_ids'])}, reprojection {det['reprojection_rms_px']:.2f} px RMS",
        highlight=False,
    )
    t = Table(
        title="per field zone: MTF area (SFR integral to Nyquist, cycles/pixel) of the photo and of lensim, their "
        "ratio lensim/photo, MTF50 photo/lensim (cycles/pixel), lateral colour R-G/B-G (px), checker PSNR (dB)"
    )
    for col in ("field", "n", "photo", "lensim", "ratio", "MTF50", "R-G/B-G", "PSNR"):
        t.add_column(col, no_wrap=True)
    for z in record["zones"]:
        lc = z["photo_lateral_colour_px"]
        t.add_row(
            f"{z['mean_field']:.2f}", str(z["edges"]), f"{z['photo_mtf_area']:.4f}", f"{z['sim_mtf_area']:.4f}",
            f"{z['mtf_area_ratio']:.3f}", f"{z['photo_mtf50_cy_px']:.3f}/{z['sim_mtf50_cy_px']:.3f}",
            f"{lc[0]:+.2f}/{lc[1]:+.2f}",
            "-" if z["psnr_db"] is None or not math.isfinite(z["psnr_db"]) else f"{z['psnr_db']:.1f}",
        )  # fmt: skip
    console.print(t)
