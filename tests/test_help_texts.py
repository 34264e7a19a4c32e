"""Every --help reads in sentences: no help line breaks a sentence.

The rule, on the help as rendered at a terminal 1000 columns wide (wide enough that the
terminal wraps nothing, so every line break left comes from the text): within a block
(a paragraph of a command's description, or one cell of a help table: a command's
summary in its group's list, an option's or an argument's help), no line that ends
without closing punctuation (. : ; ! ? or a closing bracket) is followed by a line that
starts with a lowercase letter. Docstrings are hard-wrapped in the source (120 columns);
lensim.cli.common.help_in_sentences gives typer each paragraph on one line."""

from __future__ import annotations

import pytest
import typer
from typer.testing import CliRunner

from lensim.cli import app
from lensim.cli.common import help_in_sentences, help_text

WIDTH = 1000
WIDE = {"COLUMNS": str(WIDTH)}
ENDS = (".", ":", ";", "!", "?", ")", "]")


def broken_lines(rendered: str) -> list[str]:
    """'previous / next' for every line of rendered help that breaks a sentence (see the
    module docstring): lines of a panel (│ ... │) continue the row above when they are
    indented further than it (the first columns blank); other lines continue the line
    above unless a blank line or a panel border comes between."""
    found: list[str] = []
    previous: str | None = None
    row_indent: int | None = None
    for raw in rendered.splitlines():
        line = raw.rstrip()
        stripped = line.strip()
        if stripped.startswith(("╭", "╰")) or not stripped:
            previous, row_indent = None, None
            continue
        if stripped.startswith("│"):
            inner = stripped.strip("│").rstrip()
            indent = len(inner) - len(inner.lstrip())
            text = inner.strip()
            if row_indent is None or indent <= row_indent:  # a new row of the table
                previous, row_indent = text, indent
                continue
        else:
            text = stripped
        if previous is not None and not previous.endswith(ENDS) and text[:1].islower():
            found.append(f"{previous} / {text}")
        previous = text
    return found


def _paths(command: object, path: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [path]
    for name, sub in sorted(getattr(command, "commands", {}).items()):
        out += _paths(sub, (*path, name))
    return out


ROOT = typer.main.get_command(app)
PATHS = _paths(ROOT)


@pytest.fixture(scope="module")
def helps() -> dict[tuple[str, ...], str]:
    runner = CliRunner()
    out = {}
    for path in PATHS:
        result = runner.invoke(app, [*path, "--help"], env=WIDE)
        assert result.exit_code == 0, result.output
        out[path] = result.output
    return out


def test_every_command_and_group_is_rendered_wider_than_any_paragraph(helps) -> None:
    assert {(), ("lens",), ("lens", "info"), ("psf", "bank"), ("restore",)} <= set(helps)
    assert all(max(map(len, text.splitlines())) == WIDTH for text in helps.values())  # at the wide terminal

    def texts(command: object) -> list[str]:
        out = (getattr(command, "help", None) or "").split("\n")
        out += [getattr(p, "help", None) or "" for p in getattr(command, "params", [])]
        return out + [t for sub in getattr(command, "commands", {}).values() for t in texts(sub)]

    assert max(map(len, texts(ROOT))) < WIDTH - 200  # room for the tables' first columns: no line is wrapped


@pytest.mark.parametrize("path", PATHS, ids=lambda p: " ".join(p) or "lensim")
def test_no_help_line_breaks_a_sentence(helps, path: tuple[str, ...]) -> None:
    assert broken_lines(helps[path]) == []


def _hard_wrapped_app() -> typer.Typer:
    demo = typer.Typer()

    @demo.command("one")
    def one(width: int = typer.Option(1, "--width", help="A width in pixels.")) -> None:
        """Draw the lens layout (a y-z cross-section with a fan of rays per field), or its
        distortion against the field.

        Camera raw files are developed with the simulator's own chain, restored
        with the field of view of their active area.

        Example: lensim one --width 3
        Example: lensim one --width 4
        """

    @demo.command("two")
    def two() -> None:
        """Another command."""

    return demo


def test_the_rule_finds_typer_s_hard_wrapped_help_and_help_in_sentences_mends_it() -> None:
    """The check can fail: typer shows a docstring's source line breaks in its group's command
    list and in the later paragraphs of a command's help."""
    runner = CliRunner()
    demo = _hard_wrapped_app()
    assert broken_lines(runner.invoke(demo, ["--help"], env=WIDE).output) == [
        "one  Draw the lens layout (a y-z cross-section with a fan of rays per field), or its / "
        "distortion against the field."
    ]
    assert broken_lines(runner.invoke(demo, ["one", "--help"], env=WIDE).output) == [
        "Camera raw files are developed with the simulator's own chain, restored / "
        "with the field of view of their active area."
    ]
    help_in_sentences(demo)
    for args in (["--help"], ["one", "--help"]):
        assert broken_lines(runner.invoke(demo, args, env=WIDE).output) == []
    shown = runner.invoke(demo, ["one", "--help"], env=WIDE).output
    assert "Example: lensim one --width 3 " in shown and "Example: lensim one --width 4" in shown  # own lines


def test_help_text_joins_the_lines_of_each_paragraph() -> None:
    doc = "First line\n    goes on.\n\n    Second paragraph,\n    two lines.\n\n    Example: a\n    b\n    Example: c"
    assert help_text(doc) == "First line goes on.\n\nSecond paragraph, two lines.\n\nExample: a b\nExample: c"
