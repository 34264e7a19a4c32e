#!/usr/bin/env bash
# Install Debian's Chromium for the report's browser test (pytest -m slow tests/test_report_browser.py).
set -euo pipefail
if ! command -v chromium >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium
fi
chromium --version
