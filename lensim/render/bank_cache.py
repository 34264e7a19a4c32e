"""PSF banks cached on disk by what they were computed from: ``ensure_bank`` (and
``ensure_grid``, for a grid of shooting settings) loads the
bank that BankSettings ask for, for a lens at a pixel pitch, from
``<cache>/bank-<key>`` when complete and computes (or finishes, after a kill) it
otherwise. The key (BankSettings.cache_key) names the lens, pitch, kernel size, spectral
response and every setting that shapes the kernels, so the same request always finds the
same bank."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from lensim.optics.lens import Lens
from lensim.psf.bank import BankSettings, GridAxes, GridBank, Progress, PSFBank, build_bank, compute_grid


def cached_bank_dir(lens: Lens, pitch_um: float, settings: BankSettings, response: str | Path | None = None) -> Path:
    """The cache folder of the bank `settings` ask for, for this lens at this pitch (um)
    and spectral response (None: compute_bank's default camera)."""
    kernel = settings.kernel_size(lens, pitch_um)
    return settings.cache_root() / f"bank-{settings.cache_key(lens, pitch_um, kernel, response)}"


def ensure_bank(
    lens: Lens,
    pitch_um: float,
    settings: BankSettings | None = None,
    response: str | Path | None = None,
    workers: int = 1,
    progress: Progress | None = None,
    scheduler: str | None = None,
) -> PSFBank:
    """The bank `settings` ask for (default BankSettings()) for this lens at this pitch
    (um) and spectral response (a colour-science camera name or a CSV path; None: the
    default camera): loaded from the cache when complete, computed (or finished, after a
    kill) otherwise, with `workers` processes or on the Dask cluster at `scheduler`;
    progress(done, total) per field."""
    settings = settings or BankSettings()
    settings = dataclasses.replace(settings, kernel_pixels=settings.kernel_size(lens, pitch_um))  # sized once
    out = cached_bank_dir(lens, pitch_um, settings, response)
    return build_bank(
        lens,
        pitch_um,
        settings,
        response=response,
        out_dir=out,
        workers=workers,
        progress=progress,
        scheduler=scheduler,
    )


def ensure_grid(
    lens: Lens,
    pitch_um: float,
    axes: GridAxes,
    settings: BankSettings | None = None,
    response: str | Path | None = None,
    workers: int = 1,
    progress: Progress | None = None,
    scheduler: str | None = None,
) -> GridBank:
    """The grid of banks over `axes` (lensim.psf.bank.grid) for this lens at this pitch
    (um) with these bank settings, cached as ``<cache>/grid-<key>`` like ensure_bank's
    banks (the key adds the axes; the kernel size is sized once over every setting)."""
    from lensim.optics.shooting import lens_at
    from lensim.psf.bank.grid import grid_kernel_pixels

    settings = settings or BankSettings()
    kernel = grid_kernel_pixels([lens_at(lens, s) for s in axes.settings()], pitch_um, settings)
    settings = dataclasses.replace(settings, kernel_pixels=kernel)
    blob = settings.cache_key(lens, pitch_um, kernel, None if response is None else str(response)) + json.dumps(
        axes.to_dict(), sort_keys=True
    )
    out = settings.cache_root() / f"grid-{hashlib.sha256(blob.encode()).hexdigest()[:16]}"
    return compute_grid(
        lens, pitch_um, axes, settings, out, response=response, workers=workers, scheduler=scheduler, progress=progress
    )
