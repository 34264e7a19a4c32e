"""The universal model: one restoration network pretrained on the lens library's pairs
(lensim.data.library_pairs: one pairs folder per library bank, each with its own lens,
shooting settings, pixel pitch and sensor), so that a lens it never saw is corrected with
no training (zero-shot) and a per-lens run starts from it (``lensim train --init universal``).

Pretraining (:func:`pretrain`): the pairs of every folder in one pool (each item's FOV
channels normalised to its own sensor, lensim.restore.dataset), random sub-crops with
FOV-consistent dihedral augmentation, Adam at a constant learning rate, MSE loss. The data
order of epoch e is a permutation drawn from (seed, e) and each item's draws from (seed, e,
index), as in lensim.restore.train. Resumable: RUN/last.pt (the checkpoint format of
lensim.restore.checkpoint, with the optimizer, position and random states) is written
atomically every ``checkpoint_every_s`` seconds and at the end; a rerun with the same
folder continues from it (the time budget counts the seconds of every call), and
RUN/log.csv gets one row per checkpoint (step, epoch, mean loss since the last row,
seconds in all, pairs folders in the pool).

The shipped model (:func:`ship`, lensim/assets/models/universal/): model.pt holds only what
inference needs (format, model_config, model_state in float32) and ``universal``: the
ranges of pixel pitch (um) and F-number it was trained across and the library banks it saw.
:func:`check_range` refuses a lens or sensor outside them (InputError naming the parameter).

Network (:meth:`PretrainConfig.network`): the PSF-informed network (lensim.restore.psfnet,
``arch="psfnet"``: NAFNet with FOV channels, pixel-unshuffle stem 2, refining the Wiener
stage's image of the lens's own bank), so that what tells it the lens is the bank, not
what it memorised; untrained it is the Wiener stage. Each pairs folder's Wiener stage cache
(lensim.restore.psf_stage.ensure_wiener_cache, with its own bank) is computed where
missing before training. ``arch="nafnet"`` pretrains the image-only default network.
"""

from __future__ import annotations

import csv
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch

from lensim.errors import InputError, ParameterError
from lensim.io import append_text, atomic_write_json, folder_lock, read_json

#: where the shipped universal model lives
MODEL_DIR = Path(__file__).resolve().parent.parent / "assets" / "models" / "universal"
MODEL_FILE = "model.pt"
#: the name `--init` and `--model` take for the shipped model
NAME = "universal"
LOG = "log.csv"
RANGE_MARGIN = 0.05  # a lens or sensor within 5 % beyond a trained range is still served


@dataclass(frozen=True)
class PretrainConfig:
    """Pretraining settings. arch: "psfnet" (the PSF-informed network) or "nafnet" (image
    only); width, stem: its NAFNet body (FOV channels on); crop: training sub-crop
    (pixels); batch_size; lr: Adam's learning rate; time_budget_s: seconds of training in
    all (every call's; None: until max_steps); max_steps: optimizer steps in all (None: no
    limit); checkpoint_every_s: seconds between checkpoints; seed; device: "cpu", "cuda" or
    "cuda:N"; amp: mixed precision on CUDA (lensim.restore.distributed.amp_dtype; float16
    with a grad scaler where bfloat16 is unsupported)."""

    width: int = 32
    stem: int = 2
    crop: int = 96
    batch_size: int = 8
    lr: float = 5e-4
    time_budget_s: float | None = 3600.0
    max_steps: int | None = None
    checkpoint_every_s: float = 120.0
    seed: int = 0
    arch: str = "psfnet"
    device: str = "cpu"
    amp: bool = True

    def network(self) -> dict[str, Any]:
        """The network's config (lensim.restore.models.build_model)."""
        if self.arch not in ("psfnet", "nafnet"):
            raise ParameterError(None, "arch", f"expected 'psfnet' or 'nafnet', got {self.arch!r}")
        return {"arch": self.arch, "width": self.width, "stem": self.stem, "use_fov": True}


@dataclass
class PretrainResult:
    """Where a pretraining call ended: steps in all, seconds in all, the last logged loss."""

    run: str
    step: int
    epoch: int
    seconds: float
    loss: float | None
    folders: int


def _stage_cache(job: tuple[str, dict[str, Any]]) -> str:
    """One folder's Wiener stage cache (a picklable job of :func:`stage_caches`)."""
    from lensim.restore.psf_stage import training_cache

    folder, network = job
    training_cache(folder, network)
    return folder


def stage_caches(
    folders: Sequence[str | Path],
    network: dict[str, Any],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> None:
    """Compute each pairs folder's Wiener stage cache for a network of config ``network``
    where it is missing (none for a network without the stage), ``workers`` folders at a
    time on a local Dask cluster (lensim.workers.run_jobs; one thread each), else one after
    another here. progress(folders done, folders) as each finishes. :func:`pool` then finds
    the caches made."""
    from lensim.workers import run_jobs

    if network.get("arch") != "psfnet":
        return
    done = [0]

    def finished(_job: tuple[str, dict[str, Any]], _result: str) -> None:
        done[0] += 1
        if progress is not None:
            progress(done[0], len(folders))

    run_jobs(_stage_cache, [(str(f), dict(network)) for f in folders], workers, None, finished)


def pool(
    folders: Sequence[str | Path],
    crop: int,
    seed: int,
    network: dict[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> torch.utils.data.ConcatDataset:
    """The pairs of every folder as one dataset (items as lensim.restore.dataset's). For a
    network with the Wiener stage (``network``: its config) each folder's stage cache is
    computed where missing (progress(folders done, folders))."""
    from lensim.restore.dataset import PairDataset
    from lensim.restore.psf_stage import training_cache

    if not folders:
        raise InputError(None, "folders", "expected at least one pairs folder")
    parts = []
    for done, folder in enumerate(folders, 1):
        wiener_dir = training_cache(folder, network or {})
        parts.append(PairDataset.from_folder(folder, crop=crop, augment=True, seed=seed, wiener_dir=wiener_dir))
        if progress is not None:
            progress(done, len(folders))
    return torch.utils.data.ConcatDataset(parts)


def _set_epoch(data: torch.utils.data.ConcatDataset, epoch: int) -> None:
    for part in data.datasets:
        part.set_epoch(epoch)  # type: ignore[attr-defined]


def _ranges(folders: Sequence[str | Path]) -> dict[str, Any]:
    """The pixel pitch (um, of each folder's sensor) and F-number (of its bank's shooting
    settings, where recorded) ranges of the pairs folders, and their banks' folder names."""
    pitches, fnos, banks, missing = [], [], [], []
    for f in folders:
        manifest = read_json(Path(f) / "manifest.json", "pairs manifest")
        pitches.append(float(manifest["sensor"]["pixel_pitch_um"]))
        bank_dir = Path(manifest["bank"]) if manifest.get("bank") else None
        if bank_dir is not None and (bank_dir / "manifest.json").exists():
            bank = read_json(bank_dir / "manifest.json", "bank manifest")
            resolved = (bank.get("shooting") or {}).get("resolved") or {}
            if resolved.get("fno") is not None:
                fnos.append(float(resolved["fno"]))
            banks.append(bank_dir.name)
        elif bank_dir is not None:
            missing.append(bank_dir)
    if missing:  # pairs copied without their banks (to a GPU machine, say)
        warnings.warn(
            f"{missing[0]}: the bank of {len(missing)} of {len(folders)} pairs folders is not here, so the model "
            "records no F-number range for them (lensim restore checks F-numbers against the banks found only)",
            UserWarning,
            stacklevel=2,
        )
    return {
        "pixel_pitch_um": [min(pitches), max(pitches)],
        "fno": [min(fnos), max(fnos)] if fnos else None,
        "banks": banks,
    }


def _new_state(cfg: PretrainConfig) -> dict[str, Any]:
    from lensim.restore.distributed import checked_device, mixed_precision
    from lensim.restore.models import build_model

    device = checked_device(cfg.device)
    torch.manual_seed(cfg.seed)
    model = build_model(cfg.network()).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    autocast, scaler = mixed_precision(device, cfg.amp)
    return {
        "model": model,
        "opt": opt,
        "step": 0,
        "epoch": 0,
        "batch": 0,
        "seconds": 0.0,
        "device": device,
        "autocast": autocast,
        "scaler": scaler,
    }


def _resume(run: Path, cfg: PretrainConfig) -> dict[str, Any]:
    """A fresh state, or the state of RUN/last.pt (a run of another network is refused)."""
    from lensim.restore.checkpoint import LAST, read_checkpoint, set_rng_state

    state = _new_state(cfg)
    if not (run / LAST).exists():
        return state
    ckpt = read_checkpoint(run / LAST)
    if ckpt["model_config"] != state["model"].config:
        raise InputError(str(run / LAST), "model_config", "is another network's; expected this run's settings")
    state["model"].load_state_dict(ckpt["model_state"])
    state["opt"].load_state_dict(ckpt["optimizer"])
    state.update(step=int(ckpt["step"]), epoch=int(ckpt["epoch"]), batch=int(ckpt["batch_in_epoch"]))
    state["seconds"] = float(ckpt["train_seconds"])
    set_rng_state(ckpt["rng"])
    return state


def _save(run: Path, state: dict[str, Any], cfg: PretrainConfig, universal: dict[str, Any]) -> None:
    from lensim.restore.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, LAST, atomic_torch_save, rng_state
    from lensim.restore.divergence import check_weights

    check_weights(state["model"])
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "model_config": state["model"].config,
            "model_state": state["model"].state_dict(),
            "optimizer": state["opt"].state_dict(),
            "epoch": state["epoch"],
            "batch_in_epoch": state["batch"],
            "step": state["step"],
            "rng": rng_state(),
            "train_seconds": state["seconds"],
            "pretrain_config": asdict(cfg),
            "universal": universal,
        },
        run / LAST,
    )


def _log(run: Path, state: dict[str, Any], loss: float, folders: int) -> None:
    path = run / LOG
    if not path.exists():
        append_text(path, "step,epoch,loss,seconds,folders\n")
    append_text(path, f"{state['step']},{state['epoch']},{loss:.6g},{state['seconds']:.1f},{folders}\n")


def _done(state: dict[str, Any], cfg: PretrainConfig) -> bool:
    over_time = cfg.time_budget_s is not None and state["seconds"] >= cfg.time_budget_s
    return over_time or (cfg.max_steps is not None and state["step"] >= cfg.max_steps)


def _step(state: dict[str, Any], batch: dict[str, torch.Tensor]) -> float:
    from lensim.restore.batches import model_inputs

    model, opt, device, scaler = state["model"], state["opt"], state["device"], state["scaler"]
    with torch.autocast(device.type, dtype=state["autocast"], enabled=state["autocast"] is not None):
        out = model(*model_inputs(batch, device))
    loss = torch.nn.functional.mse_loss(out.float(), batch["target"].to(device, non_blocking=True))
    if not torch.isfinite(loss):
        raise InputError(None, "lr", f"the loss is {float(loss)} at step {state['step']}; expected a lower lr")
    opt.zero_grad(set_to_none=True)
    scaler.scale(loss).backward()
    scaler.step(opt)
    scaler.update()
    state["step"] += 1
    return loss.item()


def pretrain(
    folders: Sequence[str | Path],
    run_dir: str | Path,
    config: PretrainConfig | None = None,
    progress: Callable[[float, float], None] | None = None,
    call_budget_s: float | None = None,
    cache_workers: int = 1,
) -> PretrainResult:
    """Pretrain (or continue pretraining) the universal network on the pairs folders
    (module docstring) into run_dir. progress(seconds, budget) after every step;
    call_budget_s: this call stops (checkpointed) after that many seconds of training;
    cache_workers: folders whose Wiener stage caches are computed at a time before
    training (:func:`stage_caches`)."""
    from lensim.restore.batches import collate, epoch_batches

    cfg = config or PretrainConfig()
    run = Path(run_dir)
    with folder_lock(run):
        atomic_write_json(run / "config.json", {**asdict(cfg), "folders": [str(f) for f in folders]})
        stage_caches(folders, cfg.network(), cache_workers)
        data = pool(folders, cfg.crop, cfg.seed, cfg.network())
        universal = _ranges(folders)
        state = _resume(run, cfg)
        if call_budget_s is not None:
            total = state["seconds"] + call_budget_s
            cfg = replace(cfg, time_budget_s=total if cfg.time_budget_s is None else min(cfg.time_budget_s, total))
        state["model"].train()
        start, last_save, losses = time.perf_counter() - state["seconds"], time.perf_counter(), []
        while not _done(state, cfg):
            batches = epoch_batches(len(data), cfg.batch_size, cfg.seed, state["epoch"])
            _set_epoch(data, state["epoch"])
            for b in range(state["batch"], len(batches)):
                losses.append(_step(state, collate([data[i] for i in batches[b]])))
                state["batch"], state["seconds"] = b + 1, time.perf_counter() - start
                if progress:
                    progress(state["seconds"], cfg.time_budget_s or 0.0)
                if time.perf_counter() - last_save >= cfg.checkpoint_every_s or _done(state, cfg):
                    _save(run, state, cfg, universal)
                    _log(run, state, sum(losses) / len(losses), len(folders))
                    last_save, losses = time.perf_counter(), []
                if _done(state, cfg):
                    break
            else:
                state["epoch"], state["batch"] = state["epoch"] + 1, 0
        _save(run, state, cfg, universal)
        if losses:
            _log(run, state, sum(losses) / len(losses), len(folders))
    last = _last_loss(run)
    return PretrainResult(str(run), state["step"], state["epoch"], state["seconds"], last, len(folders))


def _last_loss(run: Path) -> float | None:
    path = run / LOG
    if not path.exists():
        return None
    rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    return float(rows[-1]["loss"]) if rows else None


def ship(run_dir: str | Path, dest: str | Path = MODEL_DIR) -> Path:
    """Write the run's model for inference into dest/model.pt (format, model_config,
    model_state, universal, pretrain_config, step, train_seconds) and copy its log; the path."""
    from lensim.io import atomic_write_text
    from lensim.restore.checkpoint import LAST, atomic_torch_save, read_checkpoint

    run, out = Path(run_dir), Path(dest)
    ckpt = read_checkpoint(run / LAST)
    keep = ("format", "version", "model_config", "model_state", "universal", "pretrain_config", "step")
    model = {k: ckpt[k] for k in keep}
    model["train_seconds"] = ckpt["train_seconds"]
    atomic_torch_save(model, out / MODEL_FILE)
    if (run / LOG).exists():
        atomic_write_text(out / "training_log.csv", (run / LOG).read_text(encoding="utf-8"))
    return out / MODEL_FILE


def model_path(name_or_path: str | Path) -> Path:
    """The shipped model for the name "universal", else the path (a file or a folder
    holding model.pt); InputError when there is none."""
    p = MODEL_DIR / MODEL_FILE if str(name_or_path) == NAME else Path(name_or_path)
    if p.is_dir():
        p = p / MODEL_FILE
    if not p.is_file():
        raise InputError(str(p), None, "no universal model here; expected lensim/assets/models/universal/model.pt")
    return p


def is_universal_model(path: str | Path) -> bool:
    """Whether path is a universal model as `ship` writes it (a folder holding model.pt, or
    that file) with its ``universal`` record; False for anything else, a training run included
    (its folder holds last.pt/best.pt, not model.pt)."""
    from lensim.restore.checkpoint import read_checkpoint

    try:
        p = model_path(path)
        return p.suffix == ".pt" and "universal" in read_checkpoint(p)
    except InputError:
        return False


def load_universal(name_or_path: str | Path = NAME) -> tuple[torch.nn.Module, dict[str, Any]]:
    """The universal network (eval mode, float32) and its ``universal`` record (ranges)."""
    from lensim.restore.checkpoint import load_checkpoint

    path = model_path(name_or_path)
    model, ckpt = load_checkpoint(path)
    return model, dict(ckpt.get("universal") or {})


def check_range(universal: dict[str, Any], key: str, value: float, where: str) -> None:
    """InputError (one line naming `where`) when `value` of `key` ("pixel_pitch_um": the
    sensor's pitch in um, "fno": the F-number) lies outside what the model was trained
    across (RANGE_MARGIN beyond either end allowed); nothing when it records no range."""
    what = {"pixel_pitch_um": "um pixel pitch", "fno": "F-number"}[key]
    rng = universal.get(key)
    if not rng:
        return
    lo, hi = float(rng[0]), float(rng[1])
    if not (math.isfinite(value) and lo * (1 - RANGE_MARGIN) <= value <= hi * (1 + RANGE_MARGIN)):
        raise InputError(
            where,
            key,
            f"{value:g} {what} is outside the universal model's range {lo:g}..{hi:g}; "
            "expected a lens and sensor like those it was trained on (or train a model for this lens)",
        )


def load_lens_or_entry(name: str | Path) -> Any:
    """A lens file, a built-in lens or a library entry by name (lensim.assets.library)."""
    from lensim.assets.library import library_index, load_library_lens
    from lensim.optics.lens_file import load_lens

    if not Path(name).exists() and str(name) in {e.name for e in library_index()}:
        return load_library_lens(str(name))
    return load_lens(name, warn=False)


def zero_shot_fno(lens: Any, fno: float | None) -> float:
    """The F-number the lens is used at: `fno`, else its own (image space, at infinity)."""
    if fno is not None:
        return float(fno)
    from lensim.optics.shooting import ShootingSettings, describe

    return float(describe(lens, ShootingSettings(focus_m=math.inf))["fno"])


def zero_shot_bank(
    lens: Any,
    sensor: Any,
    fno: float | None,
    focus_m: float | None,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> Any:
    """The lens's PSF bank at the sensor's pitch and these settings, with the library's bank
    settings (lensim.data.library_banks.LIBRARY_BANK_SETTINGS), from the bank cache or
    computed into it (progress(fields done, fields)): what a PSF-informed universal network
    reads."""
    import warnings

    from lensim.data.library_banks import LIBRARY_BANK_SETTINGS
    from lensim.optics.shooting import ShootingSettings
    from lensim.psf.bank import get_bank

    shot = None if fno is None and focus_m is None else ShootingSettings(fno=fno, focus_m=focus_m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # wide open within a sixth of a stop
        return get_bank(
            lens,
            sensor.pixel_pitch_um,
            LIBRARY_BANK_SETTINGS,
            response=sensor.spectral_response,
            shooting=shot,
            workers=workers,
            progress=progress,
        )


def init_path(init: str | Path) -> Path:
    """The checkpoint file a run starts from: the shipped model for "universal", else the
    run folder's or checkpoint's (lensim.restore.checkpoint.resolve_checkpoint)."""
    from lensim.restore.checkpoint import resolve_checkpoint

    return model_path(NAME) if str(init) == NAME else resolve_checkpoint(init)


def load_init(model: torch.nn.Module, init: str | Path) -> None:
    """Load the weights of checkpoint `init` ("universal": the shipped model) into `model`
    (a new run's network); InputError naming "init" when they are another network's."""
    from lensim.restore.checkpoint import read_checkpoint

    path = init_path(init)
    ckpt = read_checkpoint(path)
    config: dict[str, Any] = getattr(model, "config")  # noqa: B009  (every lensim network has one)
    mine, theirs = _weights_config(config), _weights_config(build_config(ckpt["model_config"]))
    if mine != theirs:
        differ = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        raise InputError(
            str(path),
            "init",
            f"is another network ({', '.join(f'{k} {theirs.get(k)!r}' for k in differ)}; this run builds "
            f"{', '.join(f'{k} {mine.get(k)!r}' for k in differ)}); expected the same network",
        )
    model.load_state_dict(ckpt["model_state"])


#: The TrainConfig fields that say which network a run builds (what --init must match).
NETWORK_FIELDS = ("arch", "width", "stem", "use_fov", "use_deformable", "use_context")


def init_network(init: str | Path) -> dict[str, Any]:
    """The network of checkpoint ``init`` ("universal": the shipped model) as TrainConfig
    fields (:data:`NETWORK_FIELDS`): what a run started from it builds unless told otherwise."""
    from lensim.restore.checkpoint import read_checkpoint

    config = build_config(read_checkpoint(init_path(init))["model_config"])
    return {k: config[k] for k in NETWORK_FIELDS if k in config}


#: Config keys that do not shape a network's weights: the DCN backend, and the deformable
#: blocks' settings of a network without deformable blocks.
_DEFORMABLE_KEYS = ("deformable_groups", "deformable_scales")


def _weights_config(config: dict[str, Any]) -> dict[str, Any]:
    """The part of a network's config that decides its weights (what --init must match)."""
    drop = {"dcn_backend", *(() if config.get("use_deformable") else _DEFORMABLE_KEYS)}
    return {k: v for k, v in config.items() if k not in drop}


def build_config(config: dict[str, Any]) -> dict[str, Any]:
    """The full config of the network a (possibly partial) config builds."""
    from lensim.restore.models import build_model

    with torch.device("meta"):
        built: dict[str, Any] = getattr(build_model(config), "config")  # noqa: B009
    return dict(built)
