"""Three messages that blamed the wrong thing (issue 28): each now names the file, the
field and what was expected, and the failed command leaves nothing behind."""

from __future__ import annotations

from pathlib import Path

import pytest

from cli_runner import run_cli
from faults import one_line_error
from test_negative_thickness import _zmx

BANK = ["--fields", "2", "--wavelengths-nm", "550", "--pupil-samples", "32", "--quiet"]


def _refused(args: list[str], capsys, monkeypatch, *expect: str) -> str:
    code, _, err = run_cli(args, capsys, monkeypatch)
    line = one_line_error(err)
    assert code == 2, err
    for text in expect:
        assert text in line, f"{text!r} not in {line!r}"
    return line


@pytest.mark.parametrize("where", ["before the stop", "inside the lens", "to the image"])
def test_an_absurd_thickness_names_the_surface_not_the_field(tmp_path, capsys, monkeypatch, where):
    text = _zmx(0.3, 0.3)
    old = {"before the stop": "  DISZ 0.3\nSURF 2", "inside the lens": "  DISZ 3.25896", "to the image": "  DISZ 50"}[
        where
    ]
    path = tmp_path / "absurd.zmx"
    path.write_text(text.replace(old, old.replace(old.split()[1], "1e9", 1), 1))
    for args in (
        ["lens", "info", str(path)],
        ["psf", "bank", str(path), "--pixel-um", "4", "-o", str(tmp_path / "b"), *BANK],
    ):
        line = _refused(args, capsys, monkeypatch, str(path), "thickness", "1e+09")
        assert "field" not in line.split("thickness")[0], line
    assert not (tmp_path / "b").exists()


def test_a_stop_with_a_tiny_clear_aperture_names_the_file_and_the_stop(tmp_path, capsys, monkeypatch):
    path = tmp_path / "tiny_stop.zmx"
    path.write_text(_zmx(0.3, 0.3).replace("  STOP\n  TYPE STANDARD\n", "  STOP\n  TYPE STANDARD\n  CLAP 0 0.0001 0\n"))
    out = tmp_path / "b"
    line = _refused(
        ["psf", "bank", str(path), "--pixel-um", "4", "-o", str(out), *BANK], capsys, monkeypatch, str(path), "stop"
    )
    assert "pupil sampling too coarse" not in line, line
    assert "0.0001" in line, line
    assert not out.exists()


@pytest.mark.parametrize("how", ["--pixel-um", "sensor file"])
def test_a_sensor_pitch_of_a_millionth_of_a_micrometre_names_the_pitch(tmp_path, capsys, monkeypatch, how):
    out = tmp_path / "bank"
    if how == "--pixel-um":
        args, names = ["--pixel-um", "1e-6"], ("--pixel-um", "1e-06")
    else:
        sensor = Path(__file__).resolve().parents[1] / "lensim" / "assets" / "sensors" / "apsc_mirrorless.yaml"
        bad = tmp_path / "sensor.yaml"
        bad.write_text(sensor.read_text().replace("pixel_pitch_um: 3.92", "pixel_pitch_um: 1.0e-6"))
        args, names = ["--sensor", str(bad)], (str(bad), "pixel_pitch_um")
    line = _refused(["psf", "bank", "cooke_triplet", *args, "-o", str(out), *BANK], capsys, monkeypatch, *names)
    assert "window" not in line, line
    assert not out.exists(), sorted(p.name for p in out.iterdir())
