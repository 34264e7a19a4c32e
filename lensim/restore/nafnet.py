"""NAFNet (Chen, Chu, Zhang, Sun, "Simple Baselines for Image Restoration", ECCV 2022) as a
restoration baseline, with lensim's field-aware switches.

Block (the paper's NAFBlock, channels c, expansions 2 and 2), (B, c, H, W) -> same:

    y = x + beta  * conv1x1_{c->c}( SCA( SimpleGate( dwconv3x3_{2c}( conv1x1_{c->2c}( LN(x) ) ) ) ) )
    z = y + gamma * conv1x1_{c->c}( SimpleGate( conv1x1_{c->2c}( LN(y) ) ) )

LN is a layer norm over the channels of each pixel (weight and bias per channel, eps 1e-6),
SimpleGate splits the channels in two halves and multiplies them (2c -> c), SCA (simplified
channel attention) multiplies its input by a 1x1 conv (c -> c) of its average, and beta and
gamma are per-channel scales initialised to zero (every block starts as the identity). All
convs have biases. Parameters per block: 7 c^2 + 33 c (LN 2 x 2c, conv 2c^2 + 2c, depthwise
18c + 2c, SCA c^2 + c, conv c^2 + c, conv 2c^2 + 2c, conv c^2 + c, beta and gamma 2c). The
paper's dropout is left out (rate 0 in its restoration models).

SCA pools locally here, not over the whole image: the mean is taken over a
``sca_window`` x ``sca_window`` box around each pixel at the block's own scale (pixels
outside the image do not count). The paper's global mean makes every output pixel depend
on the whole input, so tiled restoration could never equal whole-image restoration, and it
differs between 96-pixel training crops and large photos at test time (the mismatch Chu et
al., "Improving Image Restoration by Revisiting Global Information Aggregation", ECCV 2022,
remove by pooling locally at test time). The parameters are those of the paper's block.

Network (a UNet of NAFBlocks, as the paper's NAFNet): optional pixel-unshuffle stem (``stem``
= 2: the input's 2x2 blocks become channels, every layer runs at half resolution and the
output is pixel-shuffled back: about 4x less work per pixel); 3x3 intro conv; at each
encoder scale ``enc_blocks[s]`` NAFBlocks, then a stride-2 2x2 conv (c -> 2c); at the
smallest scale ``middle_blocks`` NAFBlocks (and, when ``use_context``, lensim's context
block: dilated 3x3 convs, lensim.restore.network.ContextBlock); at each decoder scale a
1x1 conv (c -> 2c, no bias) + PixelShuffle(2) up, the encoder skip added, optionally a
deformable residual block (lensim.restore.network.DeformResBlock, DCNv2 via grid_sample,
offsets passed from coarse to fine as in FieldAwareUNet; ``deformable_scales`` coarsest
decoder scales), then ``dec_blocks`` NAFBlocks; a 3x3 ending conv to 3 channels (x stem^2
before the pixel shuffle), **zero-initialised**, added to the input: the untrained network
is the identity, like FieldAwareUNet.

Inputs: RGB (B, 3, H, W); with ``use_fov`` the 2 FOV channels (lensim.restore.fov); with
``settings_dim`` > 0 the shooting-settings vector (B, settings_dim) broadcast to constant
planes (lensim.restore.conditioning.settings_planes). All are concatenated at the input
(the UNet also applies a FiLM per scale; NAFNet takes the settings at the input only). Sizes are padded at the bottom/right to a
multiple of ``size_multiple`` (stem * 2**scales-1) like FieldAwareUNet and cropped back.

Receptive field (radius in input pixels with zero offsets, measured by back-propagating
from one output pixel; tests/test_nafnet.py checks these): 31 px for the default (stem 1,
widths w/2w/4w, blocks 1/1, 2, 1/1, SCA window 3), 62 px with stem 2, 63 px with the
context block, 46 px with SCA window 5; plus what learned offsets add. They fit the
default tile margin of `lensim restore` (72 px at overlap 192) except stem 2 with the
context block (about 126 px).

Tiles (`lensim restore`, lensim.restore.infer.default_overlap): NAFNet's networks overlap
by 96 px by default (margin 36 px), not the UNet's 192: far fewer pixels are computed twice
(1.5x instead of 2.6x at 512 px tiles). The exact receptive field reaches further, but
what lies beyond 36 px changes an output by less than float32 rounding: against
whole-image inference, the largest difference at overlap 96 was 2.4e-7 for the shipped
universal model on a photo, and 2e-7 to 2e-6 (outputs up to 4.4) for randomly perturbed
networks of the default, the stem-2 width-46 and a width-64 (2, 2 / 4 / 2, 2 blocks)
layout (tests/test_infer_overlap.py); at overlap 64 the universal model's difference
was 1.4e-4. The context block, deformable convs, wider SCA windows and more scales keep
192.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn as nn
import torch.nn.functional as F

from lensim.restore.arch_rules import check_switches
from lensim.restore.conditioning import batch_settings, settings_planes
from lensim.restore.fov import batch_fov
from lensim.restore.network import ContextBlock, DeformResBlock, _pad_bottom_right, count_parameters


class LayerNorm2d(nn.Module):
    """Layer norm over the channels of every pixel: (x - mean_c) / sqrt(var_c + eps) * weight
    + bias, weight and bias (C,). (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, ch: int, eps: float = 1e-6) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(ch))
        self.bias = nn.Parameter(torch.zeros(ch))
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.is_contiguous(memory_format=torch.channels_last) and not torch.onnx.is_in_onnx_export():
            # channels_last (CPU inference): the channels are the last axis of the NHWC view,
            # where torch's layer norm is one fused pass instead of the nine below
            y = F.layer_norm(x.permute(0, 2, 3, 1), (x.shape[1],), self.weight, self.bias, self.eps)
            return y.permute(0, 3, 1, 2)
        mu = x.mean(1, keepdim=True)
        d = x - mu
        var = (d * d).mean(1, keepdim=True)
        return d * torch.rsqrt(var + self.eps) * self.weight.view(1, -1, 1, 1) + self.bias.view(1, -1, 1, 1)


def simple_gate(x: torch.Tensor) -> torch.Tensor:
    """SimpleGate: (B, 2c, H, W) -> first half * second half, (B, c, H, W)."""
    a, b = x.chunk(2, dim=1)
    return a * b


def box_mean(x: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over a window x window box centred on each pixel (odd window), counting only
    pixels inside the image. (B, C, H, W) -> same. A depthwise conv with a kernel of ones
    divided by the count of pixels inside (about 7x faster on a CPU than stride-1
    average pooling)."""
    r = window // 2
    if r == 0:
        return x
    # int(): the kernel's shape is a constant of the network (an ONNX export needs it static)
    ch, (h, w) = int(x.shape[1]), x.shape[-2:]
    ones = torch.ones(ch, 1, window, window, dtype=x.dtype, device=x.device)
    total = F.conv2d(x, ones, padding=r, groups=ch)
    count = F.conv2d(torch.ones(1, 1, h, w, dtype=x.dtype, device=x.device), ones[:1], padding=r)
    return total / count


class NAFBlock(nn.Module):
    """The paper's NAFBlock (module docstring), SCA pooled over a local box.
    (B, c, H, W) -> (B, c, H, W); 7 c^2 + 33 c parameters."""

    def __init__(self, ch: int, sca_window: int = 3) -> None:
        super().__init__()
        if sca_window < 1 or sca_window % 2 != 1:
            raise ValueError(f"sca_window must be a positive odd number of pixels, got {sca_window}")
        self.sca_window = sca_window
        self.norm1 = LayerNorm2d(ch)
        self.conv1 = nn.Conv2d(ch, 2 * ch, 1)
        self.conv2 = nn.Conv2d(2 * ch, 2 * ch, 3, padding=1, groups=2 * ch)
        self.sca = nn.Conv2d(ch, ch, 1)
        self.conv3 = nn.Conv2d(ch, ch, 1)
        self.norm2 = LayerNorm2d(ch)
        self.conv4 = nn.Conv2d(ch, 2 * ch, 1)
        self.conv5 = nn.Conv2d(ch, ch, 1)
        self.beta = nn.Parameter(torch.zeros(1, ch, 1, 1))
        self.gamma = nn.Parameter(torch.zeros(1, ch, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        t = simple_gate(self.conv2(self.conv1(self.norm1(x))))
        t = t * self.sca(box_mean(t, self.sca_window))
        y = torch.addcmul(x, self.beta, self.conv3(t))  # x + beta * conv3(t) in one pass
        t = simple_gate(self.conv4(self.norm2(y)))
        return torch.addcmul(y, self.gamma, self.conv5(t))


def _blocks(ch: int, n: int, sca_window: int) -> nn.Sequential:
    return nn.Sequential(*(NAFBlock(ch, sca_window) for _ in range(n)))


class NAFNet(nn.Module):
    """NAFNet with lensim's field-aware switches; see the module docstring.

    Args:
        width: channels of the first scale; scale s has width * 2**s.
        enc_blocks: NAFBlocks per encoder scale (one entry per downsampling).
        middle_blocks: NAFBlocks at the smallest scale.
        dec_blocks: NAFBlocks per decoder scale, coarsest first (same length as enc_blocks).
        use_fov: take the 2 FOV channels as extra input.
        use_deformable: a deformable residual block at the ``deformable_scales`` coarsest
            decoder scales (DCNv2, ``deformable_groups`` offset groups).
        use_context: lensim's context block after the middle blocks.
        stem: 1, or 2 for a pixel-unshuffle stem (all layers at half resolution).
        sca_window: side of the SCA's local pooling box, pixels at each block's scale (odd).
        settings_dim: length of the shooting-settings vector taken as constant input planes
            (0: none; lensim.restore.conditioning builds the vector).
        zero_init_tail: zero the ending conv so the untrained network is the identity.
        dcn_backend: "auto", "grid_sample" or "torchvision" (lensim.restore.deform).

    forward(rgb (B, 3, H, W), fov (B, 2, H, W) or (2, H, W) iff use_fov, settings
    (B, settings_dim) or (settings_dim,) iff settings_dim) -> restored (B, 3, H, W), rgb's
    dtype.
    """

    def __init__(
        self,
        width: int = 16,
        enc_blocks: Sequence[int] = (1, 1),
        middle_blocks: int = 2,
        dec_blocks: Sequence[int] = (1, 1),
        use_fov: bool = False,
        use_deformable: bool = False,
        use_context: bool = False,
        deformable_groups: int = 2,
        deformable_scales: int = 1,
        stem: int = 1,
        sca_window: int = 3,
        settings_dim: int = 0,
        zero_init_tail: bool = True,
        dcn_backend: str = "auto",
        arch: str = "nafnet",
    ) -> None:
        super().__init__()
        enc, dec = tuple(int(n) for n in enc_blocks), tuple(int(n) for n in dec_blocks)
        _check_args(arch, width, enc, dec, middle_blocks, settings_dim)
        ws = tuple(width * 2**s for s in range(len(enc) + 1))
        check_switches(  # which architecture takes which switches (lensim.restore.arch_rules)
            "nafnet",
            use_fov=use_fov,
            use_deformable=use_deformable,
            deformable_groups=deformable_groups,
            deformable_scales=deformable_scales,
            stem=stem,
            widths=ws,
        )
        self.width, self.widths, self.enc_blocks, self.dec_blocks = width, ws, enc, dec
        self.middle_blocks, self.stem, self.sca_window = int(middle_blocks), int(stem), int(sca_window)
        self.use_fov, self.use_deformable, self.use_context = use_fov, use_deformable, use_context
        self.deformable_groups, self.deformable_scales = int(deformable_groups), int(deformable_scales)
        self.settings_dim, self.zero_init_tail, self.dcn_backend = int(settings_dim), zero_init_tail, dcn_backend

        cin = (3 + (2 if use_fov else 0) + self.settings_dim) * stem * stem
        self.intro = nn.Conv2d(cin, width, 3, padding=1)
        self.encoders = nn.ModuleList(_blocks(ws[s], n, sca_window) for s, n in enumerate(enc))
        self.downs = nn.ModuleList(nn.Conv2d(ws[s], ws[s + 1], 2, stride=2) for s in range(len(enc)))
        self.middle = _blocks(ws[-1], self.middle_blocks, sca_window)
        self.context: nn.Module = ContextBlock(ws[-1]) if use_context else nn.Identity()
        dec_scales = list(range(len(enc) - 1, -1, -1))  # coarse to fine
        self.ups = nn.ModuleList(
            nn.Sequential(nn.Conv2d(ws[s + 1], 2 * ws[s + 1], 1, bias=False), nn.PixelShuffle(2)) for s in dec_scales
        )
        n_deform = self.deformable_scales if use_deformable else 0
        self.deform = nn.ModuleList(
            DeformResBlock(ws[s], deformable_groups, coarse_offsets=i > 0, backend=dcn_backend)
            if i < n_deform
            else nn.Identity()
            for i, s in enumerate(dec_scales)
        )
        self.decoders = nn.ModuleList(_blocks(ws[s], n, sca_window) for s, n in zip(dec_scales, dec, strict=True))
        self.ending = nn.Conv2d(width, 3 * stem * stem, 3, padding=1)
        if zero_init_tail:
            nn.init.zeros_(self.ending.weight)
            assert self.ending.bias is not None
            nn.init.zeros_(self.ending.bias)

    @property
    def tile_overlap(self) -> int | None:
        """The tile overlap (pixels) `lensim restore` uses by default (the module docstring):
        96 for at most two downsamplings, a stem of at most 2 and SCA windows of 3 with no
        context block or deformable convs; None (lensim.restore.infer.DEFAULT_OVERLAP, 192)
        for the rest."""
        plain = not (self.use_context or self.use_deformable) and self.sca_window <= 3
        return 96 if plain and len(self.enc_blocks) <= 2 and self.stem <= 2 else None

    @property
    def tile_size(self) -> int | None:
        """The largest tile side (pixels) `lensim restore` uses by default: 1024 for the
        layouts that overlap by 96 px (:attr:`tile_overlap`; a 1024 px tile of the width-46
        stem-2 network takes about 0.5 GB on a CPU), None (lensim.restore.infer.DEFAULT_TILE,
        512) for the rest. Per pixel a tile of 1024 px costs what one of 512 px costs, and a
        24 MP frame then computes 1.21 times its pixels instead of 1.50 (overlap and edges)."""
        return 1024 if self.tile_overlap == 96 else None

    @property
    def size_multiple(self) -> int:
        """Inputs are padded internally to a multiple of this (stem * 2**len(enc_blocks))."""
        return self.stem * 2 ** len(self.enc_blocks)

    @property
    def config(self) -> dict[str, Any]:
        """Constructor arguments that rebuild this network (for checkpoints; build_model)."""
        return {
            "arch": "nafnet",
            "width": self.width,
            "enc_blocks": list(self.enc_blocks),
            "middle_blocks": self.middle_blocks,
            "dec_blocks": list(self.dec_blocks),
            "use_fov": self.use_fov,
            "use_deformable": self.use_deformable,
            "use_context": self.use_context,
            "deformable_groups": self.deformable_groups,
            "deformable_scales": self.deformable_scales,
            "stem": self.stem,
            "sca_window": self.sca_window,
            "settings_dim": self.settings_dim,
            "zero_init_tail": self.zero_init_tail,
            "dcn_backend": self.dcn_backend,
        }

    def _inputs(
        self,
        rgb: torch.Tensor,
        fov: torch.Tensor | None,
        settings: torch.Tensor | None,
        guide: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The padded input planes: RGB [+ guide (B, G, H, W), e.g. the PSF-informed
        network's Wiener image] [+ FOV] [+ settings], (B, C, H', W') (pixel-unshuffled by
        the stem)."""
        b, _, h, w = rgb.shape
        m = self.size_multiple
        ph, pw = (-h) % m, (-w) % m
        planes = [_pad_bottom_right(rgb, ph, pw, linear=False)]
        if guide is not None:
            planes.append(_pad_bottom_right(guide.to(rgb.dtype), ph, pw, linear=False))
        if self.use_fov:
            planes.append(_pad_bottom_right(batch_fov(fov, rgb), ph, pw, linear=True))
        s = batch_settings(settings, b, self.settings_dim, rgb)
        if s is not None:
            planes.append(settings_planes(s, h + ph, w + pw))
        x = torch.cat(planes, dim=1) if len(planes) > 1 else planes[0]
        return F.pixel_unshuffle(x, self.stem) if self.stem > 1 else x

    def forward(
        self, rgb: torch.Tensor, fov: torch.Tensor | None = None, settings: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, 3, H, W) [+ FOV (B, 2, H, W)] [+ settings (B, settings_dim)] -> (B, 3, H, W)."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W), got {tuple(rgb.shape)}")
        h, w = rgb.shape[-2:]
        return rgb + self._residual(self._inputs(rgb, fov, settings), h, w)

    def _residual(self, x: torch.Tensor, h: int, w: int) -> torch.Tensor:
        """The network's body on the input planes x (:meth:`_inputs`): the correction
        (B, 3, h, w) added to the image it refines."""
        if not self.training and x.device.type == "cpu" and not torch.onnx.is_in_onnx_export():
            # inference on a CPU in channels_last: 1.8x the restore speed of NCHW
            # (benchmarks/restore_speed.py; depthwise convs about 6x faster); training
            # keeps NCHW, where it measured faster
            x = x.contiguous(memory_format=torch.channels_last)
        feat = self.intro(x)
        skips = []
        for encoder, down in zip(self.encoders, self.downs, strict=True):
            feat = encoder(feat)
            skips.append(feat)
            feat = down(feat)
        feat = self.context(self.middle(feat))
        offset: torch.Tensor | None = None
        for up, deform, decoder in zip(self.ups, self.deform, self.decoders, strict=True):
            feat = up(feat) + skips.pop()
            if isinstance(deform, DeformResBlock):
                feat, offset = deform(feat, offset)
            feat = decoder(feat)
        residual = self.ending(feat)
        if self.stem > 1:
            residual = F.pixel_shuffle(residual, self.stem)
        return residual[..., :h, :w]


def _check_args(
    arch: str, width: int, enc: tuple[int, ...], dec: tuple[int, ...], middle: int, settings_dim: int
) -> None:
    """The constructor's structural arguments (ValueError naming the argument; the rules of
    which switches it takes: lensim.restore.arch_rules)."""
    if arch != "nafnet":
        raise ValueError(f"arch must be 'nafnet' for NAFNet, got {arch!r}")
    if width < 1:
        raise ValueError(f"width must be positive, got {width}")
    if not enc or len(enc) != len(dec):
        raise ValueError(f"enc_blocks {enc} and dec_blocks {dec} must be non-empty and of the same length")
    if any(n < 0 for n in enc + dec) or middle < 0:
        raise ValueError(f"block counts must be >= 0, got enc {enc}, middle {middle}, dec {dec}")
    if settings_dim < 0:
        raise ValueError(f"settings_dim must be >= 0, got {settings_dim}")


def nafblock_parameters(ch: int) -> int:
    """Parameters of one NAFBlock of ``ch`` channels by the paper's definition: 7 c^2 + 33 c."""
    return 7 * ch * ch + 33 * ch


def _count(width: int, arch: dict[str, Any]) -> int:
    with torch.device("meta"):
        return count_parameters(NAFNet(width=width, **arch))


def nafnet_width(target_params: int, **arch: Any) -> int:
    """Width of the NAFNet (other constructor arguments ``arch``) whose parameter count is
    closest to ``target_params``; ValueError if even the best is more than 10% off. The
    count grows with the width, so a bisection finds the crossing."""
    if target_params < 1:
        raise ValueError(f"target_params must be positive, got {target_params}")
    groups = int(arch.get("deformable_groups", 2)) if arch.get("use_deformable") else 1
    lo, hi = 1, 1
    while _count(hi * groups, arch) < target_params and hi < 4096:
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if _count(mid * groups, arch) < target_params else (lo, mid)
    cands = {w * groups: _count(w * groups, arch) for w in (lo, hi)}
    best = min(cands, key=lambda w: abs(cands[w] - target_params))
    if abs(cands[best] - target_params) > 0.1 * target_params:
        raise ValueError(
            f"no NAFNet width within 10% of {target_params} parameters (closest: width {best}, {cands[best]})"
        )
    return best


def nafnet_matching(reference: nn.Module | int, **arch: Any) -> NAFNet:
    """A NAFNet (constructor arguments ``arch`` but the width) with the parameter count of
    ``reference`` (a model or a count) within 10%."""
    target = count_parameters(reference) if isinstance(reference, nn.Module) else int(reference)
    return NAFNet(width=nafnet_width(target, **arch), **arch)


__all__ = [
    "LayerNorm2d",
    "NAFBlock",
    "NAFNet",
    "box_mean",
    "nafblock_parameters",
    "nafnet_matching",
    "nafnet_width",
    "simple_gate",
]
