"""Spatially-variant blur in the energy domain (the paper's Eq. 11), seam-free.

The image is partitioned into tiles whose centres form a regular grid (spacing `tile`
pixels). Each tile centre gets its own RGB kernel (the bank's PSF at that sensor point,
rotated to its azimuth). A source pixel's energy is spread with a bilinear blend of the
kernels of the four surrounding tile centres: out = sum_t k_t * (w_t . image), where the
w_t are bilinear hat functions (they sum to 1 everywhere), so the effective PSF varies
continuously from pixel to pixel and no tile seam can appear. Energy is conserved: each
source pixel's energy times its kernels' sum.

Computed cell by cell (issue 29): a cell is the tile x tile square between four centres,
where each of the four hats is a product of linear ramps. The cell's four weighted copies
are transformed (FFT of the cell plus the kernel's width), multiplied by their centres'
kernel spectra and summed in the frequency domain, so each cell takes one inverse
transform; the cells' results are overlap-added. This is the same sum as one FFT
convolution per centre over its hat's whole support (2 tile + 1 pixels: four cells), in
about half the transform work; results agree to float32 rounding (tests/test_render.py
checks it against a per-pixel reference, tests/test_render_kernels.py against the
per-support computation).
"""

from __future__ import annotations

import math

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
    chunk: int = 8,
) -> torch.Tensor:
    """Blur a (C, H, W) image with kernels that vary over the image.

    kernel_at(rows, cols) takes tile-centre pixel coordinates (float64 tensors, (N,)) and
    returns (N, C, P, P) kernels (P odd, centre pixel = the source point). Computation in
    float32; returns (C, H, W) in the input's dtype. ``chunk`` cells are transformed at a
    time. Memory: about chunk * C * n^2 * 24 bytes (n: the FFT length, about tile + P) and
    two rows of kernel spectra (2 * centres per row * C * n^2 * 4 bytes) at a time, plus
    the padded image and output.
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
    my, mx = math.ceil(h / tile), math.ceil(w / tile)  # cells down and across
    block = tile + p - 1  # full linear convolution of a cell with a kernel
    n_fft = _fast_len(block)
    kernels = kernels.float().reshape(ny, nx, c, p, p)
    cells = F.pad(image.float(), (0, mx * tile - w, 0, my * tile - h)).unfold(1, tile, tile).unfold(2, tile, tile)
    u = torch.arange(tile, dtype=torch.float64) / tile
    ramps = torch.stack([1.0 - u, u]).float()  # (2, T): a cell's weights of its first and second centre
    weights = [ramps[dy].unsqueeze(1) * ramps[dx].unsqueeze(0) for dy in (0, 1) for dx in (0, 1)]
    out = torch.zeros(c, (my - 1) * tile + block, (mx - 1) * tile + block, dtype=torch.float32)
    below = _spectra(kernels, 0, mx, n_fft)
    for i in range(my):
        above, below = below, _spectra(kernels, i + 1, mx, n_fft)
        for a in range(0, mx, chunk):
            js = range(a, min(a + chunk, mx))
            patch = cells[:, i, a : js[-1] + 1].transpose(0, 1)  # (N, C, T, T)
            acc = torch.zeros(len(js), c, n_fft, n_fft // 2 + 1, dtype=torch.complex64)
            for k, (spec, dx) in enumerate(((above, 0), (above, 1), (below, 0), (below, 1))):
                acc += torch.fft.rfft2(patch * weights[k], s=(n_fft, n_fft)) * spec[a + dx : js[-1] + 1 + dx]
            conv = torch.fft.irfft2(acc, s=(n_fft, n_fft))
            for n, j in enumerate(js):
                out[:, i * tile : i * tile + block, j * tile : j * tile + block] += conv[n, :, :block, :block]
    r = p // 2  # out index 0 = image row -r
    return out[:, r : r + h, r : r + w].to(image.dtype)


def _spectra(kernels: torch.Tensor, row: int, cells: int, n_fft: int) -> torch.Tensor:
    """(cells + 1, C, n, n // 2 + 1) spectra of the kernels of centre row ``row`` (kernels:
    (ny, nx, C, P, P) float32), zero-padded to n x n; zero beyond the grid (a centre past
    the image's last pixel weighs nothing there)."""
    ny, nx, c = kernels.shape[:3]
    out = torch.zeros(cells + 1, c, n_fft, n_fft // 2 + 1, dtype=torch.complex64)
    if row < ny:
        k = min(nx, cells + 1)
        out[:k] = torch.fft.rfft2(kernels[row, :k], s=(n_fft, n_fft))
    return out
