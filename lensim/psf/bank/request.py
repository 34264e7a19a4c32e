"""The one public way to get a PSF bank: get_bank (one) and get_banks (many at once).

A request is a lens, a pixel pitch (um), BankSettings (the one set of bank defaults), a
spectral response and, optionally, shooting settings: one ShootingSettings gives the bank
of the lens at that setting (its manifest records the setting), a GridAxes gives a grid of
banks over the settings it spans (lensim.psf.bank.grid). The bank comes from its folder:
``out_dir`` when given, else the cache (BankSettings.cache_root(): ``bank-<key>`` or
``grid-<key>``, the key naming the lens, pitch, kernel size, response and every setting
that shapes the kernels, so the same request always finds the same bank). A complete bank
is loaded; an incomplete one is finished (resume after a kill: fields already on disk are
kept); ``memory_only`` computes without writing anything.

get_banks checks every request before any work, then computes the fields of all of them as
one list of jobs (lensim.workers.run_jobs: in this process, on a local Dask cluster of
``workers`` processes or on the cluster at ``scheduler``), each field written as it
finishes; requests naming the same folder are computed once. The folders are locked while
computing (lensim.io.folder_lock).

Units: pixel pitch um, wavelengths nm.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

from lensim.errors import InputError
from lensim.io import folder_lock
from lensim.optics.lens import Lens
from lensim.optics.shooting import ShootingSettings, describe, lens_at, record
from lensim.psf.bank.compute import BankPlan, _compute_plans, _plan_bank
from lensim.psf.bank.grid import (
    GridAxes,
    GridBank,
    _plan_grid,
    grid_kernel_pixels,
    open_grid_directory,
    setting_label,
)
from lensim.psf.bank.settings import BankSettings
from lensim.psf.bank.store import drop_damaged_manifests, manifest_differences, release_bank_directory
from lensim.psf.bank.types import Progress, PSFBank
from lensim.sensor.spectral import SpectralResponse

Response = str | Path | SpectralResponse | None


@dataclass(frozen=True)
class BankRequest:
    """One bank (or grid of banks) asked for.

    lens: the lens (as its file has it; `shooting` sets it); pixel_pitch_um: the sensor's
    pixel pitch (um); settings: how the bank samples the lens (BankSettings' defaults when
    not given); response: the camera's spectral sensitivities, a colour-science camera
    name, a CSV path (wavelength_nm,r,g,b) or a SpectralResponse at the settings'
    wavelengths (None: the measured Nikon 5100 (NPL) camera); shooting: None (the lens as
    given), a ShootingSettings (one bank of the lens at it, the setting recorded in its
    manifest) or a GridAxes (a grid of banks, lensim.psf.bank.grid); out_dir: the bank's
    folder (None: its folder in the cache); memory_only: compute without writing anything
    (a single bank only, out_dir None)."""

    lens: Lens
    pixel_pitch_um: float
    settings: BankSettings = field(default_factory=BankSettings)
    response: Response = None
    shooting: ShootingSettings | GridAxes | None = None
    out_dir: str | Path | None = None
    memory_only: bool = False


@dataclass
class _Prepared:
    """A checked request: its folder (None: memory only), its banks' plans and, for a
    grid, the grid's manifest."""

    directory: Path | None
    plans: list[BankPlan]
    grid_manifest: dict | None = None
    cached: bool = False  # the folder is a bank cache entry (damaged manifests there are recomputed)

    def result(self) -> PSFBank | GridBank:
        if self.grid_manifest is not None:
            assert self.directory is not None
            return GridBank.load(self.directory)
        return self.plans[0].result()

    def manifests(self) -> list[dict]:
        return [p.manifest for p in self.plans] + ([self.grid_manifest] if self.grid_manifest else [])


def _response_key(response: Response) -> object:
    """The response as a cache key holds it: a name or path as text, a SpectralResponse as
    its mapping."""
    if response is None or isinstance(response, SpectralResponse):
        return None if response is None else response.to_dict()
    return str(response)


def _prepare_grid(req: BankRequest, axes: GridAxes) -> _Prepared:
    """The plans of a grid request, in out_dir or in the cache's ``grid-<key>`` folder
    (the key: the bank key of the lens as its file has it, with the axes)."""
    if req.memory_only:
        raise InputError(None, "memory_only", "a grid of banks is kept in a folder; expected memory_only=False")
    settings = req.settings
    kernel = grid_kernel_pixels([lens_at(req.lens, s) for s in axes.settings()], req.pixel_pitch_um, settings)
    settings = dataclasses.replace(settings, kernel_pixels=kernel)  # sized once over every setting
    if req.out_dir is not None:
        out = Path(req.out_dir)
    else:
        key = settings.cache_key(req.lens, req.pixel_pitch_um, kernel, _response_key(req.response))
        blob = key + json.dumps(axes.to_dict(), sort_keys=True)
        out = settings.cache_root() / f"grid-{hashlib.sha256(blob.encode()).hexdigest()[:16]}"
    plans, manifest = _plan_grid(req.lens, req.pixel_pitch_um, axes, settings, req.response, out)
    return _Prepared(out, plans, manifest, cached=req.out_dir is None)


def _prepare(req: BankRequest) -> _Prepared:
    """A request checked and planned, nothing computed or written."""
    if isinstance(req.shooting, GridAxes):
        return _prepare_grid(req, req.shooting)
    if req.memory_only and req.out_dir is not None:
        raise InputError(None, "out_dir", "expected no folder with memory_only=True")
    shot = req.shooting
    lens = req.lens if shot is None else lens_at(req.lens, shot)
    pitch = req.pixel_pitch_um
    kernel = req.settings.kernel_size(lens, pitch)
    directory: Path | None = None
    if req.out_dir is not None:
        directory = Path(req.out_dir)
    elif not req.memory_only:
        key = req.settings.cache_key(lens, pitch, kernel, _response_key(req.response))
        directory = req.settings.cache_root() / f"bank-{key}"
    label = "" if shot is None else setting_label(shot)
    plan = _plan_bank(lens, pitch, kernel, req.settings, req.response, directory, label)
    if shot is not None:
        plan.manifest["shooting"] = {"request": shot.to_dict(), "resolved": record(describe(req.lens, shot))}
    return _Prepared(directory, [plan], cached=req.out_dir is None and directory is not None)


def _distinct(prepared: list[_Prepared]) -> list[_Prepared]:
    """The requests to compute: those naming the same folder once. Two requests asking
    for different banks in one folder are refused (InputError naming both)."""
    seen: dict[Path, tuple[int, _Prepared]] = {}
    out = []
    for i, p in enumerate(prepared):
        if p.directory is None:
            out.append(p)
            continue
        key = p.directory.resolve()
        if key not in seen:
            seen[key] = (i, p)
            out.append(p)
            continue
        j, first = seen[key]
        mine, theirs = p.manifests(), first.manifests()
        if len(mine) != len(theirs) or any(manifest_differences(a, b) for a, b in zip(mine, theirs, strict=True)):
            raise InputError(
                str(p.directory), None, f"requests {j} and {i} ask for different banks in this folder; expected one"
            )
        prepared[i] = first
    return out


def get_banks(
    requests: Sequence[BankRequest],
    *,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> list[PSFBank | GridBank]:
    """The banks (PSFBank, or GridBank for a GridAxes request) of many requests, in their
    order, computed together (see the module docstring): every request is checked before
    any work; the fields still missing in every folder are one list of jobs, computed here
    (workers=1, one torch thread, restored afterwards), on a local Dask cluster of
    `workers` processes (each with one torch thread; started with the 'spawn' method, so a
    script calling this with workers > 1 needs the usual ``if __name__ == "__main__":``
    guard) or on the Dask cluster at `scheduler` (an address such as tcp://10.0.0.5:8786);
    progress(done, total) counts the fields of all the banks, once at the start (done:
    fields already on disk) and after each field.

    Raises InputError for a request the lens cannot take (naming the parameter), a folder
    holding a bank of other settings, two requests asking for different banks in one
    folder, or a folder another process is writing into."""
    if workers < 1:
        raise InputError(None, "workers", f"expected at least 1 worker, got {workers}")
    prepared = [_prepare(r) for r in requests]
    todo = _distinct(prepared)
    with ExitStack() as stack:
        for p in todo:
            if p.directory is not None:
                stack.enter_context(folder_lock(p.directory))
        for p in todo:
            if p.cached and p.directory is not None:
                drop_damaged_manifests(p.directory)
            if p.grid_manifest is not None and p.directory is not None:
                open_grid_directory(p.directory, p.grid_manifest)
        try:
            _compute_plans([plan for p in todo for plan in p.plans], workers, scheduler, progress)
        except BaseException:
            for p in todo:  # a grid that computed no field leaves no manifest (its banks' go in _compute_plans)
                if p.grid_manifest is not None and p.directory is not None:
                    release_bank_directory(p.directory, "s[0-9][0-9][0-9]/field_*.npz")
            raise
    return [p.result() for p in prepared]


@overload
def get_bank(
    lens: Lens,
    pixel_pitch_um: float,
    settings: BankSettings | None = None,
    *,
    response: Response = None,
    shooting: GridAxes,
    out_dir: str | Path | None = None,
    memory_only: bool = False,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> GridBank: ...


@overload
def get_bank(
    lens: Lens,
    pixel_pitch_um: float,
    settings: BankSettings | None = None,
    *,
    response: Response = None,
    shooting: ShootingSettings | None = None,
    out_dir: str | Path | None = None,
    memory_only: bool = False,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> PSFBank: ...


@overload
def get_bank(
    lens: Lens,
    pixel_pitch_um: float,
    settings: BankSettings | None = None,
    *,
    response: Response = None,
    shooting: ShootingSettings | GridAxes | None = None,
    out_dir: str | Path | None = None,
    memory_only: bool = False,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> PSFBank | GridBank: ...


def get_bank(
    lens: Lens,
    pixel_pitch_um: float,
    settings: BankSettings | None = None,
    *,
    response: Response = None,
    shooting: ShootingSettings | GridAxes | None = None,
    out_dir: str | Path | None = None,
    memory_only: bool = False,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> PSFBank | GridBank:
    """The bank `settings` (default BankSettings()) ask for, for this lens at this pixel
    pitch (um) and spectral response: from its folder (out_dir, else the cache) when
    complete, computed or finished otherwise; a GridBank when `shooting` is a GridAxes.
    The arguments are BankRequest's and get_banks' (see both)."""
    request = BankRequest(lens, pixel_pitch_um, settings or BankSettings(), response, shooting, out_dir, memory_only)
    return get_banks([request], workers=workers, scheduler=scheduler, progress=progress)[0]
