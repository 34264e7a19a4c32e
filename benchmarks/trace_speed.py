"""Real-ray tracing speed: lensim against optiland's tracer on the same rays.

Run by hand from the repository root (optiland is a test-only dependency):

    .venv/bin/python benchmarks/trace_speed.py [--rays 100000 1000000] [--repeats 5]
    .venv/bin/python benchmarks/trace_speed.py --baseline ../old-checkout [--lens double_gauss phone_wide]

Lens: the built-in double Gauss (f = 100 mm, F/2, from tests/data/lenses/ag_dblgauss.seq),
one field at 10 deg, primary wavelength 587.6 nm, a square grid of pupil points inside
the unit disc, paraxial ray aiming (both tracers aim at the paraxial entrance pupil, so
the rays are identical). Each timing is the median of the repeats and covers generating
the rays for the pupil grid and tracing them to the image plane. optiland traces with
`record=False` (no per-surface history) and lensim's glass data, so that both do the
same work; the image-plane intercepts are compared to show it.

With --baseline DIR the same rays are traced by this tree's trace() and by the one of the
lensim checkout DIR (say `git worktree add ../old-checkout main`), old against new: each
tree runs in a worker process of its own (this file with --serve, DIR first on the Python
path for the baseline) that loads the rays the parent saved; the parent alternates the
two, --repeats times each, after two warm-up runs, and reports the median of the
per-run ratios old / new (above 1: this tree is faster), of wall-clock and of CPU time (the
steadier one on a shared machine, with --threads 1), and whether both trees give
bit-identical rays (positions, directions, optical paths, validity, status). The field is
the double Gauss's 10 deg for the default lens, else 0.7 of the lens's maximum field.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.trace import Rays, trace

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
    from lensim.optics.aiming.rays import generate_rays

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


def serve() -> None:
    """Worker of --baseline: 'load FILE LENS' loads saved rays, 'run' answers the wall and
    CPU seconds of one trace(), 'digest' a hash of its results, 'quit' ends."""
    lens = saved = None
    for line in sys.stdin:
        cmd, *arg = line.split()
        if cmd == "load":
            saved = torch.load(arg[0])
            lens = load_lens(arg[1], warn=False) if arg[1] != "-" else load_benchmark_lens()
            reply = "ok"
        elif cmd in ("run", "digest"):
            rays = Rays(saved["position"], saved["direction"], saved["opl"], saved["valid"])
            t0, c0 = time.perf_counter(), time.process_time()
            res = trace(lens, rays, saved["wavelength"])
            reply = f"{time.perf_counter() - t0} {time.process_time() - c0}"
            if cmd == "digest":
                out = (res.rays.position, res.rays.direction, res.rays.opl, res.rays.valid, res.status, res.failed_at)
                reply = hashlib.sha256(b"".join(t.contiguous().numpy().tobytes() for t in out)).hexdigest()
        else:
            return
        print(reply, flush=True)


class _Worker:
    """A --serve process with lensim from `tree` first on its path."""

    def __init__(self, tree: Path, threads: int | None) -> None:
        env = dict(os.environ, PYTHONPATH=str(tree))
        cmd = [sys.executable, __file__, "--serve"] + (["--threads", str(threads)] if threads else [])
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)

    def ask(self, line: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline().strip()

    def close(self) -> None:
        self.ask("quit")
        self.proc.wait()


def compare_trees(baseline: Path, lens_names: list[str], sizes: list[int], repeats: int, threads: int | None) -> None:
    """Old (baseline checkout) against new (this tree): trace() on the same saved rays."""
    from lensim.optics.aiming.rays import generate_rays

    here = Path(__file__).resolve().parents[1]
    old, new = _Worker(baseline.resolve(), threads), _Worker(here, threads)
    print(f"old: {baseline.resolve()}, new: {here}; median of {repeats} interleaved runs of trace() each")
    print("| lens | field | rays | traced | old (s) | new (s) | old / new | old / new, CPU time | bit-identical |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for name in lens_names:
            lens = load_lens(name, warn=False) if name != "-" else load_benchmark_lens()
            field = FIELD_DEG if name == "-" else 0.7 * lens.max_field  # rays that reach the image
            for n in sizes:
                rays, wl = generate_rays(
                    lens,
                    [field],
                    torch.as_tensor(pupil_grid(n)),
                    [lens.primary_wavelength_um],
                    "paraxial",
                )
                path = Path(tmp) / "rays.pt"
                torch.save(
                    dict(
                        position=rays.position, direction=rays.direction, opl=rays.opl, valid=rays.valid, wavelength=wl
                    ),
                    path,
                )
                for w in (old, new):
                    w.ask(f"load {path} {name}")
                    w.ask("run"), w.ask("run")  # warm up
                t_old, t_new = [], []  # (wall, CPU) seconds per run
                for k in range(repeats):  # alternate which goes first
                    for w, times in ((old, t_old), (new, t_new)) if k % 2 == 0 else ((new, t_new), (old, t_old)):
                        times.append(tuple(float(v) for v in w.ask("run").split()))
                ratio, cpu_ratio = (statistics.median(o[i] / m[i] for o, m in zip(t_old, t_new)) for i in (0, 1))
                same = old.ask("digest") == new.ask("digest")
                traced = float(trace(lens, rays, wl).rays.valid.double().mean())
                print(
                    f"| {lens.name or name} | {field:.3g} {lens.field_type} | {rays.opl.numel():,} | {traced:.0%} "
                    f"| {statistics.median(t[0] for t in t_old):.4f} | {statistics.median(t[0] for t in t_new):.4f} "
                    f"| {ratio:.3f} | {cpu_ratio:.3f} | {'yes' if same else 'NO'} |",
                    flush=True,
                )
    old.close(), new.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None, help="torch threads for lensim (default: torch's)")
    ap.add_argument("--baseline", type=Path, default=None, help="a lensim checkout to compare trace() against")
    ap.add_argument("--lens", nargs="+", default=["-"], help="lenses for --baseline (default: the double Gauss)")
    ap.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.serve:
        return serve()
    if args.baseline is not None:
        return compare_trees(args.baseline, args.lens, args.rays, args.repeats, args.threads)
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
