"""The PSF-informed network (issue 23, ``arch="psfnet"``): NAFNet refining the Wiener
stage's image.

Inputs at every pixel: the aberrated image (RGB), the Wiener stage's image (RGB: the
lens's PSF bank deconvolved per tile, lensim.restore.psf_stage), the two FOV channels and,
for a conditioned network, the shooting-settings planes; all concatenated at the input of
the default network's body (lensim.restore.nafnet.NAFNet: NAFBlocks, pixel-unshuffle stem,
local channel attention, so tiles equal whole images). The output is the Wiener image plus
a correction, the last conv zero-initialised: the untrained network is the Wiener stage
(Deep Wiener Deconvolution, Dong et al. NeurIPS 2020: a Wiener step with the known PSF,
then a refinement network).

Lens-agnostic: nothing but the Wiener image (through the bank) and the FOV channels tells
the network which lens it corrects, so one network can serve many lenses (the universal
model builds on this).

forward(rgb (B, 3, H, W), fov (B, 2, H, W), settings (B, D) or None, wiener (B, 3, H, W))
-> (B, 3, H, W); every image in sRGB [0, 1]. Models built by lensim.restore.models carry
``uses_wiener`` (True here) and ``stage`` (the WienerStage that made their inputs).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
import torch.nn as nn

from lensim.restore.nafnet import NAFNet
from lensim.restore.psf_stage import WienerStage

#: Channels of the Wiener image.
WIENER_CHANNELS = 3


class PSFNet(NAFNet):
    """NAFNet with the Wiener stage's image as a second RGB input, refining it (module
    docstring). Arguments as NAFNet's, plus ``stage``: the WienerStage's dict that makes
    its ``wiener`` input (None: the defaults), recorded in :attr:`config`."""

    uses_wiener = True

    def __init__(self, stage: Mapping[str, Any] | None = None, arch: str = "psfnet", **kwargs: Any) -> None:
        if arch != "psfnet":
            raise ValueError(f"arch must be 'psfnet' for PSFNet, got {arch!r}")
        super().__init__(**kwargs)  # NAFNet's arguments (keywords), its arch "nafnet"
        self.stage = WienerStage.from_dict(stage, "PSFNet")
        old = self.intro
        self.intro = nn.Conv2d(old.in_channels + WIENER_CHANNELS * self.stem**2, old.out_channels, 3, padding=1)

    @property
    def config(self) -> dict[str, Any]:
        """Constructor arguments that rebuild this network (build_model)."""
        return {**super().config, "arch": "psfnet", "stage": self.stage.to_dict()}

    def forward(  # type: ignore[override]
        self,
        rgb: torch.Tensor,
        fov: torch.Tensor | None = None,
        settings: torch.Tensor | None = None,
        wiener: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(B, 3, H, W) aberrated [+ FOV] [+ settings] + the Wiener image (B, 3, H, W) ->
        the restored image (B, 3, H, W), the Wiener image plus a correction."""
        if rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"rgb must be (B, 3, H, W), got {tuple(rgb.shape)}")
        if wiener is None or tuple(wiener.shape) != tuple(rgb.shape):
            raise ValueError(
                f"wiener must be the Wiener stage's image of rgb's shape {tuple(rgb.shape)} "
                f"(lensim.restore.psf_stage), got {None if wiener is None else tuple(wiener.shape)}"
            )
        h, w = rgb.shape[-2:]
        wiener = wiener.to(rgb.dtype)
        return wiener + self._residual(self._inputs(rgb, fov, settings, wiener), h, w)


def uses_wiener(model: Any) -> bool:
    """Whether a network (or engine) takes the Wiener stage's image."""
    return bool(getattr(model, "uses_wiener", False))


__all__ = ["WIENER_CHANNELS", "PSFNet", "uses_wiener"]
