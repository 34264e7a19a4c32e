"""Modulated deformable convolution (lensim.restore.deform): plain-conv limit, direct
reference, the (dy, dx) layout, gradients. Tiny sizes: the whole file runs in seconds."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from lensim.restore.deform import (
    ModulatedDeformConv2d,
    deform_conv2d,
    deform_conv2d_grid_sample,
    deform_conv2d_reference,
    torchvision_deform_conv2d,
)


@pytest.fixture(autouse=True, scope="module")
def _one_thread():  # type: ignore[no-untyped-def]
    """Tiny tensors: OpenMP threads only add contention on a busy 2-core machine (a tiny
    float64 conv measured 70 ms with 2 threads under load vs 0.3 ms with 1)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _case(
    dtype: torch.dtype,
    b: int = 2,
    c: int = 4,
    h: int = 5,
    w: int = 7,
    out: int = 3,
    g: int = 2,
    k: int = 3,
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(b, c, h, w, generator=gen, dtype=dtype)
    offset = 2.5 * torch.randn(b, 2 * g * k * k, h, w, generator=gen, dtype=dtype)
    mask = torch.rand(b, g * k * k, h, w, generator=gen, dtype=dtype)
    weight = torch.randn(out, c, k, k, generator=gen, dtype=dtype) / (c * k * k) ** 0.5
    bias = torch.randn(out, generator=gen, dtype=dtype)
    return x, offset, mask, weight, bias


@pytest.mark.parametrize(("dtype", "tol"), [(torch.float32, 1e-6), (torch.float64, 1e-12)], ids=["float32", "float64"])
@pytest.mark.parametrize("k", [1, 3, 5])
def test_zero_offset_unit_mask_is_plain_conv(dtype: torch.dtype, tol: float, k: int) -> None:
    """offset 0, mask 1 -> exactly conv2d with 'same' zero padding (atol = rtol = tol)."""
    x, offset, mask, weight, bias = _case(dtype, k=k, h=6, w=9)
    y = deform_conv2d(x, torch.zeros_like(offset), torch.ones_like(mask), weight, bias, 2, backend="grid_sample")
    ref = F.conv2d(x, weight, bias, padding=k // 2)
    torch.testing.assert_close(y, ref, atol=tol, rtol=tol)


def test_module_zero_offset_matches_conv_module() -> None:
    """The nn.Module with zero offsets and unit masks equals nn.Conv2d with the same weights."""
    torch.manual_seed(1)
    conv = torch.nn.Conv2d(6, 5, 3, padding=1)
    dcn = ModulatedDeformConv2d(6, 5, 3, deformable_groups=3)
    with torch.no_grad():
        dcn.weight.copy_(conv.weight)
        assert dcn.bias is not None
        dcn.bias.copy_(conv.bias)
    x = torch.rand(2, 6, 8, 5)
    off = torch.zeros(2, dcn.offset_channels, 8, 5)
    m = torch.ones(2, dcn.mask_channels, 8, 5)
    torch.testing.assert_close(dcn(x, off, m), conv(x), atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("g", [1, 2, 4])
def test_random_offsets_match_direct_reference(g: int) -> None:
    """Random offsets up to several pixels (many samples fall outside the image) and
    random masks: grid_sample path equals explicit bilinear loops to 1e-10 (float64)."""
    x, offset, mask, weight, bias = _case(torch.float64, g=g, seed=g)
    # Include exact integer offsets, half-pixel offsets and samples exactly on the borders.
    offset[0, :6] = torch.tensor([1.0, -1.0, 0.5, 2.0, -3.0, 7.0], dtype=torch.float64).view(6, 1, 1)
    y = deform_conv2d_grid_sample(x, offset, mask, weight, bias, g)
    ref = deform_conv2d_reference(x, offset, mask, weight, bias, g)
    torch.testing.assert_close(y, ref, atol=1e-10, rtol=0)


def test_reference_without_bias_and_nonsquare_groups() -> None:
    """No bias, 1x1 image row: paths still agree (float64, 1e-10)."""
    x, offset, mask, weight, _ = _case(torch.float64, b=1, c=6, h=1, w=6, out=2, g=3)
    y = deform_conv2d_grid_sample(x, offset, mask, weight, None, 3)
    ref = deform_conv2d_reference(x, offset, mask, weight, None, 3)
    torch.testing.assert_close(y, ref, atol=1e-10, rtol=0)


def test_offset_layout_dy_then_dx() -> None:
    """Independent of the reference: a constant integer shift (dy, dx) = (1, -2) on every
    tap equals a plain conv read at (h+1, w-2), zeros outside the image (float64, 1e-12).
    Swapping dy/dx would fail."""
    x, _, _, weight, bias = _case(torch.float64, b=1, c=2, h=6, w=8, g=1, seed=3)
    k2 = 9
    offset = torch.zeros(1, 2 * k2, 6, 8, dtype=torch.float64)
    offset[:, 0::2] = 1.0  # dy
    offset[:, 1::2] = -2.0  # dx
    mask = torch.ones(1, k2, 6, 8, dtype=torch.float64)
    y = deform_conv2d_grid_sample(x, offset, mask, weight, bias, 1)
    # out[h, w] = sum_ij W[i, j] x[h + i - 1 + dy, w + j - 1 + dx] with x = 0 outside: a
    # valid conv of x zero-padded by P = 3, read from row P - 1 + dy and column P - 1 + dx.
    full = F.conv2d(F.pad(x, (3, 3, 3, 3)), weight, bias)
    torch.testing.assert_close(y, full[:, :, 3 : 3 + 6, 0 : 0 + 8], atol=1e-12, rtol=0)


def test_mask_scales_taps() -> None:
    """A mask that is one only on the centre tap reduces the conv to a 1x1 conv with the
    centre weights (float64, 1e-12); per-group masks act on their own channels only."""
    x, offset, _, weight, bias = _case(torch.float64, b=1, c=4, h=4, w=5, g=2, seed=4)
    mask = torch.zeros(1, 18, 4, 5, dtype=torch.float64)
    mask[:, 4] = 1.0  # group 0 centre tap; group 1 fully masked out
    y = deform_conv2d_grid_sample(x, torch.zeros_like(offset), mask, weight, bias, 2)
    ref = F.conv2d(x[:, :2], weight[:, :2, 1:2, 1:2], bias)
    torch.testing.assert_close(y, ref, atol=1e-12, rtol=0)


def test_gradcheck_all_inputs() -> None:
    """torch.autograd.gradcheck (float64, default eps 1e-6, atol 1e-5) w.r.t. input,
    offset, mask, weight and bias. Offsets are kept 0.2..0.8 px away from integers so the
    finite differences never straddle a kink of bilinear interpolation."""
    gen = torch.Generator().manual_seed(5)
    b, c, h, w, g, out = 1, 2, 3, 4, 2, 2
    x = torch.randn(b, c, h, w, generator=gen, dtype=torch.float64, requires_grad=True)
    base = torch.randint(-2, 2, (b, 2 * g * 9, h, w), generator=gen).to(torch.float64)
    frac = 0.2 + 0.6 * torch.rand(b, 2 * g * 9, h, w, generator=gen, dtype=torch.float64)
    offset = (base + frac).requires_grad_(True)
    mask = torch.rand(b, g * 9, h, w, generator=gen, dtype=torch.float64, requires_grad=True)
    weight = torch.randn(out, c, 3, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    bias = torch.randn(out, generator=gen, dtype=torch.float64, requires_grad=True)

    def fn(x_: torch.Tensor, o_: torch.Tensor, m_: torch.Tensor, w_: torch.Tensor, b_: torch.Tensor) -> torch.Tensor:
        return deform_conv2d_grid_sample(x_, o_, m_, w_, b_, g)

    assert torch.autograd.gradcheck(fn, (x, offset, mask, weight, bias), eps=1e-6, atol=1e-5)


def test_offset_gradient_is_nonzero_and_matches_reference_difference() -> None:
    """d(sum out)/d(offset) of one tap equals the central difference of the *reference*
    implementation (float64, rel. 1e-6): the gradient path is right, not only the values."""
    x, offset, mask, weight, bias = _case(torch.float64, b=1, c=2, h=4, w=4, g=1, seed=6)
    offset = (0.4 * offset).round() + 0.37  # within about a pixel, away from kinks
    offset.requires_grad_(True)
    deform_conv2d_grid_sample(x, offset, mask, weight, bias, 1).sum().backward()
    assert offset.grad is not None
    idx = (0, 9, 2, 1)  # channel 9 = dx of tap 4 (the centre), output pixel (2, 1)
    eps = 1e-6
    plus, minus = offset.detach().clone(), offset.detach().clone()
    plus[idx] += eps
    minus[idx] -= eps
    fd = (
        deform_conv2d_reference(x, plus, mask, weight, bias, 1).sum()
        - deform_conv2d_reference(x, minus, mask, weight, bias, 1).sum()
    ) / (2 * eps)
    assert abs(fd.item()) > 1e-3
    assert offset.grad[idx].item() == pytest.approx(fd.item(), rel=1e-6)


def test_shape_errors_are_clear() -> None:
    x, offset, mask, weight, bias = _case(torch.float32, g=2)
    with pytest.raises(ValueError, match="offset"):
        deform_conv2d(x, offset[:, :-2], mask, weight, bias, 2)
    with pytest.raises(ValueError, match="mask"):
        deform_conv2d(x, offset, mask[:, :-1], weight, bias, 2)
    with pytest.raises(ValueError, match="deformable_groups"):
        deform_conv2d(x, offset, mask, weight, bias, 3)
    with pytest.raises(ValueError, match="backend"):
        deform_conv2d(x, offset, mask, weight, bias, 2, backend="cuda-magic")
    with pytest.raises(ValueError, match="odd"):
        ModulatedDeformConv2d(4, 4, kernel_size=2)


@pytest.mark.skipif(torchvision_deform_conv2d() is not None, reason="torchvision imports here")
def test_torchvision_backend_refuses_clearly_when_missing() -> None:
    """Without torchvision, asking for it is an error; 'auto' silently uses grid_sample."""
    x, offset, mask, weight, bias = _case(torch.float64)
    with pytest.raises(RuntimeError, match="torchvision"):
        deform_conv2d(x, offset, mask, weight, bias, 2, backend="torchvision")
    with pytest.raises(RuntimeError, match="torchvision"):
        ModulatedDeformConv2d(4, 3, backend="torchvision")
    torch.testing.assert_close(
        deform_conv2d(x, offset, mask, weight, bias, 2, backend="auto"),
        deform_conv2d_grid_sample(x, offset, mask, weight, bias, 2),
        atol=0,
        rtol=0,
    )


@pytest.mark.skipif(torchvision_deform_conv2d() is None, reason="torchvision does not import here")
def test_torchvision_backend_matches() -> None:
    """Where torchvision imports, its op agrees with the grid_sample path (float64, 1e-10)."""
    x, offset, mask, weight, bias = _case(torch.float64, g=2)
    torch.testing.assert_close(
        deform_conv2d(x, offset, mask, weight, bias, 2, backend="torchvision"),
        deform_conv2d_grid_sample(x, offset, mask, weight, bias, 2),
        atol=1e-10,
        rtol=0,
    )
