"""`lensim dataset make` speed for the demo's training pairs: this checkout against an earlier
revision in the same run (issue 29), and whether the pairs are the same.

Run by hand from the repository root, under the CPU lock (10-15 minutes on 2 cores):

    .venv/bin/python benchmarks/dataset_speed.py --before REV [--repeats 2] [--cases demo,demo-2w] \
        [--work /tmp/lensim-dataset-speed] [--json benchmarks/results/dataset_speed.json]

The demo's pairs (lensim.demo.DemoSettings, full size): the built-in sample photos
centre-cropped to 512 x 512, 3 placements x 4 crops of 128 pixels, seed 0, through the
demo's bank (the Cooke triplet on the APS-C sensor: 12 fields, 400-700 nm every 25 nm,
128 pupil samples, kernels sized from the spots up to 41 pixels). The bank and the photos
are made once by this checkout in --work (kept for the next run); both revisions use them.

Each run is one `lensim dataset make --bank BANK` subprocess (the lensim of a checkout on
PYTHONPATH) into a fresh folder, timed from start to exit: wall time and CPU seconds (user +
system, the process and the workers it waited for). Cases: demo (``--workers 1``: one
process, one torch thread) and demo-2w (``--workers 2``: a local Dask cluster of two,
what `lensim demo` uses on 2 cores). Runs alternate between the checkouts (before, after;
the next repeat in the reverse order), so a busy machine slows both alike; the ratios
are what hold. ``--before REV`` is checked out into a temporary git worktree.

Accuracy: every input and target PNG of the after run against the before run (the first
repeat of each): the largest absolute difference in 8-bit code values and how many values
differ; and whether the records (placements, crops, capture draws) are equal.
"""

from __future__ import annotations

import argparse
import json
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
WORKERS = {"demo": 1, "demo-2w": 2}


def prepare(work: Path) -> tuple[Path, Path]:
    """The demo's bank and photos in work (made by this checkout once, then reused)."""
    from lensim.assets.images import available_sample_images, write_centre_crops
    from lensim.demo import DemoSettings, _set_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

    s = DemoSettings.make(False)
    lens, _ = _set_lens(None)
    sensor = load_sensor(DEFAULT_SENSOR)
    settings = BankSettings(
        fields=s.fields, wavelengths_nm=s.wavelengths_nm, pupil_samples=s.pupil_samples, kernel_limit=41
    )
    get_bank(lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, out_dir=work / "bank", workers=2)
    write_centre_crops(available_sample_images(), work / "photos", s.photo_size)
    return work / "bank", work / "photos"


def run_pairs(checkout: Path, case: str, bank: Path, photos: Path, out: Path) -> tuple[float, float]:
    """Wall-clock and CPU seconds of one `lensim dataset make` of the demo's pairs."""
    from lensim.demo import DemoSettings

    s = DemoSettings.make(False)
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [sys.executable, "-m", "lensim", "dataset", "make", str(photos), "-o", str(out), "--bank", str(bank)]
    cmd += ["--crops", str(s.crops), "--size", str(s.crop_size), "--placements", str(s.placements)]
    cmd += ["--seed", "0", "--workers", str(WORKERS[case]), "--quiet"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, cwd=checkout, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def compare(old: Path, new: Path) -> dict:
    """The after run's PNGs against the before run's: largest |difference| (code values),
    values that differ, values compared, files; and whether the records are equal."""
    from PIL import Image

    files = sorted((old / "pairs").glob("*.png"))
    worst, differ, total = 0, 0, 0
    for f in files:
        a = np.asarray(Image.open(f)).astype(np.int32)
        b = np.asarray(Image.open(new / "pairs" / f.name)).astype(np.int32)
        d = np.abs(a - b)
        worst, differ, total = max(worst, int(d.max())), differ + int((d > 0).sum()), total + d.size
    records = [json.loads((d / "manifest.json").read_text())["records"] for d in (old, new)]
    for r in records[0] + records[1]:
        r.pop("source", None)
    return {"files": len(files), "max_abs_diff": worst, "values_differ": differ, "values": total,
            "records_equal": records[0] == records[1]}  # fmt: skip


def _table(rev: str, cases: list[str], times: dict, accuracy: dict) -> str:
    lines = [
        f"before: {rev}; after: this checkout; {os.cpu_count()} CPUs\n",
        "| case | before wall (s) | after wall (s) | wall ratio | CPU s before | CPU s after | CPU ratio "
        "| max PNG diff | values differing | records equal |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for case in cases:
        old, new = times[case]["before"], times[case]["after"]
        w0, w1 = (statistics.median(t for t, _ in v) for v in (old, new))
        c0, c1 = (statistics.median(c for _, c in v) for v in (old, new))
        acc = accuracy[case]
        lines.append(
            f"| {case} | {' / '.join(f'{t:.1f}' for t, _ in old)} | {' / '.join(f'{t:.1f}' for t, _ in new)} "
            f"| {w0 / w1:.2f}x | {' / '.join(f'{c:.1f}' for _, c in old)} | {' / '.join(f'{c:.1f}' for _, c in new)} "
            f"| {c0 / c1:.2f}x | {acc['max_abs_diff']} | {acc['values_differ']} of {acc['values']} "
            f"| {acc['records_equal']} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="git revision to compare against")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--cases", default="demo,demo-2w")
    parser.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "lensim-dataset-speed"))
    parser.add_argument("--json", default=None, help="also write the figures here")
    args = parser.parse_args()
    cases = args.cases.split(",")
    work = Path(args.work)
    bank, photos = prepare(work)
    old = Path(tempfile.mkdtemp(prefix="lensim-dataset-before-")) / "checkout"
    subprocess.run(["git", "worktree", "add", "--detach", "-q", str(old), args.before], cwd=REPO, check=True)
    checkouts = {"before": old, "after": REPO}
    try:
        times: dict = {case: {which: [] for which in checkouts} for case in cases}
        accuracy: dict = {}
        for case in cases:
            for r in range(args.repeats):
                for which in ("before", "after") if r % 2 == 0 else ("after", "before"):
                    out = work / f"{case}-{which}-{r}"
                    shutil.rmtree(out, ignore_errors=True)
                    times[case][which].append(run_pairs(checkouts[which], case, bank, photos, out))
                    wall, cpu = times[case][which][-1]
                    print(f"{case} {which} run {r}: {wall:.1f} s ({cpu:.1f} s CPU)", file=sys.stderr, flush=True)
            accuracy[case] = compare(work / f"{case}-before-0", work / f"{case}-after-0")
        print(_table(args.before, cases, times, accuracy))
        if args.json:
            Path(args.json).write_text(
                json.dumps(
                    {"before": args.before, "cpus": os.cpu_count(), "times": times, "accuracy": accuracy}, indent=1
                )
                + "\n"
            )
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=REPO, check=False)
        shutil.rmtree(old.parent, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
