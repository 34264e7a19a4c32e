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
    chunk: int = 256,
) -> torch.Tensor:
    """Blur a (C, H, W) image with kernels that vary over the image.

    kernel_at(rows, cols) takes tile-centre pixel coordinates (float64 tensors, (N,)) and
    returns (N, C, P, P) kernels (P odd, centre pixel = the source point). Computation in
    float32; returns (C, H, W) in the input's dtype. Memory: about
    chunk * C * (2 tile + P)^2 * 12 bytes at a time plus the padded output.
    """
    if image.dim() != 3:
        raise ValueError("expected a (C, H, W) image")
    c, h, w = image.shape
    hy, hx = _hat(h, tile).float(), _hat(w, tile).float()
    cy, cx = tile_centres(h, tile), tile_centres(w, tile)
    ny, nx = len(cy), len(cx)
    kernels = kernel_at(cy.repeat_interleave(nx), cx.repeat(ny))
    p = kernels.shape[-1]
    if kernels.shape[-2] != p or p % 2 == 0 or kernels.shape[1] != c or kernels.shape[0] != ny * nx:
        raise ValueError(f"kernel_at must return ({ny * nx}, {c}, P, P) with P odd, got {tuple(kernels.shape)}")
    r = p // 2
    support = 2 * tile + 1  # hat support: centre - tile .. centre + tile
    block = support + p - 1  # full linear convolution of a support patch with a kernel
    n_fft = _fast_len(block)
    pad_hi_y = (ny - 1) * tile + tile + 1 - h
    pad_hi_x = (nx - 1) * tile + tile + 1 - w
    img_p = F.pad(image.float(), (tile, pad_hi_x, tile, pad_hi_y))
    hy_p = F.pad(hy, (tile, pad_hi_y))
    hx_p = F.pad(hx, (tile, pad_hi_x))
    ar = torch.arange(support)
    blocks = torch.empty(ny * nx, c, block, block, dtype=torch.float32)
    for a in range(0, ny * nx, chunk):
        idx = torch.arange(a, min(a + chunk, ny * nx))
        ty, tx = idx // nx, idx % nx
        ys = (ty * tile).unsqueeze(1) + ar  # padded coordinates of each support
        xs = (tx * tile).unsqueeze(1) + ar
        patch = img_p[:, ys.unsqueeze(2), xs.unsqueeze(1)]  # (C, N, S, S)
        wgt = hy_p[ty.unsqueeze(1), ys].unsqueeze(2) * hx_p[tx.unsqueeze(1), xs].unsqueeze(1)
        patch = (patch * wgt.unsqueeze(0)).permute(1, 0, 2, 3)
        pf = torch.fft.rfft2(patch, s=(n_fft, n_fft))
        kf = torch.fft.rfft2(kernels[idx].float(), s=(n_fft, n_fft))
        blocks[a : a + len(idx)] = torch.fft.irfft2(pf * kf, s=(n_fft, n_fft))[..., :block, :block]
    # overlap-add: block of tile (ty, tx) starts at padded coordinate (ty*tile - r, tx*tile - r)
    out_h = (ny - 1) * tile + block
    out_w = (nx - 1) * tile + block
    cols = blocks.reshape(ny * nx, c * block * block).T.unsqueeze(0)  # (1, C*B*B, L)
    out = F.fold(cols, output_size=(out_h, out_w), kernel_size=block, stride=tile)[0]
    # out index 0 = padded coordinate -r; image row 0 = padded coordinate tile
    res = out[:, tile + r : tile + r + h, tile + r : tile + r + w]
    return res.to(image.dtype)
