"""Computing PSF banks (private: the one public way to get a bank is
lensim.psf.bank.get_bank / get_banks): the per-field work (fine PSFs per wavelength, pixel
integration, relative illumination, spectral weighting), the checked plan of one bank
(_plan_bank) and the plans of many banks run as one list of field jobs through
lensim.workers.run_jobs (in this process, on a local Dask cluster or on a cluster given by
address; _compute_plans), each field written as it finishes."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from lensim.errors import InputError, PupilSamplingError
from lensim.optics.aiming.modes import Aiming
from lensim.optics.field_analysis import axis_solid_angles
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_to_dict
from lensim.optics.paraxial import ParaxialData, paraxial_data, paraxial_image_height
from lensim.psf.bank.azimuth import azimuth_kernels
from lensim.psf.bank.settings import BankSettings
from lensim.psf.bank.store import (
    FORMAT,
    FORMAT_VERSION,
    lensim_version,
    open_bank_directory,
    read_manifest,
    release_bank_directory,
    write_field,
)
from lensim.psf.bank.types import BankField, Progress, PSFBank
from lensim.psf.compute import PSF_FUNCTIONS, PSFSamplingWarning, check_sampling, field_in_lens_units
from lensim.psf.defaults import PsfMethod
from lensim.psf.metrics import strehl_ratio
from lensim.psf.pixels import integrate_pixels, oversampling_factor
from lensim.psf.pupil_field import PupilField, pupil_field
from lensim.sensor.spectral import SpectralResponse, spectral_response
from lensim.workers import run_jobs


@dataclass
class _Job:
    """Everything a worker needs to compute fields (picklable)."""

    lens: Lens
    wavelengths_um: list[float]
    weights: np.ndarray  # (3, W)
    primary_um: float
    pixel_pitch_um: float
    kernel_pixels: int
    k: int
    method: PsfMethod
    pupil_samples: int
    ri_samples: int
    aiming: Aiming
    ri_axis: np.ndarray | None = None  # (W,) the on-axis beam's solid angles (sr), traced once per bank

    @property
    def spacing_um(self) -> float:
        """Fine PSF sample spacing (um)."""
        return self.pixel_pitch_um / self.k


def alias_free_pixels(pf: PupilField, kernel_pixels: int, pixel_pitch_um: float, method: PsfMethod) -> int:
    """The odd number of kernel pixels (<= kernel_pixels) whose window the pupil sampling
    resolves without wrap-around: a pupil grid of N samples repeats a diffraction PSF every
    lambda / (n' du) um (du: direction-cosine step between samples). Outside that central
    window the kernel is left at zero; check_sampling then makes sure the spot fits in it."""
    if method == "geometric":
        return kernel_pixels
    m = int(ALIAS_FREE_FRACTION * _alias_period_um(pf) / pixel_pitch_um)
    m = m if m % 2 else m - 1
    return max(1, min(kernel_pixels, m))


#: the fraction of the pupil grid's repeat period that alias_free_pixels computes
ALIAS_FREE_FRACTION = 0.95


def _alias_period_um(pf: PupilField) -> float:
    """How often (um) the pupil grid of pf repeats a diffraction PSF: lambda / (n' du), du
    the direction-cosine step between neighbouring samples."""
    from lensim.psf.fourier import direction_scale

    ax, ay = direction_scale(pf)
    du = max(abs(ax), abs(ay)) * 2.0 / pf.samples
    return pf.wavelength_um / pf.n_image / du


def pupil_samples_for_kernel(pf: PupilField, kernel_pixels: int, pixel_pitch_um: float) -> int:
    """The pupil samples across whose alias-free window (alias_free_pixels) is the whole
    kernel of kernel_pixels pixels: the repeat period grows in proportion to the samples."""
    window_um = kernel_pixels * pixel_pitch_um
    return math.ceil(pf.samples * window_um / (ALIAS_FREE_FRACTION * _alias_period_um(pf))) + 1


def embed_centred(small: np.ndarray, size: int) -> np.ndarray:
    """A (size, size) array with `small` (odd-sized) in its centre and zeros around it."""
    n = small.shape[-1]
    if n == size:
        return small
    out = np.zeros(small.shape[:-2] + (size, size), dtype=small.dtype)
    a = (size - n) // 2
    out[..., a : a + n, a : a + n] = small
    return out


class _FieldWork:
    """The PSFs of one bank field: traced pupils, checked sampling (its warnings collected
    in `caught`) and fine PSFs on the (k P) x (k P) grid, in the lens's field unit."""

    def __init__(self, job: _Job, fld: float, para: ParaxialData) -> None:
        self.job, self.fld, self.para = job, fld, para
        self.lens = job.lens
        self.value = field_in_lens_units(job.lens, fld)
        self.caught: list[str] = []

    def trace(self, wl_um: float, near: PupilField | None = None) -> PupilField:
        """The pupil field at a wavelength (um), its aiming started from that of ``near``
        (the same field at another wavelength) when given; a failed trace names the field."""
        start = None if near is None else near.aim
        try:
            return pupil_field(self.lens, self.value, wl_um, self.job.pupil_samples, self.job.aiming, self.para, start)
        except InputError as e:
            raise InputError(
                self.lens.source, f"field {self.fld:g} ({self.value:g}) at {wl_um * 1e3:g} nm", e.message
            ) from None

    def _check(
        self, pf: PupilField, wl_um: float, sub_grid: int, offset: tuple[float, float], cut: bool = False
    ) -> None:
        job = self.job
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            try:
                check_sampling(self.lens, pf, sub_grid, job.spacing_um, job.method, offset)
            except PupilSamplingError as e:
                raise PupilSamplingError(
                    self.lens.source,
                    f"field {self.fld:g} at {wl_um * 1e3:g} nm",
                    f"{e.message} (kernel {job.kernel_pixels} px of {job.pixel_pitch_um:g} um)",
                    e.needed,
                ) from None
            except InputError as e:
                raise InputError(
                    self.lens.source,
                    f"field {self.fld:g} at {wl_um * 1e3:g} nm",
                    f"{e.message} (kernel {job.kernel_pixels} px of {job.pixel_pitch_um:g} um)",
                ) from None
        prefix = f"{self.lens.source}: "
        for w in rec:
            if issubclass(w.category, PSFSamplingWarning):
                msg = str(w.message)
                msg = msg.removeprefix(prefix).replace(
                    "enlarge the grid or the spacing",
                    "use more pupil samples (the window is cut to what they resolve)" if cut else "use a larger kernel",
                )
                self.caught.append(f"{wl_um * 1e3:g} nm: {msg}")

    def fine_psf(self, pf: PupilField, wl_um: float, offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """(kP, kP) fine PSF (energy per sample), computed on the alias-free central
        window and zero outside it, its centre `offset` (mm) from the pupil's chief ray."""
        job = self.job
        m = alias_free_pixels(pf, job.kernel_pixels, job.pixel_pitch_um, job.method)
        try:
            self._check(pf, wl_um, m * job.k, offset, cut=m < job.kernel_pixels)
        except PupilSamplingError:
            raise
        except InputError as e:
            if m < job.kernel_pixels and self._kernel_holds_spot(pf, offset):
                need = pupil_samples_for_kernel(pf, job.kernel_pixels, job.pixel_pitch_um)
                raise PupilSamplingError(
                    e.source,
                    e.field,
                    f"{e.message.split('; expected')[0]}: {pf.samples} pupil samples resolve {m} of the kernel's "
                    f"{job.kernel_pixels} px without wrap-around; expected at least {need} pupil samples",
                    need,
                ) from None
            raise
        fine = PSF_FUNCTIONS[job.method](pf, m * job.k, job.spacing_um, offset)
        return embed_centred(fine.numpy(), job.k * job.kernel_pixels)

    def _kernel_holds_spot(self, pf: PupilField, offset: tuple[float, float]) -> bool:
        """Whether the whole kernel window holds the geometric spot as check_sampling asks
        (at least half of it): the spot is too large for the pupil sampling, not the kernel."""
        job = self.job
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                check_sampling(self.lens, pf, job.kernel_pixels * job.k, job.spacing_um, "geometric", offset)
            except InputError:
                return False
        return True

    def relative_illumination(self) -> np.ndarray:
        """Relative illumination at this field (1 on axis) at each bank wavelength, (W,),
        all wavelengths traced together."""
        from lensim.optics.field_analysis import relative_illumination_spectrum

        job = self.job
        return relative_illumination_spectrum(
            self.lens, self.value, job.wavelengths_um, job.ri_samples, job.aiming, para=self.para, axis=job.ri_axis
        )


def _compute_field(job: _Job, index: int, fld: float, para: ParaxialData | None = None) -> BankField:
    """Compute one bank field: per wavelength a fine PSF about the primary chief-ray point,
    integrated over pixels, normalized to unit sum, times relative illumination and the
    channel weights, summed into R, G, B (see lensim.psf.bank)."""
    from lensim.optics.aiming.rays import object_field

    lens = job.lens
    para = para or paraxial_data(lens)
    work = _FieldWork(job, fld, para)
    primary_pf = work.trace(job.primary_um)
    ref = primary_pf.chief[:2].clone()
    para_y = paraxial_image_height(lens.launch_lens(), object_field(lens, work.value, job.aiming, para), para)
    W, P = len(job.wavelengths_um), job.kernel_pixels
    rgb = np.zeros((3, P, P))
    rgb_fine = np.zeros((3, job.k * P, job.k * P))  # the same sum before pixel integration
    offsets, trans, window = np.zeros((W, 2)), np.zeros(W), np.zeros(W)
    ri = work.relative_illumination()
    primary_fine = None
    strehl = math.nan
    near = primary_pf  # each wavelength's aiming starts from the last one's
    for w, wl in enumerate(job.wavelengths_um):
        is_primary = abs(wl - job.primary_um) < 1e-9
        pf = primary_pf if is_primary else work.trace(wl, near)
        near = pf
        off = (ref - pf.chief[:2]).tolist()
        fine = work.fine_psf(pf, wl, (off[0], off[1]))
        pix = integrate_pixels(fine, job.k)
        total = float(pix.sum())
        if not total > 0:
            raise InputError(
                lens.source,
                f"field {fld:g} at {wl * 1e3:g} nm",
                "no energy inside the kernel window; expected a larger kernel",
            )
        rgb += (job.weights[:, w] * ri[w])[:, None, None] * (pix / total)[None]
        rgb_fine += (job.weights[:, w] * ri[w])[:, None, None] * (fine / total)[None]
        offsets[w] = [-off[0], -off[1]]
        trans[w] = pf.transmission
        window[w] = total / pf.transmission if pf.transmission > 0 else 0.0
        if is_primary:
            primary_fine = fine
    if primary_fine is None:  # the primary wavelength is not a bank wavelength: one more PSF
        primary_fine = work.fine_psf(primary_pf, job.primary_um)
    if job.method != "geometric":
        strehl = strehl_ratio(torch.from_numpy(primary_fine), primary_pf, job.spacing_um)
    return BankField(
        index=index,
        field=float(fld),
        field_value=float(work.value),
        rgb=rgb.astype(np.float32),
        reference_xy_mm=ref.numpy().astype(np.float64),
        paraxial_xy_mm=np.array([0.0, float(para_y)]),
        chief_offsets_mm=offsets,
        relative_illumination=ri,
        transmission=trans,
        window_energy=window,
        strehl=float(strehl),
        working_fno=float(primary_pf.working_fno()),
        primary_fine=primary_fine.astype(np.float32),
        warnings=work.caught,
        rgb_azimuths=azimuth_kernels(rgb_fine, job.k).astype(np.float32),
    )


@dataclass
class FieldTask:
    """One bank field to compute (picklable: a job of lensim.workers.run_jobs): the
    bank's job, the field's index and normalized position, the lens's paraxial data, and
    which of the banks computed together it belongs to."""

    job: _Job
    index: int
    field: float
    para: ParaxialData
    bank: int = 0
    label: str = ""


def compute_field_task(task: FieldTask) -> BankField:
    """The field a FieldTask names (run in this process or in a worker); an error names
    the bank's label (a grid's setting) after the field."""
    try:
        return _compute_field(task.job, task.index, task.field, task.para)
    except PupilSamplingError as e:
        if not task.label:
            raise
        raise PupilSamplingError(e.source, f"{e.field} ({task.label})", e.message, e.needed) from None
    except InputError as e:
        if not task.label:
            raise
        raise type(e)(e.source, f"{e.field} ({task.label})" if e.field else task.label, e.message) from None


def _check_pitch(lens: Lens, pixel_pitch_um: float) -> None:
    if not (pixel_pitch_um > 0 and math.isfinite(pixel_pitch_um)):
        raise InputError(lens.source, "pixel_pitch_um", f"expected a positive pitch (um), got {pixel_pitch_um}")


def _response(
    lens: Lens,
    wavelengths_nm: tuple[float, ...],
    response: str | Path | SpectralResponse | None,
    illuminant: str,
) -> SpectralResponse:
    """The spectral weights at the bank wavelengths (strictly increasing)."""
    if isinstance(response, SpectralResponse):
        resp = response
        if len(wavelengths_nm) != len(resp.wavelengths_nm) or not np.allclose(
            np.asarray(wavelengths_nm, dtype=np.float64), resp.wavelengths_nm
        ):
            raise InputError(lens.source, "wavelengths_nm", "expected the wavelengths of the given SpectralResponse")
    else:
        resp = spectral_response(list(wavelengths_nm), response, illuminant)
    if np.any(np.diff(np.asarray(resp.wavelengths_nm, dtype=np.float64)) <= 0):
        raise InputError(lens.source, "wavelengths_nm", "expected strictly increasing wavelengths")
    return resp


def _manifest(job: _Job, fields: np.ndarray, resp: SpectralResponse, max_spacing_um: float) -> dict:
    """Every setting that shapes the kernels (and, informative, the lens file and version)."""
    lens = job.lens
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "lens_file": lens.source,
        "lens": lens_to_dict(lens),
        "pixel_pitch_um": float(job.pixel_pitch_um),
        "kernel_pixels": int(job.kernel_pixels),
        "oversampling": int(job.k),
        "fine_spacing_um": float(job.pixel_pitch_um) / job.k,
        "max_spacing_um": float(max_spacing_um),
        "fields": [float(f) for f in fields],
        "field_values": [float(f) * lens.max_field for f in fields],
        "field_type": lens.field_type,
        "wavelengths_nm": [float(w) for w in resp.wavelengths_nm],
        "primary_wavelength_nm": job.primary_um * 1000.0,
        "response": resp.to_dict(),
        "method": job.method,
        "pupil_samples": int(job.pupil_samples),
        "ri_samples": int(job.ri_samples),
        "relative_illumination": "lensim.optics.field_analysis.relative_illumination (projected solid angle, normalized on axis)",
        "aiming": job.aiming,
        "lensim_version": lensim_version(),
    }


class BankPlan:
    """A bank to compute (_plan_bank makes one, checked): its job, normalized fields,
    manifest, the lens's paraxial data and the directory it is stored in (None: memory
    only). open() finds the fields already on disk; tasks() are the fields still to
    compute; finish(field) stores one computed field; result() is the whole bank. `label`
    names the bank in sampling warnings (a grid's setting)."""

    def __init__(
        self,
        job: _Job,
        fields: np.ndarray,
        manifest: dict,
        para: ParaxialData,
        directory: Path | None = None,
        label: str = "",
    ) -> None:
        self.job, self.fields, self.manifest, self.para = job, fields, manifest, para
        self.directory, self.label = directory, label
        self.done: dict[int, BankField] = {}

    def open(self) -> None:
        """Prepare the directory (refusing a bank of other settings) and read the fields
        already computed there (lensim.psf.bank.store.open_bank_directory)."""
        if self.directory is not None:
            self.done = open_bank_directory(self.directory, self.manifest, self.fields)

    def tasks(self, bank: int = 0) -> list[FieldTask]:
        """The fields still to compute, tagged with `bank` (the on-axis relative-illumination
        trace done here, once for them all)."""
        todo = [i for i in range(len(self.fields)) if i not in self.done]
        if todo and self.job.ri_axis is None:
            job = self.job
            axis = axis_solid_angles(job.lens, job.wavelengths_um, job.ri_samples, job.aiming, para=self.para)  # type: ignore[arg-type]
            self.job = replace(job, ri_axis=axis)
        return [FieldTask(self.job, i, float(self.fields[i]), self.para, bank, self.label) for i in todo]

    def finish(self, bf: BankField) -> None:
        """Store a computed field (written into the directory atomically) and pass on its
        sampling warnings as one PSFSamplingWarning."""
        if self.directory is not None:
            write_field(self.directory, bf, self.manifest)
        self.done[bf.index] = bf
        if bf.warnings:
            more = f" (and {len(bf.warnings) - 1} more)" if len(bf.warnings) > 1 else ""
            where = f" ({self.label})" if self.label else ""
            warnings.warn(
                f"{self.job.lens.source}: bank field {bf.field:.4f}{where}: {bf.warnings[0]}{more}",
                PSFSamplingWarning,
                stacklevel=6,
            )

    def result(self) -> PSFBank:
        """The bank, every field computed."""
        manifest = self.manifest if self.directory is None else (read_manifest(self.directory) or self.manifest)
        return PSFBank(manifest, [self.done[i] for i in range(len(self.fields))], self.directory)


def _plan_bank(
    lens: Lens,
    pixel_pitch_um: float,
    kernel_pixels: int,
    settings: BankSettings,
    response: str | Path | SpectralResponse | None = None,
    out_dir: str | Path | None = None,
    label: str = "",
) -> BankPlan:
    """The checked plan of one bank (see lensim.psf.bank), nothing computed and nothing
    written yet: this lens at this pixel pitch (um) with an odd kernel of kernel_pixels,
    sampled as `settings` ask (fields, wavelengths, pupil samples, aiming, method, fine
    spacing, illuminant, relative-illumination samples), weighted by `response` (a
    colour-science camera name, a CSV path (wavelength_nm,r,g,b) or a SpectralResponse at
    the settings' wavelengths; None: the measured Nikon 5100 (NPL) camera), stored in
    out_dir (None: memory only); `label` names the bank in messages (a grid's setting)."""
    _check_pitch(lens, pixel_pitch_um)
    if kernel_pixels < 1 or kernel_pixels % 2 == 0:
        raise InputError(lens.source, "kernel_pixels", f"expected an odd number of pixels, got {kernel_pixels}")
    flds = settings.field_positions()
    resp = _response(lens, settings.wavelengths_nm, response, settings.illuminant)
    wl_um = [float(w) / 1000.0 for w in np.asarray(resp.wavelengths_nm, dtype=np.float64)]
    para = paraxial_data(lens)
    max_spacing_um = settings.max_spacing_um
    if max_spacing_um is None:
        pf0 = pupil_field(lens, 0.0, min(wl_um), settings.pupil_samples, settings.aiming, para)
        max_spacing_um = 0.5 * 1.22 * min(wl_um) * pf0.working_fno()
    job = _Job(
        lens,
        wl_um,
        resp.weights,
        lens.primary_wavelength_um,
        float(pixel_pitch_um),
        int(kernel_pixels),
        oversampling_factor(pixel_pitch_um, max_spacing_um),
        settings.method,
        int(settings.pupil_samples),
        int(settings.ri_samples),
        settings.aiming,
    )
    return BankPlan(
        job, flds, _manifest(job, flds, resp, max_spacing_um), para, None if out_dir is None else Path(out_dir), label
    )


def _compute_plans(
    plans: list[BankPlan], workers: int = 1, scheduler: str | None = None, progress: Progress | None = None
) -> list[PSFBank]:
    """Compute several banks as one list of field jobs (lensim.workers.run_jobs: here, on
    a local Dask cluster of `workers` processes or on the cluster at `scheduler`), each
    resuming from the fields already in its directory and writing each field as it
    finishes; progress(done, total) counts the fields of all the banks. The caller holds
    the directories' locks."""
    for plan in plans:
        plan.open()
    total = sum(len(p.fields) for p in plans)
    count = sum(len(p.done) for p in plans)
    if progress is not None:
        progress(count, total)

    def finish(task: FieldTask, bf: BankField) -> None:
        nonlocal count
        plans[task.bank].finish(bf)
        count += 1
        if progress is not None:
            progress(count, total)

    try:
        run_jobs(compute_field_task, [t for b, p in enumerate(plans) for t in p.tasks(b)], workers, scheduler, finish)
    except BaseException:
        for p in plans:
            if p.directory is not None:
                release_bank_directory(p.directory)  # a bank with no field computed leaves nothing
        raise
    return [p.result() for p in plans]
