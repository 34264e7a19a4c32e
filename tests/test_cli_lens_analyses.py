"""`lensim lens mtf / wavefront / fans / field-curves / energy`: each writes its figure and
prints the JSON scripts rely on, at small sizes (the physics is in test_analyses.py and
test_analyses_peers.py; bad options in test_hostile_options.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from cli_runner import run_cli


def _run(args: list[str], capsys, monkeypatch) -> dict:
    code, out, err = run_cli(args, capsys, monkeypatch)
    assert code == 0, err
    return json.loads(out)


def _png(path: Path) -> None:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_mtf_json_and_figure(tmp_path: Path, capsys, monkeypatch) -> None:
    out = tmp_path / "mtf.png"
    args = ["lens", "mtf", "cooke_triplet", "--json", "-o", str(out), "--pupil-samples", "32", "--aiming", "paraxial"]
    args += ["--field", "0", "--field", "1", "--focus-steps", "3", "--frequency", "20", "--frequency", "40"]
    args += ["--sweep-fields", "5"]
    report = _run(args, capsys, monkeypatch)
    _png(out)
    assert [f["field"] for f in report["fields"]] == [0.0, 20.0]
    for f in report["fields"]:
        assert len(f["frequency_lp_mm"]) == len(f["sagittal"]) == len(f["tangential"]) == 51
        assert f["sagittal"][0] == pytest.approx(1.0) and f["tangential"][0] == pytest.approx(1.0)
        assert f["frequency_lp_mm"][-1] == pytest.approx(max(g["cutoff_lp_mm"] for g in report["fields"]))
    on_axis = report["fields"][0]
    assert on_axis["sagittal"] == pytest.approx(on_axis["tangential"], abs=1e-9)
    sweep = report["against_field"]
    assert sweep["frequency_lp_mm"] == [20.0, 40.0] and sweep["fields"] == [0.0, 5.0, 10.0, 15.0, 20.0]
    assert len(sweep["sagittal"]) == 2 and len(sweep["sagittal"][0]) == 5
    tf = report["through_focus"]
    assert len(tf["focus_shift_mm"]) == 3 and tf["focus_shift_mm"][1] == pytest.approx(0.0, abs=1e-12)
    assert (
        len(tf["fields"]) == 2
        and len(tf["fields"][0]["tangential"]) == 2
        and len(tf["fields"][0]["tangential"][0]) == 3
    )
    # the through-focus curve at zero shift is the MTF against field's point at the same field
    assert tf["fields"][1]["tangential"][0][1] == pytest.approx(sweep["tangential"][0][-1], abs=1e-9)
    assert report["weighting"] == "lens file" and report["wavelengths_nm"] == [480.0, 550.0, 650.0]


def test_mtf_with_a_sensor(capsys, monkeypatch) -> None:
    """--sensor: its spectral response weights 400-700 nm, its Nyquist frequency sets the
    frequencies (Nyquist/4, /2) and the top of the axis."""
    args = ["lens", "mtf", "cooke_triplet", "--json", "--sensor", "apsc_mirrorless", "--channel", "g"]
    args += ["--pupil-samples", "32", "--field", "0.5", "--focus-steps", "0", "--wavelengths-nm", "450:650:50"]
    args += ["--aiming", "paraxial", "--sweep-fields", "3"]
    report = _run(args, capsys, monkeypatch)
    nyquist = report["nyquist_lp_mm"]
    assert report["against_field"]["frequency_lp_mm"] == pytest.approx([nyquist / 4, nyquist / 2])
    assert report["fields"][0]["frequency_lp_mm"][-1] == pytest.approx(nyquist)
    assert report["wavelengths_nm"] == [450.0, 500.0, 550.0, 600.0, 650.0]
    weights = report["wavelength_weights"]
    assert sum(weights) == pytest.approx(1.0) and weights.index(max(weights)) == 2  # green peaks at 550
    assert "through_focus" not in report and report["weighting"].startswith("sensor apsc_mirrorless")


@pytest.mark.parametrize("convention, terms", [("noll", 22), ("fringe", 37)])
def test_wavefront_json(convention: str, terms: int, tmp_path: Path, capsys, monkeypatch) -> None:
    out = tmp_path / "wf.png"
    args = ["lens", "wavefront", "cooke_triplet", "--field", "0.7", "--json", "-o", str(out)]
    args += ["--zernike", convention, "--zernike-terms", str(terms), "--pupil-samples", "32"]
    report = _run(args, capsys, monkeypatch)
    _png(out)
    for key in ("rms_waves", "pv_waves", "strehl"):
        assert math.isfinite(report[key]) and report[key] > 0
    assert report["strehl"] <= 1.0 and report["pv_waves"] > report["rms_waves"]
    z = report["zernike"]
    assert z["convention"] == convention and convention.capitalize() in z["convention_name"]
    assert len(z["coefficients_waves"]) == len(z["terms"]) == terms
    assert z["terms"][3]["name"] == "defocus" and z["terms"][3]["waves"] == z["coefficients_waves"][3]
    assert report["field"] == pytest.approx(14.0) and report["wavelength_nm"] == 550.0


def test_fans_and_field_curves_json(tmp_path: Path, capsys, monkeypatch) -> None:
    fans = _run(
        ["lens", "fans", "cooke_triplet", "--json", "--rays", "11", "-o", str(tmp_path / "f.png")], capsys, monkeypatch
    )
    _png(tmp_path / "f.png")
    assert len(fans["pupil"]) == 11 and [f["field"] for f in fans["fields"]] == [0.0, 14.0, 20.0]
    assert len(fans["fields"][1]["tangential_ey_um"]) == 3 and len(fans["fields"][1]["sagittal_ex_um"][0]) == 11
    assert fans["fields"][0]["tangential_ey_um"][1][5] == pytest.approx(0.0, abs=1e-9)  # the primary chief ray
    curves = _run(["lens", "field-curves", "cooke_triplet", "--json"], capsys, monkeypatch)
    assert len(curves["fields"]) == 21
    w = curves["wavelengths"][1]
    assert w["wavelength_nm"] == 550.0 and len(w["tangential_mm"]) == len(w["sagittal_mm"]) == 21
    assert w["astigmatism_mm"][0] == pytest.approx(0.0, abs=1e-9)


def test_energy_json(tmp_path: Path, capsys, monkeypatch) -> None:
    out = tmp_path / "ee.png"
    args = ["lens", "energy", "cooke_triplet", "--json", "-o", str(out), "--field", "0", "--grid", "64"]
    args += ["--method", "fft", "--wavelengths-nm", "550"]
    report = _run(args, capsys, monkeypatch)
    _png(out)
    f = report["fields"][0]
    assert len(f["radius_um"]) == len(f["encircled"]) == len(f["ensquared"]) == 101
    assert f["encircled"][0] == 0.0 and 0.9 < f["encircled"][-1] <= 1.0 + 1e-9
    assert 0.0 < f["ee50_radius_um"] < f["ee80_radius_um"]
    assert f["ensquared50_half_width_um"] <= f["ee50_radius_um"]
