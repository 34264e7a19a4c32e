"""Training-pair generation: determinism, resume, refusal of changed settings, dask."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from lensim.assets.images import sample_image_path
from lensim.errors import InputError
from lensim.data.pairs import make_dataset
from lensim.images import read_image, write_image
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import compute_bank
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
    bank = compute_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, 21, fields=[0.0, 0.5, 0.8, 1.0],
                        wavelengths_nm=[500, 600], pupil_samples=96, out_dir=base / "bank")
    return base, sharp, sensor, bank


def _run(setup, out, **kw):
    base, sharp, sensor, bank = setup
    calls = []
    m = make_dataset(sharp, base / out, bank, SENSOR, sensor, crops=2, size=64, seed=3,
                     progress=lambda d, t: calls.append((d, t)), **kw)
    return m, calls


def test_pairs_are_written_with_positions_and_draws(setup):
    m, calls = _run(setup, "a")
    assert m["pairs"] == 4 and calls[0] == (0, 2) and calls[-1] == (2, 2)
    sensor = setup[2]
    for rec in m["records"]:
        assert rec["capture"]["kelvin"] > 0 and rec["capture"]["shot"] is not None
        for c in rec["crops"]:
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
