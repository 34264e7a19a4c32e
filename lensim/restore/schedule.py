"""The learning rate of every training step, and the one clock of a run's time budget.

Schedules (``TrainConfig.lr_schedule``):
    "step"    the paper's: ``lr`` halved every ``lr_halve_every`` epochs (torch StepLR,
              stepped after each completed epoch);
    "cosine"  ``lr * (1 + cos(pi p)) / 2`` set before every step, at progress p in [0, 1]:
              the share of the time budget spent when one is set, else of the epochs
              (the better choice for a fixed wall-clock budget, where a step schedule
              decays too early or too late).

The budget clock counts the seconds a run has trained in all: those of the calls before a
resume (stored in the checkpoint) plus those of this call (time.perf_counter).
"""

from __future__ import annotations

import math
import time

import torch

LR_SCHEDULES = ("step", "cosine")


def cosine_lr(lr0: float, progress: float) -> float:
    """Half-cosine annealing: lr0 at progress 0, 0 at progress >= 1."""
    return lr0 * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


class BudgetClock:
    """Seconds trained by this call and by the whole run, against an optional budget.

    Args:
        budget_s: stop once the run has trained this many seconds (None: no limit).
        seconds_before: seconds trained by the calls before a resume.
    """

    def __init__(self, budget_s: float | None, seconds_before: float = 0.0) -> None:
        self.budget_s = budget_s
        self.seconds_before = seconds_before
        self.start = time.perf_counter()

    def call_s(self) -> float:
        """Seconds since this call started."""
        return time.perf_counter() - self.start

    def run_s(self) -> float:
        """Seconds this run has trained, the calls before a resume included."""
        return self.seconds_before + self.call_s()

    def spent(self) -> bool:
        """Whether the budget is used up (never without one)."""
        return self.budget_s is not None and self.run_s() >= self.budget_s


class LearningRate:
    """Sets the optimizer's learning rate for a schedule (module docstring).

    ``scheduler`` (a StepLR, present for both schedules) is what checkpoints store.
    """

    def __init__(
        self, optimizer: torch.optim.Optimizer, schedule: str, lr0: float, halve_every: int, epochs: int
    ) -> None:
        self.optimizer = optimizer
        self.schedule = schedule
        self.lr0 = lr0
        self.epochs = epochs
        self.scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=halve_every, gamma=0.5)

    @property
    def lr(self) -> float:
        """The learning rate the next step uses."""
        return float(self.optimizer.param_groups[0]["lr"])

    def before_step(self, clock: BudgetClock, epoch: int, batch: int, batches: int) -> None:
        """Set the cosine rate for batch ``batch`` of ``batches`` in epoch ``epoch`` (0-based):
        progress along the budget of ``clock`` when it has one, else along the epochs."""
        if self.schedule != "cosine":
            return
        if clock.budget_s:
            progress = clock.run_s() / clock.budget_s
        else:
            progress = (epoch + batch / max(batches, 1)) / self.epochs
        for group in self.optimizer.param_groups:
            group["lr"] = cosine_lr(self.lr0, progress)

    def after_epoch(self) -> None:
        """Advance the step schedule past a completed epoch."""
        if self.schedule == "step":
            self.scheduler.step()


__all__ = ["LR_SCHEDULES", "BudgetClock", "LearningRate", "cosine_lr"]
