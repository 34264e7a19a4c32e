"""`lensim demo`: the whole pipeline on the built-in camera, with an HTML report."""
from __future__ import annotations

import time
from pathlib import Path

import typer

from lensim.cli.common import console, print_json


def demo_command(
    output: Path = typer.Option(Path("lensim-demo"), "-o", "--output", help="Output folder (reused: stages are cached)."),
    quick: bool = typer.Option(False, "--quick", help="A ~3-minute run (CI); the default takes about 15 minutes."),
    seed: int = typer.Option(0, "--seed", help="Seed of every random draw."),
    workers: int = typer.Option(1, "--workers", help="Processes for the PSF bank and the pairs."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:N: where the networks train and run."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print report.json's metrics."),
) -> None:
    """Lens -> PSF bank -> simulated pairs -> training -> restoration -> evaluation -> report.

    Writes OUT/report.html (self-contained), OUT/report.json and the figures in
    OUT/figures/. A second run reuses every finished stage.

    Example: lensim demo --quick -o demo/
    """
    from lensim.demo import run_demo

    start = time.perf_counter()
    show = not quiet and not json_out
    bars = None
    if show:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        bars = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                        TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True)
    task = None

    def say(msg: str) -> None:
        """A stage begins: a line in the log and a fresh bar."""
        nonlocal task
        if bars is None:
            return
        console.print(f"[{time.perf_counter() - start:6.1f} s] {msg}", highlight=False)
        if task is not None:
            bars.remove_task(task)
        task = bars.add_task(msg, total=None)

    def progress(done: float, total: float) -> None:
        if bars is not None and task is not None:
            bars.update(task, completed=done, total=total)

    if bars is not None:
        bars.start()
    try:
        report = run_demo(output, quick=quick, seed=seed, workers=workers, say=say, device=device, progress=progress)
    finally:
        if bars is not None:
            bars.stop()
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
    import json

    from lensim.errors import InputError
    from lensim.report import write_report

    path = demo_dir / "report.json"
    if not path.is_file():
        raise InputError(str(path), None, "missing; expected a folder written by `lensim demo`")
    try:
        report = json.loads(path.read_text())
    except ValueError as e:
        raise InputError(str(path), None, f"not valid JSON: {e}") from None
    console.print(f"wrote {write_report(demo_dir, report, demo_dir / 'figures')}", highlight=False)
