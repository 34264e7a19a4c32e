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
# 37 more training photos where apt and root are available (without them lensim trains on the
# 8 photos in sporco, below): Debian's mate-backgrounds (12 nature photos, GPL-2+, 46 MB),
# plasma-workspace-wallpapers (11 KDE photos, LGPL-3 / GPL-2+, 94 MB) and lomiri-wallpapers-16.04
# (14 contest photos, CC-BY-4.0 / CC-BY-SA-4.0 / CC0, 16 MB): about 156 MB to download, 10-30 s
# on a fast mirror (measured: 1.7 s download at 180 MB/s + 4.3 s install for the last two).
# Installed in the background while pip works.
DEBIAN_PHOTOS=(mate-backgrounds plasma-workspace-wallpapers lomiri-wallpapers-16.04)
photos_pid=
if { [ ! -d /usr/share/backgrounds/mate/nature ] || [ ! -d /usr/share/wallpapers/Path ] \
     || [ ! -f /usr/share/backgrounds/life_by_Aitzol_Berasategi.jpg ]; } \
   && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  export DEBIAN_FRONTEND=noninteractive
  ( (apt-get install -y -qq --no-install-recommends "${DEBIAN_PHOTOS[@]}" >/dev/null 2>&1 \
    || (apt-get update -qq >/dev/null 2>&1 \
        && apt-get install -y -qq --no-install-recommends "${DEBIAN_PHOTOS[@]}" >/dev/null 2>&1)) \
    || echo "note: could not install Debian's ${DEBIAN_PHOTOS[*]}; lensim trains on its 8 other sample photos" ) &
  photos_pid=$!
fi
# --no-compile: no bytecode for the ~10,000 installed modules (torch, the peers); Python
# compiles the few hundred it imports on first use.
PIP=(.venv/bin/python -m pip install -q --disable-pip-version-check --no-compile)
"${PIP[@]}" --upgrade pip
# torch pinned: on these machines 2.13.0 is the CPU wheel on local disk.
"${PIP[@]}" "torch==2.13.0" -e ".[test]"
# sample photos (Kodak, Waterloo BragZone) ship inside sporco; its own dependencies are not needed
"${PIP[@]}" --no-deps "sporco==0.2.2.post1"
if [ -n "$photos_pid" ]; then
  wait "$photos_pid"
fi
.venv/bin/python -c "import lensim, torch; print('lensim ready (torch', torch.__version__ + ')')"
