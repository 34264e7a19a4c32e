"""`lensim library ...`: the lens library's prescriptions (lensim/assets/library)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lensim.cli.bank_options import scheduler_option, workers_option
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, choice, positive, scheduler_address
from lensim.cli.validate import device as checked_device_option
from lensim.errors import InputError

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


@library_app.command("banks")
def banks_command(
    output: Path = typer.Option(..., "-o", "--output", help="The library's folder (plan.json, banks/, sensors/)."),
    workers: int = workers_option(),
    scheduler: str = scheduler_option(),
    limit: int = typer.Option(None, "--limit", help="Compute at most this many banks in this run (default: all)."),
    split: str = typer.Option("all", "--split", help="Which lenses: all, train or holdout."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON (no progress output)."),
) -> None:
    """Compute the library's PSF banks: every lens wide open and two stops down, focused at
    infinity and near, on two pixel pitches of its format (352 banks; lensim.data.library_banks).

    Resumable: a rerun skips the banks already done (and those the lens cannot give,
    listed in failed/) and finishes the rest. The banks are computed here (--workers 1),
    side by side on a local Dask cluster (--workers N: one whole bank per worker at a time),
    or each bank's fields on an existing cluster (--scheduler ADDRESS).

    Example: lensim library banks -o library/ --workers 2
    """
    from lensim.assets.library import list_lenses
    from lensim.data.library_banks import bank_plan, compute_library_banks

    split = choice(split, SPLITS, "--split")
    at_least(workers, 1, "--workers", what="a number of processes")
    if limit is not None:
        at_least(limit, 0, "--limit", what="a number of banks")
    scheduler_address(scheduler)
    holdout = {"all": None, "train": False, "holdout": True}[split]
    plan = bank_plan(list_lenses(holdout=holdout))
    with progress_bar("library banks", "banks", quiet or json_out) as report:
        result = compute_library_banks(output, plan, workers=workers, scheduler=scheduler, limit=limit, progress=report)
    summary = {"output": str(output), "banks": len(plan), **result.__dict__}
    if json_out:
        print_json(summary)
        return
    console.print(
        f"{output}: {result.done + result.computed} of {len(plan)} banks done "
        f"({result.computed} computed now, {result.failed} the lenses cannot give, {result.todo} left)",
        highlight=False,
    )


@library_app.command("pairs")
def pairs_command(
    library: Path = typer.Argument(..., help="The library's folder (made by `lensim library banks`)."),
    output: Path = typer.Option(..., "-o", "--output", help="The pairs' folder (photos/, pairs/<bank>/)."),
    split: str = typer.Option("train", "--split", help="Whose banks: train (default) or holdout (evaluation pairs)."),
    photos_per_bank: int = typer.Option(2, "--photos-per-bank", help="Training photos simulated per bank."),
    placements: int = typer.Option(3, "--placements", help="Sensor positions per photo (centre, middle, edge)."),
    crops: int = typer.Option(1, "--crops", help="Crops per placement."),
    size: int = typer.Option(128, "--size", help="Crop size (pixels, even)."),
    photo_size: int = typer.Option(384, "--photo-size", help="The photos' centre crop (pixels)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the photo draw and the captures."),
    limit: int = typer.Option(None, "--limit", help="Make at most this many banks' pairs in this run."),
    workers: int = workers_option(),
    scheduler: str = scheduler_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON (no progress output)."),
) -> None:
    """Make training pairs from the library's banks: a few crops per bank from the built-in
    training photos (never the unseen test photos), one pairs folder per bank.

    Resumable: a rerun skips the banks whose pairs are complete and adds banks computed since.
    --workers N makes N banks' pairs side by side on a local Dask cluster.

    Example: lensim library pairs library/ -o library-pairs/
    """
    from lensim.data.library_pairs import LibraryPairsSettings, make_library_pairs

    split = choice(split, ("train", "holdout"), "--split")
    for value, option in ((photos_per_bank, "--photos-per-bank"), (placements, "--placements"), (crops, "--crops")):
        at_least(value, 1, option, what="a count")
    at_least(size, 16, "--size", unit="pixels")
    at_least(photo_size, size, "--photo-size", unit="pixels")
    if size % 2:
        raise InputError("<command line>", "--size", f"expected an even crop size, got {size}")
    at_least(workers, 1, "--workers", what="a number of processes")
    scheduler_address(scheduler)
    settings = LibraryPairsSettings(photos_per_bank, placements, crops, size, photo_size, seed)
    with progress_bar("library pairs", "banks", quiet or json_out) as report:
        result = make_library_pairs(
            library,
            output,
            settings,
            holdout=split == "holdout",
            limit=limit,
            workers=workers,
            scheduler=scheduler,
            progress=report,
        )
    if json_out:
        print_json({"output": str(output), **result.__dict__})
        return
    console.print(
        f"{output}: pairs of {result.done + result.made} banks ({result.made} made now, {result.pairs} crops)",
        highlight=False,
    )


def _pair_folders(paths: list[Path]) -> list[Path]:
    """Each PATH: a library pairs folder (its pairs/<bank>/ folders) or one pairs folder."""
    from lensim.data.library_pairs import library_pair_folders

    out: list[Path] = []
    for p in paths:
        found = [p] if (p / "manifest.json").exists() else library_pair_folders(p)
        if not found:
            raise InputError(str(p), None, "holds no pairs; expected a `lensim library pairs` folder or a pairs folder")
        out.extend(found)
    return out


@library_app.command("pretrain")
def pretrain_command(
    pairs: list[Path] = typer.Argument(
        ..., help="Library pairs folder(s) (`lensim library pairs -o`) or pairs folders."
    ),
    output: Path = typer.Option(..., "-o", "--output", help="The run folder (last.pt, log.csv); a rerun resumes it."),
    minutes: float = typer.Option(60.0, "--minutes", help="Training time in all, every call's (minutes)."),
    call_minutes: float = typer.Option(None, "--call-minutes", help="Stop this call after this many minutes."),
    arch: str = typer.Option(
        "psfnet",
        "--arch",
        help="The network: psfnet (refines the Wiener stage of each lens's own PSF bank) or nafnet (image only).",
    ),
    width: int = typer.Option(46, "--width", help="NAFNet width (46: the default network's size)."),
    crop: int = typer.Option(96, "--crop", help="Training sub-crop (pixels)."),
    batch_size: int = typer.Option(8, "--batch-size", help="Crops per step."),
    lr: float = typer.Option(5e-4, "--lr", help="Adam learning rate."),
    seed: int = typer.Option(0, "--seed", help="Seed of initialisation, data order and augmentation."),
    max_steps: int = typer.Option(0, "--max-steps", help="Stop after this many optimizer steps in all (0: no limit)."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:N (mixed precision on CUDA)."),
    no_amp: bool = typer.Option(False, "--no-amp", help="Full float32 on CUDA."),
    ship_to: Path = typer.Option(None, "--ship", help="Write the model for inference into this folder at the end."),
    workers: int = typer.Option(
        1, "--workers", help="Pairs folders whose Wiener stage caches are computed at a time before training."
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
) -> None:
    """Pretrain the universal model on the library's pairs (lensim.restore.universal).

    Resumable: the same command continues the run (the time counts every call's);
    --minutes larger than before trains on.

    Example: lensim library pretrain library-pairs/ -o runs/universal --minutes 60
    """
    from lensim.restore.universal import PretrainConfig, pretrain, ship

    positive(minutes, "--minutes", "minutes")
    if call_minutes is not None:
        positive(call_minutes, "--call-minutes", "minutes")
    for value, option in ((width, "--width"), (crop, "--crop"), (batch_size, "--batch-size")):
        at_least(value, 1, option, what="a count")
    positive(lr, "--lr")
    at_least(max_steps, 0, "--max-steps", what="a count")
    at_least(workers, 1, "--workers", what="a number of processes")
    cfg = PretrainConfig(
        width=width,
        crop=crop,
        batch_size=batch_size,
        lr=lr,
        time_budget_s=minutes * 60.0,
        max_steps=max_steps or None,
        seed=seed,
        arch=arch,
        device=checked_device_option(device),
        amp=not no_amp,
    )
    cfg.network()  # an unknown --arch is one line before any work
    folders = _pair_folders(pairs)
    with progress_bar("universal pretraining", "s", quiet) as report:
        call_s = None if call_minutes is None else call_minutes * 60.0
        result = pretrain(folders, output, cfg, report, call_s, cache_workers=workers)
    if ship_to is not None:
        ship(output, ship_to)
    loss = "n/a" if result.loss is None else f"{result.loss:.5g}"
    console.print(
        f"{output}: {result.step} steps, {result.seconds / 60:.1f} min on {result.folders} pairs folders, loss {loss}",
        highlight=False,
    )
