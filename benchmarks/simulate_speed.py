"""Benchmark: simulate a 2048x1365 photo with the default lens and sensor (issue 4).

Runs by hand: `python benchmarks/simulate_speed.py [--threads 2]`. Prints a table:
the full simulation (unprocess, seam-free spatially-variant blur, mosaic, noise, AHD,
process), the blur alone, and a naive baseline in the same run: per-tile direct
convolution (torch conv2d of each 64x64 tile, padded by the kernel radius, with that
tile's kernel; no blending, so it also shows seams), with the ratio and peak memory (each
variant in its own subprocess, peak RSS from getrusage).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time, torch, torch.nn.functional as F
torch.set_num_threads(int(sys.argv[2]))
from lensim.optics.lens_file import load_lens
from lensim.sensor.profile import load_sensor
from lensim.psf.bank import BankSettings, get_bank
from lensim.render.kernels import kernel_function
from lensim.render.mapping import map_to_sensor
from lensim.render.pipeline import blur_energy_image, simulate
from lensim.assets import DEFAULT_LENS
from lensim.assets.images import sample_image_path
from lensim.images import read_image
variant = sys.argv[1]
lens, sensor = load_lens(DEFAULT_LENS), load_sensor()
img, _ = read_image(sample_image_path("kodim23"))
img = F.interpolate(img[None], size=(1365, 2048), mode="bilinear", align_corners=False)[0].clamp(0, 1)
m = map_to_sensor(1365, 2048, sensor)
settings = BankSettings(fields=32, wavelengths_nm=[400 + 20 * i for i in range(16)], pupil_samples=96,
                        cache_dir=sys.argv[3])
bank = get_bank(lens, m.pitch_um, settings, response=sensor.spectral_response)
cam = img.clone()
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
if variant == "simulate":
    out, _ = simulate(img, bank, sensor, torch.Generator().manual_seed(0))
elif variant == "blur":
    out = blur_energy_image(cam, bank, m)
else:  # naive per-tile direct convolution
    tile = 64
    kat = kernel_function(bank, m)
    rows = torch.arange(0, 1365, tile, dtype=torch.float64) + tile / 2
    cols = torch.arange(0, 2048, tile, dtype=torch.float64) + tile / 2
    out = torch.zeros_like(cam)
    for r in rows:
        ks = kat(r.repeat(len(cols)), cols).float()
        p = ks.shape[-1] // 2
        for j, c in enumerate(cols):
            y0, x0 = int(r - tile / 2), int(c - tile / 2)
            y1, x1 = min(y0 + tile, 1365), min(x0 + tile, 2048)
            src = F.pad(cam[None], (p, p, p, p))[:, :, y0:y1 + 2 * p, x0:x1 + 2 * p]
            out[:, y0:y1, x0:x1] = F.conv2d(src, ks[j].flip(-1, -2)[:, None], groups=3)[0]
dt = time.perf_counter() - t
print(json.dumps({"variant": variant, "seconds": dt, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "kernel": bank.kernel_pixels, "pitch_um": m.pitch_um}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", default="/tmp/lensim-bench-cache")
    args = ap.parse_args()
    rows = []
    for variant in ("blur", "naive", "simulate"):
        for _ in range(2):  # the first run of a variant may compute and cache the bank
            res = subprocess.run(
                [sys.executable, "-c", CHILD, variant, str(args.threads), args.cache],
                capture_output=True,
                text=True,
                check=True,
            )
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    naive = next(r for r in rows if r["variant"] == "naive")["seconds"]
    print(
        f"2048x1365, default lens and sensor, pitch {rows[0]['pitch_um']:.2f} um, kernel {rows[0]['kernel']} px, "
        f"{args.threads} threads"
    )
    print(f"{'variant':<12}{'seconds':>10}{'peak RSS MB':>14}{'vs naive':>10}")
    for r in rows:
        print(f"{r['variant']:<12}{r['seconds']:>10.2f}{r['peak_rss_mb']:>14.0f}{naive / r['seconds']:>9.2f}x")


if __name__ == "__main__":
    main()
