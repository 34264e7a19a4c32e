"""The paper's ablation (Table 2): the field-aware network with each idea switched off in
turn (FOV input, deformable decoder, context block), and a plain UNet of about the same
parameter count, trained on the same pairs with the same time budget and evaluated on the
same held-out photos."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from lensim.data.manifest import read_held_out, read_pairs_manifest
from lensim.errors import InputError
from lensim.io import atomic_write_json, folder_lock, read_json
from lensim.restore.network import FieldAwareUNet, count_parameters, plain_unet_width
from lensim.restore.train import TrainConfig, budget_progress, train

VARIANTS: dict[str, dict] = {
    "full": {},
    "no-fov": {"use_fov": False},
    "no-deformable": {"use_deformable": False},
    "no-context": {"use_context": False},
    "plain-unet": {"use_fov": False, "use_deformable": False, "use_context": False},
}


def run_ablation(pairs_dir: str | Path, out_dir: str | Path, time_budget_s: float, width: int = TrainConfig.width,
                 crop: int | None = TrainConfig.crop, seed: int = TrainConfig.seed, variants: list[str] | None = None,
                 say: Callable[[str], None] | None = None, device: str = TrainConfig.device,
                 progress: Callable[[float, float], None] | None = None) -> dict:
    """Train every variant (cached: a finished run is reused) and evaluate it on the held-out
    photos of the first run's split; returns {"variants": {name: {params, train, metrics}}}.
    say(stage) announces each training and the evaluation; progress(done, total) reports
    training seconds and evaluated crops within them. out_dir is locked while it runs
    (lensim.io.folder_lock)."""
    names = variants or list(VARIANTS)
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise InputError(None, "variants", f"unknown variant {unknown[0]!r}; expected some of {', '.join(VARIANTS)}")
    if time_budget_s <= 0:
        raise InputError(None, "time_budget_s", f"expected a positive number of seconds, got {time_budget_s:g}")
    manifest = read_pairs_manifest(pairs_dir)
    with folder_lock(out_dir):
        return _run_variants(pairs_dir, manifest, Path(out_dir), time_budget_s, width, crop, seed, names,
                             say or (lambda m: None), device, progress)


def _run_variants(pairs_dir: str | Path, manifest: dict, out: Path, time_budget_s: float, width: int,
                  crop: int | None, seed: int, names: list[str], say: Callable[[str], None], device: str,
                  progress: Callable[[float, float], None] | None) -> dict:
    """run_ablation's training and evaluation, the output folder locked."""
    from lensim.evaluate.harness import checkpoint_method, evaluate

    full_params = count_parameters(FieldAwareUNet(width=width))
    results: dict[str, dict] = {}
    held_out = None
    for name in names:
        switches = dict(VARIANTS[name])
        w = plain_unet_width(full_params, 3) if name == "plain-unet" else width
        run = out / name
        marker = run / "done.json"
        if not marker.exists():
            say(f"training {name} ({time_budget_s:g} s)")
            res = train(pairs_dir, run, epochs=100_000, width=w, crop=crop, seed=seed, lr=5e-4, lr_schedule="cosine",
                        time_budget_s=time_budget_s, device=device,
                        progress=budget_progress(progress, time_budget_s), **switches)
            atomic_write_json(marker, {"steps": res.step, "seconds": res.seconds})
        held_out = held_out or read_held_out(run)
        params = count_parameters(FieldAwareUNet(width=w, **switches))
        results[name] = {"params": params, "width": w, **switches, "train": read_json(marker, "training record")}
    say("evaluating on the held-out photos")
    methods = {name: checkpoint_method(out / name, manifest.get("lens"), manifest.get("sensor"), device=device)
               for name in names}
    metrics = evaluate(pairs_dir, methods, sources=held_out, progress=progress)
    for name in names:
        results[name]["metrics"] = metrics["methods"][name]
    summary = {"held_out_photos": held_out, "time_budget_s": time_budget_s, "input": metrics["methods"]["input"],
               "variants": results}
    atomic_write_json(out / "ablation.json", summary)
    return summary
