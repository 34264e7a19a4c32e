"""Restoration networks and their training.

The default network (`lensim train`, TrainConfig(), the demo) is NAFNet with lensim's
field-aware parts: the two field-of-view (FOV) input channels, a 2x pixel-unshuffle stem
(every layer at half resolution), no deformable blocks and no context block, at the width
that matches the paper's UNet's parameter count (lensim.restore.nafnet.NAFNet). The paper's
field-aware UNet (FOV channels, modulated deformable convolutions in the decoder, a context
block) is the other architecture (lensim.restore.network.FieldAwareUNet, arch "unet").

build_model builds either from its config; default_width sizes them; which architecture
takes which switches, and each one's defaults, live in lensim.restore.arch_rules
(check_switches, ARCH_DEFAULTS); the FOV channels and their consistent dihedral
augmentation in lensim.restore.fov; modulated deformable convolution in
lensim.restore.deform; training in lensim.restore.train (TrainConfig, train).

The names below load lazily (module __getattr__), so that importing a light submodule such
as lensim.restore.config does not import torch."""

from __future__ import annotations

_API = {
    "ARCHS": "lensim.restore.arch_rules",
    "ARCH_DEFAULTS": "lensim.restore.arch_rules",
    "DIHEDRAL_OPS": "lensim.restore.fov",
    "FieldAwareUNet": "lensim.restore.network",
    "ModulatedDeformConv2d": "lensim.restore.deform",
    "NAFNet": "lensim.restore.nafnet",
    "TrainConfig": "lensim.restore.config",
    "augment": "lensim.restore.fov",
    "build_model": "lensim.restore.models",
    "check_switches": "lensim.restore.arch_rules",
    "count_parameters": "lensim.restore.network",
    "default_width": "lensim.restore.models",
    "deform_conv2d": "lensim.restore.deform",
    "deform_conv2d_reference": "lensim.restore.deform",
    "describe_network": "lensim.restore.models",
    "fov_channels": "lensim.restore.fov",
    "invert_augment": "lensim.restore.fov",
    "nafnet_width": "lensim.restore.nafnet",
    "plain_unet_matching": "lensim.restore.network",
    "plain_unet_width": "lensim.restore.network",
}


def __getattr__(name: str):
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'lensim.restore' has no attribute {name!r}")


__all__ = sorted(_API)
