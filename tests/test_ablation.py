"""lensim ablation on a tiny pairs set: every variant trained, evaluated, cached."""
import json

import pytest

from lensim.ablation import VARIANTS, run_ablation
from lensim.restore.network import FieldAwareUNet, count_parameters


def test_variants_switch_what_they_say():
    full = count_parameters(FieldAwareUNet(width=8))
    for name, switches in VARIANTS.items():
        if switches:
            assert count_parameters(FieldAwareUNet(width=8, **switches)) < full, name


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    from lensim.assets.images import sample_image_path
    from lensim.data.pairs import make_dataset
    from lensim.images import read_image, write_image
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import compute_bank
    from lensim.sensor.profile import load_sensor

    base = tmp_path_factory.mktemp("abl")
    for name in ("kodim23", "coffee", "chelsea", "sail"):
        img, _ = read_image(sample_image_path(name))
        write_image(base / "sharp" / f"{name}.png", img[:, :96, :96])
    sensor = load_sensor("apsc_mirrorless")
    bank = compute_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, 15, fields=[0.0, 1.0],
                        wavelengths_nm=[550], pupil_samples=64, out_dir=base / "bank")
    make_dataset(base / "sharp", base / "pairs", bank, "apsc_mirrorless", sensor, crops=2, size=48, seed=1)
    return base


def test_ablation_trains_evaluates_and_caches(pairs):
    said = []
    out = pairs / "ablation"
    s = run_ablation(pairs / "pairs", out, minutes=0.05, width=8, crop=32, variants=["full", "plain-unet"],
                     say=said.append)
    assert set(s["variants"]) == {"full", "plain-unet"}
    for v in s["variants"].values():
        assert v["metrics"]["psnr_db"] > 0 and v["train"]["steps"] >= 1
    assert s["variants"]["plain-unet"]["use_fov"] is False
    assert json.loads((out / "ablation.json").read_text())["held_out_photos"] == s["held_out_photos"]
    said.clear()
    run_ablation(pairs / "pairs", out, minutes=0.05, width=8, crop=32, variants=["full", "plain-unet"], say=said.append)
    assert not any(m.startswith("training") for m in said)  # finished runs are reused
