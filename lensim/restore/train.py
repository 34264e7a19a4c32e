"""Training of the field-aware restoration network on a pairs folder.

Recipe (the paper follows Chang et al. 2020): Adam, MSE loss, learning rate ``lr`` halved
every ``lr_halve_every`` epochs (paper: 1e-4 halved every 5 of 30 epochs; ``lr_schedule=
"step"``) or annealed to zero along a half cosine over the run (``"cosine"``: over the
time budget when one is set, else over the epochs; the better choice for a fixed
wall-clock budget, where a step schedule decays too early or too late), random
``crop`` x ``crop`` sub-crops with FOV-consistent dihedral augmentation, validation PSNR
(dB) and SSIM on whole held-out crops after every epoch. The validation photos are chosen
by source photo (lensim.restore.dataset.split_sources) and recorded in RUN/split.json and
in every checkpoint.

Run folder:
    RUN/config.json   the training settings
    RUN/split.json    train/validation source photos
    RUN/log.csv       one row per epoch (and one when stopped early): epoch (epochs
                      completed), step (optimizer steps done), loss (mean training MSE
                      of the epoch's steps in this call), val_psnr (dB), val_ssim, lr
                      (used during the epoch), seconds (since this call started)
    RUN/steps.csv     one row per optimizer step: epoch, step, loss, lr, seconds
    RUN/last.pt       latest checkpoint (every epoch and when stopped)
    RUN/best.pt       checkpoint with the best validation PSNR so far
    RUN/tb/           TensorBoard events, only when torch.utils.tensorboard imports

Checkpoints (torch.save of a dict; loadable with weights_only=True) hold the model config
and state, optimizer, scheduler, grad-scaler, epoch / position in the epoch / global step,
RNG states, the training settings, the split, and the dataset's lens and sensor (from its
manifest) so inference can warn when used on another camera. They are written to a
temporary file in RUN/ and renamed (os.replace): a crash never leaves a partial file.

Determinism and resume: the data order of epoch e is a permutation drawn from (seed, e)
and each item's random draws from (seed, e, index) (lensim.restore.dataset), so a run
resumed from any checkpoint, even one written mid-epoch by the time budget, continues the
very same sequence of batches; with model, optimizer and scheduler state restored the loss
curve on CPU is bit-for-bit that of an uninterrupted run (same thread count).

Devices: "cpu" (default), "cuda" (mixed precision: bfloat16 autocast where supported, else
float16 with a gradient scaler). Multi-GPU: launch with ``torchrun --nproc_per_node N``;
when WORLD_SIZE > 1 a process group is initialised (NCCL on CUDA, Gloo on CPU), the model
is wrapped in DistributedDataParallel, each rank takes every N-th item of the epoch's
permutation, the batch size is per rank, and rank 0 alone validates and writes files.
"""
from __future__ import annotations

import csv
import json
import math
import os
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader

from lensim.errors import InputError
from lensim.io import atomic_write_text, atomic_writer
from lensim.restore.dataset import PairDataset, crop_refs, load_manifest, sensor_hw, split_sources
from lensim.restore.metrics import psnr, ssim
from lensim.restore.network import FieldAwareUNet

CHECKPOINT_FORMAT = "lensim-restore-checkpoint"
CHECKPOINT_VERSION = 1
LOG_FIELDS = ("epoch", "step", "loss", "val_psnr", "val_ssim", "lr", "seconds")
STEP_FIELDS = ("epoch", "step", "loss", "lr", "seconds")


@dataclass
class TrainConfig:
    """Training settings (all recorded in RUN/config.json and in checkpoints).

    epochs: epochs to train in total (a resumed run may raise it).
    batch_size: crops per optimizer step (per rank under DDP).
    lr: initial Adam learning rate.
    lr_schedule: "step" (halve every ``lr_halve_every`` epochs) or "cosine" (lr * (1 +
        cos(pi p)) / 2 at progress p in [0, 1]: the share of the time budget spent when
        one is set, else of the epochs; set before every step).
    crop: training sub-crop size in pixels (None: the stored crops).
    width, depth, use_fov, use_deformable, use_context, deformable_groups,
        deformable_scales, field_modulation: the network (lensim.restore.network.FieldAwareUNet).
    seed: seeds model initialisation, data order, crops and augmentation.
    augment: random FOV-consistent dihedral ops.
    val_fraction: share of source photos held out for validation.
    val_batch_size: crops per validation forward pass.
    device: "cpu", "cuda", "cuda:N".
    amp: mixed precision on CUDA (ignored on CPU).
    time_budget_s: stop cleanly (checkpoint, log row) once the run has trained this many
        seconds in all, counting the calls before a resume (None: no limit).
    max_steps_per_epoch: cap on steps per epoch (None: the whole epoch), for quick runs.
    """

    epochs: int = 30
    batch_size: int = 4
    lr: float = 1e-4
    lr_halve_every: int = 5
    lr_schedule: str = "step"
    crop: int | None = 128
    width: int = 32
    depth: int = 3
    use_fov: bool = True
    use_deformable: bool = True
    use_context: bool = True
    deformable_groups: int = 2
    deformable_scales: int | None = None
    field_modulation: bool = False
    seed: int = 0
    augment: bool = True
    val_fraction: float = 0.2
    val_batch_size: int = 8
    device: str = "cpu"
    amp: bool = True
    time_budget_s: float | None = None
    max_steps_per_epoch: int | None = None

    def model_kwargs(self) -> dict[str, Any]:
        return {"width": self.width, "depth": self.depth, "use_fov": self.use_fov,
                "use_deformable": self.use_deformable, "use_context": self.use_context,
                "deformable_groups": self.deformable_groups, "deformable_scales": self.deformable_scales,
                "field_modulation": self.field_modulation}


# Settings that must not change when resuming (they would change the loss curve's meaning).
_FROZEN_ON_RESUME = ("batch_size", "lr", "lr_halve_every", "lr_schedule", "crop", "width", "depth", "use_fov",
                     "use_deformable", "use_context", "deformable_groups", "deformable_scales", "field_modulation",
                     "seed", "augment", "val_fraction",
                     "max_steps_per_epoch")


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


def budget_progress(report: Callable[[float, float], None] | None,
                    budget_s: float) -> Callable[[TrainProgress], None] | None:
    """A train() progress callback that passes (seconds trained in this call, capped at
    budget_s; budget_s) to ``report``, for a progress bar over a time budget."""
    if report is None:
        return None
    return lambda p: report(min(p.seconds, budget_s), budget_s)


# ----------------------------------------------------------------------------- helpers


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    """torch.save through :func:`lensim.io.atomic_writer`: readers see the old file or
    the new one, never a partial one."""
    with atomic_writer(path, suffix=".tmp") as fh:
        torch.save(obj, fh)


def rng_state() -> dict[str, Any]:
    """Torch (CPU and CUDA), Python and NumPy RNG states as tensors/lists (weights_only-safe)."""
    py = random.getstate()
    npst = np.random.get_state()
    out: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "python": [py[0], list(py[1]), py[2]],
        "numpy": [npst[0], torch.from_numpy(npst[1].astype(np.int64)), int(npst[2]), int(npst[3]), float(npst[4])],
    }
    if torch.cuda.is_available():
        out["cuda"] = torch.cuda.get_rng_state_all()
    return out


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`rng_state` returned."""
    torch.set_rng_state(state["torch"])
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    n = state["numpy"]
    np.random.set_state((n[0], n[1].numpy().astype(np.uint32), n[2], n[3], n[4]))
    if "cuda" in state and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(state["cuda"])


def epoch_order(n: int, seed: int, epoch: int) -> list[int]:
    """The permutation of item indices for one epoch (depends only on n, seed, epoch)."""
    gen = torch.Generator().manual_seed((seed * 1_000_003 + epoch * 7919 + 12345) % (2**63))
    return torch.randperm(n, generator=gen).tolist()


def epoch_batches(n: int, batch_size: int, seed: int, epoch: int, rank: int = 0, world: int = 1,
                  max_batches: int | None = None) -> list[list[int]]:
    """Batches of one epoch for one rank: the epoch's permutation, padded (by wrapping) to
    a multiple of world so ranks get equal shares, strided by rank, cut into batches;
    a last partial batch is dropped unless it is the only one."""
    order = epoch_order(n, seed, epoch)
    if world > 1:
        pad = (-len(order)) % world
        order = (order + order[:pad])[rank::world]
    nb = max(1, len(order) // batch_size)
    batches = [order[i * batch_size:(i + 1) * batch_size] for i in range(nb)]
    return batches[:max_batches] if max_batches else batches


def _collate(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    return {k: torch.stack([it[k] for it in items]) if k != "index" else torch.tensor([it[k] for it in items])
            for k in items[0]}


LR_SCHEDULES = ("step", "cosine")


def cosine_lr(lr0: float, progress: float) -> float:
    """Half-cosine annealing: lr0 at progress 0, 0 at progress >= 1."""
    return lr0 * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


def _lr(optimizer: torch.optim.Optimizer) -> float:
    return float(optimizer.param_groups[0]["lr"])


@dataclass
class _Dist:
    world: int = 1
    rank: int = 0
    local_rank: int = 0

    @property
    def main(self) -> bool:
        return self.rank == 0


def _init_distributed(device: str) -> tuple[_Dist, str, bool]:
    """(ranks, this rank's device, whether this call created the process group)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return _Dist(), device, False
    import torch.distributed as dist

    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    created = False
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.startswith("cuda") else "gloo")
        created = True
    if device.startswith("cuda"):
        torch.cuda.set_device(local)
        device = f"cuda:{local}"
    return _Dist(world, rank, local), device, created


def _amp_dtype(device: torch.device, enabled: bool) -> torch.dtype | None:
    """Autocast dtype for mixed precision (bfloat16 where supported, else float16), or None."""
    if device.type != "cuda" or not enabled:
        return None
    return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16


class _CsvLog:
    """Append-only CSV that, on resume, drops rows newer than the checkpoint's step."""

    def __init__(self, path: Path, fields: tuple[str, ...], keep_until_step: int | None) -> None:
        self.path = path
        self.fields = fields
        rows: list[dict[str, str]] = []
        if keep_until_step is not None and path.exists():
            with open(path, newline="") as fh:
                rows = [r for r in csv.DictReader(fh) if r.get("step", "").isdigit() and int(r["step"]) <= keep_until_step]
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)

    def write(self, row: dict[str, Any]) -> None:
        with open(self.path, "a", newline="") as fh:
            csv.DictWriter(fh, fieldnames=self.fields).writerow({k: _fmt(row.get(k)) for k in self.fields})


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return "" if v is None else v


def read_csv(path: str | Path) -> list[dict[str, float]]:
    """Rows of a log CSV with numbers parsed (empty cells -> nan)."""
    with open(path, newline="") as fh:
        return [{k: float(v) if v != "" else math.nan for k, v in r.items()} for r in csv.DictReader(fh)]


@torch.no_grad()
def evaluate_pairs(model: torch.nn.Module, loader: Iterator[dict[str, torch.Tensor]] | DataLoader,
                   device: torch.device) -> dict[str, float]:
    """Mean PSNR (dB) and SSIM over crops of the restored output and of the input itself
    (outputs clamped to [0, 1] as when written to a file)."""
    was_training = model.training
    model.eval()
    tot = {"psnr": 0.0, "ssim": 0.0, "input_psnr": 0.0, "input_ssim": 0.0}
    n = 0
    for batch in loader:
        inp = batch["input"].to(device)
        tgt = batch["target"].to(device)
        out = model(inp, batch["fov"].to(device)).float().clamp(0, 1)
        tot["psnr"] += float(psnr(out, tgt).clamp(max=100.0).sum())
        tot["ssim"] += float(ssim(out, tgt).sum())
        tot["input_psnr"] += float(psnr(inp, tgt).clamp(max=100.0).sum())
        tot["input_ssim"] += float(ssim(inp, tgt).sum())
        n += inp.shape[0]
    model.train(was_training)
    return {k: v / n for k, v in tot.items()} if n else {k: math.nan for k in tot}


# ----------------------------------------------------------------------------- train


def train(
    dataset_dir: str | Path,
    run_dir: str | Path,
    config: TrainConfig | None = None,
    resume: bool = False,
    progress: Callable[[TrainProgress], None] | None = None,
    **overrides: Any,
) -> TrainResult:
    """Train (or, with ``resume``, continue training) a FieldAwareUNet on a pairs folder.

    Args:
        dataset_dir: folder written by ``lensim dataset make`` (manifest.json + crops).
        run_dir: output folder (created); must not hold a run unless ``resume``.
        config: settings (TrainConfig); keyword ``overrides`` replace single fields, e.g.
            ``train(ds, run, epochs=2, width=8)``.
        resume: continue from RUN/last.pt. The settings listed in _FROZEN_ON_RESUME are
            taken from the checkpoint (a differing explicit value is an InputError);
            epochs, time_budget_s, device, amp and val_batch_size may change.
        progress: called with a TrainProgress after every step and every validation.

    Returns:
        TrainResult (final and best validation metrics, steps, whether the time budget
        stopped the run, and the per-epoch history rows).
    """
    cfg = TrainConfig(**{**asdict(config or TrainConfig()), **overrides})
    run = Path(run_dir)
    last_path = run / "last.pt"
    ckpt: dict[str, Any] | None = None
    if resume:
        if not last_path.is_file():
            raise InputError(str(last_path), None, "no such file; expected a run folder holding last.pt to resume")
        ckpt = _read_checkpoint(last_path)
        saved = ckpt["train_config"]
        diff = [k for k in _FROZEN_ON_RESUME if k in overrides and overrides[k] != saved.get(k)]
        if diff:
            raise InputError(str(last_path), ", ".join(diff), f"differs from the run being resumed "
                             f"({', '.join(f'{k}={saved.get(k)!r}' for k in diff)}); expected the same value or none")
        cfg = TrainConfig(**{**saved, **{k: v for k, v in asdict(cfg).items() if k not in _FROZEN_ON_RESUME}})
    elif last_path.exists():
        raise InputError(str(run), None, "already holds a training run (last.pt); expected --resume or a new folder")
    if cfg.epochs < 1 or cfg.batch_size < 1 or cfg.lr <= 0 or cfg.lr_halve_every < 1:
        raise InputError(None, "config", f"expected epochs, batch_size, lr_halve_every >= 1 and lr > 0, got "
                         f"epochs={cfg.epochs}, batch_size={cfg.batch_size}, lr={cfg.lr}, "
                         f"lr_halve_every={cfg.lr_halve_every}")
    if cfg.lr_schedule not in LR_SCHEDULES:
        raise InputError(None, "lr_schedule", f"expected one of {', '.join(LR_SCHEDULES)}, got {cfg.lr_schedule!r}")

    dist_info, device_name, created_group = _init_distributed(cfg.device)
    if device_name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(None, "device", f"{device_name!r} requested but CUDA is not available; expected 'cpu'")
    device = torch.device(device_name)

    manifest = load_manifest(dataset_dir)
    refs = crop_refs(dataset_dir, manifest)
    sources = sorted({r.source for r in refs})
    if ckpt is not None:
        train_src, val_src = ckpt["split"]["train"], ckpt["split"]["val"]
        missing = sorted(set(train_src + val_src) - set(sources))
        if missing:
            raise InputError(str(dataset_dir), "records", f"lacks source photos of the run being resumed "
                             f"({', '.join(missing[:3])}); expected the dataset it was trained on")
    else:
        train_src, val_src = split_sources(sources, cfg.val_fraction, cfg.seed)
    hw = sensor_hw(manifest)
    train_refs = [r for r in refs if r.source in set(train_src)]
    val_refs = [r for r in refs if r.source in set(val_src)]
    train_ds = PairDataset(train_refs, hw, crop=cfg.crop, augment=cfg.augment, seed=cfg.seed)
    val_ds = PairDataset(val_refs, hw, crop=None, augment=False, seed=cfg.seed)
    if len(train_ds) < 1:
        raise InputError(str(dataset_dir), "records", "has no training crops; expected at least one")

    torch.manual_seed(cfg.seed)
    model = FieldAwareUNet(**cfg.model_kwargs()).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=cfg.lr_halve_every, gamma=0.5)
    amp_dtype = _amp_dtype(device, cfg.amp)
    scaler = torch.amp.GradScaler("cuda", enabled=amp_dtype == torch.float16)

    epoch, batch_pos, step = 0, 0, 0
    best = -math.inf
    seconds_before = 0.0  # training seconds of the calls before a resume
    if ckpt is not None:
        try:
            model.load_state_dict(ckpt["model_state"])
        except RuntimeError as e:
            raise InputError(str(last_path), "model_state", f"does not match its model config ({str(e).splitlines()[0]})") from None
        optimizer.load_state_dict(ckpt["optimizer"])
        scheduler.load_state_dict(ckpt["scheduler"])
        if ckpt.get("scaler"):
            scaler.load_state_dict(ckpt["scaler"])
        epoch, batch_pos, step = int(ckpt["epoch"]), int(ckpt["batch_in_epoch"]), int(ckpt["step"])
        best = float(ckpt.get("best_val_psnr") or -math.inf)
        seconds_before = float(ckpt.get("train_seconds") or 0.0)
        set_rng_state(ckpt["rng"])

    net: torch.nn.Module = model
    if dist_info.world > 1:
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(model, device_ids=[dist_info.local_rank] if device.type == "cuda" else None)

    main = dist_info.main
    split = {"train": list(train_src), "val": list(val_src), "val_fraction": cfg.val_fraction, "seed": cfg.seed}
    steps_log = log = None
    tb = None
    if main:
        run.mkdir(parents=True, exist_ok=True)
        cfg_json = {**asdict(cfg), "dataset": str(Path(dataset_dir).resolve())}
        atomic_write_text(run / "config.json", json.dumps(cfg_json, indent=1) + "\n")
        atomic_write_text(run / "split.json", json.dumps(split, indent=1) + "\n")
        keep = step if ckpt is not None else None
        steps_log = _CsvLog(run / "steps.csv", STEP_FIELDS, keep)
        log = _CsvLog(run / "log.csv", LOG_FIELDS, keep)
        try:
            from torch.utils.tensorboard import SummaryWriter

            tb = SummaryWriter(str(run / "tb"), purge_step=step if ckpt is not None else None)
        except Exception:  # tensorboard is optional
            tb = None

    val_loader = DataLoader(val_ds, batch_size=cfg.val_batch_size, shuffle=False, collate_fn=_collate)
    start = time.perf_counter()
    stopped = False
    history: list[dict[str, Any]] = []
    last_loss = math.nan
    metrics: dict[str, float] = {}

    def trained_s() -> float:
        """Seconds this run has trained, the calls before a resume included."""
        return seconds_before + time.perf_counter() - start

    def save(kind_best: bool = False) -> None:
        state = {
            "format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION,
            "model_config": model.config, "model_state": model.state_dict(),
            "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
            "scaler": scaler.state_dict() if scaler.is_enabled() else None,
            "epoch": epoch, "batch_in_epoch": batch_pos, "step": step, "rng": rng_state(),
            "train_seconds": trained_s(),
            "train_config": asdict(cfg), "split": split, "best_val_psnr": best if math.isfinite(best) else None,
            "val_psnr": metrics.get("psnr"), "val_ssim": metrics.get("ssim"),
            "lens": manifest.get("lens"), "sensor": manifest.get("sensor"), "sensor_name": manifest.get("sensor_name"),
            "dataset": str(Path(dataset_dir).resolve()),
        }
        atomic_torch_save(state, last_path)
        if kind_best:
            atomic_torch_save(state, run / "best.pt")

    def validate_and_log(loss_value: float, lr_used: float) -> None:
        nonlocal metrics, best
        metrics = evaluate_pairs(model, val_loader, device) if len(val_ds) else {}
        vp, vs = metrics.get("psnr", math.nan), metrics.get("ssim", math.nan)
        row = {"epoch": epoch, "step": step, "loss": loss_value, "val_psnr": vp, "val_ssim": vs,
               "lr": lr_used, "seconds": time.perf_counter() - start}
        history.append(row)
        assert log is not None
        log.write(row)
        if tb is not None:
            tb.add_scalar("val/psnr", vp, step)
            tb.add_scalar("val/ssim", vs, step)
        improved = math.isfinite(vp) and vp > best
        if improved:
            best = vp
        save(kind_best=improved or not (run / "best.pt").exists())

    model.train()
    while epoch < cfg.epochs and not stopped:
        batches = epoch_batches(len(train_ds), cfg.batch_size, cfg.seed, epoch, dist_info.rank, dist_info.world,
                                cfg.max_steps_per_epoch)
        train_ds.set_epoch(epoch)
        loader = DataLoader(train_ds, batch_sampler=batches[batch_pos:], collate_fn=_collate)
        run_sum, run_n = 0.0, 0
        epoch_lr = _lr(optimizer)
        for batch in loader:
            if cfg.lr_schedule == "cosine":
                if cfg.time_budget_s:
                    progress_share = trained_s() / cfg.time_budget_s
                else:
                    progress_share = (epoch + batch_pos / max(len(batches), 1)) / cfg.epochs
                for group in optimizer.param_groups:
                    group["lr"] = cosine_lr(cfg.lr, progress_share)
            inp = batch["input"].to(device, non_blocking=True)
            tgt = batch["target"].to(device, non_blocking=True)
            fov = batch["fov"].to(device, non_blocking=True)
            optimizer.zero_grad(set_to_none=True)
            if amp_dtype is not None:
                with torch.autocast(device_type="cuda", dtype=amp_dtype):
                    out = net(inp, fov)
                loss = F.mse_loss(out.float(), tgt)
            else:
                loss = F.mse_loss(net(inp, fov), tgt)
            scaler.scale(loss).backward()
            scaler.step(optimizer)
            scaler.update()
            step += 1
            batch_pos += 1
            last_loss = float(loss.detach())
            if dist_info.world > 1:
                import torch.distributed as dist

                t = torch.tensor([last_loss], device=device)
                dist.all_reduce(t)
                last_loss = float(t) / dist_info.world
            run_sum += last_loss
            run_n += 1
            elapsed = time.perf_counter() - start
            if main:
                assert steps_log is not None
                steps_log.write({"epoch": epoch, "step": step, "loss": last_loss, "lr": _lr(optimizer),
                                 "seconds": elapsed})
                if tb is not None:
                    tb.add_scalar("train/loss", last_loss, step)
            if progress is not None and main:
                progress(TrainProgress("step", epoch, cfg.epochs, step, batch_pos, len(batches), last_loss,
                                       _lr(optimizer), elapsed))
            over = cfg.time_budget_s is not None and seconds_before + elapsed >= cfg.time_budget_s
            if dist_info.world > 1:
                import torch.distributed as dist

                flag = torch.tensor([int(over)], device=device)
                dist.broadcast(flag, 0)
                over = bool(flag)
            if over and batch_pos < len(batches):
                stopped = True
                break
        mean_loss = run_sum / run_n if run_n else last_loss
        if not stopped:
            epoch += 1
            batch_pos = 0
            if cfg.lr_schedule == "step":
                scheduler.step()
        if main:
            validate_and_log(mean_loss, epoch_lr)
            if progress is not None:
                progress(TrainProgress("stop" if stopped else "epoch", epoch - (0 if stopped else 1), cfg.epochs, step,
                                       batch_pos, len(batches), mean_loss, epoch_lr,
                                       time.perf_counter() - start, metrics.get("psnr"), metrics.get("ssim")))
        if dist_info.world > 1:
            import torch.distributed as dist

            dist.barrier()
        if not stopped and cfg.time_budget_s is not None and trained_s() >= cfg.time_budget_s and epoch < cfg.epochs:
            stopped = True
    if tb is not None:
        tb.close()
    if created_group:
        import torch.distributed as dist

        dist.destroy_process_group()
    return TrainResult(str(run), epoch, step, stopped, time.perf_counter() - start, last_loss,
                       metrics.get("psnr"), metrics.get("ssim"), metrics.get("input_psnr"),
                       best if math.isfinite(best) else None, history)


def _read_checkpoint(path: Path) -> dict[str, Any]:
    from lensim.restore.infer import read_checkpoint

    return read_checkpoint(path)


__all__ = ["TrainConfig", "TrainProgress", "TrainResult", "atomic_torch_save", "budget_progress", "epoch_batches",
           "epoch_order",
           "evaluate_pairs", "read_csv", "rng_state", "set_rng_state", "train"]
