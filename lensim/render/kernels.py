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
    ks = bank.psfs_at(x.numpy(), y.numpy()).astype(np.float64)
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


#: Azimuth spacing (degrees) of :class:`PolarKernels`' nodes.
POLAR_STEP_DEG = 3.0


class PolarKernels:
    """A bank's kernels on a polar grid, interpolated: the nodes lie at the bank's field
    radii (``bank.radii_mm``) and every ``step_deg`` of azimuth; node (i, b) is
    ``bank.psf_at`` at radius r_i, azimuth b * step_deg (computed on first use and kept).
    A kernel anywhere is the bilinear interpolation of its four nodes in (radius,
    azimuth): linear in radius as ``bank.psf_at`` itself interpolates between fields
    (beyond the last field: the last field's), linear in azimuth between two turns
    step_deg apart (a 3-degree step displaces a 35 px kernel's rim by at most 0.45 px).
    This makes a kernel cost a few array additions instead of a spline rotation."""

    def __init__(self, bank: PSFBank, step_deg: float = POLAR_STEP_DEG) -> None:
        if not step_deg > 0:
            raise ValueError(f"step_deg must be positive, got {step_deg}")
        self.bank = bank
        self.step_deg = float(step_deg)
        self.radii = np.asarray(bank.radii_mm, dtype=np.float64)
        self.bins = max(1, round(360.0 / self.step_deg))
        self._nodes: dict[tuple[int, int], np.ndarray] = {}

    def _node(self, i: int, b: int) -> np.ndarray:
        key = (i, b % self.bins)
        if key not in self._nodes:
            r = max(float(self.radii[i]), 1e-9)  # off the axis, so psf_at turns it like its neighbours
            a = math.radians(key[1] * 360.0 / self.bins)
            self._nodes[key] = self.bank.psf_at(r * math.cos(a), r * math.sin(a)).astype(np.float32)
        return self._nodes[key]

    def _radial_weights(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower node index (N,) and the upper node's weight (N,) per radius (mm)."""
        radii = self.radii
        if len(radii) == 1:
            return np.zeros(len(r), dtype=np.int64), np.zeros(len(r))
        rc = np.clip(r, radii[0], radii[-1])
        j = np.clip(np.searchsorted(radii, rc, side="right") - 1, 0, len(radii) - 2)
        return j, (rc - radii[j]) / (radii[j + 1] - radii[j])

    def node(self, i: int, b: int) -> np.ndarray:
        """(3, P, P) float32 kernel of node (radius index i, azimuth step b)."""
        return self._node(i, b)

    def stencil(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The four nodes of each image point (x_mm, y_mm) ((N,) each, mm) and their
        weights: keys (N, 4, 2) int64 (radius index, azimuth step mod ``bins``) and
        weights (N, 4) float64 summing to 1 (a missing outer node has weight 0)."""
        x, y = np.asarray(x_mm, dtype=np.float64).ravel(), np.asarray(y_mm, dtype=np.float64).ravel()
        j, tr = self._radial_weights(np.hypot(x, y))
        pos = np.degrees(np.arctan2(y, x)) % 360.0 / (360.0 / self.bins)
        b = np.floor(pos).astype(np.int64)
        ta = pos - b
        top = len(self.radii) - 1
        keys = np.stack(
            [np.stack([np.minimum(j + di, top), (b + db) % self.bins], axis=-1) for di in (0, 1) for db in (0, 1)],
            axis=1,
        )
        weights = np.stack([(1 - tr) * (1 - ta), (1 - tr) * ta, tr * (1 - ta), tr * ta], axis=1)
        return keys, weights

    def at(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """(N, 3, P, P) float32 kernels at image points (x_mm, y_mm) ((N,) each, mm)."""
        keys, weights = self.stencil(x_mm, y_mm)
        p = self.bank.kernel_pixels
        out = np.zeros((len(keys), 3, p, p), dtype=np.float32)
        for n in range(len(keys)):
            for (i, b), wt in zip(keys[n], weights[n]):
                if wt > 0:
                    out[n] += np.float32(wt) * self._node(int(i), int(b))
        return out
