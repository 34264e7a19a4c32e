#!/bin/bash
# The run that made lensim/assets/models/universal (see its README.md): the PSF-informed universal
# network pretrained on the library's pairs. Every step resumes after a kill; rerun this script
# (or any single command) to continue the same run.
#   bash scripts/universal_pretrain.sh WORK_DIR [MINUTES] [NEW_BANKS]
# WORK_DIR/lib: the library's banks (`lensim library banks`); NEW_BANKS (default 0): how many more
# banks of the plan to compute first (all: leave it empty and run `lensim library banks` alone).
set -eu
WORK=${1:?usage: universal_pretrain.sh WORK_DIR [MINUTES] [NEW_BANKS]}
MINUTES=${2:-60}
NEW_BANKS=${3:-0}
export OMP_NUM_THREADS=1 MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=100000000000
LENSIM="nice -n 15 ${LENSIM_PYTHON:-.venv/bin/python} -W ignore -m lensim"
if [ "$NEW_BANKS" -gt 0 ]; then
  $LENSIM library banks -o "$WORK/lib" --limit "$NEW_BANKS" --quiet
fi
# 4 training photos x 3 sensor positions per bank: 12 crops of 128 px
$LENSIM library pairs "$WORK/lib" -o "$WORK/pairs" --photos-per-bank 4 --placements 3 --crops 1 --quiet
# each pairs folder's Wiener stage cache is computed first (resumable), then training in calls of
# 10 minutes (checkpointed every 2 minutes)
# (a call after the budget is spent returns at once)
for _ in $(seq 1 $((MINUTES / 10 + 1))); do
  $LENSIM library pretrain "$WORK/pairs" -o "$WORK/run" --arch psfnet --minutes "$MINUTES" --call-minutes 10 --quiet
done
$LENSIM library pretrain "$WORK/pairs" -o "$WORK/run" --arch psfnet --minutes "$MINUTES" --ship lensim/assets/models/universal --quiet
