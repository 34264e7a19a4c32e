"""Sensor profiles: built-ins, validation (one-line errors naming file and field),
white-balance interpolation in mired, random draws, and the derivation of the built-in
colour numbers from their stated sources."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from lensim.errors import InputError
from lensim.sensor import load_sensor, sensor_from_dict, sensor_names
from lensim.sensor.profile import DEFAULT_SENSOR, SENSOR_DIR


def _builtin_dict(name: str = "fullframe_dslr") -> dict:
    return yaml.safe_load((SENSOR_DIR / f"{name}.yaml").read_text())


def test_builtins_load_with_stated_geometry_and_sources():
    assert {"fullframe_dslr", "phone"} <= set(sensor_names())
    assert load_sensor().name == load_sensor(DEFAULT_SENSOR).name
    ff = load_sensor("fullframe_dslr")
    w, h = ff.sensor_size_mm
    assert abs(w - 35.82) < 1e-9 and abs(h - 23.88) < 1e-9  # 6000 x 4000 at 5.97 um
    ph = load_sensor("phone")
    assert ph.sensor_size_mm == pytest.approx((3.6736, 2.75968), abs=1e-9)  # Sony IMX219: 3280 x 2464 at 1.12 um
    for p in (ff, ph):
        assert p.bayer_pattern in ("RGGB", "BGGR", "GRBG", "GBRG")
        assert np.allclose(np.sum(p.ccm, axis=1), 1.0, atol=1e-5)
        assert "Brooks" in p.source and "dcraw" in p.source and "NPL" in p.source
        assert p.white_level < 2**p.bit_depth and p.black_level < p.white_level


def test_builtin_colour_numbers_reproduce_from_their_sources():
    """The CCMs and white-balance tables in the YAML files are what
    lensim.sensor.calibration computes from the DNG matrices and NPL sensitivities."""
    pytest.importorskip("colour")
    from lensim.sensor.calibration import ccm_from_dng_color_matrix, wb_table

    dng = {
        "fullframe_dslr": [5271, -712, -347, -6153, 13653, 2763, -1601, 2366, 7242],  # Sony ILCE-7
        "apsc_mirrorless": [5271, -712, -347, -6153, 13653, 2763, -1601, 2366, 7242],  # ILCE-7 colour, stated
        "phone": [6596, -2079, -562, -4782, 13016, 1933, -970, 1581, 5181],
    }  # Sony DSC-RX100M
    for name, m in dng.items():
        p = load_sensor(name)
        xyz2cam = np.array(m) / 10000.0
        ccm, r65, b65 = ccm_from_dng_color_matrix(xyz2cam)
        assert np.abs(ccm - np.array(p.ccm)).max() < 1e-6  # stored with 6 decimals
        table = wb_table([q.kelvin for q in p.white_balance], xyz2cam)
        got = np.array([[q.r_gain, q.b_gain] for q in p.white_balance])
        want = np.array([[e["r_gain"], e["b_gain"]] for e in table])
        assert np.abs(got - want).max() < 1e-4  # stored with 4 decimals
        assert p.wb_gains(6504.0) == pytest.approx((r65, b65), abs=1e-4)


def test_wb_interpolates_linearly_in_mired_and_clamps():
    d = _builtin_dict()
    d["white_balance"] = [
        {"kelvin": 2500, "r_gain": 1.0, "b_gain": 3.0},
        {"kelvin": 10000, "r_gain": 3.0, "b_gain": 1.0},
    ]
    d.pop("kelvin_range")
    p = sensor_from_dict(d, "mem.yaml")
    # 4000 K = 250 mired, halfway between 400 and 100 mired (a linear-in-kelvin rule gives 1.4, 2.6)
    assert p.wb_gains(4000.0) == pytest.approx((2.0, 2.0), abs=1e-12)
    assert p.wb_gains(2500.0) == pytest.approx((1.0, 3.0), abs=1e-12)
    assert p.wb_gains(5000.0) == pytest.approx(
        (1.0 + 2.0 * (400 - 200) / 300, 3.0 - 2.0 * (400 - 200) / 300), abs=1e-12
    )
    assert p.wb_gains(1000.0) == pytest.approx((1.0, 3.0))  # held at the ends
    assert p.wb_gains(50000.0) == pytest.approx((3.0, 1.0))
    assert p.kelvin_range == (2500.0, 10000.0)
    ff = load_sensor("fullframe_dslr")
    for q in ff.white_balance:  # table entries are returned exactly
        assert ff.wb_gains(q.kelvin) == pytest.approx((q.r_gain, q.b_gain), abs=1e-12)
    with pytest.raises(InputError):
        ff.wb_gains(-5.0)


def test_kelvin_draws_are_seeded_in_range_and_uniform_in_mired():
    p = load_sensor("fullframe_dslr")
    a = [p.sample_kelvin(torch.Generator().manual_seed(7)) for _ in range(2)]
    assert a[0] == a[1]
    g = torch.Generator().manual_seed(0)
    ks = np.array([p.sample_kelvin(g) for _ in range(4000)])
    lo, hi = p.kelvin_range
    assert ks.min() >= lo - 1e-9 and ks.max() <= hi + 1e-9
    mired = 1e6 / ks
    m_lo, m_hi = 1e6 / hi, 1e6 / lo
    mean, sd = 0.5 * (m_lo + m_hi), (m_hi - m_lo) / math.sqrt(12 * len(ks))
    assert abs(mired.mean() - mean) < 4 * sd  # uniform in mired (4-sigma band)


def test_noise_draws_follow_brooks_relation_and_ranges():
    p = load_sensor("phone")  # shot log-uniform [1e-4, 1.2e-2], log(read^2) = 2.18 log(shot) + 1.20 + N(0, 0.26^2)
    g = torch.Generator().manual_seed(3)
    draws = np.array([p.sample_noise(g) for _ in range(4000)])
    shot, read = draws[:, 0], draws[:, 1]
    assert shot.min() >= 1e-4 and shot.max() <= 1.2e-2
    ls = np.log(shot)
    assert abs(ls.mean() - 0.5 * (math.log(1e-4) + math.log(1.2e-2))) < 0.1  # log-uniform mean (sd of mean 0.02)
    slope, intercept = np.polyfit(ls, np.log(read**2), 1)
    resid = np.log(read**2) - (slope * ls + intercept)
    assert abs(slope - 2.18) < 0.05 and abs(intercept - 1.20) < 0.25 and abs(resid.std() - 0.26) < 0.02
    d = _builtin_dict()
    d["noise"] = {"shot": 0.01, "read": [1e-3, 1e-2]}
    q = sensor_from_dict(d, "mem.yaml")
    dr = np.array([q.sample_noise(g) for _ in range(500)])
    assert np.all(dr[:, 0] == 0.01) and dr[:, 1].min() >= 1e-3 and dr[:, 1].max() <= 1e-2


def test_to_dict_round_trip_and_json_file(tmp_path: Path):
    p = load_sensor("phone")
    f = tmp_path / "cam.json"
    f.write_text(json.dumps(p.to_dict()))
    q = load_sensor(f)
    assert q == p and q.path == str(f)


# ----------------------------------------------------------------- validation errors


def _set(path: str, value):
    def mutate(d: dict) -> None:
        keys = path.split(".")
        obj = d
        for k in keys[:-1]:
            obj = obj[int(k)] if isinstance(obj, list) else obj[k]
        last = keys[-1]
        if isinstance(obj, list):
            obj[int(last)] = value
        elif value is _DELETE:
            del obj[last]
        else:
            obj[last] = value

    return mutate


_DELETE = object()

BAD = [
    ("unknown top-level key", _set("pixel_pitch", 4.0), "pixel_pitch", "unknown key"),
    ("missing field", _set("name", _DELETE), "name", "missing"),
    ("negative pitch", _set("pixel_pitch_um", -1.0), "pixel_pitch_um", "positive"),
    ("pitch as text", _set("pixel_pitch_um", "six"), "pixel_pitch_um", "number"),
    ("odd resolution", _set("resolution", [6001, 4000]), "resolution", "even"),
    ("resolution shape", _set("resolution", [6000]), "resolution", "[width, height]"),
    ("bayer pattern", _set("bayer_pattern", "RGBG"), "bayer_pattern", "RGGB"),
    ("ccm shape", _set("ccm", [[1, 0], [0, 1]]), "ccm", "3x3"),
    ("ccm row sum", _set("ccm.1", [0.0, 1.2, 0.0]), "ccm[1]", "sum to 1"),
    ("ccm singular", _set("ccm", [[1, 0, 0], [1, 0, 0], [0, 0, 1]]), "ccm", "invertible"),
    ("wb not increasing", _set("white_balance.1.kelvin", 2000), "white_balance[1].kelvin", "increasing"),
    (
        "wb unknown key",
        _set("white_balance.0", {"kelvin": 2500, "r_gain": 1.3, "g_gain": 1.0, "b_gain": 2.7}),
        "white_balance[0].g_gain",
        "unknown key",
    ),
    ("wb negative gain", _set("white_balance.2.r_gain", -1.0), "white_balance[2].r_gain", "positive"),
    ("wb empty", _set("white_balance", []), "white_balance", "non-empty"),
    ("kelvin range outside table", _set("kelvin_range", [2000, 7500]), "kelvin_range", "inside"),
    ("white above bit depth", _set("white_level", 20000), "white_level", "2**bit_depth"),
    ("white below black", _set("white_level", 100), "white_level", "black_level"),
    ("bit depth", _set("bit_depth", 20), "bit_depth", "[8, 16]"),
    ("bit depth nan", _set("bit_depth", float("nan")), "bit_depth", "integer"),
    ("noise read and read_from_shot", _set("noise.read", 0.001), "noise.read", "exactly one"),
    ("noise range order", _set("noise.shot", [0.01, 0.001]), "noise.shot", "min <= max"),
    ("noise unknown key", _set("noise.gain", 2.0), "noise.gain", "unknown key"),
    (
        "read_from_shot key missing",
        _set("noise.read_from_shot", {"slope": 2.18, "intercept": 1.2}),
        "noise.read_from_shot.sigma",
        "missing",
    ),
    ("spectral csv missing", _set("spectral_response", "nowhere.csv"), "spectral_response", "not found"),
]


@pytest.mark.parametrize("label,mutate,field,words", BAD, ids=[b[0] for b in BAD])
def test_bad_profiles_give_one_line_errors_naming_file_and_field(tmp_path: Path, label, mutate, field, words):
    d = copy.deepcopy(_builtin_dict())
    mutate(d)
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError) as ei:
        load_sensor(f)
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith(f"{f}: {field}: "), msg
    assert words in msg, msg
    assert ei.value.field == field and ei.value.source == str(f)


def test_syntax_errors_unknown_names_and_csv_response(tmp_path: Path):
    f = tmp_path / "broken.yaml"
    f.write_text("name: [unclosed\n")
    with pytest.raises(InputError, match=r"broken.yaml: syntax: not valid YAML"):
        load_sensor(f)
    with pytest.raises(InputError, match=r"not a built-in sensor \(built-ins: apsc_mirrorless, fullframe_dslr, phone"):
        load_sensor("no_such_sensor")
    # a CSV response is resolved relative to the profile's folder and checked
    (tmp_path / "resp.csv").write_text("wavelength_nm,r,g,b\n400,0.1,0.2,0.9\n700,0.9,0.1,0.0\n")
    d = _builtin_dict()
    d["spectral_response"] = "resp.csv"
    ok = tmp_path / "ok.yaml"
    ok.write_text(yaml.safe_dump(d))
    assert load_sensor(ok).spectral_response == str(tmp_path / "resp.csv")
    (tmp_path / "resp.csv").write_text("wavelength_nm,r,g,b\n400,0.1,x,0.9\n700,0.9,0.1,0.0\n")
    with pytest.raises(InputError, match=r"resp.csv: line 2, column g"):
        load_sensor(ok)


def test_shipped_camera_tables_are_colour_sciences():
    # a bank reads the camera sensitivities from lensim's copy (no colour-science import):
    # the same numbers, names and version line as the installed colour-science
    import colour

    from lensim.sensor.spectral import CAMERA_TABLES, _camera_table

    shipped = json.loads(CAMERA_TABLES.read_text())
    assert sorted(shipped["cameras"]) == sorted(colour.MSDS_CAMERA_SENSITIVITIES.keys())
    for name, msds in colour.MSDS_CAMERA_SENSITIVITIES.items():
        wl, table, source = _camera_table(name)
        labels = [str(x).lower() for x in msds.labels]
        values = np.asarray(msds.values, dtype=np.float64)[:, [labels.index(c) for c in ("red", "green", "blue")]]
        assert np.array_equal(wl, np.asarray(msds.wavelengths, dtype=np.float64))
        assert np.array_equal(table, values.T)
        assert source.startswith(f"colour-science {shipped['colour_version']} MSDS_CAMERA_SENSITIVITIES[{name!r}]")
