"""ruff passes on the whole repository (the check .ci/run makes before the tests), run here
too so that a change shows its findings before it lands. The baseline of what the code had
when the lint came in is pyproject.toml's per-file ignores (scripts/ruff_baseline.py).
Skipped where ruff is not installed; scripts/setup.sh installs it."""

from __future__ import annotations

import importlib.util
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _ruff_baseline_script():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("ruff_baseline", REPO / "scripts" / "ruff_baseline.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ruff_passes_with_its_baseline() -> None:
    script = _ruff_baseline_script()
    try:
        ruff = script.ruff_executable()
    except SystemExit:
        pytest.skip("ruff is not installed (scripts/setup.sh installs it)")
    run = subprocess.run(
        [ruff, "check", "--no-cache", "--output-format", "concise"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, f"ruff check found problems; fix them (do not add them to the baseline):\n{run.stdout}"
