#!/usr/bin/env bash
# Issue 17's generalization measurement: the default field-aware network trained on the old
# photo set (the 20 photos lensim had: scikit-image, sporco, mate-backgrounds; MSE) against
# the same network trained on the enlarged set with the new levers (45 photos with the KDE
# and Lomiri wallpapers, exposure drawn in [-3, 0] stops per placement, the charbonnier-edge
# loss), the same wall-clock budget each, scored per photo on the unseen test photos
# (lensim.assets.images.TEST_IMAGES, never trained on) with the aberrated input and the
# Wiener oracle (true PSFs).
#
# Usage (from the repository root, after scripts/setup.sh, with the Debian wallpapers):
#   bash benchmarks/generalization.sh [OUT] [MINUTES]      # defaults: bench-generalization 10
#
# Every stage is cached in OUT (a rerun skips what exists):
#   1. the default demo's PSF bank (Cooke triplet on the APS-C sensor, 12 fields, 13
#      wavelengths 400-700 nm, 128 pupil samples);
#   2. photos: old/ (the 20 photos of before), new/ (all 45 training photos), test/ (the 11
#      unseen test photos, two of them 3 stops under in linear light);
#   3. pairs: 3 sensor placements per photo x 8 crops of 128 px, seed 0; new/ adds
#      --exposure-ev -3,0; the test pairs have no exposure draw (their dark scenes are dark);
#   4. both networks side by side, one thread (one core) each, for MINUTES: width 32, FOV
#      input, context block, deformable blocks at the coarsest decoder scale, Adam from
#      5e-4, cosine schedule over the budget, batch 4, 96-px crops, dihedral augmentation,
#      a tenth of the photos held out for validation, seed 0; old: MSE, new: charbonnier-edge;
#   5. then, alone, a third run that separates the photos from the levers: the 45 photos
#      with MSE and no exposure draw (what `lensim demo` now trains on), same recipe;
#   6. benchmarks/generalization.py: the last checkpoints, input and Wiener on every test
#      crop; the per-photo table (printed, and OUT/per_photo.md, OUT/summary.json,
#      OUT/metrics.csv).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench-generalization}
MINUTES=${2:-10}
LENSIM=${LENSIM:-.venv/bin/lensim}
PY=${PY:-.venv/bin/python}
mkdir -p "$OUT"

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

if [ ! -d "$OUT/photos-new" ]; then
  "$LENSIM" assets --export-photos "$OUT/photos-new.tmp" --export-test-photos "$OUT/photos-test.tmp" >/dev/null
  n=$(ls "$OUT/photos-new.tmp" | wc -l)
  [ "$n" = 45 ] || { echo "expected the 45 training photos (install the Debian wallpapers), got $n" >&2; exit 1; }
  mkdir -p "$OUT/photos-old.tmp"
  for f in "$OUT"/photos-new.tmp/*.png; do  # the 20 of before: all but the KDE and Lomiri wallpapers
    case "$(basename "$f")" in kde-*|lomiri-*) ;; *) cp "$f" "$OUT/photos-old.tmp/" ;; esac
  done
  mv "$OUT/photos-old.tmp" "$OUT/photos-old"; mv "$OUT/photos-test.tmp" "$OUT/photos-test"
  mv "$OUT/photos-new.tmp" "$OUT/photos-new"
fi

PAIRS="--bank $OUT/bank --placements 3 --crops 8 --size 128 --seed 0 --workers 2 --quiet"
"$LENSIM" dataset make "$OUT/photos-old" -o "$OUT/pairs-old" $PAIRS
"$LENSIM" dataset make "$OUT/photos-new" -o "$OUT/pairs-new" $PAIRS --exposure-ev=-3,0
"$LENSIM" dataset make "$OUT/photos-test" -o "$OUT/pairs-test" $PAIRS
"$LENSIM" dataset make "$OUT/photos-new" -o "$OUT/pairs-more" $PAIRS

TRAIN="--time-budget-s $((MINUTES * 60)) --threads 1 --crop 96 --batch-size 4 --lr 5e-4 --lr-schedule cosine
       --epochs 100000 --val-fraction 0.1 --seed 0 --arch unet --width 32 --deformable-scales 1 --quiet"
pids=()
if [ ! -f "$OUT/old.done" ]; then
  rm -rf "$OUT/old"
  ("$LENSIM" train "$OUT/pairs-old" -o "$OUT/old" $TRAIN --loss mse && touch "$OUT/old.done") &
  pids+=($!)
fi
if [ ! -f "$OUT/new.done" ]; then
  rm -rf "$OUT/new"
  ("$LENSIM" train "$OUT/pairs-new" -o "$OUT/new" $TRAIN --loss charbonnier-edge && touch "$OUT/new.done") &
  pids+=($!)
fi
for p in "${pids[@]}"; do wait "$p"; done
if [ ! -f "$OUT/more.done" ]; then
  rm -rf "$OUT/more"
  "$LENSIM" train "$OUT/pairs-more" -o "$OUT/more" $TRAIN --loss mse && touch "$OUT/more.done"
fi

"$PY" benchmarks/generalization.py "$OUT"
