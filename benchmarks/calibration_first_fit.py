"""A quick calibration check on one camera of calibration_validation.py: the first fit
(lensim.calibrate.fit.fit on the photographed chart's data with the nominal lens's system
transfer, the element given instead of chosen) and then up to --rounds transfer refreshes
(lensim.calibrate.refresh), the PSF NCC (both windows) after each step, the zone ratios
after the last. Where calibration_validation.py takes an hour and more per camera, this
takes 20-40 minutes of one thread.

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_first_fit.py larger_decentre \
        --element e3 --rounds 1 --out benchmarks/results/calibration/sampled

Writes OUT/<camera>.first_fit.json after every step (values, sigma, RMS, seconds, NCC rows).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from calibration_validation import CAMERAS, World, photograph, psf_nccs, ratios  # type: ignore[import-not-found]

from lensim.calibrate.calibrate import chart_data, observations
from lensim.calibrate.chart_detect import detect_chart
from lensim.calibrate.fit import IMAGE_PARAMETERS, fit
from lensim.calibrate.refresh import chart_simulator, refine
from lensim.calibrate.tolerances import perturbed_lens


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("camera", choices=sorted(CAMERAS))
    ap.add_argument("--element", default="e3", help="the element whose decentre is fitted")
    ap.add_argument("--rounds", type=int, default=1, help="transfer refreshes after the first fit")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calibration/sampled"))
    ap.add_argument("--cache", type=Path, default=Path("benchmarks/results/calibration-cache"), help="bank cache")
    args = ap.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    w = World(args.cache)
    truth = perturbed_lens(w.lens, CAMERAS[args.camera])
    photo = photograph(w, truth, seed=11)
    det = detect_chart(photo, w.layout, args.camera)
    data = chart_data(photo, w.layout, w.lens, w.bank(w.lens), w.sensor, w.mapping, w.spectrum, args.camera)
    obs = observations([data], w.spectrum)
    names = [*IMAGE_PARAMETERS, f"{args.element}.decentre_x", f"{args.element}.decentre_y"]
    t0 = time.perf_counter()
    first = fit(w.lens, obs, names=names)
    out = {"camera": args.camera, "truth": CAMERAS[args.camera], "steps": []}
    step = {"step": "first fit", "values": first.values, "sigma": first.sigma, "rms": first.rms_after}
    step |= {"seconds": time.perf_counter() - t0, "starts": first.lens.as_built["starts"]}
    path = args.out / f"{args.camera}.first_fit.json"

    def record(step: dict) -> None:
        step["psf_ncc"] = psf_nccs(w, truth, {"nominal": w.lens, "fitted": perturbed_lens(w.lens, step["values"])})
        out["steps"].append(step)
        path.write_text(json.dumps(out, indent=1))

    record(step)
    sim = chart_simulator(photo, w.layout, det, data, w.sensor, w.mapping, w.bank)
    keep = ("values", "sigma", "rms_at_start", "rms_after", "moved_sigma", "simulate_s", "fit_s", "at_bound")

    def on_round(rounds: list[dict]) -> None:
        record({"step": f"round {len(rounds)}"} | {x: rounds[-1][x] for x in keep if x in rounds[-1]})

    values = refine(w.lens, obs, [sim], first, args.rounds, args.camera, on_round=on_round).values
    out["ratios_before"] = [z["ratio"] for z in ratios(w, photo, w.lens, det)]
    out["ratios_after"] = [z["ratio"] for z in ratios(w, photo, perturbed_lens(w.lens, values), det)]
    path.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
