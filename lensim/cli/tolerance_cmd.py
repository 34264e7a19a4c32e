"""`lensim lens tolerance` and `lensim lens perturb`: Monte Carlo tolerancing and
perturbed (as-built) lens files, registered on the `lens` group of lensim.cli.lens_cmd.
The library computes (lensim.calibrate.tolerances, lensim.calibrate.tolerance_report) and
draws (lensim.plots.tolerance)."""

from __future__ import annotations

from pathlib import Path

import typer

from lensim.cli.common import console, progress_bar
from lensim.cli.lens_analysis_cmd import (
    CHANNEL_HELP,
    FIELD_DEG_OPTION,
    FIELD_OPTION,
    IMAGE_HEIGHT_OPTION,
    OUTPUT_HELP,
    PUPIL_HELP,
    SENSOR_HELP,
    _fields,
    _finish,
    _outputs,
    _spectrum,
)
from lensim.cli.lens_cmd import LENS_ARG, AimingChoice, _load, lens_app
from lensim.cli.validate import at_least, input_file, output_file, positive
from lensim.errors import InputError

TOLERANCES_HELP = (
    "Tolerance file (YAML): +- ranges per element or group (decentre_mm, tilt_deg, thickness_mm, "
    "spacing_mm) and for the image (focus_mm, tilt_deg); docs/calibration.md."
)


@lens_app.command("tolerance")
def tolerance_command(
    lens_file: str = LENS_ARG,
    tolerances: Path = typer.Option(..., "--tolerances", help=TOLERANCES_HELP),
    draws: int = typer.Option(20, "--draws", help="Monte Carlo draws."),
    seed: int = typer.Option(0, "--seed", help="Seed of the draws (draw k of a seed is always the same lens)."),
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    field: list[float] | None = FIELD_OPTION,
    field_deg: list[float] | None = FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = IMAGE_HEIGHT_OPTION,
    frequency: float | None = typer.Option(
        None, "--frequency", help="MTF frequency (lp/mm). Default: Nyquist/2 of --sensor, else 30."
    ),
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP),
    channel: str | None = typer.Option(None, "--channel", help=CHANNEL_HELP),
    sensitivity: bool = typer.Option(
        True, "--sensitivity/--no-sensitivity", help="Also change each parameter alone (+- its range)."
    ),
    pupil_samples: int = typer.Option(64, "--pupil-samples", help=PUPIL_HELP),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
) -> None:
    """Spread of RMS spot and MTF over seeded tolerance draws (fields along +y), and which
    element's decentre, tilt or spacing lowers the corner MTF most.

    Example: lensim lens tolerance cooke_triplet --tolerances tol.yaml --draws 50 --seed 1 -o tol.png --json
    """
    from lensim.calibrate.tolerance_report import Probe, tolerance_report
    from lensim.calibrate.tolerances import load_tolerances
    from lensim.plots.tolerance import tolerance_figure

    _outputs(output, json_out)
    at_least(draws, 0, "--draws", what="a number of draws")
    at_least(pupil_samples, 16, "--pupil-samples", what="a number of pupil samples")
    if frequency is not None:
        positive(frequency, "--frequency", "lp/mm", "a frequency")
    input_file(tolerances, "--tolerances", "tolerance file")
    base, _ = _load(lens_file)
    tol = load_tolerances(tolerances, base)
    if draws == 0 and not sensitivity:
        raise InputError(None, "--draws", "expected at least 1 draw, or --sensitivity")
    lens, fields = _fields(base, field, field_deg, image_height_mm)
    wls, weights, nyquist = _spectrum(lens, sensor, channel, None)
    freq = frequency or (nyquist / 2.0 if nyquist else 30.0)
    probe = Probe(fields, wls, weights, freq, pupil_samples, aiming.value)
    with progress_bar("tolerance", "lenses", quiet or json_out) as cb:
        report = tolerance_report(lens, tol, probe, draws, seed, cb, sensitivity)
    _finish(report, output, json_out, lambda: tolerance_figure(report, output))


def _parse_set(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, eq, value = item.partition("=")
        try:
            out[name.strip()] = float(value) if eq else float("nan")
        except ValueError:
            out[name.strip()] = float("nan")
        if out[name.strip()] != out[name.strip()]:
            raise InputError(None, "--set", f"expected NAME=VALUE like e2.decentre_x=0.01, got {item!r}")
    return out


@lens_app.command("perturb")
def perturb_command(
    lens_file: str = LENS_ARG,
    output: Path = typer.Option(..., "-o", "--output", help="Native lens file to write (.json or .yaml)."),
    tolerances: Path | None = typer.Option(None, "--tolerances", help=TOLERANCES_HELP),
    seed: int = typer.Option(0, "--seed", help="Seed of the draw."),
    draw: int = typer.Option(0, "--draw", help="Which draw of the seed (0-based)."),
    set_: list[str] | None = typer.Option(
        None, "--set", help="A parameter NAME=VALUE (mm or deg), e.g. e2.decentre_x=0.01, image.focus=0.02; repeat."
    ),
) -> None:
    """Write a perturbed (as-built) lens: draw --draw of --seed within --tolerances, and/or
    parameters given with --set. Every command accepts the file.

    Example: lensim lens perturb cooke_triplet --tolerances tol.yaml --seed 3 --draw 7 -o unit7.yaml
    """
    from lensim.calibrate.tolerances import draw as draw_values
    from lensim.calibrate.tolerances import load_tolerances, perturbed_lens
    from lensim.optics.lens_file import save_lens

    if output.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise InputError(str(output), "--output", "expected a .json, .yaml or .yml file name for a native lens file")
    output_file(output)
    at_least(draw, 0, "--draw", what="a draw index")
    given = _parse_set(set_ or [])
    if tolerances is None and not given:
        raise InputError(None, "--tolerances", "expected a tolerance file, --set NAME=VALUE, or both")
    base, _ = _load(lens_file)
    values: dict[str, float] = {}
    record: dict = {"kind": "perturbation"}
    if tolerances is not None:
        input_file(tolerances, "--tolerances", "tolerance file")
        values = draw_values(load_tolerances(tolerances, base), seed, draw).values
        record = {"kind": "tolerance draw", "tolerances": str(tolerances), "seed": seed, "draw": draw}
    values.update(given)
    save_lens(perturbed_lens(base, values, record), output)
    console.print(f"wrote {output}", highlight=False)
