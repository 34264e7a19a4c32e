"""Restoration of photos from a perturbed camera, three models compared (issue 24, item 5).

The camera is calibration_validation.py's `focus_decentre`: phone_wide at 1 m on the phone
sensor with focus +6 um and element 3 decentred 4 um in x. Three PSF-informed networks,
each fine-tuned from the universal model (`lensim train --init universal`) on the same time
budget and seed, are compared on the perturbed camera's photos:

  (a) nominal     trained on pairs through the nominal lens;
  (b) calibrated  trained on pairs through the as-built lens `lensim calibrate --candidates 3`
                  recovered (benchmarks/results/calibration/candidates3/focus_decentre.json,
                  made a lens by lensim.calibrate.tolerances.perturbed_lens as the validation
                  does);
  (c) tolerances  trained on pairs through TOLERANCE_DRAWS draws of TOLERANCES
                  (`lensim dataset make --tolerances`).

The test pairs are simulated through the true perturbed lens from photos no training set
contains (every TEST_EVERY-th built-in sample photo; the others are the training photos).
Each network's Wiener stage uses the bank its user would have: the nominal lens's for (a)
and (c), the calibrated lens's for (b) (`lensim evaluate --bank`); the Wiener oracle uses
the true lens's bank. In training, (c)'s stage of each pair uses the bank of the draw the
pair went through (lensim's rule for tolerance pairs; before, every pair's was draw 0's,
and this script computed them all with the nominal lens's). Scored by `lensim evaluate`
per field zone (centre, middle, edge) and per photo.

A lens with decentres is not rotationally symmetric; its PSF bank is computed along +y
and rotated to every azimuth like any bank (the test camera "is" that bank; the chart
validation renders one bank per quadrant instead).

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_restoration.py \\
        --out /tmp/calibration-restoration --results benchmarks/results/calibration/restoration

Resumable: every stage's output is kept under --out (lenses, photos, pairs, runs, evals)
and skipped on a rerun (dataset make and train resume themselves); --results gets
table.md and restoration.json.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

LENS, SENSOR, DISTANCE_M = "phone_wide", "phone", 1.0
TRUTH = {"image.focus": 0.006, "e3.decentre_x": 0.004}
FIT = Path(__file__).parent / "results/calibration/candidates3/focus_decentre.json"
#: the unit-to-unit spread model (c) trains with: a maker's tolerance file, not fitted to this unit
TOLERANCES = """\
distribution: uniform
elements:
  all: {decentre_mm: 0.005, tilt_deg: 0.05, spacing_mm: 0.003}
image: {focus_mm: 0.008, tilt_deg: 0.05}
"""
TEST_EVERY = 5
ZONES = ("centre", "middle", "edge")
MODELS = {"nominal": "nominal", "calibrated": "calibrated", "tolerances": "nominal"}  # model -> its stage's lens
FULL = dict(
    photo=384,
    crops=2,
    test_crops=4,
    size=128,
    placements=3,
    fields=7,
    wl="450:650:50",
    pupil=64,
    draws=4,
    budget=300.0,
    train_crop=96,
)
TINY = dict(
    photo=160,
    crops=1,
    test_crops=1,
    size=64,
    placements=3,
    fields=3,
    wl="450,550,650",
    pupil=32,
    draws=2,
    budget=20.0,
    train_crop=64,
)


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def lensim(*args: str) -> str:
    """Run the lensim CLI (this interpreter, one torch thread); its stdout."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-m", "lensim", *args], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"lensim {' '.join(args)} failed ({res.returncode}): {res.stderr.strip()[-2000:]}")
    return res.stdout


def make_lenses(out: Path) -> dict[str, Path]:
    """The nominal, calibrated and true lenses at the chart's 1 m (JSON lens files) and the tolerance file."""
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens
    from lensim.optics.shooting import ShootingSettings, lens_at

    d = out / "lenses"
    d.mkdir(parents=True, exist_ok=True)
    lens = lens_at(load_lens(LENS, warn=False), ShootingSettings(object_m=DISTANCE_M, focus_m=DISTANCE_M))
    fitted = json.loads(FIT.read_text())["fitted"]
    lenses = {"nominal": lens, "calibrated": perturbed_lens(lens, fitted), "truth": perturbed_lens(lens, TRUTH)}
    paths = {k: d / f"{k}.json" for k in lenses}
    for k, m in lenses.items():
        if not paths[k].exists():
            save_lens(m, paths[k])  # JSON: save_lens to YAML fails on a lens_at lens's numpy floats
    tol = d / "tolerances.yaml"
    if not tol.exists():
        tol.write_text(TOLERANCES)
    paths["tolerances"] = tol
    return paths


def split_photos(out: Path, size: int, tiny: bool) -> tuple[Path, Path]:
    """The built-in sample photos centre-cropped: every TEST_EVERY-th to test/, the rest to train/."""
    from lensim.assets.images import available_sample_images, write_centre_crops

    photos = available_sample_images()
    test = photos[::TEST_EVERY]
    train = [p for p in photos if p not in test]
    if tiny:
        test, train = test[:2], train[:6]
    d = out / "photos"
    write_centre_crops(test, d / "test", size)
    write_centre_crops(train, d / "train", size)
    return d / "train", d / "test"


def make_pairs(out: Path, name: str, photos: Path, lens: Path, s: dict, tolerances: Path | None = None) -> Path:
    """`lensim dataset make` (it resumes a folder made with the same settings)."""
    pairs = out / "pairs" / name
    if (pairs / "done").exists():
        return pairs
    log(f"pairs {name}")
    args = [str(photos), "--lens", str(lens), "--sensor", SENSOR, "-o", str(pairs), "--crops", str(s["crops"])]
    args += ["--size", str(s["size"]), "--placements", str(s["placements"]), "--seed", "0", "--fields"]
    args += [str(s["fields"]), "--wavelengths-nm", s["wl"], "--pupil-samples", str(s["pupil"])]
    args += ["--cache", str(out / "cache"), "--quiet"]
    if tolerances is not None:
        args += ["--tolerances", str(tolerances), "--tolerance-draws", str(s["draws"])]
    t = time.perf_counter()
    lensim("dataset", "make", *args)
    (pairs / "done").write_text(json.dumps({"seconds": time.perf_counter() - t}))
    return pairs


def bank_of(pairs: Path) -> str:
    return json.loads((pairs / "manifest.json").read_text())["bank"]


def train(out: Path, name: str, pairs: Path, budget: float, crop: int, seed: int = 0) -> dict:
    """`lensim train --init universal` on the time budget (as the demo fine-tunes), once."""
    run = out / "runs" / name
    marker = run / "summary.json"
    if marker.exists():
        return json.loads(marker.read_text())
    log(f"train {name} ({budget:.0f} s)")
    args = ["train", str(pairs), "-o", str(run), "--init", "universal", "--time-budget-s", str(budget)]
    args += ["--epochs", "100000", "--batch-size", "4", "--lr", "2e-4", "--lr-schedule", "cosine", "--crop", str(crop)]
    args += ["--val-fraction", "0.25", "--seed", str(seed), "--threads", "1", "--json"]
    if (run / "last.pt").exists():
        args.append("--resume")
    t = time.perf_counter()
    summary = json.loads(lensim(*args))
    summary["wall_s"] = time.perf_counter() - t
    marker.write_text(json.dumps(summary, indent=1))
    log(f"train {name}: {summary['steps']} steps, val PSNR {summary['val_psnr_db']:.2f} dB")
    return summary


def evaluate(out: Path, name: str, test: Path, methods: str, bank: str | None, model: Path | None) -> Path:
    """`lensim evaluate` on the test pairs into OUT/evals/<name> (once)."""
    d = out / "evals" / name
    if (d / "metrics.json").exists():
        return d
    log(f"evaluate {name}")
    args = ["evaluate", "--pairs", str(test), "--methods", methods, "-o", str(d), "--quiet"]
    args += (["--bank", bank] if bank else []) + (["--model", str(model)] if model else [])
    lensim(*args)
    return d


def per_photo(evals: Path, method: str) -> dict[str, dict[str, float]]:
    """Per test photo: the mean PSNR (dB) over its crops ("all"), and per zone over the
    crops with pixels in that zone (each crop's PSNR over its pixels there)."""
    acc: dict[str, dict[str, list[float]]] = {}
    with open(evals / "metrics.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["method"] != method:
                continue
            mine = acc.setdefault(Path(row["source"]).stem, {})
            mine.setdefault("all", []).append(float(row["psnr_db"]))
            for z in ZONES:
                if int(row[f"{z}_pixels"]) > 0:
                    mine.setdefault(z, []).append(float(row[f"{z}_psnr_db"]))
    return {p: {k: sum(v) / len(v) for k, v in d.items()} for p, d in sorted(acc.items())}


def gather(out: Path, runs: dict[str, dict], seconds: float) -> dict:
    """Per method: overall and per-zone PSNR/SSIM, per-photo PSNR; each model's steps."""
    ev = out / "evals"
    oracle = json.loads((ev / "oracle" / "metrics.json").read_text())["methods"]
    rows = {"input": oracle["input"], "wiener (true PSFs)": oracle["wiener"]}
    photos = {"input": per_photo(ev / "oracle", "input"), "wiener (true PSFs)": per_photo(ev / "oracle", "wiener")}
    for m in runs:
        rows[m] = json.loads((ev / m / "metrics.json").read_text())["methods"]["model"]
        photos[m] = per_photo(ev / m, "model")
    keys = ("steps", "epochs_done", "seconds", "val_psnr_db", "val_input_psnr_db", "wall_s")
    train_info = {m: {k: runs[m][k] for k in keys} for m in runs}
    rows["universal (zero-shot)"] = json.loads((ev / "universal" / "metrics.json").read_text())["methods"]["universal"]
    photos["universal (zero-shot)"] = per_photo(ev / "universal", "universal")
    stages = {p.parent.name: json.loads(p.read_text())["seconds"] for p in sorted((out / "pairs").glob("*/done"))}
    return {"camera": "focus_decentre", "truth": TRUTH, "metrics": rows, "per_photo": photos, "training": train_info,
            "pairs_seconds": stages, "run_seconds_all_invocations": seconds}  # fmt: skip


def table(res: dict) -> str:
    zones = ZONES
    lines = ["| method | all PSNR / SSIM | " + " | ".join(zones) + " |", "| --- | --- | --- | --- | --- |"]
    for name, m in res["metrics"].items():
        cells = [f"{m['psnr_db']:.2f} / {m['ssim']:.3f}"]
        cells += [f"{m['zones'][z]['psnr_db']:.2f} / {m['zones'][z]['ssim']:.3f}" for z in zones]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    zs = {n: {z: res["metrics"][n]["zones"][z]["psnr_db"] for z in zones} for n in MODELS if n in res["metrics"]}
    lines += ["", "| difference (dB) | " + " | ".join(zones) + " |", "| --- | --- | --- | --- |"]
    for a, b in (("calibrated", "nominal"), ("tolerances", "calibrated"), ("tolerances", "nominal")):
        if a not in zs or b not in zs:
            continue
        lines.append(f"| {a} - {b} | " + " | ".join(f"{zs[a][z] - zs[b][z]:+.2f}" for z in zones) + " |")
    names = list(res["per_photo"])
    for zone in ("all", "edge"):
        what = "all crops" if zone == "all" else "edge zone"
        lines += ["", f"| photo ({what}, dB) | " + " | ".join(names) + " |", "|" + " --- |" * (len(names) + 1)]
        for p in res["per_photo"]["input"]:
            cells = [res["per_photo"][n].get(p, {}).get(zone, float("nan")) for n in names]
            lines.append(f"| {p} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    lines += ["", "| network (trained on) | Wiener stage's bank | all | centre | middle | edge |"]
    lines.append("| --- | --- | --- | --- | --- | --- |")
    for m, by_stage in res.get("stage_swap", {}).items():
        for stage, v in by_stage.items():
            mark = " (its own)" if stage == MODELS[m] else ""
            cells = " | ".join(f"{v[k]:.2f}" for k in ("all", *ZONES))
            lines.append(f"| {m} | {stage}{mark} | {cells} |")
    lines += ["", "| model | steps | epochs | trained s | val PSNR |", "| --- | --- | --- | --- | --- |"]
    for n, t in res["training"].items():
        lines.append(f"| {n} | {t['steps']} | {t['epochs_done']} | {t['seconds']:.0f} | {t['val_psnr_db']:.2f} |")
    return "\n".join(lines) + "\n"


def stage_swap(out: Path) -> dict[str, dict[str, dict]]:
    """Each network's PSNR (all and per zone) with each stage bank evaluated so far."""
    swap: dict[str, dict[str, dict]] = {}
    for m, own in MODELS.items():
        for stage in ("nominal", "calibrated", "truth"):
            d = out / "evals" / (m if stage == own else f"{m}@{stage}") / "metrics.json"
            if d.exists():
                v = json.loads(d.read_text())["methods"]["model"]
                swap.setdefault(m, {})[stage] = {"all": v["psnr_db"], **{z: v["zones"][z]["psnr_db"] for z in ZONES}}
    return swap


def report(out: Path, results: Path | None, runs: dict[str, dict], s: dict, seconds: float) -> None:
    """OUT/restoration.json and OUT/table.md from the stages done so far (copied to results)."""
    res = gather(out, runs, seconds)
    res["settings"] = s
    res["stage_swap"] = stage_swap(out)
    (out / "restoration.json").write_text(json.dumps(res, indent=1))
    (out / "table.md").write_text(table(res))
    if results:
        results.mkdir(parents=True, exist_ok=True)
        for f in ("restoration.json", "table.md"):
            (results / f).write_text((out / f).read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/calibration-restoration"), help="work folder (resumable)")
    ap.add_argument("--results", type=Path, default=None, help="folder for table.md and restoration.json")
    ap.add_argument("--tiny", action="store_true", help="a dry run at tiny sizes")
    args = ap.parse_args()
    s = TINY if args.tiny else FULL
    t0 = time.perf_counter()
    elapsed = args.out / "elapsed.json"  # seconds of earlier invocations (a killed run's are lost)
    before = json.loads(elapsed.read_text())["seconds"] if elapsed.exists() else 0.0
    args.out.mkdir(parents=True, exist_ok=True)
    lenses = make_lenses(args.out)
    train_photos, test_photos = split_photos(args.out, s["photo"], args.tiny)
    test = make_pairs(args.out, "test", test_photos, lenses["truth"], {**s, "crops": s["test_crops"]})
    evaluate(args.out, "oracle", test, "input,wiener", None, None)
    pairs = {"nominal": make_pairs(args.out, "nominal", train_photos, lenses["nominal"], s)}
    evaluate(args.out, "universal", test, "input,universal", bank_of(pairs["nominal"]), None)
    runs: dict[str, dict] = {}
    for m, stage_lens in MODELS.items():  # one model after the other: a partial run reports what it has
        if m == "tolerances":
            pairs[m] = make_pairs(args.out, m, train_photos, lenses["nominal"], s, lenses["tolerances"])
        elif m not in pairs:
            pairs[m] = make_pairs(args.out, m, train_photos, lenses[m], s)
        runs[m] = train(args.out, m, pairs[m], s["budget"], s["train_crop"])
        evaluate(args.out, m, test, "input,model", bank_of(pairs[stage_lens]), args.out / "runs" / m)
        report(args.out, args.results, runs, s, before + time.perf_counter() - t0)
    banks = {"nominal": bank_of(pairs["nominal"]), "calibrated": bank_of(pairs["calibrated"]), "truth": bank_of(test)}
    for m in MODELS:  # every network with every stage bank: what the training pairs do, what the stage does
        for stage, bank in banks.items():
            if stage != MODELS[m]:
                evaluate(args.out, f"{m}@{stage}", test, "input,model", bank, args.out / "runs" / m)
    report(args.out, args.results, runs, s, before + time.perf_counter() - t0)
    elapsed.write_text(json.dumps({"seconds": before + time.perf_counter() - t0}))
    log("done")


if __name__ == "__main__":
    main()
