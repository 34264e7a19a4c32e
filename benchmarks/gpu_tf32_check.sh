#!/bin/bash
# Is CUDA training of the universal model sound? (issue 23: the H200's whole-library model
# scored 0.7-1.2 dB below the CPU-trained one, erratic even on banks it trained on.)
#   bash benchmarks/gpu_tf32_check.sh OUT_DIR PAIRS_DIR[+PAIRS_DIR...] [SECONDS]
# Each PAIRS_DIR holds library pairs folders WITH their Wiener stage caches (made on the CPU
# machine: the shipped model's 27 banks). Side by side, all from seed 0, float32:
#   tf32on   width 46 on CUDA, PyTorch's default (cuDNN convolutions in TF32)
#   tf32off  width 46 on CUDA, TF32 off (benchmarks/cuda_precision_run.py)
#   w24off   width 24 on CUDA, TF32 off (a network of a quarter of the cost, for restore speed)
#   cpu      width 46 on the device machine's CPU (6 threads), the control
# The GPU runs ship a model at 1000 and 3000 steps and at the end of the time, the CPU run at
# 1000 steps or its time; OUT_DIR/RUN.tar holds RUN-STEPS/{model.pt,training_log.csv}.
# Scored afterwards on the held-out lenses (benchmarks/universal_zero_shot.py --model).
# GPU_CHECK_RUNS="NAME,TF32,DEVICE,WIDTH,THREADS ..." replaces these four runs (the CPU run is
# the one whose DEVICE is cpu: it stops at the first snapshot).
set -u
OUT=${1:?usage: gpu_tf32_check.sh OUT_DIR PAIRS_DIR [SECONDS]}
DATA=${2:?usage: gpu_tf32_check.sh OUT_DIR PAIRS_DIR [SECONDS]}
TOTAL=${3:-400}
STEPS=${GPU_CHECK_STEPS:-1000 3000}  # the snapshots (a dry run on a CPU: GPU_CHECK_STEPS="4 8")
DEV=${GPU_CHECK_DEVICE:-cuda}
PY=${PYTHON:-python3}
WORK=${GPU_CHECK_WORK:-/tmp/tf32}
START=$(date +%s)
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
mkdir -p "$OUT" "$WORK/ship"
left() { echo $((TOTAL - $(date +%s) + START)); }
say() { echo "[$(( $(date +%s) - START )) s] $*" | tee -a "$OUT/log.txt"; }

pretrain() {  # NAME TF32 DEVICE WIDTH THREADS STEPS (0: until the time is spent)
  local name=$1 tf32=$2 dev=$3 width=$4 threads=$5 steps=$6 limit amp=""
  [ "$dev" = cpu ] || amp=--no-amp
  limit=$(awk -v s=$(($(left) - 45)) 'BEGIN { printf "%.2f", (s > 6 ? s : 6) / 60 }')
  OMP_NUM_THREADS=$threads timeout $(($(left) - 5)) $PY -W ignore benchmarks/cuda_precision_run.py --tf32 "$tf32" \
    library pretrain $(for d in ${DATA//+/ }; do echo "$d"/*; done) -o "$WORK/$name" --arch psfnet --width "$width" --device "$dev" $amp \
    --max-steps "$steps" --minutes 100 --call-minutes "$limit" --seed 0 --ship "$WORK/ship/$name-$steps" --quiet \
    >> "$WORK/$name.log" 2>&1
  say "$name to $steps steps: exit $?; $(tail -n 1 "$WORK/$name/log.csv" 2>&1)"
}
series() {  # NAME TF32 DEVICE WIDTH THREADS STEPS...
  local name=$1 tf32=$2 dev=$3 width=$4 threads=$5 steps
  shift 5
  for steps in "$@"; do
    [ "$(left)" -gt 30 ] && pretrain "$name" "$tf32" "$dev" "$width" "$threads" "$steps"
  done
  ls "$WORK/ship" | grep -q "^$name-" && tar -C "$WORK/ship" -cf "$OUT/$name.tar" $(cd "$WORK/ship" && ls -d "$name"-* 2>/dev/null)
  tail -n 5 "$WORK/$name.log" | cut -c1-300 >> "$OUT/log.txt"
}

say "device: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1 | head -n 1); torch $($PY -c 'import torch; print(torch.__version__)')"
RUNS=${GPU_CHECK_RUNS:-tf32on,on,$DEV,46,2 tf32off,off,$DEV,46,2 w24off,off,$DEV,24,2 cpu,off,cpu,46,6}
for run in $RUNS; do
  IFS=, read -r name tf32 dev width threads <<< "$run"
  if [ "$dev" = cpu ]; then
    series "$name" "$tf32" "$dev" "$width" "$threads" ${STEPS%% *} &
  else
    series "$name" "$tf32" "$dev" "$width" "$threads" $STEPS 0 &
  fi
done
wait
say "done"
