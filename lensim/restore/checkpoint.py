"""Checkpoints of `lensim train`: the format, atomic saving, loading (for inference and
evaluation: :func:`load_checkpoint` rebuilds the network) and resuming.

A checkpoint is a ``torch.save`` of a dict, loadable with ``weights_only=True``:
    format, version          CHECKPOINT_FORMAT, CHECKPOINT_VERSION
    model_config, model_state the network (lensim.restore.models.build_model(config); a config
                              without "arch" is a FieldAwareUNet)
    optimizer, scheduler, scaler  Adam, StepLR and grad-scaler states (scaler None when off)
    epoch, batch_in_epoch, step   epochs completed, batches done in the current epoch,
                              optimizer steps done
    skipped_batches          [epoch, batch] of each batch skipped after a non-finite loss
                              (lensim.restore.divergence; absent before it: none)
    rng                      torch (CPU, CUDA), Python and NumPy random states
    train_seconds            seconds the run has trained in all, resumes included
    train_config, split      the training settings and the train/validation source photos
    best_val_psnr, val_psnr, val_ssim  validation figures (dB; None before any)
    lens, sensor, sensor_name, dataset  the dataset's camera (from its manifest) and folder,
                              so inference warns when used on another camera
    conditioning             the shooting settings the network is conditioned on and the
                              ranges it was trained across (lensim.restore.conditioning.
                              Conditioning.to_dict(); absent in checkpoints from before it:
                              no settings)
Inference needs only format, model_config and model_state (:data:`REQUIRED_KEYS`).

Saving goes through lensim.io.atomic_writer (temporary file in the run folder, fsync,
rename): a crash never leaves a partial file, and readers see the old checkpoint or the new.
A training state whose weights are not all finite is never saved (TrainingState.save
raises lensim.restore.divergence.NonFinite instead).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import pickle
import random
import shutil
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lensim.errors import InputError
from lensim.io import LOCK_NAME, atomic_writer, folder_lock
from lensim.restore.conditioning import checkpoint_conditioning
from lensim.restore.models import build_model

CHECKPOINT_FORMAT = "lensim-restore-checkpoint"
CHECKPOINT_VERSION = 1
#: Keys every checkpoint holds; inference reads only these.
REQUIRED_KEYS = ("format", "model_config", "model_state")
#: Keys only training needs (left out of what load_checkpoint returns).
TRAINING_STATE_KEYS = ("model_state", "optimizer", "scheduler", "scaler", "rng")
LAST = "last.pt"
BEST = "best.pt"


# ----------------------------------------------------------------------------- files


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    """torch.save through :func:`lensim.io.atomic_writer`: readers see the old file or
    the new one, never a partial one."""
    with atomic_writer(path, suffix=".tmp") as fh:
        torch.save(obj, fh)


def _load_failure(e: Exception) -> str:
    """Why torch.load failed, in a few words. Torch's advice to retry with
    weights_only=False (running whatever code the file holds) is not passed on."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    if "weights_only" in text or isinstance(e, pickle.UnpicklingError):
        return (
            f"{type(e).__name__}: not data a safe load reads (damaged, or objects other than tensors and plain values)"
        )
    return f"{type(e).__name__}: {text[:200]}"


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The dict stored in a lensim checkpoint (loaded with weights_only=True on CPU);
    one-line InputError naming the file when it is missing, corrupt or not ours."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise InputError(src, None, "no such file; expected a lensim training checkpoint (.pt)")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated zip, pickle garbage, foreign objects
        raise InputError(src, None, f"is corrupt or not a lensim checkpoint ({_load_failure(e)})") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(src, "format", f"expected a {CHECKPOINT_FORMAT!r} dict from `lensim train`")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise InputError(src, ", ".join(missing), "missing; expected a complete lensim checkpoint")
    return data


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint file, or RUN/best.pt (else RUN/last.pt) for a run folder."""
    path = Path(path)
    if path.is_dir():
        for name in (BEST, LAST):
            if (path / name).is_file():
                return path / name
        raise InputError(str(path), None, "holds no best.pt or last.pt; expected a `lensim train` run folder")
    return path


# ----------------------------------------------------------------------------- inference


def _describe_lens(lens: Any) -> str:
    return str(lens.get("name") or "unnamed lens") if isinstance(lens, dict) else str(lens)


def _describe_sensor(sensor: Any) -> str:
    if isinstance(sensor, dict):
        res = sensor.get("resolution")
        return f"{sensor.get('name', 'unnamed sensor')} {res[0]}x{res[1]}" if res else str(sensor.get("name"))
    return str(sensor)


def _canonical(d: Any) -> str:
    return json.dumps(d, sort_keys=True, default=str)


def _differing(a: Any, b: Any, path: str = "", depth: int = 3) -> list[str]:
    """The paths (such as ``surfaces[5].decentre``, at most ``depth`` levels deep) where two
    JSON-like values differ."""
    if _canonical(a) == _canonical(b):
        return []
    if depth and isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b), key=str)
        return [p for k in keys for p in _differing(a.get(k), b.get(k), f"{path}.{k}" if path else str(k), depth - 1)]
    if depth and isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [
            p for i, (x, y) in enumerate(zip(a, b, strict=True)) for p in _differing(x, y, f"{path}[{i}]", depth - 1)
        ]
    return [path or "the whole"]


def lens_difference(trained: Any, used: Any, most: int = 3) -> str:
    """What differs between two lens dicts, for one line: the first ``most`` differing
    fields and, when the two have the same name, a digest of each (two units of one
    design, say a nominal and an as-built lens)."""
    paths = sorted(_differing(trained, used), key=lambda p: p.startswith("as_built"))  # the optics first
    text = ", ".join(paths[:most]) + (f" and {len(paths) - most} more" if len(paths) > most else "")
    if _describe_lens(trained) == _describe_lens(used):
        digest = [hashlib.sha256(_canonical(d).encode()).hexdigest()[:8] for d in (trained, used)]
        text += f"; lens digests {digest[0]} (trained) and {digest[1]} (used)"
    return text


def warn_other_camera(
    source: str, trained: dict[str, Any], lens: dict[str, Any] | None, sensor: dict[str, Any] | None
) -> None:
    """A UserWarning naming ``source`` when the given lens or sensor (dicts, or None: not
    given) differs from the one ``trained`` records (its "lens" and "sensor": a
    checkpoint, or an ONNX export's metadata)."""
    if lens is not None and trained.get("lens") is not None and _canonical(lens) != _canonical(trained["lens"]):
        warnings.warn(
            f"{source}: trained for lens {_describe_lens(trained['lens'])!r}, used for lens "
            f"{_describe_lens(lens)!r} (they differ in {lens_difference(trained['lens'], lens)}); "
            "the restoration may be wrong",
            UserWarning,
            stacklevel=3,
        )
    if sensor is not None and trained.get("sensor") is not None and _canonical(sensor) != _canonical(trained["sensor"]):
        warnings.warn(
            f"{source}: trained for sensor {_describe_sensor(trained['sensor'])!r}, used for sensor "
            f"{_describe_sensor(sensor)!r}; the restoration may be wrong",
            UserWarning,
            stacklevel=3,
        )


def load_checkpoint(
    path: str | Path,
    lens: dict[str, Any] | None = None,
    sensor: dict[str, Any] | None = None,
    device: str | torch.device = "cpu",
) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Rebuild the trained network from a checkpoint (or run folder).

    Args:
        path: a checkpoint file, or a run folder (best.pt, else last.pt).
        lens: the lens the user will restore photos of (lensim.optics.lens_file.lens_to_dict),
            or None. A UserWarning is issued when it differs from the checkpoint's lens.
        sensor: the sensor profile dict (SensorProfile.to_dict()), or None; warned likewise.
        device: where the model is put.

    Returns:
        (model in eval mode, the checkpoint dict without optimizer/RNG state; its
        ``conditioning`` is always there, Conditioning.to_dict(): {"keys": [], "ranges": {}}
        for a checkpoint from before conditioning).
    Raises:
        InputError (one line, naming the file) for a missing, corrupt, foreign or
        mismatched checkpoint (state not matching its model config).
    """
    path = resolve_checkpoint(path)
    data = read_checkpoint(path)
    cfg = data["model_config"]
    try:
        if not isinstance(cfg, dict):
            raise TypeError(f"expected a dict, got {type(cfg).__name__}")
        model = build_model(cfg)
    except (TypeError, ValueError) as e:
        raise InputError(str(path), "model_config", f"cannot build the network ({e})") from None
    try:
        model.load_state_dict(data["model_state"])
    except (RuntimeError, KeyError, TypeError) as e:
        first = str(e).strip().splitlines()
        detail = " ".join(line.strip() for line in first[:3])[:300]
        raise InputError(str(path), "model_state", f"does not match the model config it records ({detail})") from None
    model.to(device).eval()
    conditioning = checkpoint_conditioning(data, int(getattr(model, "settings_dim", 0)), str(path))
    warn_other_camera(str(path), data, lens, sensor)
    info = {k: v for k, v in data.items() if k not in TRAINING_STATE_KEYS}
    info["path"] = str(path)
    info["conditioning"] = conditioning.to_dict()
    return model, info


# ----------------------------------------------------------------------------- random states


def rng_state() -> dict[str, Any]:
    """Torch (CPU and CUDA), Python and NumPy RNG states as tensors/lists (weights_only-safe)."""
    py = random.getstate()
    npst: Any = np.random.get_state()  # the legacy tuple (kind, keys, pos, has_gauss, cached)
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


# ----------------------------------------------------------------------------- training state


@dataclass
class TrainingState:
    """What a training run carries from step to step and across a resume.

    epoch: epochs completed; batch_in_epoch: batches done in the current epoch; step:
    optimizer steps done; best_val_psnr: best validation PSNR so far in dB (-inf before
    any); train_seconds: seconds trained by the calls before this one (resumes); skipped:
    the (epoch, batch) of each batch skipped after a non-finite loss."""

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    scaler: torch.amp.GradScaler
    epoch: int = 0
    batch_in_epoch: int = 0
    step: int = 0
    best_val_psnr: float = -math.inf
    train_seconds: float = 0.0
    skipped: set[tuple[int, int]] = field(default_factory=set)

    def checkpoint(self, train_seconds: float, context: dict[str, Any]) -> dict[str, Any]:
        """The checkpoint dict (module docstring). train_seconds: the run's seconds so far;
        context: train_config, split, val_psnr, val_ssim, lens, sensor, sensor_name, dataset."""
        model = self.model
        best = self.best_val_psnr
        return {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "scaler": self.scaler.state_dict() if self.scaler.is_enabled() else None,
            "epoch": self.epoch,
            "batch_in_epoch": self.batch_in_epoch,
            "step": self.step,
            "skipped_batches": [list(b) for b in sorted(self.skipped)],
            "rng": rng_state(),
            "train_seconds": train_seconds,
            "train_config": context["train_config"],
            "split": context["split"],
            "best_val_psnr": best if math.isfinite(best) else None,
            "val_psnr": context.get("val_psnr"),
            "val_ssim": context.get("val_ssim"),
            "lens": context.get("lens"),
            "sensor": context.get("sensor"),
            "sensor_name": context.get("sensor_name"),
            "dataset": context.get("dataset"),
            "conditioning": context.get("conditioning"),
        }

    def save(self, run: Path, train_seconds: float, context: dict[str, Any], best: bool) -> None:
        """Write RUN/last.pt (and RUN/best.pt when ``best``) atomically; weights that are
        not all finite are never written (lensim.restore.divergence.NonFinite)."""
        from lensim.restore.divergence import check_weights

        check_weights(self.model)
        state = self.checkpoint(train_seconds, context)
        atomic_torch_save(state, run / LAST)
        if best:
            atomic_torch_save(state, run / BEST)

    def resume_from(self, ckpt: dict[str, Any], source: str) -> None:
        """Load model, optimizer, scheduler, scaler, position and random states from a
        checkpoint (call after building the model: its initialisation draws random numbers).
        A model state that does not fit is a one-line InputError naming ``source``."""
        try:
            self.model.load_state_dict(ckpt["model_state"])
        except RuntimeError as e:
            raise InputError(
                source, "model_state", f"does not match its model config ({str(e).splitlines()[0]})"
            ) from None
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        if ckpt.get("scaler"):
            self.scaler.load_state_dict(ckpt["scaler"])
        self.epoch, self.batch_in_epoch, self.step = int(ckpt["epoch"]), int(ckpt["batch_in_epoch"]), int(ckpt["step"])
        self.best_val_psnr = float(ckpt.get("best_val_psnr") or -math.inf)
        self.train_seconds = float(ckpt.get("train_seconds") or 0.0)
        self.skipped = {(int(e), int(b)) for e, b in ckpt.get("skipped_batches") or []}
        set_rng_state(ckpt["rng"])


def read_resume_checkpoint(run: Path) -> dict[str, Any]:
    """RUN/last.pt of a run to resume; one-line InputError when there is none."""
    path = run / LAST
    if not path.is_file():
        raise InputError(str(path), None, "no such file; expected a run folder holding last.pt to resume")
    return read_checkpoint(path)


def refuse_existing_run(run: Path) -> None:
    """A one-line InputError when ``run`` already holds a training run (a fresh run would
    overwrite it)."""
    if (run / LAST).exists():
        raise InputError(str(run), None, "already holds a training run (last.pt); expected `resume` or a new folder")


def remove_unfinished_run(run: Path) -> bool:
    """Remove a run folder that holds no checkpoint (*.pt), so that nothing half-made is left
    in the way of the rerun; a folder another process has locked (lensim.io.LOCK_NAME: its
    own run) is left alone. Returns whether it was removed."""
    if not run.is_dir() or any(run.glob("*.pt")) or (run / LOCK_NAME).exists():
        return False
    shutil.rmtree(run, ignore_errors=True)
    return not run.exists()


@contextlib.contextmanager
def run_folder(run: Path, writer: bool = True) -> Iterator[Path]:
    """The run folder while a run trains: locked (lensim.io.folder_lock: a second writer is
    refused at once) when this process writes it (rank 0 under torchrun); a new run that
    fails or is interrupted before its first checkpoint is removed (remove_unfinished_run)."""
    new_run = not run.exists()
    try:
        with folder_lock(run) if writer else contextlib.nullcontext(run):
            yield run
    except BaseException:
        if writer and new_run:
            remove_unfinished_run(run)
        raise


__all__ = [
    "BEST",
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "LAST",
    "REQUIRED_KEYS",
    "TRAINING_STATE_KEYS",
    "TrainingState",
    "atomic_torch_save",
    "load_checkpoint",
    "read_checkpoint",
    "read_resume_checkpoint",
    "refuse_existing_run",
    "remove_unfinished_run",
    "resolve_checkpoint",
    "run_folder",
    "rng_state",
    "set_rng_state",
    "lens_difference",
    "warn_other_camera",
]
