"""CLI coherence: every subcommand exists, has help with an example, and spells the
common options one way (--lens, --sensor, --device, --workers, --seed, -o/--output,
--quiet, --json)."""

from __future__ import annotations

from typing import Any

import pytest
import typer

from lensim.cli import app

TOP = {
    "lens",
    "psf",
    "simulate",
    "dataset",
    "train",
    "restore",
    "evaluate",
    "ablation",
    "report",
    "demo",
    "assets",
    "raw",
    "develop",
    "sensor",
    "export",
    "library",
    "chart",
    "calibrate",
}
# other spellings of the common options that must not appear anywhere
FORBIDDEN = {
    "--out",
    "--outdir",
    "--output-dir",
    "--num-workers",
    "--jobs",
    "-j",
    "--gpu",
    "--cuda",
    "--random-seed",
    "--lens-file",
    "--camera",
    "--silent",
    "--verbose-json",
    "--dev",
}


def _leaves(cmd: Any, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """(path, command) of every leaf command (typer's click objects, duck-typed)."""
    if hasattr(cmd, "commands"):
        return [leaf for name, sub in sorted(cmd.commands.items()) for leaf in _leaves(sub, path + (name,))]
    return [(path, cmd)]


def _is_option(param: Any) -> bool:
    return param.param_type_name == "option"


ROOT = typer.main.get_command(app)
LEAVES = _leaves(ROOT)


def test_top_level_subcommands() -> None:
    assert set(ROOT.commands) == TOP


@pytest.mark.parametrize("path, cmd", LEAVES, ids=[" ".join(p) for p, _ in LEAVES])
def test_common_options_are_spelled_one_way(path: tuple[str, ...], cmd: Any) -> None:
    opts = {o for p in cmd.params if _is_option(p) for o in p.opts + p.secondary_opts}
    assert not opts & FORBIDDEN, f"{' '.join(path)}: {sorted(opts & FORBIDDEN)}"
    if "--output" in opts:
        assert "-o" in opts, f"{' '.join(path)}: --output without -o"
    if "--json" in opts and path not in {
        ("lens", "info"),
        ("lens", "spot"),
        ("lens", "field"),
        ("lens", "wavefront"),
        ("lens", "fans"),
        ("lens", "field-curves"),
        ("psf", "compute"),
        ("assets",),
        ("library", "list"),
        ("raw", "info"),
        ("sensor", "from-raw"),
    }:
        assert "--quiet" in opts, f"{' '.join(path)}: long job with --json but no --quiet"
    assert "Example:" in (cmd.help or ""), f"{' '.join(path)}: --help has no example"


@pytest.mark.parametrize(
    "path",
    [
        ("simulate",),
        ("dataset", "make"),
        ("psf", "bank"),
        ("restore",),
        ("chart", "make"),
        ("chart", "compare"),
        ("calibrate",),
    ],
)
def test_lens_and_sensor_options_where_a_camera_is_chosen(path: tuple[str, ...]) -> None:
    cmd = dict(LEAVES)[path]
    opts = {o for p in cmd.params if _is_option(p) for o in p.opts}
    assert {"--lens", "--sensor"} <= opts


@pytest.mark.parametrize("path", [("train",), ("restore",), ("evaluate",), ("ablation",), ("demo",)])
def test_device_option_wherever_a_network_runs(path: tuple[str, ...]) -> None:
    cmd = dict(LEAVES)[path]
    assert "--device" in {o for p in cmd.params if _is_option(p) for o in p.opts}
