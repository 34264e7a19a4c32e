"""Kernels from a PSF bank at image pixels, and the tile-centre grid they are taken on.

The blur (lensim.render.blur) and the deconvolution baselines (lensim.evaluate.baselines)
both take one RGB kernel per tile centre, centres on a regular grid of spacing ``tile``
pixels (0, tile, 2 tile, ... in both axes), at the centre's sensor position
(``bank.psf_at``: radially interpolated and rotated to the azimuth).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from lensim.errors import InputError
from lensim.render.mapping import SensorMapping

if TYPE_CHECKING:
    from lensim.psf.bank import PSFBank

KernelFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def tile_centres(size: int, tile: int) -> torch.Tensor:
    """Tile-centre pixel coordinates along one axis (float64, (n,)): 0, tile, 2 tile, ...,
    the last at or beyond size - 1."""
    n = math.ceil(max(size - 1, 0) / tile) + 1
    return torch.arange(n, dtype=torch.float64) * tile


def kernels_at(bank: PSFBank, mapping: SensorMapping, rows: Any, cols: Any, unit_sum: bool = False) -> torch.Tensor:
    """(N, C, P, P) float64 kernels of the bank at the sensor positions of image pixels
    (rows, cols) ((N,) each, pixel units of the mapped image, tensors or arrays). With
    unit_sum each channel is normalized to sum 1 (no relative illumination: no lens
    shading); otherwise a kernel's sum is its relative illumination."""
    x, y = mapping.pixel_to_mm(torch.as_tensor(rows, dtype=torch.float64), torch.as_tensor(cols, dtype=torch.float64))
    ks = np.stack([bank.psf_at(float(a), float(b)) for a, b in zip(x.tolist(), y.tolist())]).astype(np.float64)
    if unit_sum:
        ks /= ks.sum(axis=(-2, -1), keepdims=True)
    return torch.from_numpy(ks)


def kernel_function(bank: PSFBank, mapping: SensorMapping, relative_illumination: bool = True) -> KernelFn:
    """kernel_at(rows, cols) for lensim.render.blur: :func:`kernels_at` with unit-sum
    kernels when relative_illumination is False."""

    def kernel_at(rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
        return kernels_at(bank, mapping, rows, cols, unit_sum=not relative_illumination)

    return kernel_at


def check_bank_fits(bank: PSFBank, mapping: SensorMapping, source: str = "<bank>") -> None:
    """The bank must be at the mapping's pitch and cover the image's half-diagonal;
    InputError naming ``source`` otherwise."""
    if abs(bank.pixel_pitch_um / mapping.pitch_um - 1.0) > 1e-6:
        raise InputError(
            source,
            "pixel_pitch_um",
            f"the bank is at {bank.pixel_pitch_um:.6g} um but the image maps onto "
            f"the sensor at {mapping.pitch_um:.6g} um per pixel; expected a bank computed at that pitch",
        )
    r_max = float(bank.radii_mm[-1])
    if mapping.half_diagonal_mm > r_max * (1 + 1e-6) + 0.5 * mapping.pitch_um * 1e-3:
        raise InputError(
            source,
            "fields",
            f"the image's corners lie {mapping.half_diagonal_mm:.4g} mm off axis but the bank "
            f"(the lens's field) reaches {r_max:.4g} mm; expected a lens covering the sensor diagonal",
        )
