"""The field-aware restoration UNet (the paper's "Aberrations Image Recovery" section).

Architecture (scales s = 0 .. depth-1 with widths[s] channels, s = 0 at full resolution):

* input: aberrated RGB (B, 3, H, W) plus, when ``use_fov``, the 2 FOV channels of
  :func:`lensim.restore.fov.fov_channels` (each pixel's absolute sensor position divided by
  the sensor half-diagonal), concatenated to 5 channels;
* encoder: a 3x3 head conv and one residual block (conv3x3-ReLU-conv3x3 + skip) at scale 0;
  at each further scale a stride-2 3x3 conv (+ReLU) and one residual block;
* bottleneck (smallest scale), when ``use_context``: a context block: four parallel 3x3
  convs with dilations 1, 2, 4, 8 (widths[-1] -> widths[-1] // 4 each, ReLU), concatenated,
  fused by a 1x1 conv, added to its input. Without it the bottleneck is the identity;
* decoder, scales depth-2 .. 0: 2x2 stride-2 transposed conv up, concatenation with the
  encoder skip, 1x1 fusion conv, then one *deformable residual block* when
  ``use_deformable`` (else a plain residual block): a 3x3 conv over [features, 2x upsampled
  offsets of the coarser decoder scale (in that scale's pixels, so multiplied by 2)] predicts
  offsets (2*G*9 channels, pixels) and mask logits (G*9, sigmoid) for a modulated deformable
  3x3 conv (DCNv2) followed by ReLU and a 3x3 conv, added to the block's input. The coarsest
  decoder scale has no coarser offsets and predicts them from its features alone. The
  offset/mask conv is zero-initialised (offsets 0, masks 0.5 at init, as in DCNv2);
* field modulation, when ``field_modulation`` (a lensim extension, not in the paper; needs
  ``use_fov``): the blur a pixel needs undone is a function of its position, so at the
  bottleneck and at every decoder scale the features are scaled and shifted per channel
  by functions of the position: feat * (1 + gamma) + beta, with (gamma, beta) from a small
  per-pixel MLP (1x1 conv 5 -> 16, ReLU, 1x1 conv 16 -> 2C, last layer zero-initialised)
  of the field features (x, y, x^2 - y^2, 2xy, x^2 + y^2) of the FOV channels averaged
  down to that scale. These five are the position's natural basis for a rotationally
  symmetric lens: the PSF's size follows the radius and its orientation the azimuth
  (cos 2 theta, sin 2 theta). The deformable blocks see the modulated features, so their
  offsets can follow the local PSF directly. It adds about 1 % to the parameters;
* shooting settings, when ``settings_dim`` k > 0 (issue 16; lensim.restore.conditioning):
  the k-vector (normalized F-number, focus dioptres, focal length over the trained range)
  enters as k constant input channels, and at the bottleneck and every decoder scale the
  features get a per-channel FiLM, feat * (1 + gamma) + beta with (gamma, beta) from an MLP
  of the vector (Linear k -> 32, ReLU, Linear 32 -> 2C, last layer zero-initialised); with
  field modulation its MLP also sees the k values, so the position-dependent modulation
  follows the settings too (how far the PSF grows towards the corner depends on the
  aperture). With k = 0 none of this exists and the network is exactly the one before;
* tail: a 3x3 conv to 3 channels, **zero-initialised** (``zero_init_tail=True``), whose
  output is added to the input RGB: restored = rgb + residual, so the untrained network is
  exactly the identity.

Inputs of any size are padded on the bottom/right to a multiple of 2**(depth-1) (RGB by
edge replication, FOV channels by linear continuation, which is exact for the affine FOV
map) and the output is cropped back. Runs in the dtype of its parameters (float32 by
default).

Tiling: the strided convs make the network shift-equivariant only for shifts that are
multiples of ``size_multiple`` (a tile starting one pixel off the grid differed from the
whole-image result by about 1e-2 in a test), so tiles must start at multiples of it. The
receptive field radius with zero offsets is about 58 px for the default configuration and
about 118 px for the paper's 4-scale one (measured by back-propagating from one output
pixel), plus whatever the learned offsets add; tile margins must exceed it.

With ``use_fov=use_deformable=use_context=False`` this is a plain UNet;
:func:`plain_unet_matching` picks the width giving the same parameter count (within 10%)
as a given field-aware configuration, for the paper's ablation/baseline.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn as nn
import torch.nn.functional as F

from lensim.restore.arch_rules import check_switches
from lensim.restore.conditioning import batch_settings, settings_planes
from lensim.restore.deform import ModulatedDeformConv2d
from lensim.restore.fov import batch_fov

KERNEL_TAPS = 9  # 3x3 deformable kernels


def count_parameters(model: nn.Module) -> int:
    """Number of trainable scalars in ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def _conv3(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation)


class ResBlock(nn.Module):
    """x + conv3x3(ReLU(conv3x3(x))); (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, ch: int) -> None:
        super().__init__()
        self.conv1 = _conv3(ch, ch)
        self.conv2 = _conv3(ch, ch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(x)))


class ContextBlock(nn.Module):
    """Parallel dilated 3x3 convs (dilations 1, 2, 4, 8; ch -> ch // 4 each, ReLU),
    concatenated, fused by a 1x1 conv, residual. (B, ch, H, W) -> (B, ch, H, W)."""

    DILATIONS: tuple[int, ...] = (1, 2, 4, 8)

    def __init__(self, ch: int) -> None:
        super().__init__()
        branch = max(1, ch // len(self.DILATIONS))
        self.branches = nn.ModuleList(_conv3(ch, branch, dilation=d) for d in self.DILATIONS)
        self.fuse = nn.Conv2d(branch * len(self.DILATIONS), ch, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = torch.cat([F.relu(b(x)) for b in self.branches], dim=1)
        return x + self.fuse(y)


FIELD_FEATURES = 5


def field_features(fov: torch.Tensor) -> torch.Tensor:
    """(B, 2, H, W) FOV channels (x, y) -> (B, 5, H, W): x, y, x^2 - y^2, 2xy, x^2 + y^2."""
    x, y = fov[:, 0:1], fov[:, 1:2]
    return torch.cat((x, y, x * x - y * y, 2 * x * y, x * x + y * y), dim=1)


class FieldModulation(nn.Module):
    """feat * (1 + gamma) + beta, (gamma, beta) = MLP(field features) per pixel; the identity
    at initialisation. forward(feat (B, ch, H, W), feats (B, 5 + extra, H, W)) -> (B, ch, H, W);
    ``extra``: further per-pixel inputs (the settings planes of a conditioned network, so the
    modulation is a joint function of position and settings)."""

    HIDDEN = 16

    def __init__(self, ch: int, extra: int = 0) -> None:
        super().__init__()
        self.hidden = nn.Conv2d(FIELD_FEATURES + extra, self.HIDDEN, 1)
        self.out = nn.Conv2d(self.HIDDEN, 2 * ch, 1)
        nn.init.zeros_(self.out.weight)
        assert self.out.bias is not None
        nn.init.zeros_(self.out.bias)

    def forward(self, feat: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
        gamma, beta = self.out(F.relu(self.hidden(feats))).chunk(2, dim=1)
        return feat * (1.0 + gamma) + beta


class SettingsModulation(nn.Module):
    """FiLM by the shooting settings: feat * (1 + gamma) + beta with per-channel (gamma,
    beta) = MLP(settings vector) (Linear k -> 32, ReLU, Linear 32 -> 2ch, the last layer
    zero-initialised: the identity at initialisation).
    forward(feat (B, ch, H, W), settings (B, k)) -> (B, ch, H, W)."""

    HIDDEN = 32

    def __init__(self, ch: int, settings_dim: int) -> None:
        super().__init__()
        self.hidden = nn.Linear(settings_dim, self.HIDDEN)
        self.out = nn.Linear(self.HIDDEN, 2 * ch)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, feat: torch.Tensor, settings: torch.Tensor) -> torch.Tensor:
        gamma, beta = self.out(F.relu(self.hidden(settings)))[:, :, None, None].chunk(2, dim=1)
        return feat * (1.0 + gamma) + beta


class DeformResBlock(nn.Module):
    """Residual block whose first conv is a modulated deformable 3x3 conv.

    forward(x (B, ch, H, W), coarse_offset (B, 2*G*9, H/2, W/2) or None) ->
    (x + conv3x3(ReLU(DCN(x))) (B, ch, H, W), offset (B, 2*G*9, H, W) in pixels of this
    scale). Offsets and mask logits come from one 3x3 conv over the features concatenated
    with the coarser offsets upsampled 2x (bilinear) and doubled (pixel units halve).
    """

    def __init__(self, ch: int, deformable_groups: int, coarse_offsets: bool, backend: str = "auto") -> None:
        super().__init__()
        self.groups = deformable_groups
        self.coarse_offsets = coarse_offsets
        n_off = 2 * deformable_groups * KERNEL_TAPS
        n_mask = deformable_groups * KERNEL_TAPS
        self.offset_conv = _conv3(ch + (n_off if coarse_offsets else 0), n_off + n_mask)
        nn.init.zeros_(self.offset_conv.weight)
        assert self.offset_conv.bias is not None
        nn.init.zeros_(self.offset_conv.bias)
        self.dcn = ModulatedDeformConv2d(ch, ch, 3, deformable_groups, backend=backend)
        self.conv2 = _conv3(ch, ch)

    def forward(self, x: torch.Tensor, coarse_offset: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        if self.coarse_offsets:
            if coarse_offset is None:
                raise ValueError("this block expects the offsets of the coarser scale")
            up = 2.0 * F.interpolate(coarse_offset, size=x.shape[-2:], mode="bilinear", align_corners=False)
            inp = torch.cat((x, up), dim=1)
        else:
            inp = x
        om = self.offset_conv(inp)
        n_off = 2 * self.groups * KERNEL_TAPS
        offset = om[:, :n_off]
        mask = torch.sigmoid(om[:, n_off:])
        y = self.conv2(F.relu(self.dcn(x, offset, mask)))
        return x + y, offset


def _pad_bottom_right(x: torch.Tensor, ph: int, pw: int, linear: bool) -> torch.Tensor:
    """Pad (B, C, H, W) by ph rows / pw columns at the bottom / right: edge replication, or
    linear continuation from the last two rows/columns when ``linear`` (replication where
    the size is 1)."""
    if ph:
        if linear and x.shape[-2] >= 2:
            step = x[..., -1:, :] - x[..., -2:-1, :]
            k = torch.arange(1, ph + 1, dtype=x.dtype, device=x.device).view(ph, 1)
            x = torch.cat((x, x[..., -1:, :] + k * step), dim=-2)
        else:
            x = torch.cat((x, x[..., -1:, :].expand(*x.shape[:-2], ph, x.shape[-1])), dim=-2)
    if pw:
        if linear and x.shape[-1] >= 2:
            step = x[..., :, -1:] - x[..., :, -2:-1]
            k = torch.arange(1, pw + 1, dtype=x.dtype, device=x.device).view(1, pw)
            x = torch.cat((x, x[..., :, -1:] + k * step), dim=-1)
        else:
            x = torch.cat((x, x[..., :, -1:].expand(*x.shape[:-1], pw)), dim=-1)
    return x


class FieldAwareUNet(nn.Module):
    """Field-aware restoration UNet; see the module docstring for the architecture.

    Args:
        width: channels at full resolution; scale s has width * 2**s (ignored if ``widths``).
        depth: number of scales (>= 2); depth - 1 stride-2 downsamplings.
        use_fov: take the 2 FOV channels as extra input.
        use_deformable: deformable residual blocks in the decoder (plain ones otherwise).
        use_context: context block at the smallest scale (identity otherwise).
        deformable_groups: G, offset/mask groups of each DCN; must divide the decoder widths.
            The offset/mask conv has 27G outputs at every decoder scale (full resolution
            included), so G drives the cost: on 2 CPU cores a training step of the default
            net took about 1.4x as long with G=4 as with G=2 (G=1 and G=2 cost about the
            same). Default 2; the paper used 8.
        widths: explicit per-scale channel counts (overrides width/depth), e.g. the paper's
            (32, 64, 128, 256) with deformable_groups=8.
        zero_init_tail: zero the last conv so the untrained network is the identity.
        dcn_backend: "auto", "grid_sample" or "torchvision" (see lensim.restore.deform).
        deformable_scales: how many decoder scales, coarsest first, use deformable blocks
            (the rest use plain residual blocks); None: all of them (the paper). On a CPU
            the full-resolution DCN is most of the cost: 1 (deformable at the coarsest
            decoder scale only) trains about twice as fast as all.
        field_modulation: position-dependent feature modulation at the bottleneck and every
            decoder scale (see the module docstring; requires use_fov).
        settings_dim: k, the length of the shooting-settings vector the network is conditioned
            on (lensim.restore.conditioning; 0: none). The k values enter as constant input
            channels (settings_planes) and as per-channel FiLM (SettingsModulation) at the
            bottleneck and every decoder scale; with field_modulation the field MLP also
            sees them, so the position-dependent modulation depends on the settings.
        arch: "unet", the name lensim.restore.models.build_model knows this class by (it is
            in ``config``, so a config rebuilds the network either way).

    forward(rgb (B, 3, H, W), fov (B, 2, H, W) or (2, H, W), required iff use_fov,
    settings (B, k) or (k,), required iff settings_dim > 0) ->
    restored (B, 3, H, W), same dtype as rgb. Values are whatever range the caller trains
    with (the network adds a residual; nothing is clamped).
    """

    def __init__(
        self,
        width: int = 32,
        depth: int = 3,
        use_fov: bool = True,
        use_deformable: bool = True,
        use_context: bool = True,
        deformable_groups: int = 2,
        widths: Sequence[int] | None = None,
        zero_init_tail: bool = True,
        dcn_backend: str = "auto",
        deformable_scales: int | None = None,
        field_modulation: bool = False,
        settings_dim: int = 0,
        arch: str = "unet",
    ) -> None:
        super().__init__()
        if arch != "unet":
            raise ValueError(f"arch must be 'unet' for FieldAwareUNet, got {arch!r}")
        ws = tuple(int(w) for w in widths) if widths is not None else tuple(width * 2**s for s in range(depth))
        if len(ws) < 2:
            raise ValueError(f"need at least 2 scales, got widths {ws}")
        if settings_dim < 0:
            raise ValueError(f"settings_dim must be >= 0, got {settings_dim}")
        if any(w < 1 for w in ws):
            raise ValueError(f"widths must be positive, got {ws}")
        check_switches(  # which architecture takes which switches (lensim.restore.arch_rules)
            "unet",
            use_fov=use_fov,
            use_deformable=use_deformable,
            deformable_groups=deformable_groups,
            deformable_scales=deformable_scales,
            field_modulation=field_modulation,
            widths=ws,
        )
        n_dec = len(ws) - 1
        self.widths = ws
        self.depth = len(ws)
        self.deformable_scales = n_dec if deformable_scales is None else int(deformable_scales)
        self.use_fov = use_fov
        self.use_deformable = use_deformable
        self.use_context = use_context
        self.field_modulation = field_modulation
        self.deformable_groups = deformable_groups
        self.zero_init_tail = zero_init_tail
        self.dcn_backend = dcn_backend
        self.settings_dim = int(settings_dim)

        self.head = _conv3((5 if use_fov else 3) + self.settings_dim, ws[0])
        self.enc0 = ResBlock(ws[0])
        self.down = nn.ModuleList(
            nn.Sequential(_conv3(ws[s - 1], ws[s], stride=2), nn.ReLU(), ResBlock(ws[s])) for s in range(1, len(ws))
        )
        self.context: nn.Module = ContextBlock(ws[-1]) if use_context else nn.Identity()
        # Decoder modules are listed coarse to fine: index i works at scale depth-2-i.
        dec_scales = list(range(len(ws) - 2, -1, -1))
        self.up = nn.ModuleList(nn.ConvTranspose2d(ws[s + 1], ws[s], 2, stride=2) for s in dec_scales)
        self.fuse = nn.ModuleList(nn.Conv2d(2 * ws[s], ws[s], 1) for s in dec_scales)
        n_deform = self.deformable_scales if use_deformable else 0
        self.dec = nn.ModuleList(
            DeformResBlock(ws[s], deformable_groups, coarse_offsets=i > 0, backend=dcn_backend)
            if i < n_deform
            else ResBlock(ws[s])
            for i, s in enumerate(dec_scales)
        )
        # modulations listed coarse to fine: the bottleneck, then the decoder scales
        self.modulate = (
            nn.ModuleList(FieldModulation(ws[s], self.settings_dim) for s in [len(ws) - 1, *dec_scales])
            if field_modulation
            else None
        )
        # settings FiLM, likewise the bottleneck then the decoder scales (none when settings_dim is 0)
        self.film = (
            nn.ModuleList(SettingsModulation(ws[s], self.settings_dim) for s in [len(ws) - 1, *dec_scales])
            if self.settings_dim
            else None
        )
        self.tail = _conv3(ws[0], 3)
        if zero_init_tail:
            nn.init.zeros_(self.tail.weight)
            assert self.tail.bias is not None
            nn.init.zeros_(self.tail.bias)

    @property
    def size_multiple(self) -> int:
        """Inputs are padded internally to a multiple of this (2**(depth-1))."""
        return 2 ** (self.depth - 1)

    @property
    def config(self) -> dict[str, Any]:
        """Constructor arguments that rebuild this architecture (for checkpoints)."""
        return {
            "arch": "unet",
            "widths": list(self.widths),
            "use_fov": self.use_fov,
            "use_deformable": self.use_deformable,
            "use_context": self.use_context,
            "deformable_groups": self.deformable_groups,
            "zero_init_tail": self.zero_init_tail,
            "dcn_backend": self.dcn_backend,
            "deformable_scales": self.deformable_scales,
            "field_modulation": self.field_modulation,
            "settings_dim": self.settings_dim,
        }

    def _inputs(
        self, rgb: torch.Tensor, fov: torch.Tensor | None, settings: torch.Tensor | None, ph: int, pw: int
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The padded input stack (RGB [+ FOV] [+ settings planes]), the padded FOV channels
        and the (B, k) settings (None where unused)."""
        b = rgb.shape[0]
        x = _pad_bottom_right(rgb, ph, pw, linear=False)
        if self.use_fov:
            fov = _pad_bottom_right(batch_fov(fov, rgb), ph, pw, linear=True)
            x = torch.cat((x, fov), dim=1)
        s = batch_settings(settings, b, self.settings_dim, rgb)
        if s is not None:
            x = torch.cat((x, settings_planes(s, x.shape[-2], x.shape[-1])), dim=1)
        return x, fov, s

    def _modulate(self, i: int, feat: torch.Tensor, fov: torch.Tensor | None, s: torch.Tensor | None) -> torch.Tensor:
        """The field and settings modulations of level i (0: the bottleneck, i: decoder step i),
        where the network has them."""
        if self.modulate is not None:
            assert fov is not None
            factor = self.size_multiple // 2**i
            pooled = field_features(F.avg_pool2d(fov, factor) if factor > 1 else fov)
            if s is not None:
                pooled = torch.cat((pooled, settings_planes(s, pooled.shape[-2], pooled.shape[-1])), dim=1)
            feat = self.modulate[i](feat, pooled)
        if self.film is not None:
            assert s is not None
            feat = self.film[i](feat, s)
        return feat

    def forward(
        self, rgb: torch.Tensor, fov: torch.Tensor | None = None, settings: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, 3, H, W) [+ FOV (B, 2, H, W) or (2, H, W)] [+ settings (B, k) or (k,)] -> (B, 3, H, W)."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W), got {tuple(rgb.shape)}")
        _, _, h, w = rgb.shape
        m = self.size_multiple
        x, fov, s = self._inputs(rgb, fov, settings, (-h) % m, (-w) % m)
        feat = self.enc0(self.head(x))
        skips = [feat]
        for down in self.down:
            feat = down(feat)
            skips.append(feat)
        feat = self._modulate(0, self.context(skips.pop()), fov, s)
        offset: torch.Tensor | None = None
        for i, (up, fuse, dec) in enumerate(zip(self.up, self.fuse, self.dec)):
            feat = self._modulate(i + 1, fuse(torch.cat((up(feat), skips.pop()), dim=1)), fov, s)
            if isinstance(dec, DeformResBlock):
                feat, offset = dec(feat, offset)
            else:
                feat = dec(feat)
        residual = self.tail(feat)
        return rgb + residual[..., :h, :w]


def _plain_count(width: int, depth: int) -> int:
    with torch.device("meta"):
        model = FieldAwareUNet(width, depth, use_fov=False, use_deformable=False, use_context=False)
    return count_parameters(model)


def plain_unet_width(target_params: int, depth: int = 3) -> int:
    """Width of the plain UNet (all switches off, ``depth`` scales) whose parameter count is
    closest to ``target_params``. Raises ValueError if even the best is more than 10% off."""
    if target_params < 1:
        raise ValueError(f"target_params must be positive, got {target_params}")
    # The plain count is an exact quadratic a w^2 + b w + c in the width: fit, solve, refine.
    n1, n2, n3 = (_plain_count(w, depth) for w in (1, 2, 3))
    a = (n3 - 2 * n2 + n1) / 2.0
    bq = n2 - n1 - 3 * a
    c = n1 - a - bq
    disc = bq * bq - 4 * a * (c - target_params)
    guess = max(1, round((-bq + max(disc, 0.0) ** 0.5) / (2 * a)))
    candidates = {w: _plain_count(w, depth) for w in range(max(1, guess - 2), guess + 3)}
    best = min(candidates, key=lambda w: abs(candidates[w] - target_params))
    if abs(candidates[best] - target_params) > 0.1 * target_params:
        raise ValueError(
            f"no plain UNet width within 10% of {target_params} parameters (closest: width {best}, {candidates[best]})"
        )
    return best


def plain_unet_matching(reference: nn.Module | int, depth: int | None = None) -> FieldAwareUNet:
    """A plain UNet (use_fov=use_deformable=use_context=False) with the parameter count of
    ``reference`` (a model or a count) within 10%, and the same number of scales as the
    reference model (or ``depth``, default 3, when a count is given)."""
    if isinstance(reference, nn.Module):
        target = count_parameters(reference)
        if depth is None:
            depth = int(getattr(reference, "depth", 3))
    else:
        target = int(reference)
        depth = 3 if depth is None else depth
    width = plain_unet_width(target, depth)
    return FieldAwareUNet(width, depth, use_fov=False, use_deformable=False, use_context=False)


__all__ = [
    "ContextBlock",
    "DeformResBlock",
    "FieldAwareUNet",
    "FieldModulation",
    "ResBlock",
    "SettingsModulation",
    "count_parameters",
    "field_features",
    "plain_unet_matching",
    "plain_unet_width",
]
