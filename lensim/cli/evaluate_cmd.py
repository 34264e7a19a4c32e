"""`lensim evaluate`: PSNR / SSIM of restoration methods on a pairs dataset, per field zone.

Register in lensim/cli/__init__.py with
    from lensim.cli.evaluate_cmd import evaluate_command
    app.command("evaluate")(evaluate_command)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, choice, finite, output_folder, positive
from lensim.cli.validate import device as check_device
from lensim.errors import InputError

DEFAULT_METHODS = "input,wiener,rl,unsharp"


def evaluate_command(
    pairs: Path = typer.Option(..., "--pairs", help="Pairs folder from `lensim dataset make`."),
    methods: str = typer.Option(
        None,
        "--methods",
        help="Comma list of input, wiener, rl, unsharp, model, plain, universal (the shipped universal "
        "model, zero-shot) (default: input,wiener,rl,unsharp plus model / plain when their runs are given).",
    ),
    model: Path = typer.Option(
        None, "--model", help="`lensim train` run folder or checkpoint of the field-aware model."
    ),
    plain: Path = typer.Option(
        None, "--plain", help="Run folder or checkpoint of the plain network baseline (no field-aware part)."
    ),
    plain_unet: Path = typer.Option(None, "--plain-unet", hidden=True, help="Old name of --plain."),
    bank: Path = typer.Option(
        None, "--bank", help="The dataset's PSF bank folder (default: the one its manifest names)."
    ),
    held_out: Path = typer.Option(
        None, "--held-out", help="Evaluate only the validation photos of this training run (RUN/split.json)."
    ),
    sources: str = typer.Option(None, "--sources", help="Comma list of source photo file names to evaluate."),
    max_crops: int = typer.Option(None, "--max-crops", help="Evaluate at most this many crops."),
    rl_iterations: int = typer.Option(None, "--rl-iterations", help="Richardson-Lucy iterations (default 3)."),
    unsharp_sigma: float = typer.Option(
        None, "--unsharp-sigma", help="Unsharp-mask Gaussian sigma in pixels (default 1)."
    ),
    unsharp_amount: float = typer.Option(None, "--unsharp-amount", help="Unsharp-mask amount (default 0.6)."),
    arch: str = typer.Option(
        None,
        "--arch",
        help="Architecture the --model and --plain checkpoints must hold "
        "(unet or nafnet; default: whatever they hold).",
    ),
    device: str = typer.Option("cpu", "--device", help="Device of the trained networks (cpu, cuda, cuda:N)."),
    output: Path = typer.Option(
        None, "-o", "--output", help="Folder for metrics.csv (per crop), metrics.md, metrics.json."
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print the summary JSON instead of a table."),
) -> None:
    """Restore every input crop of a pairs dataset with each method and score it against
    its sharp target: PSNR (dB) and SSIM overall and per field zone (centre, middle, edge:
    normalized sensor radius < 1/3, 1/3..2/3, > 2/3 of the half-diagonal). `input` is the
    aberrated crop itself; wiener and rl are oracles given the true PSF bank. `plain-unet`
    (method) and --plain-unet (option) are old names of `plain` and --plain; results are
    keyed by the name used (in --methods, else the option's).

    Example: lensim evaluate --pairs data/ --methods input,wiener,rl,unsharp,model --model runs/a --held-out runs/a -o eval/
    """
    from lensim.data.manifest import read_held_out, read_pairs_manifest
    from lensim.evaluate import harness

    runs = _runs(model, plain, plain_unet)
    if methods is not None and "universal" in [m.strip() for m in methods.split(",")]:
        from lensim.restore.universal import NAME, model_path

        runs["universal"] = model_path(NAME)  # the shipped universal model, zero-shot
    names = _method_names(methods, runs, "plain-unet" if plain_unet is not None else "plain")
    _check_options(rl_iterations, unsharp_sigma, unsharp_amount, max_crops, device, output)
    if arch is not None:
        from lensim.restore.models import ARCHS

        choice(arch, ARCHS, "--arch")
    manifest = read_pairs_manifest(pairs)
    keep = read_held_out(held_out) if held_out is not None else None
    if sources:
        asked = [s.strip() for s in sources.split(",") if s.strip()]
        _check_sources(pairs, manifest, asked)
        keep = (keep or []) + asked
    options: dict[str, dict[str, Any]] = {
        "rl": {"iterations": rl_iterations},
        "unsharp": {"sigma_px": unsharp_sigma, "amount": unsharp_amount},
    }
    table: dict[str, harness.Method] = {}
    for n in names:
        run = runs.get(harness.METHOD_ALIASES.get(n, n))  # a checkpoint method: _method_names checked its run
        if run is not None:
            table[n] = harness.checkpoint_method(
                run, manifest.get("lens"), manifest.get("sensor"), device=device, arch=arch
            )
        elif n != "input":
            table[n] = harness.builtin_method(n, **{k: v for k, v in options.get(n, {}).items() if v is not None})
    rows: list[dict[str, Any]] = []
    with progress_bar("evaluate", "crops", quiet or json_out) as cb:
        summary = harness.evaluate(pairs, table, bank=bank, sources=keep, max_crops=max_crops, progress=cb, rows=rows)
    if output is not None:
        _write_outputs(output, pairs, rows, summary)
    if json_out:
        print_json(summary)
    elif not quiet:
        _print_table(pairs, rows, summary)
        if output is not None:
            console.print(
                f"wrote {output / 'metrics.csv'}, {output / 'metrics.md'}, {output / 'metrics.json'}", highlight=False
            )


def _check_options(
    rl_iterations: int | None,
    unsharp_sigma: float | None,
    unsharp_amount: float | None,
    max_crops: int | None,
    device: str,
    output: Path | None,
) -> None:
    """The numbers, the device and the output folder, before any work."""
    if rl_iterations is not None:
        at_least(rl_iterations, 1, "--rl-iterations", what="a number of iterations")
    if unsharp_sigma is not None:
        positive(unsharp_sigma, "--unsharp-sigma", "px", "a Gaussian sigma")
    if unsharp_amount is not None:
        finite(unsharp_amount, "--unsharp-amount")
    if max_crops is not None:
        at_least(max_crops, 1, "--max-crops", what="a number of crops")
    check_device(device)
    if output is not None:
        output_folder(output)


def _check_sources(pairs: Path, manifest: dict[str, Any], asked: list[str]) -> None:
    """Every --sources name is a source photo of the dataset (its path or file name)."""
    known = set()
    for rec in manifest["records"]:
        src = str(rec.get("source", ""))
        known |= {src, Path(src).name}
    unknown = [s for s in asked if s not in known]
    if unknown:
        raise InputError("--sources", None, f"{', '.join(unknown)} not among the source photos of {pairs}")


def _runs(model: Path | None, plain: Path | None, plain_unet: Path | None) -> dict[str, Path | None]:
    """The run of each checkpoint method ("model", "plain"); --plain-unet is the old name of
    --plain (not both)."""
    if plain is not None and plain_unet is not None:
        raise InputError("--plain-unet", None, "is the old name of --plain; expected one of them, not both")
    return {"model": model, "plain": plain if plain is not None else plain_unet, "universal": None}


def _method_names(methods: str | None, runs: dict[str, Path | None], plain_name: str = "plain") -> list[str]:
    """The methods asked for (default: the built-in ones plus those whose runs are given,
    the plain network as ``plain_name``: "plain", or "plain-unet" when --plain-unet gave
    its run), checked: known names (aliases included), and a run for each checkpoint
    method."""
    from lensim.evaluate.harness import BUILTIN_METHODS, CHECKPOINT_METHODS, METHOD_ALIASES

    if methods is None:
        names = DEFAULT_METHODS.split(",") + [
            plain_name if n == "plain" else n for n in CHECKPOINT_METHODS if runs.get(n) is not None
        ]
    else:
        names = [m.strip() for m in methods.split(",") if m.strip()]
    if not names:
        raise InputError("--methods", None, "expected at least one method")
    for n in names:
        if n not in BUILTIN_METHODS + CHECKPOINT_METHODS + tuple(METHOD_ALIASES):
            raise InputError(
                "--methods",
                None,
                f"unknown method {n!r}; expected some of {', '.join(BUILTIN_METHODS + CHECKPOINT_METHODS)}",
            )
        canonical = METHOD_ALIASES.get(n, n)
        if canonical in CHECKPOINT_METHODS and runs.get(canonical) is None:
            raise InputError("--methods", None, f"method {n!r} needs its run: pass --{canonical} RUN")
    return names


def _write_outputs(output: Path, pairs: Path, rows: list[dict[str, Any]], summary: dict[str, Any]) -> None:
    """OUTPUT/metrics.csv (per crop), metrics.md and metrics.json (the summary)."""
    from lensim.evaluate import harness
    from lensim.io import atomic_write_json
    from lensim.jsonable import jsonable

    output.mkdir(parents=True, exist_ok=True)
    harness.write_csv(rows, output / "metrics.csv")
    harness.write_markdown(summary, output / "metrics.md", title=f"lensim evaluate: {pairs}")
    atomic_write_json(output / "metrics.json", jsonable(summary), indent=2)


def _print_table(pairs: Path, rows: list[dict[str, Any]], summary: dict[str, Any]) -> None:
    """The summary as a rich table: PSNR, gain over the input and SSIM, overall and per zone."""
    from rich.table import Table

    from lensim.evaluate.harness import format_score
    from lensim.evaluate.metrics import ZONES

    t = Table(
        title=f"{len(rows) // max(len(summary['methods']), 1)} crops from {pairs}",
        caption="zones: PSNR (dB) / SSIM; normalized sensor radius < 1/3, 1/3..2/3, > 2/3",
    )
    t.add_column("method")
    t.add_column("PSNR (dB)", justify="right")
    t.add_column("gain", justify="right")
    t.add_column("SSIM", justify="right")
    for z in ZONES:
        t.add_column(z, justify="right", no_wrap=True)
    base = summary["methods"]["input"]["psnr_db"]
    f = format_score
    for n, m in summary["methods"].items():
        t.add_row(
            n,
            f(m["psnr_db"], 2),
            f(m["psnr_db"] - base, 2),
            f(m["ssim"], 4),
            *[f"{f(m['zones'][z]['psnr_db'], 2)} / {f(m['zones'][z]['ssim'], 3)}" for z in ZONES],
        )
    console.print(t)
