"""One restoration network across shooting settings (issue 16): pairs whose records carry
settings, training a conditioned network, its checkpoint, evaluation and `lensim restore`
with --fno/--focus-m/--focal-mm or a raw file's EXIF."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from cli_runner import run_cli
from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.restore.checkpoint import load_checkpoint
from lensim.restore.conditioning import Conditioning
from lensim.restore.dataset import PairDataset
from lensim.restore.infer import restore_image
from lensim.restore.run_log import read_csv
from lensim.restore.train import train


def _sensor() -> dict:
    from lensim.sensor.profile import load_sensor

    data = load_sensor("apsc_mirrorless").to_dict()
    data.update(name="test sensor", resolution=[640, 480], pixel_pitch_um=3.92)
    return data


SENSOR = _sensor()
LENS = {"name": "test lens", "surfaces": [{"radius": 10.0, "thickness": 1.0}]}
# (fno, focus_m) of the grid; the target's offset from the input depends on the F-number,
# so only a network that knows the setting can learn every record
GRID = [(2.0, 1.0), (2.0, math.inf), (8.0, 1.0), (8.0, math.inf)]
OFFSET = {2.0: 0.2, 8.0: 0.0}
# the UNet without deformable blocks: the learning thresholds below were measured on it
TINY = dict(
    arch="unet",
    width=8,
    depth=2,
    crop=32,
    batch_size=4,
    lr=1e-2,
    val_fraction=0.25,
    val_batch_size=8,
    seed=1,
    deformable_scales=0,
)


def settings_of(fno: float, focus_m: float) -> dict:
    """A record's settings as lensim.optics.shooting.describe gives them."""
    return {"fno": fno, "focus_m": focus_m, "object_m": focus_m, "focal_mm": 50.0, "config": None}


def make_settings_pairs(
    root: Path, grid=GRID, photos: int = 4, crops: int = 2, size: int = 40, with_settings: bool = True
) -> Path:
    """A pairs folder as `dataset make` across a grid writes it: one record per (photo,
    setting) with ``settings``; target = input + OFFSET[fno]."""
    gen = torch.Generator().manual_seed(0)
    records = []
    for i in range(photos):
        for fno, focus in grid:
            cs = []
            for k in range(crops):
                base = torch.rand(3, size // 8, size // 8, generator=gen)
                inp = (
                    0.1
                    + 0.6
                    * torch.nn.functional.interpolate(
                        base[None], size=(size, size), mode="bilinear", align_corners=False
                    )[0]
                )
                stem = f"pairs/{len(records):06d}_{k:03d}"
                write_image(root / f"{stem}_input.png", inp, 8)
                write_image(root / f"{stem}_target.png", inp + OFFSET.get(fno, 0.1), 8)
                cs.append(
                    {
                        "input": f"{stem}_input.png",
                        "target": f"{stem}_target.png",
                        "sensor_top": 20 * i,
                        "sensor_left": 30 * k,
                    }
                )
            rec = {"index": len(records), "source": f"/photos/photo{i}.png", "crops": cs}
            if with_settings:
                rec["settings"] = settings_of(fno, focus)
            records.append(rec)
    manifest = {
        "format": "lensim-pairs",
        "sensor": SENSOR,
        "sensor_name": "test",
        "lens": LENS,
        "size": size,
        "records": records,
    }
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_settings_pairs(tmp_path_factory.mktemp("grid"))


@pytest.fixture(scope="module")
def runs(pairs: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A conditioned run and one trained on the same pairs without the settings."""
    root = tmp_path_factory.mktemp("runs")
    torch.set_num_threads(1)
    train(pairs, root / "cond", epochs=6, **TINY)
    train(pairs, root / "plain", epochs=6, use_settings=False, **TINY)
    return {"cond": root / "cond", "plain": root / "plain"}


# ----------------------------------------------------------------------------- data


def test_dataset_yields_settings_vectors(pairs: Path):
    cond = Conditioning({"fno": (2.0, 8.0), "focus_m": (1.0, math.inf), "focal_mm": (50.0, 50.0)}, ("fno", "focus_m"))
    ds = PairDataset.from_folder(pairs, crop=32, conditioning=cond)
    item = ds[0]
    assert item["settings"].tolist() == [-1.0, -1.0]  # record 0: f/2 focused at 1 m
    assert ds[7]["settings"].tolist() == [1.0, 1.0]  # record 3: f/8 at infinity
    assert "settings" not in PairDataset.from_folder(pairs, crop=32)[0]  # no conditioning asked for


def test_mixed_or_bad_settings_are_refused(tmp_path: Path):
    root = make_settings_pairs(tmp_path / "p", photos=1, crops=1)
    manifest = json.loads((root / "manifest.json").read_text())
    del manifest["records"][2]["settings"]
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match=r"records\[2\]\.settings"):
        PairDataset.from_folder(root)
    manifest["records"][2]["settings"] = settings_of(-4.0, 1.0)
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match=r"records\[2\]\.settings\.fno"):
        PairDataset.from_folder(root)


def test_one_setting_trains_exactly_as_no_settings(tmp_path: Path):
    """Records at one setting give a network without settings inputs (nothing varies):
    the very losses of the same pairs without settings."""
    a = make_settings_pairs(tmp_path / "a", grid=[(4.0, 2.0)], photos=4, crops=2)
    b = make_settings_pairs(tmp_path / "b", grid=[(4.0, 2.0)], photos=4, crops=2, with_settings=False)
    ra = train(a, tmp_path / "ra", epochs=1, max_steps_per_epoch=3, **TINY)
    rb = train(b, tmp_path / "rb", epochs=1, max_steps_per_epoch=3, **TINY)
    la = [r["loss"] for r in read_csv(tmp_path / "ra" / "steps.csv")]
    lb = [r["loss"] for r in read_csv(tmp_path / "rb" / "steps.csv")]
    assert la == lb and ra.val_psnr == rb.val_psnr
    _, info = load_checkpoint(tmp_path / "ra")
    assert info["model_config"]["settings_dim"] == 0
    assert info["conditioning"] == {
        "keys": [],
        "ranges": {"fno": [4.0, 4.0], "focus_m": [2.0, 2.0], "focal_mm": [50.0, 50.0]},
    }
    _, old = load_checkpoint(tmp_path / "rb")
    assert old["conditioning"] == {"keys": [], "ranges": {}}


# ----------------------------------------------------------------------------- training


def test_conditioned_run_records_its_settings_and_learns_them(runs: dict[str, Path]):
    model, info = load_checkpoint(runs["cond"] / "last.pt")
    assert model.settings_dim == 2 and info["conditioning"]["keys"] == ["fno", "focus_m"]
    assert info["conditioning"]["ranges"]["fno"] == [2.0, 8.0]
    config = json.loads((runs["cond"] / "config.json").read_text())
    assert config["conditioning"]["keys"] == ["fno", "focus_m"] and config["use_settings"] is True
    plain, pinfo = load_checkpoint(runs["plain"] / "last.pt")
    assert plain.settings_dim == 0 and pinfo["conditioning"]["keys"] == []
    assert pinfo["conditioning"]["ranges"]["fno"] == [2.0, 8.0]  # still checked when restoring
    # the target's offset depends on the F-number: only the conditioned network can fit both
    cond_psnr = float(read_csv(runs["cond"] / "log.csv")[-1]["val_psnr"])
    plain_psnr = float(read_csv(runs["plain"] / "log.csv")[-1]["val_psnr"])
    assert cond_psnr > plain_psnr + 3.0, (cond_psnr, plain_psnr)


def test_resume_keeps_the_conditioning(pairs: Path, tmp_path: Path):
    train(pairs, tmp_path / "r", epochs=1, max_steps_per_epoch=2, **TINY)
    again = train(pairs, tmp_path / "r", resume=True, epochs=2)
    assert again.epochs_done == 2
    _, info = load_checkpoint(tmp_path / "r")
    assert info["conditioning"]["keys"] == ["fno", "focus_m"]
    with pytest.raises(InputError, match="use_settings"):
        train(pairs, tmp_path / "r", resume=True, epochs=3, use_settings=False)


def test_evaluation_gives_each_crop_its_settings(pairs: Path, runs: dict[str, Path]):
    from lensim.evaluate.harness import checkpoint_method, evaluate_rows

    rows = evaluate_rows(pairs, {"model": checkpoint_method(runs["cond"])}, sources=["photo0.png"])
    model, _ = load_checkpoint(runs["cond"])
    manifest = json.loads((pairs / "manifest.json").read_text())
    row = next(r for r in rows if r["method"] == "model" and r["record"] == 2)  # f/8 at 1 m
    crop = manifest["records"][2]["crops"][0]
    x, _ = read_image(pairs / crop["input"])
    y, _ = read_image(pairs / crop["target"])
    out = restore_image(
        model, x, (crop["sensor_top"], crop["sensor_left"]), (480.0, 640.0), settings=torch.tensor([1.0, -1.0])
    ).clamp(0, 1)
    mse = float(((out - y) ** 2).mean())
    assert row["mse"] == pytest.approx(mse, rel=1e-4)


# ----------------------------------------------------------------------------- restore


def _photo(tmp_path: Path) -> Path:
    img = 0.2 + 0.5 * torch.rand(3, 40, 48, generator=torch.Generator().manual_seed(5))
    write_image(tmp_path / "shot.png", img, 8)
    return tmp_path / "shot.png"


def test_restore_takes_the_settings_from_the_options(runs: dict[str, Path], tmp_path: Path, capsys, monkeypatch):
    photo = _photo(tmp_path)
    base = [
        "restore",
        str(runs["cond"]),
        str(photo),
        "--sensor-offset",
        "100,200",
        "--quiet",
        "--tile",
        "32",
        "--overlap",
        "8",
        "--precision",
        "float32",
    ]
    code, _, err = run_cli(base + ["-o", str(tmp_path / "none")], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "--fno" in err and "--focus-m" in err and "f/2 to f/8" in err and "--focal-mm" not in err
    assert not (tmp_path / "none").exists()
    code, _, err = run_cli(base + ["-o", str(tmp_path / "out"), "--fno", "4", "--focus-m", "2"], capsys, monkeypatch)
    assert code == 0, err
    assert "warning" not in err
    model, _ = load_checkpoint(runs["cond"])
    img, _ = read_image(photo)
    want = restore_image(
        model, img, (100.0, 200.0), (480.0, 640.0), tile=32, overlap=8, settings=torch.tensor([0.0, 0.0])
    ).clamp(0, 1)
    got, _ = read_image(tmp_path / "out" / "shot.png")
    assert float((got - want).abs().max()) <= 0.5 / 255 + 1e-6
    other = restore_image(
        model, img, (100.0, 200.0), (480.0, 640.0), tile=32, overlap=8, settings=torch.tensor([1.0, 0.0])
    ).clamp(0, 1)
    assert float((other - want).abs().max()) > 0.02  # the settings matter to this network


def test_restore_warns_outside_and_refuses_far_outside(runs: dict[str, Path], tmp_path: Path, capsys, monkeypatch):
    photo = _photo(tmp_path)
    base = ["restore", str(runs["cond"]), str(photo), "--sensor-offset", "100,200", "--quiet", "--focus-m", "inf"]
    code, _, err = run_cli(base + ["-o", str(tmp_path / "a"), "--fno", "11"], capsys, monkeypatch)
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning:") and "f/11" in lines[0] and "f/2 to f/8" in lines[0]
    code, _, err = run_cli(base + ["-o", str(tmp_path / "b"), "--fno", "22"], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--fno" in err and "f/22" in err
    assert not (tmp_path / "b").exists()
    # an unconditioned network trained on the same grid does not need the settings, and only warns
    code, _, err = run_cli(
        [
            "restore",
            str(runs["plain"]),
            str(photo),
            "--sensor-offset",
            "100,200",
            "--quiet",
            "-o",
            str(tmp_path / "c"),
            "--fno",
            "22",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0 and "warning" in err and "f/22" in err
    code, _, err = run_cli(
        ["restore", str(runs["plain"]), str(photo), "--sensor-offset", "100,200", "--quiet", "-o", str(tmp_path / "d")],
        capsys,
        monkeypatch,
    )
    assert code == 0 and not err.strip()


# ----------------------------------------------------------------------------- raw files


def _dng(tmp_path: Path, name: str, **exif) -> Path:
    from lensim.raw.dng import DngExif, write_capture_dng
    from lensim.sensor import isp
    from lensim.sensor.profile import sensor_from_dict

    sensor = sensor_from_dict(SENSOR, "test")
    g = torch.Generator().manual_seed(2)
    cam, params = isp.unprocess(0.2 + 0.5 * torch.rand(3, 32, 48, generator=g), sensor, g)
    raw = isp.quantize_raw(isp.mosaic(cam, sensor.bayer_pattern), sensor)
    return write_capture_dng(tmp_path / name, raw, sensor, params, exif=DngExif(**exif))


def test_exif_settings_are_read_from_a_dng(tmp_path: Path):
    from lensim.raw import read_raw
    from lensim.raw.restore import raw_settings

    raw = read_raw(_dng(tmp_path, "a.dng", fno=5.6, focal_length_mm=50.0, focus_distance_m=2.5))
    assert (raw.fno, raw.focal_length_mm, raw.focus_distance_m) == (5.6, 50.0, 2.5)
    assert raw_settings(raw, {}) == {"fno": 5.6, "focus_m": 2.5, "focal_mm": 50.0}
    assert raw_settings(raw, {"fno": 4.0}) == {"fno": 4.0, "focus_m": 2.5, "focal_mm": 50.0}  # options win
    far = read_raw(_dng(tmp_path, "b.dng", fno=8.0, focus_distance_m=math.inf))
    assert far.focus_distance_m == math.inf and far.focal_length_mm is None
    assert raw_settings(far, {}) == {"fno": 8.0, "focus_m": math.inf}


def test_restore_reads_a_raws_settings_from_exif(runs: dict[str, Path], tmp_path: Path, capsys, monkeypatch):
    raws = tmp_path / "raws"
    _dng(raws, "shot.dng", fno=4.0, focal_length_mm=50.0, focus_distance_m=2.0)
    base = ["restore", str(runs["cond"]), "--quiet", "--allow-other-camera", "--tile", "32", "--overlap", "8"]
    code, _, err = run_cli(base + [str(raws), "-o", str(tmp_path / "exif")], capsys, monkeypatch)
    assert code == 0, err
    code, _, err = run_cli(
        base + [str(raws), "-o", str(tmp_path / "opts"), "--fno", "4", "--focus-m", "2"], capsys, monkeypatch
    )
    assert code == 0, err
    exif, _ = read_image(tmp_path / "exif" / "shot.tif")
    opts, _ = read_image(tmp_path / "opts" / "shot.tif")
    assert torch.equal(exif, opts)
    code, _, err = run_cli(base + [str(raws), "-o", str(tmp_path / "f8"), "--fno", "8"], capsys, monkeypatch)
    assert code == 0, err
    f8, _ = read_image(tmp_path / "f8" / "shot.tif")
    assert float((f8 - exif).abs().max()) > 0.02  # --fno overrides the EXIF F-number
    # a raw without FNumber and no --fno: one line naming the file, EXIF tag and option; nothing written
    _dng(tmp_path / "bare", "bare.dng", focal_length_mm=50.0, focus_distance_m=2.0)
    code, _, err = run_cli(base + [str(tmp_path / "bare"), "-o", str(tmp_path / "none")], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "bare.dng" in err and "FNumber" in err and "--fno" in err
    assert not (tmp_path / "none").exists() or not any((tmp_path / "none").iterdir())
    _dng(tmp_path / "wide", "wide.dng", fno=0.7, focus_distance_m=2.0)  # 1.5 stops beyond f/2: refused
    code, _, err = run_cli(base + [str(tmp_path / "wide"), "-o", str(tmp_path / "w")], capsys, monkeypatch)
    assert code == 2 and "wide.dng" in err and "f/0.7" in err


def test_developed_photos_take_their_settings_from_exif(runs: dict[str, Path], tmp_path: Path, capsys, monkeypatch):
    import shutil

    import numpy as np
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    from lensim.raw.read import photo_exif_settings

    exif = Image.Exif()
    exif.get_ifd(0x8769).update({33437: IFDRational(4, 1), 37382: IFDRational(2, 1), 37386: IFDRational(50, 1)})
    pixels = (np.asarray(read_image(_photo(tmp_path))[0].permute(1, 2, 0)) * 255).round().astype(np.uint8)
    Image.fromarray(pixels).save(tmp_path / "exif.png", exif=exif.tobytes())
    assert photo_exif_settings(tmp_path / "exif.png") == {"fno": 4.0, "focus_m": 2.0, "focal_mm": 50.0}
    assert photo_exif_settings(tmp_path / "shot.png") == {}
    shutil.copy(_dng(tmp_path, "t.dng", fno=8.0, focus_distance_m=math.inf), tmp_path / "t.tif")  # a TIFF's Exif IFD
    assert photo_exif_settings(tmp_path / "t.tif") == {"fno": 8.0, "focus_m": math.inf}
    base = ["restore", str(runs["cond"]), "--sensor-offset", "100,200", "--quiet", "--tile", "32", "--overlap", "8"]
    code, _, err = run_cli(base + [str(tmp_path / "exif.png"), "-o", str(tmp_path / "a")], capsys, monkeypatch)
    assert code == 0, err
    code, _, err = run_cli(
        base + [str(tmp_path / "shot.png"), "-o", str(tmp_path / "b"), "--fno", "4", "--focus-m", "2"],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert torch.equal(read_image(tmp_path / "a" / "exif.png")[0], read_image(tmp_path / "b" / "shot.png")[0])
    code, _, err = run_cli(
        base + [str(tmp_path / "exif.png"), "-o", str(tmp_path / "c"), "--fno", "8"], capsys, monkeypatch
    )
    assert code == 0 and not torch.equal(
        read_image(tmp_path / "c" / "exif.png")[0], read_image(tmp_path / "a" / "exif.png")[0]
    )  # the option wins


def test_train_command_says_what_it_is_conditioned_on(pairs: Path, tmp_path: Path, capsys, monkeypatch):
    args = [
        "train",
        str(pairs),
        "--epochs",
        "1",
        "--steps-per-epoch",
        "1",
        "--width",
        "4",
        "--depth",
        "2",
        "--crop",
        "32",
        "--deformable-scales",
        "0",
    ]
    code, out, err = run_cli(args + ["-o", str(tmp_path / "a"), "--quiet"], capsys, monkeypatch)
    assert code == 0, err
    code, out, err = run_cli(args + ["-o", str(tmp_path / "b"), "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert json.loads(out)["conditioning"]["keys"] == ["fno", "focus_m"]
    code, out, err = run_cli(args + ["-o", str(tmp_path / "c"), "--no-settings", "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert json.loads(out)["conditioning"]["keys"] == []
    code, out, err = run_cli(args + ["-o", str(tmp_path / "d"), "--threads", "1"], capsys, monkeypatch)
    assert code == 0 and "conditioned on fno, focus_m (f/2 to f/8" in out


def test_evaluating_a_conditioned_network_on_pairs_without_settings_is_refused(runs: dict[str, Path], tmp_path: Path):
    from lensim.evaluate.harness import checkpoint_method, evaluate_rows

    bare = make_settings_pairs(tmp_path / "bare", grid=[(4.0, 2.0)], photos=1, crops=1, with_settings=False)
    with pytest.raises(InputError, match="has no settings"):
        evaluate_rows(bare, {"model": checkpoint_method(runs["cond"])})
