"""Spatially-variant blur in the energy domain (the paper's Eq. 11), seam-free.

The image is partitioned into tiles whose centres form a regular grid (spacing `tile`
pixels). Each tile centre gets its own RGB kernel (the bank's PSF at that sensor point,
rotated to its azimuth). A source pixel's energy is spread with a bilinear blend of the
kernels of the four surrounding tile centres: out = sum_t k_t * (w_t . image), where the
w_t are bilinear hat functions (they sum to 1 everywhere), so the effective PSF varies
continuously from pixel to pixel and no tile seam can appear. Each term is computed on the
hat's support only (2*tile pixels plus the kernel) with batched FFTs, and the results are
overlap-added. Energy is conserved: each source pixel's energy times its kernels' sum.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lensim.render.kernels import KernelFn, tile_centres


def _hat(size: int, tile: int) -> torch.Tensor:
    """(n_centres, size) bilinear weights along one axis (columns sum to 1)."""
    c = tile_centres(size, tile)
    x = torch.arange(size, dtype=torch.float64)
    return torch.clamp(1.0 - (x.unsqueeze(0) - c.unsqueeze(1)).abs() / tile, min=0.0)


def _fast_len(n: int) -> int:
    """Smallest 2^a 3^b >= n (fast FFT sizes)."""
    best = 1 << (n - 1).bit_length()
    p3 = 1
    while p3 < best:
        p2 = p3
        while p2 < n:
            p2 *= 2
        best = min(best, p2)
        p3 *= 3
    return best


def spatially_variant_blur(
    image: torch.Tensor,
    kernel_at: KernelFn,
    tile: int = 64,
    chunk: int = 16,
) -> torch.Tensor:
    """Blur a (C, H, W) image with kernels that vary over the image.

    kernel_at(rows, cols) takes tile-centre pixel coordinates (float64 tensors, (N,)) and
    returns (N, C, P, P) kernels (P odd, centre pixel = the source point). Computation in
    float32; returns (C, H, W) in the input's dtype. ``chunk`` tiles are transformed at a
    time (16: the FFT buffers stay small; measured faster than all tiles at once, and the
    result does not depend on it). Memory: about chunk * C * n^2 * 16 bytes at a time (n:
    the FFT length, about 2 tile + P) plus the padded image and output.
    """
    if image.dim() != 3:
        raise ValueError("expected a (C, H, W) image")
    c, h, w = image.shape
    cy, cx = tile_centres(h, tile), tile_centres(w, tile)
    ny, nx = len(cy), len(cx)
    kernels = kernel_at(cy.repeat_interleave(nx), cx.repeat(ny))
    p = kernels.shape[-1]
    if kernels.shape[-2] != p or p % 2 == 0 or kernels.shape[1] != c or kernels.shape[0] != ny * nx:
        raise ValueError(f"kernel_at must return ({ny * nx}, {c}, P, P) with P odd, got {tuple(kernels.shape)}")
    supports, wy, wx = _supports(image, tile, ny, nx)
    block = 2 * tile + p  # full linear convolution of a support patch (2 tile + 1) with a kernel
    n_fft = _fast_len(block)
    # overlap-add: block of tile (ty, tx) starts at padded coordinate (ty*tile - r, tx*tile - r);
    # blocks are added last tile first, the order in which F.fold (col2im) adds them
    out = torch.zeros(c, (ny - 1) * tile + block, (nx - 1) * tile + block, dtype=torch.float32)
    for a in reversed(range(0, ny * nx, chunk)):
        idx = torch.arange(a, min(a + chunk, ny * nx))
        ty, tx = idx // nx, idx % nx
        wgt = wy[ty].unsqueeze(2) * wx[tx].unsqueeze(1)  # (N, S, S)
        patch = (supports[:, ty, tx] * wgt.unsqueeze(0)).permute(1, 0, 2, 3)  # (N, C, S, S)
        pf = torch.fft.rfft2(patch, s=(n_fft, n_fft))
        kf = torch.fft.rfft2(kernels[idx].float(), s=(n_fft, n_fft))
        conv = torch.fft.irfft2(pf * kf, s=(n_fft, n_fft))
        for j in reversed(range(len(idx))):
            y0, x0 = int(ty[j]) * tile, int(tx[j]) * tile
            out[:, y0 : y0 + block, x0 : x0 + block] += conv[j, :, :block, :block]
    # out index 0 = padded coordinate -r; image row 0 = padded coordinate tile
    r = p // 2
    return out[:, tile + r : tile + r + h, tile + r : tile + r + w].to(image.dtype)


def _supports(image: torch.Tensor, tile: int, ny: int, nx: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every tile centre's hat support of the (C, H, W) image, S x S pixels (S = 2 tile + 1,
    tile apart, the image zero-padded by tile before and enough after), as a view
    (C, ny, nx, S, S) float32, and each centre's hat weights on its support along rows
    (ny, S) and columns (nx, S)."""
    _, h, w = image.shape
    support = 2 * tile + 1
    pad_y, pad_x = ny * tile + 1 - h, nx * tile + 1 - w
    img_p = F.pad(image.float(), (tile, pad_x, tile, pad_y))
    hy_p = F.pad(_hat(h, tile).float(), (tile, pad_y))
    hx_p = F.pad(_hat(w, tile).float(), (tile, pad_x))
    supports = img_p.unfold(1, support, tile).unfold(2, support, tile)
    wy = hy_p.unfold(1, support, tile).diagonal().T
    wx = hx_p.unfold(1, support, tile).diagonal().T
    return supports, wy, wx
