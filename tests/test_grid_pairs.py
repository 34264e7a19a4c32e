"""Training pairs across a grid of shooting settings (dataset make --bank GRID): each photo
gets one setting, seeded and balanced; its record carries the resolved settings; a photo's
pairs are those its setting's bank alone gives; resume and refusals as for one bank."""

from __future__ import annotations

import json
import math
import shutil
import warnings

import pytest

from lensim.assets.images import sample_image_path
from lensim.data.pairs import grid_settings_of_photos, make_dataset
from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, GridAxes, GridBank, PSFBank, get_bank
from lensim.sensor.profile import load_sensor

SENSOR = "apsc_mirrorless"
SETTINGS = BankSettings(fields=3, wavelengths_nm=(500.0, 600.0), pupil_samples=40, kernel_pixels=21)
OPTIONS = dict(crops=1, size=64, seed=3, noise=True)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    base = tmp_path_factory.mktemp("grid-pairs")
    for name in ("kodim23", "coffee", "chelsea"):
        img, _ = read_image(sample_image_path(name))
        write_image(base / "sharp" / f"{name}.png", img[:, :128, :160])
    sensor = load_sensor(SENSOR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        grid = get_bank(
            load_lens("cooke_triplet"),
            sensor.pixel_pitch_um,
            SETTINGS,
            shooting=GridAxes(fno=(5.6, 8.0)),
            out_dir=base / "grid",
        )
        made = make_dataset(base / "sharp", base / "data", grid, SENSOR, sensor, **OPTIONS)
    return base, sensor, grid, made


def test_settings_of_photos_are_balanced_and_seeded():
    picks = grid_settings_of_photos(0, 10, 4)
    assert picks == grid_settings_of_photos(0, 10, 4) and len(picks) == 10
    assert sorted(picks[:4]) == [0, 1, 2, 3] and sorted(picks[4:8]) == [0, 1, 2, 3]
    assert [picks.count(k) for k in range(4)] in (
        [3, 3, 2, 2],
        [3, 2, 3, 2],
        [3, 2, 2, 3],
        [2, 3, 3, 2],
        [2, 3, 2, 3],
        [2, 2, 3, 3],
    )
    assert any(grid_settings_of_photos(s, 10, 4) != picks for s in range(1, 5))
    assert grid_settings_of_photos(5, 3, 1) == [0, 0, 0]


def test_records_carry_their_settings_and_the_manifest_the_grid(world):
    base, _, grid, made = world
    assert [e["photos"] for e in made["grid"]] in ([2, 1], [1, 2])
    assert made["bank"] == str(grid.directory) and made["lens"] == grid.lens
    for rec in made["records"]:
        k = rec["grid_setting"]
        assert rec["settings"] == grid.manifest["settings"][k]["resolved"]
        assert rec["settings"]["fno"] == pytest.approx(grid.settings[k].fno)
        assert rec["settings"]["focus_m"] == "inf" and math.isinf(float(rec["settings"]["focus_m"]))
    on_disk = json.loads((base / "data" / "manifest.json").read_text())
    assert on_disk["grid"] == made["grid"]


def test_a_photo_gets_the_pairs_of_its_setting_bank_alone(world, tmp_path):
    base, sensor, grid, made = world
    k = made["records"][0]["grid_setting"]
    single = make_dataset(base / "sharp", tmp_path / "one", PSFBank.load(grid.bank_dir(k)), SENSOR, sensor, **OPTIONS)
    assert "grid" not in single and all("settings" in r and "grid_setting" not in r for r in single["records"])
    for rec, alone in zip(made["records"], single["records"], strict=True):
        if rec["grid_setting"] != k:
            continue
        for a, b in zip(rec["crops"], alone["crops"], strict=True):
            assert (base / "data" / a["input"]).read_bytes() == (tmp_path / "one" / b["input"]).read_bytes()


def test_resume_and_refusals(world, tmp_path):
    base, sensor, grid, made = world
    out = tmp_path / "data"
    shutil.copytree(base / "data", out)
    (out / "records" / "000001.json").unlink()
    (out / made["records"][1]["crops"][0]["input"]).unlink()
    calls = []
    again = make_dataset(
        base / "sharp", out, grid, SENSOR, sensor, progress=lambda d, t: calls.append((d, t)), **OPTIONS
    )
    assert calls[0] == (2, 3) and again["records"] == made["records"]
    for rec in made["records"]:
        for c in rec["crops"]:
            assert (out / c["input"]).read_bytes() == (base / "data" / c["input"]).read_bytes()
    other = tmp_path / "other-grid"
    shutil.copytree(base / "grid", other)
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["settings"][1]["resolved"]["fno"] = 11.0
    (other / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match="grid"):
        make_dataset(base / "sharp", out, GridBank.load(other), SENSOR, sensor, **OPTIONS)
    with pytest.raises(InputError, match="pixel_pitch_um"):
        make_dataset(base / "sharp", tmp_path / "x", grid, "phone", load_sensor("phone"), **OPTIONS)
