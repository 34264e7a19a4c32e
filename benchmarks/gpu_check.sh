#!/bin/bash
# The GPU check, run once on a machine with one GPU (issue 27's figures, and issue 23's GPU
# pretraining and held-out lenses), from the repository root:
#   bash benchmarks/gpu_check.sh OUT_DIR DATA_DIR [STEPS]
# DATA_DIR holds copies of the lens library's data (made on the CPU machine beforehand):
#   lib/        plan.json, sensors/ and the held-out lenses' banks (`lensim library banks`)
#   zs/LENS/pairs   the zero-shot benchmark's pairs of each held-out lens (11 unseen photos)
#   pre/        a few library pairs folders with their Wiener stage caches (`lensim library pairs`)
# Steps, each bounded in time, all writing under OUT_DIR (at most 8 files):
#   1. in the background, per held-out lens: training pairs on the CPU, then the universal
#      network fine-tuned and trained from scratch on the GPU for STEPS steps each (default
#      3600: more than a 30-minute run on one CPU core gets), scored on the lens's unseen
#      photos (benchmarks/universal_finetune.py); combined into heldout.json
#   2. benchmarks/gpu_check.py: training steps/s, 24 MP restoration MP/s, Huygens PSFs/s
#   3. universal pretraining on the GPU (`lensim library pretrain --device cuda`), 600 steps
#      (GPU_CHECK_PRETRAIN_STEPS)
#   4. the CUDA tests (pytest -m gpu)
#   5. a torchrun launch of `lensim train --device cuda` (one process, a few steps)
#   6. `lensim demo --quick --device cuda`, where time is left
set -u
OUT=${1:?usage: gpu_check.sh OUT_DIR DATA_DIR [STEPS]}
DATA=${2:?usage: gpu_check.sh OUT_DIR DATA_DIR [STEPS]}
STEPS=${3:-3600}
# GPU_CHECK_DEVICE=cpu: a dry run of this script on a machine without a GPU (use few STEPS)
DEV=${GPU_CHECK_DEVICE:-cuda}
PRETRAIN_STEPS=${GPU_CHECK_PRETRAIN_STEPS:-600}
export LENSIM_GPU_TESTS_DEVICE=$DEV
DEADLINE=${GPU_CHECK_SECONDS:-540}
PY=${PYTHON:-python3}
WORK=${GPU_CHECK_WORK:-/tmp/gpu-check}
START=$(date +%s)
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
mkdir -p "$OUT" "$WORK"
elapsed() { echo $(( $(date +%s) - START )); }
left() { echo $(( DEADLINE - $(elapsed) )); }
say() { echo "[$(elapsed) s] $*" | tee -a "$OUT/log.txt"; }

say "device: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1)"
# The first GPU_CHECK_LENSES held-out lenses (default 2): on the H200 five lenses x 2 runs x 3600
# steps, side by side, did not finish in 8 minutes (each run is bound by kernel launches and data
# loading, about 30 steps/s alone); float32 is used, mixed precision being slower there.
pids=()
for dir in $(ls -d "$DATA"/zs/*/ | head -n "${GPU_CHECK_LENSES:-2}"); do
  lens=$(basename "$dir")
  OMP_NUM_THREADS=1 timeout $(( DEADLINE - 30 )) $PY benchmarks/universal_finetune.py --library "$DATA/lib" \
    --lens "$lens" --eval-pairs "$dir/pairs" --steps "$STEPS" --device "$DEV" --no-amp --threads 1 -o "$WORK/ft/$lens" \
    > "$WORK/ft-$lens.log" 2>&1 &
  pids+=($!)
done
say "held-out lenses started: ${#pids[@]}"

say "speed"
timeout 200 $PY benchmarks/gpu_check.py --device "$DEV" $([ "$DEV" = cpu ] && echo --tiny) --out "$OUT" 2>&1 | tail -n 4 | cut -c1-400 | tee -a "$OUT/log.txt"

say "pretraining"
timeout 150 $PY -m lensim library pretrain "$DATA"/pre/* -o "$WORK/pre" --device "$DEV" --max-steps "$PRETRAIN_STEPS" \
  --minutes 100 --quiet 2>&1 | tail -n 2 | tee -a "$OUT/log.txt"
cp "$WORK/pre/log.csv" "$OUT/pretrain_log.csv" 2>/dev/null

say "tests"
timeout 240 $PY -m pytest -q -p no:cacheprovider -m gpu tests/test_gpu.py > "$OUT/tests.txt" 2>&1
tail -n 3 "$OUT/tests.txt" | tee -a "$OUT/log.txt"

say "torchrun"
first=$(ls -d "$DATA"/pre/*/ | head -n 1)
timeout 120 $PY -m torch.distributed.run --nproc_per_node 1 -m lensim train "$first" -o "$WORK/ddp" --device "$DEV" --epochs 2 \
  --steps-per-epoch 10 --quiet 2>&1 | tail -n 3 | cut -c1-600 | tee -a "$OUT/log.txt"
say "torchrun exit ${PIPESTATUS[0]}; last steps: $(tail -n 2 "$WORK/ddp/steps.csv" 2>&1 | tr '\n' ' ')"

say "waiting for the held-out lenses"
for p in "${pids[@]}"; do wait "$p"; done
for f in "$WORK"/ft-*.log; do echo "== $f"; tail -n 9 "$f"; done >> "$OUT/log.txt"
$PY - "$WORK/ft" "$OUT/heldout.json" <<'EOF'
import json, sys
from pathlib import Path
runs = {p.parent.name: json.loads(p.read_text()) for p in sorted(Path(sys.argv[1]).glob("*/result.json"))}
Path(sys.argv[2]).write_text(json.dumps(runs, indent=1))
print(f"held-out lenses scored: {len(runs)}")
EOF

if [ "$DEV" != cpu ] && [ "$(left)" -gt 150 ]; then
  say "quick demo"
  timeout $(( $(left) - 10 )) $PY -m lensim demo --quick --device cuda -o "$WORK/demo" > "$WORK/demo.log" 2>&1
  say "demo exit $?"; tail -n 25 "$WORK/demo.log" | cut -c1-300 >> "$OUT/log.txt"
  cp "$WORK/demo/report.json" "$OUT/demo_report.json" 2>/dev/null
fi
say "done"
