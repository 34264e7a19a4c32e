"""Fine-tuning from the universal model against training from scratch, on a held-out library
lens (issue 23, item 5): the same PSF-informed network (the universal model's: psfnet, its
width and stem), the same pairs, the same wall-clock budget, one started from the shipped
universal model's weights (``--init universal``), one from a random initialisation.

Training pairs: the built-in training photos (never the unseen test photos), 384 px centre
crops through the lens's first library bank (wide open, infinity, the 24 MP sensor of its
format) at 3 sensor positions, 2 crops of 128 px each (lensim.data.pairs.make_dataset).
Scored on the zero-shot benchmark's pairs of that lens (benchmarks/universal_zero_shot.py:
the 11 unseen photos, 33 crops), per zone: input, the Wiener oracle, the universal model
zero-shot, fine-tuned, from scratch.

Budget: ``--minutes`` of wall-clock training each (the cosine schedule over the time), or
``--steps`` optimizer steps each (the cosine schedule over the steps; the GPU check uses it
to give each run the steps of a 30-minute CPU run, benchmarks/gpu_check.sh). ``--device
cuda`` trains on the GPU (mixed precision); pairs and scores are made on the CPU.

Resumable: pairs and each finished run are kept in OUT (a killed run is trained again).

    OMP_NUM_THREADS=1 nice -n 15 python benchmarks/universal_finetune.py --library LIBDIR \\
        --lens canon_rf16_f2.8_jp2022085382 --eval-pairs ZS/canon_rf16_f2.8_jp2022085382/pairs \\
        --minutes 5 -o OUT
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path


def lens_bank(library: Path, lens: str) -> tuple:
    """(planned bank, bank folder, sensor file) of the lens's first complete library bank."""
    from lensim.data import library_banks as lb

    for b, d, s in lb.library_banks(library, holdout=True):
        if b.lens == lens:
            return b, d, s
    raise SystemExit(f"{library}: no complete held-out bank of {lens}")


def training_pairs(out: Path, bank_dir: Path, sensor_file: Path) -> Path:
    """The lens's training pairs (made once)."""
    from lensim.assets.images import available_sample_images, write_centre_crops
    from lensim.data.pairs import make_dataset
    from lensim.psf.bank import PSFBank
    from lensim.sensor.profile import load_sensor

    photos = out / "photos"
    write_centre_crops(available_sample_images(), photos, 384)
    pairs = out / "pairs"
    sensor = load_sensor(sensor_file)
    make_dataset(photos, pairs, PSFBank.load(bank_dir), str(sensor_file), sensor, crops=2, size=128, placements=3)
    return pairs


BATCH = 8


def budget(pairs: Path, minutes: float, steps: int | None) -> dict:
    """train()'s budget settings: a time budget, or ``steps`` steps rounded up to whole
    epochs of the pairs folder (every crop trains; a last partial batch is dropped)."""
    if steps is None:
        return {"epochs": 100_000, "time_budget_s": minutes * 60.0}
    from lensim.data.manifest import read_pairs_manifest

    crops = sum(len(r.get("crops", [])) for r in read_pairs_manifest(pairs)["records"])
    per_epoch = max(1, crops // BATCH)
    return {"epochs": -(-steps // per_epoch), "time_budget_s": None}


#: run name -> (folder suffix, init, learning rate): fine-tuned from the universal model at
#: 2e-4, from scratch at 5e-4, and fine-tuned at half the rate (does a gentler start keep more
#: of what pretraining learned?)
RUNS = {
    "fine-tuned": ("tuned", "universal", 2e-4),
    "scratch": ("scratch", None, 5e-4),
    "fine-tuned-lr1e-4": ("tuned-lr1e-4", "universal", 1e-4),
}


def train_run(
    pairs: Path, run: Path, limits: dict, init: str | None, device: str = "cpu", amp: bool = True, lr: float = 2e-4
) -> dict:
    """One run on the universal model's network (made once: RUN/done.json); limits:
    :func:`budget`'s; lr: the initial learning rate (cosine)."""
    import time

    from lensim.restore.train import train
    from lensim.restore.universal import NAME, init_network

    if (run / "done.json").exists():
        return json.loads((run / "done.json").read_text())
    if run.exists():
        shutil.rmtree(run)
    start = time.perf_counter()
    res = train(
        pairs,
        run,
        **init_network(NAME),  # psfnet, its width and stem, FOV on, no deformable or context block
        **limits,
        batch_size=BATCH,
        lr=lr,
        lr_schedule="cosine",
        crop=96,
        val_fraction=0.0,
        seed=0,
        init=init,
        device=device,
        amp=amp,
    )
    info = {"steps": res.step, "seconds": round(time.perf_counter() - start, 1), "init": init, "device": device}
    (run / "done.json").write_text(json.dumps(info))
    return info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, required=True)
    ap.add_argument("--lens", required=True, help="a held-out library lens")
    ap.add_argument("--eval-pairs", type=Path, required=True, help="the zero-shot benchmark's pairs of that lens")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--steps", type=int, default=None, help="steps per run instead of --minutes")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-amp", action="store_true", help="float32 on CUDA (faster for this small network)")
    ap.add_argument(
        "--runs",
        default="fine-tuned,scratch",
        help=f"the runs this call trains, of {', '.join(RUNS)} (calls may train one each, side by side, once "
        "the pairs exist); every finished run in OUT is scored",
    )
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args()

    import torch

    from lensim.evaluate import harness
    from lensim.restore.universal import NAME, model_path

    torch.set_num_threads(args.threads)
    out = args.output
    planned, bank_dir, sensor_file = lens_bank(args.library, args.lens)
    pairs = training_pairs(out, bank_dir, sensor_file)
    limits = budget(pairs, args.minutes, args.steps)
    for name in args.runs.split(","):
        d, init, lr = RUNS[name]
        train_run(pairs, out / f"run-{d}", limits, init, args.device, not args.no_amp, lr)
    runs = {name: r for name, r in RUNS.items() if (out / f"run-{r[0]}" / "done.json").exists()}
    info = {name: json.loads((out / f"run-{r[0]}" / "done.json").read_text()) for name, r in runs.items()}
    methods = {
        "wiener": harness.builtin_method("wiener"),
        "universal": harness.checkpoint_method(model_path(NAME), tile=128, overlap=0),
    }
    for name, (d, _, _) in runs.items():
        methods[name] = harness.checkpoint_method(out / f"run-{d}" / "last.pt", tile=128, overlap=0)
    scores = harness.evaluate(args.eval_pairs, methods)["methods"]
    result = {
        "lens": args.lens,
        "bank": planned.id,
        "minutes": None if args.steps else args.minutes,
        "steps": args.steps,
        "runs": info,
        "methods": scores,
    }
    (out / "result.json").write_text(json.dumps(result, indent=1))
    lines = ["| method | PSNR (dB) | SSIM | centre | middle | edge |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, m in scores.items():
        zones = " | ".join(f"{m['zones'][z]['psnr_db']:.2f}" for z in ("centre", "middle", "edge"))
        lines.append(f"| {name} | {m['psnr_db']:.2f} | {m['ssim']:.3f} | {zones} |")
    (out / "result.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
