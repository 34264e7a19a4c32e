"""Start-up: the command line builds its options without the restoration networks, the
training and evaluation modules, SciPy's signal/statistics packages, Dask or Matplotlib
(they load inside the commands that use them). Checked in a fresh interpreter through
sys.modules, not by timing: `import lensim.cli`, `lensim --help` and `lensim lens info`."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# what only training, restoring, evaluating, grids on Dask or plotting need
HEAVY = ("lensim.restore.network", "lensim.restore.models", "lensim.restore.train", "lensim.restore.deform",
         "lensim.evaluate", "lensim.demo", "lensim.report", "scipy.signal", "scipy.stats", "dask", "distributed",
         "matplotlib", "onnx", "onnxruntime")

PROBE = """
import json, sys
from typer.testing import CliRunner
import lensim.cli
after_import = sorted(sys.modules)
args = json.loads(sys.argv[1])
result = CliRunner().invoke(lensim.cli.app, args) if args else None
print(json.dumps({"import": after_import, "command": sorted(sys.modules),
                  "exit": None if result is None else result.exit_code,
                  "output": None if result is None else result.output}))
"""


def _modules_after(args: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", PROBE, json.dumps(args)], capture_output=True, text=True, env=env,
                         cwd=ROOT, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _heavy(modules: list[str]) -> list[str]:
    return [m for m in HEAVY if m in modules]


def test_import_and_help_leave_the_heavy_modules_unloaded() -> None:
    probe = _modules_after(["--help"])
    assert probe["exit"] == 0 and "ablation" in probe["output"] and "train" in probe["output"]
    assert _heavy(probe["import"]) == []
    assert _heavy(probe["command"]) == []


@pytest.mark.parametrize("args", [["lens", "info", "cooke_triplet"], ["train", "--help"], ["ablation", "--help"]])
def test_light_commands_leave_the_heavy_modules_unloaded(args: list[str]) -> None:
    probe = _modules_after(args)
    assert probe["exit"] == 0, probe["output"]
    assert _heavy(probe["command"]) == []


def test_the_probe_sees_a_heavy_import() -> None:
    """The check can fail: a command that trains imports the training modules."""
    probe = _modules_after(["ablation", "no-such-pairs", "-o", "out", "--time-budget-s", "0"])
    assert probe["exit"] != 0  # refused (no such pairs folder) after the imports
    assert "lensim.restore.models" in probe["command"]
