"""lensim ablation (the paper's Table 2) on a tiny pairs set: each variant switches off
exactly the component it names; every variant is trained on the same photos and scored on
the same held-out photos, none of them seen in training; the input's score matches
scikit-image's PSNR of the held-out crops; the untrained-from-identity networks score
close to the input after a 3-second budget; finished runs are reused."""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from skimage.metrics import peak_signal_noise_ratio

from lensim.ablation import VARIANTS, run_ablation
from lensim.restore.network import ContextBlock, DeformResBlock, FieldAwareUNet, count_parameters, plain_unet_width

PHOTOS = ("kodim23", "coffee", "chelsea", "sail")
# what each variant of the paper's ablation switches off
SWITCHED_OFF = {
    "full": set(),
    "no-fov": {"fov"},
    "no-deformable": {"deformable"},
    "no-context": {"context"},
    "plain-unet": {"fov", "deformable", "context"},
}


def _components_on(net: FieldAwareUNet) -> dict[str, bool]:
    """Which of the three ideas the built network really contains (from its modules)."""
    return {
        "fov": net.head.in_channels == 5,  # RGB + the 2 FOV channels
        "deformable": any(isinstance(block, DeformResBlock) for block in net.dec),
        "context": isinstance(net.context, ContextBlock),
    }


def test_variants_switch_off_exactly_what_they_name() -> None:
    assert set(VARIANTS) == set(SWITCHED_OFF)
    for name, off in SWITCHED_OFF.items():
        on = _components_on(FieldAwareUNet(width=8, **VARIANTS[name]))
        assert {c for c, present in on.items() if not present} == off, name


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from lensim.assets.images import sample_image_path
    from lensim.data.pairs import make_dataset
    from lensim.images import read_image, write_image
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import load_sensor

    base = tmp_path_factory.mktemp("abl")
    for name in PHOTOS:
        img, _ = read_image(sample_image_path(name))
        write_image(base / "sharp" / f"{name}.png", img[:, :96, :96])
    sensor = load_sensor("apsc_mirrorless")
    settings = BankSettings(fields=(0.0, 1.0), wavelengths_nm=(550,), pupil_samples=64, kernel_pixels=15)
    bank = get_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, settings, out_dir=base / "bank")
    make_dataset(base / "sharp", base / "pairs", bank, "apsc_mirrorless", sensor, crops=2, size=48, seed=1)
    return base


def _input_psnr_by_skimage(pairs_dir: Path, held_out: list[str]) -> float:
    """Mean over the held-out crops of scikit-image's PSNR of input against target (8-bit
    PNGs read by Pillow, data range 1)."""
    manifest = json.loads((pairs_dir / "manifest.json").read_text())
    scores = []
    for record in manifest["records"]:
        if Path(record["source"]).name not in held_out and record["source"] not in held_out:
            continue
        for crop in record["crops"]:
            x, y = (np.asarray(Image.open(pairs_dir / crop[k]), dtype=np.float64) / 255.0 for k in ("input", "target"))
            scores.append(peak_signal_noise_ratio(y, x, data_range=1.0))
    assert scores, "no held-out crops"
    return float(np.mean(scores))


def test_ablation_trains_evaluates_and_caches(pairs: Path) -> None:
    said: list[str] = []
    out = pairs / "ablation"
    names = ["full", "plain-unet"]
    s = run_ablation(pairs / "pairs", out, time_budget_s=3.0, width=8, crop=32, variants=names, say=said.append)
    assert list(s["variants"]) == names
    # the same held-out photos for every variant, none of them trained on; all photos used
    held_out = s["held_out_photos"]
    assert held_out
    for name in names:
        split = json.loads((out / name / "split.json").read_text())
        assert split["val"] == held_out and not set(split["train"]) & set(held_out)
        assert sorted(Path(p).stem for p in split["train"] + split["val"]) == sorted(PHOTOS)
    assert s["input"]["psnr_db"] == pytest.approx(_input_psnr_by_skimage(pairs / "pairs", held_out), abs=1e-6)
    # sizes: the full net as built; the plain UNet at the width matching it within 10 %
    full = count_parameters(FieldAwareUNet(width=8))
    plain = s["variants"]["plain-unet"]
    assert s["variants"]["full"]["params"] == full and s["variants"]["full"]["width"] == 8
    assert plain["width"] == plain_unet_width(full, 3) and abs(plain["params"] - full) <= 0.1 * full
    assert plain["use_fov"] is False and plain["use_deformable"] is False and plain["use_context"] is False
    for name in names:
        v = s["variants"][name]
        assert v["train"]["steps"] >= 1
        # zero-initialised tail: each network starts as the identity, and a few seconds of
        # training at lr 5e-4 keep it near the input's score (measured on 2 cores: +0.13 dB
        # after 5 and 13 steps); a mis-wired evaluation (other crops, scale) is far off
        assert abs(v["metrics"]["psnr_db"] - s["input"]["psnr_db"]) < 1.0, name
    assert json.loads((out / "ablation.json").read_text())["held_out_photos"] == held_out
    said.clear()
    run_ablation(pairs / "pairs", out, time_budget_s=3.0, width=8, crop=32, variants=names, say=said.append)
    assert said and not any(m.startswith("training") for m in said)  # finished runs are reused


def test_nafnet_ablation(pairs: Path) -> None:
    """--arch nafnet: the same switches on NAFNet, the plain variant (plain-nafnet) at the
    width matching the full NAFNet's parameter count, both NAFNets in their checkpoints."""
    from lensim.ablation import variants_for
    from lensim.restore.checkpoint import load_checkpoint
    from lensim.restore.nafnet import NAFNet, nafnet_width

    assert list(variants_for("nafnet")) == ["full", "no-fov", "no-deformable", "no-context", "plain-nafnet"]
    out = pairs / "ablation-nafnet"
    s = run_ablation(
        pairs / "pairs", out, time_budget_s=2.0, width=8, crop=32, variants=["full", "plain-nafnet"], arch="nafnet"
    )
    assert s["arch"] == "nafnet"
    full = NAFNet(8, use_fov=True, use_deformable=True, use_context=True, deformable_scales=2)
    assert s["variants"]["full"]["params"] == count_parameters(full)
    plain = s["variants"]["plain-nafnet"]
    assert plain["width"] == nafnet_width(count_parameters(full)) and abs(
        plain["params"] - count_parameters(full)
    ) <= 0.1 * count_parameters(full)
    model, _ = load_checkpoint(out / "plain-nafnet")
    assert isinstance(model, NAFNet) and not (model.use_fov or model.use_deformable or model.use_context)
    assert abs(s["variants"]["full"]["metrics"]["psnr_db"] - s["input"]["psnr_db"]) < 1.0


def test_bad_variants_and_budgets_are_refused_before_any_work(tmp_path: Path) -> None:
    from lensim.errors import InputError

    with pytest.raises(InputError, match="variants: unknown variant 'no-such'; expected some of full, no-fov"):
        run_ablation(tmp_path / "pairs", tmp_path / "out", 1.0, variants=["full", "no-such"])
    with pytest.raises(InputError, match="time_budget_s: expected a positive number of seconds"):
        run_ablation(tmp_path / "pairs", tmp_path / "out", 0.0)
    assert not (tmp_path / "out").exists()


def test_a_killed_ablation_resumes(pairs: Path) -> None:
    """A rerun after a kill: the unfinished variant (last.pt, no done.json) continues from
    its checkpoint on the rest of its budget; one killed before its first checkpoint (no
    last.pt) starts again; a changed network is refused in one line naming last.pt."""
    from lensim.errors import InputError
    from lensim.restore.checkpoint import read_checkpoint
    from lensim.restore.train import train

    out = pairs / "ablation-killed"
    # what a kill leaves: the full variant trained part of its budget, the plain one only begun
    partial = train(
        pairs / "pairs",
        out / "full",
        epochs=100_000,
        arch="unet",
        width=8,
        crop=32,
        seed=0,
        lr=5e-4,
        lr_schedule="cosine",
        time_budget_s=0.5,
    )
    (out / "plain-unet").mkdir(parents=True)
    (out / "plain-unet" / "log.csv").write_text("epoch,step\n")
    with pytest.raises(InputError, match=r"full/last.pt: crop: differs from the run being resumed"):
        run_ablation(pairs / "pairs", out, time_budget_s=2.0, width=8, crop=48, variants=["full"])
    said: list[str] = []
    s = run_ablation(
        pairs / "pairs", out, time_budget_s=2.0, width=8, crop=32, variants=["full", "plain-unet"], say=said.append
    )
    assert said[:2] == ["training full (2 s)", "training plain-unet (2 s)"]
    ckpt = read_checkpoint(out / "full" / "last.pt")
    assert s["variants"]["full"]["train"]["steps"] > partial.step  # continued, not started again
    assert ckpt["train_config"]["time_budget_s"] == 2.0 and ckpt["train_seconds"] >= 1.9
    assert s["variants"]["plain-unet"]["train"]["steps"] >= 1
    assert (out / "ablation.json").is_file() and (out / "plain-unet" / "done.json").is_file()
