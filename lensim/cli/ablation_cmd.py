"""`lensim ablation`: rerun the paper's ablation on your pairs."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lensim.ablation import VARIANTS, variants_for
from lensim.cli.common import StageBars, console, print_json
from lensim.cli.validate import at_least, choice, input_folder, output_folder, positive
from lensim.cli.validate import device as check_device
from lensim.restore.config import TrainConfig

_D = TrainConfig()


def ablation_command(
    dataset: Path = typer.Argument(..., help="Pairs folder from `lensim dataset make`."),
    output: Path = typer.Option(..., "-o", "--output", help="Folder for the runs and ablation.json (reused)."),
    time_budget_s: float = typer.Option(600.0, "--time-budget-s", help="Training seconds per variant."),
    arch: str = typer.Option(
        "unet",
        "--arch",
        help="Network: unet (the paper's field-aware UNet) or nafnet (NAFNet "
        "with the same switches; its plain variant is plain-nafnet).",
    ),
    width: int = typer.Option(
        None,
        "--width",
        help="Channels at the first scale of the full network (default: "
        "the architecture's, the size of the paper's UNet: unet 32).",
    ),
    crop: int = typer.Option(_D.crop, "--crop", help="Training sub-crop size in pixels."),
    seed: int = typer.Option(_D.seed, "--seed", help="Seed of every run."),
    variants: str = typer.Option(
        None,
        "--variants",
        help="Comma-separated subset of the variants (default: all: "
        f"{', '.join(VARIANTS)}; with --arch nafnet plain-nafnet for plain-unet).",
    ),
    device: str = typer.Option(_D.device, "--device", help="cpu, cuda or cuda:N."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print ablation.json."),
) -> None:
    """Train the field-aware network (the UNet, or NAFNet with --arch nafnet) with each idea
    switched off in turn, and a plain network of about the same size, on the same budget;
    report held-out PSNR/SSIM by zone.

    Example: lensim ablation data/ -o ablation/ --time-budget-s 600
    """
    from lensim.ablation import run_ablation
    from lensim.evaluate.harness import format_score
    from lensim.evaluate.metrics import ZONES
    from lensim.restore.models import ARCHS

    choice(arch, ARCHS, "--arch")
    table = list(variants_for(arch))
    names = table if variants is None else [choice(v.strip(), table, "--variants") for v in variants.split(",")]
    positive(time_budget_s, "--time-budget-s", "s", "a training time per variant")
    if width is not None:
        at_least(width, 1, "--width", "channels", "a width")
    at_least(crop, 16, "--crop", "px", "a training crop")
    check_device(device)
    input_folder(dataset, what="pairs folder")
    output_folder(output)
    with StageBars(show=not quiet and not json_out) as bars:
        summary = run_ablation(
            dataset,
            output,
            time_budget_s,
            width,
            crop,
            seed,
            names,
            bars.say,
            device=device,
            progress=bars.progress,
            arch=arch,
        )
    if json_out:
        print_json(summary)
        return
    t = Table(title=f"Ablation ({arch}), {time_budget_s:g} s per variant, held-out photos")
    for c in ("variant", "params", "PSNR dB", "SSIM", "centre", "middle", "edge"):
        t.add_column(c, justify="left" if c == "variant" else "right")
    rows = [("input", None, summary["input"])] + [
        (k, v["params"], v["metrics"]) for k, v in summary["variants"].items()
    ]
    for name, params, m in rows:
        z = m["zones"]
        t.add_row(
            name,
            "" if params is None else f"{params:,}",
            format_score(m["psnr_db"], 2),
            format_score(m["ssim"], 3),
            *(format_score(z[zone]["psnr_db"], 2) for zone in ZONES),
        )
    console.print(t)
