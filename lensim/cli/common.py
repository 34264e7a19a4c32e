"""Shared CLI helpers: consoles, one-line error handling, JSON output."""
from __future__ import annotations

import json
import sys
import time
import warnings

import typer
from rich.console import Console

from lensim.errors import LensimError
from lensim.jsonable import jsonable

console = Console()
err_console = Console(stderr=True)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    err_console.print(f"[yellow]warning:[/yellow] {message}", highlight=False, soft_wrap=True)


def run_guarded(app: typer.Typer) -> None:
    """Run a Typer app; lensim errors become one line on stderr and exit status 2."""
    warnings.showwarning = _show_warning
    try:
        app(standalone_mode=True)
    except LensimError as e:
        err_console.print(f"[red]error:[/red] {e}", highlight=False, soft_wrap=True)
        sys.exit(2)


def print_json(data) -> None:
    """Print a JSON document on stdout (non-finite numbers become null)."""
    sys.stdout.write(json.dumps(jsonable(data), indent=2) + "\n")


def progress_bar(label: str, unit: str, quiet: bool):
    """A rich progress bar and its callback(done, total); (None, None) when quiet."""
    if quiet:
        return None, None
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    prog = Progress(TextColumn(label), BarColumn(), TextColumn("{task.completed}/{task.total} " + unit),
                    TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True)
    task = prog.add_task(label, total=None)

    def callback(done: int, total: int) -> None:
        prog.update(task, completed=done, total=total)
    return prog, callback


class StageBars:
    """Progress for a job of several long stages (demo, ablation): say(stage) prints a
    timestamped line and starts a fresh bar, progress(done, total) moves it. A context
    manager; with show=False both are silent."""

    def __init__(self, show: bool) -> None:
        self.start = time.perf_counter()
        self.bars = None
        self.task = None
        if show:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            self.bars = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                                 TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True)

    def __enter__(self) -> "StageBars":
        if self.bars is not None:
            self.bars.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bars is not None:
            self.bars.stop()

    def say(self, stage: str) -> None:
        if self.bars is None:
            return
        console.print(f"[{time.perf_counter() - self.start:6.1f} s] {stage}", highlight=False)
        if self.task is not None:
            self.bars.remove_task(self.task)
        self.task = self.bars.add_task(stage, total=None)

    def progress(self, done: float, total: float) -> None:
        if self.bars is not None and self.task is not None:
            self.bars.update(self.task, completed=done, total=total)

