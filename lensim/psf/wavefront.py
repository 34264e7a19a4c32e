"""The wavefront of one field at one wavelength: the optical path difference (OPD) over the
exit pupil against the reference sphere, its RMS, peak-to-valley and Strehl ratio, and
its Zernike coefficients.

The OPD comes from the pupil field (lensim.psf.pupil_field, the one the Huygens and FFT
PSFs use): a uniform samples x samples grid over the normalized pupil (the entrance
pupil for paraxial aiming, the stop for real aiming), each ray carried to the reference
sphere centred on the real chief-ray image point and through the chief ray's crossing of
the paraxial exit-pupil plane.

Sign convention (Zemax's and optiland's): OPD = (chief ray's optical path - the ray's) / wavelength,
in waves, so moving the image plane away from the lens by dz adds +dz / (8 N^2) waves
of rho^2 (paraxially; n' dz (1 - cos u) exactly, u the ray's angle to the chief ray).

Figures (piston and tilt removed by an equal-weight least-squares fit over the pupil
samples, so they do not depend on where the image point is taken):
rms_waves, pv_waves; strehl = |sum a_j exp(2 pi i W_j)|^2 / (sum a_j)^2 with a_j the
rays' Huygens amplitudes (ray power and sphere area, as the PSFs weight them), the peak
of the PSF at the best-fit image point over the aberration-free peak of the same pupil;
strehl_marechal = exp(-(2 pi rms)^2). rms_waves_piston_only keeps the tilt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lensim.optics.aiming import Aiming
from lensim.optics.lens import Lens
from lensim.psf import zernike
from lensim.psf.fourier import pupil_indices
from lensim.psf.pupil_field import PupilField, pupil_field


@dataclass
class Wavefront:
    """The OPD of one field and wavelength at the pupil samples that reach the image.

    pupil_xy (P, 2) normalized pupil coordinates; opd_waves (P,); amplitude (P,) the
    rays' Huygens amplitudes (relative); rows, cols (P,) each sample's cell on the
    samples x samples grid (rows are y); wavelength_um; field_value in the lens's unit;
    chief_xy_mm the chief-ray image point; transmission the unvignetted fraction."""

    pupil_xy: np.ndarray
    opd_waves: np.ndarray
    amplitude: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    samples: int
    wavelength_um: float
    field_value: float
    chief_xy_mm: tuple[float, float]
    transmission: float

    def opd_map(self, remove_tilt: bool = True) -> np.ndarray:
        """(samples, samples) OPD in waves (rows are y, pupil y rising with the row),
        NaN where no ray passes; piston and tilt removed unless remove_tilt is False
        (then only piston)."""
        out = np.full((self.samples, self.samples), np.nan)
        out[self.rows, self.cols] = remove_piston_tilt(self.pupil_xy, self.opd_waves, tilt=remove_tilt)
        return out


def from_pupil_field(pf: PupilField, field_value: float) -> Wavefront:
    """The wavefront a pupil field carries (OPD sign as the module says)."""
    rows, cols = pupil_indices(pf)
    return Wavefront(
        pupil_xy=pf.pupil_xy.numpy().copy(),
        opd_waves=(-pf.opl / pf.wavelength_mm).numpy().copy(),
        amplitude=(pf.power * pf.area).sqrt().numpy().copy(),
        rows=rows.numpy(),
        cols=cols.numpy(),
        samples=pf.samples,
        wavelength_um=pf.wavelength_um,
        field_value=field_value,
        chief_xy_mm=(float(pf.chief[0]), float(pf.chief[1])),
        transmission=pf.transmission,
    )


def wavefront(
    lens: Lens, field_value: float, wavelength_um: float, samples: int = 64, aiming: Aiming = "real"
) -> Wavefront:
    """The wavefront of one field (in the lens's field unit) at one wavelength (um), on a
    samples x samples pupil grid."""
    return from_pupil_field(pupil_field(lens, field_value, wavelength_um, samples, aiming), field_value)


def remove_piston_tilt(xy: np.ndarray, w: np.ndarray, tilt: bool = True) -> np.ndarray:
    """w (P,) less its equal-weight least-squares piston (and x, y tilt) over the points xy (P, 2)."""
    cols = [np.ones_like(w)] + ([xy[:, 0], xy[:, 1]] if tilt else [])
    a = np.stack(cols, -1)
    c, *_ = np.linalg.lstsq(a, w, rcond=None)
    return w - a @ c


def wavefront_figures(wf: Wavefront) -> dict:
    """rms_waves, pv_waves, strehl, strehl_marechal (piston and tilt removed) and
    rms_waves_piston_only, as the module defines them."""
    resid = remove_piston_tilt(wf.pupil_xy, wf.opd_waves)
    rms = float(np.sqrt(np.mean(resid**2)))
    a = wf.amplitude
    field = (a * np.exp(2j * math.pi * resid)).sum()
    return {
        "rms_waves": rms,
        "pv_waves": float(resid.max() - resid.min()),
        "strehl": float(abs(field) ** 2 / a.sum() ** 2),
        "strehl_marechal": math.exp(-((2.0 * math.pi * rms) ** 2)),
        "rms_waves_piston_only": float(np.std(wf.opd_waves)),
    }


def zernike_fit(wf: Wavefront, convention: str = "noll", terms: int = 37) -> dict:
    """The wavefront's Zernike coefficients (waves, piston and tilt kept) by least squares
    over the pupil samples, and the RMS of what they leave: a JSON-ready dict."""
    zernike.check_terms(convention, terms)
    x, y = wf.pupil_xy[:, 0], wf.pupil_xy[:, 1]
    a = zernike.design_matrix(convention, terms, x, y)
    coeffs, *_ = np.linalg.lstsq(a, wf.opd_waves, rcond=None)
    resid = wf.opd_waves - a @ coeffs
    rows = []
    for j, c in enumerate(coeffs, start=1):
        n, m = zernike.term_nm(convention, j)
        rows.append({"term": j, "n": n, "m": m, "name": zernike.term_name(n, m), "waves": float(c)})
    return {
        "convention": convention,
        "convention_name": zernike.CONVENTION_NAMES[convention],
        "terms": rows,
        "coefficients_waves": [float(c) for c in coeffs],
        "fit_residual_rms_waves": float(np.sqrt(np.mean(resid**2))),
    }
