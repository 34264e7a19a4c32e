"""Normalized pupil sampling patterns (points in the unit disc)."""

from __future__ import annotations

import math

import torch

from lensim.optics.trace import DTYPE


def square_grid(n: int, device=None) -> torch.Tensor:
    """Points of an n x n grid over [-1, 1]^2 that fall inside the unit disc, (P, 2).

    Cell centres, so no point lies exactly on the rim and the grid is symmetric.
    """
    if n < 1:
        raise ValueError("square_grid needs n >= 1")
    g = (torch.arange(n, dtype=DTYPE, device=device) + 0.5) / n * 2.0 - 1.0
    x, y = torch.meshgrid(g, g, indexing="xy")
    inside = x * x + y * y <= 1.0
    return torch.stack([x[inside], y[inside]], -1)


def square_grid_full(n: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """All n x n cell centres over [-1, 1]^2, (n*n, 2), and the inside-the-disc mask (n*n,)."""
    g = (torch.arange(n, dtype=DTYPE, device=device) + 0.5) / n * 2.0 - 1.0
    x, y = torch.meshgrid(g, g, indexing="xy")
    pts = torch.stack([x.reshape(-1), y.reshape(-1)], -1)
    return pts, (pts * pts).sum(-1) <= 1.0


def hexapolar(rings: int, device=None) -> torch.Tensor:
    """Centre point plus `rings` rings with 6, 12, 18, ... points, (P, 2)."""
    pts = [(0.0, 0.0)]
    for i in range(1, rings + 1):
        r = i / rings
        for j in range(6 * i):
            a = 2.0 * math.pi * j / (6 * i)
            pts.append((r * math.cos(a), r * math.sin(a)))
    return torch.tensor(pts, dtype=DTYPE, device=device)


def random_uniform(n: int, seed: int = 0, device=None) -> torch.Tensor:
    """n points uniform in the unit disc (seeded)."""
    g = torch.Generator().manual_seed(seed)
    r = torch.sqrt(torch.rand(n, generator=g, dtype=DTYPE))
    a = torch.rand(n, generator=g, dtype=DTYPE) * 2 * math.pi
    return torch.stack([r * torch.cos(a), r * torch.sin(a)], -1).to(device)
