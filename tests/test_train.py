"""Training: dataset (split, FOV channels, augmentation), metrics, loss decrease, exact
resume, atomic checkpoints. Tiny models (width 8) on a synthetic pairs folder."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from lensim.data.manifest import read_pairs_manifest
from lensim.errors import OutputError
from lensim.images import write_image
from lensim.restore.checkpoint import atomic_torch_save
from lensim.restore.dataset import PairDataset, crop_refs, split_sources
from lensim.restore.fov import fov_channels, invert_augment
from lensim.restore.run_log import read_csv
from lensim.restore.train import train

SENSOR = {"name": "test sensor", "resolution": [640, 480]}  # [width, height]
LENS = {"name": "test lens", "surfaces": [{"radius": 10.0, "thickness": 1.0}]}


def make_pairs(root: Path, photos: int = 4, crops: int = 3, size: int = 40, seed: int = 0) -> Path:
    """A pairs folder like `lensim dataset make` writes: target = input + 0.1 (learnable
    by the network's residual bias), smooth random inputs in [0.1, 0.8]."""
    gen = torch.Generator().manual_seed(seed)
    records = []
    for i in range(photos):
        cs = []
        for k in range(crops):
            base = torch.rand(3, size // 8, size // 8, generator=gen)
            inp = (
                0.1
                + 0.7
                * torch.nn.functional.interpolate(base[None], size=(size, size), mode="bilinear", align_corners=False)[
                    0
                ]
            )
            name_in, name_gt = f"pairs/{i:06d}_{k:03d}_input.png", f"pairs/{i:06d}_{k:03d}_target.png"
            write_image(root / name_in, inp, 8)
            write_image(root / name_gt, inp + 0.1, 8)
            cs.append({"input": name_in, "target": name_gt, "sensor_top": 10 * i + 3 * k, "sensor_left": 100 + 7 * k})
        records.append({"index": i, "source": f"/photos/photo{i}.png", "crops": cs})
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


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_pairs(tmp_path_factory.mktemp("pairs"))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


TINY = dict(width=8, depth=2, crop=32, batch_size=2, lr=5e-3, val_fraction=0.25, val_batch_size=4, seed=3)


# ----------------------------------------------------------------------------- dataset


def test_split_by_source_is_deterministic_and_disjoint():
    names = [f"p{i}.png" for i in range(10)]
    tr, va = split_sources(names, 0.2, seed=1)
    assert len(va) == 2 and len(tr) == 8 and not set(tr) & set(va) and set(tr) | set(va) == set(names)
    assert split_sources(list(reversed(names)), 0.2, seed=1) == (tr, va)  # order-independent
    assert split_sources(["only.png"], 0.5, seed=0) == (["only.png"], [])  # never all photos in validation


def test_crops_of_one_photo_never_straddle_the_split(pairs: Path, tmp_path: Path):
    train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **TINY)
    split = json.loads((tmp_path / "run" / "split.json").read_text())
    refs = crop_refs(pairs, read_pairs_manifest(pairs))
    assert split["val"] and split["train"] and not set(split["val"]) & set(split["train"])
    for src in {r.source for r in refs}:
        assert src in split["train"] or src in split["val"]


def test_items_carry_absolute_fov_channels(pairs: Path):
    refs = crop_refs(pairs, read_pairs_manifest(pairs))
    plain = PairDataset(refs, (480, 640), crop=None, augment=False)
    for i in (0, 5):
        item = plain[i]
        expected = fov_channels(40, 40, refs[i].sensor_top, refs[i].sensor_left, 480, 640)
        assert torch.equal(item["fov"], expected)
    # sub-crops with augmentation: undoing the drawn op (one of 8) gives a crop of the stored
    # image and the FOV channels of its absolute sensor position
    aug = PairDataset(refs, (480, 640), crop=24, augment=True, seed=5)
    base = {i: plain[i] for i in range(len(refs))}
    ops_seen = set()
    for epoch in range(3):
        aug.set_epoch(epoch)
        for i in range(len(refs)):
            item = aug[i]
            assert item["input"].shape == (3, 24, 24) and item["fov"].shape == (2, 24, 24)
            found = False
            for op in range(8):
                inp, fov = invert_augment(item["input"], item["fov"], op)
                tgt, _ = invert_augment(item["target"], item["fov"], op)
                # locate the sub-crop by its FOV (absolute position), then compare pixels
                left = round(float(fov[0, 0, 0]) * 400 + 320 - 0.5) - refs[i].sensor_left
                top = round(float(fov[1, 0, 0]) * 400 + 240 - 0.5) - refs[i].sensor_top
                if not (0 <= top <= 16 and 0 <= left <= 16):
                    continue
                exp_fov = fov_channels(24, 24, refs[i].sensor_top + top, refs[i].sensor_left + left, 480, 640)
                if (
                    torch.allclose(fov, exp_fov, atol=1e-6)
                    and torch.equal(inp, base[i]["input"][:, top : top + 24, left : left + 24])
                    and torch.equal(tgt, base[i]["target"][:, top : top + 24, left : left + 24])
                ):
                    found = True
                    ops_seen.add(op)
                    break
            assert found, f"item {i} epoch {epoch}: no dihedral op maps it back to an absolute crop"
    assert len(ops_seen) >= 4  # augmentation really varies (36 draws)


def test_items_are_seeded_by_epoch_and_index(pairs: Path):
    ds = PairDataset.from_folder(pairs, crop=16, augment=True, seed=1)
    a = ds[3]
    ds2 = PairDataset.from_folder(pairs, crop=16, augment=True, seed=1)
    assert torch.equal(ds2[3]["input"], a["input"])
    ds2.set_epoch(1)
    assert not all(torch.equal(ds2[i]["fov"], ds[i]["fov"]) for i in range(len(ds)))


def test_bad_manifest_is_a_one_line_error(tmp_path: Path):
    from lensim.errors import InputError

    (tmp_path / "manifest.json").write_text(json.dumps({"sensor": {"resolution": [10]}, "records": []}))
    with pytest.raises(InputError, match="manifest.json: sensor.resolution"):
        read_pairs_manifest(tmp_path)


# ----------------------------------------------------------------------------- training


def test_loss_decreases_and_logs_are_written(pairs: Path, tmp_path: Path):
    run = tmp_path / "run"
    seen = []
    # the UNet: its tail bias is what learns the offset below (NAFNet at this lr overshoots in 4 steps)
    res = train(pairs, run, epochs=1, max_steps_per_epoch=4, progress=seen.append, arch="unet", **TINY)
    steps = read_csv(run / "steps.csv")
    losses = [r["loss"] for r in steps]
    assert len(losses) == 4 and res.step == 4
    # target = input + 0.1: first loss about 0.01; Adam at 5e-3 moves the tail bias 0.02 in 4 steps
    assert 0.005 < losses[0] < 0.015
    assert losses[-1] < 0.85 * losses[0], losses
    log = read_csv(run / "log.csv")
    assert [r["epoch"] for r in log] == [1.0] and log[0]["step"] == 4
    assert math.isfinite(log[0]["val_psnr"]) and 0 < log[0]["val_ssim"] <= 1
    assert res.val_psnr > res.val_input_psnr  # restored validation crops got closer to the targets
    assert [p.kind for p in seen] == ["step"] * 4 + ["epoch"]
    assert (run / "last.pt").is_file() and (run / "best.pt").is_file()
    ck = torch.load(run / "last.pt", weights_only=True)
    assert ck["lens"] == LENS and ck["sensor"] == SENSOR and ck["step"] == 4 and ck["epoch"] == 1
    assert ck["split"]["val"] == json.loads((run / "split.json").read_text())["val"]
    assert not [p for p in os.listdir(run) if p.endswith(".tmp")]


def test_validation_computes_the_inputs_metrics_once(pairs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The validation crops' own PSNR/SSIM do not change between epochs: the first
    validation computes them, the later ones reuse them (the same figures)."""
    from lensim.restore import batches

    calls = []
    real = batches.ssim_batch
    monkeypatch.setattr(batches, "ssim_batch", lambda a, b: calls.append(1) or real(a, b))
    res = train(pairs, tmp_path / "run", epochs=3, max_steps_per_epoch=1, arch="unet", **TINY)
    val_batches = math.ceil(3 / TINY["val_batch_size"])  # one validation photo of 3 crops
    assert len(calls) == (3 + 1) * val_batches  # the output's at 3 validations, the input's once
    once = train(pairs, tmp_path / "one", epochs=1, max_steps_per_epoch=1, arch="unet", **TINY)  # computed afresh
    assert math.isfinite(res.val_input_psnr) and res.val_input_psnr == once.val_input_psnr


def test_a_run_folder_is_not_overwritten(pairs: Path, tmp_path: Path):
    from lensim.errors import InputError

    train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **TINY)
    with pytest.raises(InputError, match="already holds a training run"):
        train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **TINY)


def test_a_failed_new_run_leaves_no_folder_and_an_old_one_is_kept(
    pairs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """train() itself (not only the CLI) removes a new run folder that failed before its
    first checkpoint; a folder that existed before, or that holds a checkpoint, stays."""
    import lensim.restore.train as train_module

    def fail(loop, batches):
        assert (tmp_path / "new" / "config.json").exists() or (tmp_path / "old").exists()  # the run had started
        raise RuntimeError("out of memory")

    monkeypatch.setattr(train_module, "_train_epoch", fail)
    with pytest.raises(RuntimeError, match="out of memory"):
        train(pairs, tmp_path / "new", epochs=1, **TINY)
    assert not (tmp_path / "new").exists()
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "notes.txt").write_text("mine")
    with pytest.raises(RuntimeError):
        train(pairs, tmp_path / "old", epochs=1, **TINY)
    assert (tmp_path / "old" / "notes.txt").read_text() == "mine"


def test_the_run_folder_is_removed_only_when_new_unfinished_and_unlocked(tmp_path: Path):
    from lensim.io import LOCK_NAME
    from lensim.restore.checkpoint import remove_unfinished_run, run_folder

    with pytest.raises(KeyboardInterrupt), run_folder(tmp_path / "a") as run:
        (run / "config.json").write_text("{}")
        raise KeyboardInterrupt  # a kill the process survives to clean up after
    assert not (tmp_path / "a").exists()
    with pytest.raises(RuntimeError), run_folder(tmp_path / "b") as run:
        (run / "last.pt").write_bytes(b"checkpoint")
        raise RuntimeError
    assert (tmp_path / "b" / "last.pt").exists()  # a checkpoint: resumable, kept
    with pytest.raises(RuntimeError), run_folder(tmp_path / "c", writer=False):
        (tmp_path / "c").mkdir()  # another rank's folder: only rank 0 writes (and removes)
        raise RuntimeError
    assert (tmp_path / "c").exists()
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / LOCK_NAME).write_text("")
    assert remove_unfinished_run(tmp_path / "d") is False  # another process's run


def test_resume_reproduces_the_loss_curve_exactly(pairs: Path, tmp_path: Path):
    kw = dict(TINY, max_steps_per_epoch=3, crop=24, depth=3)
    train(pairs, tmp_path / "straight", epochs=2, **kw)
    # an epoch boundary resume
    train(pairs, tmp_path / "split", epochs=1, **kw)
    train(pairs, tmp_path / "split", epochs=2, resume=True)
    # a mid-epoch resume: a zero time budget stops after the first step
    r = train(pairs, tmp_path / "mid", epochs=2, time_budget_s=0.0, **kw)
    assert r.stopped_early and r.step == 1
    while r.stopped_early:
        r = train(pairs, tmp_path / "mid", epochs=2, resume=True, time_budget_s=0.0)
    ref = read_csv(tmp_path / "straight" / "steps.csv")
    assert len(ref) == 6
    for name in ("split", "mid"):
        got = read_csv(tmp_path / name / "steps.csv")
        assert [(g["step"], g["loss"], g["lr"]) for g in got] == [(e["step"], e["loss"], e["lr"]) for e in ref], name
    a = torch.load(tmp_path / "straight" / "last.pt", weights_only=True)["model_state"]
    b = torch.load(tmp_path / "mid" / "last.pt", weights_only=True)["model_state"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resume_refuses_a_changed_recipe(pairs: Path, tmp_path: Path):
    from lensim.errors import InputError

    train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **TINY)
    with pytest.raises(InputError, match="width"):
        train(pairs, tmp_path / "run", epochs=2, resume=True, width=16)
    with pytest.raises(InputError, match="last.pt: no such file"):
        train(pairs, tmp_path / "other", epochs=2, resume=True)


def test_learning_rate_halves_every_k_epochs(pairs: Path, tmp_path: Path):
    train(pairs, tmp_path / "run", epochs=3, max_steps_per_epoch=1, lr_halve_every=2, **{**TINY, "lr": 1e-3})
    lrs = [r["lr"] for r in read_csv(tmp_path / "run" / "log.csv")]
    assert lrs == [1e-3, 1e-3, 5e-4]


def test_cosine_schedule_anneals_over_the_epochs_and_resumes_exactly(pairs: Path, tmp_path: Path):
    from lensim.restore.schedule import cosine_lr

    kw = dict(TINY, max_steps_per_epoch=2, lr_schedule="cosine", lr=1e-3)
    train(pairs, tmp_path / "straight", epochs=3, **kw)
    got = [r["lr"] for r in read_csv(tmp_path / "straight" / "steps.csv")]
    # step k of 6 runs at progress k / 6 (2 steps an epoch, 3 epochs)
    assert got == pytest.approx([1e-3 * 0.5 * (1 + math.cos(math.pi * k / 6)) for k in range(6)], rel=1e-6)
    assert cosine_lr(1e-3, 0.0) == 1e-3 and cosine_lr(1e-3, 1.5) == 0.0
    r = train(pairs, tmp_path / "mid", epochs=3, time_budget_s=0.0, **kw)
    assert r.stopped_early and r.step == 1
    # a resume that lifts the budget continues the same epoch-based schedule
    train(pairs, tmp_path / "mid", epochs=3, resume=True, time_budget_s=None)
    ref = read_csv(tmp_path / "straight" / "steps.csv")
    mid = read_csv(tmp_path / "mid" / "steps.csv")
    assert [(g["step"], g["loss"], g["lr"]) for g in mid] == [(e["step"], e["loss"], e["lr"]) for e in ref]


def test_time_budget_counts_the_calls_before_a_resume(pairs: Path, tmp_path: Path):
    kw = dict(TINY, max_steps_per_epoch=2)
    r = train(pairs, tmp_path / "run", epochs=50, time_budget_s=0.0, **kw)
    assert r.stopped_early and r.step == 1
    spent = torch.load(tmp_path / "run" / "last.pt", weights_only=True)["train_seconds"]
    assert spent > 0
    # a budget already spent by the first call: one more step, then stop
    r = train(pairs, tmp_path / "run", epochs=50, resume=True, time_budget_s=spent)
    assert r.stopped_early and r.step == 2
    assert torch.load(tmp_path / "run" / "last.pt", weights_only=True)["train_seconds"] > spent


def test_a_resume_keeps_the_stored_epochs_and_budget_unless_told_otherwise(pairs: Path, tmp_path: Path):
    kw = dict(TINY, max_steps_per_epoch=2)
    r = train(pairs, tmp_path / "run", epochs=3, time_budget_s=0.0, **kw)
    assert r.stopped_early and r.step == 1
    r = train(pairs, tmp_path / "run", resume=True)  # the budget is spent: one step, then stop
    assert r.stopped_early and r.step == 2
    r = train(pairs, tmp_path / "run", resume=True, time_budget_s=None)  # lifted: the stored 3 epochs, not 30
    assert not r.stopped_early and r.epochs_done == 3 and r.step == 6
    saved = torch.load(tmp_path / "run" / "last.pt", weights_only=True)["train_config"]
    assert saved["epochs"] == 3 and saved["time_budget_s"] is None


def test_cli_resume_takes_the_run_settings_not_the_option_defaults(
    pairs: Path, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
):
    from cli_runner import run_cli

    run = tmp_path / "run"
    args = ["train", str(pairs), "-o", str(run), "--quiet"]
    tiny = [
        "--width",
        "8",
        "--depth",
        "2",
        "--crop",
        "32",
        "--batch-size",
        "2",
        "--val-fraction",
        "0.25",
        "--seed",
        "3",
        "--steps-per-epoch",
        "1",
    ]
    assert run_cli([*args, *tiny, "--epochs", "2"], capsys, monkeypatch)[0] == 0
    code, out, _ = run_cli([*args, "--resume", "--json"], capsys, monkeypatch)
    assert code == 0 and json.loads(out)["steps"] == 2  # nothing left: 2 epochs (not the default 30), 1 step each
    code, out, _ = run_cli([*args, "--resume", "--json", "--epochs", "3"], capsys, monkeypatch)
    assert code == 0 and json.loads(out)["steps"] == 3
    code, _, err = run_cli([*args, "--resume", "--width", "16"], capsys, monkeypatch)
    assert code == 2 and "width" in err and err.count("\n") == 1


def test_a_truncated_checkpoint_is_named_in_one_line(
    pairs: Path, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
):
    from cli_runner import run_cli

    run = tmp_path / "run"
    train(pairs, run, epochs=1, max_steps_per_epoch=1, **TINY)
    data = (run / "last.pt").read_bytes()
    (run / "last.pt").write_bytes(data[: len(data) // 2])
    for args in (
        ["train", str(pairs), "-o", str(run), "--resume"],
        ["restore", str(run / "last.pt"), str(tmp_path / "x.png"), "-o", str(tmp_path / "o")],
    ):
        code, _, err = run_cli(args, capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1, err
        assert f"{run / 'last.pt'}: is corrupt or not a lensim checkpoint" in err


def test_checkpoints_within_an_epoch_every_n_steps(pairs: Path, tmp_path: Path):
    from lensim.restore.train import TrainProgress

    run = tmp_path / "run"
    seen: list[int | None] = []

    def look(p: TrainProgress) -> None:
        if p.kind == "step":
            last = run / "last.pt"
            seen.append(torch.load(last, weights_only=True)["step"] if last.exists() else None)

    train(pairs, run, epochs=1, max_steps_per_epoch=4, checkpoint_every_steps=2, progress=look, **TINY)
    assert seen == [None, None, 2, 2]  # written after steps 2 (mid-epoch) and 4 (the epoch's end)
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["step"] == 4 and ckpt["epoch"] == 1


def test_budget_progress_reports_seconds_against_the_budget(pairs: Path, tmp_path: Path):
    from lensim.restore.train import budget_progress

    assert budget_progress(None, 10.0) is None
    seen: list[tuple[float, float]] = []
    train(
        pairs,
        tmp_path / "run",
        epochs=1,
        max_steps_per_epoch=3,
        progress=budget_progress(lambda done, total: seen.append((done, total)), 1e-9),
        **TINY,
    )
    assert len(seen) >= 3 and all(total == 1e-9 and 0 <= done <= total for done, total in seen)


def test_unknown_schedule_is_a_clear_error(pairs: Path, tmp_path: Path):
    from lensim.errors import InputError

    with pytest.raises(InputError, match="lr_schedule: expected one of step, cosine"):
        train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **{**TINY, "lr_schedule": "linear"})


def test_checkpoint_save_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "last.pt"
    atomic_torch_save({"a": torch.arange(3)}, path)
    real_save = torch.save

    def broken_save(obj, fh, *args, **kwargs):
        fh.write(b"PK\x03\x04 half a zip")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OutputError, match=r"last\.pt: could not be written: disk full"):  # one line naming the file
        atomic_torch_save({"a": torch.arange(5)}, path)
    with pytest.raises(OutputError):
        atomic_torch_save({"a": torch.arange(5)}, tmp_path / "new.pt")
    monkeypatch.setattr(torch, "save", real_save)
    assert torch.equal(torch.load(path, weights_only=True)["a"], torch.arange(3))  # the old file, intact
    assert sorted(os.listdir(tmp_path)) == ["last.pt"]  # no partial new.pt, no temporary files


def test_training_interrupted_while_saving_leaves_the_previous_checkpoint(
    pairs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    run = tmp_path / "run"
    train(pairs, run, epochs=1, max_steps_per_epoch=1, **TINY)
    before = (run / "last.pt").read_bytes()
    real_save = torch.save

    def broken_save(obj, fh, *args, **kwargs):
        real_save(obj, fh, *args, **kwargs)
        fh.truncate(100)
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(KeyboardInterrupt):
        train(pairs, run, epochs=2, resume=True)
    monkeypatch.setattr(torch, "save", real_save)
    assert (run / "last.pt").read_bytes() == before
    assert not [p for p in os.listdir(run) if p.startswith(".")]
    res = train(pairs, run, epochs=2, resume=True)  # the run continues from the intact checkpoint
    assert res.epochs_done == 2 and res.step == 2


def _ddp_worker(rank: int, world: int, pairs: str, run: str, port: int, queue) -> None:
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world), RANK=str(rank), LOCAL_RANK=str(rank)
    )
    torch.set_num_threads(1)
    res = train(pairs, run, epochs=1, max_steps_per_epoch=2, **{**TINY, "batch_size": 2})
    queue.put((rank, res.step, res.val_psnr))


@pytest.mark.slow  # about 25 s: two spawned processes import torch
def test_distributed_data_parallel_on_cpu_matches_one_process(pairs: Path, tmp_path: Path):
    """Two Gloo ranks with 2 crops each take the steps one process takes with 4 crops."""
    import socket

    import torch.multiprocessing as mp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    mp.start_processes(
        _ddp_worker, args=(2, str(pairs), str(tmp_path / "ddp"), port, queue), nprocs=2, start_method="spawn"
    )
    results = sorted(queue.get(timeout=60) for _ in range(2))
    assert [r[:2] for r in results] == [(0, 2), (1, 2)]
    assert results[0][2] is not None and results[1][2] is None  # rank 0 alone validates
    train(pairs, tmp_path / "one", epochs=1, max_steps_per_epoch=2, **{**TINY, "batch_size": 4})
    ddp = [r["loss"] for r in read_csv(tmp_path / "ddp" / "steps.csv")]
    one = [r["loss"] for r in read_csv(tmp_path / "one" / "steps.csv")]
    assert len(ddp) == len(one) == 2
    assert np.allclose(ddp, one, rtol=1e-4, atol=0), (ddp, one)  # gradient all-reduce order: float rounding only


def test_training_state_resumes_through_the_checkpoint_module(tmp_path: Path):
    """TrainingState.save then resume_from restores weights, Adam, StepLR, position and the
    random streams exactly: the next step and the next random draw match an uninterrupted run."""
    from lensim.errors import InputError
    from lensim.restore.checkpoint import TrainingState, read_resume_checkpoint, refuse_existing_run
    from lensim.restore.network import FieldAwareUNet

    def fresh(seed: int) -> TrainingState:
        torch.manual_seed(seed)
        model = FieldAwareUNet(width=4, depth=2, use_deformable=False)
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)
        return TrainingState(
            model, opt, torch.optim.lr_scheduler.StepLR(opt, 1, 0.5), torch.amp.GradScaler("cuda", enabled=False)
        )

    def one_step(state: TrainingState) -> float:
        x = torch.rand(1, 3, 16, 16)
        loss = (state.model(x, fov_channels(16, 16, 0, 0, 32, 32)[None]) - x).pow(2).mean()
        state.optimizer.zero_grad()
        loss.backward()
        state.optimizer.step()
        state.scheduler.step()
        state.step += 1
        return float(loss.detach())

    with pytest.raises(InputError, match="last.pt: no such file"):
        read_resume_checkpoint(tmp_path)
    a = fresh(0)
    one_step(a)
    a.epoch, a.batch_in_epoch, a.best_val_psnr = 1, 0, 31.5
    a.save(tmp_path, 12.5, {"train_config": {}, "split": {}}, best=False)
    with pytest.raises(InputError, match="already holds a training run"):
        refuse_existing_run(tmp_path)
    expected = one_step(a), float(torch.rand(()))
    b = fresh(1)  # other weights and random state: all of it must come from the checkpoint
    b.resume_from(read_resume_checkpoint(tmp_path), "last.pt")
    assert (b.epoch, b.step, b.best_val_psnr, b.train_seconds) == (1, 1, 31.5, 12.5)
    assert (one_step(b), float(torch.rand(()))) == expected
    assert b.optimizer.param_groups[0]["lr"] == a.optimizer.param_groups[0]["lr"] == 2.5e-4
    assert all(torch.equal(p, q) for p, q in zip(a.model.parameters(), b.model.parameters()))
