"""`lensim library ...`: the lens library's prescriptions (lensim/assets/library)."""

from __future__ import annotations

import typer
from rich.table import Table

from lensim.cli.common import console, print_json
from lensim.cli.validate import choice

library_app = typer.Typer(
    help="The lens library: published prescriptions for training and evaluation.", no_args_is_help=True
)

SPLITS = ("all", "train", "holdout")


@library_app.command("list")
def list_command(
    split: str = typer.Option(
        "all", "--split", help="Which entries: all, train (may be trained on) or holdout (never trained on)."
    ),
    family: str = typer.Option(None, "--family", help="Only this family (triplet, tessar, zoom, phone, ...)."),
    json_out: bool = typer.Option(False, "--json", help="Print a JSON list (every index field, and the file's path)."),
) -> None:
    """List the library's lenses: family, focal length, F-number, field, hold-out (--json adds source, licence, file).

    Example: lensim library list --split holdout
    """
    from lensim.assets.library import FAMILIES, list_lenses

    split = choice(split, SPLITS, "--split")
    if family is not None:
        family = choice(family, FAMILIES, "--family")
    holdout = {"all": None, "train": False, "holdout": True}[split]
    entries = list_lenses(holdout=holdout, family=family)
    if json_out:
        print_json([{**e.__dict__, "path": str(e.path)} for e in entries])
        return
    t = Table(title=f"Lens library ({len(entries)} entries, {len({e.file for e in entries})} prescriptions)")
    t.add_column("name", no_wrap=True)
    for col in ("family", "f (mm)", "F/#", "half field", "held out"):
        t.add_column(col)
    for e in entries:
        t.add_row(
            e.name,
            e.family,
            f"{e.focal_mm:g}",
            f"{e.fno:g}",
            f"{e.half_field_deg:g} deg",
            "yes" if e.holdout else "",
        )
    console.print(t)
