"""Grid banks: wall time and peak memory of a grid of shooting settings on Dask, the old
process pool against Dask for one bank, and how well kernels interpolate between settings.

Run by hand from the repository root (a few minutes on 2 cores):

    .venv/bin/python benchmarks/grid_bank.py [--out DIR] [--workers 2] [--skip-timing] [--skip-interpolation]

Case: the built-in Cooke triplet (f = 50 mm, F/5) on the APS-C sensor (3.92 um pixels, its
spectral response), 8 sqrt-spaced fields, 450-650 nm every 50 nm (5 wavelengths), 64
pupil samples, real aiming; kernels sized once for the whole grid (the largest any
setting's spots ask for).

Timing (each command a subprocess; peak memory is the largest sum of RSS over the
process and all its descendants, sampled every 50 ms with psutil):
* the grid: `lensim psf bank --fno 5.6,8,11 --focus-m inf,2 --workers N` (6 settings x 8
  fields, one Dask job list);
* one bank (F/5.6, infinity) three ways: `lensim psf bank --fno 5.6 --workers N` (Dask),
  the engine `psf bank` used before (a spawn ProcessPoolExecutor of N workers sending
  each field back as npz bytes, reproduced here from the same per-field function), and
  `--workers 1` (this process); the field files of all three are compared byte for byte.

Interpolation (lensim.psf.bank.GridBank.interpolated) against banks computed directly:
* F/8 from F/5.6 and F/11, two stops apart (linear in stops, the default; and linear in
  1/N), at infinity and at 2 m; the nearest grid settings (F/5.6, F/11) as baselines;
* F/6.7 from F/5.6 and F/8, one stop apart, at infinity (and the nearest settings);
* focus 4 m (0.25 dioptre) from infinity and 2 m (0 and 0.5 dioptre), at F/5.6 and
  F/11; the nearest settings (infinity, 2 m) as baselines.
Figures: kernel NCC (Pearson, per field and channel; the worst), kernel L1 error relative
to the direct kernel's sum (the worst field), and the PSNR between a photo blurred with
the interpolated bank and with the direct bank (lensim.render.pipeline.blur_energy_image,
energy domain, no noise; a 384 x 512 crop at the sensor centre and one at its corner).

Prints markdown tables.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

LENS, SENSOR = "cooke_triplet", "apsc_mirrorless"
FIELDS, WAVELENGTHS, PUPIL = 8, "450:650:50", 64
FNOS, FOCI = "5.6,8,11", "inf,2"


def bank_args() -> list[str]:
    return ["--fields", str(FIELDS), "--wavelengths-nm", WAVELENGTHS, "--pupil-samples", str(PUPIL), "--quiet"]


def bank_settings(kernel: int | None = None):
    from lensim.psf.bank import BankSettings, parse_wavelengths_nm

    return BankSettings(
        fields=FIELDS, wavelengths_nm=parse_wavelengths_nm(WAVELENGTHS), pupil_samples=PUPIL, kernel_pixels=kernel
    )


def peak_tree_rss(cmd: list[str], env: dict) -> tuple[float, float, int]:
    """(wall seconds, peak RSS of the process tree in MB, exit status) of a command."""
    import psutil

    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak = 0
    ps = psutil.Process(proc.pid)
    while proc.poll() is None:
        total = 0
        try:
            for p in [ps, *ps.children(recursive=True)]:
                try:
                    total += p.memory_info().rss
                except psutil.Error:
                    pass
        except psutil.Error:
            pass
        peak = max(peak, total)
        time.sleep(0.05)
    err = proc.stderr.read() if proc.stderr else ""
    if proc.returncode:
        print(err, file=sys.stderr)
    return time.perf_counter() - t0, peak / 2**20, proc.returncode


def lensim(args: list[str]) -> list[str]:
    return [sys.executable, "-m", "lensim", *args]


def old_pool(out: str, workers: int) -> None:
    """One bank (F/5.6, infinity) with the engine `psf bank` had before Dask: a spawn
    ProcessPoolExecutor, one torch thread per worker, fields sent back as npz bytes, the
    parent writing each field file (lensim.psf.bank.compute before it moved to run_jobs)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import ShootingSettings, lens_at
    from lensim.psf.bank import BankField
    from lensim.psf.bank.compute import _plan_bank
    from lensim.psf.bank.grid import GridAxes, grid_kernel_pixels
    from lensim.sensor.profile import load_sensor

    sensor = load_sensor(SENSOR)
    lens = load_lens(LENS)
    kernel = grid_kernel_pixels(
        [lens_at(lens, s) for s in GridAxes.from_options(FNOS, FOCI).settings()], sensor.pixel_pitch_um, bank_settings()
    )
    settings = bank_settings(kernel)
    plan = _plan_bank(
        lens_at(lens, ShootingSettings(fno=5.6)), sensor.pixel_pitch_um, kernel, settings, sensor.spectral_response, out
    )
    plan.open()
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_old, initargs=(os.getpid(),)
    ) as ex:
        futures = [ex.submit(_old_worker, t) for t in plan.tasks()]
        for fut in as_completed(futures):
            plan.finish(BankField.from_npz(io.BytesIO(fut.result())))


def _init_old(parent_pid: int) -> None:
    import torch

    from lensim.workers import exit_with_parent

    exit_with_parent(parent_pid)
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")


def _old_worker(task) -> bytes:
    from lensim.psf.bank.compute import compute_field_task

    return compute_field_task(task).to_npz_bytes()


def same_fields(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.glob("field_*.npz"))
    return (
        bool(names)
        and names == sorted(p.name for p in b.glob("field_*.npz"))
        and all((a / n).read_bytes() == (b / n).read_bytes() for n in names)
    )


def timing(out: Path, workers: int) -> tuple[float, float]:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    common = ["psf", "bank", "--lens", LENS, "--sensor", SENSOR, *bank_args()]
    rows = []
    grid_time, grid_mb, code = peak_tree_rss(
        lensim([*common, "--fno", FNOS, "--focus-m", FOCI, "--workers", str(workers), "-o", str(out / "grid")]), env
    )
    assert code == 0
    kernel = json.loads((out / "grid" / "manifest.json").read_text())["bank"]["kernel_pixels"]
    one = [*common, "--fno", "5.6", "--kernel", str(kernel)]
    runs = {
        f"Dask, {workers} workers": lensim([*one, "--workers", str(workers), "-o", str(out / "dask")]),
        f"old process pool, {workers} workers": [
            sys.executable,
            __file__,
            "--old-pool",
            str(out / "pool"),
            "--workers",
            str(workers),
            *(["--quick"] if FIELDS < 8 else []),
        ],
        "this process (--workers 1)": lensim([*one, "--workers", "1", "-o", str(out / "here")]),
    }
    times = {}
    for name, cmd in runs.items():
        t, mb, code = peak_tree_rss(cmd, env)
        assert code == 0, name
        times[name] = t
        rows.append((name, t, mb))
    load = os.getloadavg()[0]
    print(
        f"\n{LENS} on {SENSOR}, {FIELDS} fields, wavelengths {WAVELENGTHS} nm, {PUPIL} pupil samples, "
        f"kernel {kernel} px; "
        f"load average {load:.1f} before the runs\n"
    )
    print("| run | fields | wall (s) | peak RSS, process tree (MB) |")
    print("| --- | ---: | ---: | ---: |")
    print(
        f"| grid, 3 F-numbers x 2 focus distances, Dask {workers} workers | {6 * FIELDS} | {grid_time:.1f} | "
        f"{grid_mb:.0f} |"
    )
    for name, t, mb in rows:
        print(f"| one bank (F/5.6, inf), {name} | {FIELDS} | {t:.1f} | {mb:.0f} |")
    dask_t = times[f"Dask, {workers} workers"]
    pool_t = times[f"old process pool, {workers} workers"]
    same = (
        same_fields(out / "dask", out / "pool")
        and same_fields(out / "dask", out / "here")
        and same_fields(out / "dask", out / "grid" / "s000")
    )
    print(
        f"\nDask / old pool wall time: {dask_t / pool_t:.2f}; field files identical (Dask, pool, here, "
        f"the grid's F/5.6-inf bank): {same}"
    )
    return grid_time, grid_mb


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float(a @ b / math.sqrt((a @ a) * (b @ b)))


def compare(got, want, photo, sensor) -> dict:
    """Kernel NCC (worst field and channel), relative L1 (worst field) and blurred-photo
    PSNR (dB; centre and corner crops) of bank `got` against bank `want`."""
    import torch

    from lensim.render.mapping import native_mapping
    from lensim.render.pipeline import blur_energy_image

    ncc = min(
        _ncc(g.rgb[c].astype(np.float64), w.rgb[c].astype(np.float64))
        for g, w in zip(got.fields, want.fields, strict=True)
        for c in range(3)
    )
    l1 = max(
        float(np.abs(g.rgb.astype(np.float64) - w.rgb).sum() / w.rgb.sum())
        for g, w in zip(got.fields, want.fields, strict=True)
    )
    h, w = photo.shape[1:]
    psnr = []
    for top, left in (((sensor.height - h) // 2, (sensor.width - w) // 2), (0, 0)):
        m = native_mapping(h, w, sensor, top, left)
        with torch.no_grad():
            a = blur_energy_image(photo, got, m)
            b = blur_energy_image(photo, want, m)
        mse = float(((a - b) ** 2).mean())
        psnr.append(10 * math.log10(1.0 / mse) if mse > 0 else math.inf)
    return {"ncc": ncc, "l1": l1, "psnr_centre": psnr[0], "psnr_corner": psnr[1]}


def _coarse_view(grid_dir: Path, out: Path, keep) -> Path:
    """A grid folder holding some of another grid's settings (links to its banks)."""
    m = json.loads((grid_dir / "manifest.json").read_text())
    entries = [e for e in m["settings"] if keep(e["request"])]
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    for e in entries:
        (out / e["bank"]).symlink_to((grid_dir / e["bank"]).resolve())
    fnos = sorted({e["request"]["fno"] for e in entries})
    m["settings"], m["axes"]["fno"] = entries, fnos
    (out / "manifest.json").write_text(json.dumps(m))
    return out


def _blend(banks, weights):
    from lensim.psf.bank.grid_interp import _blend_field
    from lensim.psf.bank.types import PSFBank

    return PSFBank(
        banks[0].manifest, [_blend_field([b.fields[j] for b in banks], weights) for j in range(len(banks[0].fields))]
    )


def interpolation(out: Path, workers: int) -> None:
    import torch

    from lensim.assets.images import sample_image_path
    from lensim.images import read_image
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import ShootingSettings
    from lensim.psf.bank import GridAxes, GridBank, get_bank
    from lensim.sensor.isp import srgb_to_linear
    from lensim.sensor.profile import load_sensor

    sensor, lens = load_sensor(SENSOR), load_lens(LENS)
    grid_dir = out / "grid"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not (grid_dir / "manifest.json").exists():
            get_bank(
                lens,
                sensor.pixel_pitch_um,
                bank_settings(),
                shooting=GridAxes.from_options(FNOS, FOCI),
                out_dir=grid_dir,
                response=sensor.spectral_response,
                workers=workers,
            )
        full = GridBank.load(grid_dir)
        kernel = full.bank(0).kernel_pixels
        settings = bank_settings(kernel)
        direct4m = {
            n: get_bank(
                lens,
                sensor.pixel_pitch_um,
                settings,
                shooting=ShootingSettings(fno=n, focus_m=4.0),
                out_dir=out / f"direct-f{n}-4m",
                response=sensor.spectral_response,
                workers=workers,
            )
            for n in (5.6, 11.0)
        }
        direct67 = get_bank(
            lens,
            sensor.pixel_pitch_um,
            settings,
            shooting=ShootingSettings(fno=6.7),
            out_dir=out / "direct-f6.7-inf",
            response=sensor.spectral_response,
            workers=workers,
        )
    coarse = GridBank.load(_coarse_view(grid_dir, out / "coarse", lambda r: r["fno"] != 8.0))
    img, _ = read_image(sample_image_path("kodim23"))
    photo = srgb_to_linear(torch.as_tensor(img[:, :384, :512], dtype=torch.float32))
    idx = {(s.fno, s.focus_m): i for i, s in enumerate(full.settings)}
    rows = []
    for focus in (math.inf, 2.0):
        want = full.bank(idx[(8.0, focus)])
        lo, hi = full.bank(idx[(5.6, focus)]), full.bank(idx[(11.0, focus)])
        t_inv = (1 / 5.6 - 1 / 8.0) / (1 / 5.6 - 1 / 11.0)
        where = "inf" if math.isinf(focus) else f"{focus:g} m"
        rows.append(
            (
                f"F/8 at {where}, linear in stops",
                compare(coarse.interpolated(fno=8.0, focus_m=focus), want, photo, sensor),
            )
        )
        rows.append(
            (f"F/8 at {where}, linear in 1/N", compare(_blend([lo, hi], [1 - t_inv, t_inv]), want, photo, sensor))
        )
        rows.append((f"F/8 at {where}, nearest (F/5.6)", compare(lo, want, photo, sensor)))
        rows.append((f"F/8 at {where}, nearest (F/11)", compare(hi, want, photo, sensor)))
    rows.append(
        (
            "F/6.7 at inf (1 stop apart), linear in stops",
            compare(full.interpolated(fno=6.7, focus_m=math.inf), direct67, photo, sensor),
        )
    )
    rows.append(("F/6.7 at inf, nearest (F/5.6)", compare(full.bank(idx[(5.6, math.inf)]), direct67, photo, sensor)))
    rows.append(("F/6.7 at inf, nearest (F/8)", compare(full.bank(idx[(8.0, math.inf)]), direct67, photo, sensor)))
    for n in (5.6, 11.0):
        want = direct4m[n]
        rows.append(
            (f"4 m at F/{n:g}, linear in dioptres", compare(full.interpolated(fno=n, focus_m=4.0), want, photo, sensor))
        )
        rows.append((f"4 m at F/{n:g}, nearest (inf)", compare(full.bank(idx[(n, math.inf)]), want, photo, sensor)))
        rows.append((f"4 m at F/{n:g}, nearest (2 m)", compare(full.bank(idx[(n, 2.0)]), want, photo, sensor)))
    print(f"\nInterpolated (or nearest) banks against directly computed ones; kernel {kernel} px\n")
    print("| setting, from | kernel NCC (worst) | kernel L1 / sum (worst) | blurred PSNR centre (dB) | corner (dB) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, r in rows:
        print(f"| {name} | {r['ncc']:.4f} | {r['l1']:.3f} | {r['psnr_centre']:.1f} | {r['psnr_corner']:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("grid-bench"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--skip-interpolation", action="store_true")
    ap.add_argument("--quick", action="store_true", help="3 fields, 550 nm, 48 pupil samples: checks the script runs")
    ap.add_argument("--old-pool", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.quick:
        global FIELDS, WAVELENGTHS, PUPIL
        FIELDS, WAVELENGTHS, PUPIL = 3, "550", 48
    if a.old_pool:
        old_pool(a.old_pool, a.workers)
        return
    if not a.skip_timing:
        shutil.rmtree(a.out, ignore_errors=True)
        a.out.mkdir(parents=True)
        timing(a.out, a.workers)
    if not a.skip_interpolation:
        interpolation(a.out, a.workers)


if __name__ == "__main__":
    main()
