"""Benchmark: `lensim restore` on a 24-megapixel raw file, time and peak memory (issue 14).

Runs by hand: `python benchmarks/raw_restore.py [--threads 2] [--dng] [--keep DIR]`.

It writes a simulated CFA DNG of the APS-C sensor's whole active area (6000 x 4000, the
camera of the demo: a smooth random scene through unprocess, mosaic, noise and the ADC,
lensim.raw.dng.write_capture_dng) and a checkpoint of the demo's network layout (width
32, deformable convolution at the coarsest decoder scale; random seeded weights: speed
and memory do not depend on training), then runs the whole command in a child process:
read the raw (LibRaw), develop it with the simulator's chain (AHD), restore it tile by
tile at the CLI's defaults (tile 512, overlap 192), write the 16-bit sRGB TIFF (and with
--dng the LinearRaw DNG). The child reports its wall time and peak RSS (getrusage), with
the CLI's allocator setting (lensim.cli.allocator), as `lensim restore` runs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
import torch
torch.set_num_threads(int(sys.argv[1]))
from lensim.cli import main
sys.argv = ["lensim", "restore", *sys.argv[2:]]
t = time.perf_counter()
try:
    main()
except SystemExit as e:
    if e.code:
        raise
print(json.dumps({"seconds": time.perf_counter() - t,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def make_inputs(folder: Path) -> tuple[Path, Path]:
    """A 24 MP simulated DNG and a checkpoint for its sensor, in ``folder``."""
    import torch
    import torch.nn.functional as F

    from lensim.raw.dng import write_capture_dng
    from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
    from lensim.restore.network import FieldAwareUNet
    from lensim.sensor import isp
    from lensim.sensor.profile import load_sensor

    sensor = load_sensor("apsc_mirrorless")
    g = torch.Generator().manual_seed(0)
    coarse = torch.rand(1, 3, sensor.height // 50, sensor.width // 50, generator=g)
    scene = F.interpolate(coarse, size=(sensor.height, sensor.width), mode="bicubic", align_corners=False)[0]
    cam, params = isp.unprocess(scene.clamp_(0, 1), sensor, g)
    del scene
    raw = isp.mosaic(cam, sensor.bayer_pattern)
    del cam
    params.shot, params.read = 1e-3, 2e-3
    raw = isp.quantize_raw(isp.add_noise(raw, params.shot, params.read, g), sensor)
    dng = write_capture_dng(folder / "frame.dng", raw, sensor, params)
    torch.manual_seed(0)
    model = FieldAwareUNet(width=32, deformable_scales=1).eval()
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": sensor.to_dict(),
            "lens": None,
        },
        folder / "run" / "last.pt",
    )
    return dng, folder / "run"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--dng", action="store_true", help="Also write the LinearRaw DNG (--dng).")
    ap.add_argument(
        "--keep", type=Path, default=None, help="Work in this folder and keep it (default: a temporary one)."
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        dng, run = make_inputs(folder)
        cmd = [str(run), str(dng), "-o", str(folder / "out"), "--quiet"] + (["--dng"] if args.dng else [])
        res = subprocess.run(
            [sys.executable, "-c", CHILD, str(args.threads), *cmd], capture_output=True, text=True, check=False
        )
        if res.returncode:
            sys.exit(res.stderr)
        row = json.loads(res.stdout.strip().splitlines()[-1])
    print(
        f"lensim restore on a 6000 x 4000 DNG (develop + restore + write{' + linear DNG' if args.dng else ''}), "
        f"{args.threads} threads, width-32 network (DCN at the coarsest scale), random weights"
    )
    print(f"{'seconds':>10}{'MP/s':>8}{'peak RSS MB':>13}")
    print(f"{row['seconds']:>10.1f}{24.0 / row['seconds']:>8.3f}{row['peak_rss_mb']:>13.0f}")


if __name__ == "__main__":
    main()
