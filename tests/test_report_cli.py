"""`lensim report` rebuilds the page from report.json; bad folders give one line."""

import json

from typer.testing import CliRunner

from lensim.cli import app
from lensim.report import write_report


def _report():
    zone = {"psnr_db": 20.0, "ssim": 0.5}
    m = {
        "psnr_db": 20.0,
        "ssim": 0.5,
        "zones": {"centre": zone, "middle": zone, "edge": {"psnr_db": None, "ssim": None}},
    }
    return {
        "lens": {"name": "L", "efl_mm": 50.0, "fno": 5.0, "image_height_mm": 18.0},
        "sensor": {"name": "S"},
        "settings": {"quick": True},
        "metrics": {"methods": {"input": m, "model": m}},
        "slanted_edge": [],
        "lateral_colour": [],
        "timings_s": {"bank": 1.0},
    }


def test_report_rebuilds_html_from_json(tmp_path):
    (tmp_path / "figures").mkdir()
    write_report(tmp_path, _report(), tmp_path / "figures")
    (tmp_path / "report.html").unlink()
    res = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "report.html").read_text()
    assert "<td>model</td><td>20.00</td>" in page and "<td>-</td>" in page  # null zone shown as a dash
    assert (
        json.loads((tmp_path / "report.json").read_text())["metrics"]["methods"]["input"]["zones"]["edge"]["psnr_db"]
        is None
    )


def test_report_names_the_trained_networks(tmp_path):
    """The restoration section says what `model` and `plain` are, as report.json's
    training entries name them (a report without them still renders)."""
    (tmp_path / "figures").mkdir()
    m = _report()["metrics"]["methods"]["model"]
    report = {
        **_report(),
        "metrics": {"methods": {"input": m, "model": m, "plain": m}},
        "training": {
            "model": {"network": "NAFNet with FOV (stem 2, width 23)"},
            "plain": {"network": "plain NAFNet (stem 2, width 23)"},
        },
    }
    write_report(tmp_path, report, tmp_path / "figures")
    page = (tmp_path / "report.html").read_text()
    assert "<td>plain</td><td>20.00</td>" in page
    assert "<code>model</code> is the demo's network (NAFNet with FOV (stem 2, width 23))" in page
    assert "<code>plain</code> is the plain network (plain NAFNet (stem 2, width 23))" in page
    assert "plain UNet" not in page and "plain-unet" not in page


def test_report_on_a_folder_without_json_is_one_line(tmp_path):
    res = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert res.exit_code != 0
    assert "report.json" in str(res.exception or res.output)


def test_report_with_a_missing_key_is_one_line_and_rewrites_nothing(tmp_path, capsys, monkeypatch):
    from cli_runner import run_cli

    (tmp_path / "figures").mkdir()
    write_report(tmp_path, _report(), tmp_path / "figures")
    for broken, what in (
        ({k: v for k, v in _report().items() if k != "metrics"}, "metrics: missing"),
        ([1, 2], "expected a JSON object"),
    ):
        (tmp_path / "report.json").write_text(json.dumps(broken))
        before = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
        code, _, err = run_cli(["report", str(tmp_path)], capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
        assert f"{tmp_path / 'report.json'}: {what}" in err
        assert {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_demo_refuses_a_folder_made_with_other_settings(tmp_path, capsys, monkeypatch):
    """A default-size demo folder rerun with --quick stops at once with one line naming the
    marker and the differing settings (nothing is computed)."""
    from cli_runner import run_cli
    from lensim.demo import DemoSettings, _claim_folder

    _claim_folder(tmp_path, DemoSettings.make(False), quick=False, seed=0)
    _claim_folder(tmp_path, DemoSettings.make(False), quick=False, seed=0)  # the same: resumes
    code, _, err = run_cli(["demo", "--quick", "-o", str(tmp_path)], capsys, monkeypatch)
    assert code == 2
    line = err.strip()
    assert "\n" not in line and "demo.json" in line and "quick=False" in line and "new output folder" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.json"]
