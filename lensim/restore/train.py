"""Training of a restoration network (TrainConfig.arch: NAFNet by default, or the paper's
field-aware UNet) on a pairs folder.

Recipe (the paper follows Chang et al. 2020): Adam, MSE loss (``loss``: or a Charbonnier
loss with an edge term, lensim.restore.losses), learning rate ``lr`` halved
every ``lr_halve_every`` epochs (paper: 1e-4 halved every 5 of 30 epochs; ``lr_schedule=
"step"``) or annealed to zero along a half cosine over the run (``"cosine"``: over the
time budget when one is set, else over the epochs; the better choice for a fixed
wall-clock budget, where a step schedule decays too early or too late), random
``crop`` x ``crop`` sub-crops with FOV-consistent dihedral augmentation, validation PSNR
(dB) and SSIM on whole held-out crops after every epoch. The validation photos are chosen
by source photo (lensim.restore.dataset.split_sources) and recorded in RUN/split.json and
in every checkpoint.

Run folder:
    RUN/config.json, split.json, log.csv, steps.csv, tb/   lensim.restore.run_log. log.csv
                      has one row per epoch (and one when stopped early): epoch (epochs
                      completed), step (optimizer steps done), loss (mean training loss
                      of the epoch's steps in this call), val_psnr (dB), val_ssim, lr
                      (used during the epoch), seconds (since this call started)
    RUN/last.pt       latest checkpoint (every epoch, when stopped, and within an epoch
                      every TrainConfig.checkpoint_every_s seconds / _steps steps)
    RUN/best.pt       checkpoint with the best validation PSNR so far
Checkpoints (format, atomic writes, resume): lensim.restore.checkpoint. Learning-rate
schedules and the time budget's clock: lensim.restore.schedule. NaN or Inf (a poisoned
batch, an exploding learning rate): detected at the step, never checkpointed, rolled back
or stopped by TrainConfig.on_nan (lensim.restore.divergence).

Determinism and resume: the data order of epoch e is a permutation drawn from (seed, e)
and each item's random draws from (seed, e, index) (lensim.restore.dataset), so a run
resumed from any checkpoint, even one written mid-epoch by the time budget, continues the
very same sequence of batches; with model, optimizer and scheduler state restored the loss
curve on CPU is bit-for-bit that of an uninterrupted run (same thread count).

Devices: "cpu", "cuda" (bfloat16 autocast where supported, else float16 with a grad scaler); multi-GPU:
``torchrun --nproc_per_node N`` (lensim.restore.distributed). TrainConfig.init: start from those weights.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader

from lensim.data.manifest import read_pairs_manifest
from lensim.errors import InputError
from lensim.restore.batches import INPUT_METRICS, collate, epoch_batches, epoch_order, evaluate_pairs, model_inputs
from lensim.restore.checkpoint import (
    BEST,
    LAST,
    TrainingState,
    read_resume_checkpoint,
    refuse_existing_run,
    run_folder,
)
from lensim.restore.conditioning import Conditioning
from lensim.restore.config import TrainConfig
from lensim.restore.dataset import PairDataset, crop_refs, sensor_hw, split_sources
from lensim.restore.distributed import (
    Ranks,
    barrier,
    checked_device,
    init_distributed,
    mean_over_ranks,
    mixed_precision,
    rank0_decides,
    shutdown,
    wrap_model,
)
from lensim.restore.divergence import NonFinite, Rollbacks, check_loss, roll_back
from lensim.restore.losses import restoration_loss
from lensim.restore.models import build_model
from lensim.restore.psf_stage import training_cache
from lensim.restore.run_config import FROZEN_ON_RESUME, resolve_config, saved_config
from lensim.restore.run_log import RunLog
from lensim.restore.schedule import BudgetClock, LearningRate
from lensim.restore.universal import load_init


@dataclass
class TrainProgress:
    """What a progress callback receives. kind: "step" after each optimizer step,
    "epoch" after each validation, "stop" when the time budget ends the run."""

    kind: str
    epoch: int  # 0-based epoch being trained (for "epoch": the one just finished)
    epochs: int
    step: int  # global optimizer steps done
    batch: int  # batches done in this epoch
    batches: int  # batches per epoch
    loss: float
    lr: float
    seconds: float  # since this call started
    val_psnr: float | None = None
    val_ssim: float | None = None


@dataclass
class TrainResult:
    """Summary of a train() call."""

    run_dir: str
    epochs_done: int
    step: int
    stopped_early: bool
    seconds: float
    last_loss: float
    val_psnr: float | None
    val_ssim: float | None
    val_input_psnr: float | None
    best_val_psnr: float | None
    history: list[dict[str, Any]] = field(default_factory=list)
    conditioning: dict[str, Any] | None = None  # TrainConfig.conditioning of the run


def budget_progress(
    report: Callable[[float, float], None] | None, budget_s: float
) -> Callable[[TrainProgress], None] | None:
    """A train() progress callback that passes (seconds trained in this call, capped at
    budget_s; budget_s) to ``report``, for a progress bar over a time budget."""
    if report is None:
        return None
    return lambda p: report(min(p.seconds, budget_s), budget_s)


# ----------------------------------------------------------------------------- set-up


def _device(cfg: TrainConfig) -> tuple[Ranks, torch.device]:
    """This process's ranks and device (torchrun's environment; CUDA checked)."""
    ranks, name = init_distributed(cfg.device)
    return ranks, checked_device(name)


@dataclass
class _Data:
    """The datasets of a run, its split (as recorded in split.json) and the pairs manifest."""

    train: PairDataset
    val: PairDataset
    split: dict[str, Any]
    manifest: dict[str, Any]


def _load_data(dataset_dir: str | Path, cfg: TrainConfig, ckpt: dict[str, Any] | None) -> _Data:
    """Training and validation crops split by source photo (a resumed run keeps its split)."""
    manifest = read_pairs_manifest(dataset_dir)
    refs = crop_refs(dataset_dir, manifest)
    sources = sorted({r.source for r in refs})
    if ckpt is not None:
        train_src, val_src = ckpt["split"]["train"], ckpt["split"]["val"]
        missing = sorted(set(train_src + val_src) - set(sources))
        if missing:
            raise InputError(
                str(dataset_dir),
                "records",
                f"lacks source photos of the run being resumed "
                f"({', '.join(missing[:3])}); expected the dataset it was trained on",
            )
    else:
        train_src, val_src = split_sources(sources, cfg.val_fraction, cfg.seed)
    hw = sensor_hw(manifest)
    train_refs = [r for r in refs if r.source in set(train_src)]
    if cfg.conditioning is None:  # a new run: what its training records span
        cfg.conditioning = Conditioning.from_records((r.settings for r in train_refs), cfg.use_settings).to_dict()
    cond = Conditioning.from_dict(cfg.conditioning, str(dataset_dir))
    shared: dict[str, Any] = dict(
        seed=cfg.seed, conditioning=cond, wiener_dir=training_cache(dataset_dir, cfg.model_kwargs())
    )
    train_ds = PairDataset(train_refs, hw, crop=cfg.crop, augment=cfg.augment, **shared)
    val_ds = PairDataset([r for r in refs if r.source in set(val_src)], hw, crop=None, augment=False, **shared)
    if len(train_ds) < 1:
        raise InputError(str(dataset_dir), "records", "has no training crops; expected at least one")
    split = {"train": list(train_src), "val": list(val_src), "val_fraction": cfg.val_fraction, "seed": cfg.seed}
    return _Data(train_ds, val_ds, split, manifest)


def _build_state(
    cfg: TrainConfig, device: torch.device, ckpt: dict[str, Any] | None, source: str
) -> tuple[TrainingState, LearningRate, torch.dtype | None]:
    """Model (seeded), Adam, learning-rate schedule, grad scaler and position, restored from
    ``ckpt`` when resuming; the autocast dtype (None: full precision)."""
    torch.manual_seed(cfg.seed)
    try:
        model = build_model(cfg.model_kwargs()).to(device)
    except (TypeError, ValueError) as e:
        raise InputError(None, "config", f"cannot build the {cfg.arch} network ({e})") from None
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    lr = LearningRate(optimizer, cfg.lr_schedule, cfg.lr, cfg.lr_halve_every, cfg.epochs)
    autocast, scaler = mixed_precision(device, cfg.amp)
    state = TrainingState(model, optimizer, lr.scheduler, scaler)
    if ckpt is not None:
        state.resume_from(ckpt, source)
    elif cfg.init:
        load_init(model, cfg.init)
    return state, lr, autocast


# ----------------------------------------------------------------------------- the loop


@dataclass
class _Loop:
    """Everything the epochs of one train() call share."""

    cfg: TrainConfig
    state: TrainingState
    lr: LearningRate
    net: torch.nn.Module  # the model, or its DistributedDataParallel wrapper
    autocast: torch.dtype | None
    ranks: Ranks
    device: torch.device
    data: _Data
    val_loader: DataLoader
    log: RunLog | None  # rank 0 only
    clock: BudgetClock
    progress: Callable[[TrainProgress], None] | None
    run: Path
    context: dict[str, Any]  # what checkpoints record besides the training state
    rollbacks: Rollbacks
    last_loss: float = math.nan
    checkpoint_s: float = 0.0  # clock.call_s() at the last checkpoint
    checkpoint_step: int = 0  # the optimizer step of the last checkpoint
    val_metrics: dict[str, float] = field(default_factory=dict)  # of the last validation
    input_metrics: dict[str, float] | None = None  # the validation inputs' own, from the first validation

    def evaluate(self) -> dict[str, float]:
        """evaluate_pairs of the model on the validation crops (their input metrics computed
        once per call of train())."""
        metrics = evaluate_pairs(self.state.model, self.val_loader, self.device, self.input_metrics)
        self.input_metrics = {k: metrics[k] for k in INPUT_METRICS}
        return metrics


def _checkpoint_due(loop: _Loop) -> bool:
    """Whether TrainConfig.checkpoint_every_s / _steps ask for a checkpoint now (rank 0)."""
    cfg = loop.cfg
    steps = cfg.checkpoint_every_steps
    every_s = cfg.checkpoint_every_s
    return bool(
        (steps and loop.state.step - loop.checkpoint_step >= steps)
        or (every_s and loop.clock.call_s() - loop.checkpoint_s >= every_s)
    )


def _save_checkpoint(loop: _Loop, best: bool) -> None:
    """Write RUN/last.pt (and RUN/best.pt when ``best``) with the last validation's figures."""
    metrics = loop.val_metrics
    loop.state.save(
        loop.run,
        loop.clock.run_s(),
        {**loop.context, "val_psnr": metrics.get("psnr"), "val_ssim": metrics.get("ssim")},
        best=best,
    )
    loop.checkpoint_s, loop.checkpoint_step = loop.clock.call_s(), loop.state.step
    loop.rollbacks.checkpoint_written(loop.state.step)


def _optimizer_step(loop: _Loop, batch: dict[str, torch.Tensor]) -> float:
    """One Adam step on the training loss (TrainConfig.loss) of a batch (autocast on CUDA); the loss, averaged over ranks."""
    device, state = loop.device, loop.state
    args = model_inputs(batch, device)
    tgt = batch["target"].to(device, non_blocking=True)
    state.optimizer.zero_grad(set_to_none=True)
    if loop.autocast is not None:
        with torch.autocast(device_type="cuda", dtype=loop.autocast):
            out = loop.net(*args)
        loss = restoration_loss(loop.cfg.loss, out.float(), tgt)
    else:
        loss = restoration_loss(loop.cfg.loss, loop.net(*args), tgt)
    ranks = loop.ranks
    check_loss(loss, (lambda bad: mean_over_ranks(float(bad), ranks, device) > 0) if ranks.world > 1 else None)
    state.scaler.scale(loss).backward()
    state.scaler.step(state.optimizer)
    state.scaler.update()
    return mean_over_ranks(float(loss.detach()), loop.ranks, device)


def _train_epoch(loop: _Loop, batches: list[list[int]]) -> tuple[bool, float]:
    """The epoch's remaining batches, or until the time budget is spent; (whether the budget
    stopped the epoch, mean loss of its steps in this call)."""
    cfg, state = loop.cfg, loop.state
    loop.data.train.set_epoch(state.epoch)
    todo = [b for b in range(state.batch_in_epoch, len(batches)) if (state.epoch, b) not in state.skipped]
    loader = DataLoader(loop.data.train, batch_sampler=[batches[b] for b in todo], collate_fn=collate)
    losses: list[float] = []
    for b, batch in zip(todo, loader, strict=True):
        state.batch_in_epoch = b  # past the batches skipped after a non-finite loss
        loop.lr.before_step(loop.clock, state.epoch, state.batch_in_epoch, len(batches))
        loop.last_loss = _optimizer_step(loop, batch)
        state.step += 1
        state.batch_in_epoch += 1
        losses.append(loop.last_loss)
        seconds = loop.clock.call_s()
        if loop.log is not None:
            loop.log.step(state.epoch, state.step, loop.last_loss, loop.lr.lr, seconds)
        if loop.progress is not None and loop.ranks.main:
            loop.progress(
                TrainProgress(
                    "step",
                    state.epoch,
                    cfg.epochs,
                    state.step,
                    state.batch_in_epoch,
                    len(batches),
                    loop.last_loss,
                    loop.lr.lr,
                    seconds,
                )
            )
        if loop.ranks.main and state.batch_in_epoch < len(batches) and _checkpoint_due(loop):
            _save_checkpoint(loop, best=False)  # within the epoch: a kill loses at most the interval
        if rank0_decides(loop.clock.spent(), loop.ranks, loop.device) and state.batch_in_epoch < len(batches):
            return True, sum(losses) / len(losses)
    return False, sum(losses) / len(losses) if losses else loop.last_loss


def _validate(loop: _Loop, mean_loss: float, epoch_lr: float) -> tuple[dict[str, Any], dict[str, float]]:
    """Rank 0 after an epoch (or a budget stop): validation metrics, a log row, last.pt and,
    when validation PSNR improved (or there is none yet), best.pt. Returns (the log row,
    the metrics of evaluate_pairs; empty without validation photos)."""
    state = loop.state
    metrics = loop.evaluate() if len(loop.data.val) else {}
    vp, vs = metrics.get("psnr", math.nan), metrics.get("ssim", math.nan)
    row = {
        "epoch": state.epoch,
        "step": state.step,
        "loss": mean_loss,
        "val_psnr": vp,
        "val_ssim": vs,
        "lr": epoch_lr,
        "seconds": loop.clock.call_s(),
    }
    assert loop.log is not None
    loop.log.epoch(row)
    improved = math.isfinite(vp) and vp > state.best_val_psnr
    if improved:
        state.best_val_psnr = vp
    loop.val_metrics = metrics
    _save_checkpoint(loop, best=improved or not (loop.run / BEST).exists())
    return row, metrics


def _validate_start(loop: _Loop) -> None:
    """A run started from other weights (TrainConfig.init): validate them before the first
    step and write them as best.pt, so that best.pt is never worse on the validation photos
    than where the run started (a short fine-tuning whose first steps lose ground keeps the
    starting weights)."""
    state = loop.state
    loop.val_metrics = loop.evaluate()
    vp = loop.val_metrics.get("psnr", math.nan)
    if math.isfinite(vp):
        state.best_val_psnr = vp
    _save_checkpoint(loop, best=True)


def _epoch(loop: _Loop, batches: list[list[int]]) -> tuple[bool, dict[str, Any] | None, dict[str, float]]:
    """Train the epoch's remaining batches (_train_epoch), then on rank 0 validate and
    checkpoint (_validate) and report progress; (whether the time budget stopped it, the
    log row or None off rank 0, the validation metrics)."""
    state, cfg = loop.state, loop.cfg
    epoch_lr = loop.lr.lr
    stopped, mean_loss = _train_epoch(loop, batches)
    if not stopped:
        state.epoch += 1
        state.batch_in_epoch = 0
        loop.lr.after_epoch()
    if not loop.ranks.main:
        return stopped, None, {}
    row, metrics = _validate(loop, mean_loss, epoch_lr)
    if loop.progress is not None:
        loop.progress(
            TrainProgress(
                "stop" if stopped else "epoch",
                state.epoch - (0 if stopped else 1),
                cfg.epochs,
                state.step,
                state.batch_in_epoch,
                len(batches),
                mean_loss,
                epoch_lr,
                loop.clock.call_s(),
                metrics.get("psnr"),
                metrics.get("ssim"),
            )
        )
    return stopped, row, metrics


# ----------------------------------------------------------------------------- train


def train(
    dataset_dir: str | Path,
    run_dir: str | Path,
    config: TrainConfig | None = None,
    resume: bool = False,
    progress: Callable[[TrainProgress], None] | None = None,
    **overrides: Any,
) -> TrainResult:
    """Train (or, with ``resume``, continue training) a restoration network (TrainConfig.arch)
    on a pairs folder.

    Args:
        dataset_dir: folder written by ``lensim dataset make`` (manifest.json + crops).
        run_dir: output folder (created); must not hold a run unless ``resume``.
        config: settings (TrainConfig); keyword ``overrides`` replace single fields, e.g.
            ``train(ds, run, epochs=2, width=8)``.
        resume: continue from RUN/last.pt with the settings stored there (``config`` is
            not used): ``overrides`` may change epochs, time_budget_s, device, amp,
            val_batch_size and the checkpoint intervals; a differing value of one listed in
            FROZEN_ON_RESUME is an InputError.
        progress: called with a TrainProgress after every step and every validation.
        The run folder is locked while training, and removed if new and failed before its
        first checkpoint (lensim.restore.checkpoint.run_folder).

    Returns:
        TrainResult (final and best validation metrics, steps, whether the time budget
        stopped the run, and the per-epoch history rows).
    """
    run = Path(run_dir)
    writer = int(os.environ.get("RANK", "0")) == 0  # rank 0 writes the run folder (torchrun)
    with run_folder(run, writer):
        return _train(dataset_dir, run, config, resume, progress, overrides)


def _train(
    dataset_dir: str | Path,
    run: Path,
    config: TrainConfig | None,
    resume: bool,
    progress: Callable[[TrainProgress], None] | None,
    overrides: dict[str, Any],
) -> TrainResult:
    """train() with the run folder locked."""
    ckpt = read_resume_checkpoint(run) if resume else None
    if ckpt is None:
        refuse_existing_run(run)
    cfg = resolve_config(config, overrides, ckpt, str(run / LAST))
    ranks, device = _device(cfg)
    data = _load_data(dataset_dir, cfg, ckpt)  # sets cfg.conditioning for a new run
    state, lr, autocast = _build_state(cfg, device, ckpt, str(run / LAST))
    net = wrap_model(state.model, ranks, device)
    manifest = data.manifest
    context = {
        "train_config": asdict(cfg),
        "split": data.split,
        "conditioning": cfg.conditioning,
        "lens": manifest.get("lens"),
        "sensor": manifest.get("sensor"),
        "sensor_name": manifest.get("sensor_name"),
        "dataset": str(Path(dataset_dir).resolve()),
    }
    log = None
    if ranks.main:
        log = RunLog(
            run, {**asdict(cfg), "dataset": context["dataset"]}, data.split, state.step if ckpt is not None else None
        )
    val_loader = DataLoader(data.val, batch_size=cfg.val_batch_size, shuffle=False, collate_fn=collate)
    loop = _Loop(
        cfg,
        state,
        lr,
        net,
        autocast,
        ranks,
        device,
        data,
        val_loader,
        log,
        BudgetClock(cfg.time_budget_s, state.train_seconds),
        progress,
        run,
        context,
        Rollbacks.start(run, state.checkpoint(state.train_seconds, context) if ranks.main else None),
        checkpoint_step=state.step,
    )
    history: list[dict[str, Any]] = []
    metrics: dict[str, float] = {}
    stopped = False
    if ckpt is None and cfg.init and ranks.main and len(data.val):
        _validate_start(loop)
    state.model.train()
    while state.epoch < cfg.epochs and not stopped:
        batches = epoch_batches(
            len(data.train), cfg.batch_size, cfg.seed, state.epoch, ranks.rank, ranks.world, cfg.max_steps_per_epoch
        )
        try:
            stopped, row, metrics = _epoch(loop, batches)
        except NonFinite as bad:
            roll_back(loop, bad, len(batches), history)
            continue
        if row is not None:
            history.append(row)
        barrier(ranks)
        stopped = stopped or (loop.clock.spent() and state.epoch < cfg.epochs)
    if log is not None:
        log.close()
    shutdown(ranks)
    best = state.best_val_psnr
    return TrainResult(
        str(run),
        state.epoch,
        state.step,
        stopped,
        loop.clock.call_s(),
        loop.last_loss,
        metrics.get("psnr"),
        metrics.get("ssim"),
        metrics.get("input_psnr"),
        best if math.isfinite(best) else None,
        history,
        cfg.conditioning,
    )


__all__ = [
    "FROZEN_ON_RESUME",
    "TrainConfig",
    "TrainProgress",
    "TrainResult",
    "budget_progress",
    "epoch_batches",
    "epoch_order",
    "evaluate_pairs",
    "model_inputs",
    "saved_config",
    "train",
]
