"""The universal model (lensim.restore.universal): pretraining resumes to the very weights of
an uninterrupted run; the shipped (PSF-informed) model loads and restores a photo zero-shot
through `lensim restore --lens --sensor`, the lens's bank computed for it; a sensor or
F-number outside its trained ranges is one line (exit 2); `lensim train --init` starts from
its weights and resumes after a kill.

Networks and pairs are tiny (width 8; synthetic pairs, or the tiny camera's pairs where the
Wiener stage needs a bank): the shipped model's training is recorded in
lensim/assets/models/universal/README.md.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest
import torch

import lensim.restore.universal as uni
from cli_runner import run_cli
from lensim.data.pairs import make_dataset
from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.restore.config import TrainConfig
from lensim.restore.models import build_model
from lensim.restore.psfnet import uses_wiener
from lensim.sensor.profile import load_sensor
from test_kill_resume import TRAIN, _losses, _rows, cli, kill_when
from test_train import make_pairs
from tests.tiny_camera import tiny_camera

pytestmark = pytest.mark.usefixtures("one_torch_thread")

PITCH_UM = 5.97  # the fullframe_dslr profile's pitch: the synthetic pairs' sensor
TINY = uni.PretrainConfig(
    width=8, stem=2, crop=32, batch_size=2, time_budget_s=None, checkpoint_every_s=0.0, arch="nafnet"
)


def _pairs(root: Path, seed: int) -> Path:
    """Synthetic pairs (tests/test_train.make_pairs) on a sensor of PITCH_UM."""
    make_pairs(root, seed=seed)
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["sensor"] = {**load_sensor("fullframe_dslr").to_dict(), "resolution": manifest["sensor"]["resolution"]}
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


@pytest.fixture(scope="module")
def camera(tmp_path_factory) -> dict:
    """The tiny camera (tests/tiny_camera.py) and two pairs folders made through its bank."""
    base = tmp_path_factory.mktemp("camera")
    sharp, sensor_file, sensor, bank = tiny_camera(base)
    folders = []
    for seed in (0, 1):
        make_dataset(sharp, base / f"pairs{seed}", bank, str(sensor_file), sensor, crops=1, size=64, seed=seed)
        folders.append(base / f"pairs{seed}")
    return {"base": base, "folders": folders, "sensor_file": sensor_file, "sensor": sensor}


@pytest.fixture(scope="module")
def shipped(camera) -> Path:
    """A tiny PSF-informed universal model pretrained on the tiny camera's two pairs folders
    (their Wiener stage caches computed first) and shipped into a folder."""
    base = camera["base"]
    uni.pretrain(camera["folders"], base / "run", uni.replace(TINY, arch="psfnet", max_steps=4))
    return uni.ship(base / "run", base / "model").parent


def test_pretraining_resumes_to_the_weights_of_an_uninterrupted_run(tmp_path):
    folders = [_pairs(tmp_path / "a", 0), _pairs(tmp_path / "b", 1)]
    whole = uni.pretrain(folders, tmp_path / "whole", uni.replace(TINY, max_steps=6))
    uni.pretrain(folders, tmp_path / "parts", uni.replace(TINY, max_steps=2))  # "killed" after 2 steps
    parts = uni.pretrain(folders, tmp_path / "parts", uni.replace(TINY, max_steps=6))
    assert whole.step == parts.step == 6
    a = torch.load(tmp_path / "whole" / "last.pt", weights_only=True)["model_state"]
    b = torch.load(tmp_path / "parts" / "last.pt", weights_only=True)["model_state"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert (tmp_path / "parts" / "log.csv").read_text().splitlines()[0] == "step,epoch,loss,seconds,folders"


def test_shipped_model_loads_with_its_ranges(shipped, camera):
    model, universal = uni.load_universal(shipped)
    pitch = camera["sensor"].pixel_pitch_um
    assert universal["pixel_pitch_um"] == [pitch, pitch] and uses_wiener(model)
    out = model(torch.rand(1, 3, 32, 32), torch.zeros(1, 2, 32, 32), None, torch.rand(1, 3, 32, 32))
    assert out.shape == (1, 3, 32, 32) and torch.isfinite(out).all()
    assert (shipped / "training_log.csv").exists()
    for folder in camera["folders"]:  # each pairs folder's own Wiener stage cache
        assert len(list((folder / "wiener").glob("*/*.png"))) == 2


@pytest.mark.slow  # a 2-worker local Dask cluster (about 15 s)
def test_pairs_copied_without_their_banks_warn_that_no_fno_range_is_recorded(camera, tmp_path):
    """Pairs carried to another machine without their banks (the Wiener stage caches made
    already): pretraining works, says in one warning that it records no F-number range, and
    records the pitch range; with the banks there the F-number range is recorded."""
    uni.stage_caches(camera["folders"], uni.replace(TINY, arch="psfnet").network())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert uni._ranges(camera["folders"])["fno"] is not None
    copies = []
    for folder in camera["folders"]:
        shutil.copytree(folder, tmp_path / folder.name)
        manifest = json.loads((tmp_path / folder.name / "manifest.json").read_text())
        manifest["bank"] = str(tmp_path / "elsewhere" / folder.name)
        (tmp_path / folder.name / "manifest.json").write_text(json.dumps(manifest))
        copies.append(tmp_path / folder.name)
    with pytest.warns(UserWarning, match="2 of 2 pairs folders.*no F-number range"):
        ranges = uni._ranges(copies)
    assert ranges["fno"] is None and ranges["pixel_pitch_um"][0] > 0


def test_stage_caches_on_two_workers_equal_one_process(camera, tmp_path):
    """stage_caches with 2 workers writes each folder's Wiener stage cache byte for byte as
    one process does, and reports every folder."""
    import shutil

    network = uni.replace(TINY, arch="psfnet").network()
    copies = {}
    for workers in (1, 2):
        folders = []
        for folder in camera["folders"]:
            copy = tmp_path / f"w{workers}" / folder.name
            shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("wiener"))
            folders.append(copy)
        seen: list[tuple[int, int]] = []
        uni.stage_caches(folders, network, workers, lambda done, total, seen=seen: seen.append((done, total)))
        assert seen[-1] == (2, 2)
        copies[workers] = {
            p.relative_to(tmp_path / f"w{workers}"): p.read_bytes()
            for p in (tmp_path / f"w{workers}").glob("*/wiener/*/*.png")
        }
    assert len(copies[1]) == 4 and copies[1] == copies[2]
    assert uni.stage_caches(camera["folders"], uni.replace(TINY, arch="nafnet").network(), 2) is None  # no stage


def test_unknown_architecture_is_one_line_naming_it(tmp_path, capsys, monkeypatch):
    code, _, err = run_cli(
        ["library", "pretrain", str(tmp_path), "-o", str(tmp_path / "run"), "--arch", "unet"], capsys, monkeypatch
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--arch" in err, err


def test_check_range_is_one_line_naming_the_option():
    ranges = {"pixel_pitch_um": [1.0, 6.0], "fno": [2.0, 8.0]}
    uni.check_range(ranges, "pixel_pitch_um", 6.2, "--sensor")  # within the 5 % margin
    with pytest.raises(InputError, match="--sensor.*outside the universal model's range 1..6") as e:
        uni.check_range(ranges, "pixel_pitch_um", 0.5, "--sensor")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="F-number"):
        uni.check_range(ranges, "fno", 22.0, "--fno")


def _photo(tmp_path: Path, h: int = 96, w: int = 128) -> Path:
    img = torch.rand(3, 1, 1).expand(3, h, w) * 0.5 + 0.25 * torch.rand(3, h, w)
    write_image(tmp_path / "photo.png", img, 8)
    return tmp_path / "photo.png"


def test_zero_shot_restore_and_out_of_range_sensor(shipped, camera, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    photo = _photo(tmp_path)  # a whole frame of the tiny camera's 128 x 96 sensor
    sensor = str(camera["sensor_file"])
    args = ["restore", "--lens", "cooke_triplet", "--sensor", sensor, str(photo), "-o", str(tmp_path / "o")]
    code, _, err = run_cli([*args, "--quiet"], capsys, monkeypatch)
    assert code == 0, err
    assert (tmp_path / "o" / "photo.png").exists()
    assert list((tmp_path / "cache").rglob("manifest.json"))  # the lens's bank, computed for the stage
    small = _photo(tmp_path / "small", 48, 64)  # not at the sensor's scale: the bank cannot serve it
    args = ["restore", "--lens", "cooke_triplet", "--sensor", sensor, str(small), "-o", str(tmp_path / "o2")]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "native pixel scale" in err, err
    assert not (tmp_path / "o2" / "photo.png").exists()
    args = ["restore", "universal", str(photo), "--lens", "cooke_triplet", "--sensor", "phone", "-o", str(tmp_path)]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "--sensor" in lines[0] and "1.12 um pixel pitch" in lines[0], err


def test_zero_shot_with_a_universal_model_of_ones_own(shipped, camera, tmp_path, capsys, monkeypatch):
    """A model from `lensim library pretrain --ship DIR` restores zero-shot as CHECKPOINT with
    --lens, the shipped one not used (MODEL_DIR points nowhere); a training run is not one."""
    monkeypatch.setattr(uni, "MODEL_DIR", tmp_path / "nowhere")
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    photo = _photo(tmp_path)
    sensor = str(camera["sensor_file"])
    for i, model in enumerate((shipped, shipped / "model.pt")):
        args = [
            "restore",
            str(model),
            str(photo),
            "--lens",
            "cooke_triplet",
            "--sensor",
            sensor,
            "-o",
            str(tmp_path / f"o{i}"),
        ]
        code, _, err = run_cli([*args, "--quiet"], capsys, monkeypatch)
        assert code == 0, err
        assert (tmp_path / f"o{i}" / "photo.png").exists()
    assert uni.is_universal_model(shipped) and not uni.is_universal_model(camera["base"] / "run")
    assert not uni.is_universal_model(photo)


def test_zero_shot_needs_lens_and_sensor(shipped, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    code, _, err = run_cli(
        ["restore", "universal", str(_photo(tmp_path)), "-o", str(tmp_path / "o")], capsys, monkeypatch
    )
    assert code == 2 and "--lens" in err and len(err.strip().splitlines()) == 1


def _init_checkpoint(tmp_path: Path, reference_run: Path) -> Path:
    """The reference run's trained weights as a checkpoint to start from (--init)."""
    ckpt = torch.load(reference_run / "last.pt", weights_only=True)
    path = tmp_path / "init.pt"
    torch.save({k: ckpt[k] for k in ("format", "version", "model_config", "model_state")}, path)
    return path


@pytest.fixture(scope="module")
def init_reference(tmp_path_factory):
    """Uninterrupted runs on synthetic pairs: from scratch, then one started from its weights."""
    base = tmp_path_factory.mktemp("init")
    pairs = make_pairs(base / "pairs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert cli(["train", str(pairs), "-o", str(base / "scratch"), *TRAIN]) == 0
        init = _init_checkpoint(base, base / "scratch")
        assert cli(["train", str(pairs), "-o", str(base / "tuned"), "--init", str(init), *TRAIN]) == 0
    return base, pairs, init


def test_init_starts_from_the_weights(init_reference):
    base, _, _ = init_reference
    scratch, tuned = _losses(base / "scratch"), _losses(base / "tuned")
    assert float(tuned[0][1]) < float(scratch[0][1])  # the first step already has the trained weights


def test_a_fine_tuning_that_loses_ground_keeps_its_starting_weights(init_reference, tmp_path):
    """best.pt starts as the --init weights (validated before the first step): a run whose
    steps only make things worse (an absurd learning rate) ends with them in best.pt."""
    _, pairs, init = init_reference
    run = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = cli(["train", str(pairs), "-o", str(run), "--init", str(init), *TRAIN, "--lr", "1"])
    assert code == 0
    start = torch.load(init, weights_only=True)["model_state"]
    best = torch.load(run / "best.pt", weights_only=True)
    last = torch.load(run / "last.pt", weights_only=True)
    assert best["step"] == 0 and last["step"] > 0
    assert all(torch.equal(best["model_state"][k], v) for k, v in start.items())
    assert not all(torch.equal(last["model_state"][k], v) for k, v in start.items())


def test_init_resumes_after_a_kill(init_reference, tmp_path):
    base, pairs, init = init_reference
    run = tmp_path / "run"
    args = ["train", str(pairs), "-o", str(run), "--init", str(init), *TRAIN]
    steps = kill_when(args, lambda: _rows(run / "steps.csv"), 8, 0, 0.02)
    resume = ["train", str(pairs), "-o", str(run), "--resume", "--threads", "1", "--quiet"]
    assert cli(resume if (run / "last.pt").exists() else args) == 0
    ref = torch.load(base / "tuned" / "last.pt", weights_only=True)
    got = torch.load(run / "last.pt", weights_only=True)
    assert got["step"] == ref["step"] == 8, f"killed at step {steps}"
    for key, value in ref["model_state"].items():
        assert torch.equal(got["model_state"][key], value), f"{key}, killed at step {steps}"


def test_init_of_another_network_is_one_line(tmp_path):
    other = build_model(TrainConfig(width=8).resolved().model_kwargs())
    path = tmp_path / "other.pt"
    torch.save(
        {"format": "lensim-restore-checkpoint", "model_config": other.config, "model_state": other.state_dict()}, path
    )
    mine = build_model(TrainConfig(width=16).resolved().model_kwargs())
    with pytest.raises(InputError, match="init.*width 8.*width 16"):
        uni.load_init(mine, path)


def test_evaluate_scores_the_universal_model(shipped, camera, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    pairs = camera["folders"][1]
    code, out, err = run_cli(
        ["evaluate", "--pairs", str(pairs), "--methods", "input,universal", "--json"], capsys, monkeypatch
    )
    assert code == 0, err
    summary = json.loads(out)
    assert set(summary["methods"]) == {"input", "universal"}
    assert summary["methods"]["universal"]["psnr_db"] != summary["methods"]["input"]["psnr_db"]


def test_demo_starts_from_a_universal_model_that_serves_its_camera(shipped, camera, tmp_path, monkeypatch):
    """lensim demo fine-tunes the shipped universal model where it serves the demo's camera:
    its PSF-informed network (width, stem) with init "universal", and a plain baseline of its
    size; a sensor outside its pitch range (or a non-PSF-informed demo) trains from scratch."""
    import dataclasses

    from lensim.demo import DemoSettings, plain_network, with_universal_start
    from lensim.restore.network import count_parameters
    from test_default_network import _demo_configs

    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    quick = DemoSettings.make(quick=True)
    pitch = camera["sensor"].pixel_pitch_um
    start = with_universal_start(quick, pitch, 4.0)
    assert (start.init, start.init_width) == ("universal", 8)
    assert with_universal_start(quick, 3 * pitch, 4.0) == quick  # outside the pitch range
    assert with_universal_start(dataclasses.replace(quick, arch="nafnet"), pitch, 4.0).init is None
    model, plain = _demo_configs(tmp_path, monkeypatch, [(start, False), (start, True)])
    assert (model.arch, model.width, model.stem, model.init) == ("psfnet", 8, quick.stem, "universal")
    assert model.lr < plain.lr  # fine-tuning rate for the start, the scratch rate for the plain network
    assert plain.init is None and plain.width == plain_network(start)["width"]
    with torch.device("meta"):
        sizes = [count_parameters(build_model(c.model_kwargs())) for c in (model, plain)]
    assert abs(sizes[0] - sizes[1]) <= 0.25 * sizes[0]


def test_init_ignores_settings_that_do_not_shape_the_weights(shipped):
    """A psfnet without deformable blocks starts from the universal model whatever its
    (unused) deformable_scales says: the demo's and `lensim train`'s default is 2, the
    shipped model records 1."""
    model_config = torch.load(shipped / "model.pt", weights_only=True)["model_config"]
    for scales in (1, 2):
        model = build_model({**model_config, "deformable_scales": scales})
        uni.load_init(model, shipped / "model.pt")
    with pytest.raises(InputError, match="width"):
        uni.load_init(build_model({**model_config, "width": 16}), shipped / "model.pt")


def test_init_universal_builds_its_network_unless_told_otherwise(shipped, camera, tmp_path, capsys, monkeypatch):
    """`lensim train --init universal` with no network options builds the universal model's
    network (psfnet of its width) and starts from its weights; a --width that differs from
    it is one line naming init."""
    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    pairs, run = camera["folders"][0], tmp_path / "run"
    args = [
        "train",
        str(pairs),
        "-o",
        str(run),
        "--init",
        "universal",
        "--epochs",
        "1",
        "--threads",
        "1",
        "--crop",
        "32",
    ]
    code, _, err = run_cli([*args, "--steps-per-epoch", "1", "--quiet"], capsys, monkeypatch)
    assert code == 0, err
    config = torch.load(run / "last.pt", weights_only=True)["model_config"]
    assert (config["arch"], config["width"]) == ("psfnet", 8)
    code, _, err = run_cli([*args, "-o", str(tmp_path / "r2"), "--width", "12"], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "width" in err, err


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine with CUDA serves --device cuda")
def test_pretraining_on_a_device_this_machine_lacks_is_one_line(tmp_path, capsys, monkeypatch):
    folder = _pairs(tmp_path / "p", 0)
    args = ["library", "pretrain", str(folder), "-o", str(tmp_path / "run"), "--device", "cuda", "--quiet"]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--device" in err and "CUDA" in err, err
    assert not (tmp_path / "run").exists()


def test_zero_shot_restore_with_an_as_built_lens_uses_its_posed_banks(shipped, camera, tmp_path, capsys, monkeypatch):
    """A lens with poses (what `lensim calibrate` writes) restores zero-shot with its banks
    by sensor source (8: each quadrant's and its mirrored lens's, lensim.render.posed), the
    stage composed per pixel; a raw file too."""
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens

    monkeypatch.setattr(uni, "MODEL_DIR", shipped)
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    as_built = tmp_path / "as_built.yaml"
    save_lens(perturbed_lens(load_lens("cooke_triplet", warn=False), {"e2.decentre_x": 0.03}), as_built)
    photo, sensor = _photo(tmp_path), str(camera["sensor_file"])
    outs = {}
    for lens in ("cooke_triplet", str(as_built)):
        out = tmp_path / f"o-{len(outs)}"
        code, _, err = run_cli(
            ["restore", "--lens", lens, "--sensor", sensor, str(photo), "-o", str(out), "--quiet"], capsys, monkeypatch
        )
        assert code == 0, err
        outs[lens] = read_image(out / "photo.png")[0]
    assert len(list((tmp_path / "cache").rglob("manifest.json"))) == 1 + 8  # the nominal lens's, the 8 posed
    assert not torch.equal(outs["cooke_triplet"], outs[str(as_built)])
    from tests.raw_fixtures import random_mosaic, write_dng

    raw = write_dng(tmp_path / "shot.dng", random_mosaic(96, 128, 600, 4000))
    tifs = {}
    for lens in ("cooke_triplet", str(as_built)):  # a raw file the same way, its stage posed too
        out = tmp_path / f"raw-{len(tifs)}"
        args = ["restore", "--lens", lens, "--sensor", sensor, str(raw), "-o", str(out), "--allow-other-camera"]
        code, _, err = run_cli([*args, "--quiet"], capsys, monkeypatch)
        assert code == 0, err
        tifs[lens] = read_image(out / "shot.tif")[0]
    assert not torch.equal(tifs["cooke_triplet"], tifs[str(as_built)])
    assert len(list((tmp_path / "cache").rglob("manifest.json"))) == 1 + 8  # no bank computed again
