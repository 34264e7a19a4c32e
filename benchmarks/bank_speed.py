"""PSF-bank speed: this checkout against an earlier revision in the same run, and bank
throughput (banks per hour) at the demo's sampling and at a coarse "library" sampling.

Run by hand from the repository root (10-20 minutes on 2 cores):

    .venv/bin/python benchmarks/bank_speed.py --before REV [--before REV2 ...] [--repeats 1] \
        [--cases demo,library,demo-2w]

Each bank is one `lensim psf bank` subprocess (the lensim of a checkout on PYTHONPATH), timed
from start to exit, into a fresh folder. Runs alternate between the checkouts (each before,
then after; the next repeat in the reverse order), so a busy machine slows them alike; the
ratios are what hold. Each ``--before REV`` is checked out into a temporary git worktree
(removed at the end).

Cases (the built-in Cooke triplet on the APS-C sensor, 3.92 um pixels, its spectral response):
* demo: the demo's bank: 12 fields, 400-700 nm every 25 nm (13 wavelengths), 128 pupil
  samples, 35-pixel kernels, computed in one process (``--workers 1``, one torch thread);
* library: a coarse bank for a lens library: 8 fields, 420-680 nm every 40 nm (7), 64 pupil
  samples, kernels sized from the spots (``--kernel 0``), one process;
* demo-2w: the demo's bank on a local Dask cluster of two workers (``--workers 2``).

Accuracy: every kernel (field x channel) of the new bank against the old one: the worst
Pearson correlation (NCC) and the worst absolute difference relative to the kernel's peak.

Prints a markdown table per earlier revision: case, seconds before / after (each run), the
ratio of the medians, banks per hour after (and per worker for demo-2w), and the accuracy
figures against that revision's bank.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BASE = ["--lens", "cooke_triplet", "--sensor", "apsc_mirrorless", "--quiet"]
CASES = {
    "demo": ["--fields", "12", "--wavelengths-nm", "400:700:25", "--pupil-samples", "128", "--kernel", "35"],
    "library": ["--fields", "8", "--wavelengths-nm", "420:680:40", "--pupil-samples", "64", "--kernel", "0"],
    "demo-2w": ["--fields", "12", "--wavelengths-nm", "400:700:25", "--pupil-samples", "128", "--kernel", "35"],
}
WORKERS = {"demo": 1, "library": 1, "demo-2w": 2}


def run_bank(checkout: Path, case: str, out: Path) -> tuple[float, float]:
    """Wall-clock seconds and CPU seconds (user + system, the process and the workers it
    waited for) of one `lensim psf bank` of `case` with the lensim of `checkout`."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [sys.executable, "-m", "lensim", "psf", "bank", *BASE, *CASES[case], "--workers", str(WORKERS[case])]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([*cmd, "-o", str(out)], env=env, check=True, cwd=checkout)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def kernels(bank_dir: Path) -> list[np.ndarray]:
    """Every field's (3, P, P) RGB kernels, in field order."""
    return [np.load(p)["rgb"] for p in sorted(bank_dir.glob("field_*.npz"))]


def compare(old: Path, new: Path) -> tuple[float, float]:
    """(worst NCC, worst |difference| / peak) over every kernel (field x channel)."""
    worst_ncc, worst_diff = 1.0, 0.0
    for a, b in zip(kernels(old), kernels(new), strict=True):
        for ca, cb in zip(a, b, strict=True):
            x, y = ca - ca.mean(), cb - cb.mean()
            worst_ncc = min(worst_ncc, float((x * y).sum() / np.sqrt((x * x).sum() * (y * y).sum())))
            worst_diff = max(worst_diff, float(np.abs(ca - cb).max() / ca.max()))
    return worst_ncc, worst_diff


def _table(rev: str, cases: list[str], times: dict, accuracy: dict) -> str:
    """The markdown table of one earlier revision against this checkout."""
    lines = [
        f"before: {rev}; after: this checkout; {os.cpu_count()} CPUs\n",
        "| case | before (s) | after (s) | speed-up | CPU s before / after | speed-up (CPU) "
        "| banks/hour after | worst kernel NCC | worst diff / peak |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for case in cases:
        old, new = [t for t, _ in times[case][rev]], [t for t, _ in times[case]["after"]]
        cpu_old, cpu_new = (statistics.median(c for _, c in times[case][w]) for w in (rev, "after"))
        per_hour = 3600.0 / statistics.median(new)
        per_worker = f" ({per_hour / WORKERS[case]:.0f} per worker)" if WORKERS[case] > 1 else ""
        ncc, diff = accuracy[case][rev]
        lines.append(
            f"| {case} | {' / '.join(f'{t:.1f}' for t in old)} | {' / '.join(f'{t:.1f}' for t in new)} "
            f"| {statistics.median(old) / statistics.median(new):.2f}x | {cpu_old:.1f} / {cpu_new:.1f} "
            f"| {cpu_old / cpu_new:.2f}x | {per_hour:.0f}{per_worker} "
            f"| {ncc:.7f} | {diff:.1e} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, action="append", help="git revision to compare against (repeatable)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--cases", default="demo,library,demo-2w")
    args = parser.parse_args()
    cases = args.cases.split(",")
    work = Path(tempfile.mkdtemp(prefix="lensim-bank-speed-"))
    checkouts = {rev: work / f"before-{i}" for i, rev in enumerate(args.before)}
    for rev, path in checkouts.items():
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(path), rev], cwd=REPO, check=True)
    checkouts["after"] = REPO
    try:
        times: dict = {case: {which: [] for which in checkouts} for case in cases}
        accuracy: dict = {case: {} for case in cases}
        for case in cases:
            order = list(checkouts)
            for r in range(args.repeats):
                for which in order if r % 2 == 0 else order[::-1]:
                    out = work / f"{case}-{list(checkouts).index(which)}-{r}"
                    times[case][which].append(run_bank(checkouts[which], case, out))
                    wall, cpu = times[case][which][-1]
                    print(f"{case} {which} run {r}: {wall:.1f} s ({cpu:.1f} s CPU)", file=sys.stderr, flush=True)
            after = work / f"{case}-{len(checkouts) - 1}-0"
            for i, rev in enumerate(args.before):
                accuracy[case][rev] = compare(work / f"{case}-{i}-0", after)
        print("\n\n".join(_table(rev, cases, times, accuracy) for rev in args.before))
    finally:
        for rev in args.before:
            subprocess.run(["git", "worktree", "remove", "--force", str(checkouts[rev])], cwd=REPO, check=False)
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
