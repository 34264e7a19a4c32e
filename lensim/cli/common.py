"""Shared CLI helpers: consoles, one-line error handling, JSON output."""

from __future__ import annotations

import contextlib
import json
import sys
import time
import warnings
from collections.abc import Callable, Iterator

import typer
from rich.console import Console
from rich.text import Text

from lensim.errors import LensimError
from lensim.jsonable import jsonable

# markup off: file names and values such as "bad[bold]name.yaml" print as they are
console = Console(markup=False)
err_console = Console(stderr=True, markup=False)


def plain_line(text: object) -> str:
    """``text`` as one printable line: newlines become spaces, other control characters
    (a NUL byte read from a binary file, an escape sequence in a file name) their Python
    escapes, so a message can neither break the line nor drive the terminal."""
    flat = " ".join(str(text).splitlines())
    return "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in flat)


def print_error_line(label: str, style: str, message: object) -> None:
    """One line on stderr, ``LABEL: message``; the message is shown literally (file names
    and values with square brackets are text, never rich markup)."""
    err_console.print(Text.assemble((f"{label}:", style), " ", plain_line(message)), highlight=False, soft_wrap=True)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print_error_line("warning", "yellow", message)


def _usage_error_line(e: typer.TyperException) -> str:
    """A click usage error (unknown option, missing argument, a value of the wrong type)
    as one line naming the command and where its help is."""
    ctx = getattr(e, "ctx", None)
    where = ctx.command_path if ctx is not None else "lensim"
    return f"{where}: {e.format_message()} (see {where} --help)"


def run_guarded(app: typer.Typer) -> None:
    """Run a Typer app; lensim errors and command-line usage errors become one line on
    stderr and exit status 2 (usage errors keep click's status); a command's help
    (asked for, or shown for a group given no command) is printed as usual."""
    warnings.showwarning = _show_warning
    try:
        code = app(standalone_mode=False, prog_name="lensim")
    except typer.TyperException as e:  # click's errors (typer vendors click)
        ctx = getattr(e, "ctx", None)
        if type(e).__name__ == "NoArgsIsHelpError" and ctx is not None:
            console.print(ctx.get_help(), markup=False, highlight=False)
        else:
            print_error_line("error", "red", _usage_error_line(e))
        sys.exit(getattr(e, "exit_code", 2))
    except typer.Abort:
        print_error_line("error", "red", "aborted")
        sys.exit(1)
    except LensimError as e:
        print_error_line("error", "red", e)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


def print_json(data) -> None:
    """Print a JSON document on stdout (non-finite numbers become null)."""
    sys.stdout.write(json.dumps(jsonable(data), indent=2) + "\n")


@contextlib.contextmanager
def progress_bar(label: str, unit: str, quiet: bool) -> Iterator[Callable[[float, float], None] | None]:
    """A rich progress bar shown while the ``with`` block runs; yields its callback(done,
    total), or None when quiet. The label is shown literally (no markup)."""
    if quiet:
        yield None
        return
    from rich.markup import escape
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    prog = Progress(
        TextColumn(escape(label)),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} " + escape(unit)),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )
    task = prog.add_task(label, total=None)

    def callback(done: float, total: float) -> None:
        prog.update(task, completed=done, total=total)

    with prog:
        yield callback


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

            self.bars = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.percentage:>3.0f}%"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=console,
                transient=True,
            )

    def __enter__(self) -> StageBars:
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
