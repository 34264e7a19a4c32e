"""Image-quality metrics for training validation: PSNR and SSIM on batched tensors.

Both take images (B, C, H, W) (or (C, H, W)) with values in [0, data_range] and return one
value per image (B,) in float64: PSNR in dB over all channels and pixels, SSIM (Wang et
al. 2004) with an 11x11 Gaussian window (sigma 1.5 px), K1 = 0.01, K2 = 0.03, computed per
channel over the valid (unpadded) window positions and averaged over channels and
positions. That is the convention of ``skimage.metrics.structural_similarity`` with
``gaussian_weights=True, use_sample_covariance=False, data_range=data_range`` (matched to
1e-6 in a test).
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def _as_batch(x: torch.Tensor, name: str) -> torch.Tensor:
    if x.dim() == 3:
        x = x.unsqueeze(0)
    if x.dim() != 4:
        raise ValueError(f"{name} must be (B, C, H, W) or (C, H, W), got {tuple(x.shape)}")
    return x.to(torch.float64)


def psnr(pred: torch.Tensor, target: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Peak signal-to-noise ratio (B,) in dB; +inf for identical images."""
    p, t = _as_batch(pred, "pred"), _as_batch(target, "target")
    if p.shape != t.shape:
        raise ValueError(f"shapes differ: {tuple(p.shape)} vs {tuple(t.shape)}")
    mse = (p - t).pow(2).flatten(1).mean(1)
    return 10.0 * torch.log10(data_range**2 / mse)


def _gaussian_window(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    r = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2.0
    g = torch.exp(-(r**2) / (2.0 * sigma**2))
    return g / g.sum()


def ssim(
    pred: torch.Tensor,
    target: torch.Tensor,
    data_range: float = 1.0,
    window: int = 11,
    sigma: float = 1.5,
) -> torch.Tensor:
    """Structural similarity (B,) (see the module docstring); images must be at least
    ``window`` pixels on each side."""
    p, t = _as_batch(pred, "pred"), _as_batch(target, "target")
    if p.shape != t.shape:
        raise ValueError(f"shapes differ: {tuple(p.shape)} vs {tuple(t.shape)}")
    b, c, h, w = p.shape
    if h < window or w < window:
        raise ValueError(f"SSIM needs images of at least {window}x{window} pixels, got {h}x{w}")
    g = _gaussian_window(window, sigma, p.dtype, p.device)
    kx = g.view(1, 1, 1, window).expand(c, 1, 1, window)
    ky = g.view(1, 1, window, 1).expand(c, 1, window, 1)

    def blur(x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(x, kx, groups=c), ky, groups=c)

    mu_p, mu_t = blur(p), blur(t)
    s_pp = blur(p * p) - mu_p**2
    s_tt = blur(t * t) - mu_t**2
    s_pt = blur(p * t) - mu_p * mu_t
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    num = (2 * mu_p * mu_t + c1) * (2 * s_pt + c2)
    den = (mu_p**2 + mu_t**2 + c1) * (s_pp + s_tt + c2)
    return (num / den).flatten(1).mean(1)


def mse_to_psnr(mse: float, data_range: float = 1.0) -> float:
    """PSNR in dB of a mean squared error (inf for 0)."""
    return math.inf if mse <= 0 else 10.0 * math.log10(data_range**2 / mse)


__all__ = ["mse_to_psnr", "psnr", "ssim"]
