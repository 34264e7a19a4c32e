"""Training losses of the restoration network (TrainConfig.loss, `lensim train --loss`).

* ``mse``: mean squared error, the paper's loss (the default). Its optimum under
  uncertainty is the conditional mean, which is smooth where fine detail is uncertain.
* ``charbonnier``: mean of sqrt((out - target)**2 + eps**2), eps = 1e-3: an L1 loss made
  differentiable at 0 (Charbonnier et al. 1994, Lai et al. 2017). Its optimum is closer to
  the conditional median, so it hedges less towards a blur, and it weights many small
  errors more than MSE does.
* ``charbonnier-edge``: the above plus ``EDGE_WEIGHT`` times the Charbonnier loss of the
  two images' Laplacians (3 x 3, per channel, reflect padding), after MPRNet's "edge
  loss" (Zamir et al. 2021). The Laplacian's gain grows as the square of spatial
  frequency (0 for a constant, 8 at the Nyquist checkerboard), so lost fine detail costs
  more than an error of the same size in smooth content: it does not reward
  over-smoothing the way MSE does (two outputs with equal MSE, one over-smoothed and one
  with a smooth shading error, score the same under MSE and the smoothed one worse here;
  tests/test_losses.py).

Every loss takes (B, 3, H, W) float tensors (sRGB in [0, 1]) and returns a scalar.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

CHARBONNIER_EPS = 1e-3
EDGE_WEIGHT = 0.1

_LAPLACIAN = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]])


def charbonnier(out: torch.Tensor, target: torch.Tensor, eps: float = CHARBONNIER_EPS) -> torch.Tensor:
    """Mean of sqrt((out - target)**2 + eps**2) over every element."""
    return torch.sqrt((out - target) ** 2 + eps * eps).mean()


def laplacian(img: torch.Tensor) -> torch.Tensor:
    """The 3 x 3 Laplacian of every channel of (B, C, H, W), reflect padded, same shape."""
    c = img.shape[1]
    kernel = _LAPLACIAN.to(img).expand(c, 1, 3, 3)
    return F.conv2d(F.pad(img, (1, 1, 1, 1), mode="reflect"), kernel, groups=c)


def charbonnier_edge(out: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Charbonnier loss of the images plus EDGE_WEIGHT times that of their Laplacians."""
    return charbonnier(out, target) + EDGE_WEIGHT * charbonnier(laplacian(out), laplacian(target))


LOSSES: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "mse": F.mse_loss,
    "charbonnier": charbonnier,
    "charbonnier-edge": charbonnier_edge,
}


def restoration_loss(name: str, out: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The loss called ``name`` (a key of LOSSES) of out against target, both (B, 3, H, W)."""
    return LOSSES[name](out, target)


__all__ = [
    "CHARBONNIER_EPS",
    "EDGE_WEIGHT",
    "LOSSES",
    "charbonnier",
    "charbonnier_edge",
    "laplacian",
    "restoration_loss",
]
