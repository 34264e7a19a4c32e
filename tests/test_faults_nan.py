"""NaN or Inf in training: a poisoned batch (one crop whose input is NaN) or an exploding
learning rate. Training detects the non-finite loss at the step it appears, says which
step, and rolls back to the last good checkpoint (skipping the batch), or with --on-nan
stop ends in one line; a checkpoint with non-finite weights is never written, as last.pt
or as best.pt."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from cli_runner import run_cli
from fault_world import TRAIN, cli
from faults import one_line_error

pytestmark = pytest.mark.usefixtures("one_torch_thread")

POISONED = 1  # the training item whose input is NaN


def _poison(monkeypatch, item: int = POISONED) -> None:
    from lensim.restore.dataset import PairDataset

    real = PairDataset.__getitem__

    def getitem(self, i):
        out = real(self, i)
        if i == item and self.augment:  # the training set's item (validation has no augmentation)
            out["input"] = torch.full_like(out["input"], math.nan)
        return out

    monkeypatch.setattr(PairDataset, "__getitem__", getitem)


def _finite(path: Path) -> bool:
    ckpt = torch.load(path, weights_only=True)
    return all(bool(torch.isfinite(v).all()) for v in ckpt["model_state"].values() if v.is_floating_point())


def _losses(run: Path) -> list[float]:
    from lensim.restore.run_log import read_csv

    return [float(r["loss"]) for r in read_csv(run / "steps.csv")]


def test_a_poisoned_batch_is_rolled_back_and_skipped(fault_world, tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    _poison(monkeypatch)
    code, _, err = run_cli(["train", str(fault_world.train_pairs), "-o", str(run), *TRAIN], capsys, monkeypatch)
    assert code == 0, err
    assert "Traceback" not in err
    warned = [line for line in err.splitlines() if "rolled back" in line]
    assert warned and all(line.startswith("warning: ") and " step " in line for line in warned), err
    assert _finite(run / "last.pt") and _finite(run / "best.pt")
    assert torch.load(run / "last.pt", weights_only=True)["step"] < 8  # the poisoned steps were skipped
    assert all(math.isfinite(v) for v in _losses(run))


def test_a_poisoned_batch_with_on_nan_stop_ends_in_one_line_naming_the_step(fault_world, tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    _poison(monkeypatch)
    code, _, err = run_cli(
        ["train", str(fault_world.train_pairs), "-o", str(run), *TRAIN, "--on-nan", "stop"], capsys, monkeypatch
    )
    line = one_line_error(err)
    assert code == 2 and "step" in line and "nan" in line.lower(), err
    assert _finite(run / "last.pt") and (not (run / "best.pt").exists() or _finite(run / "best.pt"))
    print(line)
    monkeypatch.undo()
    assert cli(["train", str(fault_world.train_pairs), "-o", str(run), "--resume", "--threads", "1", "--quiet"]) == 0
    assert _finite(run / "last.pt") and torch.load(run / "last.pt", weights_only=True)["step"] == 8


def test_an_exploding_learning_rate_stops_in_one_line_naming_the_step_and_the_rate(
    fault_world, tmp_path, capsys, monkeypatch
):
    run = tmp_path / "run"
    args = ["train", str(fault_world.train_pairs), "-o", str(run), *TRAIN, "--lr", "1e30"]
    code, _, err = run_cli(args, capsys, monkeypatch)
    line = one_line_error(err)
    assert code == 2 and "step" in line and "--lr" in line, err
    for name in ("last.pt", "best.pt"):
        assert not (run / name).exists() or _finite(run / name), name
