"""Which of a drawn camera's errors matter to its PSFs, with the truth known (issue 24).

For a camera of benchmarks/calibration_validation.py drawn from HELD_OUT_TOLERANCES (draw
0 of a seed), prints its true parameters, then the NCC of the true lens's Huygens PSFs
(calibration_validation._psf: 550 nm, 16 um window) against those of the truth with one
group of its parameters reset to nominal (every element tilt, decentre or spacing; the
image plane; each element's decentre, tilt or spacing): at the centre, and the worst of
the four diagonals at 0.7 and the corner. A group whose reset keeps the NCC near 1 need
not be modelled; the image parameters are not refitted after a reset, so a group the
image plane can compensate (the spacings, largely a focus change) reads worse than it is.

    python benchmarks/calibration_what_matters.py --seed 2024
"""

from __future__ import annotations

import argparse
import json
import math
import warnings

from calibration_validation import HELD_OUT_TOLERANCES, LENS, SENSOR, _ncc, _psf

from lensim.calibrate.tolerances import drawn_lens, perturbed_lens, tolerances_from_dict
from lensim.optics.lens_file import load_lens
from lensim.optics.shooting import ShootingSettings, lens_at
from lensim.render.mapping import map_to_sensor
from lensim.render.posed import quadrant_azimuths
from lensim.sensor.profile import load_sensor


def groups(parameters: dict[str, float]) -> dict[str, list[str]]:
    """The groups reset, each a list of parameter names."""
    out = {
        "every element tilt": [k for k in parameters if k.startswith("e") and ".tilt" in k],
        "every element decentre": [k for k in parameters if "decentre" in k],
        "every spacing": [k for k in parameters if k.endswith(".spacing")],
        "the image plane": [k for k in parameters if k.startswith("image.")],
    }
    for e in sorted({k.partition(".")[0] for k in parameters if k.startswith("e")}):
        for kind in ("decentre", "tilt", "spacing"):
            out[f"{e} {kind}"] = [k for k in parameters if k.startswith(f"{e}.{kind}")]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2024)
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    sensor = load_sensor(SENSOR)
    mapping = map_to_sensor(720, 960, sensor)
    lens = lens_at(load_lens(LENS, warn=False), ShootingSettings(object_m=1.0, focus_m=1.0))
    truth = drawn_lens(lens, tolerances_from_dict(HELD_OUT_TOLERANCES, lens, "held-out tolerances"), args.seed, 0)
    p = truth.as_built["parameters"]
    print(json.dumps(p, indent=1))
    half = math.hypot(mapping.x0_mm, mapping.y0_mm)
    fields = [(0.0, 0.0)] + [(f * half, az) for f in (0.7, 0.95) for az in quadrant_azimuths(mapping).values()]
    true_psfs = [_psf(truth, r, az, 16.0) for r, az in fields]
    print("| reset to nominal | centre | 0.7 worst | corner worst |\n| --- | --- | --- | --- |")
    for name, keys in {"(everything: the nominal lens)": list(p), **groups(p)}.items():
        lens_reset = perturbed_lens(lens, {k: v for k, v in p.items() if k not in keys})
        n = [_ncc(_psf(lens_reset, r, az, 16.0), t) for (r, az), t in zip(fields, true_psfs, strict=True)]
        print(f"| {name} | {n[0]:.3f} | {min(n[1:5]):.3f} | {min(n[5:9]):.3f} |", flush=True)


if __name__ == "__main__":
    main()
