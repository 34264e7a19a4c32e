#!/bin/bash
# The universal model made from nothing but the repository on one machine with a GPU and many
# cores, within a fixed time (lensim/assets/models/universal/README.md says which run shipped):
#   bash scripts/universal_pretrain_gpu.sh WORK_DIR OUT_DIR [SECONDS]
# 1. the library's banks of the trainable lenses, whole banks side by side on a local Dask
#    cluster of one worker per core (`lensim library banks --split train --workers N`), for at
#    most BANK_SECONDS: the banks complete by then are used (the plan's rounds order covers every
#    lens first), a rerun resumes;
# 2. their pairs (`lensim library pairs --workers N`: 2 training photos x 3 sensor positions per
#    bank), for at most PAIRS_SECONDS;
# 3. `lensim library pretrain --workers N --device cuda --no-amp`: each pairs folder's Wiener
#    stage cache, N folders at a time, then training for the time left (float32: mixed
#    precision is slower for this small network, benchmarks/results/gpu/README.md), shipped into
#    OUT_DIR/universal (model.pt, training_log.csv).
# OUT_DIR also gets log.txt (each step's time), banks.json and pairs.json (the commands' summaries).
# UNIVERSAL_DEVICE=cpu with small SECONDS: a dry run on a machine without a GPU.
set -u
WORK=${1:?usage: universal_pretrain_gpu.sh WORK_DIR OUT_DIR [SECONDS]}
OUT=${2:?usage: universal_pretrain_gpu.sh WORK_DIR OUT_DIR [SECONDS]}
TOTAL=${3:-560}
DEV=${UNIVERSAL_DEVICE:-cuda}
CORES=$(nproc)  # (before OMP_NUM_THREADS is set: nproc honours it)
WORKERS=${UNIVERSAL_WORKERS:-$CORES}
BANK_SECONDS=${UNIVERSAL_BANK_SECONDS:-240}
PAIRS_SECONDS=${UNIVERSAL_PAIRS_SECONDS:-90}
PY=${PYTHON:-python3}
START=$(date +%s)
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
mkdir -p "$OUT" "$WORK"
elapsed() { echo $(($(date +%s) - START)); }
say() { echo "[$(elapsed) s] $*" | tee -a "$OUT/log.txt"; }
AMP=$([ "$DEV" = cpu ] || echo --no-amp)

say "device: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1 | head -n 1); $CORES cores; workers $WORKERS"
say "banks"
timeout "$BANK_SECONDS" $PY -W ignore -m lensim library banks -o "$WORK/lib" --split train --workers "$WORKERS" --json \
  > "$OUT/banks.json" 2> "$WORK/banks.err"
say "banks exit $? (124: stopped at $BANK_SECONDS s); complete: $(ls "$WORK/lib/sensors" 2>/dev/null | wc -l), failed: $(ls "$WORK/lib/failed" 2>/dev/null | wc -l)"
tail -n 3 "$WORK/banks.err" | cut -c1-300 | tee -a "$OUT/log.txt"

say "pairs"
timeout "$PAIRS_SECONDS" $PY -W ignore -m lensim library pairs "$WORK/lib" -o "$WORK/pairs" --workers "$WORKERS" --json \
  > "$OUT/pairs.json" 2> "$WORK/pairs.err"
say "pairs exit $?; complete folders: $(ls "$WORK"/pairs/pairs/*/manifest.json 2>/dev/null | wc -l)"
tail -n 3 "$WORK/pairs.err" | cut -c1-300 | tee -a "$OUT/log.txt"

MINUTES=$(awk -v s=$((TOTAL - $(elapsed) - 60)) 'BEGIN { printf "%.2f", (s > 30 ? s : 30) / 60 }')
say "Wiener stage caches ($WORKERS folders at a time), then pretraining for $MINUTES minutes on $DEV"
$PY -W ignore -m lensim library pretrain "$WORK/pairs" -o "$WORK/run" --arch psfnet --device "$DEV" $AMP \
  --minutes "$MINUTES" --workers "$WORKERS" --ship "$OUT/universal" --quiet 2>&1 | tail -n 3 | cut -c1-400 | tee -a "$OUT/log.txt"
say "pretraining done; last log rows: $(tail -n 2 "$WORK/run/log.csv" 2>&1 | tr '\n' ' ')"
