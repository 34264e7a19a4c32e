"""Per-photo scores on the unseen test photos for benchmarks/generalization.sh.

    .venv/bin/python benchmarks/generalization.py OUT

Reads OUT/pairs-test (the unseen photos' pairs), the last checkpoints of the runs in
OUT/old, OUT/new and OUT/more that exist (no model selection on the test photos), OUT/bank;
scores input, the Wiener oracle (true PSFs) and each network on every test crop
(lensim.evaluate.harness, the same code as `lensim evaluate`; methods already in
OUT/metrics.csv are not scored again), writes OUT/metrics.csv (per crop and method),
OUT/summary.json (overall and per photo) and OUT/per_photo.md, and prints the table: per
photo, the mean over its crops of PSNR (dB) and its gain over the input, SSIM, and each
network's margin over the Wiener oracle.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import sys
from pathlib import Path

import torch

from lensim.evaluate.harness import builtin_method, checkpoint_method, evaluate_rows, summarize, write_csv

RUNS = {"old": "old set, MSE", "new": "new set + levers", "more": "new set, MSE"}


def per_photo(rows: list[dict]) -> dict[str, dict[str, dict[str, float]]]:
    """{photo: {method: {"psnr_db", "ssim", "crops"}}}: means over the photo's crops."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for r in rows:
        photo = Path(str(r["source"])).stem
        m = out.setdefault(photo, {}).setdefault(r["method"], {"psnr": [], "ssim": []})
        m["psnr"].append(float(r["psnr_db"]))
        m["ssim"].append(float(r["ssim"]))
    return {
        p: {
            k: {"psnr_db": statistics.mean(v["psnr"]), "ssim": statistics.mean(v["ssim"]), "crops": len(v["psnr"])}
            for k, v in ms.items()
        }
        for p, ms in out.items()
    }


def table(photos: dict, summary: dict, runs: list[str]) -> str:
    methods = ["input", "wiener", *runs]
    lines = [
        "| photo | crops | input PSNR | Wiener oracle | "
        + " | ".join(RUNS[r] for r in runs)
        + " | "
        + " | ".join(f"{r} - Wiener" for r in runs)
        + " | SSIM "
        + " / ".join(methods)
        + " |",
        "| --- | ---: | ---: | ---: | " + "---: | " * (2 * len(runs)) + "--- |",
    ]

    def cell(ms: dict, k: str) -> str:
        return f"{ms[k]['psnr_db']:.2f} ({ms[k]['psnr_db'] - ms['input']['psnr_db']:+.2f})"

    mean = {k: {"psnr_db": v["psnr_db"], "ssim": v["ssim"], "crops": None} for k, v in summary["methods"].items()}
    for photo, ms in list(photos.items()) + [("**mean over crops**", mean)]:
        crops = ms["input"]["crops"]
        lines.append(
            f"| {photo} | {'' if crops is None else crops} | {ms['input']['psnr_db']:.2f} | "
            + " | ".join(cell(ms, k) for k in ["wiener", *runs])
            + " | "
            + " | ".join(f"{ms[r]['psnr_db'] - ms['wiener']['psnr_db']:+.2f}" for r in runs)
            + " | "
            + " / ".join(f"{ms[k]['ssim']:.3f}" for k in methods)
            + " |"
        )
    return "\n".join(lines)


def read_rows(path: Path) -> list[dict]:
    """Rows of a metrics.csv written by harness.write_csv, numbers as floats (empty: NaN)."""
    if not path.is_file():
        return []
    rows = []
    for r in csv.DictReader(path.open()):
        row: dict = {}
        for k, v in r.items():
            if k in ("method", "source", "input"):
                row[k] = v
            else:
                row[k] = math.nan if v == "" else float(v)
        rows.append(row)
    return rows


def main(out: Path) -> None:
    torch.set_num_threads(2)
    runs = [r for r in RUNS if (out / r / "last.pt").is_file()]
    rows = read_rows(out / "metrics.csv")
    done = {r["method"] for r in rows}
    methods = {} if "wiener" in done else {"wiener": builtin_method("wiener")}
    methods.update({r: checkpoint_method(out / r / "last.pt") for r in runs if r not in done})
    if methods:
        new = evaluate_rows(out / "pairs-test", methods, bank=out / "bank")
        rows += [r for r in new if r["method"] not in done]
        write_csv(rows, out / "metrics.csv")
    summary = summarize(rows)
    photos = per_photo(rows)
    beats = {r: {p: ms[r]["psnr_db"] > ms["wiener"]["psnr_db"] for p, ms in photos.items()} for r in runs}
    training = {}
    for run in runs:
        last = (out / run / "log.csv").read_text().splitlines()[-1].split(",")
        training[run] = {"steps": int(float(last[1])), "seconds": float(last[-1]), "val_psnr": float(last[3])}
    result = {"summary": summary, "per_photo": photos, "beats_wiener": beats, "training": training}
    (out / "summary.json").write_text(json.dumps(result, indent=2))
    text = table(photos, summary, runs)
    (out / "per_photo.md").write_text(text + "\n")
    print(text)
    for run in runs:
        t = training[run]
        print(
            f"\n{run} ({RUNS[run]}): above the Wiener oracle on {sum(beats[run].values())} of {len(photos)} "
            f"photos; {t['steps']} steps in {t['seconds']:.0f} s, validation PSNR {t['val_psnr']:.2f} dB"
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]))
