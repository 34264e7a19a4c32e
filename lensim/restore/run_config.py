"""The settings of a training run (lensim.restore.train): a new run's TrainConfig with the
caller's overrides, checked; a resumed run's from its checkpoint, with only the settings
outside FROZEN_ON_RESUME allowed to change."""

from __future__ import annotations

import contextlib
from dataclasses import asdict, replace
from typing import Any

from lensim.errors import InputError
from lensim.restore.config import TrainConfig
from lensim.restore.divergence import ON_NAN
from lensim.restore.losses import LOSSES
from lensim.restore.models import ARCHS
from lensim.restore.schedule import LR_SCHEDULES

# Settings that must not change when resuming (they would change the loss curve's meaning).
FROZEN_ON_RESUME = (
    "loss",
    "batch_size",
    "lr",
    "lr_halve_every",
    "lr_schedule",
    "crop",
    "arch",
    "width",
    "depth",
    "use_fov",
    "use_deformable",
    "use_context",
    "deformable_groups",
    "deformable_scales",
    "field_modulation",
    "stem",
    "seed",
    "augment",
    "val_fraction",
    "max_steps_per_epoch",
    "use_settings",
    "conditioning",
)


def resolve_config(
    config: TrainConfig | None, overrides: dict[str, Any], ckpt: dict[str, Any] | None, source: str
) -> TrainConfig:
    """The run's settings: ``config`` with ``overrides``, resolved (TrainConfig.resolved:
    the architecture's defaults filled in, as RUN/config.json and checkpoints record them).
    When resuming, every setting comes from the checkpoint (``config`` is not used) and
    ``overrides`` change only those outside FROZEN_ON_RESUME (a value of a frozen one that
    resolves differently is an InputError naming ``source``), so a resumed run keeps its
    epochs and time budget unless told otherwise. Checked before any work starts."""
    if ckpt is None:
        cfg = TrainConfig(**{**asdict(config or TrainConfig()), **overrides})
    else:
        saved = saved_config(ckpt["train_config"])
        diff = frozen_differences(saved, overrides)
        if diff:
            raise InputError(
                source,
                ", ".join(diff),
                f"differs from the run being resumed "
                f"({', '.join(f'{k}={getattr(saved, k)!r}' for k in diff)}); expected the same value "
                "or none",
            )
        cfg = replace(saved, **{k: v for k, v in overrides.items() if k not in FROZEN_ON_RESUME})
    if cfg.epochs < 1 or cfg.batch_size < 1 or cfg.lr <= 0 or cfg.lr_halve_every < 1:
        raise InputError(
            None,
            "config",
            f"expected epochs, batch_size, lr_halve_every >= 1 and lr > 0, got "
            f"epochs={cfg.epochs}, batch_size={cfg.batch_size}, lr={cfg.lr}, "
            f"lr_halve_every={cfg.lr_halve_every}",
        )
    if cfg.lr_schedule not in LR_SCHEDULES:
        raise InputError(None, "lr_schedule", f"expected one of {', '.join(LR_SCHEDULES)}, got {cfg.lr_schedule!r}")
    if cfg.loss not in LOSSES:
        raise InputError(None, "loss", f"expected one of {', '.join(LOSSES)}, got {cfg.loss!r}")
    if cfg.arch not in ARCHS:
        raise InputError(None, "arch", f"expected one of {', '.join(ARCHS)}, got {cfg.arch!r}")
    if cfg.on_nan not in ON_NAN:
        raise InputError(None, "on_nan", f"expected one of {', '.join(ON_NAN)}, got {cfg.on_nan!r}")
    return cfg.resolved()


def saved_config(train_config: dict[str, Any]) -> TrainConfig:
    """A checkpoint's TrainConfig, resolved. A setting the checkpoint predates had its
    default value there; a checkpoint without "arch" holds the paper's UNet (written before
    there was a choice: lensim.restore.models.arch_of), whose missing switches resolve to
    the UNet's defaults (stem 1)."""
    known = set(asdict(TrainConfig()))
    return TrainConfig(
        **{**asdict(TrainConfig()), "arch": "unet", **{k: v for k, v in train_config.items() if k in known}}
    ).resolved()


def frozen_differences(saved: TrainConfig, overrides: dict[str, Any]) -> list[str]:
    """The FROZEN_ON_RESUME settings among ``overrides`` that differ from the resolved
    ``saved`` run's once resolved themselves (``stem=0`` or ``use_context=None`` ask for
    the architecture's default, which is no change when it is the run's value)."""
    given = {k: overrides[k] for k in FROZEN_ON_RESUME if k in overrides}
    want = replace(saved, **given)
    with contextlib.suppress(InputError):  # a combination the network refuses: compare as given
        want = want.resolved()
    return [k for k in given if getattr(want, k) != getattr(saved, k)]
