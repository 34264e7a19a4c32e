"""Threads on a shared machine: lensim's PSF work beside one other busy process.

Run by hand from the repository root (a few minutes on 2 cores):

    .venv/bin/python benchmarks/oversubscription.py [--repeats 3]

Each case runs in a fresh subprocess, so lensim's OpenMP setting (OMP_WAIT_POLICY=PASSIVE,
set by ``import lensim`` before torch loads, unless the environment sets it) applies as it
does for a user. While a case runs, one other process spins on a core (a pure-Python busy
loop), as on a laptop or a shared server. Cases alternate, so a noisy machine slows
them alike.

* ``compute_psf`` with torch's default thread count (one per core) against one thread: the
  Cooke triplet at 0.7 field, 550 nm, 128 pupil samples, 128 x 128 samples, real aiming (the
  median of 3 PSFs after one warm-up). Also with the environment's OMP_WAIT_POLICY=ACTIVE,
  which is what torch does when lensim is imported after it (spinning threads).
* a bank on a local Dask cluster of 2 workers against (its PSF count) x (one single-thread
  PSF of the same bank) / 2 cores: the overhead of the cluster and of the bank's other work
  (tracing, relative illumination, pixel integration, azimuth kernels) on top of the PSFs
  themselves. ``--bank demo`` (the default) is the demo's bank (12 fields, 13 wavelengths,
  128 pupil samples, 35-pixel kernels: 156 PSFs); ``--bank small`` the 6 fields x 7
  wavelengths (42 PSFs) of the first measurement, where the command's fixed start-up
  (Python, torch, the cluster's two workers) weighs more.

Prints a markdown table of seconds and ratios.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PSF_CASE = """
import sys, time
import lensim
import torch
threads = int(sys.argv[1])
if threads:
    torch.set_num_threads(threads)
from lensim.optics.lens_file import load_lens
from lensim.psf.compute import compute_psf
lens = load_lens("cooke_triplet")
compute_psf(lens, 0.7, 0.55, pupil_samples=64, grid=64)
times = []
for _ in range(3):
    t = time.perf_counter()
    compute_psf(lens, 0.7, 0.55, pupil_samples=128, grid=128)
    times.append(time.perf_counter() - t)
print(sorted(times)[1])
"""

BANK_ARGS = ["--lens", "cooke_triplet", "--sensor", "apsc_mirrorless", "--pupil-samples", "128", "--kernel", "35",
             "--quiet"]  # fmt: skip
#: the banks of --bank: (fields, wavelength range in nm)
BANKS = {"demo": (12, "400:700:25"), "small": (6, "400:700:50")}


def busy() -> subprocess.Popen:
    """A process that keeps one core busy until killed."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def psf_seconds(threads: int, wait_policy: str | None) -> float:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("OMP_WAIT_POLICY", None)
    if wait_policy:
        env["OMP_WAIT_POLICY"] = wait_policy
    out = subprocess.run([sys.executable, "-c", PSF_CASE, str(threads)], env=env, check=True, capture_output=True)
    return float(out.stdout.decode().split()[-1])


def bank_psfs(bank: str) -> int:
    """How many PSFs the bank of --bank computes (fields x wavelengths)."""
    fields, wavelengths = BANKS[bank]
    lo, hi, step = (int(v) for v in wavelengths.split(":"))
    return fields * ((hi - lo) // step + 1)


def bank_seconds(bank: str, workers: int, out: Path) -> float:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    fields, wavelengths = BANKS[bank]
    sampling = ["--fields", str(fields), "--wavelengths-nm", wavelengths]
    t = time.perf_counter()
    cmd = [sys.executable, "-m", "lensim", "psf", "bank", *BANK_ARGS, *sampling, "--workers", str(workers)]
    cmd += ["-o", str(out)]
    subprocess.run(cmd, env=env, check=True)
    return time.perf_counter() - t


def single_psf_of_bank() -> float:
    """Seconds for one PSF at the bank's sampling, one thread (the 0.7 field, 550 nm)."""
    code = """
import time, lensim, torch
torch.set_num_threads(1)
from lensim.optics.lens_file import load_lens
from lensim.psf.compute import compute_psf
lens = load_lens("cooke_triplet")
compute_psf(lens, 0.7, 0.55, pupil_samples=64, grid=64)
times = []
for _ in range(3):
    t = time.perf_counter()
    compute_psf(lens, 0.7, 0.55, pupil_samples=128, grid=175, spacing_um=3.92 / 5)
    times.append(time.perf_counter() - t)
print(sorted(times)[1])
"""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True)
    return float(out.stdout.decode().split()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bank", choices=sorted(BANKS), default="demo")
    args = parser.parse_args()
    cases = {"default threads, passive": (0, None), "one thread": (1, None), "default threads, ACTIVE": (0, "ACTIVE")}
    times: dict[str, list[float]] = {k: [] for k in cases}
    hog = busy()
    try:
        for r in range(args.repeats):
            for name, (threads, policy) in cases.items() if r % 2 == 0 else reversed(cases.items()):
                times[name].append(psf_seconds(threads, policy))
                print(f"{name}: {times[name][-1]:.3f} s", file=sys.stderr, flush=True)
    finally:
        hog.kill()
    one = statistics.median(times["one thread"])
    print(f"compute_psf beside one busy process ({os.cpu_count()} CPUs), median of {args.repeats} runs:\n")
    print("| case | seconds | / one thread |")
    print("| --- | ---: | ---: |")
    for name, ts in times.items():
        print(f"| {name} | {statistics.median(ts):.3f} | {statistics.median(ts) / one:.2f} |")
    with tempfile.TemporaryDirectory() as tmp:
        psf = single_psf_of_bank()
        bank = bank_seconds(args.bank, 2, Path(tmp) / "bank")
    count = bank_psfs(args.bank)
    ideal = count * psf / 2
    print(f"\n{args.bank} bank of {count} PSFs on a 2-worker local cluster: {bank:.1f} s; ", end="")
    print(f"{count} x {psf:.3f} s / 2 cores = {ideal:.1f} s;")
    print(f"ratio {bank / ideal:.2f} (target <= 2.5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
