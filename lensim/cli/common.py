"""Shared CLI helpers: consoles, one-line error handling (bad input, with library parameter
names shown as the command's options, and the faults of a long run: a full disk, too
little memory, SIGTERM or Ctrl-C), JSON output."""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import re
import signal
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import typer
from rich.console import Console
from rich.text import Text
from typer.models import OptionInfo

from lensim.errors import InputError, LensimError, ParameterError
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


#: Warnings held back until the command starts its long work or ends well (None: shown
#: at once). A command that fails before then shows only its one error line.
_held_warnings: list[str] | None = None


def _show_warning(message, category, filename, lineno, file=None, line=None):
    if _held_warnings is None:
        print_error_line("warning", "yellow", message)
    else:
        _held_warnings.append(str(message))


def release_warnings() -> None:
    """Show the warnings held so far, and every later one at once (called when a progress
    bar starts and when a command ends well)."""
    global _held_warnings
    held, _held_warnings = _held_warnings or [], None
    for message in held:
        print_error_line("warning", "yellow", message)


def _usage_error_line(e: typer.TyperException) -> str:
    """A click usage error (unknown option, missing argument, a value of the wrong type)
    as one line naming the command and where its help is."""
    ctx = getattr(e, "ctx", None)
    where = ctx.command_path if ctx is not None else "lensim"
    return f"{where}: {e.format_message()} (see {where} --help)"


# ---------------------------------------------------------------- parameter names -> options

#: Library parameters that a command's own parameter spells differently: {library name:
#: the command function's parameter name}. The one table of the mapping; everything else
#: is read from the command's signature (see option_of).
PARAMETER_ALIASES: dict[str, str] = {
    "pixel_pitch_um": "pixel_um",  # sensor from-raw --pixel-um
    "focal_mm": "focal",  # lens lensfun --focal
    "distance_m": "distance",  # lens lensfun --distance
    "makers": "glass_makers",  # lens info/convert/field/lensfun --glass-makers
    "flats": "flat",  # sensor from-raw --flat
    "out_dir": "output",  # restore --output
}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_QUOTED = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)`")


def command_options(command: Callable[..., Any]) -> dict[str, str]:
    """{Python parameter name: its long option} of a Typer command function (typer's
    default spelling, --name-with-dashes, where the option gives no names)."""
    out: dict[str, str] = {}
    for name, param in inspect.signature(command).parameters.items():
        if isinstance(param.default, OptionInfo):
            decls = [d for d in param.default.param_decls or () if d.startswith("--")]
            out[name] = decls[0].split("/")[0] if decls else "--" + name.replace("_", "-")
    return out


def option_of(parameter: str, options: dict[str, str]) -> str | None:
    """The option that gives a library parameter, among a command's ``options``
    (command_options): the command's parameter of that name or of its PARAMETER_ALIASES
    name, else an option spelled --PARAMETER (underscores as dashes); None when the
    command has none."""
    for name in (parameter, PARAMETER_ALIASES.get(parameter)):
        if name is not None and name in options:
            return options[name]
    dashed = "--" + parameter.replace("_", "-")
    return dashed if dashed in options.values() else None


def error_for_command_line(error: LensimError, options: dict[str, str]) -> LensimError:
    """The error as the command line shows it: the parameter(s) a ParameterError names, and
    every `name` a message quotes in backticks, become the command's options; a name the
    command has no option for stays as it is. The error itself when nothing changes."""

    def named(m: re.Match[str]) -> str:
        return option_of(m.group(0), options) or m.group(0)

    def quoted(m: re.Match[str]) -> str:
        return option_of(m.group(1), options) or m.group(0)

    if isinstance(error, InputError):
        field = _NAME.sub(named, error.field) if isinstance(error, ParameterError) and error.field else error.field
        message = _QUOTED.sub(quoted, error.message)
        if (field, message) == (error.field, error.message):
            return error
        return InputError(error.source, field, message)
    text = _QUOTED.sub(quoted, str(error))
    return error if text == str(error) else LensimError(text)


def _naming_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """The command function, its lensim errors shown with its options (error_for_command_line)."""
    if getattr(command, "names_options", False):
        return command

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except LensimError as e:
            shown = error_for_command_line(e, command_options(command))
            if shown is e:
                raise
            raise shown from e

    run.names_options = True  # type: ignore[attr-defined]
    return run


def help_text(doc: str) -> str:
    """A command's docstring as its help text: each paragraph (they are separated by blank
    lines) on one line, for the terminal to wrap at its own width, so that no line of the
    help breaks a sentence where the source file wraps it; a line that starts with
    "Example:" keeps a line of its own."""
    paragraphs = []
    for paragraph in inspect.cleandoc(doc).split("\n\n"):
        lines: list[str] = []
        for line in (text.strip() for text in paragraph.splitlines()):
            if lines and line and not line.startswith("Example:"):
                lines[-1] = f"{lines[-1]} {line}"
            elif line:
                lines.append(line)
        paragraphs.append("\n".join(lines))
    return "\n\n".join(paragraphs)


def help_in_sentences(app: typer.Typer) -> None:
    """Give every command of ``app`` (and of its sub-apps) its docstring as help_text: typer
    keeps a docstring's line breaks (in its groups' command lists, and in every paragraph of
    a command's help but the first), which cut sentences mid-line at a wide terminal."""
    for info in app.registered_commands:
        doc = info.help or (inspect.getdoc(info.callback) if info.callback is not None else None)
        if doc:
            info.help = help_text(doc)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            help_in_sentences(group.typer_instance)


def name_options(app: typer.Typer) -> None:
    """Make every command of ``app`` (and of its sub-apps) show the library parameters its
    errors name as the command's options: the library never names a command-line option
    (its errors name the parameter), the command line maps it, here."""
    for info in app.registered_commands:
        if info.callback is not None:
            info.callback = _naming_options(info.callback)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            name_options(group.typer_instance)


# ---------------------------------------------------------------- faults and running the app


class Stopped(BaseException):
    """SIGTERM or SIGINT (Ctrl-C), raised in the main thread so that every ``finally`` and
    ``with`` on the way out runs: Dask clusters close, locks are released, a temporary file
    being written is removed. Not an Exception: no handler of errors catches it."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _stop(signum: int, frame: object) -> None:
    """The handler of SIGTERM and SIGINT: a second one ends the process at once."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    raise Stopped(signum)


@contextlib.contextmanager
def _stopped_by_signals() -> Iterator[None]:
    """SIGTERM and SIGINT raise Stopped in the block (the handlers before are put back)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    for s in saved:
        signal.signal(s, _stop)
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


#: what sizes each command's memory, for the line an allocation failure prints
_MEMORY_OPTIONS = {
    "restore": "a smaller --tile, or fewer --workers",
    "train": "a smaller --batch-size or --crop",
    "dataset": "fewer --workers, or smaller photos",
    "psf": "fewer --workers, or fewer --pupil-samples",
    "simulate": "fewer --workers",
}


def fault_line(error: BaseException) -> str | None:
    """The one line for a fault of the environment that no lensim code turned into a
    LensimError (a file system that refuses a write, an allocation that fails), or None
    for any other exception (a bug: its traceback is shown)."""
    from lensim.errors import out_of_memory
    from lensim.io import ENVIRONMENT, NO_ROOM, why_not_written

    if out_of_memory(error):
        command = next((a for a in sys.argv[1:] if not a.startswith("-")), "")
        what = _MEMORY_OPTIONS.get(command, "a smaller job")
        return f"out of memory ({plain_line(error)[:160]}); expected more free memory, or {what}"
    if isinstance(error, OSError) and error.errno in ENVIRONMENT:
        where = f"{error.filename}: " if error.filename else ""
        if error.errno in NO_ROOM:
            return f"{where}{why_not_written(error)}; expected room on the file system: free some and run again"
        return f"{where}{why_not_written(error)}; expected a file lensim may read and write"
    return None


def _run_holding_warnings(app: typer.Typer) -> object:
    """Run the app with its warnings held until its long work starts or it ends well (a
    command that fails before then shows only its error line); returns its exit code."""
    global _held_warnings
    _held_warnings = []
    try:
        with _stopped_by_signals():
            code = app(standalone_mode=False, prog_name="lensim")
        release_warnings()
        return code
    finally:
        _held_warnings = None


def run_guarded(app: typer.Typer) -> None:
    """Run a Typer app; lensim errors and command-line usage errors become one line on
    stderr and exit status 2 (usage errors keep click's status); a command's help
    (asked for, or shown for a group given no command) is printed as usual. The faults
    of a long run are one line too: SIGTERM and Ctrl-C stop it cleanly (exit status 128
    plus the signal), a full disk or an allocation failure exit with status 2
    (:func:`fault_line`)."""
    warnings.showwarning = _show_warning
    try:
        code = _run_holding_warnings(app)
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
    except Stopped as e:
        name = signal.Signals(e.signum).name
        print_error_line(
            "error",
            "red",
            f"stopped by {name}; the work finished so far is kept: run the same command "
            "again to resume it (train: with --resume)",
        )
        sys.exit(128 + e.signum)
    except LensimError as e:
        print_error_line("error", "red", e)
        sys.exit(2)
    except Exception as e:
        line = fault_line(e)
        if line is None:
            raise
        print_error_line("error", "red", line)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


def print_json(data) -> None:
    """Print a JSON document on stdout (non-finite numbers become null)."""
    sys.stdout.write(json.dumps(jsonable(data), indent=2) + "\n")


@contextlib.contextmanager
def progress_bar(label: str, unit: str, quiet: bool) -> Iterator[Callable[[float, float], None] | None]:
    """A rich progress bar shown while the ``with`` block runs; yields its callback(done,
    total), or None when quiet. The label is shown literally (no markup). The warnings
    held so far are shown first."""
    release_warnings()
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
        self.task: Any = None  # rich's TaskID of the current stage's bar
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
        release_warnings()
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
