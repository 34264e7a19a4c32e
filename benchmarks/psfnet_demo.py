"""Issue 23 item 1's measurement: the PSF-informed network (``--arch psfnet``) against the
demo's networks in the demo's setting (5 minutes of training each on the demo's pairs).

    .venv/bin/python benchmarks/psfnet_demo.py OUT [--seconds 300] [--seeds 0,1,2]

Every stage is cached in OUT (a rerun skips what exists, a killed training resumes):

1. data (benchmarks/psfnet_data.py): the demo's bank, pairs from the demo's photos and from
   the 11 unseen test photos, made as `lensim demo` makes them; the Wiener stage cache of
   the training pairs (lensim.restore.psf_stage.ensure_wiener_cache; its time is printed);
2. for each seed, three networks trained with `lensim demo`'s recipe (Adam from 5e-4,
   cosine over the budget, batch 4, 96-px crops, a quarter of the photos held out, chosen
   by the seed) for --seconds each, two at a time, one thread each, under ``nice -n 15``:
   ``plain`` (NAFNet, stem 2, no FOV: the demo's baseline), ``default`` (NAFNet + FOV,
   stem 2: the demo's field-aware network before issue 23) and ``psfnet`` (the same body
   refining the Wiener stage's image);
3. the last checkpoints scored with lensim.evaluate.harness on each seed's held-out crops
   and on every unseen crop, beside the input and the Wiener oracle: OUT/eval-*.csv (per
   crop), OUT/results.json and OUT/table.md (per seed and the mean over seeds, overall,
   per zone, per photo).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECIPE = [
    "--threads",
    "1",
    "--crop",
    "96",
    "--batch-size",
    "4",
    "--lr",
    "5e-4",
    "--lr-schedule",
    "cosine",
    "--val-fraction",
    "0.25",
    "--quiet",
]
NETWORKS = {
    "plain": ["--arch", "nafnet", "--stem", "2", "--no-fov", "--no-deformable", "--no-context"],
    "default": ["--arch", "nafnet", "--stem", "2", "--no-deformable", "--no-context"],
    "psfnet": ["--arch", "psfnet", "--stem", "2", "--no-deformable", "--no-context"],
}
METHODS = ["input", "wiener", *NETWORKS]


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}


def prepare(out: Path) -> None:
    """Stage 1."""
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "psfnet_data.py"), str(out)], check=True, env=_env())
    from lensim.restore.psf_stage import ensure_wiener_cache

    t = time.perf_counter()
    folder = ensure_wiener_cache(out / "pairs")
    print(f"Wiener stage cache {folder}: {time.perf_counter() - t:.1f} s", flush=True)


def _command(out: Path, name: str, seed: int, budget: tuple[float, int]) -> list[str]:
    """The run's `lensim train` command: a time budget (seconds, epochs 0) or, with epochs >
    0, that many epochs (the cosine schedule over them) and no time budget."""
    run = out / f"{name}-s{seed}"
    args = [sys.executable, "-m", "lensim", "train", str(out / "pairs"), "-o", str(run)]
    if (run / "last.pt").exists():
        return ["nice", "-n", "15", *args, "--resume", "--quiet"]
    seconds, epochs = budget
    limit = ["--epochs", str(epochs)] if epochs else ["--time-budget-s", f"{seconds:g}", "--epochs", "100000"]
    return ["nice", "-n", "15", *args, *limit, "--seed", str(seed), *RECIPE, *NETWORKS[name]]


def train_all(out: Path, seeds: list[int], budget: tuple[float, int]) -> None:
    """Stage 2 (cached by NAME-sSEED.done), two runs at a time."""
    import shutil

    order = [(n, s) for s in seeds for n in ("psfnet", "default", "plain")]
    todo = [(n, s) for n, s in order if not (out / f"{n}-s{s}.done").exists()]
    for i in range(0, len(todo), 2):
        procs = []
        for name, seed in todo[i : i + 2]:
            run = out / f"{name}-s{seed}"
            if run.exists() and not (run / "last.pt").exists():
                shutil.rmtree(run)
            procs.append((name, seed, subprocess.Popen(_command(out, name, seed, budget), cwd=ROOT, env=_env())))
        for name, seed, p in procs:
            if p.wait() != 0:
                raise SystemExit(f"training {name} seed {seed} failed (exit {p.returncode})")
            (out / f"{name}-s{seed}.done").write_text(time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()) + "\n")


def _steps(run: Path) -> int:
    from lensim.restore.checkpoint import read_checkpoint

    return int(read_checkpoint(run / "last.pt")["step"])


def evaluate_all(out: Path, seeds: list[int]) -> dict:
    """Stage 3: per seed, its held-out crops and every unseen crop (cached per CSV)."""
    from lensim.data.manifest import read_held_out
    from lensim.evaluate.harness import builtin_method, checkpoint_method, evaluate_rows, summarize, write_csv

    results: dict = {}
    for seed in seeds:
        nets = [n for n in NETWORKS if (out / f"{n}-s{seed}.done").exists()]  # those trained so far
        for label, pairs, sources in (
            ("held_out", out / "pairs", read_held_out(out / f"psfnet-s{seed}")),
            ("unseen", out / "pairs-test", None),
        ):
            csv_path = out / f"eval-{label}-s{seed}.csv"
            rows = _read_rows(csv_path) if csv_path.exists() else []
            todo = [n for n in ["wiener", *nets] if n not in {r["method"] for r in rows}]
            if todo:
                methods = {n: checkpoint_method(out / f"{n}-s{seed}" / "last.pt") for n in todo if n != "wiener"}
                if "wiener" in todo:
                    methods = {"wiener": builtin_method("wiener"), **methods}
                new = evaluate_rows(pairs, methods, bank=out / "bank", sources=sources)
                rows += [r for r in new if r["method"] != "input" or not rows]
                write_csv(rows, csv_path)
                rows = _read_rows(csv_path)
            results[f"{label}-s{seed}"] = {
                "summary": summarize(rows),
                "photos": _per_photo(rows),
                "steps": {n: _steps(out / f"{n}-s{seed}") for n in nets},
            }
    return results


def _read_rows(path: Path) -> list[dict]:
    import csv
    import math

    def num(v: str) -> object:
        try:
            return float(v) if v != "" else math.nan
        except ValueError:
            return v

    with open(path, newline="") as f:
        return [{k: num(v) for k, v in r.items()} for r in csv.DictReader(f)]


def _per_photo(rows: list[dict]) -> dict:
    out: dict = {}
    for r in rows:
        m = out.setdefault(Path(str(r["source"])).stem, {}).setdefault(r["method"], {"psnr": [], "ssim": []})
        m["psnr"].append(float(r["psnr_db"]))
        m["ssim"].append(float(r["ssim"]))
    return {
        p: {k: [statistics.mean(v["psnr"]), statistics.mean(v["ssim"])] for k, v in ms.items()} for p, ms in out.items()
    }


def _present(runs: list[dict]) -> list[str]:
    """The methods every run scored, in METHODS order."""
    return [n for n in METHODS if all(n in r["summary"]["methods"] for r in runs)]


def _row(name: str, runs: list[dict]) -> str:
    """One method's line: PSNR (gain over input) and SSIM, mean over the seeds; zone gains."""
    ms = [r["summary"]["methods"] for r in runs]
    psnr = statistics.mean(m[name]["psnr_db"] for m in ms)
    base = statistics.mean(m["input"]["psnr_db"] for m in ms)
    ssim = statistics.mean(m[name]["ssim"] for m in ms)
    zones = " / ".join(
        f"{statistics.mean(m[name]['zones'][z]['psnr_db'] - m['input']['zones'][z]['psnr_db'] for m in ms):+.2f}"
        for z in ("centre", "middle", "edge")
    )
    per_seed = " / ".join(f"{m[name]['psnr_db']:.2f}" for m in ms)
    return f"| {name} | {psnr:.2f} ({psnr - base:+.2f}) | {ssim:.3f} | {zones} | {per_seed} |"


def tables(results: dict, seeds: list[int]) -> str:
    lines = []
    for label in ("held_out", "unseen"):
        runs = [results[f"{label}-s{s}"] for s in seeds]
        lines += [
            f"### {label.replace('_', '-')} photos, mean over seeds {', '.join(map(str, seeds))}",
            "",
            "| method | PSNR dB (gain) | SSIM | gain centre / middle / edge | PSNR per seed |",
            "| --- | ---: | ---: | --- | --- |",
            *[_row(n, runs) for n in _present(runs)],
            "",
        ]
        nets = [n for n in _present(runs) if n in NETWORKS]
        steps = " ; ".join(f"{n} " + "/".join(str(r["steps"][n]) for r in runs) for n in nets)
        lines += [f"Training steps per seed: {steps}.", ""]
        photos = sorted(runs[0]["photos"]) if label == "unseen" else []
        if photos and "psfnet" in nets:
            present = _present(runs)
            refs = [n for n in ("wiener", "default", "plain") if n in present]
            lines += [
                "| photo | " + " | ".join(present) + " | " + " | ".join(f"psfnet - {n}" for n in refs) + " |",
                "| --- |" + " ---: |" * (len(present) + len(refs)),
            ]
            for p in photos:
                v = {n: statistics.mean(r["photos"][p][n][0] for r in runs) for n in present}
                lines.append(
                    f"| {p} | "
                    + " | ".join(f"{v[n]:.2f}" for n in present)
                    + " | "
                    + " | ".join(f"{v['psfnet'] - v[n]:+.2f}" for n in refs)
                    + " |"
                )
            lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument(
        "--epochs",
        type=int,
        default=0,
        help="train this many epochs instead of --seconds (17 epochs of the demo's pairs: 1,734 steps, "
        "what 5 minutes give on a quiet 2-core machine)",
    )
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--stage", choices=("all", "data", "train", "evaluate"), default="all")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    if a.stage in ("all", "data"):
        prepare(a.out)
    if a.stage in ("all", "train"):
        train_all(a.out, seeds, (a.seconds, a.epochs))
    if a.stage in ("all", "evaluate"):
        results = evaluate_all(a.out, seeds)
        (a.out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
        text = tables(results, seeds)
        (a.out / "table.md").write_text(text + "\n")
        print(text)


if __name__ == "__main__":
    main()
