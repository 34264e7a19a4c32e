"""Benchmark: restoration speed of the PSF-informed network (issue 23), its Wiener stage
included, against the default network, in the same run.

    .venv/bin/python benchmarks/psfnet_speed.py BANK [--threads 2] [--side 1024] [--rounds 3]
        [--old TREE --old-side 512]

BANK: a PSF bank of the default sensor (benchmarks/psfnet_data.py writes the demo's). Each
measurement runs in its own subprocess with ``--threads`` torch threads, on a synthetic
side x side photo at the sensor's native scale (its top-left corner at the sensor's, so the
stage's kernels span the field from the corner inwards), rounds interleaved:

* ``stage``: lensim.restore.psf_stage.photo_wiener over the photo (the Wiener stage; in a
  fresh process, so its time includes computing the bank's polar kernel nodes for the
  photo's part of the field, not the import of lensim.evaluate); ``stage-warm``: a second
  call in that process (the nodes known, as for every photo after the first);
* ``stage-old`` (with ``--old TREE``, a checkout of lensim before the stage's fast
  computation, e.g. ``git worktree add /tmp/old 297078e``): the same call with that
  tree's lensim, on an ``--old-side`` photo (it is ~100 times slower; the rate is per pixel);
* ``default``: the default network (NAFNet + FOV, stem 2, width 46) through restore_image;
* ``psfnet``: the PSF-informed network (same body, width 46) through restore_image, given
  the stage's image (computed once beforehand, not timed here).

Prints MP/s (median over rounds) and the time a 24-megapixel frame would take at that rate
(every part is linear in the pixels: the stage works per 32-pixel tile, the networks per
512-pixel tile), with the stage's and the network's times added for ``psfnet``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

CHILD = r"""
import json, sys, time, torch
torch.set_num_threads(int(sys.argv[3]))
from lensim.cli.allocator import keep_freed_memory
keep_freed_memory()
from lensim.psf.bank import PSFBank
from lensim.restore.infer import restore_image
from lensim.restore.nafnet import NAFNet
from lensim.restore.psf_stage import photo_wiener
from lensim.restore.psfnet import PSFNet
from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

what, bank_dir, side = sys.argv[1].removesuffix("-old"), sys.argv[2], int(sys.argv[4])
sensor = load_sensor(DEFAULT_SENSOR)
gen = torch.Generator().manual_seed(0)
photo = torch.rand(3, side, side, generator=gen)
size = (float(sensor.height), float(sensor.width))
torch.manual_seed(0)
with torch.inference_mode():
    if what == "stage":
        import lensim.evaluate.baselines  # its import (scipy) is not the stage's time
        bank = PSFBank.load(bank_dir)
        t = time.perf_counter()
        photo_wiener(photo, bank, sensor, (0.0, 0.0), size)
        if sys.argv[1] == "stage":  # again, the bank's kernel nodes now known
            first, t = time.perf_counter() - t, time.perf_counter()
            photo_wiener(photo, bank, sensor, (0.0, 0.0), size)
            print(json.dumps({"seconds": first, "warm": time.perf_counter() - t}))
            sys.exit(0)
    else:
        net = (PSFNet if what == "psfnet" else NAFNet)(width=46, use_fov=True, stem=2).eval()
        for p in net.parameters():
            p.add_(0.01 * torch.randn_like(p))
        kw = {"wiener": torch.rand(3, side, side, generator=gen)} if what == "psfnet" else {}
        t = time.perf_counter()
        restore_image(net, photo, (0.0, 0.0), size, **kw)
print(json.dumps({"seconds": time.perf_counter() - t}))
"""

PARTS = ("stage", "default", "psfnet")
#: the stage's second call in the same process (its kernel nodes known), per round
WARM: list[float] = []


def measure(part: str, bank: str, threads: int, side: int, tree: str | None = None) -> float:
    env = {**os.environ, "PYTHONPATH": tree} if tree else None
    out = subprocess.run(
        [sys.executable, "-c", CHILD, part, bank, str(threads), str(side)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,  # python -c puts the working folder first on sys.path: the tree's lensim, not this one
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    if "warm" in got:
        WARM.append(float(got["warm"]))
    return float(got["seconds"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bank")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--side", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--old", help="a lensim tree before the fast stage (measured as stage-old)")
    ap.add_argument("--old-side", type=int, default=512)
    a = ap.parse_args()
    parts = PARTS + (("stage-old",) if a.old else ())
    side = {p: a.old_side if p == "stage-old" else a.side for p in parts}
    times: dict[str, list[float]] = {p: [] for p in parts}
    for r in range(a.rounds):
        for part in parts[r % len(parts) :] + parts[: r % len(parts)]:
            tree = a.old if part == "stage-old" else None
            times[part].append(measure(part, a.bank, a.threads, side[part], tree))
    times["stage-warm"] = WARM
    rate = {p: side.get(p, a.side) ** 2 / 1e6 / statistics.median(t) for p, t in times.items()}
    parts = (*parts, "stage-warm")
    full = {p: 24.0 / rate[p] for p in parts}
    print(f"{a.side}x{a.side} photo ({a.old_side} for stage-old), {a.threads} threads, {a.rounds} rounds (median):")
    for p in parts:
        print(f"  {p:9s} {rate[p]:.3f} MP/s  (24 MP: {full[p]:.0f} s)")
    for stage in ("stage", "stage-warm", "stage-old")[: 2 + bool(a.old)]:
        total = full[stage] + full["psfnet"]
        print(f"  psfnet with its {stage}: {24.0 / total:.3f} MP/s (24 MP: {total:.0f} s)")
    print(json.dumps({"times_s": times, "mp_per_s": rate}))


if __name__ == "__main__":
    main()
