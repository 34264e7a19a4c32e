"""`lensim train`: train a restoration network on a pairs folder (by default NAFNet with
FOV input channels and a 2x pixel-unshuffle stem; --arch unet: the paper's field-aware UNet).

Every default comes from lensim.restore.config.TrainConfig (the one place that sets them;
the architecture's own, ARCH_DEFAULTS, where an option is left unset); torch and the
training modules load when the command runs.

Register in lensim/cli/__init__.py with
    app.command("train")(train_command)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from lensim.cli.common import console, print_json
from lensim.cli.validate import at_least, choice, in_range, input_folder, output_folder, positive
from lensim.cli.validate import device as check_device
from lensim.errors import InputError
from lensim.restore.config import TrainConfig

if TYPE_CHECKING:
    from lensim.restore.train import TrainProgress, TrainResult

_D = TrainConfig()


def train_command(
    ctx: typer.Context,
    dataset: Path = typer.Argument(..., help="Pairs folder from `lensim dataset make`."),
    output: Path = typer.Option(..., "-o", "--output", help="Run folder (checkpoints, logs)."),
    epochs: int = typer.Option(_D.epochs, "--epochs", help="Epochs in total (paper: 30)."),
    batch_size: int = typer.Option(_D.batch_size, "--batch-size", help="Crops per step (per GPU under torchrun)."),
    lr: float = typer.Option(_D.lr, "--lr", help="Initial Adam learning rate (paper: 1e-4)."),
    lr_halve_every: int = typer.Option(
        _D.lr_halve_every, "--lr-halve-every", help="Halve the learning rate every N epochs (paper: 5)."
    ),
    lr_schedule: str = typer.Option(
        _D.lr_schedule,
        "--lr-schedule",
        help="step (halve every --lr-halve-every "
        "epochs) or cosine (anneal to 0 over the time budget, else over the epochs).",
    ),
    loss: str = typer.Option(
        _D.loss,
        "--loss",
        help="mse (the paper's), charbonnier, or charbonnier-edge "
        "(Charbonnier plus an edge term that does not reward over-smoothing).",
    ),
    crop: int = typer.Option(_D.crop or 0, "--crop", help="Training sub-crop size in pixels (0: the stored crops)."),
    arch: str = typer.Option(
        _D.arch,
        "--arch",
        help="Network: nafnet (the default: NAFNet blocks with FOV input "
        "channels and a 2x pixel-unshuffle stem, no deformable convolution, no context block) "
        "unet (the paper's field-aware UNet: FOV input, deformable decoder, context block) "
        "or psfnet (the PSF-informed network: the nafnet body refining the Wiener deconvolution "
        "with the pairs' PSF bank, computed once per crop into DATASET/wiener/).",
    ),
    width: int = typer.Option(
        _D.width,
        "--width",
        help="Channels at the first scale, doubled at each further one (0: "
        "the architecture's default: unet 32, nafnet the width of about the same parameter "
        "count).",
    ),
    stem: int = typer.Option(
        _D.stem,
        "--stem",
        help="2 for a pixel-unshuffle stem (every layer at half resolution, "
        "about 4x faster; nafnet only), 1 for none; 0: the architecture's default (nafnet 2, "
        "unet 1).",
    ),
    depth: int = typer.Option(_D.depth, "--depth", help="Number of scales."),
    deformable_groups: int = typer.Option(
        _D.deformable_groups, "--deformable-groups", help="Offset groups of each deformable conv."
    ),
    deformable_scales: int = typer.Option(
        -1 if _D.deformable_scales is None else _D.deformable_scales,
        "--deformable-scales",
        help="Decoder scales, coarsest first, with "
        "deformable blocks (-1: all, the paper; 1 trains about 2x faster on a CPU).",
    ),
    field_modulation: bool = typer.Option(
        _D.field_modulation,
        "--field-modulation",
        help="Scale and shift the "
        "features by functions of the sensor position at every decoder scale "
        "(lensim's extension of the paper's FOV input).",
    ),
    no_fov: bool = typer.Option(not _D.use_fov, "--no-fov", help="Ablation: no field-of-view input channels."),
    deformable: bool | None = typer.Option(
        _D.use_deformable,
        "--deformable/--no-deformable",
        show_default=False,
        help="Deformable decoder blocks, or plain residual ones (default: the "
        "architecture's: on for unet, off for nafnet).",
    ),
    context: bool | None = typer.Option(
        _D.use_context,
        "--context/--no-context",
        show_default=False,
        help="The context block (default: the architecture's: on for unet, off for nafnet).",
    ),
    no_settings: bool = typer.Option(
        not _D.use_settings,
        "--no-settings",
        help="Pairs made across shooting settings: "
        "train without the settings as inputs (an unconditioned network; the ranges are "
        "still recorded and checked when restoring).",
    ),
    val_fraction: float = typer.Option(
        _D.val_fraction, "--val-fraction", help="Share of source photos held out for validation."
    ),
    steps_per_epoch: int = typer.Option(
        _D.max_steps_per_epoch or 0, "--steps-per-epoch", help="Cap on steps per epoch (0: whole epochs)."
    ),
    time_budget_s: float = typer.Option(
        _D.time_budget_s or 0.0,
        "--time-budget-s",
        help="Stop cleanly once the run has trained this many seconds in all, resumes included (0: none).",
    ),
    checkpoint_every_s: float = typer.Option(
        _D.checkpoint_every_s or 0.0,
        "--checkpoint-every-s",
        help="Also write last.pt within an epoch every N seconds of training (0: at epoch ends only).",
    ),
    checkpoint_every_steps: int = typer.Option(
        _D.checkpoint_every_steps or 0,
        "--checkpoint-every-steps",
        help="Also write last.pt every N optimizer steps (0: off).",
    ),
    resume: bool = typer.Option(
        False,
        "--resume",
        help="Continue the run in OUTPUT from last.pt with its stored "
        "settings; options given change those that may change (--epochs, --time-budget-s, "
        "--device, --no-amp, checkpoint intervals), others must match.",
    ),
    on_nan: str = typer.Option(
        _D.on_nan,
        "--on-nan",
        help="A NaN or infinite loss: rollback (to the last good checkpoint, skipping the "
        "batch; stops after 3 in a row) or stop (one line naming the step).",
    ),
    seed: int = typer.Option(_D.seed, "--seed", help="Seed of initialisation, data order, crops and augmentation."),
    init: str = typer.Option(
        None,
        "--init",
        help="Start from these weights instead of a random initialisation: 'universal' (the shipped "
        "universal model; fine-tuning) or a run folder / checkpoint. The run builds their network "
        "(architecture, width, stem, FOV, deformable and context switches) where no option says otherwise.",
    ),
    device: str = typer.Option(_D.device, "--device", help="cpu, cuda or cuda:N (mixed precision on CUDA)."),
    no_amp: bool = typer.Option(not _D.amp, "--no-amp", help="Full float32 on CUDA."),
    threads: int = typer.Option(0, "--threads", help="CPU threads for PyTorch (0: PyTorch's default)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON (no progress output)."),
) -> None:
    """Train a restoration network: NAFNet with FOV input and a 2x stem (default) or the paper's field-aware UNet
    (--arch unet). Adam, MSE or --loss, halving learning rate, FOV-consistent augmentation, validation PSNR/SSIM
    per epoch; RUN/log.csv, steps.csv, last.pt, best.pt.
    Multi-GPU: torchrun --nproc_per_node N -m lensim train ... --device cuda

    Example: lensim train data/ -o runs/a --epochs 30 --crop 128 --time-budget-s 1800
    """
    import torch

    from lensim.restore.divergence import ON_NAN
    from lensim.restore.losses import LOSSES
    from lensim.restore.train import train

    _check_recipe(epochs, batch_size, lr, lr_halve_every, lr_schedule, val_fraction, steps_per_epoch, time_budget_s)
    # a resumed run has its own architecture: the rules that depend on it are left to the run's (frozen) settings
    _check_network(
        arch if not resume or _given(ctx, "arch") else None,
        width,
        depth,
        deformable_groups,
        deformable_scales,
        field_modulation,
        no_fov,
        stem,
        deformable,
    )
    choice(loss, tuple(LOSSES), "--loss")
    choice(on_nan, ON_NAN, "--on-nan")
    at_least(threads, 0, "--threads", what="a number of threads (0: PyTorch's default)")
    at_least(checkpoint_every_s, 0.0, "--checkpoint-every-s", "s", "an interval (0: at epoch ends only)")
    at_least(checkpoint_every_steps, 0, "--checkpoint-every-steps", what="a number of steps (0: off)")
    check_device(device)
    input_folder(dataset, what="pairs folder")
    output_folder(output)
    if not resume or _given(ctx, "crop"):  # a resumed run has its own crop
        _check_crop(dataset, crop)
    if threads > 0:
        torch.set_num_threads(threads)
    overrides: dict[str, Any] = {
        "epochs": epochs,
        "batch_size": batch_size,
        "lr": lr,
        "lr_halve_every": lr_halve_every,
        "lr_schedule": lr_schedule,
        "loss": loss,
        "crop": crop or None,
        "arch": arch,
        "width": width,
        "depth": depth,
        "stem": stem,
        "deformable_groups": deformable_groups,
        "deformable_scales": None if deformable_scales < 0 else deformable_scales,
        "use_fov": not no_fov,
        "field_modulation": field_modulation,
        "use_deformable": deformable,
        "use_context": context,
        "val_fraction": val_fraction,
        "max_steps_per_epoch": steps_per_epoch or None,
        "time_budget_s": time_budget_s if time_budget_s > 0 else None,
        "seed": seed,
        "device": device,
        "amp": not no_amp,
        "checkpoint_every_s": checkpoint_every_s if checkpoint_every_s > 0 else None,
        "checkpoint_every_steps": checkpoint_every_steps or None,
        "use_settings": not no_settings,
        "on_nan": on_nan,
        "init": _check_init(init),
    }
    if resume:  # the checkpoint's settings, changed only where an option is given
        overrides = {k: v for k, v in overrides.items() if _given(ctx, _OPTION_OF.get(k, k))}
    elif init is not None:  # the network of the weights it starts from, where no option says otherwise
        from lensim.restore.universal import init_network

        given = init_network(init)
        overrides.update({k: v for k, v in given.items() if not _given(ctx, _OPTION_OF.get(k, k))})
    prog, callback = _progress(epochs, show=not quiet and not json_out)
    try:  # a new run that fails before its first checkpoint leaves no folder (train removes it)
        result = _train(train, dataset, output, resume, callback, overrides)
    finally:
        if prog is not None:
            prog.stop()
    _report(result, quiet, json_out)


def _check_init(init: str | None) -> str | None:
    """--init: 'universal' (the shipped model must be there) or an existing run or checkpoint."""
    if init is None:
        return None
    from lensim.restore.universal import NAME, model_path

    if init == NAME:
        model_path(NAME)
    elif not Path(init).exists():
        raise InputError("--init", None, f"no such run folder or checkpoint {init!r}; expected 'universal' or a path")
    return init


def _train(
    train: Callable[..., TrainResult], dataset: Path, output: Path, resume: bool, callback, overrides
) -> TrainResult:
    """lensim.restore.train.train with a divergence's line naming the options that help."""
    from lensim.errors import NonFiniteError

    try:
        return train(dataset, output, TrainConfig(), resume=resume, progress=callback, **overrides)
    except NonFiniteError as e:
        skip = "" if "rollbacks" in e.message else " (or --on-nan rollback to skip a bad batch)"
        raise NonFiniteError(
            e.source,
            e.field,
            f"{e.message}; expected a finite loss: give a lower --lr{skip}, then train again with --resume",
        ) from None


def _check_recipe(
    epochs: int,
    batch_size: int,
    lr: float,
    lr_halve_every: int,
    lr_schedule: str,
    val_fraction: float,
    steps_per_epoch: int,
    time_budget_s: float,
) -> None:
    """The training recipe's options, before any work (one-line errors naming the option)."""
    from lensim.restore.schedule import LR_SCHEDULES

    at_least(epochs, 1, "--epochs", what="a number of epochs")
    at_least(batch_size, 1, "--batch-size", what="a number of crops per step")
    positive(lr, "--lr", what="a learning rate")
    at_least(lr_halve_every, 1, "--lr-halve-every", what="a number of epochs")
    choice(lr_schedule, LR_SCHEDULES, "--lr-schedule")
    in_range(val_fraction, 0.0, 1.0, "--val-fraction", what="a share of the photos", high_open=True)
    at_least(steps_per_epoch, 0, "--steps-per-epoch", what="a number of steps (0: whole epochs)")
    at_least(time_budget_s, 0.0, "--time-budget-s", "s", "a time budget (0: none)")


def _check_network(
    arch: str | None,
    width: int,
    depth: int,
    groups: int,
    deformable_scales: int,
    field_modulation: bool,
    no_fov: bool,
    stem: int,
    deformable: bool | None = None,
) -> None:
    """The network's options (their ranges, then lensim.restore.arch_rules: which
    architecture takes which switches), before any work. ``deformable`` None: the
    architecture's default (lensim.restore.arch_rules.ARCH_DEFAULTS). ``arch`` None (a resumed run whose
    --arch is not given): the rules that depend on the architecture are skipped; the run's
    stored settings hold, and a differing network option is refused by train()."""
    from lensim.restore.arch_rules import ARCHS

    if arch is not None:
        choice(arch, ARCHS, "--arch")
    at_least(width, 0, "--width", "channels", "a width (0: the architecture's default)")
    at_least(depth, 2, "--depth", "scales", "a depth")
    in_range(deformable_scales, -1, depth - 1, "--deformable-scales", what="a number of decoder scales (-1: all)")
    choice(stem, (0, 1, 2), "--stem")
    _check_arch_rules(arch, width, depth, groups, deformable_scales, field_modulation, no_fov, stem, deformable)


#: the option of each network parameter lensim.restore.arch_rules names
_NETWORK_OPTIONS = {
    "arch": "--arch",
    "deformable_groups": "--deformable-groups",
    "deformable_scales": "--deformable-scales",
    "field_modulation": "--field-modulation",
    "stem": "--stem",
}


def _check_arch_rules(
    arch: str | None,
    width: int,
    depth: int,
    groups: int,
    deformable_scales: int,
    field_modulation: bool,
    no_fov: bool,
    stem: int,
    deformable: bool | None,
) -> None:
    """Which architecture takes which switches (lensim.restore.arch_rules), the options'
    sentinels resolved (width 0: not chosen yet; --deformable-scales -1: all; --stem 0 and
    --deformable/--no-deformable unset: the architecture's default); an error names the
    option."""
    from lensim.restore.arch_rules import ARCH_DEFAULTS, check_switches

    defaults = ARCH_DEFAULTS.get(arch or "", {"use_deformable": False, "stem": 1})
    try:
        check_switches(
            arch,
            use_fov=not no_fov,
            use_deformable=bool(defaults["use_deformable"] if deformable is None else deformable),
            deformable_groups=groups,
            deformable_scales=None if deformable_scales < 0 else deformable_scales,
            field_modulation=field_modulation,
            stem=stem or defaults["stem"],
            widths=tuple(width * 2**s for s in range(depth)) if width else None,
        )
    except InputError as e:
        if e.source is not None or e.field not in _NETWORK_OPTIONS:
            raise
        raise InputError(_NETWORK_OPTIONS[e.field], None, e.message) from None


def _check_crop(dataset: Path, crop: int) -> None:
    """--crop: 0 (the stored crops) or at most the dataset's crop size."""
    at_least(crop, 0, "--crop", "px", "a crop size (0: the stored crops)")
    if crop:
        from lensim.data.manifest import read_pairs_manifest

        stored = read_pairs_manifest(dataset).get("size")
        if isinstance(stored, int) and crop > stored:
            raise InputError("--crop", None, f"expected at most the dataset's crop size {stored} px, got {crop} px")


# TrainConfig fields whose option's parameter has another name
_OPTION_OF = {
    "use_fov": "no_fov",
    "use_deformable": "deformable",
    "use_context": "context",
    "max_steps_per_epoch": "steps_per_epoch",
    "amp": "no_amp",
    "use_settings": "no_settings",
}


def _given(ctx: typer.Context, parameter: str) -> bool:
    """Whether the user gave the option of ``parameter`` (not left at its default). By the
    source's name: typer may bring its own copy of click's ParameterSource."""
    source = ctx.get_parameter_source(parameter)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


def _progress(epochs: int, show: bool) -> tuple[Any, Callable[[TrainProgress], None] | None]:
    """A started rich progress bar over an epoch's steps and its train() callback (a line
    per validation); (None, None) when not shown."""
    if not show:
        return None, None
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(
        TextColumn("epoch {task.fields[epoch]}/{task.fields[epochs]}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} steps"),
        TextColumn("loss {task.fields[loss]}"),
        TextColumn("{task.fields[val]}"),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    )
    task = prog.add_task("train", total=None, epoch=0, epochs=epochs, loss="-", val="")

    def callback(p: TrainProgress) -> None:
        if p.kind == "step":
            prog.update(
                task, completed=p.batch, total=p.batches, epoch=p.epoch + 1, epochs=p.epochs, loss=f"{p.loss:.3e}"
            )
            return
        val = "" if p.val_psnr is None or math.isnan(p.val_psnr) else f"val {p.val_psnr:.2f} dB / SSIM {p.val_ssim:.4f}"
        prog.update(task, val=val)
        console.print(
            f"epoch {p.epoch + 1}/{p.epochs} step {p.step}: loss {p.loss:.4e}"
            + (f", {val}" if val else "")
            + (" (time budget reached)" if p.kind == "stop" else ""),
            highlight=False,
        )

    prog.start()
    return prog, callback


def _report(result: TrainResult, quiet: bool, json_out: bool) -> None:
    """Print the run's summary: JSON, one line, or nothing."""
    summary = {
        "run": result.run_dir,
        "epochs_done": result.epochs_done,
        "steps": result.step,
        "stopped_early": result.stopped_early,
        "seconds": result.seconds,
        "val_psnr_db": result.val_psnr,
        "val_ssim": result.val_ssim,
        "val_input_psnr_db": result.val_input_psnr,
        "best_val_psnr_db": result.best_val_psnr,
        "conditioning": result.conditioning,
    }
    if json_out:
        print_json(summary)
    elif not quiet:
        vp = "n/a" if result.val_psnr is None else f"{result.val_psnr:.2f} dB (input {result.val_input_psnr:.2f} dB)"
        console.print(
            f"trained {result.step} steps in {result.seconds:.0f} s; validation PSNR {vp}; "
            f"checkpoints in {result.run_dir}",
            highlight=False,
        )
        from lensim.restore.conditioning import Conditioning

        cond = Conditioning.from_dict(result.conditioning)
        if cond.dim:
            console.print(
                f"conditioned on {', '.join(cond.keys)} ({cond.describe()}): restore needs the photos' "
                "settings (a raw's EXIF or --fno/--focus-m/--focal-mm)",
                highlight=False,
            )


__all__ = ["train_command"]
