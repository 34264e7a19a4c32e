"""`lensim sensor from-raw`: a profile for the camera that wrote a raw file.

Truths: the built-in apsc_mirrorless profile's colour was derived from the Sony ILCE-7
DNG matrix (tests/test_sensor.py), so a DNG carrying that matrix must give the same CCM
and white-balance table; noise frames drawn with known shot and read noise must give
them back."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from cli_runner import run_cli
from lensim.sensor import load_sensor
from raw_fixtures import random_mosaic, write_dng

BLACK, WHITE = 512, 16383


def _frame(path, level: float, shot: float, read: float, seed: int, size: int = 128):
    """A flat (level > 0) or dark (level 0) frame with the profile noise model's draws."""
    rng = np.random.default_rng(seed)
    x = level + np.sqrt(shot * level + read**2) * rng.standard_normal((size, size))
    dn = np.clip(np.round(BLACK + x * (WHITE - BLACK)), 0, WHITE).astype(np.uint16)
    return write_dng(path, dn, black=(BLACK,) * 4, white=WHITE)


def test_profile_from_a_dng_matches_the_builtin_made_from_the_same_matrix(tmp_path, capsys, monkeypatch):
    pytest.importorskip("colour")
    raw = write_dng(
        tmp_path / "cam.dng",
        random_mosaic(hi=WHITE),
        pattern="GRBG",
        black=(510, 512, 514, 516),
        white=WHITE,
        exif={"pixel_um": 3.92},
    )
    out = tmp_path / "mycam.yaml"
    code, _, err = run_cli(["sensor", "from-raw", str(raw), "-o", str(out)], capsys, monkeypatch)
    assert code == 0, err
    mine, ref = load_sensor(out), load_sensor("apsc_mirrorless")
    assert mine.pixel_pitch_um == pytest.approx(3.92, rel=1e-9)  # from EXIF FocalPlaneXResolution
    assert (mine.resolution, mine.bayer_pattern, mine.white_level, mine.bit_depth) == ((96, 64), "GRBG", WHITE, 14)
    assert mine.black_level == pytest.approx(513.0)
    assert np.abs(np.array(mine.ccm) - np.array(ref.ccm)).max() < 1e-6  # built-in stored with 6 decimals
    got = np.array([[p.kelvin, p.r_gain, p.b_gain] for p in mine.white_balance])
    want = np.array([[p.kelvin, p.r_gain, p.b_gain] for p in ref.white_balance])
    assert got.shape == want.shape and np.abs(got - want).max() < 1e-4
    # --pixel-um overrides the EXIF pitch; the profile works with other commands' --sensor
    code, _, err = run_cli(
        ["sensor", "from-raw", str(raw), "--pixel-um", "5", "-o", str(tmp_path / "b.json")], capsys, monkeypatch
    )
    assert code == 0 and json.loads((tmp_path / "b.json").read_text())["pixel_pitch_um"] == 5.0
    code, _, err = run_cli(
        ["develop", str(raw), "-o", str(tmp_path / "dev"), "--sensor", str(out), "--quiet"], capsys, monkeypatch
    )
    assert code == 0 and (tmp_path / "dev" / "cam.tif").is_file(), err


def test_no_pixel_pitch_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    raw = write_dng(tmp_path / "cam.dng", random_mosaic(hi=WHITE), white=WHITE)
    out = tmp_path / "mycam.yaml"
    code, _, err = run_cli(["sensor", "from-raw", str(raw), "-o", str(out)], capsys, monkeypatch)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "--pixel-um" in lines[0] and str(raw) in lines[0], err
    assert not out.exists() and list(tmp_path.iterdir()) == [raw]


def test_noise_from_dark_and_flat_frames(tmp_path, capsys, monkeypatch):
    pytest.importorskip("colour")
    shot, read = 2.0e-3, 3.0e-3
    raw = write_dng(tmp_path / "cam.dng", random_mosaic(128, 128, hi=WHITE), black=(BLACK,) * 4, white=WHITE)
    dark = _frame(tmp_path / "dark.dng", 0.0, shot, read, 1)
    flats = [_frame(tmp_path / f"flat{k}.dng", level, shot, read, 2 + k) for k, level in enumerate((0.02, 0.08))]
    for args in (["--dark", str(dark), "--flat", str(flats[0])], ["--flat", str(flats[0]), "--flat", str(flats[1])]):
        out = tmp_path / "n.yaml"
        code, _, err = run_cli(
            ["sensor", "from-raw", str(raw), "--pixel-um", "4", "-o", str(out), *args], capsys, monkeypatch
        )
        assert code == 0, err
        noise = yaml.safe_load(out.read_text())["noise"]
        assert noise["shot"] == pytest.approx(shot, rel=0.05), args
        assert noise["read"] == pytest.approx(read, rel=0.1 if "--dark" in args else 0.3), args
        assert load_sensor(out).noise.read == (noise["read"], noise["read"])
