"""`lensim calibrate`: one-line errors before any work (the fit itself: test_calibrate_fit,
benchmarks/calibration_validation.py)."""

import pytest

from cli_runner import run_cli


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["-o", "{tmp}/as_built.txt"], "--output: expected a .json, .yaml or .yml file name"),
        (["-o", "{tmp}/as_built.yaml", "--elements", "9"], "--elements"),
        (["-o", "{tmp}/as_built.yaml", "--model-samples", "4"], "--model-samples"),
        (["-o", "{tmp}/as_built.yaml", "--refresh-rounds", "-1"], "--refresh-rounds"),
        (["-o", "{tmp}/as_built.yaml", "--candidates", "0"], "--candidates"),
    ],
)
def test_calibrate_refuses_bad_options_in_one_line(tmp_path, capsys, monkeypatch, extra, expected):
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"")
    chart = tmp_path / "chart.json"
    args = ["calibrate", str(photo), "--chart", str(chart), "--lens", "phone_wide", "--sensor", "phone"]
    code, out, err = run_cli([*args, *[a.format(tmp=tmp_path) for a in extra]], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "as_built.yaml").exists()


def test_calibrate_names_a_missing_chart(tmp_path, capsys, monkeypatch):
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"")
    args = ["calibrate", str(photo), "--chart", str(tmp_path / "nope.json"), "-o", str(tmp_path / "a.yaml")]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and "nope.json" in err and err.count("\n") == 1
