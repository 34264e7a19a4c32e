#!/bin/bash
# The run that made lensim/assets/models/universal (see its README.md): the library's banks in the
# background, and rounds of pairs for the banks done so far + 6 minutes of pretraining, until END.
# Every step resumes after a kill; rerun this script (or any single command) to continue.
#   bash scripts/universal_pretrain.sh WORK_DIR [END_TIME] [MINUTES]
set -u
WORK=${1:?usage: universal_pretrain.sh WORK_DIR [END_TIME] [MINUTES]}
END=$(date -d "${2:-+75 minutes}" +%s)
MINUTES=${3:-75}
export OMP_NUM_THREADS=1 MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=100000000000
LENSIM="nice -n 15 ${LENSIM_PYTHON:-.venv/bin/python} -W ignore -m lensim"
$LENSIM library banks -o "$WORK/lib" --quiet &
BANKS=$!
trap 'kill $BANKS 2>/dev/null' EXIT
while [ "$(date +%s)" -lt "$END" ]; do
  $LENSIM library pairs "$WORK/lib" -o "$WORK/pairs" --limit 6 --quiet
  $LENSIM library pretrain "$WORK/pairs" -o "$WORK/run" --minutes "$MINUTES" --call-minutes 6 --quiet || break
done
$LENSIM library pretrain "$WORK/pairs" -o "$WORK/run" --minutes 0.001 --ship lensim/assets/models/universal --quiet
