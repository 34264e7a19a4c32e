"""PSF banks cached on disk by what they were computed from: ``ensure_bank`` loads the
bank for a lens at a pixel pitch from ``cache_dir/bank-<key>`` when complete and computes
(or finishes, after a kill) it otherwise; ``suggest_kernel_pixels`` sizes its kernels."""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any, Callable

import torch

from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_to_dict
from lensim.psf.bank import PSFBank, compute_bank


def suggest_kernel_pixels(lens: Lens, pitch_um: float, limit: int = 99) -> int:
    """An odd kernel size (pixels) holding the polychromatic spot at every field: twice the
    radius (about the primary chief ray) that holds 98 % of the traced rays at the worst
    field (400-700 nm, fields 0..1), plus 3 Airy radii of margin for diffraction, at least
    7 and at most `limit`."""
    from lensim.optics.aiming import generate_rays, object_field
    from lensim.optics.paraxial import paraxial_data
    from lensim.optics.pupil import hexapolar
    from lensim.optics.trace import trace

    para = paraxial_data(lens)
    fields = [object_field(lens, f * lens.max_field, "real", para) for f in (0.0, 0.5, 0.7, 0.85, 1.0)]
    pupil = torch.cat([torch.zeros(1, 2, dtype=torch.float64), hexapolar(8)])
    rays, wl = generate_rays(lens, fields, pupil, [lens.primary_wavelength_um, 0.40, 0.70], "real", para)
    res = trace(lens, rays, wl)
    chief = res.rays.position[0, :, 0, :2]  # primary wavelength
    d = torch.linalg.norm(res.rays.position[..., :2] - chief.unsqueeze(0).unsqueeze(2), dim=-1)
    reach_um = 0.0
    for fi in range(len(fields)):
        ok = res.rays.valid[:, fi]
        if bool(ok.any()):
            reach_um = max(reach_um, float(torch.quantile(d[:, fi][ok], 0.98)) * 1e3)
    reach_um += 3 * 1.22 * 0.7 * para.working_fno
    p = 2 * math.ceil(reach_um / pitch_um) + 1
    return int(min(max(p, 7), limit if limit % 2 else limit - 1))


def bank_key(lens: Lens, pitch_um: float, kernel_pixels: int, settings: dict) -> str:
    """A short hash naming a cached bank: the lens as a native mapping, pitch, kernel and
    every other bank setting."""
    blob = json.dumps({"lens": lens_to_dict(lens), "pitch_um": round(pitch_um, 9), "kernel": kernel_pixels, **settings},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def ensure_bank(lens: Lens, pitch_um: float, cache_dir: str | Path, kernel_pixels: int | None = None,
                progress: Callable[[int, int], None] | None = None, **settings: Any) -> PSFBank:
    """The bank for this lens at this pitch (um): loaded from cache_dir/bank-<key> when
    complete, computed (or finished, after a kill) otherwise. settings go to compute_bank."""
    kernel_pixels = kernel_pixels or suggest_kernel_pixels(lens, pitch_um)
    key = bank_key(lens, pitch_um, kernel_pixels, settings)
    out = Path(cache_dir) / f"bank-{key}"
    return compute_bank(lens, pitch_um, kernel_pixels, out_dir=out, progress=progress, **settings)
