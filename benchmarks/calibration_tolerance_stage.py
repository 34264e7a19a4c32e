"""Which bank the Wiener stage of tolerance pairs should use in training (issue 24, item 4).

Model (c) of calibration_restoration.py (the universal model fine-tuned 300 s on pairs made
through tolerance draws) trained with its training pairs' PSF-informed stage computed three
ways, on the same pairs:

  own      each pair's own draw's bank (lensim's rule: the manifest's "stage_bank");
  nominal  the nominal lens's bank for every pair (the stage inference will have);
  draw0    draw 0's bank for every pair (what `lensim train` did before the fix).

The nominal and draw0 variants train on a copy of the pairs (hard links) whose manifest names
that one bank and no tolerance draws. Each network restores the perturbed camera's test
pairs with the nominal and with the calibrated lens's stage (`lensim evaluate --bank`).
Needs calibration_restoration.py's work folder (its pairs; its (c) run is `own`, seed 0):

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_tolerance_stage.py \\
        --out /tmp/calibration-restoration \\
        --results benchmarks/results/calibration/restoration/tolerance_stage.json

Resumable (every run and evaluation is kept under --out and skipped when done).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
from pathlib import Path

import calibration_restoration as cr

VARIANTS = ("own", "nominal", "draw0")
RUNS = {("own", 0): "tolerances"}  # the benchmark's own (c)


def pairs_for(out: Path, variant: str) -> Path:
    """The tolerance pairs, or a hard-linked copy whose manifest gives every pair one bank."""
    src = out / "pairs" / "tolerances"
    if variant == "own":
        return src
    dst = out / "pairs" / f"tolerances-{variant}-stage"
    if not (dst / "manifest.json").exists():
        tmp = dst.with_name(dst.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        subprocess.run(["cp", "-al", str(src), str(tmp)], check=True)
        shutil.rmtree(tmp / "wiener", ignore_errors=True)
        m = json.loads((tmp / "manifest.json").read_text())
        if variant == "draw0":
            m["bank"] = m["tolerances"]["draws"][0]["bank"]
        m.pop("tolerances")
        m.pop("stage_bank", None)
        os.unlink(tmp / "manifest.json")  # a hard link: the original's must stay
        (tmp / "manifest.json").write_text(json.dumps(m))
        os.rename(tmp, dst)
    return dst


def scores(evals: Path) -> dict[str, float]:
    v = json.loads((evals / "metrics.json").read_text())["methods"]["model"]
    return {"all": round(v["psnr_db"], 3), **{z: round(v["zones"][z]["psnr_db"], 3) for z in cr.ZONES}}


def one(out: Path, variant: str, seed: int) -> dict:
    """Train (once) and evaluate with the nominal and calibrated stages."""
    name = RUNS.get((variant, seed), f"tolerances-{variant}-s{seed}")
    s = cr.FULL
    run = cr.train(out, name, pairs_for(out, variant), s["budget"], s["train_crop"], seed)
    res: dict = {"steps": run["steps"]}
    for stage in ("nominal", "calibrated"):
        bank = cr.bank_of(out / "pairs" / stage)
        own_stage = (name == "tolerances") and stage == "nominal"  # the benchmark's own evaluation
        d = cr.evaluate(out, name if own_stage else f"{name}@{stage}", out / "pairs/test", "input,model", bank,
                        out / "runs" / name)  # fmt: skip
        res[f"stage_{stage}"] = scores(d)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=Path("/tmp/calibration-restoration"), help="the benchmark's work folder"
    )
    ap.add_argument("--results", type=Path, default=None, help="the JSON file to write")
    ap.add_argument("--seeds", default="0,1", help="training seeds, comma-separated")
    args = ap.parse_args()
    seeds = [int(v) for v in args.seeds.split(",")]
    what = " ".join(" ".join(__doc__.split("\n\n")[1:4]).split())
    res: dict = {"what": what, "command": "benchmarks/calibration_tolerance_stage.py", "psnr_db": {}}
    for seed in seeds:
        for variant in VARIANTS:
            res["psnr_db"].setdefault(f"seed{seed}", {})[variant] = one(args.out, variant, seed)
            text = json.dumps(res, indent=1) + "\n"
            (args.out / "tolerance_stage.json").write_text(text)
            if args.results:
                args.results.write_text(text)
    cr.log("done")


if __name__ == "__main__":
    main()
