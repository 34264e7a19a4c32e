"""The field-aware UNet (lensim.restore.network): shapes, dtypes, identity at init, the
three ablation switches, the parameter-matched plain UNet; against derivations by hand
from the block definitions: absolute parameter counts, the receptive field, the residual
contract and shift equivariance on the downsampling grid. Tiny widths and images."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from lensim.restore.fov import fov_channels
from lensim.restore.network import (
    ContextBlock,
    DeformResBlock,
    FieldAwareUNet,
    count_parameters,
    field_features,
    plain_unet_matching,
    plain_unet_width,
)

W0, DEPTH, G = 8, 3, 2  # tiny test network: widths 8/16/32


@pytest.fixture(autouse=True, scope="module")
def _one_thread():  # type: ignore[no-untyped-def]
    """Tiny tensors: OpenMP threads only add contention on a busy 2-core machine."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _net(**kw: object) -> FieldAwareUNet:
    torch.manual_seed(0)
    args: dict[str, object] = {"width": W0, "depth": DEPTH, "deformable_groups": G}
    args.update(kw)
    return FieldAwareUNet(**args)  # type: ignore[arg-type]


def _randomise_tail(net: FieldAwareUNet) -> None:
    with torch.no_grad():
        net.tail.weight.normal_(0.0, 0.1)
        net.tail.bias.normal_(0.0, 0.1)


def _inputs(b: int, h: int, w: int, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(h * 100 + w)
    rgb = torch.rand(b, 3, h, w, generator=gen, dtype=dtype)
    fov = fov_channels(h, w, 3, 5, 40, 60, dtype=dtype)
    return rgb, fov


@pytest.mark.parametrize("size", [(13, 10), (16, 12), (1, 7), (9, 9)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
def test_output_shape_and_dtype(size: tuple[int, int], dtype: torch.dtype) -> None:
    """Odd and even sizes (padded internally to a multiple of 4, cropped back), batch 2."""
    net = _net(zero_init_tail=False).to(dtype)
    rgb, fov = _inputs(2, *size, dtype=dtype)
    out = net(rgb, fov)
    assert out.shape == rgb.shape and out.dtype == dtype
    assert torch.isfinite(out).all()
    assert (out - rgb).abs().max().item() > 1e-4  # the residual is really added


def test_identity_at_init_with_zero_tail() -> None:
    """The last conv is zero-initialised (zero_init_tail=True, the default): the untrained
    network returns its input exactly; with zero_init_tail=False it does not."""
    rgb, fov = _inputs(2, 11, 14)
    assert torch.equal(_net()(rgb, fov), rgb)
    assert not torch.allclose(_net(zero_init_tail=False)(rgb, fov), rgb, atol=1e-3)


def test_padding_continues_fov_linearly() -> None:
    """A 13x10 input (padded to 16x12) gives the top-left 13x10 of the output of the 16x12
    input built by edge-replicating the RGB and taking the FOV of the larger crop
    (float64, 1e-12): the padded FOV channels are the true continued coordinates."""
    net = _net(zero_init_tail=False).double()
    rgb, _ = _inputs(1, 13, 10, dtype=torch.float64)
    fov = fov_channels(13, 10, 4, 2, 30, 20, dtype=torch.float64)
    big_rgb = F.pad(rgb, (0, 2, 0, 3), mode="replicate")
    big_fov = fov_channels(16, 12, 4, 2, 30, 20, dtype=torch.float64)
    torch.testing.assert_close(net(rgb, fov), net(big_rgb, big_fov)[..., :13, :10], atol=1e-12, rtol=0)


def _conv3_params(cin: int, cout: int) -> int:
    return cout * (9 * cin + 1)


def test_switches_change_parameter_count_as_expected() -> None:
    """Exact differences: FOV input adds 2 head input channels (2*9*w0 weights); the context
    block adds 4 dilated convs (C -> C/4) and a 1x1 fusion (4*C/4 -> C); deformable blocks
    add one offset/mask conv per decoder scale (coarsest: C -> 27G; finer: C + 18G -> 27G);
    the DCN itself has exactly the weights of the plain conv it replaces."""
    full = count_parameters(_net())
    c_last = W0 * 2 ** (DEPTH - 1)
    assert full - count_parameters(_net(use_fov=False)) == 2 * 9 * W0
    b = c_last // 4
    assert full - count_parameters(_net(use_context=False)) == 4 * _conv3_params(c_last, b) + (4 * b * c_last + c_last)
    assert count_parameters(ContextBlock(c_last)) == 4 * _conv3_params(c_last, b) + (4 * b * c_last + c_last)
    dec = [W0 * 2**s for s in range(DEPTH - 2, -1, -1)]  # coarse to fine
    offsets = _conv3_params(dec[0], 27 * G) + sum(_conv3_params(c + 18 * G, 27 * G) for c in dec[1:])
    assert full - count_parameters(_net(use_deformable=False)) == offsets
    plain = _net(use_fov=False, use_deformable=False, use_context=False)
    assert full - count_parameters(plain) == 2 * 9 * W0 + offsets + count_parameters(ContextBlock(c_last))


def _block_counts(
    ws: tuple[int, ...], fov: bool, deformable: int, context: bool, groups: int, modulation: bool = False
) -> int:
    """Parameter count of FieldAwareUNet written out from the block definitions in the module
    docstring: k x k convs have cout * (cin * k^2 + 1) parameters, the 2x2 transposed conv
    cin * cout * 4 + cout, the DCN as many as the 3x3 conv it replaces; ``deformable`` is
    the number of deformable decoder scales, coarsest first."""

    def conv(cin: int, cout: int, k: int = 3) -> int:
        return cout * (cin * k * k + 1)

    def res(c: int) -> int:
        return 2 * conv(c, c)

    n = conv(5 if fov else 3, ws[0]) + res(ws[0]) + conv(ws[0], 3)  # head, first block, tail
    n += sum(conv(ws[s - 1], ws[s]) + res(ws[s]) for s in range(1, len(ws)))  # encoder
    if context:
        branch = ws[-1] // 4
        n += 4 * conv(ws[-1], branch) + conv(4 * branch, ws[-1], 1)
    taps = 9 * groups  # offsets 2 * taps, masks taps
    for i, s in enumerate(range(len(ws) - 2, -1, -1)):  # decoder, coarse to fine
        n += ws[s + 1] * ws[s] * 4 + ws[s] + conv(2 * ws[s], ws[s], 1) + res(ws[s])
        if i < deformable:
            n += conv(ws[s] + (2 * taps if i > 0 else 0), 3 * taps)
    if modulation:
        n += sum(conv(5, 16, 1) + conv(16, 2 * c, 1) for c in [ws[-1], *ws[-2::-1]])
    return n


@pytest.mark.parametrize(
    "ws, groups", [((8, 16, 32), 2), ((32, 64, 128), 2), ((32, 64, 128, 256), 8)], ids=["tiny", "default", "paper"]
)
def test_parameter_counts_from_the_block_definitions(ws: tuple[int, ...], groups: int) -> None:
    """Absolute counts of the full net, every ablation variant, partial deformable scales
    and field modulation, against the block-by-block count above."""
    dec = len(ws) - 1
    cases = [
        ({}, dict(fov=True, deformable=dec, context=True)),
        ({"use_fov": False}, dict(fov=False, deformable=dec, context=True)),
        ({"use_deformable": False}, dict(fov=True, deformable=0, context=True)),
        ({"use_context": False}, dict(fov=True, deformable=dec, context=False)),
        (
            {"use_fov": False, "use_deformable": False, "use_context": False},
            dict(fov=False, deformable=0, context=False),
        ),
        ({"deformable_scales": 1}, dict(fov=True, deformable=1, context=True)),
        (
            {"deformable_scales": 1, "field_modulation": True},
            dict(fov=True, deformable=1, context=True, modulation=True),
        ),
    ]
    with torch.device("meta"):
        for switches, hand in cases:
            net = FieldAwareUNet(widths=ws, deformable_groups=groups, **switches)  # type: ignore[arg-type]
            assert count_parameters(net) == _block_counts(ws, groups=groups, **hand), switches  # type: ignore[arg-type]


def test_default_and_paper_sizes() -> None:
    """Default (32/64/128, G=2) is about 0.85M parameters (trainable on 2 CPU cores); the paper
    configuration (32/64/128/256, G=8) is constructible and has the paper's 4.2M (+-1.5%)."""
    with torch.device("meta"):
        default = FieldAwareUNet()
        paper = FieldAwareUNet(widths=(32, 64, 128, 256), deformable_groups=8)
    assert default.widths == (32, 64, 128) and default.depth == 3
    assert 0.8e6 < count_parameters(default) < 1.2e6
    assert abs(count_parameters(paper) - 4.2e6) < 0.015 * 4.2e6


@pytest.mark.parametrize("ref", ["tiny", "default", "paper"])
def test_plain_unet_matches_parameter_count(ref: str) -> None:
    """plain_unet_matching: all switches off, same number of scales, count within 10%."""
    with torch.device("meta"):
        model = {
            "tiny": lambda: _net(),
            "default": lambda: FieldAwareUNet(),
            "paper": lambda: FieldAwareUNet(widths=(32, 64, 128, 256), deformable_groups=8),
        }[ref]()
        plain = plain_unet_matching(model)
    target = count_parameters(model)
    assert not (plain.use_fov or plain.use_deformable or plain.use_context)
    assert plain.depth == model.depth
    assert abs(count_parameters(plain) - target) <= 0.1 * target
    # the chosen width is the best integer width
    w = plain.widths[0]
    with torch.device("meta"):
        for other in (w - 1, w + 1):
            n = count_parameters(FieldAwareUNet(other, model.depth, False, False, False))
            assert abs(n - target) >= abs(count_parameters(plain) - target)
    assert plain_unet_width(target, model.depth) == w


def test_fov_channels_are_used_only_when_enabled() -> None:
    rgb, fov = _inputs(1, 8, 8)
    other = fov_channels(8, 8, 30, 50, 40, 60)
    net = _net()
    _randomise_tail(net)
    assert (net(rgb, fov) - net(rgb, other)).abs().max().item() > 1e-5
    with pytest.raises(ValueError, match="use_fov"):
        net(rgb)
    blind = _net(use_fov=False)
    _randomise_tail(blind)
    assert torch.equal(blind(rgb, fov), blind(rgb, other))
    assert torch.equal(blind(rgb), blind(rgb, fov))


def test_gradients_reach_every_parameter() -> None:
    """With a non-zero tail, one MSE backward gives every parameter a non-zero gradient
    (including the zero-initialised offset/mask convs and the FOV head weights)."""
    net = _net()
    _randomise_tail(net)
    rgb, fov = _inputs(2, 12, 12)
    F.mse_loss(net(rgb, fov), torch.rand_like(rgb)).backward()
    dead = [n for n, p in net.named_parameters() if p.grad is None or p.grad.abs().max().item() == 0.0]
    assert not dead


def test_offsets_change_the_output() -> None:
    """A non-zero bias on the (zero-initialised) offset conv moves the sampling points and
    changes the output: the deformable path is live."""
    net = _net()
    _randomise_tail(net)
    rgb, fov = _inputs(1, 8, 12)
    before = net(rgb, fov)
    with torch.no_grad():
        net.dec[-1].offset_conv.bias[: 2 * G * 9].fill_(0.7)
    assert (net(rgb, fov) - before).abs().max().item() > 1e-5


def test_coarse_offsets_are_upsampled_and_doubled() -> None:
    """A decoder block sees the coarser scale's offsets, upsampled 2x and doubled (pixel
    units halve): with the offset conv set to pass those input channels through (centre
    tap = 1), a constant coarse offset field c gives offsets 2c at the finer scale (1e-6),
    and the block's output then differs from the zero-offset case."""
    ch, g = 4, 1
    n_off = 18 * g
    block = DeformResBlock(ch, g, coarse_offsets=True)
    with torch.no_grad():
        for k in range(n_off):
            block.offset_conv.weight[k, ch + k, 1, 1] = 1.0
    x = torch.rand(1, ch, 6, 8)
    coarse = torch.linspace(-0.8, 0.9, n_off).view(1, n_off, 1, 1).expand(1, n_off, 3, 4).contiguous()
    out, offset = block(x, coarse)
    torch.testing.assert_close(offset, 2.0 * coarse[:, :, :1, :1].expand(1, n_off, 6, 8), atol=1e-6, rtol=0)
    out0, offset0 = block(x, torch.zeros_like(coarse))
    assert offset0.abs().max().item() == 0.0
    assert (out - out0).abs().max().item() > 1e-4
    with pytest.raises(ValueError, match="coarser"):
        block(x, None)


def test_config_rebuilds_and_bad_groups_refused() -> None:
    net = _net()
    clone = FieldAwareUNet(**net.config)
    clone.load_state_dict(net.state_dict())
    assert count_parameters(clone) == count_parameters(net)
    with pytest.raises(ValueError, match="deformable_groups"):
        FieldAwareUNet(width=6, depth=2, deformable_groups=4)
    with pytest.raises(ValueError, match="scales"):
        FieldAwareUNet(width=8, depth=1)


@pytest.mark.parametrize("scales", [0, 1, 2])
def test_deformable_scales_pick_the_coarsest_decoder_blocks(scales: int) -> None:
    """deformable_scales=n: the n coarsest decoder blocks are deformable, the rest plain;
    the forward pass works, the config rebuilds it, and n=2 (all, depth 3) is the default."""
    net = _net(deformable_scales=scales)
    kinds = [isinstance(b, DeformResBlock) for b in net.dec]
    assert kinds == [i < scales for i in range(DEPTH - 1)]
    rgb, fov = _inputs(1, 12, 16)
    assert net(rgb, fov).shape == rgb.shape
    clone = FieldAwareUNet(**net.config)
    clone.load_state_dict(net.state_dict())
    if scales == DEPTH - 1:
        assert net.config == _net().config
    with pytest.raises(ValueError, match="deformable_scales"):
        _net(deformable_scales=DEPTH)


def test_deformable_scales_offsets_live_at_the_coarse_scale() -> None:
    """With only the coarsest decoder scale deformable, its offsets still change the output."""
    net = _net(deformable_scales=1)
    _randomise_tail(net)
    rgb, fov = _inputs(1, 8, 12)
    before = net(rgb, fov)
    with torch.no_grad():
        net.dec[0].offset_conv.bias[: 2 * G * 9].fill_(0.7)
    assert (net(rgb, fov) - before).abs().max().item() > 1e-5


# ------------------------------------------------------------------ field modulation


def _modulated(**kw: object) -> FieldAwareUNet:
    net = _net(field_modulation=True, **kw)
    with torch.no_grad():
        for mod in net.modulate:
            mod.out.weight.normal_(0.0, 0.3)
    return net


def test_field_features_are_the_rotational_basis() -> None:
    fov = torch.tensor([0.6, -0.2]).view(1, 2, 1, 1)
    got = field_features(fov).flatten().tolist()
    assert got == pytest.approx([0.6, -0.2, 0.36 - 0.04, 2 * 0.6 * -0.2, 0.36 + 0.04])


def test_field_modulation_starts_as_the_identity_and_needs_fov() -> None:
    """Zero-initialised: the modulated net computes exactly what the same weights compute
    without modulation; it adds about 1 % to the default network's parameters."""
    rgb, fov = _inputs(2, 13, 18)
    plain_net = _net(zero_init_tail=False)
    mod_net = _net(zero_init_tail=False, field_modulation=True)
    mod_net.load_state_dict(plain_net.state_dict(), strict=False)
    assert torch.equal(plain_net(rgb, fov), mod_net(rgb, fov))
    base, extra = (count_parameters(FieldAwareUNet(deformable_scales=1, field_modulation=m)) for m in (False, True))
    assert 0.005 < extra / base - 1 < 0.02
    with pytest.raises(ValueError, match="field_modulation: is computed from the field-of-view input"):
        FieldAwareUNet(width=8, use_fov=False, field_modulation=True)


def test_field_modulation_makes_the_output_depend_on_position() -> None:
    """The same pixels at two sensor positions: without modulation (and with a head that
    ignores the FOV channels) the outputs agree; with it they differ, and the gradient
    reaches every modulation parameter."""
    net = _modulated(zero_init_tail=False)
    with torch.no_grad():
        net.head.weight[:, 3:].zero_()  # the FOV reaches the output through the modulation only
    rgb = torch.rand(1, 3, 12, 16)
    near, far = fov_channels(12, 16, 0, 0, 400, 600), fov_channels(12, 16, 190, 290, 400, 600)
    assert (net(rgb, near) - net(rgb, far)).abs().max().item() > 1e-3
    off = _net(zero_init_tail=False)
    with torch.no_grad():
        off.head.weight[:, 3:].zero_()
    torch.testing.assert_close(off(rgb, near), off(rgb, far), atol=1e-6, rtol=0)
    F.mse_loss(net(rgb, far), torch.rand_like(rgb)).backward()
    dead = [n for n, p in net.named_parameters() if n.startswith("modulate") and not p.grad.abs().max() > 0]
    assert not dead


def test_field_modulation_config_round_trip_and_old_configs() -> None:
    """The config rebuilds the modulated net; a config saved before the option existed
    (no key) rebuilds the unmodulated one."""
    net = _modulated()
    clone = FieldAwareUNet(**net.config)
    clone.load_state_dict(net.state_dict())
    rgb, fov = _inputs(1, 9, 11)
    assert torch.equal(clone(rgb, fov), net(rgb, fov))
    old = {k: v for k, v in _net().config.items() if k != "field_modulation"}
    assert FieldAwareUNet(**old).modulate is None


# ------------------------------------------------------------------ known values


def _receptive_columns(p: int, depth: int) -> tuple[int, int]:
    """Input columns that can reach output column ``p`` with zero offsets, derived by hand
    from the layer list in the module docstring (hull over every path of the UNet):
    a 3x3 conv widens an interval by 1 (dilation d: by d); a stride-2 3x3 conv (padding 1)
    maps coarse j to fine 2j-1 .. 2j+1; the 2x2 stride-2 transposed conv maps fine i to
    coarse i // 2; 1x1 convs, the skips and the residual additions add nothing."""

    def conv(iv: tuple[int, int], r: int = 1) -> tuple[int, int]:
        return iv[0] - r, iv[1] + r

    def encoder(iv: tuple[int, int], s: int) -> tuple[int, int]:  # output of encoder scale s
        iv = conv(conv(iv))  # residual block
        return conv(iv) if s == 0 else encoder((2 * iv[0] - 1, 2 * iv[1] + 1), s - 1)  # head / strided conv

    def decoder(iv: tuple[int, int], s: int) -> tuple[int, int]:  # output of decoder scale s
        iv = conv(conv(iv))  # (deformable) residual block, after the 1x1 fusion of [up, skip]
        coarse = (iv[0] // 2, iv[1] // 2)
        deeper = encoder(conv(coarse, 8), depth - 1) if s == depth - 2 else decoder(coarse, s + 1)  # context: d <= 8
        skip = encoder(iv, s)
        return min(skip[0], deeper[0]), max(skip[1], deeper[1])

    return decoder(conv((p, p)), 0)  # the tail conv


@pytest.mark.parametrize("widths, radius", [((4, 8, 16), 60), ((4, 8, 16, 32), 124)], ids=["depth3", "depth4"])
def test_receptive_field_is_the_architectures(widths: tuple[int, ...], radius: int) -> None:
    """Back-propagating from one output pixel reaches exactly the input columns derived by
    hand, for output columns at every phase of the downsampling grid. The largest reach
    over the phases is 60 px for 3 scales and 124 px for the paper's 4 (the module
    docstring's "about 58" and "about 118" are one output pixel's reach). Weights
    are made positive (and the FOV input weights zero) so that no ReLU is inactive: the
    gradient's support is then the structural one (float64, zero offsets)."""
    torch.manual_seed(0)
    net = FieldAwareUNet(widths=widths, zero_init_tail=False).double()
    with torch.no_grad():
        for param in net.parameters():
            param.abs_()
        net.head.weight[:, 3:].zero_()
    m = net.size_multiple
    width = 2 * (radius + 2 * m) // m * m + 4 * m
    rgb = torch.rand(1, 3, 8, width, dtype=torch.float64, requires_grad=True)
    out = net(rgb, fov_channels(8, width, 0, 0, 8, width, dtype=torch.float64))
    reach = 0
    for p in range(width // 2, width // 2 + m):
        (grad,) = torch.autograd.grad(out[0, :, 4, p].sum(), rgb, retain_graph=True)
        columns = torch.nonzero(grad.abs().sum(dim=(0, 1, 2))).flatten().tolist()
        lo, hi = _receptive_columns(p, len(widths))
        assert columns == list(range(lo, hi + 1)), p
        reach = max(reach, p - lo, hi - p)
    assert reach == radius


def test_untrained_parts_leave_the_input_plus_the_tail_bias() -> None:
    """All weights zero and the tail bias b: the output is rgb + b at every pixel, for an
    odd size (padded internally and cropped back): the residual is added, not replacing."""
    net = _net()
    bias = torch.tensor([0.1, -0.2, 0.3])
    with torch.no_grad():
        for param in net.parameters():
            param.zero_()
        net.tail.bias.copy_(bias)
    rgb, fov = _inputs(2, 13, 7)
    torch.testing.assert_close(net(rgb, fov), rgb + bias.view(1, 3, 1, 1), atol=1e-7, rtol=0)


def test_float32_and_float64_compute_the_same_function() -> None:
    """The same weights in float32 and float64 give the same output (1e-5)."""
    rgb, fov = _inputs(1, 16, 20, dtype=torch.float64)
    out64 = _net(zero_init_tail=False).double()(rgb, fov)
    out32 = _net(zero_init_tail=False)(rgb.float(), fov.float())
    torch.testing.assert_close(out32.double(), out64, atol=1e-5, rtol=0)


def test_shift_equivariant_for_multiples_of_the_grid_only() -> None:
    """Without FOV input the network is a translation-equivariant filter for shifts that
    are multiples of size_multiple: shifting the input by 4 columns shifts the output by 4
    (1e-5) wherever neither window touches the border (the hand-derived receptive field);
    a 1-column shift does not commute (the strided convs sample another grid)."""
    net = _net(zero_init_tail=False, use_fov=False)
    assert net.size_multiple == 4
    width = 160
    rgb = torch.rand(1, 3, 8, width + 4, generator=torch.Generator().manual_seed(5))
    lo, hi = _receptive_columns(0, DEPTH)
    interior = slice(-lo + 4, width - hi - 4)
    for shift, equal in ((4, True), (1, False)):
        a = net(rgb[..., shift : shift + width])[..., interior]
        b = net(rgb[..., :width])[..., shift:][..., interior]
        assert torch.allclose(a, b, atol=1e-5) == equal, shift
