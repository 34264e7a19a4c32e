"""Start-up: the command line builds its options without the restoration networks, the
training and evaluation modules, SciPy's signal/statistics packages, Dask or Matplotlib
(they load inside the commands that use them). `import lensim.cli`, `lensim --help` and
every command's --help load neither torch nor NumPy nor the optics/PSF/render stack: the
options' defaults come from plain-Python modules (lensim.psf.defaults,
lensim.optics.aiming.modes, lensim.assets). Checked in a fresh interpreter through
sys.modules, not by timing: `import lensim.cli`, `lensim --help`, `lensim CMD --help` for
every command of the app, and `lensim lens info`."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# what only training, restoring, evaluating, grids on Dask or plotting need
HEAVY = (
    "lensim.restore.network",
    "lensim.restore.models",
    "lensim.restore.train",
    "lensim.restore.deform",
    "lensim.evaluate",
    "lensim.demo",
    "lensim.report",
    "scipy.signal",
    "scipy.stats",
    "dask",
    "distributed",
    "matplotlib",
    "onnx",
    "onnxruntime",
)
# what computing needs (tensors, arrays, ray tracing, PSFs, rendering): never for building options or help
COMPUTE = (
    "torch",
    "numpy",
    "lensim.optics.lens",
    "lensim.optics.trace",
    "lensim.optics.aiming.rays",
    "lensim.optics.aiming.real",
    "lensim.psf.compute",
    "lensim.psf.bank",
    "lensim.render",
    "lensim.sensor.profile",
    "lensim.images",
    "lensim.data.pairs",
)
STARTUP = HEAVY + COMPUTE

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
    out = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=120,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def _heavy(modules: list[str] | set[str], heavy: tuple[str, ...] = HEAVY) -> list[str]:
    return [m for m in heavy if m in modules]


def test_import_and_help_leave_the_heavy_modules_unloaded() -> None:
    probe = _modules_after(["--help"])
    assert probe["exit"] == 0 and "ablation" in probe["output"] and "train" in probe["output"]
    assert _heavy(probe["import"], STARTUP) == []
    assert _heavy(probe["command"], STARTUP) == []


def test_light_commands_leave_the_heavy_modules_unloaded() -> None:
    """lens info traces rays (torch) but loads no network, training or plotting module;
    that it loads torch shows the probe sees what a command imports."""
    probe = _modules_after(["lens", "info", "cooke_triplet"])
    assert probe["exit"] == 0, probe["output"]
    assert _heavy(probe["command"]) == []
    assert _heavy(probe["command"], COMPUTE)[:1] == ["torch"]


def _command_paths() -> list[tuple[str, ...]]:
    """Every command and group of the app, as the words that name it (("lens", "info"), ("lens",), ...)."""
    import typer.main

    from lensim.cli import app

    paths: list[tuple[str, ...]] = []

    def walk(command: object, path: tuple[str, ...]) -> None:
        for name, sub in sorted(getattr(command, "commands", {}).items()):
            paths.append((*path, name))
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return paths


COMMANDS = _command_paths()

# one fresh interpreter imports lensim.cli, then runs every command's --help in turn and
# records what each one loaded
HELP_PROBE = """
import json, sys
from typer.testing import CliRunner
import lensim.cli
report = {"import": sorted(sys.modules)}
for args in json.loads(sys.argv[1]):
    before = set(sys.modules)
    result = CliRunner().invoke(lensim.cli.app, args)
    report[" ".join(args)] = {"exit": result.exit_code, "output": result.output,
                              "loaded": sorted(set(sys.modules) - before)}
print(json.dumps(report))
"""


@pytest.fixture(scope="module")
def helps() -> dict:
    """What `import lensim.cli` loaded, what each command's --help added (and, as the probe's
    control, what `lens info` added)."""
    runs = [[*path, "--help"] for path in COMMANDS] + [["lens", "info", "cooke_triplet"]]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", HELP_PROBE, json.dumps(runs)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=300,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_command_list_is_the_apps() -> None:
    assert {("lens", "info"), ("psf", "bank"), ("dataset", "make"), ("simulate",), ("restore",)} <= set(COMMANDS)


@pytest.mark.parametrize("path", COMMANDS, ids=" ".join)
def test_every_help_leaves_torch_and_the_compute_stack_unloaded(helps: dict, path: tuple[str, ...]) -> None:
    run = helps[" ".join((*path, "--help"))]
    assert run["exit"] == 0 and "Usage:" in run["output"], run["output"]
    assert _heavy(set(helps["import"]) | set(run["loaded"]), STARTUP) == []


def test_the_help_probe_sees_what_a_command_loads(helps: dict) -> None:
    """The check can fail: after the --help runs, `lens info` loads torch and the ray tracer."""
    run = helps["lens info cooke_triplet"]
    assert run["exit"] == 0, run["output"]
    assert {"torch", "lensim.optics.trace", "lensim.optics.lens"} <= set(run["loaded"])


def test_the_probe_sees_a_heavy_import() -> None:
    """The check can fail: a command that trains imports the training modules."""
    probe = _modules_after(["ablation", "no-such-pairs", "-o", "out", "--time-budget-s", "0"])
    assert probe["exit"] != 0  # refused (no such pairs folder) after the imports
    assert "lensim.restore.models" in probe["command"]
