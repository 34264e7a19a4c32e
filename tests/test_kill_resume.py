"""Long jobs killed with SIGKILL: their worker processes die with them, a second writer
into the same folder is refused at once, and a resumed run ends with the very arrays of
an uninterrupted one. The jobs run as `lensim` subprocesses on small sizes."""

from __future__ import annotations

import json
import random
import signal
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_runner import run_cli
from faults import alive, lensim_process, wait_for, workers_of
from lensim.assets.images import sample_image_path
from lensim.images import read_image, write_image
from lensim.restore.run_log import read_csv
from test_train import make_pairs

# a bank whose fields take several seconds each (61 wavelengths): a worker that outlived
# its parent would still be computing long after the kill
SLOW_BANK = [
    "psf",
    "bank",
    "cooke_triplet",
    "--pixel-um",
    "4",
    "--kernel",
    "15",
    "--fields",
    "4",
    "--wavelengths-nm",
    "400:700:5",
    "--pupil-samples",
    "64",
    "--quiet",
]


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_killed_bank_leaves_no_worker_and_a_second_writer_is_refused_meanwhile(tmp_path, capsys, monkeypatch):
    out = tmp_path / "bank"
    proc = lensim_process([*SLOW_BANK, "--workers", "2", "-o", str(out)])
    try:
        assert wait_for(lambda: len(workers_of(proc.pid, "spawn_main")) == 2, 60), proc.stderr
        workers = workers_of(proc.pid, "spawn_main")
        # another bank into the same folder, meanwhile (in this process: no start-up)
        quick = [
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
            "-o",
            str(out),
        ]
        code, _, err = run_cli(quick, capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1, err
        assert str(out) in err and f"pid {proc.pid}" in err and "another lensim run" in err
        time.sleep(0.5)
        assert all(alive(w) for w in workers)  # computing their first fields
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert wait_for(lambda: not any(alive(w) for w in workers), 5.0), "bank workers outlived their parent"


# ----------------------------------------------------------------------------- kill and resume

BANK = [
    "psf",
    "bank",
    "cooke_triplet",
    "--sensor",
    "apsc_mirrorless",
    "--kernel",
    "21",
    "--fields",
    "5",
    "--wavelengths-nm",
    "500:600:100",
    "--pupil-samples",
    "40",
    "--quiet",
]
PAIRS = ["--sensor", "apsc_mirrorless", "--crops", "2", "--size", "64", "--seed", "3", "--quiet"]
TRAIN = [
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
    "--epochs",
    "2",
    "--steps-per-epoch",
    "4",
    "--checkpoint-every-steps",
    "1",
    "--threads",
    "1",
    "--quiet",
]
DEFAULT_SEEDS = [0]
SLOW_SEEDS = [1, 5, 7]  # with seed 0: every kill point 1..total-2 of the bank and the pairs, steps 2-5 of 8


def kill_when(args: list[str], progressed, total: int, seed: int, unit_s: float) -> int:
    """Run `lensim ARGS` in a subprocess and SIGKILL it at a random point inside its work:
    once ``progressed()`` (units of work on disk, ``total`` in all, each about ``unit_s``
    seconds) reaches k, drawn from 1..total-2 with ``seed``, plus a random part of a unit.
    The process is frozen (SIGSTOP) before it is killed, so the units done at the kill are
    known exactly; they must leave work to do (else the kill came too late and the test
    proves nothing). Returns the units done at the kill."""
    rng = random.Random(seed)
    k = rng.randint(1, total - 2)
    proc = lensim_process(args)
    try:
        assert wait_for(lambda: progressed() >= k or proc.poll() is not None, 120, poll_s=0.005)
        time.sleep(rng.uniform(0.0, 0.5 * unit_s))
        proc.send_signal(signal.SIGSTOP)
        done = progressed()
        assert proc.poll() is None and 1 <= done < total, f"killed after {done} of {total} units: too late"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    return done


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Uninterrupted runs (in this process) of the three jobs, and their inputs."""
    base = tmp_path_factory.mktemp("reference")
    sharp = base / "sharp"
    for name in ("kodim23", "coffee", "chelsea", "astronaut"):
        img, _ = read_image(sample_image_path(name))
        write_image(sharp / f"{name}.png", img[:, :256, :320])
    pairs = make_pairs(base / "train-pairs")
    threads = torch.get_num_threads()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert cli([*BANK, "-o", str(base / "bank")]) == 0
            assert (
                cli(["dataset", "make", str(sharp), "-o", str(base / "pairs"), "--bank", str(base / "bank"), *PAIRS])
                == 0
            )
            assert cli(["train", str(pairs), "-o", str(base / "run"), *TRAIN]) == 0
    finally:
        torch.set_num_threads(threads)
    return base


def cli(args: list[str]) -> int:
    """`lensim ARGS` in this process; its exit status."""
    from typer.testing import CliRunner

    from lensim.cli import app

    res = CliRunner().invoke(app, args)
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res.exit_code


def npz_arrays(folder: Path, pattern: str) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for p in sorted(folder.glob(pattern)):
        with np.load(p) as z:
            out[str(p.relative_to(folder))] = {k: z[k] for k in z.files}
    return out


def assert_same_tree(a: Path, b: Path, pattern: str, context: str) -> None:
    """The files matching ``pattern`` under both folders: the same names, the same bytes."""
    names = sorted(p.relative_to(a) for p in a.glob(pattern))
    assert names and names == sorted(p.relative_to(b) for p in b.glob(pattern)), context
    for n in names:
        assert (a / n).read_bytes() == (b / n).read_bytes(), f"{n}, {context}"


def _bank_kill_resume(reference: Path, tmp_path: Path, seed: int) -> None:
    out = tmp_path / "bank"
    fields = kill_when([*BANK, "-o", str(out)], lambda: len(list(out.glob("field_*.npz"))), 5, seed, 0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert cli([*BANK, "-o", str(out)]) == 0
    ref, got = npz_arrays(reference / "bank", "field_*.npz"), npz_arrays(out, "field_*.npz")
    assert list(got) == list(ref), f"killed at {fields} fields"
    for name, arrays in ref.items():
        for key, value in arrays.items():
            np.testing.assert_array_equal(got[name][key], value, err_msg=f"{name}:{key}, killed at {fields} fields")


def _pairs_kill_resume(reference: Path, tmp_path: Path, seed: int) -> None:
    out = tmp_path / "pairs"
    args = ["dataset", "make", str(reference / "sharp"), "-o", str(out), "--bank", str(reference / "bank"), *PAIRS]
    photos = kill_when(args, lambda: len(list((out / "records").glob("*.json"))), 4, seed, 0.05)
    assert cli(args) == 0
    assert_same_tree(reference / "pairs", out, "pairs/*.png", f"killed at {photos} photos")
    assert_same_tree(reference / "pairs", out, "records/*.json", f"killed at {photos} photos")
    assert _manifest(out) == _manifest(reference / "pairs")


def _train_kill_resume(reference: Path, tmp_path: Path, seed: int) -> None:
    run = tmp_path / "run"
    pairs = reference / "train-pairs"
    steps = kill_when(["train", str(pairs), "-o", str(run), *TRAIN], lambda: _rows(run / "steps.csv"), 8, seed, 0.02)
    threads = torch.get_num_threads()
    try:
        code = cli(
            ["train", str(pairs), "-o", str(run), "--resume", "--threads", "1", "--quiet"]
            if (run / "last.pt").exists()
            else ["train", str(pairs), "-o", str(run), *TRAIN]
        )
    finally:
        torch.set_num_threads(threads)
    assert code == 0
    ref = torch.load(reference / "run" / "last.pt", weights_only=True)
    got = torch.load(run / "last.pt", weights_only=True)
    assert got["step"] == ref["step"] == 8, f"killed at step {steps}"
    for key, value in ref["model_state"].items():
        assert torch.equal(got["model_state"][key], value), f"{key}, killed at step {steps}"
    assert _losses(run) == _losses(reference / "run")


def _manifest(pairs: Path) -> dict:
    """A pairs folder's manifest but for the bank folder's path."""
    return {k: v for k, v in json.loads((pairs / "manifest.json").read_text()).items() if k != "bank"}


def _losses(run: Path) -> list[tuple[float, float]]:
    """(step, loss) of every row of a run's steps.csv."""
    return [(r["step"], r["loss"]) for r in read_csv(run / "steps.csv")]


def _rows(path: Path) -> int:
    """Data rows of a CSV log (0 while it does not exist)."""
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except OSError:
        return 0


GRID = [
    "psf",
    "bank",
    "cooke_triplet",
    "--sensor",
    "apsc_mirrorless",
    "--kernel",
    "21",
    "--fields",
    "3",
    "--wavelengths-nm",
    "500:600:100",
    "--pupil-samples",
    "40",
    "--fno",
    "5.6,8",
    "--focus-m",
    "inf,1",
    "--quiet",
]


@pytest.fixture(scope="module")
def reference_grid(tmp_path_factory):
    """An uninterrupted grid of banks (2 F-numbers x 2 focus distances x 3 fields), in this process."""
    out = tmp_path_factory.mktemp("reference-grid") / "grid"
    threads = torch.get_num_threads()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert cli([*GRID, "-o", str(out)]) == 0
    finally:
        torch.set_num_threads(threads)
    return out


def _grid_kill_resume(reference: Path, tmp_path: Path, seed: int, more: tuple[str, ...] = ()) -> None:
    out = tmp_path / "grid"
    args = [*GRID, *more, "-o", str(out)]
    fields = kill_when(args, lambda: len(list(out.glob("s*/field_*.npz"))), 12, seed, 0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert cli(args) == 0
    ref, got = npz_arrays(reference, "s*/field_*.npz"), npz_arrays(out, "s*/field_*.npz")
    assert sorted(got) == sorted(ref) and len(ref) == 12, f"killed at {fields} fields"
    for name, arrays in ref.items():
        for key, value in arrays.items():
            np.testing.assert_array_equal(got[name][key], value, err_msg=f"{name}:{key}, killed at {fields} fields")
    assert_same_tree(reference, out, "**/manifest.json", f"killed at {fields} fields")


def test_killed_grid_resumes_to_the_arrays_of_an_uninterrupted_run(reference_grid, tmp_path):
    _grid_kill_resume(reference_grid, tmp_path, 0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SLOW_SEEDS)
def test_killed_grid_on_dask_workers_resumes_to_the_arrays_of_an_uninterrupted_run(reference_grid, tmp_path, seed):
    _grid_kill_resume(reference_grid, tmp_path, seed, ("--workers", "2"))


JOBS = {"bank": _bank_kill_resume, "pairs": _pairs_kill_resume, "train": _train_kill_resume}


@pytest.mark.parametrize("seed", DEFAULT_SEEDS)
@pytest.mark.parametrize("job", list(JOBS))
def test_killed_job_resumes_to_the_arrays_of_an_uninterrupted_run(reference, tmp_path, job, seed):
    JOBS[job](reference, tmp_path, seed)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SLOW_SEEDS)
@pytest.mark.parametrize("job", list(JOBS))
def test_killed_job_resumes_to_the_arrays_of_an_uninterrupted_run_more_kill_points(reference, tmp_path, job, seed):
    JOBS[job](reference, tmp_path, seed)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_killed_dataset_make_leaves_no_dask_worker(reference, tmp_path):
    sharp = tmp_path / "sharp"
    img, _ = read_image(sample_image_path("kodim23"))
    for k in range(4):  # whole photos: a few seconds each
        write_image(sharp / f"p{k}.png", img)
    args = [
        "dataset",
        "make",
        str(sharp),
        "-o",
        str(tmp_path / "pairs"),
        "--bank",
        str(reference / "bank"),
        "--workers",
        "2",
        *PAIRS,
    ]
    proc = lensim_process(args)
    try:
        assert wait_for(lambda: len(workers_of(proc.pid, "spawn_main")) >= 2, 120)
        workers = workers_of(proc.pid, "spawn_main")
        assert wait_for(lambda: (tmp_path / "pairs" / "pairs").is_dir(), 120)  # photos are being simulated
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert wait_for(lambda: not any(alive(w) for w in workers), 5.0), "Dask workers outlived their parent"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_killed_restore_leaves_no_dask_worker(tmp_path):
    pytest.importorskip("rawpy")
    from lensim.raw.dng import write_capture_dng
    from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
    from lensim.restore.network import FieldAwareUNet
    from test_raw_restore import capture, small_sensor

    torch.manual_seed(0)
    model = FieldAwareUNet(8, 2, zero_init_tail=False).eval()
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": small_sensor().to_dict(),
            "lens": None,
        },
        tmp_path / "run" / "last.pt",
    )
    for k in range(6):  # raws larger than the sensor (restored as full frames of it): seconds each
        raw, params = capture(k, (768, 1024))
        write_capture_dng(tmp_path / "raws" / f"s{k}.dng", raw, small_sensor(), params)
    proc = lensim_process(
        [
            "restore",
            str(tmp_path / "run"),
            str(tmp_path / "raws"),
            "-o",
            str(tmp_path / "out"),
            "--allow-other-camera",
            "--workers",
            "2",
            "--quiet",
        ]
    )
    try:
        assert wait_for(lambda: len(workers_of(proc.pid, "spawn_main")) >= 2, 120), proc.poll()
        workers = workers_of(proc.pid, "spawn_main")
        time.sleep(1.0)  # the workers load the model and restore their first raws
        assert proc.poll() is None, "the restore ended before the kill"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert wait_for(lambda: not any(alive(w) for w in workers), 5.0), "Dask workers outlived their restore"
    assert len(list((tmp_path / "out").glob("*.tif"))) < 6  # killed with raws left to restore
