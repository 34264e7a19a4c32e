"""The text records of a training run (written by rank 0 only).

    RUN/config.json   the training settings and the dataset folder
    RUN/split.json    train/validation source photos
    RUN/log.csv       one row per epoch (and one when stopped early): LOG_FIELDS
    RUN/steps.csv     one row per optimizer step: STEP_FIELDS
    RUN/tb/           TensorBoard events, only when torch.utils.tensorboard imports

On a resume the CSV files keep their rows up to the checkpoint's step and drop newer ones
(written after the checkpoint by the call that was interrupted), so they hold exactly the
rows of an uninterrupted run. Floats are written with repr (exact), NaN and None as empty.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

from lensim.data.manifest import SPLIT
from lensim.io import append_text, atomic_write_json, atomic_write_text

LOG_FIELDS = ("epoch", "step", "loss", "val_psnr", "val_ssim", "lr", "seconds")
STEP_FIELDS = ("epoch", "step", "loss", "lr", "seconds")


def _cell(value: Any) -> Any:
    """A CSV cell: floats exactly (repr), NaN and None empty."""
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return "" if value is None else value


class CsvLog:
    """Append-only CSV that, on resume, drops rows newer than the checkpoint's step. The
    header and the rows kept are written atomically; each new row is appended whole or
    not at all (a log grows by one line per step; a crash or a full disk loses at most
    the line being written, never leaves half of it)."""

    def __init__(self, path: Path, fields: tuple[str, ...], keep_until_step: int | None) -> None:
        self.path = path
        self.fields = fields
        rows: list[dict[str, str]] = []
        if keep_until_step is not None and path.exists():
            with open(path, newline="") as fh:
                rows = [
                    r for r in csv.DictReader(fh) if r.get("step", "").isdigit() and int(r["step"]) <= keep_until_step
                ]
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_text(path, text.getvalue())

    def write(self, row: dict[str, Any]) -> None:
        """Append one row, whole or not at all (lensim.io.append_text)."""
        text = io.StringIO(newline="")
        csv.DictWriter(text, fieldnames=self.fields).writerow({k: _cell(row.get(k)) for k in self.fields})
        append_text(self.path, text.getvalue())


def read_csv(path: str | Path) -> list[dict[str, float]]:
    """Rows of a log CSV with numbers parsed (empty cells -> nan)."""
    with open(path, newline="") as fh:
        return [{k: float(v) if v != "" else math.nan for k, v in r.items()} for r in csv.DictReader(fh)]


class RunLog:
    """config.json, split.json, steps.csv, log.csv and TensorBoard events of one run.

    Args:
        run: the run folder (created).
        config: the settings to record in config.json.
        split: the train/validation split to record in split.json.
        resumed_at_step: the checkpoint's step when resuming (newer rows are dropped), or
            None for a new run.
    """

    def __init__(self, run: Path, config: dict[str, Any], split: dict[str, Any], resumed_at_step: int | None) -> None:
        run.mkdir(parents=True, exist_ok=True)
        atomic_write_json(run / "config.json", config)
        atomic_write_json(run / SPLIT, split)
        self.run = run
        self.tensorboard: Any = None
        self.rewind(resumed_at_step)

    def rewind(self, step: int | None) -> None:
        """Drop the rows (and TensorBoard events) newer than ``step`` (None: a new run, all
        of them): after a resume, or a rollback to the checkpoint of that step."""
        self.steps = CsvLog(self.run / "steps.csv", STEP_FIELDS, step)
        self.epochs = CsvLog(self.run / "log.csv", LOG_FIELDS, step)
        if self.tensorboard is not None:
            self.tensorboard.close()
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.tensorboard = SummaryWriter(str(self.run / "tb"), purge_step=step)
        except Exception:  # tensorboard is optional
            self.tensorboard = None

    def step(self, epoch: int, step: int, loss: float, lr: float, seconds: float) -> None:
        """One optimizer step: epoch (0-based), global step, loss (MSE), lr, seconds of this call."""
        self.steps.write({"epoch": epoch, "step": step, "loss": loss, "lr": lr, "seconds": seconds})
        if self.tensorboard is not None:
            self.tensorboard.add_scalar("train/loss", loss, step)

    def epoch(self, row: dict[str, Any]) -> None:
        """One validation: a row of LOG_FIELDS (val_psnr in dB)."""
        self.epochs.write(row)
        if self.tensorboard is not None:
            self.tensorboard.add_scalar("val/psnr", row["val_psnr"], row["step"])
            self.tensorboard.add_scalar("val/ssim", row["val_ssim"], row["step"])

    def close(self) -> None:
        if self.tensorboard is not None:
            self.tensorboard.close()


__all__ = ["LOG_FIELDS", "STEP_FIELDS", "CsvLog", "RunLog", "read_csv"]
