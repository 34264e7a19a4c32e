"""Spatially-variant blur: exactness against a naive reference, energy, seams."""

import math

import torch

from lensim.render.blur import _hat, spatially_variant_blur, tile_centres


def _kernels_factory(h, w, p=7, base=0.6, slope=1.5, shift_red=0.0):
    def kernel_at(rows, cols):
        y, x = torch.meshgrid(torch.arange(p) - p // 2, torch.arange(p) - p // 2, indexing="ij")
        r = torch.sqrt((rows - h / 2) ** 2 + (cols - w / 2) ** 2) / math.hypot(h / 2, w / 2)
        s = (base + slope * r * r).reshape(-1, 1, 1)  # smooth in x, y (no cone at the centre)
        k = torch.exp(-((x - 0.0) ** 2 + y**2) / (2 * s**2))
        kr = torch.exp(-((x - shift_red) ** 2 + y**2) / (2 * s**2))
        k = k / k.sum((1, 2), keepdim=True)
        kr = kr / kr.sum((1, 2), keepdim=True)
        return torch.stack([kr, k, k], 1).double()

    return kernel_at


def _naive(img, kernel_at, tile):
    """out(x) = sum_s img(s) k_s(x - s), k_s = bilinear blend of the tile-centre kernels."""
    c, h, w = img.shape
    hy, hx = _hat(h, tile), _hat(w, tile)
    cy, cx = tile_centres(h, tile), tile_centres(w, tile)
    ker = kernel_at(cy.repeat_interleave(len(cx)), cx.repeat(len(cy))).reshape(
        len(cy), len(cx), c, -1, kernel_at(cy[:1], cx[:1]).shape[-1]
    )
    p = ker.shape[-1]
    r = p // 2
    out = torch.zeros(c, h + 2 * r, w + 2 * r, dtype=torch.float64)
    for i in range(h):
        for j in range(w):
            k = torch.einsum("a,b,abcyx->cyx", hy[:, i], hx[:, j], ker)
            out[:, i : i + p, j : j + p] += img[:, i, j].reshape(c, 1, 1) * k
    return out[:, r : r + h, r : r + w]


def test_matches_naive_per_pixel_reference():
    torch.manual_seed(0)
    h, w, tile = 23, 31, 8
    img = torch.rand(3, h, w, dtype=torch.float64)
    kat = _kernels_factory(h, w, p=7, shift_red=0.7)
    fast = spatially_variant_blur(img, kat, tile=tile)
    ref = _naive(img, kat, tile)
    # float32 FFT arithmetic: agreement to 1e-5 of the signal
    assert (fast - ref).abs().max().item() < 1e-5


def test_energy_is_conserved_away_from_borders():
    h, w = 200, 300
    img = torch.zeros(3, h, w, dtype=torch.float64)
    img[:, 40:160, 50:250] = torch.rand(3, 120, 200, dtype=torch.float64)
    out = spatially_variant_blur(img, _kernels_factory(h, w, p=15), tile=32)
    assert abs(out.sum().item() / img.sum().item() - 1.0) < 1e-5


def test_uniform_field_stays_uniform_without_seams():
    # kernels whose width grows from 0.8 to 1.8 px across the half-diagonal (much faster
    # than a real lens's): a uniform image stays uniform to 0.2 % away from the borders and
    # no step between neighbouring pixels exceeds 5e-4 (the blend's residual ripple scales
    # with (tile spacing x kernel-width gradient)^2; a seam would be a step of the size of
    # the kernel change, ~1e-2 here)
    h, w = 300, 420
    img = torch.ones(3, h, w, dtype=torch.float64)
    out = spatially_variant_blur(img, _kernels_factory(h, w, p=15, base=0.8, slope=1.0), tile=32)
    inner = out[:, 20:-20, 20:-20]
    assert (inner - 1.0).abs().max().item() < 2e-3
    assert inner.diff(dim=1).abs().max().item() < 5e-4
    assert inner.diff(dim=2).abs().max().item() < 5e-4


def test_point_source_at_tile_centre_reproduces_its_kernel():
    h, w, tile = 128, 192, 32
    img = torch.zeros(3, h, w, dtype=torch.float64)
    img[:, 64, 96] = 1.0  # tile centre (2, 3)
    kat = _kernels_factory(h, w, p=15, shift_red=1.3)
    out = spatially_variant_blur(img, kat, tile=tile)
    k = kat(torch.tensor([64.0], dtype=torch.float64), torch.tensor([96.0], dtype=torch.float64))[0]
    assert (out[:, 64 - 7 : 64 + 8, 96 - 7 : 96 + 8] - k).abs().max().item() < 1e-6
