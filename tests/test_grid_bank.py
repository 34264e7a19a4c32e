"""Banks over a grid of shooting settings (lensim.psf.bank.grid): one bank per setting
under one manifest, each the very bank of that one setting; resume; refusals; the lists
on the command line; nearest and interpolated settings."""

from __future__ import annotations

import json
import math
import shutil
import warnings

import numpy as np
import pytest

from lensim.errors import InputError
from lensim.optics.lens_file import load_lens
from lensim.optics.shooting import ShootingSettings, lens_at
from lensim.psf.bank import BankSettings, PSFBank, get_bank
from lensim.psf.bank.grid import GridAxes, GridBank, parse_setting_list

PITCH = 4.0
SETTINGS = BankSettings(fields=3, wavelengths_nm=(500.0, 600.0), pupil_samples=32, kernel_pixels=15)
AXES = GridAxes(fno=(5.6, 8.0), focus_m=(math.inf, 1.0))


@pytest.fixture(scope="module")
def lens():
    return load_lens("cooke_triplet")


@pytest.fixture(scope="module")
def grid_dir(lens, tmp_path_factory):
    d = tmp_path_factory.mktemp("grid") / "g"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        get_bank(lens, PITCH, SETTINGS, shooting=AXES, out_dir=d)
    return d


def _same_fields(a: PSFBank, b: PSFBank) -> None:
    assert len(a.fields) == len(b.fields)
    for fa, fb in zip(a.fields, b.fields, strict=True):
        assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.reference_xy_mm, fb.reference_xy_mm)


def test_parse_setting_lists():
    assert parse_setting_list("1.4, 2,2.8", "fno") == (1.4, 2.0, 2.8)
    assert parse_setting_list("inf,3,1", "focus_m") == (math.inf, 3.0, 1.0)
    assert parse_setting_list("wide,tele", "config") == ("wide", "tele")
    assert parse_setting_list(None, "fno") is None
    for text, needle in (
        ("2,,3", "empty"),
        ("0", "positive"),
        ("2,2.0", "twice"),
        ("nan", "positive"),
        ("", "empty"),
        ("2,x", "number"),
    ):
        with pytest.raises(InputError, match=needle) as e:
            parse_setting_list(text, "fno")
        assert e.value.field == "fno" and "\n" not in str(e.value)
    with pytest.raises(InputError, match="twice"):
        parse_setting_list("inf,INF", "focus_m")
    with pytest.raises(InputError, match="^object_m: "):
        parse_setting_list("1,-3", "object_m")


def test_axes_product_order():
    shots = GridAxes(fno=(2.0, 4.0), focus_m=(math.inf, 1.0), config=("a",)).settings()
    assert [(s.config, s.fno, s.focus_m) for s in shots] == [
        ("a", 2.0, math.inf),
        ("a", 2.0, 1.0),
        ("a", 4.0, math.inf),
        ("a", 4.0, 1.0),
    ]
    assert GridAxes(fno=(2.0,)).given and not GridAxes(fno=(2.0,)).is_grid and not GridAxes().given


def test_grid_manifest_and_banks(grid_dir, lens):
    m = json.loads((grid_dir / "manifest.json").read_text())
    assert m["format"] == "lensim-psf-grid" and m["axes"]["fno"] == [5.6, 8.0] and m["axes"]["focus_m"] == ["inf", 1.0]
    assert m["axes"]["object_m"] is None and m["bank"]["kernel_pixels"] == 15 and len(m["settings"]) == 4
    assert [e["bank"] for e in m["settings"]] == ["s000", "s001", "s002", "s003"]
    grid = GridBank.load(grid_dir)
    assert grid.settings[1] == ShootingSettings(fno=5.6, focus_m=1.0)
    r = grid.resolved[1]
    assert r["fno"] == pytest.approx(5.6, rel=1e-9) and r["focus_m"] == 1.0 and r["object_m"] == 1.0
    assert grid.resolved[0]["focus_m"] == math.inf and r["working_fno"] > r["fno"]  # a near object: slower beam
    for i in range(4):
        b = grid.bank(i)
        assert b.manifest["shooting"]["request"] == grid.settings[i].to_dict()
        # the on-axis beam of each bank has the F-number asked for (paraxial N_w = N at infinity; the
        # real beam of the Cooke triplet is 1 % slower)
        if math.isinf(grid.settings[i].focus_m):
            assert b.fields[0].working_fno == pytest.approx(grid.settings[i].fno, rel=0.02)


def test_each_grid_bank_is_the_bank_of_its_setting(grid_dir, lens, tmp_path):
    grid = GridBank.load(grid_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = get_bank(lens, PITCH, SETTINGS, shooting=grid.settings[3], out_dir=tmp_path / "one")
        direct = get_bank(lens_at(lens, grid.settings[3]), PITCH, SETTINGS, memory_only=True)
    _same_fields(grid.bank(3), one)
    _same_fields(grid.bank(3), direct)
    for name in ("field_0000.npz", "field_0002.npz"):
        assert (tmp_path / "one" / name).read_bytes() == (grid_dir / "s003" / name).read_bytes()


def test_grid_resumes_only_missing_fields_and_refuses_other_settings(grid_dir, lens, tmp_path):
    d = tmp_path / "g"
    shutil.copytree(grid_dir, d)
    (d / "s001" / "field_0002.npz").unlink()
    (d / "s003" / "field_0000.npz").write_bytes(b"truncated")
    calls = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        get_bank(lens, PITCH, SETTINGS, shooting=AXES, out_dir=d, progress=lambda k, n: calls.append((k, n)))
    assert calls[0] == (10, 12) and calls[-1] == (12, 12)
    for i in range(4):
        _same_fields(GridBank.load(d).bank(i), GridBank.load(grid_dir).bank(i))
    with pytest.raises(InputError, match="different settings"):
        get_bank(lens, PITCH, SETTINGS, shooting=GridAxes(fno=(5.6, 11.0), focus_m=(math.inf, 1.0)), out_dir=d)
    with pytest.raises(InputError, match="single PSF bank"):
        get_bank(lens, PITCH, SETTINGS, shooting=AXES, out_dir=grid_dir / "s000")


def test_a_grid_is_not_a_bank(grid_dir):
    with pytest.raises(InputError, match="grid of 4 banks"):
        PSFBank.load(grid_dir)
    with pytest.raises(InputError, match="not a grid"):
        GridBank.load(grid_dir / "s000")


def test_nearest_and_interpolated(grid_dir):
    grid = GridBank.load(grid_dir)
    assert grid.nearest(fno=7.5, focus_m=1.1) == 3 and grid.nearest(fno=5.0, focus_m=100.0) == 0
    at = grid.interpolated(fno=8.0, focus_m=1.0)  # a grid point: that bank itself
    _same_fields(at, grid.bank(3))
    # halfway in stops between F/5.6 and F/8, halfway in dioptres between inf and 1 m (2 m)
    mid = grid.interpolated(fno=math.sqrt(5.6 * 8.0), focus_m=2.0)
    want = sum(0.25 * grid.bank(i).fields[1].rgb.astype(np.float64) for i in range(4))
    np.testing.assert_allclose(mid.fields[1].rgb, want, rtol=1e-6, atol=1e-9)
    assert [round(f["weight"], 9) for f in mid.manifest["interpolated"]["from"]] == [0.25] * 4
    edge = grid.interpolated(fno=8.0, focus_m=4.0)  # on the F/8 edge: two banks, 3/4 at infinity
    np.testing.assert_allclose(
        edge.fields[2].rgb,
        0.75 * grid.bank(2).fields[2].rgb.astype(np.float64) + 0.25 * grid.bank(3).fields[2].rgb,
        rtol=1e-6,
        atol=1e-9,
    )
    for bad, needle in (
        (dict(fno=4.0, focus_m=2.0), "outside the grid"),
        (dict(fno=6.0, focus_m=0.5), "outside"),
        (dict(focus_m=2.0), "expected a value"),
        (dict(fno=6.0, focus_m=2.0, object_m=2.0), "does not vary"),
    ):
        with pytest.raises(InputError, match=needle):
            grid.interpolated(**bad)


def test_f_numbers_blended_across_more_than_a_stop_warn(grid_dir):
    from lensim.psf.bank.grid_interp import GridInterpolationWarning, _bracket, coordinate

    assert coordinate("fno", 8.0) - coordinate("fno", 4.0) == pytest.approx(2.0)  # two stops
    assert coordinate("focus_m", math.inf) == 0.0 and coordinate("focus_m", 4.0) == 0.25
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        GridBank.load(grid_dir).interpolated(fno=6.7, focus_m=3.0)  # F/5.6 to F/8: one stop, no warning
        assert _bracket("focus_m", [math.inf, 1.0], 3.0, "g") == [
            (math.inf, pytest.approx(2 / 3)),
            (1.0, pytest.approx(1 / 3)),
        ]
    with pytest.warns(GridInterpolationWarning, match="1.9 stops apart"):
        assert [v for v, _ in _bracket("fno", [5.6, 11.0], 8.0, "g")] == [5.6, 11.0]


def test_command_line_grid_json_and_show(grid_dir, tmp_path, capsys, monkeypatch):
    from cli_runner import run_cli

    out = tmp_path / "g"
    code, text, err = run_cli(
        [
            "psf",
            "bank",
            "cooke_triplet",
            "--pixel-um",
            "4",
            "--kernel",
            "15",
            "--fields",
            "2",
            "--wavelengths-nm",
            "550",
            "--pupil-samples",
            "32",
            "--fno",
            "8,5.6",
            "-o",
            str(out),
            "--json",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    info = json.loads(text)
    assert info["settings"] == 2 and [e["request"]["fno"] for e in info["grid"]] == [8.0, 5.6]
    assert [p.name for p in sorted(out.iterdir()) if p.is_dir()] == ["s000", "s001"]
    code, text, err = run_cli(
        ["psf", "show", str(grid_dir), "-o", str(tmp_path / "one"), "--setting", "3"], capsys, monkeypatch
    )
    assert code == 0 and "F/8, focus 1 m" in text and (tmp_path / "one" / "psf_map.png").is_file()
    code, text, err = run_cli(["psf", "show", str(out), "-o", str(tmp_path / "all")], capsys, monkeypatch)
    assert code == 0 and all((tmp_path / "all" / s / "strehl.png").is_file() for s in ("s000", "s001"))
    import torch

    from lensim.images import write_image

    write_image(tmp_path / "x.png", torch.rand(3, 32, 48), 8)
    code, _, err = run_cli(
        ["simulate", str(tmp_path / "x.png"), "--bank", str(out), "-o", str(tmp_path / "s")], capsys, monkeypatch
    )
    assert code == 2 and err.count("\n") == 1 and "grid of 2 banks" in err, err
