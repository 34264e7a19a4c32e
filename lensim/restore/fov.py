"""Field-of-view (FOV) input channels and dihedral augmentation that keeps them consistent.

Coordinates
-----------
Pixel (row r, column c) of the sensor (height Hs, width Ws, square pixels) has its centre
at (r + 0.5, c + 0.5) pixel units; the optical axis is assumed at the sensor centre
(Hs / 2, Ws / 2). The two FOV channels are

    channel 0: x = (c + 0.5 - Ws / 2) / R      (positive to the right, along columns)
    channel 1: y = (r + 0.5 - Hs / 2) / R      (positive downwards, along rows)

with R = sqrt(Hs^2 + Ws^2) / 2 the half-diagonal in pixels, so both axes share one scale
(dimensionless; |(x, y)| < 1 on the sensor, -> 1 at the corners) and a pixel's FOV radius
is proportional to its image height. A crop at absolute offset (top, left) gets the
coordinates of the sensor pixels it covers.

Augmentation
------------
For a rotationally symmetric lens the image of a mirrored scene is the mirrored image, so
a flipped or transposed training crop is a valid crop of the *transformed* sensor: its FOV
channels must be those of the transformed frame. A horizontal flip therefore negates x, a
vertical flip negates y and a transpose swaps the two channels (all while moving the
channel values with the pixels). The authors' release only moved the values, which gives
the network wrong positions for 6 of the 8 ops.

Ops are integers 0..7 with bits: 1 = horizontal flip (reverse columns), 2 = vertical flip
(reverse rows), 4 = transpose (swap rows and columns), applied in that order.
"""

from __future__ import annotations

import math

import torch

DIHEDRAL_OPS: tuple[int, ...] = tuple(range(8))
HFLIP, VFLIP, TRANSPOSE = 1, 2, 4


def fov_channels(
    height: int,
    width: int,
    top: int | float,
    left: int | float,
    sensor_height: int | float,
    sensor_width: int | float,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """FOV channels (2, height, width) of a crop at absolute pixel offset (top, left) on a
    sensor of sensor_height x sensor_width pixels; channel 0 = x, channel 1 = y, both
    divided by the sensor half-diagonal in pixels (see the module docstring).

    The crop may extend beyond the sensor (e.g. padded tiles): coordinates are then simply
    continued linearly.
    """
    if height < 1 or width < 1:
        raise ValueError(f"crop size must be positive, got {height}x{width}")
    if sensor_height <= 0 or sensor_width <= 0:
        raise ValueError(f"sensor size must be positive, got {sensor_height}x{sensor_width}")
    half_diag = 0.5 * math.hypot(float(sensor_height), float(sensor_width))
    # Compute in float64, then cast, so float32 channels are correctly rounded.
    rows = torch.arange(height, dtype=torch.float64, device=device)
    cols = torch.arange(width, dtype=torch.float64, device=device)
    y = (rows + (float(top) + 0.5 - 0.5 * float(sensor_height))) / half_diag
    x = (cols + (float(left) + 0.5 - 0.5 * float(sensor_width))) / half_diag
    out = torch.stack((x.view(1, width).expand(height, width), y.view(height, 1).expand(height, width)))
    return out.to(dtype)


def batch_fov(fov: torch.Tensor | None, rgb: torch.Tensor) -> torch.Tensor:
    """The FOV channels a network with use_fov needs, checked against its input: fov
    (B, 2, H, W), or (2, H, W) shared by the batch, for rgb (B, 3, H, W) -> (B, 2, H, W) in
    rgb's dtype. Raises ValueError for a missing or mismatched fov."""
    if fov is None:
        raise ValueError("this model was built with use_fov=True: pass the FOV channels (fov_channels)")
    b = rgb.shape[0]
    if fov.dim() == 3:
        fov = fov.unsqueeze(0).expand(b, -1, -1, -1)
    if fov.dim() != 4 or fov.shape[0] != b or fov.shape[1] != 2 or fov.shape[-2:] != rgb.shape[-2:]:
        raise ValueError(
            f"fov must be (B, 2, H, W) or (2, H, W) matching rgb {tuple(rgb.shape)}, got {tuple(fov.shape)}"
        )
    return fov.to(rgb.dtype)


def _check(rgb: torch.Tensor, fov: torch.Tensor, op: int) -> None:
    if op not in DIHEDRAL_OPS:
        raise ValueError(f"op must be an integer in 0..7, got {op!r}")
    if rgb.dim() < 3 or fov.dim() < 3:
        raise ValueError(f"expected (..., C, H, W) tensors, got {tuple(rgb.shape)} and {tuple(fov.shape)}")
    if fov.shape[-3] != 2:
        raise ValueError(f"fov must have 2 channels at dim -3, got shape {tuple(fov.shape)}")
    if rgb.shape[-2:] != fov.shape[-2:]:
        raise ValueError(f"image {tuple(rgb.shape)} and fov {tuple(fov.shape)} differ in H, W")


def _hflip(rgb: torch.Tensor, fov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    fov = fov.flip(-1)
    return rgb.flip(-1), torch.cat((-fov[..., :1, :, :], fov[..., 1:, :, :]), dim=-3)


def _vflip(rgb: torch.Tensor, fov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    fov = fov.flip(-2)
    return rgb.flip(-2), torch.cat((fov[..., :1, :, :], -fov[..., 1:, :, :]), dim=-3)


def _transpose(rgb: torch.Tensor, fov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return rgb.transpose(-1, -2), fov.transpose(-1, -2).flip(-3)


def augment(rgb: torch.Tensor, fov: torch.Tensor, op: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Apply dihedral op (0..7, see the module docstring) to an image and its FOV channels.

    Args:
        rgb: (..., C, H, W) image (any number of channels, any leading batch dims).
        fov: (..., 2, H, W) FOV channels of the same pixels (channel 0 = x, 1 = y).
        op: bit 1 horizontal flip, bit 2 vertical flip, bit 4 transpose (in that order).

    Returns:
        (rgb', fov'), with H and W swapped when op & 4. fov' equals the FOV channels of the
        transformed sensor at the transformed crop's position. Results are contiguous.
    """
    _check(rgb, fov, op)
    if op & HFLIP:
        rgb, fov = _hflip(rgb, fov)
    if op & VFLIP:
        rgb, fov = _vflip(rgb, fov)
    if op & TRANSPOSE:
        rgb, fov = _transpose(rgb, fov)
    return rgb.contiguous(), fov.contiguous()


def invert_augment(rgb: torch.Tensor, fov: torch.Tensor, op: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Undo :func:`augment` with the same op: invert_augment(*augment(a, f, op), op) == (a, f).

    Shapes as in :func:`augment` (useful for test-time self-ensembles).
    """
    _check(rgb, fov, op)
    if op & TRANSPOSE:
        rgb, fov = _transpose(rgb, fov)
    if op & VFLIP:
        rgb, fov = _vflip(rgb, fov)
    if op & HFLIP:
        rgb, fov = _hflip(rgb, fov)
    return rgb.contiguous(), fov.contiguous()


__all__ = ["DIHEDRAL_OPS", "HFLIP", "TRANSPOSE", "VFLIP", "augment", "fov_channels", "invert_augment"]
