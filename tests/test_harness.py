"""The evaluation harness and `lensim evaluate` on a tiny generated pairs dataset."""

import json
import math

import pytest
import typer
from typer.testing import CliRunner

from lensim.cli.evaluate_cmd import evaluate_command
from lensim.data.pairs import make_dataset
from lensim.errors import InputError
from lensim.evaluate import harness
from lensim.evaluate.metrics import ZONES
from tests.tiny_camera import tiny_camera


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Two photos on a 128 x 96 pixel sensor (the APS-C profile's pitch), one 96 px crop
    each, which spans every field zone (its corners lie beyond 2/3 of the half-diagonal)."""
    base = tmp_path_factory.mktemp("harness")
    sharp, sensor_file, sensor, bank = tiny_camera(base)
    make_dataset(sharp, base / "pairs", bank, str(sensor_file), sensor, crops=1, size=96, seed=1)
    return base / "pairs"


def _methods():
    return {
        "wiener": harness.builtin_method("wiener"),
        "rl": harness.builtin_method("rl", iterations=2),
        "unsharp": harness.builtin_method("unsharp"),
    }


def _check_summary(summary):
    assert set(summary) == {"methods"}
    assert list(summary["methods"]) == ["input", "wiener", "rl", "unsharp"]
    for m in summary["methods"].values():
        assert set(m) == {"psnr_db", "ssim", "zones"}
        assert set(m["zones"]) == set(ZONES)
        for v in (m["psnr_db"], m["ssim"]):
            assert isinstance(v, float) and math.isfinite(v)
        for z in m["zones"].values():
            assert set(z) == {"psnr_db", "ssim"}
            assert all(isinstance(v, float) and math.isfinite(v) for v in z.values())
    assert 10 < summary["methods"]["input"]["psnr_db"] < 60
    assert 0 < summary["methods"]["input"]["ssim"] <= 1


def test_evaluate_shape_rows_and_writers(pairs, tmp_path):
    rows = []
    calls = []
    summary = harness.evaluate(pairs, _methods(), rows=rows, progress=lambda d, t: calls.append((d, t)))
    _check_summary(summary)
    assert calls[0] == (0, 2) and calls[-1] == (2, 2)
    assert len(rows) == 2 * 4
    for r in rows:
        assert sum(r[f"{z}_pixels"] for z in ZONES) == 96 * 96
        assert all(r[f"{z}_pixels"] > 0 for z in ZONES)
    # the summary is the documented aggregate of the rows
    inp = [r for r in rows if r["method"] == "input"]
    assert abs(summary["methods"]["input"]["psnr_db"] - sum(r["psnr_db"] for r in inp) / 2) < 1e-9
    w = [r["edge_pixels"] for r in inp]
    want = sum(r["edge_psnr_db"] * n for r, n in zip(inp, w)) / sum(w)
    assert abs(summary["methods"]["input"]["zones"]["edge"]["psnr_db"] - want) < 1e-9
    # a method that returns its input scores exactly like `input`
    same = harness.evaluate(pairs, {"copy": lambda x, ctx: x.clone()})
    assert same["methods"]["copy"] == same["methods"]["input"]
    # writers
    csv_path = harness.write_csv(rows, tmp_path / "m.csv")
    lines = csv_path.read_text().splitlines()
    assert len(lines) == 1 + len(rows) and lines[0].startswith("record,crop,source,input,sensor_top")
    md = harness.markdown_table(summary)
    assert md.count("\n") == 2 + 4 and "| wiener |" in md


def test_sources_filter_and_errors(pairs):
    one = harness.evaluate_rows(pairs, {}, sources=["coffee.png"])
    assert len(one) == 1 and one[0]["source"].endswith("coffee.png")
    with pytest.raises(InputError):
        harness.evaluate_rows(pairs, {}, sources=["nope.png"])
    with pytest.raises(InputError):
        harness.evaluate(pairs.parent / "missing", {})
    with pytest.raises(InputError):
        harness.builtin_method("median")


def test_cli_json_and_files(pairs, tmp_path):
    app = typer.Typer()
    app.command()(evaluate_command)
    out = tmp_path / "eval"
    res = CliRunner().invoke(
        app,
        [
            "--pairs",
            str(pairs),
            "--methods",
            "input,wiener,rl,unsharp",
            "--rl-iterations",
            "2",
            "--json",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    _check_summary(summary)
    assert json.loads((out / "metrics.json").read_text()) == summary
    assert (out / "metrics.csv").read_text().count("\n") == 1 + 2 * 4
    assert "| unsharp |" in (out / "metrics.md").read_text()
    # a checkpoint method without its run is a clear error
    bad = CliRunner().invoke(app, ["--pairs", str(pairs), "--methods", "input,model"])
    assert bad.exit_code != 0 and isinstance(bad.exception, InputError) and "--model" in str(bad.exception)


def test_checkpoint_method_restores_with_sensor_offsets(pairs, tmp_path):
    import torch

    from lensim.restore.checkpoint import CHECKPOINT_FORMAT
    from lensim.restore.network import FieldAwareUNet

    torch.manual_seed(0)
    net = FieldAwareUNet(width=4, depth=2, zero_init_tail=True)  # residual output 0: restores to its input
    ckpt = tmp_path / "net.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "model_config": net.config, "model_state": net.state_dict()}, ckpt)
    summary = harness.evaluate(pairs, {"model": harness.checkpoint_method(ckpt)})
    a, b = summary["methods"]["input"], summary["methods"]["model"]
    assert abs(a["psnr_db"] - b["psnr_db"]) < 1e-3 and abs(a["ssim"] - b["ssim"]) < 1e-4
    with torch.no_grad():  # a non-zero tail changes the output, and the harness sees it
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    torch.save({"format": CHECKPOINT_FORMAT, "model_config": net.config, "model_state": net.state_dict()}, ckpt)
    app = typer.Typer()
    app.command()(evaluate_command)
    res = CliRunner().invoke(app, ["--pairs", str(pairs), "--methods", "input,model", "--model", str(ckpt), "--json"])
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["methods"]
    assert list(got) == ["input", "model"] and math.isfinite(got["model"]["psnr_db"])
    assert got["model"]["psnr_db"] != got["input"]["psnr_db"]


def test_plain_network_method_and_its_old_names(pairs, tmp_path):
    """`lensim evaluate`'s baseline method `plain` (--plain) and its old names `plain-unet`
    (--plain-unet), in any pairing: the same checkpoint restores (a zero-tail network
    returns its input), keyed by the name used in --methods."""
    import torch

    from lensim.restore.checkpoint import CHECKPOINT_FORMAT
    from lensim.restore.nafnet import NAFNet

    torch.manual_seed(0)
    net = NAFNet(4, stem=2)  # no FOV, no deformable blocks, no context block: a plain network
    ckpt = tmp_path / "plain.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "model_config": net.config, "model_state": net.state_dict()}, ckpt)
    app = typer.Typer()
    app.command()(evaluate_command)
    for method, option in (
        ("plain", "--plain"),
        ("plain-unet", "--plain-unet"),
        ("plain-unet", "--plain"),
        ("plain", "--plain-unet"),
    ):
        res = CliRunner().invoke(
            app, ["--pairs", str(pairs), "--methods", f"input,{method}", option, str(ckpt), "--json"]
        )
        assert res.exit_code == 0, (method, option, res.output)
        got = json.loads(res.stdout)["methods"]
        assert list(got) == ["input", method], (method, option)
        assert abs(got[method]["psnr_db"] - got["input"]["psnr_db"]) < 1e-3, (method, option)
