"""The library names no command-line option; the command line names its options.

Library errors name the parameter (``ParameterError``: ``fno``, ``workers``) and quote
another parameter a message points to in backticks; the commands show each as their
option (lensim.cli.common.error_for_command_line, applied to every command by
name_options). The scan below reads every string literal of the library (docstrings
aside: they may describe the command line) so that an option string cannot come back."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import typer

from cli_runner import run_cli
from lensim.cli import app
from lensim.cli.common import PARAMETER_ALIASES, command_options, error_for_command_line, name_options
from lensim.errors import InputError, LensimError, ParameterError, renamed

LIBRARY = Path(__file__).resolve().parents[1] / "lensim"
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9]*(?:-[a-z0-9]+)*")


def _docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                found.add(id(first.value))
    return found


def option_strings(source: str) -> list[tuple[int, str]]:
    """(line, option) of every command-line option (--name) or "<command line>" in the
    string literals of Python source, docstrings left out."""
    tree = ast.parse(source)
    docs = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            found += [(node.lineno, m.group(0)) for m in OPTION.finditer(node.value)]
            if "<command line>" in node.value:
                found.append((node.lineno, "<command line>"))
    return found


def test_the_scan_finds_option_strings() -> None:
    """The check can fail: an option in an error, an f-string or "<command line>" is found;
    a docstring, a comment and matplotlib's "--" line style are not."""
    source = '''
def f(x):
    """Like `lensim psf bank --fno`."""
    ls = "--"  # --workers in a comment
    if x:
        raise InputError("<command line>", "--fno", f"give {x} --focus-m")
'''
    assert sorted(option_strings(source)) == [(6, "--fno"), (6, "--focus-m"), (6, "<command line>")]


def test_the_library_names_no_command_line_option() -> None:
    found = [
        f"{path.relative_to(LIBRARY.parent)}:{line}: {option}"
        for path in sorted(LIBRARY.rglob("*.py"))
        if path.relative_to(LIBRARY).parts[0] != "cli"
        for line, option in option_strings(path.read_text())
    ]
    assert found == [], "name the parameter (ParameterError, `name` in messages); the CLI maps it:\n" + "\n".join(found)


# ---------------------------------------------------------------- the mapping


def _command(
    fno: str = typer.Option(None, "--fno"),
    pixel_um: float = typer.Option(None, "--pixel-um"),
    wavelengths: str = typer.Option("400:700:20", "--wavelengths-nm"),
    output: str = typer.Option(..., "-o", "--output"),
    dng: bool = typer.Option(False, "--dng/--no-dng"),
    quiet: bool = typer.Option(False),
) -> None:
    """A command's signature, for the mapping."""


def test_a_command_s_options_are_read_from_its_signature() -> None:
    assert command_options(_command) == {
        "fno": "--fno",
        "pixel_um": "--pixel-um",
        "wavelengths": "--wavelengths-nm",
        "output": "--output",
        "dng": "--dng",
        "quiet": "--quiet",
    }


@pytest.mark.parametrize(
    "error, shown",
    [
        (ParameterError(None, "fno", "expected an `fno` of 5 or more"), "--fno: expected an --fno of 5 or more"),
        (ParameterError("a.png", "fno, wavelengths_nm", "give `fno`"), "a.png: --fno, --wavelengths-nm: give --fno"),
        (ParameterError(None, "pixel_pitch_um", "bad"), "--pixel-um: bad"),  # PARAMETER_ALIASES
        (ParameterError(None, "fno/focal_mm", "x"), "--fno/focal_mm: x"),  # no --focal-mm here: as it is
        (InputError("cam.yaml", "pixel_pitch_um", "bad"), "cam.yaml: pixel_pitch_um: bad"),  # a file's field
        (InputError("run", None, "expected `dng` or `other`"), "run: expected --dng or `other`"),
        (LensimError("leave out `dng`"), "leave out --dng"),
    ],
)
def test_parameters_are_shown_as_the_command_s_options(error: LensimError, shown: str) -> None:
    assert "pixel_pitch_um" in PARAMETER_ALIASES
    assert str(error_for_command_line(error, command_options(_command))) == shown


def test_an_error_naming_no_parameter_is_raised_as_it_is() -> None:
    error = InputError("lens.yaml", "surfaces[2].radius", "expected a number")
    assert error_for_command_line(error, command_options(_command)) is error


def test_a_renamed_error_names_the_outer_function_s_parameters() -> None:
    e = renamed(ParameterError(None, "fno", "expected an `fno` of 5 or more"), {"fno": "aperture"})
    assert isinstance(e, ParameterError) and str(e) == "aperture: expected an `aperture` of 5 or more"


def _every_command(typer_app: typer.Typer) -> list:
    infos = list(typer_app.registered_commands)
    for group in typer_app.registered_groups:
        infos += _every_command(group.typer_instance)
    return infos


def test_every_command_of_the_app_maps_parameters_to_options() -> None:
    infos = _every_command(app)
    assert len(infos) > 20 and all(getattr(info.callback, "names_options", False) for info in infos)
    name_options(app)  # twice is once
    assert all(not hasattr(info.callback.__wrapped__, "names_options") for info in _every_command(app))


def test_the_command_line_shows_the_option_the_user_typed(capsys, monkeypatch, tmp_path) -> None:
    """lens_at names fno; lensfun_profile renames it aperture; `lens lensfun` shows --aperture."""
    args = "lens lensfun cooke_triplet --maker m --model x --mount Generic --crop-factor 1.5 --focal 50"
    code, _, err = run_cli([*args.split(), "--aperture", "2", "-o", str(tmp_path / "p.xml")], capsys, monkeypatch)
    assert code == 2 and err.startswith("error: --aperture: F/2 is faster") and "an --aperture of 5" in err, err
    assert "fno" not in err and not (tmp_path / "p.xml").exists()
