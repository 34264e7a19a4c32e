"""Restoration networks: modulated deformable convolution, the field-aware UNet and its
field-of-view (FOV) input channels with consistent dihedral augmentation.

The names below load lazily (module __getattr__), so that importing a light submodule such
as lensim.restore.config does not import torch."""

from __future__ import annotations

_API = {
    "DIHEDRAL_OPS": "lensim.restore.fov",
    "FieldAwareUNet": "lensim.restore.network",
    "ModulatedDeformConv2d": "lensim.restore.deform",
    "augment": "lensim.restore.fov",
    "count_parameters": "lensim.restore.network",
    "deform_conv2d": "lensim.restore.deform",
    "deform_conv2d_reference": "lensim.restore.deform",
    "fov_channels": "lensim.restore.fov",
    "invert_augment": "lensim.restore.fov",
    "plain_unet_matching": "lensim.restore.network",
    "plain_unet_width": "lensim.restore.network",
}


def __getattr__(name: str):
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'lensim.restore' has no attribute {name!r}")


__all__ = sorted(_API)
