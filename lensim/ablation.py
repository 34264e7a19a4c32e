"""The paper's ablation (Table 2): the field-aware network with each idea switched off in
turn (FOV input, deformable decoder, context block), and a plain network of about the same
parameter count, trained on the same pairs with the same time budget and evaluated on the
same held-out photos. Either architecture (lensim.restore.models): the field-aware UNet
("unet", the paper's) or NAFNet with the same switches ("nafnet"; its plain variant is
called plain-nafnet).

A killed ablation resumes when run again with the same options: finished variants are
reused (RUN/done.json), an unfinished one continues from its RUN/last.pt on the rest of its
time budget (lensim.restore.train's resume), and one killed before its first checkpoint
starts again. torch and the training modules load when run_ablation runs."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lensim.data.manifest import read_held_out, read_pairs_manifest
from lensim.errors import InputError
from lensim.io import atomic_write_json, folder_lock, read_json
from lensim.restore.config import TrainConfig

#: The full network of the paper's ablation: FOV input, deformable decoder, context block,
#: and no stem (STEM), for either architecture. Every variant names all its switches, so
#: TrainConfig's defaults (the default network has neither deformable blocks, nor the
#: context block, and a 2x stem) do not change what an ablation trains.
FULL = {"use_fov": True, "use_deformable": True, "use_context": True}
ALL_OFF = {"use_fov": False, "use_deformable": False, "use_context": False}
STEM = 1
VARIANTS: dict[str, dict] = {
    "full": FULL,
    "no-fov": {**FULL, "use_fov": False},
    "no-deformable": {**FULL, "use_deformable": False},
    "no-context": {**FULL, "use_context": False},
    "plain-unet": ALL_OFF,
}


def variants_for(arch: str) -> dict[str, dict]:
    """The ablation's variants for an architecture: VARIANTS, the plain one named
    plain-nafnet for "nafnet"."""
    if arch == "unet":
        return dict(VARIANTS)
    return {("plain-nafnet" if k == "plain-unet" else k): v for k, v in VARIANTS.items()}


_ANY_WIDTH = 32  # a width every switch accepts, for reading a variant's switches (the width is dropped)


def _config(arch: str, width: int, crop: int | None, switches: dict[str, Any]) -> dict[str, Any]:
    """The model config train() builds for these settings (TrainConfig.model_kwargs)."""
    return TrainConfig(arch=arch, width=width, crop=crop, stem=STEM, **switches).model_kwargs()


def run_ablation(
    pairs_dir: str | Path,
    out_dir: str | Path,
    time_budget_s: float,
    width: int | None = None,
    crop: int | None = TrainConfig.crop,
    seed: int = TrainConfig.seed,
    variants: list[str] | None = None,
    say: Callable[[str], None] | None = None,
    device: str = TrainConfig.device,
    progress: Callable[[float, float], None] | None = None,
    arch: str = "unet",
) -> dict:
    """Train every variant (cached: a finished run is reused) and evaluate it on the held-out
    photos of the first run's split; returns {"arch", "variants": {name: {params, train,
    metrics}}}. width: of the full network (None: the architecture's default, matched to the
    paper's UNet's size, lensim.restore.models.reference_parameters). say(stage) announces each training and the evaluation;
    progress(done, total) reports training seconds and evaluated crops within them. out_dir
    is locked while it runs (lensim.io.folder_lock). A variant's run folder left unfinished
    by a kill (no done.json) continues from its last.pt (_train_variant)."""
    from lensim.restore.models import ARCHS, default_width

    if arch not in ARCHS:
        raise InputError(None, "arch", f"expected one of {', '.join(ARCHS)}, got {arch!r}")
    table = variants_for(arch)
    names = variants or list(table)
    unknown = [n for n in names if n not in table]
    if unknown:
        raise InputError(None, "variants", f"unknown variant {unknown[0]!r}; expected some of {', '.join(table)}")
    if time_budget_s <= 0:
        raise InputError(None, "time_budget_s", f"expected a positive number of seconds, got {time_budget_s:g}")
    manifest = read_pairs_manifest(pairs_dir)
    if width is None:
        full = {k: v for k, v in _config(arch, _ANY_WIDTH, crop, FULL).items() if k not in ("arch", "width", "depth")}
        width = default_width(arch, **full)
    with folder_lock(out_dir):
        return _run_variants(
            pairs_dir,
            manifest,
            Path(out_dir),
            time_budget_s,
            width,
            crop,
            seed,
            {n: table[n] for n in names},
            say or (lambda m: None),
            device,
            progress,
            arch,
        )


def _plain_width(arch: str, width: int, crop: int | None) -> int:
    """Width of the plain network (every switch off) with the full network's parameter count."""
    from lensim.restore.models import build_model
    from lensim.restore.nafnet import nafnet_width
    from lensim.restore.network import count_parameters, plain_unet_width

    full = count_parameters(build_model(_config(arch, width, crop, FULL)))
    if arch == "unet":
        return plain_unet_width(full, 3)
    plain = {k: v for k, v in _config(arch, _ANY_WIDTH, crop, ALL_OFF).items() if k not in ("arch", "width", "depth")}
    return nafnet_width(full, **plain)


def _train_variant(
    pairs_dir: str | Path,
    run: Path,
    time_budget_s: float,
    device: str,
    progress: Callable[[float, float], None] | None,
    network: dict[str, Any],
) -> Any:
    """Train one variant into ``run`` for ``time_budget_s`` seconds in all: a fresh run, or
    the continuation of one a kill left there (RUN/last.pt: same data order and schedule, the
    budget counts the seconds trained before; a changed network or crop is refused in one
    line naming last.pt). A folder without last.pt (killed before its first checkpoint)
    holds nothing to continue and is started again. Returns the TrainResult."""
    from lensim.restore.checkpoint import LAST
    from lensim.restore.train import budget_progress, train

    resume = (run / LAST).is_file()
    if run.exists() and not resume:
        shutil.rmtree(run)
    return train(
        pairs_dir,
        run,
        resume=resume,
        epochs=100_000,
        lr=5e-4,
        lr_schedule="cosine",
        time_budget_s=time_budget_s,
        device=device,
        progress=budget_progress(progress, time_budget_s),
        **network,
    )


def _run_variants(
    pairs_dir: str | Path,
    manifest: dict,
    out: Path,
    time_budget_s: float,
    width: int,
    crop: int | None,
    seed: int,
    variants: dict[str, dict],
    say: Callable[[str], None],
    device: str,
    progress: Callable[[float, float], None] | None,
    arch: str,
) -> dict:
    """run_ablation's training and evaluation, the output folder locked."""
    from lensim.evaluate.harness import checkpoint_method, evaluate
    from lensim.restore.models import build_model
    from lensim.restore.network import count_parameters

    results: dict[str, dict] = {}
    held_out = None
    for name, switches in variants.items():
        w = _plain_width(arch, width, crop) if switches == ALL_OFF else width
        run = out / name
        marker = run / "done.json"
        if not marker.exists():
            say(f"training {name} ({time_budget_s:g} s)")
            res = _train_variant(
                pairs_dir,
                run,
                time_budget_s,
                device,
                progress,
                dict(arch=arch, width=w, crop=crop, seed=seed, stem=STEM, **switches),
            )
            atomic_write_json(marker, {"steps": res.step, "seconds": res.seconds})
        held_out = held_out or read_held_out(run)
        params = count_parameters(build_model(_config(arch, w, crop, switches)))
        results[name] = {
            "params": params,
            "arch": arch,
            "width": w,
            **switches,
            "train": read_json(marker, "training record"),
        }
    say("evaluating on the held-out photos")
    methods = {
        name: checkpoint_method(out / name, manifest.get("lens"), manifest.get("sensor"), device=device)
        for name in variants
    }
    metrics = evaluate(pairs_dir, methods, sources=held_out, progress=progress)
    for name in variants:
        results[name]["metrics"] = metrics["methods"][name]
    summary = {
        "arch": arch,
        "held_out_photos": held_out,
        "time_budget_s": time_budget_s,
        "input": metrics["methods"]["input"],
        "variants": results,
    }
    atomic_write_json(out / "ablation.json", summary)
    return summary
