"""Real-ray tracing speed: lensim against optiland's tracer on the same rays.

Run by hand from the repository root (optiland is a test-only dependency):

    .venv/bin/python benchmarks/trace_speed.py [--rays 100000 1000000] [--repeats 5]

Lens: the built-in double Gauss (f = 100 mm, F/2, from tests/data/lenses/ag_dblgauss.seq),
one field at 10 deg, primary wavelength 587.6 nm, a square grid of pupil points inside
the unit disc, paraxial ray aiming (both tracers aim at the paraxial entrance pupil, so
the rays are identical). Each timing is the median of the repeats and covers generating
the rays for the pupil grid and tracing them to the image plane. optiland traces with
`record=False` (no per-surface history) and lensim's glass data, so that both do the
same work; the image-plane intercepts are compared to show it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from lensim.optics.aiming import generate_rays
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.trace import trace

# the optiland model is built as the tests build theirs (tests/optiland_models.py, which
# imports optiland only when a model is built)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from optiland_models import optiland_from_lens  # noqa: E402
from reference_lenses import REFERENCE_LENSES  # noqa: E402

FIELD_DEG = 10.0


def load_benchmark_lens() -> Lens:
    """The built-in double Gauss, or the CODE V original, or the Zemax double Gauss."""
    for name in ("double_gauss", REFERENCE_LENSES / "ag_dblgauss.seq", REFERENCE_LENSES / "US00583336-2-scaled.zmx"):
        try:
            return load_lens(name, warn=False)
        except Exception:  # noqa: BLE001 - try the next candidate
            continue
    raise SystemExit("no double Gauss lens found")


def pupil_grid(n_rays: int) -> np.ndarray:
    """About n_rays points of a square grid inside the unit disc, (P, 2)."""
    n = int(np.ceil(np.sqrt(n_rays * 4.0 / np.pi)))
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(g, g)
    inside = x * x + y * y <= 1.0
    return np.stack([x[inside], y[inside]], -1)


def optiland_model(lens: Lens):
    """The same prescription in optiland, with lensim's index functions: one field, the
    primary wavelength."""
    return optiland_from_lens(lens, fields_deg=[FIELD_DEG], wavelengths_um=[lens.primary_wavelength_um])


def lensim_runner(lens: Lens, pupil: np.ndarray):
    """A function that generates and traces the rays once; returns (image xy or NaN)."""
    para = paraxial_data(lens)
    pts = torch.as_tensor(pupil, dtype=torch.float64)
    wl = lens.primary_wavelength_um

    def run() -> tuple[np.ndarray, float]:
        rays, wlt = generate_rays(lens, [FIELD_DEG], pts, [wl], "paraxial", para)
        t0 = time.perf_counter()
        res = trace(lens, rays, wlt)
        t_trace = time.perf_counter() - t0
        xy = res.rays.position[0, 0, :, :2].numpy()
        return np.where(res.rays.valid[0, 0, :, None].numpy(), xy, np.nan), t_trace

    return run


def optiland_runner(op, pupil: np.ndarray, wl: float):
    import optiland.backend as be

    px, py = be.array(pupil[:, 0]), be.array(pupil[:, 1])

    def run() -> np.ndarray:
        rays = op.ray_tracer.trace_generic(0.0, 1.0, px, py, wl, record=False)
        xy = np.stack([be.to_numpy(rays.x), be.to_numpy(rays.y)], -1)
        return np.where((be.to_numpy(rays.i) > 0)[:, None], xy, np.nan)

    return run


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None, help="torch threads for lensim (default: torch's)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    if args.threads:
        torch.set_num_threads(args.threads)
    lens = load_benchmark_lens()
    op = optiland_model(lens)
    rows = []
    for n in args.rays:
        pupil = pupil_grid(n)
        run_l, run_o = lensim_runner(lens, pupil), optiland_runner(op, pupil, lens.primary_wavelength_um)
        run_l(), run_o()  # warm up (optiland compiles its numba kernels on first use)
        t_l, t_tr, t_o = [], [], []
        for _ in range(args.repeats):  # interleaved, so both see the same machine load
            dt, (xy_l, dt_trace) = timed(run_l)
            t_l.append(dt)
            t_tr.append(dt_trace)
            dt, xy_o = timed(run_o)
            t_o.append(dt)
        ratio = statistics.median(o / l for o, l in zip(t_o, t_l))
        ratio_tr = statistics.median(o / l for o, l in zip(t_o, t_tr))
        ok_l, ok_o = np.isfinite(xy_l[:, 0]), np.isfinite(xy_o[:, 0])
        both = ok_l & ok_o
        diff = float(np.abs(xy_l[both] - xy_o[both]).max()) if both.any() else float("nan")
        rows.append(
            (
                len(pupil),
                statistics.median(t_l),
                statistics.median(t_tr),
                statistics.median(t_o),
                ratio,
                ratio_tr,
                diff,
                int(ok_l.sum()),
                int(ok_o.sum()),
            )
        )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"lens: {lens.name} ({lens.num_surfaces} surfaces), field {FIELD_DEG} deg, "
        f"{lens.primary_wavelength_um * 1000:.1f} nm, paraxial aiming; torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads, {os.cpu_count()} CPUs, load average {load:.1f}; "
        f"median of {args.repeats} interleaved runs"
    )
    print(
        "| rays | lensim (s) | lensim rays/s | optiland (s) | optiland rays/s | speed-up | lensim trace() only (s) "
        "| speed-up, trace() only | max abs dxy (mm) | rays reaching the image lensim / optiland |"
    )
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for n, t_l, t_tr, t_o, ratio, ratio_tr, diff, v_l, v_o in rows:
        print(
            f"| {n:,} | {t_l:.3f} | {n / t_l:,.0f} | {t_o:.3f} | {n / t_o:,.0f} | {ratio:.2f}x | {t_tr:.3f} "
            f"| {ratio_tr:.2f}x | {diff:.1e} | {v_l:,} / {v_o:,} |"
        )
    print("speed-up: median over the runs of optiland's time / lensim's (lensim: generate_rays + trace)")


if __name__ == "__main__":
    main()
