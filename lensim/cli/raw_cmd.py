"""`lensim raw ...`: inspect camera raw files."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lensim.cli.common import console, print_json

raw_app = typer.Typer(
    help="Inspect camera raw files (DNG, CR2/CR3, NEF, ARW, RAF, ORF, RW2, PEF, ...).", no_args_is_help=True
)


def _fmt(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


@raw_app.command("info")
def info(
    files: list[Path] = typer.Argument(..., help="Raw files, or folders of raw files."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON: one object for one file, a list for several."),
) -> None:
    """Metadata of raw files: camera, active area, CFA pattern, levels, white balance,
    colour matrix (XYZ -> camera), shooting data and orientation. Every file is read
    before anything is printed.

    Example: lensim raw info IMG_0001.dng --json
    """
    from lensim.raw import raw_files, read_raw

    raws = [read_raw(p) for p in raw_files(list(files))]
    if json_out:
        infos = [r.info() for r in raws]
        print_json(infos[0] if len(infos) == 1 else infos)
        return
    for raw in raws:
        t = Table(title=raw.path, show_header=False)
        t.add_column("field")
        t.add_column("value")
        for key, value in raw.info().items():
            if key == "color_matrix" and value is not None:
                value = "; ".join(_fmt(row) for row in value)
            t.add_row(key, _fmt(value))
        console.print(t)
