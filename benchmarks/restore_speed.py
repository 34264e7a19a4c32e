"""Benchmark: restoration throughput and peak memory, the old default network against new
candidates in the same run (issues 5 and 17).

Runs by hand:

    python benchmarks/restore_speed.py [--threads 2] [--megapixels 4] [--rounds 3]
                                       [--variants a,b,...] [--big a,b,...]

Each measurement runs in its own subprocess (peak RSS from getrusage) and restores a
synthetic photo with lensim.restore.infer.restore_image (tiles of 512 px with 192 px
overlap, the CLI's defaults, unless the variant says otherwise), FOV channels at the APS-C
sensor's geometry, with the CLI's allocator setting (lensim.cli.allocator) and
torch.inference_mode. Rounds interleave the variants (the order rotates each round), so
every variant sees the same machine load; MP/s is the median over rounds and "vs old" the
median of the per-round ratios to ``unet``. Weights are random (seeded): speed and memory
do not depend on training; every weight is perturbed so that no layer is zero (NAFNet's
residual scales and the zero-initialised last convs would be). Variants:

* unet: the default field-aware UNet (width 32, DCN at the coarsest decoder scale), the
  old default (0.19 MP/s in issue 5's measurement);
* unet-dcn-all, plain-unet: the paper's layout (DCN at every decoder scale) and the plain
  UNet of its size (width 37);
* nafnet-fov: NAFNet with FOV channels, size-matched (width 46);
* nafnet-fov-stem2: the same with the pixel-unshuffle stem (every layer at half
  resolution); ``-cl``: its weights and tiles in channels_last memory format; ``-ort``:
  exported to ONNX and run by onnxruntime (lensim.restore.engines.OnnxEngine);
  ``-t1024``: tiles of 1024 px (192 px overlap: 1.5x the pixels computed instead of 2.6x);
* nafnet-full: NAFNet with FOV, DCN at the coarsest decoder scale and the context block.

With --big the named variants also restore a 24-megapixel (6000 x 4000) frame to 8 bits.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time, torch
torch.set_num_threads(int(sys.argv[2]))
from lensim.cli.allocator import keep_freed_memory
keep_freed_memory()
from lensim.restore.infer import restore_image
from lensim.restore.nafnet import NAFNet
from lensim.restore.network import FieldAwareUNet, count_parameters, plain_unet_width

variant, mp, big = sys.argv[1], float(sys.argv[3]), sys.argv[4] == "big"
torch.manual_seed(0)
base = variant.split("+")[0]
if base == "unet":
    model = FieldAwareUNet(deformable_scales=1)
elif base == "unet-dcn-all":
    model = FieldAwareUNet(deformable_scales=None)
elif base == "plain-unet":
    model = FieldAwareUNet(width=plain_unet_width(count_parameters(FieldAwareUNet())), use_fov=False,
                           use_deformable=False, use_context=False)
elif base == "nafnet-fov":
    model = NAFNet(46, use_fov=True)
elif base == "nafnet-fov-stem2":
    model = NAFNet(46, use_fov=True, stem=2)
elif base == "nafnet-full":
    model = NAFNet(36, use_fov=True, use_deformable=True, use_context=True)
else:
    raise SystemExit(f"unknown variant {variant}")
params = count_parameters(model)
with torch.no_grad():  # no zero layer (zero-initialised tails, NAFNet's beta and gamma) an engine could fold away
    for p in model.parameters():
        p.add_(0.02 * torch.randn_like(p))
opts = set(variant.split("+")[1:])
model.eval()
engine = model
if "ort" in opts:
    from lensim.restore.engines import OnnxEngine
    from lensim.restore.export import export_model_bytes
    engine = OnnxEngine(export_model_bytes(model, {}), threads=int(sys.argv[2]))
elif "cl" in opts:
    class ChannelsLast(torch.nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner.to(memory_format=torch.channels_last)
            self.size_multiple, self.use_fov = inner.size_multiple, inner.use_fov
            self.settings_dim = getattr(inner, "settings_dim", 0)
        def forward(self, rgb, fov=None, settings=None):
            cl = torch.channels_last
            return self.inner(rgb.contiguous(memory_format=cl), None if fov is None else fov.contiguous(memory_format=cl))
    engine = ChannelsLast(model).eval()
tile = 1024 if "t1024" in opts else 512
if big:
    h, w = 4000, 6000
else:
    w = int(round((mp * 1e6 * 1.5) ** 0.5 / 16)) * 16
    h = int(round(w / 1.5 / 16)) * 16
img = torch.rand(3, h, w, generator=torch.Generator().manual_seed(1))
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
with torch.inference_mode():
    out = restore_image(engine, img, (0.0, 0.0), (4000.0, 6000.0), tile=tile, overlap=192)
    out8 = (out.clamp_(0, 1) * 255 + 0.5).to(torch.uint8)
dt = time.perf_counter() - t
print(json.dumps({"variant": variant, "width": w, "height": h, "params": params, "seconds": dt,
                  "mp_per_s": h * w / 1e6 / dt, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "before_mb": before / 1024}))
"""

DEFAULT_VARIANTS = (
    "unet",
    "nafnet-fov",
    "nafnet-fov-stem2",
    "nafnet-fov-stem2+cl",
    "nafnet-fov-stem2+ort",
    "nafnet-fov-stem2+t1024",
    "nafnet-fov-stem2+ort+t1024",
)


def run(variant: str, threads: int, mp: float, big: bool) -> dict:
    res = subprocess.run(
        [sys.executable, "-c", CHILD, variant, str(threads), str(mp), "big" if big else "small"],
        capture_output=True,
        text=True,
    )
    if res.returncode:
        raise SystemExit(f"{variant} failed:\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--megapixels", type=float, default=4.0, help="Size of the throughput image.")
    ap.add_argument("--rounds", type=int, default=3, help="Interleaved rounds (medians are reported).")
    ap.add_argument("--variants", default=",".join(DEFAULT_VARIANTS), help="Comma list; 'unet' is the reference.")
    ap.add_argument("--big", default="", help="Comma list of variants that also restore a 24 MP frame.")
    args = ap.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    if "unet" not in variants:
        variants.insert(0, "unet")
    rows: dict[str, list[dict]] = {v: [] for v in variants}
    for r in range(args.rounds):
        order = variants[r % len(variants) :] + variants[: r % len(variants)]
        for v in order:
            rows[v].append(run(v, args.threads, args.megapixels, big=False))
            print(f"round {r + 1}: {v} {rows[v][-1]['mp_per_s']:.3f} MP/s", file=sys.stderr, flush=True)
    big = {v: run(v, args.threads, 0, big=True) for v in args.big.split(",") if v}
    first = rows["unet"][0]
    print(
        f"restore_image, {args.threads} threads, {first['width']}x{first['height']} image, random weights, "
        f"{args.rounds} interleaved rounds (medians)\n"
    )
    print(
        "| variant | params | MP/s | vs old (unet) | peak RSS (MB) | 24 MP time (s), from MP/s | 24 MP measured (s) "
        "| 24 MP peak RSS (MB) |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for v, rs in rows.items():
        mps = statistics.median(x["mp_per_s"] for x in rs)
        ratio = statistics.median(x["mp_per_s"] / u["mp_per_s"] for x, u in zip(rs, rows["unet"], strict=True))
        peak = max(x["peak_rss_mb"] for x in rs)
        b = big.get(v)
        print(
            f"| {v} | {rs[0]['params']:,} | {mps:.3f} | {ratio:.2f}x | {peak:.0f} | {24.0 / mps:.0f} | "
            + (f"{b['seconds']:.0f} | {b['peak_rss_mb']:.0f} |" if b else " | |")
        )
    print("\nraw:", json.dumps({"rounds": rows, "big": big}))


if __name__ == "__main__":
    main()
