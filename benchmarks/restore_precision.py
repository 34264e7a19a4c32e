"""Benchmark: `lensim restore` in float32 and in bfloat16 (issue 23: 1 MP/s for a 24 MP frame).

    .venv/bin/python benchmarks/restore_precision.py [--pairs PAIRS] [--photo FRAME.jpg]
        [--lens cooke_triplet --sensor apsc_mirrorless] [--threads 2] [--rounds 3]
        [--baseline-tree DIR]

Three measurements, each with the float32 and bfloat16 variants interleaved so both see the
same machine load:

* ``network``: the shipped universal model on one 1024 px tile (the size `lensim restore`
  cuts, lensim.restore.infer.default_tile) of a natural image and its Wiener image, in one
  process with ``--threads`` threads: seconds per tile, MP/s, the ratio, and the PSNR of the
  bfloat16 tile against the float32 one;
* ``accuracy`` (with ``--pairs [--held-out RUN]``): the universal model zero-shot on a pairs
  folder's crops (those of the photos RUN held out)
  (lensim.evaluate.harness.checkpoint_method at each precision), PSNR/SSIM against the
  ground truth overall and per zone, and the largest per-crop PSNR difference;
* ``command`` (with ``--photo``): the whole `lensim restore --lens L --sensor S PHOTO...`
  (a fresh process each time, the lens's bank cached by a first untimed run) with
  ``--precision float32`` and ``--precision bfloat16``, on the photo alone and on
  ``--batch`` copies of it: wall seconds and MP/s of a one-photo command (start-up
  included) and of each further photo of a batch.

Prints one JSON object (and a markdown table to stderr). bfloat16 needs a CPU that computes
it natively (AVX512-BF16 or AMX; lensim.restore.infer.native_bfloat16) to be faster: the
script says whether this one does.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

PRECISIONS = ("float32", "bfloat16")


def network_speed(threads: int, rounds: int) -> dict:
    """Seconds per 1024 px tile of the universal model at each precision, and the PSNR
    between the two outputs."""
    import numpy as np
    import torch
    from skimage import data

    from lensim.cli.allocator import keep_freed_memory
    from lensim.restore.infer import native_bfloat16, restore_image
    from lensim.restore.universal import load_universal

    keep_freed_memory()  # as the `lensim` command does: without it tiles take about twice as long
    torch.set_num_threads(threads)
    model, _ = load_universal()
    model.eval()
    img = torch.from_numpy(np.ascontiguousarray(data.astronaut()[:512, :512])).permute(2, 0, 1).float() / 255
    img = torch.nn.functional.interpolate(img[None], size=(1024, 1024), mode="bicubic")[0].clamp(0, 1)
    soft = torch.nn.functional.avg_pool2d(img[None], 5, 1, 2, count_include_pad=False)[0]
    times: dict[str, list[float]] = {p: [] for p in PRECISIONS}
    outs: dict[str, torch.Tensor] = {}
    for _ in range(rounds):
        for p in PRECISIONS:
            t = time.perf_counter()
            outs[p] = restore_image(model, soft, (1000.0, 1500.0), (4000.0, 6000.0), wiener=img, precision=p)
            times[p].append(time.perf_counter() - t)
    mse = float((outs["float32"] - outs["bfloat16"]).square().mean())
    med = {p: statistics.median(v) for p, v in times.items()}
    return {
        "native_bfloat16": native_bfloat16("cpu"),
        "seconds_per_tile": med,
        "all_seconds": times,
        "mp_per_s": {p: 1024 * 1024 / 1e6 / v for p, v in med.items()},
        "speedup": med["float32"] / med["bfloat16"],
        "psnr_bf16_vs_fp32_db": 10 * math.log10(1.0 / max(mse, 1e-20)),
    }


def accuracy(pairs: Path, held_out: Path | None) -> dict:
    """The universal model zero-shot at each precision on a pairs folder (per zone; only the
    photos a training run held out, when ``held_out`` names the run)."""
    from lensim.data.manifest import read_held_out
    from lensim.evaluate.harness import checkpoint_method, evaluate
    from lensim.restore.universal import model_path

    path = model_path("universal")
    methods = {f"universal-{p}": checkpoint_method(path, precision=p) for p in PRECISIONS}
    rows: list = []
    sources = read_held_out(held_out) if held_out is not None else None
    summary = evaluate(pairs, methods, sources=sources, rows=rows)
    by_crop: dict[tuple, dict[str, float]] = {}
    for r in rows:
        by_crop.setdefault((r["record"], r["crop"]), {})[r["method"]] = r["psnr_db"]
    diffs = [abs(v["universal-float32"] - v["universal-bfloat16"]) for v in by_crop.values() if len(v) >= 2]
    summary["largest_crop_difference_db"] = max(diffs) if diffs else None
    summary["crops"] = len(by_crop)
    return summary


def command_speed(
    photo: Path, lens: str, sensor: str, threads: int, rounds: int, batch: int, baseline: Path | None = None
) -> dict:
    """Wall seconds of the whole `lensim restore` at each precision (fresh processes), on
    the photo alone and on ``batch`` copies of it in one command: the first gives the
    rate of a one-photo command (start-up included), the difference the rate of every
    further photo of a batch (the model, the lens and its bank loaded once). baseline: a
    checkout of an earlier lensim (`git worktree add DIR COMMIT`), whose one-photo
    bfloat16 command runs in each round too (first on its PYTHONPATH)."""
    from PIL import Image

    with Image.open(photo) as im:
        megapixels = im.width * im.height / 1e6
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    out, copies = tmp / "restore_precision_out", tmp / "restore_precision_in"
    copies.mkdir(exist_ok=True)
    names = [copies / f"photo{k}{photo.suffix}" for k in range(batch)]
    for name in names:
        if not name.exists():
            name.write_bytes(photo.read_bytes())
    base = [sys.executable, "-m", "lensim", "restore", "--lens", lens, "--sensor", sensor]
    base += ["--threads", str(threads), "--quiet", "-o", str(out), "--precision"]

    def run(p: str, n: int, tree: Path | None = None) -> float:
        subprocess.run(["rm", "-rf", str(out)], check=True)
        env = dict(os.environ)
        if tree is not None:  # its lensim first on the path (`python -m` puts the working folder first)
            env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        t = time.perf_counter()
        subprocess.run([*base, p, *map(str, names[:n])], check=True, env=env, cwd=tree)
        return time.perf_counter() - t

    run("float32", 1)  # the lens's bank computed and cached, the modules' bytecode written
    if baseline is not None:
        run("bfloat16", 1, baseline)  # its bytecode and caches too
    times: dict[str, dict[int, list[float]]] = {p: {1: [], batch: []} for p in PRECISIONS}
    before: list[float] = []
    for _ in range(rounds):
        if baseline is not None:
            before.append(run("bfloat16", 1, baseline))
        for p in PRECISIONS:
            for n in sorted({1, batch}):
                times[p][n].append(run(p, n))
    one = {p: statistics.median(v[1]) for p, v in times.items()}
    more = {p: (statistics.median(v[batch]) - one[p]) / max(batch - 1, 1) for p, v in times.items()}
    return {
        "megapixels": megapixels,
        "batch": batch,
        "one_photo_seconds": one,
        "further_photo_seconds": more if batch > 1 else None,
        "all_seconds": {p: {str(n): v for n, v in d.items()} for p, d in times.items()},
        "one_photo_mp_per_s": {p: megapixels / v for p, v in one.items()},
        "further_photo_mp_per_s": {p: megapixels / v for p, v in more.items()} if batch > 1 else None,
        "speedup_one_photo": one["float32"] / one["bfloat16"],
        "baseline": None
        if baseline is None
        else {
            "tree": str(baseline),
            "commit": subprocess.run(
                ["git", "-C", str(baseline), "rev-parse", "HEAD"], capture_output=True, text=True
            ).stdout.strip(),
            "one_photo_bfloat16_seconds": statistics.median(before),
            "all_seconds": before,
            "speedup_one_photo_bfloat16": statistics.median(before) / one["bfloat16"],
        },
    }


def make_frame(path: Path) -> None:
    """The 6000 x 4000 test JPEG: skimage's astronaut resized (bicubic) plus Gaussian noise
    of 3 levels (seed 0), quality 92."""
    import numpy as np
    from PIL import Image
    from skimage import data

    big = np.asarray(Image.fromarray(data.astronaut()).resize((6000, 4000), Image.BICUBIC), dtype=np.float32)
    noisy = big + np.random.default_rng(0).normal(0.0, 3.0, big.shape)
    Image.fromarray(np.clip(noisy, 0, 255).astype(np.uint8)).save(path, quality=92)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=Path, default=None, help="pairs folder for the accuracy part")
    ap.add_argument("--held-out", type=Path, default=None, help="a run whose held-out photos are scored")
    ap.add_argument(
        "--photo", type=Path, default=None, help="a full frame for the whole-command part (made if missing)"
    )
    ap.add_argument("--lens", default="cooke_triplet")
    ap.add_argument("--sensor", default="apsc_mirrorless")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batch", type=int, default=2, help="photos in the batch run of the command part")
    ap.add_argument("--skip-network", action="store_true")
    ap.add_argument(
        "--baseline-tree", type=Path, default=None, help="an earlier checkout whose one-photo command runs each round"
    )
    args = ap.parse_args()
    result: dict = {}
    if not args.skip_network:
        result["network"] = network_speed(args.threads, args.rounds)
        print(json.dumps({"network": result["network"]}), file=sys.stderr, flush=True)
    if args.pairs is not None:
        result["accuracy"] = accuracy(args.pairs, args.held_out)
        print(json.dumps({"accuracy": result["accuracy"]}), file=sys.stderr, flush=True)
    if args.photo is not None:
        if not args.photo.exists():
            make_frame(args.photo)
        result["command"] = command_speed(
            args.photo, args.lens, args.sensor, args.threads, args.rounds, args.batch, args.baseline_tree
        )
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
