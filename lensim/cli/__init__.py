"""The `lensim` command line. Each subcommand group lives in its own module."""

from __future__ import annotations

import typer

from lensim.cli import (
    lens_analysis_cmd,  # noqa: F401  (registers lens mtf, wavefront, fans, ...)
    tolerance_cmd,  # noqa: F401  (registers lens tolerance, perturb)
)
from lensim.cli.ablation_cmd import ablation_command
from lensim.cli.allocator import keep_freed_memory
from lensim.cli.assets_cmd import assets_command
from lensim.cli.calibrate_cmd import calibrate_command
from lensim.cli.chart_cmd import chart_app
from lensim.cli.common import help_in_sentences, name_options, run_guarded
from lensim.cli.dataset_cmd import dataset_app
from lensim.cli.demo_cmd import demo_command, report_command
from lensim.cli.develop_cmd import develop_command
from lensim.cli.evaluate_cmd import evaluate_command
from lensim.cli.export_cmd import export_command
from lensim.cli.lens_cmd import lens_app
from lensim.cli.library_cmd import library_app
from lensim.cli.psf_cmd import psf_app
from lensim.cli.raw_cmd import raw_app
from lensim.cli.restore_cmd import restore_command
from lensim.cli.sensor_cmd import sensor_app
from lensim.cli.simulate_cmd import simulate_command
from lensim.cli.train_cmd import train_command

app = typer.Typer(
    name="lensim",
    help="Optical aberration simulation and correction from a lens prescription.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(lens_app, name="lens")
app.add_typer(library_app, name="library")
app.add_typer(psf_app, name="psf")
app.add_typer(raw_app, name="raw")
app.add_typer(sensor_app, name="sensor")
app.add_typer(chart_app, name="chart")
app.command("calibrate")(calibrate_command)
app.command("assets")(assets_command)
app.command("simulate")(simulate_command)
app.add_typer(dataset_app, name="dataset")
app.command("evaluate")(evaluate_command)
app.command("train")(train_command)
app.command("restore")(restore_command)
app.command("export")(export_command)
app.command("develop")(develop_command)
app.command("demo")(demo_command)
app.command("ablation")(ablation_command)
app.command("report")(report_command)
name_options(app)  # library errors name parameters; the commands show them as their options
help_in_sentences(app)  # docstrings' source line breaks do not reach --help


def main() -> None:
    """Console entry point: one-line errors, non-zero exit status on bad input."""
    keep_freed_memory()
    run_guarded(app)


if __name__ == "__main__":
    main()
