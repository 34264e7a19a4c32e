"""`lensim demo`: the whole pipeline on the built-in camera, with an HTML report."""

from __future__ import annotations

from pathlib import Path

import typer

from lensim.cli.bank_options import config_option, fno_option, focus_m_option, object_m_option, shooting_settings
from lensim.cli.common import StageBars, console, print_json
from lensim.cli.validate import at_least, input_folder, output_folder
from lensim.cli.validate import device as check_device


def demo_command(
    output: Path = typer.Option(
        Path("lensim-demo"), "-o", "--output", help="Output folder (reused: stages are cached)."
    ),
    quick: bool = typer.Option(
        False, "--quick", help="A ~3-minute run (CI); the default takes about 9-11 minutes on 2 quiet cores."
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of every random draw."),
    workers: int = typer.Option(
        0,
        "--workers",
        help="Processes for the PSF bank and the pairs; two or more also train the two networks side by side "
        "(0: one per available core).",
    ),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:N: where the networks train and run."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print report.json's metrics."),
    fno: str = fno_option(),
    object_m: str = object_m_option(),
    focus_m: str = focus_m_option(),
    config: str = config_option(),
) -> None:
    """Lens -> PSF bank -> simulated pairs -> training -> restoration -> evaluation -> report.

    Writes OUT/report.html (self-contained), OUT/report.json and the figures in
    OUT/figures/. A second run reuses every finished stage. --fno, --object-m, --focus-m and
    --config set the built-in lens (report.json records them as "shooting").

    Example: lensim demo --quick -o demo/
    """
    from lensim.demo import run_demo

    at_least(workers, 0, "--workers", what="a number of processes (0: one per core)")
    check_device(device)
    shooting = shooting_settings(fno, object_m, focus_m, config)
    if not shooting.is_default:  # refused before the folder is made
        from lensim.assets import DEFAULT_LENS
        from lensim.optics.lens_file import load_lens
        from lensim.optics.shooting import lens_at

        lens_at(load_lens(DEFAULT_LENS), shooting)
    output_folder(output)
    with StageBars(show=not quiet and not json_out) as bars:
        report = run_demo(
            output,
            quick=quick,
            seed=seed,
            workers=workers or None,
            say=bars.say,
            device=device,
            progress=bars.progress,
            shooting=shooting,
        )
    if json_out:
        print_json({"metrics": report["metrics"], "report": str(output / "report.html")})
    elif not quiet:
        console.print(f"wrote {output / 'report.html'} and {output / 'report.json'}", highlight=False)


def report_command(
    demo_dir: Path = typer.Argument(..., help="A folder written by `lensim demo` (report.json + figures/)."),
) -> None:
    """Rebuild DIR/report.html from DIR/report.json and DIR/figures/ (after editing or
    re-running a stage).

    Example: lensim report lensim-demo/
    """
    from lensim.errors import InputError
    from lensim.io import folder_lock, read_json
    from lensim.report import write_report

    input_folder(demo_dir, what="folder written by `lensim demo`")
    path = demo_dir / "report.json"
    if not path.exists():
        raise InputError(str(path), None, "missing; expected a folder written by `lensim demo`")
    report = read_json(path, "demo report")
    if not isinstance(report, dict):
        raise InputError(str(path), None, f"expected a JSON object (a demo report), got a {type(report).__name__}")
    with folder_lock(demo_dir):  # not while a demo writes there
        try:
            written = write_report(demo_dir, report, demo_dir / "figures")
        except KeyError as e:
            raise InputError(str(path), str(e.args[0]), "missing; expected a report written by `lensim demo`") from None
        except (TypeError, ValueError, AttributeError) as e:
            raise InputError(str(path), None, f"not a report written by `lensim demo` ({e})") from None
    console.print(f"wrote {written}", highlight=False)
