"""Restoration architectures by name: one place that builds a network from its config.

``config["arch"]`` is ``"unet"`` (lensim.restore.network.FieldAwareUNet; the default when
the key is missing, so checkpoints written before there was a choice keep loading) or
``"nafnet"`` (lensim.restore.nafnet.NAFNet) or ``"psfnet"`` (lensim.restore.psfnet.PSFNet,
NAFNet refining the Wiener stage's image). Every model has ``.config`` (a dict that
rebuilds it through :func:`build_model`, "arch" included), ``.size_multiple``, ``.use_fov``
and ``.settings_dim``.

Size matching: the reference FieldAwareUNet (width 32, 3 scales, deformable block at the
coarsest decoder scale) has 821,209 parameters; :func:`default_width` gives each
architecture's width at that size (NAFNet: :func:`lensim.restore.nafnet.nafnet_width`).
"""

from __future__ import annotations

from functools import cache
from typing import Any

import torch
import torch.nn as nn

from lensim.restore.arch_rules import ARCHS
from lensim.restore.nafnet import NAFNet, nafnet_width
from lensim.restore.network import FieldAwareUNet, count_parameters

#: Width of `lensim train --arch unet`'s FieldAwareUNet (and of the reference every default size matches).
UNET_WIDTH = 32


def arch_of(config: dict[str, Any]) -> str:
    """The architecture a model config names ("unet" when it names none)."""
    return str(config.get("arch", "unet"))


def build_model(config: dict[str, Any]) -> nn.Module:
    """The network a config describes (``model.config`` of any architecture, or an old
    checkpoint's config without "arch"). ValueError for an unknown architecture;
    TypeError / ValueError from the constructor for arguments it does not take."""
    arch = arch_of(config)
    kwargs = {k: v for k, v in config.items() if k != "arch"}
    if arch == "unet":
        return FieldAwareUNet(**kwargs)
    if arch == "nafnet":
        return NAFNet(**kwargs)
    if arch == "psfnet":
        from lensim.restore.psfnet import PSFNet

        return PSFNet(**kwargs)
    raise ValueError(f"unknown architecture {arch!r}; expected one of {', '.join(ARCHS)}")


def describe_network(config: dict[str, Any]) -> str:
    """A network's config in words, for reports: "plain NAFNet (stem 2, width 46)" with
    every field-aware part off, else e.g. "NAFNet with FOV (stem 2, width 40)" or "UNet with
    FOV, deformable, context (width 32)" (the stem only where it is not 1)."""
    arch = {"unet": "UNet", "nafnet": "NAFNet", "psfnet": "PSF-informed NAFNet (Wiener stage)"}.get(
        arch_of(config), arch_of(config)
    )
    on = arch_of(config) == "unet"  # a switch the config lacks: the constructor's default
    parts = [
        name
        for name, key in (("FOV", "use_fov"), ("deformable", "use_deformable"), ("context", "use_context"))
        if config.get(key, on)
    ]
    stem = int(config.get("stem", 1))
    width = config.get("width", (config.get("widths") or ["?"])[0])  # FieldAwareUNet records its widths
    sizes = ", ".join(([f"stem {stem}"] if stem != 1 else []) + [f"width {width}"])
    return f"{arch} with {', '.join(parts)} ({sizes})" if parts else f"plain {arch} ({sizes})"


@cache
def reference_parameters() -> int:
    """Parameters of the reference FieldAwareUNet (width 32, 3 scales, DCN at the coarsest
    decoder scale, FOV input, context block): the size every default matches."""
    with torch.device("meta"):
        return count_parameters(FieldAwareUNet(width=UNET_WIDTH, deformable_scales=1))


@cache
def _nafnet_default_width(frozen: tuple[tuple[str, Any], ...]) -> int:
    return nafnet_width(reference_parameters(), **dict(frozen))


def default_width(arch: str, **switches: Any) -> int:
    """The width of ``arch`` (with constructor ``switches`` such as use_fov, stem) whose
    parameter count matches the reference FieldAwareUNet's within 10%: 32 for "unet" (the
    reference's), the matching width for "nafnet" (46 for the plain and FOV variants, with
    the stem or without)."""
    if arch == "unet":
        return UNET_WIDTH
    if arch in ("nafnet", "psfnet"):  # psfnet: NAFNet's width (its 3 more input planes add < 1 %)
        items = ((k, v) for k, v in switches.items() if k != "stage")
        frozen = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in items))
        return _nafnet_default_width(frozen)
    raise ValueError(f"unknown architecture {arch!r}; expected one of {', '.join(ARCHS)}")


__all__ = ["ARCHS", "UNET_WIDTH", "arch_of", "build_model", "default_width", "describe_network", "reference_parameters"]
