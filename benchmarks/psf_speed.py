"""Huygens PSF speed and accuracy: lensim against optiland's HuygensPSF, same sampling.

Run by hand from the repository root (optiland is a test-only dependency):

    .venv/bin/python benchmarks/psf_speed.py [--rounds 3] [--repeats 3] [--skip-direct] [--skip-optiland]

Case: the built-in Cooke triplet (f = 50 mm, F/5), full field (20 deg), 0.55 um, a
128 x 128 pupil grid, a 128 x 128 image window 0.5 um apart, both aiming modes
(lensim 'paraxial' / 'real'; optiland's default paraxial aiming / its 'iterative' aimer
pointed at the same stop points as lensim's real aiming, see tests/test_psf_peers.py).
PyTorch runs on 2 threads (torch.set_num_threads(2)) and optiland's numba summation on
as many (`--threads` changes both). lensim is imported before torch, as a user's script or
the CLI does, so its OpenMP setting (passive waiting) applies; `OMP_WAIT_POLICY=ACTIVE` in
the environment shows torch's own spin-waiting. `--busy` keeps one core busy with another
process meanwhile (a shared machine). The load average is printed.

Timing: `--rounds` interleaved rounds, each timing every stage of both tools and both
aiming modes (lensim stages `--repeats` times per round, optiland's once); each figure is
the minimum over all of them. These 2-core machines are shared and noisy: interleaving
spreads a burst of outside load over every stage, and the minimum is the least-contended
measurement. Stages:
* lensim: pupil tracing (`pupil_field`: ray aiming, trace, reference sphere), the
  Huygens superposition alone (`huygens_psf`), the whole `compute_psf(method='huygens')`,
  and the Fourier (`fft_psf`) and geometric (`geometric_psf`) methods on the same pupil
  field, alone and through `compute_psf`.
* optiland: the whole `HuygensPSF` (after one small warm-up call that compiles numba's
  kernel) and, separately, its pupil tracing (`Wavefront` with the same uniform grid).
* accuracy: lensim's tiled Huygens summation against the exact direct summation
  (`huygens_psf_direct`) on the same pupil field: normalized cross-correlation (Pearson),
  maximum absolute difference relative to the direct PSF's peak, both Strehl ratios.
* agreement: lensim's PSF on optiland's own sample points (offset registration, as the
  test does) against optiland's PSF: normalized cross-correlation.

Prints markdown tables (timings in seconds); the machines are noisy, ratios taken inside
one run are what hold. The load average is printed with them.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

# isort: off
import lensim  # noqa: F401  (before torch, as for a user: lensim's OMP_WAIT_POLICY=PASSIVE applies)
import torch

# isort: on
from lensim.optics.aiming.rays import chief_ray_image_height
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.psf.compute import compute_psf
from lensim.psf.fourier import fft_psf, geometric_psf
from lensim.psf.huygens import huygens_psf, huygens_psf_direct, ideal_peak
from lensim.psf.pupil_field import pupil_field

# the optiland model of the Cooke triplet is the tests' (tests/optiland_models.py, which
# imports optiland only when a model is built)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from optiland_models import optiland_cooke  # noqa: E402

WAVELENGTH_UM = 0.55
FIELD = 1.0  # normalized (20 deg)
PUPIL_SAMPLES = 128
GRID = 128
SPACING_UM = 0.5


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """(minimum wall time in s over `repeats` calls, result of the last call)."""
    times = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalized cross-correlation (Pearson) of two equally framed windows."""
    a = np.asarray(a, dtype=np.float64) - np.mean(a)
    b = np.asarray(b, dtype=np.float64) - np.mean(b)
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def lensim_round(lens: Lens, para: ParaxialData, aiming: str, repeats: int, best: dict) -> tuple:
    """Time lensim's stages for one aiming mode (`repeats` calls each), keeping in `best`
    the minimum seen so far per stage (s). Returns (pupil field, Huygens PSF)."""
    value = FIELD * lens.max_field

    def keep(key: str, fn: Callable[[], object]) -> object:
        t, out = timed(fn, repeats)
        best[key] = min(best.get(key, math.inf), t)
        return out

    pf = keep("pupil", lambda: pupil_field(lens, value, WAVELENGTH_UM, PUPIL_SAMPLES, aiming, para))
    psf = keep("huygens", lambda: huygens_psf(pf, GRID, SPACING_UM))
    keep("fft", lambda: fft_psf(pf, GRID, SPACING_UM))
    keep("geometric", lambda: geometric_psf(pf, GRID, SPACING_UM))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for method in ("huygens", "fft", "geometric"):
            keep(
                f"compute_{method}",
                lambda m=method: compute_psf(lens, FIELD, WAVELENGTH_UM, m, PUPIL_SAMPLES, GRID, SPACING_UM, aiming),
            )
    best["rays"] = int(pf.points.shape[0])
    return pf, psf


def optiland_round(lens: Lens, para: ParaxialData, aiming: str, best: dict) -> None:
    """Time optiland's whole HuygensPSF and its pupil tracing alone once for one aiming
    mode, keeping the minimum per stage in `best` (s); also the NCC of lensim's PSF on
    optiland's sample points against optiland's."""
    import optiland.backend as be
    from optiland.psf import HuygensPSF
    from optiland.wavefront import Wavefront

    o = optiland_cooke(aiming, para.stop_semi_diameter_mm)
    pitch = SPACING_UM * 1e-3 * (GRID - 1) / GRID  # optiland's spacing is pitch N/(N-1)
    t, op = timed(
        lambda: HuygensPSF(o, (0.0, FIELD), WAVELENGTH_UM, num_rays=PUPIL_SAMPLES, image_size=GRID, pixel_pitch=pitch),
        1,
    )
    best["total"] = min(best.get("total", math.inf), t)
    t, _ = timed(
        lambda: Wavefront(
            o,
            fields=[(0.0, FIELD)],
            wavelengths=[WAVELENGTH_UM],
            num_rays=PUPIL_SAMPLES,
            distribution="uniform",
            strategy="chief_ray",
            remove_tilt=False,
        ),
        1,
    )
    best["pupil"] = min(best.get("pupil", math.inf), t)
    if "ncc" not in best:
        chief_y = chief_ray_image_height(lens, FIELD * lens.max_field, aiming, para, wavelength_um=WAVELENGTH_UM)
        half = 0.5 * SPACING_UM * 1e-3
        pf = pupil_field(lens, FIELD * lens.max_field, WAVELENGTH_UM, PUPIL_SAMPLES, aiming, para)
        mine = huygens_psf(pf, GRID, SPACING_UM, (float(op.cx) + half, float(op.cy) - chief_y + half)).numpy()
        best["ncc"] = ncc(mine, be.to_numpy(op.psf))
        best["rays"] = int(np.asarray(be.to_numpy(op.get_data((0.0, FIELD), WAVELENGTH_UM).intensity)).size)


def keep_a_core_busy() -> None:
    """Start a process that spins on one core until this one exits."""
    import atexit
    import subprocess

    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    atexit.register(hog.kill)


def arguments() -> argparse.Namespace:
    """The command line's arguments; with --busy, a busy core from now on."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds over all stages and both tools")
    ap.add_argument("--repeats", type=int, default=3, help="calls of each lensim stage per round")
    ap.add_argument("--skip-direct", action="store_true", help="skip the exact direct summation (~1-4 min per mode)")
    ap.add_argument("--skip-optiland", action="store_true", help="lensim only")
    ap.add_argument("--threads", type=int, default=2, help="torch threads, and numba's for optiland (default 2)")
    ap.add_argument("--busy", action="store_true", help="keep one core busy with another process meanwhile")
    args = ap.parse_args()
    if args.busy:
        keep_a_core_busy()
    return args


def main() -> None:
    args = arguments()

    torch.set_num_threads(args.threads)
    load_start = os.getloadavg()
    lens = load_lens("cooke_triplet")
    para = paraxial_data(lens)
    aimings = ("paraxial", "real")
    ours: dict = {a: {} for a in aimings}
    theirs: dict = {}
    fields: dict = {}
    if not args.skip_optiland:
        import optiland.backend as be
        from optiland.psf import HuygensPSF

        be.set_backend("numpy")
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
        t0 = time.perf_counter()  # warm-up: numba compiles its kernel on the first call
        HuygensPSF(
            optiland_cooke("paraxial", para.stop_semi_diameter_mm),
            (0.0, FIELD),
            WAVELENGTH_UM,
            num_rays=16,
            image_size=8,
        )
        warmup = time.perf_counter() - t0
        theirs = {a: {} for a in aimings}
    # interleaved rounds: a burst of load from elsewhere slows one round of every stage
    # instead of every repeat of one stage
    for _ in range(args.rounds):
        for a in aimings:
            fields[a] = lensim_round(lens, para, a, args.repeats, ours[a])
            if theirs:
                optiland_round(lens, para, a, theirs[a])

    direct: dict = {}
    if not args.skip_direct:
        for a in aimings:
            pf, fast = fields[a]
            t0 = time.perf_counter()
            ref = huygens_psf_direct(pf, GRID, SPACING_UM)
            dt = time.perf_counter() - t0
            peak = float(ideal_peak(pf, SPACING_UM))
            direct[a] = {
                "time": dt,
                "ncc": ncc(fast.numpy(), ref.numpy()),
                "maxdiff": float((fast - ref).abs().max() / ref.max()),
                "strehl_fast": float(fast.max()) / peak,
                "strehl_direct": float(ref.max()) / peak,
            }
    load_end = os.getloadavg()

    print(
        f"Cooke triplet, field {FIELD:g} (20 deg), {WAVELENGTH_UM} um, {PUPIL_SAMPLES}^2 pupil grid, "
        f"{GRID}^2 image at {SPACING_UM} um; torch threads {torch.get_num_threads()}, cores {os.cpu_count()}; "
        f"load average {load_start[0]:.2f} at start, {load_end[0]:.2f} at end"
    )
    print()
    print("| stage | lensim paraxial (s) | lensim real (s) | optiland paraxial (s) | optiland iterative (s) |")
    print("| --- | --- | --- | --- | --- |")

    def row(name: str, key: str, okey: str | None) -> None:
        ol = [f"{theirs[a][okey]:.3f}" if (theirs and okey) else "-" for a in aimings]
        print(f"| {name} | {ours['paraxial'][key]:.3f} | {ours['real'][key]:.3f} | {ol[0]} | {ol[1]} |")

    row("pupil tracing", "pupil", "pupil")
    row("Huygens superposition", "huygens", None)
    row("Huygens PSF, whole call", "compute_huygens", "total")
    row("Fourier PSF (fft_psf) on the pupil field", "fft", None)
    row("Fourier PSF, whole compute_psf", "compute_fft", None)
    row("geometric PSF on the pupil field", "geometric", None)
    row("geometric PSF, whole compute_psf", "compute_geometric", None)
    print()
    print(
        f"rays in the pupil: lensim {ours['paraxial']['rays']}"
        + (f", optiland {theirs['paraxial']['rays']}" if theirs else "")
    )
    if theirs:
        print(f"optiland numba warm-up (compile, once): {warmup:.1f} s")
        for a in aimings:
            ratio = theirs[a]["total"] / ours[a]["compute_huygens"]
            print(
                f"{a}: optiland HuygensPSF / lensim compute_psf = {ratio:.0f}x; "
                f"NCC lensim vs optiland on optiland's sample points {theirs[a]['ncc']:.5f}"
            )
    if direct:
        print()
        print(
            "| aiming | direct summation (s) | 1 - NCC fast vs direct | max abs diff / peak | Strehl fast | Strehl direct |"
        )
        print("| --- | --- | --- | --- | --- | --- |")
        for a in aimings:
            d = direct[a]
            print(
                f"| {a} | {d['time']:.1f} | {1.0 - d['ncc']:.1e} | {d['maxdiff']:.2e} | {d['strehl_fast']:.5f} "
                f"| {d['strehl_direct']:.5f} |"
            )


if __name__ == "__main__":
    main()
