"""Per-photo table of the unseen test photos: the networks of benchmarks/nafnet_vs_unet.py
against the Wiener oracle of benchmarks/generalization.sh, on the same crops (the two runs
share the generalization benchmark's test pairs; the input column checks that).

    python benchmarks/per_photo_vs_wiener.py [NAFNET_RESULTS] [GENERALIZATION_RESULTS]

Reads NAFNET_RESULTS/test_photos.csv (one row per crop and method; every network in it is
tabled) and, when that file has no "wiener" rows (a run with --no-wiener),
GENERALIZATION_RESULTS/per_photo.md (per-photo input and Wiener PSNR, the mean of the crops'
PSNR in dB), and prints a Markdown table: per photo, the mean crop PSNR of each method and
the margin of each network over the Wiener oracle.
"""

from __future__ import annotations

import csv
import re
import sys
from collections import defaultdict
from pathlib import Path


def crop_means(csv_path: Path) -> dict[tuple[str, str], float]:
    """{(photo, method): mean PSNR (dB) over the photo's crops}."""
    values: dict[tuple[str, str], list[float]] = defaultdict(list)
    with open(csv_path, newline="") as f:
        for row in csv.DictReader(f):
            values[(Path(row["source"]).stem, row["method"])].append(float(row["psnr_db"]))
    return {key: sum(v) / len(v) for key, v in values.items()}


def wiener_table(md_path: Path) -> dict[str, tuple[float, float]]:
    """{photo: (input PSNR, Wiener PSNR)} from the generalization benchmark's table."""
    out = {}
    for line in md_path.read_text().splitlines():
        m = re.match(r"\| (test-[\w-]+) \| \d+ \| ([\d.]+) \| ([\d.]+)", line)
        if m:
            out[m.group(1)] = (float(m.group(2)), float(m.group(3)))
    return out


def main() -> None:
    here = Path(__file__).parent / "results"
    nafnet = Path(sys.argv[1]) if len(sys.argv) > 1 else here / "nafnet_vs_unet"
    general = Path(sys.argv[2]) if len(sys.argv) > 2 else here / "generalization"
    means = crop_means(nafnet / "test_photos.csv")
    photos = sorted({p for p, _ in means})
    if (photos[0], "wiener") in means:
        wiener = {p: (means[(p, "input")], means[(p, "wiener")]) for p in photos}
    else:
        wiener = wiener_table(general / "per_photo.md")
    methods = list(dict.fromkeys(m for _, m in means if m not in ("input", "wiener")))
    print(
        "| photo | input | Wiener oracle | "
        + " | ".join(methods)
        + " | "
        + " | ".join(f"{m} - Wiener" for m in methods)
        + " |"
    )
    print("| --- |" + " ---: |" * (2 + 2 * len(methods)))
    for photo in sorted(wiener):
        given, oracle = wiener[photo]
        if abs(means[(photo, "input")] - given) > 0.005:
            raise SystemExit(f"{photo}: input PSNR {means[(photo, 'input')]:.2f} != {given:.2f}: not the same crops")
        nets = [means[(photo, m)] for m in methods]
        print(
            f"| {photo} | {given:.2f} | {oracle:.2f} | "
            + " | ".join(f"{v:.2f}" for v in nets)
            + " | "
            + " | ".join(f"{v - oracle:+.2f}" for v in nets)
            + " |"
        )


if __name__ == "__main__":
    main()
