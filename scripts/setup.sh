#!/usr/bin/env bash
# Set up lensim on a fresh machine: a virtual environment in .venv with the CPU build of
# PyTorch, lensim itself (editable), the test-only peers (optiland, rayoptics) and the
# linters CI runs (ruff, mypy; pinned in the `test` extra).
# Idempotent: a second run only checks that everything is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
PIP=(.venv/bin/python -m pip install -q --disable-pip-version-check)
"${PIP[@]}" --upgrade pip
# torch first and pinned: on these machines 2.13.0 is the CPU wheel on local disk.
"${PIP[@]}" "torch==2.13.0"
"${PIP[@]}" -e ".[test]"
# sample photos (Kodak, Waterloo BragZone) ship inside sporco; its own dependencies are not needed
"${PIP[@]}" --no-deps "sporco==0.2.2.post1"
# 12 more sample photos (GPL-2+) from Debian's mate-backgrounds, where apt and root are available;
# without them lensim runs on the 8 photos above
if [ ! -d /usr/share/backgrounds/mate/nature ] && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  (apt-get install -y -qq mate-backgrounds >/dev/null 2>&1 \
    || (apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mate-backgrounds >/dev/null 2>&1)) \
    || echo "note: could not install Debian's mate-backgrounds; lensim uses its 8 other sample photos"
fi
.venv/bin/python -c "import lensim, torch; print('lensim ready (torch', torch.__version__ + ')')"
