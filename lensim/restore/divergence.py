"""NaN or Inf in training (a poisoned batch, an exploding learning rate): detected at the
step it appears, never written into a checkpoint, and answered by TrainConfig.on_nan.

Detection: a step whose loss is not finite is not taken (no backward, no optimizer step;
under torchrun every rank agrees, so none waits for the others); a checkpoint is written
only when every weight is finite, so RUN/last.pt and RUN/best.pt always hold finite
weights (:func:`check_weights`). Non-finite weights (an infinite gradient with a finite
loss) show at the next step's loss or at the next checkpoint.

Answers (:func:`answer`): ``"rollback"`` (the default) puts the run back to its last good
checkpoint (RUN/last.pt, or the state it started from when it has none yet): model,
optimizer, schedule, position and random state, the CSV logs cut back to that step; the
batch at which the loss went bad is then skipped (recorded in TrainingState.skipped and in
every later checkpoint, so a resumed run skips it too), and training goes on, a warning
naming the step. Bad steps that keep coming back (more than MAX_ROLLBACKS rollbacks
without a checkpoint past the step rolled back to: an exploding learning rate) end the run with a
:class:`lensim.errors.NonFiniteError`, as ``"stop"`` does at the first one; the run folder
keeps its last good checkpoint, from which ``train(..., resume=True)`` continues.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from lensim.errors import NonFiniteError

#: TrainConfig.on_nan's choices
ON_NAN = ("rollback", "stop")
#: rollbacks in a row (no checkpoint written between them) before the run is stopped
MAX_ROLLBACKS = 3


class NonFinite(Exception):
    """A non-finite loss or weights at the current step (raised inside the loop)."""

    def __init__(self, what: str, value: float) -> None:
        super().__init__(f"{what} {value}")
        self.what, self.value = what, value


def check_loss(loss: torch.Tensor, agree: Any = None) -> None:
    """Raise NonFinite when the loss is NaN or infinite; ``agree(flag) -> flag``, when
    given, makes every rank of a distributed run see a bad loss on any rank."""
    bad = not bool(torch.isfinite(loss.detach()).all())
    if agree is not None:
        bad = agree(bad)
    if bad:
        raise NonFinite("loss", float(loss.detach().float().mean()) if loss.numel() else math.nan)


def check_weights(model: torch.nn.Module) -> None:
    """Raise NonFinite when a weight (parameter or floating-point buffer) is not finite."""
    for tensor in (*model.parameters(), *model.buffers()):
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise NonFinite("weights", math.nan)


@dataclass
class Rollbacks:
    """Where a run rolls back to and how often it did in a row. ``origin``: the checkpoint
    dict of the state the run started from (a copy), used while RUN/last.pt does not exist."""

    run: Path
    origin: dict[str, Any] | None
    in_a_row: int = 0
    back_to: int = -1  # the step of the checkpoint last rolled back to

    @classmethod
    def start(cls, run: Path, start_checkpoint: dict[str, Any] | None) -> Rollbacks:
        """For a run starting now; ``start_checkpoint`` (its state as a checkpoint dict) is
        kept, copied, only while the run has no RUN/last.pt."""
        from lensim.restore.checkpoint import LAST

        keep = None if (run / LAST).exists() or start_checkpoint is None else copy.deepcopy(start_checkpoint)
        return cls(run, keep)

    def checkpoint_written(self, step: int) -> None:
        """A checkpoint was written at ``step``: past the last rollback's, the run is making
        progress again (a checkpoint at the same step, an epoch's end, is none)."""
        if step > self.back_to:
            self.in_a_row = 0

    def good_checkpoint(self) -> tuple[dict[str, Any], str]:
        """(the last good checkpoint, where it is: RUN/last.pt or the run's start)."""
        from lensim.restore.checkpoint import LAST, read_checkpoint

        path = self.run / LAST
        if path.is_file():
            return read_checkpoint(path), str(path)
        assert self.origin is not None, "a run without last.pt keeps the state it started from"
        return self.origin, "the start of the run"


def answer(bad: NonFinite, on_nan: str, rollbacks: Rollbacks, where: dict[str, Any]) -> dict[str, Any]:
    """What to do about ``bad``, met at ``where`` (step, epoch, batch, batches, lr: the
    step being taken, 1-based, and the epoch and batch it is in, 0-based): a
    NonFiniteError naming the step when the run is to stop, else the checkpoint dict to
    roll back to (a warning names the step and the checkpoint)."""
    ckpt, source = rollbacks.good_checkpoint()
    what = "the weights are not finite" if bad.what == "weights" else f"the {bad.what} is {bad.value}"
    at = f"epoch {where['epoch'] + 1}, batch {where['batch'] + 1} of {where['batches']}"
    at += f", learning rate {where['lr']:.3g}"
    kept = f"the run keeps its last good checkpoint (step {int(ckpt.get('step', 0))}, {source})"
    step = f"step {where['step']}"
    if on_nan == "stop":
        raise NonFiniteError(str(rollbacks.run), step, f"{what} ({at}); {kept}")
    if rollbacks.in_a_row >= MAX_ROLLBACKS:
        raise NonFiniteError(
            str(rollbacks.run),
            step,
            f"{what} ({at}) again after {rollbacks.in_a_row} rollbacks in a row: training diverges; {kept}",
        )
    rollbacks.in_a_row += 1
    rollbacks.back_to = int(ckpt.get("step", 0))
    warnings.warn(
        f"{rollbacks.run}: {step}: {what} ({at}); rolled back to step {int(ckpt.get('step', 0))} ({source}) "
        "and skipping that batch",
        RuntimeWarning,
        stacklevel=3,
    )
    return ckpt


def roll_back(loop: Any, bad: NonFinite, batches: int, history: list[dict[str, Any]]) -> None:
    """Answer a non-finite loss or weights met by a training loop (lensim.restore.train's
    _Loop: state, cfg, lr, ranks, rollbacks, log, run, clock) in an epoch of ``batches``
    batches: raise a NonFiniteError (on_nan "stop", or too many rollbacks in a row), or
    put the run back to its last good checkpoint with the bad batch marked skipped, its
    logs and ``history`` (the epochs' log rows) cut back to that checkpoint's step."""
    state = loop.state
    loss = bad.what == "loss"  # a bad loss is the batch being taken; bad weights come from the last one
    epoch, batch = state.epoch, state.batch_in_epoch
    if not loss:
        epoch, batch = (epoch, batch - 1) if batch else (max(epoch - 1, 0), batches - 1)
    where = {"step": state.step + loss, "epoch": epoch, "batch": batch, "batches": batches, "lr": loop.lr.lr}
    on_nan = loop.cfg.on_nan if loss or loop.ranks.world == 1 else "stop"  # weights are checked on rank 0 only
    ckpt = answer(bad, on_nan, loop.rollbacks, where)
    skipped = state.skipped | {(epoch, batch)}
    state.resume_from(ckpt, str(loop.run))
    state.skipped |= skipped
    state.model.train()
    if loop.log is not None:
        loop.log.rewind(state.step)
    history[:] = [r for r in history if r["step"] <= state.step]
    loop.checkpoint_s, loop.checkpoint_step = loop.clock.call_s(), state.step


__all__ = ["MAX_ROLLBACKS", "ON_NAN", "NonFinite", "Rollbacks", "answer", "check_loss", "check_weights", "roll_back"]
