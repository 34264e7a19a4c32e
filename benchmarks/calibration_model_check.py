"""Calibration in the model world: the fit (lensim.calibrate.fit) on SFRs made by its own
edge model (lensim.calibrate.model) of a perturbed lens, plus Gaussian noise of 0.01, at
the chart's 17 squares (centre and fields 0.3-0.9 on the four diagonals, both edge
directions) of benchmarks/calibration_validation.py's camera. No photo, no simulation:
what the fit recovers when the observations are exactly what it models.

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_model_check.py focus_decentre \
        --out benchmarks/results/calibration/model_world [--candidates K]

With --candidates K the K elements the linear model ranks best are each fitted in full
(lensim.calibrate.fit.fit(candidates=)); the result goes to CAMERA.candidatesK.json.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from calibration_validation import CAMERAS, World  # type: ignore[import-not-found]

from lensim.calibrate.calibrate import FREQ_CY_PX
from lensim.calibrate.fit import Observations, fit
from lensim.calibrate.model import Edge, model_mtfs
from lensim.calibrate.tolerances import perturbed_lens


def chart_edges(world: World) -> list[Edge]:
    """Both edge directions at the centre and at fields 0.3-0.9 of the four diagonals."""
    p = world.mapping.pitch_um * 1e-3
    f = tuple((FREQ_CY_PX / p).tolist())
    edges = []
    for h in (0.0, 0.3, 0.5, 0.7, 0.9):
        for az in world.azimuths.values() if h else [0.0]:
            r = h * world.half_diagonal
            x, y = -r * math.sin(math.radians(az)), r * math.cos(math.radians(az))
            edges += [Edge(x, y, 0.0, f), Edge(x, y, 90.0, f)]
    return edges


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("camera", choices=sorted(CAMERAS))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calibration/model_world"))
    ap.add_argument("--cache", type=Path, default=Path("benchmarks/results/calibration-cache"))
    ap.add_argument("--candidates", type=int, default=1, help="elements fitted in full for the choice")
    args = ap.parse_args()
    torch.set_num_threads(1)
    world = World(args.cache)
    edges = chart_edges(world)
    truth = perturbed_lens(world.lens, CAMERAS[args.camera])
    rng = np.random.default_rng(0)
    measured = [m + rng.normal(0.0, 0.01, m.shape) for m in model_mtfs(truth, edges, *world.spectrum)]
    obs = Observations(edges, measured, None, list(world.spectrum[0]), list(world.spectrum[1]))
    t0 = time.perf_counter()
    res = fit(world.lens, obs, candidates=args.candidates)
    out = {
        "camera": args.camera,
        "truth": CAMERAS[args.camera],
        "fitted": res.values,
        "sigma": res.sigma,
        "rms_residual": [res.rms_before, res.rms_after],
        "starts": res.lens.as_built["starts"],
        "candidates": res.lens.as_built.get("candidates", []),
        "degenerate": res.degenerate,
        "evaluations": res.evaluations,
        "traces": res.traces,
        "seconds": time.perf_counter() - t0,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    suffix = f".candidates{args.candidates}" if args.candidates > 1 else ""
    (args.out / f"{args.camera}{suffix}.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
