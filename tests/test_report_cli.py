"""`lensim report` rebuilds the page from report.json; bad folders give one line."""
import json

from typer.testing import CliRunner

from lensim.cli import app
from lensim.report import write_report


def _report():
    zone = {"psnr_db": 20.0, "ssim": 0.5}
    m = {"psnr_db": 20.0, "ssim": 0.5, "zones": {"centre": zone, "middle": zone, "edge": {"psnr_db": None, "ssim": None}}}
    return {"lens": {"name": "L", "efl_mm": 50.0, "fno": 5.0, "image_height_mm": 18.0}, "sensor": {"name": "S"},
            "settings": {"quick": True}, "metrics": {"methods": {"input": m, "model": m}},
            "slanted_edge": [], "lateral_colour": [], "timings_s": {"bank": 1.0}}


def test_report_rebuilds_html_from_json(tmp_path):
    (tmp_path / "figures").mkdir()
    write_report(tmp_path, _report(), tmp_path / "figures")
    (tmp_path / "report.html").unlink()
    res = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "report.html").read_text()
    assert "<td>model</td><td>20.00</td>" in page and "<td>-</td>" in page  # null zone shown as a dash
    assert json.loads((tmp_path / "report.json").read_text())["metrics"]["methods"]["input"]["zones"]["edge"]["psnr_db"] is None


def test_report_on_a_folder_without_json_is_one_line(tmp_path):
    res = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert res.exit_code != 0
    assert "report.json" in str(res.exception or res.output)
