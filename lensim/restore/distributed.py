"""Multi-process training (torchrun / DistributedDataParallel) and mixed precision.

Launch with ``torchrun --nproc_per_node N -m lensim train ...``: when WORLD_SIZE > 1 a
process group is initialised (NCCL on CUDA, Gloo on CPU), the model is wrapped in
DistributedDataParallel, each rank takes every N-th item of the epoch's permutation, the
batch size is per rank, and rank 0 alone validates and writes files. With one process
every helper here is a no-op.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from lensim.errors import InputError


@dataclass
class Ranks:
    """This process's place among the training processes. created_group: whether
    :func:`init_distributed` created the process group (and :func:`shutdown` ends it)."""

    world: int = 1
    rank: int = 0
    local_rank: int = 0
    created_group: bool = False

    @property
    def main(self) -> bool:
        """Rank 0: the one that validates and writes files."""
        return self.rank == 0


def init_distributed(device: str) -> tuple[Ranks, str]:
    """(ranks, this rank's device) from torchrun's environment (WORLD_SIZE, RANK,
    LOCAL_RANK); on CUDA each rank takes the GPU of its local rank."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Ranks(), device
    import torch.distributed as dist

    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    created = False
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.startswith("cuda") else "gloo")
        created = True
    if device.startswith("cuda"):
        torch.cuda.set_device(local)
        device = f"cuda:{local}"
    return Ranks(world, rank, local, created), device


def wrap_model(model: torch.nn.Module, ranks: Ranks, device: torch.device) -> torch.nn.Module:
    """The module the training steps call: DistributedDataParallel(model) under several
    ranks, else the model itself."""
    if ranks.world <= 1:
        return model
    from torch.nn.parallel import DistributedDataParallel

    return DistributedDataParallel(model, device_ids=[ranks.local_rank] if device.type == "cuda" else None)


def mean_over_ranks(value: float, ranks: Ranks, device: torch.device) -> float:
    """The mean of ``value`` over all ranks (``value`` itself for one process)."""
    if ranks.world <= 1:
        return value
    import torch.distributed as dist

    t = torch.tensor([value], device=device)
    dist.all_reduce(t)
    return float(t) / ranks.world


def rank0_decides(flag: bool, ranks: Ranks, device: torch.device) -> bool:
    """Rank 0's ``flag`` on every rank (so all ranks stop at the same step)."""
    if ranks.world <= 1:
        return flag
    import torch.distributed as dist

    t = torch.tensor([int(flag)], device=device)
    dist.broadcast(t, 0)
    return bool(t)


def barrier(ranks: Ranks) -> None:
    """Wait for every rank (no-op for one process)."""
    if ranks.world > 1:
        import torch.distributed as dist

        dist.barrier()


def shutdown(ranks: Ranks) -> None:
    """End the process group if :func:`init_distributed` created it."""
    if ranks.created_group:
        import torch.distributed as dist

        dist.destroy_process_group()


def checked_device(name: str) -> torch.device:
    """The torch device ``name`` ("cpu", "cuda" or "cuda:N"); a CUDA device on a machine
    without CUDA is an InputError naming the parameter ``device``."""
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(None, "device", f"{name!r} requested but CUDA is not available; expected 'cpu'")
    try:
        return torch.device(name)
    except RuntimeError:
        raise InputError(None, "device", f"expected cpu, cuda or cuda:N, got {name!r}") from None


def mixed_precision(device: torch.device, enabled: bool) -> tuple[torch.dtype | None, torch.amp.GradScaler]:
    """(autocast dtype or None, grad scaler) of a training run: :func:`amp_dtype`, and a
    scaler that acts only for float16 (a no-op otherwise)."""
    autocast = amp_dtype(device, enabled)
    return autocast, torch.amp.GradScaler("cuda", enabled=autocast == torch.float16)


def amp_dtype(device: torch.device, enabled: bool) -> torch.dtype | None:
    """Autocast dtype for mixed precision on CUDA (bfloat16 where supported, else
    float16), or None (CPU, or disabled)."""
    if device.type != "cuda" or not enabled:
        return None
    return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16


__all__ = [
    "Ranks",
    "amp_dtype",
    "checked_device",
    "barrier",
    "init_distributed",
    "mean_over_ranks",
    "mixed_precision",
    "rank0_decides",
    "shutdown",
    "wrap_model",
]
