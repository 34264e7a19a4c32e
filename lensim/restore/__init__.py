"""Restoration networks: modulated deformable convolution, the field-aware UNet and its
field-of-view (FOV) input channels with consistent dihedral augmentation."""
from lensim.restore.deform import ModulatedDeformConv2d, deform_conv2d, deform_conv2d_reference
from lensim.restore.fov import DIHEDRAL_OPS, augment, fov_channels, invert_augment
from lensim.restore.network import FieldAwareUNet, count_parameters, plain_unet_matching, plain_unet_width

__all__ = [
    "DIHEDRAL_OPS",
    "FieldAwareUNet",
    "ModulatedDeformConv2d",
    "augment",
    "count_parameters",
    "deform_conv2d",
    "deform_conv2d_reference",
    "fov_channels",
    "invert_augment",
    "plain_unet_matching",
    "plain_unet_width",
]
