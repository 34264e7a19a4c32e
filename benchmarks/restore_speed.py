"""Benchmark: restoration throughput and peak memory (issue 5).

Runs by hand: `python benchmarks/restore_speed.py [--threads 2] [--megapixels 4] [--big]`.
Each row runs in its own subprocess (peak RSS from getrusage) and restores a synthetic
photo with lensim.restore.infer.restore_image at the CLI's defaults (tile 512, overlap
192), FOV channels at the APS-C sensor's geometry:

* dcn-coarsest: field-aware, DCN at the coarsest decoder scale only (`--deformable-scales 1`);
* dcn-all: field-aware, DCN at every decoder scale (the paper's layout, same width);
* plain-unet: the plain UNet of the paper layout's parameter count (ratios are against it);
* with --big: dcn-coarsest on a 24-megapixel (6000 x 4000) frame, 8-bit output, with the
  allocator setting of the `lensim` command (lensim.cli.allocator: freed memory stays in
  the process) and with glibc's defaults (`-glibc`), since that setting trades memory for
  speed.

Every row but the `-glibc` one runs with the CLI's allocator setting, as `lensim restore` does.

Weights are random (seeded): speed and memory do not depend on training.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r'''
import json, resource, sys, time, torch
torch.set_num_threads(int(sys.argv[2]))
if not sys.argv[1].endswith("-glibc"):
    from lensim.cli.allocator import keep_freed_memory
    keep_freed_memory()
from lensim.restore.infer import restore_image
from lensim.restore.network import FieldAwareUNet, count_parameters, plain_unet_width
variant, mp = sys.argv[1], float(sys.argv[3])
torch.manual_seed(0)
dcn_scales = {"dcn-coarsest": 1, "dcn-all": None, "dcn-coarsest-24mp": 1, "dcn-coarsest-24mp-glibc": 1}
reference = FieldAwareUNet(deformable_scales=None)
if variant == "plain-unet":
    model = FieldAwareUNet(width=plain_unet_width(count_parameters(reference)), use_fov=False, use_deformable=False,
                           use_context=False)
else:
    model = FieldAwareUNet(deformable_scales=dcn_scales[variant])
if "-24mp" in variant:
    h, w = 4000, 6000
else:
    w = int(round((mp * 1e6 * 1.5) ** 0.5 / 16)) * 16
    h = int(round(w / 1.5 / 16)) * 16
model.eval()
img = torch.rand(3, h, w, generator=torch.Generator().manual_seed(1))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
with torch.inference_mode():
    out = restore_image(model, img, (0.0, 0.0), (4000.0, 6000.0))
    out8 = (out.clamp_(0, 1) * 255 + 0.5).to(torch.uint8)
dt = time.perf_counter() - t
print(json.dumps({"variant": variant, "width": w, "height": h, "params": count_parameters(model), "seconds": dt,
                  "mp_per_s": h * w / 1e6 / dt, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "before_mb": base / 1024}))
'''


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--megapixels", type=float, default=4.0, help="Size of the throughput image.")
    ap.add_argument("--big", action="store_true", help="Also restore a 24-megapixel frame (dcn-coarsest).")
    args = ap.parse_args()
    variants = ["dcn-coarsest", "dcn-all", "plain-unet"] + (["dcn-coarsest-24mp", "dcn-coarsest-24mp-glibc"] if args.big else [])
    rows = []
    for v in variants:
        res = subprocess.run([sys.executable, "-c", CHILD, v, str(args.threads), str(args.megapixels)],
                             capture_output=True, text=True, check=True)
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    plain = next(r for r in rows if r["variant"] == "plain-unet")["mp_per_s"]
    print(f"restore_image, tile 512 / overlap 192, {args.threads} threads, random weights")
    print(f"{'variant':<25}{'params':>10}{'image':>12}{'seconds':>10}{'MP/s':>8}{'vs plain':>10}{'peak RSS MB':>13}")
    for r in rows:
        print(f"{r['variant']:<25}{r['params']:>10,}{r['width']:>7}x{r['height']:<5}{r['seconds']:>9.1f}"
              f"{r['mp_per_s']:>8.3f}{r['mp_per_s'] / plain:>9.2f}x{r['peak_rss_mb']:>13.0f}")


if __name__ == "__main__":
    main()
