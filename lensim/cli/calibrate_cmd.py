"""`lensim calibrate PHOTO... --lens L --sensor S --chart chart.json -o as_built.yaml`:
fit the lens as built to photographed charts (lensim.calibrate.calibrate, .fit)."""

from __future__ import annotations

import time
from dataclasses import replace
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
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, in_range, input_file, output_file
from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.calibrate.calibrate import ChartData
    from lensim.calibrate.refresh import Simulator
    from lensim.optics.lens import Lens
    from lensim.sensor.profile import SensorProfile


def _photo_data(
    photo: Path, layout: Any, lens_file: str, sensor: SensorProfile, given: Any, settings: Any, options: dict
) -> tuple[ChartData, Lens, dict | None, Simulator]:
    """One photo's chart observations, the nominal lens at its settings and distance,
    those settings as records keep them, and the photo's chart simulated through a lens
    (the transfer refreshes)."""
    from lensim.calibrate.calibrate import chart_data, luminance_spectrum
    from lensim.calibrate.chart_detect import detect_chart, estimate_pose
    from lensim.calibrate.refresh import chart_simulator
    from lensim.cli.bank_options import lens_and_record
    from lensim.cli.chart_cmd import _read_photo
    from lensim.cli.simulate_cmd import _photo_bank
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import lens_at
    from lensim.render.mapping import map_to_sensor

    img, _, _ = _read_photo(photo, sensor, options["wb"])
    detection = detect_chart(img, layout, str(photo))
    rows, cols = detection.shape
    mapping = map_to_sensor(rows, cols, sensor)
    lens0 = lens_at(load_lens(lens_file), replace(given, object_m=None, focus_m=None))
    pose = estimate_pose(detection, lens0, mapping.pitch_um, guess_m=given.object_m or 2.0)
    object_m = given.object_m if given.object_m is not None else pose.distance_m
    shooting = replace(given, object_m=object_m, focus_m=given.focus_m if given.focus_m is not None else object_m)
    lens, described = lens_and_record(lens_file, shooting)

    def bank_of(at: Lens) -> Any:
        return _photo_bank(photo, (cols, rows), mapping.pitch_um, at, sensor, settings, False, 1, options["quiet"])

    spectrum = luminance_spectrum(sensor, settings.wavelengths_nm)
    data = chart_data(img, layout, lens, bank_of(lens), sensor, mapping, spectrum, str(photo), options["samples"])
    return data, lens, described, chart_simulator(img, layout, detection, data, sensor, mapping, bank_of)


def calibrate_command(
    photos: list[Path] = typer.Argument(..., help="Photos of the chart (raw files or PNG/TIFF), one lens and setting."),
    chart: Path = typer.Option(..., "--chart", help="The chart's layout (the .json `chart make` wrote)."),
    output: Path = typer.Option(..., "-o", "--output", help="As-built lens file to write (.yaml or .json)."),
    lens_file: str = typer.Option(assets.DEFAULT_LENS, "--lens", help="Lens file or built-in lens name."),
    sensor_file: str = typer.Option(None, "--sensor", help="Sensor profile file or built-in name (default: built-in)."),
    elements: int = typer.Option(
        1,
        "--elements",
        help="Element moves fitted, each an element's decentre or tilt (x, y): the first ranked by image "
        "prefits, each further one by the linear model at the current fit (a unit whose every element is "
        "off needs several).",
    ),
    candidates: int = typer.Option(
        1,
        "--candidates",
        help="Elements tried for the first decentre, each fitted in full (the best-ranked by their image prefits); "
        "the smallest residual is kept, in every refresh round too.",
    ),
    wb: str = typer.Option("as-shot", "--wb", help="Raw photos: white balance to develop with."),
    fno: str = fno_option(),
    focus_m: str = focus_m_option(),
    object_m: str = typer.Option(
        None, "--object-m", help="Chart distance in m from the image plane (default: estimated from the photo)."
    ),
    config: str = config_option(),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    model_samples: int = typer.Option(32, "--model-samples", help="Pupil samples across for the fit's MTF model."),
    refresh_rounds: int = typer.Option(
        4,
        "--refresh-rounds",
        help="Most rounds of: simulate the chart through the fitted lens, take the system transfer there, refit "
        "(0: the transfer of the nominal lens only).",
    ),
    cache: Path = cache_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print the fit as JSON."),
) -> None:
    """Fit the lens as built to photographed charts: the image-plane offset, the sensor's
    tilt and the decentre or tilt of the element(s) that explain the photos best (a
    sensitivity analysis ranks them), each within a physical bound and with a prior
    towards the nominal design, from each chart edge's SFR against lensim's simulation of the
    nominal lens at the photo's pose. Writes a lens file every command takes, its
    as_built record holding the fitted values, their 1-sigma uncertainties and the
    residuals.

    The system transfer (pixel, mosaic, develop) is then taken again from the
    chart simulated through the fitted lens and the fit repeated, until no parameter
    moves by its 1-sigma uncertainty (the rounds are recorded). A parameter the chart's
    edges cannot constrain is held at nominal (recorded in the lens file).

    Example: lensim calibrate IMG_1.dng IMG_2.dng --lens my.yaml --sensor cam.yaml --chart chart.json -o as_built.yaml
    """
    from lensim.calibrate.calibrate import calibrate_charts, luminance_spectrum, observations
    from lensim.calibrate.chart import load_chart
    from lensim.calibrate.refresh import refine
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens
    from lensim.sensor.profile import load_sensor

    t0 = time.perf_counter()
    if output.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise InputError(str(output), "--output", "expected a .json, .yaml or .yml file name for a native lens file")
    output_file(output)
    in_range(elements, 0, 6, "--elements", what="a number of element moves")
    at_least(model_samples, 16, "--model-samples", what="a number of pupil samples")
    in_range(refresh_rounds, 0, 20, "--refresh-rounds", what="a number of rounds")
    in_range(candidates, 1, 20, "--candidates", what="a number of elements")
    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    given = shooting_settings(fno, object_m, focus_m, config)
    layout = load_chart(input_file(chart, "--chart", "chart layout"))
    sensor = load_sensor(sensor_file)
    base = load_lens(lens_file)
    options = {"wb": wb, "quiet": quiet or json_out, "samples": model_samples}
    found = [_photo_data(p, layout, lens_file, sensor, given, settings, options) for p in photos]
    spectrum = luminance_spectrum(sensor, settings.wavelengths_nm)
    where = str(photos[0]) if len(photos) == 1 else f"{len(photos)} photos"
    data = [d for d, _, _, _ in found]
    with progress_bar("calibrate", "parameters", quiet or json_out) as cb:
        result = calibrate_charts(found[0][1], data, spectrum, None, elements, model_samples, where, cb, candidates)
    obs = observations(data, spectrum, model_samples)
    sims = [s for _, _, _, s in found]
    refined = refine(found[0][1], obs, sims, result, refresh_rounds, where, candidates=candidates)
    record = {**refined.lens.as_built, "photos": [str(p) for p in photos], "settings": found[0][2]}
    record["sensitivity"] = result.sensitivity
    save_lens(perturbed_lens(base, refined.values, record), output)
    report = {
        "output": str(output),
        "values": refined.values,
        "sigma": refined.sigma,
        **{k: refined.lens.as_built.get(k) for k in ("bounds", "priors", "at_bound", "held_at_nominal")},
        "rms_residual_before": result.rms_before,
        "rms_residual_after": refined.rms_after,
        "sensitivity": result.sensitivity,
        "degenerate": result.degenerate,
        "refresh": {"rounds": refined.rounds, "converged": refined.converged, "first_fit": result.values},
        "zones_before": [z.to_dict() for z in found[0][0].comparison.zones],
        "run_time_s": time.perf_counter() - t0,
        "evaluations": result.evaluations + sum(r["evaluations"] for r in refined.rounds),
    }
    if json_out:
        print_json(report)
    elif not quiet:
        at_bound = set(refined.lens.as_built.get("at_bound", []))
        for n, v in refined.values.items():
            note = " (at its bound)" if n in at_bound else ""
            console.print(f"{n:>20s} = {v:+.5f} +- {refined.sigma[n]:.5f}{note}", highlight=False)
        for h in refined.lens.as_built.get("held_at_nominal", []):
            console.print(f"held at nominal: {h['parameter']} ({h['reason']})", highlight=False)
        for p in result.degenerate:
            a, b = p["pair"]
            console.print(f"degenerate: {a} and {b} (correlation {p['correlation']:+.2f})", highlight=False)
        state = "converged" if refined.converged else "not converged"
        console.print(f"transfer refreshed {len(refined.rounds)} times ({state})", highlight=False)
        console.print(f"wrote {output} (RMS SFR residual {result.rms_before:.4f} -> {refined.rms_after:.4f})")
