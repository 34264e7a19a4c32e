"""Training-pair generation: determinism, resume, refusal of changed settings, dask."""

import numpy as np
import pytest
import torch

from lensim.assets.images import sample_image_path
from lensim.data.pairs import crop_capture, make_dataset, place_on_sensor
from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, get_bank
from lensim.sensor.profile import load_sensor

SENSOR = "apsc_mirrorless"


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    base = tmp_path_factory.mktemp("pairs")
    sharp = base / "sharp"
    for name in ("kodim23", "coffee"):
        img, _ = read_image(sample_image_path(name))
        write_image(sharp / f"{name}.png", img[:, :192, :256])
    sensor = load_sensor(SENSOR)
    settings = BankSettings(fields=(0.0, 0.5, 0.8, 1.0), wavelengths_nm=(500, 600), pupil_samples=96, kernel_pixels=21)
    bank = get_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, settings, out_dir=base / "bank")
    return base, sharp, sensor, bank


def _run(setup, out, **kw):
    base, sharp, sensor, bank = setup
    calls = []
    m = make_dataset(
        sharp,
        base / out,
        bank,
        SENSOR,
        sensor,
        crops=2,
        size=64,
        seed=3,
        progress=lambda d, t: calls.append((d, t)),
        **kw,
    )
    return m, calls


def test_pairs_are_written_with_positions_and_draws(setup):
    m, calls = _run(setup, "a")
    assert m["pairs"] == 4 and calls[0] == (0, 2) and calls[-1] == (2, 2)
    sensor = setup[2]
    for rec in m["records"]:
        capture = rec["placements"][0]["capture"]
        assert capture["kelvin"] > 0 and capture["shot"] is not None
        for c in rec["crops"]:
            assert crop_capture(rec, c) == capture
            assert 0 <= c["sensor_top"] <= sensor.height - 64 and 0 <= c["sensor_left"] <= sensor.width - 64
            x, _ = read_image(setup[0] / "a" / c["input"])
            y, _ = read_image(setup[0] / "a" / c["target"])
            assert x.shape == y.shape == (3, 64, 64)
            assert (x - y).abs().mean() > 1e-3  # the camera changed the image
            assert (x - y).abs().mean() < 0.2  # but it is the same scene, aligned


def test_deterministic_given_the_seed(setup):
    a, _ = _run(setup, "a")
    b, _ = _run(setup, "b")
    assert [r["crops"] for r in a["records"]] == [r["crops"] for r in b["records"]]
    for ra, rb in zip(a["records"], b["records"]):
        for ca, cb in zip(ra["crops"], rb["crops"]):
            assert (setup[0] / "a" / ca["input"]).read_bytes() == (setup[0] / "b" / cb["input"]).read_bytes()


def test_resume_recomputes_only_unfinished_images(setup):
    _run(setup, "r")
    rec = setup[0] / "r" / "records" / "000001.json"
    rec.unlink()
    m, calls = _run(setup, "r")
    assert calls[0] == (1, 2) and calls[-1] == (2, 2)
    assert m["pairs"] == 4


def test_a_corrupt_record_is_recomputed_and_a_corrupt_settings_file_is_named(setup):
    first, _ = _run(setup, "k")
    rec = setup[0] / "k" / "records" / "000000.json"
    rec.write_text(rec.read_text()[:40])  # cut short by something other than lensim
    m, calls = _run(setup, "k")
    assert calls[0] == (1, 2) and m["records"] == first["records"]
    settings = setup[0] / "k" / "settings.json"
    settings.write_text('{"seed": 3, "cro')
    with pytest.raises(InputError, match=f"^{settings}: expected a pairs settings record in JSON"):
        _run(setup, "k")
    settings.write_text("[1, 2]")
    with pytest.raises(InputError, match=f"^{settings}: format: expected the 'lensim-pairs' settings record"):
        _run(setup, "k")


def test_changed_settings_are_refused(setup):
    _run(setup, "c")
    base, sharp, sensor, bank = setup
    with pytest.raises(InputError, match="crops"):
        make_dataset(sharp, base / "c", bank, SENSOR, sensor, crops=3, size=64, seed=3)


def test_dask_workers_give_the_same_pairs(setup):
    a, _ = _run(setup, "a")
    d, _ = _run(setup, "d", workers=2)
    for ra, rd in zip(a["records"], d["records"]):
        for ca, cd in zip(ra["crops"], rd["crops"]):
            assert (setup[0] / "a" / ca["input"]).read_bytes() == (setup[0] / "d" / cd["input"]).read_bytes()


def test_placements_cover_every_field_zone(setup):
    """Three placements put each photo's centre in the centre, middle and edge radius bands,
    each placement with its own capture draw and crops."""
    m, _ = _run(setup, "p", placements=3)
    sensor = setup[2]
    half_diag = np.hypot(sensor.width, sensor.height) / 2
    assert m["pairs"] == 2 * 2 * 3 and m["placements"] == 3
    for rec in m["records"]:
        _, _, h, w = rec["source_crop"]
        assert len(rec["placements"]) == 3
        for k, p in enumerate(rec["placements"]):
            assert p["sensor_top"] % 2 == 0 and p["sensor_left"] % 2 == 0
            assert 0 <= p["sensor_top"] <= sensor.height - h and 0 <= p["sensor_left"] <= sensor.width - w
            rho = np.hypot(p["sensor_top"] + h / 2 - sensor.height / 2, p["sensor_left"] + w / 2 - sensor.width / 2)
            assert k / 3 - 0.002 <= rho / half_diag < (k + 1) / 3 + 0.002
        assert [c["placement"] for c in rec["crops"]] == [0, 0, 1, 1, 2, 2]
        kelvins = {p["capture"]["kelvin"] for p in rec["placements"]}
        assert len(kelvins) == 3  # a fresh capture draw per placement


def test_placement_falls_back_to_the_nearest_band():
    """A photo as large as the sensor has a single position: every band gets it."""
    sensor = load_sensor(SENSOR)
    gen = torch.Generator().manual_seed(0)
    assert place_on_sensor(sensor.height, sensor.width, sensor, 2, 3, gen) == (0, 0)
    # a 1000-pixel photo reaches rho 0.808 at most, short of the last of 10 bands [0.9, 1):
    # it goes towards a corner, as far out as the draws allow
    top, left = place_on_sensor(1000, 1000, sensor, 9, 10, gen)
    rho = np.hypot(top + 500 - sensor.height / 2, left + 500 - sensor.width / 2) / (np.hypot(6000, 4000) / 2)
    assert 0.75 < rho <= 0.809


def test_zero_placements_are_refused(setup):
    base, sharp, sensor, bank = setup
    with pytest.raises(InputError, match="placements"):
        make_dataset(sharp, base / "z", bank, SENSOR, sensor, crops=1, size=64, placements=0)


def test_exposure_draws_darken_scene_and_target_together(setup):
    """--exposure-ev -3,-1: each placement draws its own exposure in that range (recorded),
    the target crop is the source photo at that exposure (linear light times 2**ev, to
    8-bit rounding), the input is the camera's view of the same darker scene; the range is
    recorded in the settings, and off (the default) leaves the folder as before: no key,
    bit-identical pairs."""
    from lensim.sensor.isp import expose, srgb_to_linear

    base, sharp, sensor, bank = setup
    m, _ = _run(setup, "ev", placements=2, exposure_ev=(-3.0, -1.0))
    assert m["exposure_ev"] == [-3.0, -1.0]
    for rec in m["records"]:
        evs = [p["exposure_ev"] for p in rec["placements"]]
        assert all(-3.0 <= e <= -1.0 for e in evs) and evs[0] != evs[1]
        y0, x0, _, _ = rec["source_crop"]
        src, _ = read_image(rec["source"])
        for c in rec["crops"]:
            ev = evs[c["placement"]]
            target, _ = read_image(base / "ev" / c["target"])
            inp, _ = read_image(base / "ev" / c["input"])
            top, left = (
                c["sensor_top"] - rec["placements"][c["placement"]]["sensor_top"],
                c["sensor_left"] - rec["placements"][c["placement"]]["sensor_left"],
            )
            want = expose(src[:, y0 + top : y0 + top + 64, x0 + left : x0 + left + 64], ev)
            assert float((target - want).abs().max()) <= 0.5 / 255 + 1e-6
            ratio = (
                srgb_to_linear(target).mean()
                / srgb_to_linear(src[:, y0 + top : y0 + top + 64, x0 + left : x0 + left + 64]).mean()
            )
            assert abs(float(ratio) - 2.0**ev) < 0.05 * 2.0**ev
            assert abs(float(inp.mean() - target.mean())) < 0.1  # the camera saw the same darker scene
    a, _ = _run(setup, "a")
    off, _ = _run(setup, "ev0", exposure_ev=(0.0, 0.0))
    assert "exposure_ev" not in off and all("exposure_ev" not in p for r in off["records"] for p in r["placements"])
    for ra, ro in zip(a["records"], off["records"]):
        for ca, co in zip(ra["crops"], ro["crops"]):
            assert (base / "a" / ca["input"]).read_bytes() == (base / "ev0" / co["input"]).read_bytes()
    with pytest.raises(InputError, match="exposure_ev"):
        make_dataset(sharp, base / "bad", bank, SENSOR, sensor, crops=1, size=64, exposure_ev=(0.0, -1.0))


def test_posed_banks_render_every_pixel_through_its_quadrants_bank(setup):
    # a lens with poses renders through one bank per sensor quadrant and its mirrored lens's
    # (lensim.render.posed); the same bank under every key is the plain bank's rendering, byte
    # for byte, and the manifest's "bank" is the stage's (what a restoration uses)
    from lensim.data.pairs import PosedBanks
    from lensim.render.posed import MIRROR, QUADRANTS

    bank = setup[3]
    posed = PosedBanks(dict.fromkeys((k + m for k in QUADRANTS for m in ("", MIRROR)), bank), bank)
    a, _ = _run(setup, "a")
    base, sharp, sensor, _ = setup
    p = make_dataset(sharp, base / "posed", posed, SENSOR, sensor, crops=2, size=64, seed=3)
    assert p["bank"] == str(bank.directory) and set(p["posed_banks"]) == {
        k + m for k in QUADRANTS for m in ("", MIRROR)
    }
    for ra, rp in zip(a["records"], p["records"], strict=True):
        for ca, cp in zip(ra["crops"], rp["crops"], strict=True):
            assert (base / "a" / ca["input"]).read_bytes() == (base / "posed" / cp["input"]).read_bytes()
