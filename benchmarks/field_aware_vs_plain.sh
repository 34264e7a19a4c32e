#!/usr/bin/env bash
# Issue 5's measurement: the field-aware network against a plain UNet of the same size,
# each trained for the same wall-clock budget on the same pairs, evaluated on held-out
# photos (PSNR overall and per field zone) with the aberrated input and the Wiener oracle.
#
# Usage (from the repository root, after scripts/setup.sh):
#   bash benchmarks/field_aware_vs_plain.sh [OUT] [MINUTES]      # defaults: bench-restore 30
#
# What it does, every stage cached in OUT (a rerun skips what exists):
#   1. the default demo's PSF bank (Cooke triplet on the APS-C sensor, 12 fields, 13
#      wavelengths 400-700 nm, 128 pupil samples), through `lensim demo`'s own code;
#   2. the built-in photos at their scale (`lensim assets --export-photos`) and 6 textured
#      test photos that no run trains on (scikit-image: motorcycle, hubble, grass, gravel,
#      brick; matplotlib: grace_hopper);
#   3. pairs: 3 sensor placements per photo (centre, middle and edge zones) x 8 crops of
#      128 px, seed 0 (`lensim dataset make`);
#   4. both networks side by side, one thread (one core) each, for MINUTES: Adam from 5e-4,
#      cosine schedule over the budget, batch 4, 96-px random crops, dihedral
#      augmentation; the field-aware net (width 32, FOV input, context block, deformable
#      blocks at the coarsest decoder scale) and the plain UNet of the same parameter
#      count (width 37); the same quarter of the photos held out by both;
#   5. `lensim evaluate` of the last checkpoints (no model selection on the test photos)
#      on the held-out photos and on the 6 unseen textured photos, as JSON.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench-restore}
MINUTES=${2:-30}
LENSIM=.venv/bin/lensim
PY=.venv/bin/python
mkdir -p "$OUT"

# (a finished bank is loaded, a partial one completed; a script file, not stdin, since the
# bank's worker processes re-import it)
cat > "$OUT/make_bank.py" <<'EOF'
import sys
from lensim.assets import DEFAULT_LENS
from lensim.demo import DemoSettings
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, get_bank
from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

if __name__ == "__main__":
    s = DemoSettings.make(quick=False)  # the demo's bank
    lens, sensor = load_lens(DEFAULT_LENS), load_sensor(DEFAULT_SENSOR)
    settings = BankSettings(fields=s.fields, wavelengths_nm=s.wavelengths_nm, pupil_samples=s.pupil_samples,
                            kernel_limit=41)
    get_bank(lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, workers=2, out_dir=sys.argv[1])
EOF
"$PY" "$OUT/make_bank.py" "$OUT/bank"

if [ ! -d "$OUT/photos" ]; then
  "$LENSIM" assets --export-photos "$OUT/photos.tmp" >/dev/null && mv "$OUT/photos.tmp" "$OUT/photos"
fi
if [ ! -d "$OUT/test_photos" ]; then
  "$PY" - "$OUT/test_photos.tmp" <<'EOF'
import sys
from pathlib import Path

import matplotlib.cbook
import numpy as np
from PIL import Image
from skimage import data

out = Path(sys.argv[1])
out.mkdir(parents=True, exist_ok=True)
photos = {"motorcycle": data.stereo_motorcycle()[0], "hubble": data.hubble_deep_field(), "grass": data.grass(),
          "gravel": data.gravel(), "brick": data.brick(),
          "grace_hopper": np.asarray(Image.open(matplotlib.cbook.get_sample_data("grace_hopper.jpg")))}
for name, img in photos.items():
    img = np.stack([img] * 3, axis=-1) if img.ndim == 2 else img[..., :3]
    Image.fromarray(img).save(out / f"{name}.png")
EOF
  mv "$OUT/test_photos.tmp" "$OUT/test_photos"
fi

PAIRS="--bank $OUT/bank --placements 3 --crops 8 --size 128 --seed 0 --quiet"
"$LENSIM" dataset make "$OUT/photos" -o "$OUT/pairs" $PAIRS
"$LENSIM" dataset make "$OUT/test_photos" -o "$OUT/test_pairs" $PAIRS

TRAIN="--time-budget-s $((MINUTES * 60)) --threads 1 --crop 96 --batch-size 4 --lr 5e-4 --lr-schedule cosine --epochs 100000
       --val-fraction 0.25 --seed 0 --quiet"
pids=()
if [ ! -f "$OUT/model.done" ]; then
  rm -rf "$OUT/model"
  ("$LENSIM" train "$OUT/pairs" -o "$OUT/model" $TRAIN --arch unet --width 32 --deformable-scales 1 && touch "$OUT/model.done") &
  pids+=($!)
fi
if [ ! -f "$OUT/plain.done" ]; then
  rm -rf "$OUT/plain"
  ("$LENSIM" train "$OUT/pairs" -o "$OUT/plain" $TRAIN --arch unet --width 37 --no-fov --no-deformable --no-context \
    && touch "$OUT/plain.done") &
  pids+=($!)
fi
for p in "${pids[@]}"; do wait "$p"; done

EVAL="--methods input,model,plain-unet,wiener --model $OUT/model/last.pt --plain-unet $OUT/plain/last.pt
      --bank $OUT/bank --json --quiet"
"$LENSIM" evaluate --pairs "$OUT/pairs" --held-out "$OUT/model" $EVAL -o "$OUT/eval-held-out" > "$OUT/held_out.json"
"$LENSIM" evaluate --pairs "$OUT/test_pairs" $EVAL -o "$OUT/eval-test-photos" > "$OUT/test_photos.json"
"$PY" - "$OUT" <<'EOF'
import csv, json, statistics, sys
from pathlib import Path

out = Path(sys.argv[1])
for name in ("held_out", "test_photos"):
    methods = json.loads((out / f"{name}.json").read_text())["methods"]
    base = methods["input"]
    print(f"\n{name} ({out / (name + '.json')})\n")
    print("| method | PSNR (dB) | gain | SSIM | centre gain | middle gain | edge gain |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for m, v in methods.items():
        gains = []
        for zone in ("centre", "middle", "edge"):
            a, b = v["zones"][zone]["psnr_db"], base["zones"][zone]["psnr_db"]
            gains.append("-" if a is None or b is None else f"{a - b:+.2f}")
        print(f"| {m} | {v['psnr_db']:.2f} | {v['psnr_db'] - base['psnr_db']:+.2f} | {v['ssim']:.4f} | "
              + " | ".join(gains) + " |")
    # paired per crop: the two networks restored the same crops
    crops = {}
    for row in csv.DictReader(open(out / f"eval-{name.replace('_', '-')}" / "metrics.csv")):
        crops.setdefault((row["record"], row["crop"]), {})[row["method"]] = float(row["psnr_db"])
    diff = [c["model"] - c["plain-unet"] for c in crops.values()]
    print(f"\nmodel - plain-unet per crop: mean {statistics.mean(diff):+.3f} dB, sd {statistics.stdev(diff):.3f}, "
          f"model ahead on {sum(d > 0 for d in diff)} of {len(diff)} crops")
for run in ("model", "plain"):
    rows = (out / run / "log.csv").read_text().splitlines()
    print(f"\n{run}: {rows[-1].split(',')[1]} steps in {float(rows[-1].split(',')[-1]):.0f} s")
EOF
