"""The lens library's bank settings against the demo's (issue 23): is the coarser library
setting (lensim.data.library_banks.LIBRARY_BANK_SETTINGS: 6 fields, 5 wavelengths, 64 pupil
samples, kernels <= 31 px) good enough, and what does it save?

For one lens and sensor (default: the demo's, the Cooke triplet on the APS-C sensor) it
computes the bank at the demo's settings (12 fields, 13 wavelengths, 128 pupil samples,
kernels <= 41 px) and at the library's, both timed in this process (one thread), and reports

* kernel NCC of the library bank against the demo bank at 9 radii from the axis to the edge
  (each kernel compared on the demo's grid, the smaller one embedded centred);
* the restoration effect: training pairs simulated through the demo bank (the truth), restored
  by the Wiener oracle with the demo bank and with the library bank; the PSNR (dB) and SSIM
  difference is what the coarser bank costs a PSF-driven restoration.

    OMP_NUM_THREADS=1 nice -n 15 python benchmarks/library_banks.py -o benchmarks/results/library_banks
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised cross-correlation of two (3, P, P) kernels (the smaller embedded centred)."""
    from lensim.psf.bank import embed_centred

    p = max(a.shape[-1], b.shape[-1])
    a = np.stack([embed_centred(c, p) for c in a]) if a.shape[-1] < p else a
    b = np.stack([embed_centred(c, p) for c in b]) if b.shape[-1] < p else b
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lens", default="cooke_triplet")
    ap.add_argument("--sensor", default="apsc_mirrorless")
    ap.add_argument("--photos", type=int, default=6, help="training photos to simulate (384 px crops)")
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    from lensim.data.library_banks import LIBRARY_BANK_SETTINGS
    from lensim.data.library_pairs import training_photos
    from lensim.data.pairs import make_dataset
    from lensim.evaluate import harness
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import load_sensor

    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    lens, sensor = load_lens(args.lens, warn=False), load_sensor(args.sensor)
    demo = BankSettings(
        fields=12, wavelengths_nm=tuple(float(w) for w in range(400, 701, 25)), pupil_samples=128, kernel_limit=41
    )
    banks, seconds = {}, {}
    for name, settings in (("demo", demo), ("library", LIBRARY_BANK_SETTINGS)):
        t = time.perf_counter()
        banks[name] = get_bank(
            lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, out_dir=out / f"bank-{name}"
        )
        seconds[name] = time.perf_counter() - t
    ref, lib = banks["demo"], banks["library"]
    radii = np.linspace(0.0, ref.radii_mm[-1], 9)
    ncc = [_ncc(ref.radial_kernel(r), lib.radial_kernel(r)) for r in radii]

    photos = training_photos(out / "photos", 384)[: args.photos]
    sharp = out / "sharp"
    sharp.mkdir(exist_ok=True)
    for p in photos:
        if not (sharp / p.name).exists():
            (sharp / p.name).write_bytes(p.read_bytes())
    make_dataset(sharp, out / "pairs", ref, args.sensor, sensor, crops=1, size=128, placements=3, seed=0)
    wiener = {"wiener": harness.builtin_method("wiener")}
    scores = {
        name: harness.evaluate(out / "pairs", wiener, bank=banks[name])["methods"] for name in ("demo", "library")
    }
    result = {
        "lens": args.lens,
        "sensor": args.sensor,
        "seconds_per_bank": seconds,
        "kernel_pixels": {"demo": ref.kernel_pixels, "library": lib.kernel_pixels},
        "ncc_radii_mm": [float(r) for r in radii],
        "ncc": ncc,
        "ncc_min": min(ncc),
        "ncc_mean": float(np.mean(ncc)),
        "input": {"psnr_db": scores["demo"]["input"]["psnr_db"], "ssim": scores["demo"]["input"]["ssim"]},
        "wiener_demo_bank": {k: scores["demo"]["wiener"][k] for k in ("psnr_db", "ssim")},
        "wiener_library_bank": {k: scores["library"]["wiener"][k] for k in ("psnr_db", "ssim")},
    }
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
