#!/usr/bin/env bash
# Set up lensim on a fresh machine: a virtual environment in .venv with the CPU build of
# PyTorch, lensim itself (editable) and the test-only peers (optiland, rayoptics).
# Idempotent: a second run only checks that everything is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
# torch first and pinned: on these machines 2.13.0 is the CPU wheel on local disk.
.venv/bin/python -m pip install -q --disable-pip-version-check "torch==2.13.0" 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test]" 2>&1 | grep -v "^WARNING: Location" || true
.venv/bin/python -c "import lensim, torch; print('lensim ready (torch', torch.__version__ + ')')"
