"""Batches of training: the data order of each epoch (a permutation drawn from the seed
and the epoch only, so a resumed run sees the very same batches), a batch's network
arguments, and the validation metrics over a loader (lensim.restore.train uses them)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import torch
from torch.utils.data import DataLoader

from lensim.evaluate.metrics import psnr_batch, ssim_batch


def epoch_order(n: int, seed: int, epoch: int) -> list[int]:
    """The permutation of item indices for one epoch (depends only on n, seed, epoch)."""
    gen = torch.Generator().manual_seed((seed * 1_000_003 + epoch * 7919 + 12345) % (2**63))
    return torch.randperm(n, generator=gen).tolist()


def epoch_batches(
    n: int, batch_size: int, seed: int, epoch: int, rank: int = 0, world: int = 1, max_batches: int | None = None
) -> list[list[int]]:
    """Batches of one epoch for one rank: the epoch's permutation, padded (by wrapping) to
    a multiple of world so ranks get equal shares, strided by rank, cut into batches;
    a last partial batch is dropped unless it is the only one."""
    order = epoch_order(n, seed, epoch)
    if world > 1:
        pad = (-len(order)) % world
        order = (order + order[:pad])[rank::world]
    nb = max(1, len(order) // batch_size)
    batches = [order[i * batch_size : (i + 1) * batch_size] for i in range(nb)]
    return batches[:max_batches] if max_batches else batches


def model_inputs(batch: dict[str, torch.Tensor], device: torch.device) -> tuple[torch.Tensor, ...]:
    """A batch's network arguments on ``device``: (input, fov), with (input, fov, settings)
    when the batch carries settings vectors, and (input, fov, settings or None, wiener) when
    it carries the Wiener stage's images (the PSF-informed network)."""
    args: tuple[torch.Tensor | None, ...] = (
        batch["input"].to(device, non_blocking=True),
        batch["fov"].to(device, non_blocking=True),
    )
    if "settings" in batch or "wiener" in batch:
        args += (batch["settings"].to(device, non_blocking=True) if "settings" in batch else None,)
    if "wiener" in batch:
        args += (batch["wiener"].to(device, non_blocking=True),)
    return args  # type: ignore[return-value]


def collate(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Items of a PairDataset stacked into a batch (index: a tensor of the indices)."""
    return {
        k: torch.stack([it[k] for it in items]) if k != "index" else torch.tensor([it[k] for it in items])
        for k in items[0]
    }


#: evaluate_pairs' figures of the input crops themselves (the same for any model)
INPUT_METRICS = ("input_psnr", "input_ssim")


@torch.no_grad()
def evaluate_pairs(
    model: torch.nn.Module,
    loader: Iterator[dict[str, torch.Tensor]] | DataLoader,
    device: torch.device,
    input_metrics: dict[str, float] | None = None,
) -> dict[str, float]:
    """Mean PSNR (dB) and SSIM over crops of the restored output ("psnr", "ssim") and of
    the input itself ("input_psnr", "input_ssim"; outputs clamped to [0, 1] as when written
    to a file). input_metrics: those two of an earlier call on the same crops, returned
    as given instead of computed again (a validation set's input does not change)."""
    was_training = model.training
    model.eval()
    tot = {"psnr": 0.0, "ssim": 0.0, "input_psnr": 0.0, "input_ssim": 0.0}
    n = 0
    for batch in loader:
        args = model_inputs(batch, device)
        inp = args[0]
        tgt = batch["target"].to(device)
        out = model(*args).float().clamp(0, 1)
        tot["psnr"] += float(psnr_batch(out, tgt).clamp(max=100.0).sum())
        tot["ssim"] += float(ssim_batch(out, tgt).sum())
        if input_metrics is None:
            tot["input_psnr"] += float(psnr_batch(inp, tgt).clamp(max=100.0).sum())
            tot["input_ssim"] += float(ssim_batch(inp, tgt).sum())
        n += inp.shape[0]
    model.train(was_training)
    metrics = {k: v / n for k, v in tot.items()} if n else {k: math.nan for k in tot}
    if input_metrics is not None:
        metrics.update({k: input_metrics[k] for k in INPUT_METRICS})
    return metrics


__all__ = ["INPUT_METRICS", "collate", "epoch_batches", "epoch_order", "evaluate_pairs", "model_inputs"]
