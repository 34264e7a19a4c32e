"""The fault suite's small jobs and their uninterrupted results, made once per session:
the command line of each long command (psf bank, a grid of banks, dataset make, train,
restore of a folder of raw files) on inputs small enough to run in seconds, and the
folder each writes when nothing goes wrong (the reference a faulted run must match)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from faults import folder_bytes

BANK = [
    "psf",
    "bank",
    "cooke_triplet",
    "--sensor",
    "apsc_mirrorless",
    "--kernel",
    "15",
    "--fields",
    "4",
    "--wavelengths-nm",
    "500:600:100",
    "--pupil-samples",
    "32",
    "--quiet",
]
GRID = [*BANK[:8], "3", *BANK[9:], "--fno", "5.6,8"]  # 2 settings x 3 fields
PAIRS = ["--sensor", "apsc_mirrorless", "--crops", "2", "--size", "32", "--seed", "3", "--quiet"]
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
RAWS = 3


@dataclass(frozen=True)
class FaultWorld:
    """Inputs of the jobs and their uninterrupted outputs."""

    root: Path
    sharp: Path  # 3 photos, 64 x 96
    train_pairs: Path  # a synthetic pairs folder (tests/test_train.make_pairs)
    raws: Path  # RAWS DNGs of a 64 x 48 sensor
    model: Path  # a run folder holding a width-8 UNet's best.pt for that sensor
    bank: Path  # BANK's output
    grid: Path  # GRID's output
    pairs: Path  # dataset make of sharp/ with bank/
    run: Path  # train of train_pairs/
    restored: Path  # restore of raws/ with model/

    def args(self, job: str, out: Path, *more: str) -> list[str]:
        """The command line of ``job`` (bank, grid, pairs, train, restore) writing ``out``."""
        return {
            "bank": [*BANK, "-o", str(out), *more],
            "grid": [*GRID, "-o", str(out), *more],
            "pairs": ["dataset", "make", str(self.sharp), "-o", str(out), "--bank", str(self.bank), *PAIRS, *more],
            "train": ["train", str(self.train_pairs), "-o", str(out), *TRAIN, *more],
            "restore": [
                "restore",
                str(self.model),
                str(self.raws),
                "-o",
                str(out),
                "--allow-other-camera",
                "--threads",
                "1",
                "--quiet",
                *more,
            ],
        }[job]

    def reference(self, job: str) -> Path:
        return {
            "bank": self.bank,
            "grid": self.grid,
            "pairs": self.pairs,
            "train": self.run,
            "restore": self.restored,
        }[job]

    def size(self, job: str) -> int:
        """Bytes the job's output folder holds when it is done."""
        return folder_bytes(self.reference(job))


def cli(args: list[str]) -> int:
    """`lensim ARGS` in this process (its torch thread count kept); its exit status."""
    from typer.testing import CliRunner

    from lensim.cli import app

    threads = torch.get_num_threads()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = CliRunner().invoke(app, args)
    finally:
        torch.set_num_threads(threads)
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res.exit_code


def _inputs(root: Path) -> tuple[Path, Path, Path, Path]:
    from lensim.assets.images import sample_image_path
    from lensim.images import read_image, write_image
    from lensim.raw.dng import write_capture_dng
    from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
    from lensim.restore.network import FieldAwareUNet
    from test_raw_restore import capture, small_sensor
    from test_train import make_pairs

    sharp = root / "sharp"
    for name in ("kodim23", "coffee", "chelsea"):
        img, _ = read_image(sample_image_path(name))
        write_image(sharp / f"{name}.png", img[:, :64, :96])
    train_pairs = make_pairs(root / "train-pairs")
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
        root / "model" / "best.pt",
    )
    for k in range(RAWS):
        raw, params = capture(k, (48, 64))
        write_capture_dng(root / "raws" / f"s{k}.dng", raw, small_sensor(), params)
    return sharp, train_pairs, root / "raws", root / "model"


def build_fault_world(root: Path) -> FaultWorld:
    """Make the inputs and run every job once, uninterrupted (about 10 s)."""
    sharp, train_pairs, raws, model = _inputs(root)
    world = FaultWorld(
        root, sharp, train_pairs, raws, model, root / "bank", root / "grid", root / "pairs", root / "run", root / "out"
    )
    for job in ("bank", "grid", "pairs", "train", "restore"):
        assert cli(world.args(job, world.reference(job))) == 0, job
    return world


# ----------------------------------------------------------------------------- comparing


def npz_arrays(folder: Path, pattern: str) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for p in sorted(folder.glob(pattern)):
        with np.load(p) as z:
            out[str(p.relative_to(folder))] = {k: z[k] for k in z.files}
    return out


def same_files(a: Path, b: Path, pattern: str) -> list[str]:
    """Files matching ``pattern`` that differ between the folders (or are missing in one)."""
    names = sorted({str(p.relative_to(a)) for p in a.glob(pattern)} | {str(p.relative_to(b)) for p in b.glob(pattern)})
    return [
        n
        for n in names
        if not ((a / n).is_file() and (b / n).is_file() and (a / n).read_bytes() == (b / n).read_bytes())
    ]


def _losses(run: Path) -> list[tuple[str, str]]:
    from lensim.restore.run_log import read_csv

    return [(r["step"], r["loss"]) for r in read_csv(run / "steps.csv")]


def differences(job: str, reference: Path, out: Path) -> list[str]:
    """What differs between a job's output and its uninterrupted reference: for banks the
    arrays of every field file (and the grid's manifests), for pairs and restored raws the
    bytes of every output, for a training run its last checkpoint's step and weights and
    its per-step losses. Empty when they are the same."""
    if job in ("bank", "grid"):
        pattern = "field_*.npz" if job == "bank" else "s*/field_*.npz"
        ref, got = npz_arrays(reference, pattern), npz_arrays(out, pattern)
        diff = sorted(set(ref) ^ set(got))
        diff += [
            f"{n}:{k}" for n in set(ref) & set(got) for k in ref[n] if not np.array_equal(ref[n][k], got[n].get(k))
        ]
        return diff + (same_files(reference, out, "**/manifest.json") if job == "grid" else [])
    if job == "pairs":
        return same_files(reference, out, "pairs/*.png") + same_files(reference, out, "records/*.json")
    if job == "restore":
        return same_files(reference, out, "*.tif")
    ref = torch.load(reference / "last.pt", weights_only=True)
    if not (out / "last.pt").is_file():
        return ["last.pt"]
    got = torch.load(out / "last.pt", weights_only=True)
    diff = [] if got["step"] == ref["step"] else [f"step {got['step']} != {ref['step']}"]
    diff += [k for k, v in ref["model_state"].items() if not torch.equal(got["model_state"][k], v)]
    return diff + ([] if _losses(out) == _losses(reference) else ["steps.csv losses"])
