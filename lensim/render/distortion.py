"""The lens's distortion applied to an image (a warp; lateral colour stays in the kernels)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from lensim.render.mapping import SensorMapping

if TYPE_CHECKING:
    from lensim.psf.bank import PSFBank


def apply_distortion(cam: torch.Tensor, bank: PSFBank, mapping: SensorMapping) -> torch.Tensor:
    """Warp an image (C, H, W) as the lens distorts it: the pixel at real image radius r
    shows the scene point whose paraxial (undistorted) image radius r' has its real chief
    ray at r. r(r') comes from the bank's stored chief-ray and paraxial points (primary
    wavelength; lateral colour stays in the kernels). Bilinear resampling, edge values
    repeated outside the image."""
    r_real = np.array([float(np.hypot(*f.reference_xy_mm)) for f in bank.fields])
    r_par = np.array([float(np.hypot(*f.paraxial_xy_mm)) for f in bank.fields])
    c, h, w = cam.shape
    rows = torch.arange(h, dtype=torch.float64).unsqueeze(1).expand(h, w)
    cols = torch.arange(w, dtype=torch.float64).unsqueeze(0).expand(h, w)
    x, y = mapping.pixel_to_mm(rows, cols)
    r = torch.sqrt(x * x + y * y)
    r_src = torch.from_numpy(np.interp(r.numpy().ravel(), r_real, r_par).reshape(h, w))
    scale = torch.where(r > 0, r_src / r.clamp_min(1e-12), torch.ones_like(r))
    p = mapping.pitch_um * 1e-3
    src_col = (x * scale - mapping.x0_mm) / p - 0.5
    src_row = (y * scale - mapping.y0_mm) / p - 0.5
    grid = torch.stack([src_col / (w - 1) * 2 - 1, src_row / (h - 1) * 2 - 1], -1).unsqueeze(0).to(cam.dtype)
    return F.grid_sample(cam.unsqueeze(0), grid, mode="bilinear", padding_mode="border", align_corners=True)[0]
