"""Benchmark: restoration throughput of the two engines of `lensim restore` (issue 17 part 4).

Runs by hand: `python benchmarks/engine_speed.py [--threads 2] [--megapixels 1] [--rounds 3]`.
For each network (random seeded weights, perturbed so no layer is zero: speed does not
depend on training) one process restores the same synthetic photo with
lensim.restore.infer.restore_image at the CLI's defaults (tile 512, overlap 192), FOV
channels at the APS-C sensor's geometry, alternately with the PyTorch network (torch
engine) and with its ONNX export run by onnxruntime (the engine of `--engine
onnxruntime`), ``rounds`` times each, interleaved so that both see the same machine load.
Both use ``threads`` threads (torch.set_num_threads; onnxruntime's intra-op threads) and
the allocator setting of the `lensim` command. Prints the median seconds and MP/s of each
engine, their ratio and the largest difference between the two outputs.

* dcn-all: the network `lensim train --arch unet` builds by default (DCN at every decoder scale);
* dcn-coarsest: DCN at the coarsest decoder scale only (the demo's network).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, statistics, sys, time
import lensim  # first, as the `lensim` command: it sets OMP_WAIT_POLICY=PASSIVE before torch loads
import torch
from lensim.cli.allocator import keep_freed_memory
keep_freed_memory()
from lensim.restore.engines import OnnxEngine
from lensim.restore.export import export_model_bytes
from lensim.restore.infer import restore_image
from lensim.restore.network import FieldAwareUNet
variant, threads, mp, rounds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
torch.set_num_threads(threads)
torch.manual_seed(0)
model = FieldAwareUNet(deformable_scales={"dcn-all": None, "dcn-coarsest": 1}[variant])
with torch.no_grad():
    for p in model.parameters():
        p.add_(0.02 * torch.randn_like(p))
model.eval()
t = time.perf_counter()
onnx = OnnxEngine(export_model_bytes(model, {}), threads=threads)
export_s = time.perf_counter() - t
w = int(round((mp * 1e6 * 1.5) ** 0.5 / 16)) * 16
h = int(round(w / 1.5 / 16)) * 16
img = torch.rand(3, h, w, generator=torch.Generator().manual_seed(1))
times = {"torch": [], "onnxruntime": []}
outs = {}
for _ in range(rounds):
    for name, engine in (("torch", model), ("onnxruntime", onnx)):
        t = time.perf_counter()
        with torch.inference_mode():
            outs[name] = restore_image(engine, img, (0.0, 0.0), (4000.0, 6000.0))
        times[name].append(time.perf_counter() - t)
med = {k: statistics.median(v) for k, v in times.items()}
print(json.dumps({"variant": variant, "width": w, "height": h, "export_s": export_s, "seconds": med,
                  "all_seconds": times, "mp_per_s": {k: h * w / 1e6 / v for k, v in med.items()},
                  "max_abs_diff": (outs["torch"] - outs["onnxruntime"]).abs().max().item()}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--megapixels", type=float, default=1.0, help="Size of the synthetic photo.")
    ap.add_argument("--rounds", type=int, default=3, help="Restores per engine (interleaved); the median counts.")
    ap.add_argument("--variants", default="dcn-all,dcn-coarsest")
    args = ap.parse_args()
    rows = []
    for v in args.variants.split(","):
        res = subprocess.run(
            [sys.executable, "-c", CHILD, v, str(args.threads), str(args.megapixels), str(args.rounds)],
            capture_output=True,
            text=True,
            check=True,
        )
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    print(f"restore_image, tile 512 / overlap 192, {args.threads} threads, median of {args.rounds} interleaved rounds")
    print(
        f"{'variant':<14}{'image':>12}{'export s':>10}{'torch s':>9}{'ORT s':>8}{'torch MP/s':>12}{'ORT MP/s':>10}"
        f"{'ORT/torch':>11}{'max |diff|':>12}"
    )
    for r in rows:
        s, m = r["seconds"], r["mp_per_s"]
        print(
            f"{r['variant']:<14}{r['width']:>7}x{r['height']:<5}{r['export_s']:>9.1f}{s['torch']:>9.2f}"
            f"{s['onnxruntime']:>8.2f}{m['torch']:>12.3f}{m['onnxruntime']:>10.3f}"
            f"{m['onnxruntime'] / m['torch']:>10.2f}x{r['max_abs_diff']:>12.2e}"
        )
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
