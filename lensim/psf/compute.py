"""One PSF for one field and wavelength: methods, sampling checks, figures.

Framing: a grid x grid window with sample spacing spacing_um, sample (grid//2, grid//2)
on the real chief-ray image point (plus an optional offset); rows are y, columns x.
Fields are given normalized, 0..1 of the lens's maximum field along +y.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from lensim.errors import InputError, PupilSamplingError
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import object_field
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data, paraxial_image_height
from lensim.psf.defaults import PsfMethod, psf_method
from lensim.psf.fourier import direction_scale, fft_psf, geometric_psf
from lensim.psf.huygens import huygens_psf
from lensim.psf.metrics import encircled_energy_radii, rms_spot_radius_um, strehl_ratio
from lensim.psf.pupil_field import PupilField, pupil_field


class PSFSamplingWarning(UserWarning):
    """The requested PSF sampling is marginal (undersampled, window too small)."""


#: the function of each PSF method: (pupil field, grid, spacing um, offset mm) -> (grid, grid) PSF
PSF_FUNCTIONS: dict[PsfMethod, Callable[..., torch.Tensor]] = {
    "huygens": huygens_psf,
    "fft": fft_psf,
    "geometric": geometric_psf,
}


@dataclass
class PSF:
    """A PSF and where it lies. data: (grid, grid) energy per sample (sums to the
    transmitted fraction inside the window); spacing_um; chief_xy_mm: real chief-ray image
    point; paraxial_xy_mm: paraxial image point of the same field; figures: Strehl etc."""

    data: np.ndarray
    spacing_um: float
    field: float
    field_value: float
    wavelength_um: float
    method: PsfMethod
    chief_xy_mm: tuple[float, float]
    paraxial_xy_mm: tuple[float, float]
    transmission: float
    figures: dict = dataclasses.field(default_factory=dict)


def check_sampling(
    lens: Lens,
    pf: PupilField,
    grid: int,
    spacing_um: float,
    method: PsfMethod,
    offset_mm: tuple[float, float] = (0.0, 0.0),
) -> None:
    """Refuse sampling that would alias; warn, with the figures, when it is marginal.
    The window is centred on the chief-ray point plus offset_mm, as the PSF's."""
    src = lens.source
    window_um = grid * spacing_um
    lam_um = pf.wavelength_um / pf.n_image
    ax, ay = direction_scale(pf)
    du = max(abs(ax), abs(ay)) * 2.0 / pf.samples
    if method != "geometric":
        period_um = lam_um / du
        if window_um > period_um:
            need = math.ceil(pf.samples * window_um / period_um)
            raise PupilSamplingError(
                src,
                "pupil_samples",
                f"{pf.samples} pupil samples repeat the PSF every "
                f"{period_um:.1f} um but the window is {window_um:.1f} um wide; expected at least "
                f"{need} pupil samples or a smaller window",
                need,
            )
        # wavefront sampling: phase step between neighbouring pupil samples
        airy_um = 1.22 * pf.wavelength_um * pf.working_fno()
        if spacing_um > airy_um:
            warnings.warn(
                f"{src}: spacing {spacing_um:g} um exceeds the Airy radius {airy_um:.2f} um: the PSF is "
                "undersampled; use a finer spacing (pixel integration bins it to pixels exactly)",
                PSFSamplingWarning,
                stacklevel=3,
            )
    rel = (pf.image_xy - pf.chief[:2] - torch.tensor(offset_mm, dtype=pf.image_xy.dtype)) * 1e3
    half = window_um / 2.0
    inside = ((rel.abs() <= half).all(-1).to(torch.float64) * pf.power).sum().item() / pf.power.sum().item()
    if inside < 0.5:
        raise InputError(
            src,
            "grid",
            f"the {window_um:.1f} um window holds only {inside:.0%} of the geometric spot "
            f"(RMS radius {rms_spot_radius_um(pf):.1f} um); expected a window at least as large as the spot",
        )
    if inside < 0.95:
        warnings.warn(
            f"{src}: the {window_um:.1f} um window holds {inside:.0%} of the geometric spot (RMS radius "
            f"{rms_spot_radius_um(pf):.1f} um); enlarge the grid or the spacing",
            PSFSamplingWarning,
            stacklevel=3,
        )


def field_in_lens_units(lens: Lens, field: float) -> float:
    """Normalized field (0..1 of the maximum field) to the lens's field unit; checks range."""
    if not (0.0 <= field <= 1.0 + 1e-9):
        raise InputError(
            lens.source,
            "field",
            f"expected a normalized field between 0 and 1 (1 = max field {lens.max_field:g}), got {field:g}",
        )
    return field * lens.max_field


def compute_psf(
    lens: Lens,
    field: float,
    wavelength_um: float,
    method: PsfMethod = "huygens",
    pupil_samples: int = 128,
    grid: int = 128,
    spacing_um: float = 0.5,
    aiming: Aiming = "real",
    offset_mm: tuple[float, float] = (0.0, 0.0),
) -> PSF:
    """PSF of one normalized field (0..1) at one wavelength (um) by the chosen method."""
    method = psf_method(method, lens.source)
    if grid < 8 or spacing_um <= 0:
        raise InputError(lens.source, "grid", f"expected grid >= 8 and spacing > 0, got {grid} and {spacing_um}")
    para = paraxial_data(lens)
    value = field_in_lens_units(lens, field)
    pf = pupil_field(lens, value, wavelength_um, pupil_samples, aiming, para)
    check_sampling(lens, pf, grid, spacing_um, method, offset_mm)
    fn = PSF_FUNCTIONS[method]
    data = fn(pf, grid, spacing_um, offset_mm)
    launch = object_field(lens, value, aiming, para)
    para_y = paraxial_image_height(lens.launch_lens(), launch, para)
    arr = data.numpy()
    ee50, ee80 = encircled_energy_radii(arr, spacing_um, (0.5, 0.8), method != "geometric")
    figures = {
        "strehl": strehl_ratio(data, pf, spacing_um) if method != "geometric" else None,
        "rms_spot_radius_um": rms_spot_radius_um(pf),
        "ee50_radius_um": ee50,
        "ee80_radius_um": ee80,
        "energy_in_window": float(arr.sum()),
        "transmission": pf.transmission,
        "chief_ray_xy_mm": [float(pf.chief[0]), float(pf.chief[1])],
        "paraxial_xy_mm": [0.0, float(para_y)],
        "working_fno": pf.working_fno(),
    }
    return PSF(
        arr,
        spacing_um,
        field,
        value,
        wavelength_um,
        method,
        (float(pf.chief[0]), float(pf.chief[1])),
        (0.0, float(para_y)),
        pf.transmission,
        figures,
    )
