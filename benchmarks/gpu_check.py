"""GPU speed check: training steps, tiled restoration and the Huygens PSF on one accelerator,
each against the CPU (issue 27's figures; `benchmarks/gpu_check.sh` runs it on the device
machine beside the CUDA tests, a torchrun launch, GPU pretraining and the held-out lenses).

    python benchmarks/gpu_check.py --device cuda --out DIR [--sections train,restore,huygens]
    python benchmarks/gpu_check.py --device cpu --tiny --out DIR      # a dry run on a laptop

Sections (each written to DIR/gpu_check.json as soon as it ends, so a killed run keeps what
it measured; a section that fails records its one-line error and the others go on):

* ``env``: torch, the device's name as the machine reports it, its memory.
* ``train``: optimizer steps per second on synthetic batches (data loading excluded), float32
  and mixed precision (bfloat16 autocast, lensim.restore.distributed.amp_dtype): the demo's
  network (the universal model's PSF-informed network, width 46, stem 2) at the demo's crop
  of 128 px and batch of 4, the same at pretraining's crop of 96 px and batch of 8, and
  `lensim train`'s default network (NAFNet with FOV channels) at the demo's crop and batch.
  Median of 5 timed blocks after a warm-up.
* ``restore``: megapixels per second restoring a 24 MP frame (6000 x 4000) with
  lensim.restore.infer.restore_image (the CLI's tiles of 512 px, 192 px overlap) through the
  shipped universal network (its Wiener input given, the network's cost alone) in float32,
  bfloat16 and float16, and each one's PSNR against float32.
* ``huygens``: the Huygens PSF of the built-in Cooke triplet at 0.7 field, 0.55 um, a 128^2
  pupil and a 128^2 image (psf_speed.py's case): the pupil traced once on the CPU, the
  Huygens sum timed on the CPU and on the device (PSFs per second), their NCC; and the whole
  compute_psf (tracer included) with the device as torch's default device, where it runs.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

# isort: off
import lensim  # noqa: F401  (before torch: lensim's OpenMP settings apply)
import torch

# isort: on


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed_blocks(fn: Callable[[], Any], device: torch.device, blocks: int, per_block: int) -> float:
    """Median seconds of one call of fn over ``blocks`` blocks of ``per_block`` calls."""
    times = []
    for _ in range(blocks):
        sync(device)
        t = time.perf_counter()
        for _ in range(per_block):
            fn()
        sync(device)
        times.append((time.perf_counter() - t) / per_block)
    return statistics.median(times)


# ----------------------------------------------------------------------------- sections


def env_section(device: torch.device) -> dict:
    info: dict[str, Any] = {"torch": torch.__version__, "device": str(device), "cpu_threads": torch.get_num_threads()}
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        info.update(
            name=torch.cuda.get_device_name(device),
            memory_gib=round(props.total_memory / 2**30, 1),
            multiprocessors=props.multi_processor_count,
            cuda=torch.version.cuda,
            bf16=torch.cuda.is_bf16_supported(),
        )
    return info


def _network(config: dict) -> torch.nn.Module:
    from lensim.restore.models import build_model

    torch.manual_seed(0)
    return build_model(config)


def _batch(model: torch.nn.Module, batch: int, crop: int, device: torch.device) -> tuple[tuple, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(batch, 3, crop, crop, generator=gen)
    fov = torch.rand(batch, 2, crop, crop, generator=gen) * 2 - 1
    args: tuple = (x, fov)
    if getattr(model, "uses_wiener", False):
        args = (x, fov, None, torch.rand(batch, 3, crop, crop, generator=gen))
    moved = tuple(a.to(device) if a is not None else None for a in args)
    return moved, (x + 0.05).to(device)


def train_rate(config: dict, batch: int, crop: int, device: torch.device, amp: bool, tiny: bool) -> dict:
    """Steps per second of Adam on MSE for one network, batch and crop."""
    from lensim.restore.distributed import amp_dtype

    model = _network(config).to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    args, target = _batch(model, batch, crop, device)
    dtype = amp_dtype(device, amp)

    def step() -> None:
        with torch.autocast(device.type, dtype=dtype, enabled=dtype is not None):
            out = model(*args)
        loss = torch.nn.functional.mse_loss(out.float(), target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    for _ in range(2 if tiny else 10):
        step()
    sec = timed_blocks(step, device, 2 if tiny else 5, 2 if tiny else 20)
    return {
        "steps_per_s": 1.0 / sec,
        "ms_per_step": 1e3 * sec,
        "amp": str(dtype).replace("torch.", "") if dtype else None,
    }


def train_section(device: torch.device, tiny: bool) -> dict:
    from lensim.restore.config import TrainConfig
    from lensim.restore.universal import load_universal

    universal = load_universal()[0].config
    cases = {
        "demo network (psfnet 46, stem 2), crop 128, batch 4": (universal, 4, 128),
        "demo network, pretraining's crop 96, batch 8": (universal, 8, 96),
        "lensim train default (nafnet FOV), crop 128, batch 4": (TrainConfig().model_kwargs(), 4, 128),
    }
    out = {}
    for name, (config, batch, crop) in cases.items():
        if tiny:
            batch, crop = 2, 32
        modes = (False, True) if device.type == "cuda" else (False,)
        out[name] = {("amp" if amp else "fp32"): train_rate(config, batch, crop, device, amp, tiny) for amp in modes}
    return out


def restore_section(device: torch.device, tiny: bool) -> dict:
    from lensim.restore.infer import restore_image
    from lensim.restore.universal import load_universal

    h, w = (400, 600) if tiny else (4000, 6000)
    gen = torch.Generator().manual_seed(1)
    image, wiener = torch.rand(3, h, w, generator=gen), torch.rand(3, h, w, generator=gen)
    model = load_universal()[0].eval()
    dtypes = (torch.float32, torch.bfloat16, torch.float16) if device.type == "cuda" else (torch.float32,)
    out: dict[str, Any] = {"megapixels": h * w / 1e6, "tile": 512, "overlap": 192}
    ref = None
    for dtype in dtypes:
        net = model.to(device=device, dtype=dtype)
        with torch.inference_mode():
            restore_image(net, image[:, :512, :512], (0.0, 0.0), (h, w), wiener=wiener[:, :512, :512])  # warm-up
            sync(device)
            t = time.perf_counter()
            got = restore_image(net, image, (0.0, 0.0), (h, w), tile=512, overlap=192, wiener=wiener)
            sync(device)
            sec = time.perf_counter() - t
        row: dict[str, Any] = {"seconds": sec, "mp_per_s": h * w / 1e6 / sec}
        if ref is None:
            ref = got.clamp(0, 1)
        else:
            mse = float((got.float().clamp(0, 1) - ref).square().mean())
            row["psnr_vs_fp32_db"] = 10 * math.log10(1.0 / max(mse, 1e-20))
        out[str(dtype).replace("torch.", "")] = row
    if device.type == "cuda":
        out["peak_gpu_mib"] = torch.cuda.max_memory_allocated(device) / 2**20
    return out


def huygens_section(device: torch.device, tiny: bool) -> dict:
    from lensim.optics.lens_file import load_lens
    from lensim.optics.paraxial import paraxial_data
    from lensim.psf.compute import compute_psf
    from lensim.psf.huygens import huygens_psf
    from lensim.psf.pupil_field import pupil_field

    samples, grid = (32, 128) if tiny else (128, 128)
    lens = load_lens("cooke_triplet")
    pf = pupil_field(lens, 0.7 * lens.max_field, 0.55, samples, "real", paraxial_data(lens))
    cpu = timed_blocks(lambda: huygens_psf(pf, grid, 0.5), torch.device("cpu"), 3, 1)
    ref = huygens_psf(pf, grid, 0.5)
    out: dict[str, Any] = {"pupil_samples": samples, "grid": grid, "cpu_threads": torch.get_num_threads()}
    out["huygens_cpu"] = {"seconds": cpu, "psfs_per_s": 1.0 / cpu}
    if device.type == "cuda":
        gpf = pf.to(device)
        huygens_psf(gpf, grid, 0.5)  # warm-up
        sec = timed_blocks(lambda: huygens_psf(gpf, grid, 0.5), device, 5, 5)
        got = huygens_psf(gpf, grid, 0.5).cpu()
        a, b = got.flatten() - got.mean(), ref.flatten() - ref.mean()
        ncc = float((a * b).sum() / (a.norm() * b.norm()))
        out["huygens_gpu"] = {"seconds": sec, "psfs_per_s": 1.0 / sec, "vs_cpu": cpu / sec, "ncc_vs_cpu": ncc}
        out["compute_psf_gpu_default_device"] = _whole_psf_on(device, lens, samples, grid, compute_psf)
    cpu_whole = timed_blocks(
        lambda: compute_psf(lens, 0.7, 0.55, pupil_samples=samples, grid=grid), torch.device("cpu"), 3, 1
    )
    out["compute_psf_cpu"] = {"seconds": cpu_whole, "psfs_per_s": 1.0 / cpu_whole}
    return out


def _whole_psf_on(device: torch.device, lens: Any, samples: int, grid: int, compute_psf: Callable) -> dict:
    """compute_psf (tracer and Huygens sum) with ``device`` as torch's default device."""
    try:
        with torch.device(device):
            compute_psf(lens, 0.7, 0.55, pupil_samples=samples, grid=grid)
            sec = timed_blocks(lambda: compute_psf(lens, 0.7, 0.55, pupil_samples=samples, grid=grid), device, 3, 1)
        return {"seconds": sec, "psfs_per_s": 1.0 / sec}
    except Exception as exc:  # a path that does not run there is a finding, recorded
        return {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0][:300]}"}


SECTIONS = {"train": train_section, "restore": restore_section, "huygens": huygens_section}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sections", default=",".join(SECTIONS))
    ap.add_argument("--tiny", action="store_true", help="tiny sizes: a dry run of the script")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads for torch (0: torch's default)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / ("gpu_check.json" if device.type == "cuda" else f"gpu_check_{device.type}.json")
    result: dict[str, Any] = {"env": env_section(device)}
    for name in args.sections.split(","):
        t = time.perf_counter()
        try:
            result[name] = SECTIONS[name](device, args.tiny)
        except Exception as exc:
            traceback.print_exc()
            result[name] = {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0][:300] if str(exc) else ''}"}
        result[name]["section_seconds"] = round(time.perf_counter() - t, 1)
        path.write_text(json.dumps(result, indent=1))
        print(f"{name}: {json.dumps(result[name])}", flush=True)


if __name__ == "__main__":
    main()
