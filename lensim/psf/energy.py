"""Encircled and ensquared energy against radius (half-width), per field, from the
polychromatic PSF (Huygens by default; FFT or geometric on request).

Each wavelength's PSF (lensim.psf.compute's framing and sampling checks) is computed on
one window, centred on the reference point (the weighted mean of the wavelengths'
chief-ray image points), so lateral colour stays in the sum; the sum is weighted by the
wavelengths' weights. The curves are fractions of the transmitted energy (sum of weight
times transmitted fraction): energy outside the window counts as lost, so a window too
small shows as a curve that stays below 1 (energy_in_window says how much it holds).
They are measured around the polychromatic PSF's centroid (centre 'centroid') or the
reference point ('chief').

Sampling, unless given: spacing lambda_min N_w / 4 (N_w the working F-number, about a
fifth of the Airy radius), a window of `grid` samples, and the fewest pupil samples (at
least 64) whose PSF does not wrap around in that window.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError
from lensim.optics.aiming import Aiming
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.psf.compute import check_sampling
from lensim.psf.defaults import PsfMethod
from lensim.psf.fourier import fft_psf, geometric_psf
from lensim.psf.huygens import huygens_psf
from lensim.psf.metrics import enclosed_energy, psf_centroid_um, size_at_fraction
from lensim.psf.pupil_field import PupilField, pupil_field

CENTRES = ("centroid", "chief")
MIN_PUPIL_SAMPLES = 64


@dataclass
class EnergyCurves:
    """One field's curves: sizes_um (K,) radii and half-widths; encircled, ensquared (K,)
    fractions of the transmitted energy; the PSF window it came from."""

    field_value: float
    sizes_um: np.ndarray
    encircled: np.ndarray
    ensquared: np.ndarray
    energy_in_window: float
    centre_um: tuple[float, float]
    spacing_um: float
    grid: int
    pupil_samples: int

    def to_dict(self) -> dict:
        """JSON-ready, with the radii / half-widths holding 50 %, 80 % and 90 %."""
        out: dict = {
            "field": self.field_value,
            "radius_um": [float(r) for r in self.sizes_um],
            "encircled": [float(v) for v in self.encircled],
            "half_width_um": [float(r) for r in self.sizes_um],
            "ensquared": [float(v) for v in self.ensquared],
        }
        for p in (50, 80, 90):
            out[f"ee{p}_radius_um"] = size_at_fraction(self.sizes_um, self.encircled, p / 100)
            out[f"ensquared{p}_half_width_um"] = size_at_fraction(self.sizes_um, self.ensquared, p / 100)
        out |= {
            "energy_in_window": self.energy_in_window,
            "centre_um": list(self.centre_um),
            "spacing_um": self.spacing_um,
            "grid": self.grid,
            "pupil_samples": self.pupil_samples,
        }
        return out


def default_spacing_um(lens: Lens, wavelengths_um: Sequence[float]) -> float:
    """lambda_min N_w / 4 (um): the working F-number's Airy radius over about 5."""
    return min(wavelengths_um) * paraxial_data(lens).working_fno / 4.0


def polychromatic_psf(
    lens: Lens,
    field_value: float,
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    grid: int,
    spacing_um: float,
    pupil_samples: int | None = None,
    aiming: Aiming = "real",
    method: PsfMethod = "huygens",
) -> tuple[np.ndarray, float, int]:
    """(grid x grid weighted sum of the wavelengths' PSFs centred on the reference point,
    the transmitted energy sum of weight x transmission, the pupil samples used)."""
    if len(weights) != len(wavelengths_um):
        raise InputError(None, "wavelength_weights", f"expected {len(wavelengths_um)} weights, got {len(weights)}")
    para = paraxial_data(lens)
    fn = {"huygens": huygens_psf, "fft": fft_psf, "geometric": geometric_psf}[method]
    if pupil_samples is None:
        need = grid * spacing_um / (min(wavelengths_um) * para.working_fno)
        pupil_samples = max(MIN_PUPIL_SAMPLES, 2 * math.ceil(0.6 * need))
    pfs: list[PupilField] = []
    for wl in wavelengths_um:  # each wavelength's real aiming starts from the last one's solution
        pfs.append(pupil_field(lens, field_value, wl, pupil_samples, aiming, para, pfs[-1].aim if pfs else None))
    w = np.asarray(weights, dtype=np.float64)
    ref = sum(wi * pf.chief[:2] for wi, pf in zip(w, pfs, strict=True)) / w.sum()
    total = np.zeros((grid, grid))
    transmitted = 0.0
    for wi, pf in zip(w, pfs, strict=True):
        off = ref - pf.chief[:2]
        offset = (float(off[0]), float(off[1]))
        check_sampling(lens, pf, grid, spacing_um, method, offset)
        total += wi * fn(pf, grid, spacing_um, offset).numpy()
        transmitted += wi * pf.transmission
    return total, transmitted, pupil_samples


def energy_curves(
    lens: Lens,
    field_value: float,
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    grid: int = 128,
    spacing_um: float | None = None,
    pupil_samples: int | None = None,
    aiming: Aiming = "real",
    method: PsfMethod = "huygens",
    centre: str = "centroid",
    points: int = 101,
) -> EnergyCurves:
    """Encircled and ensquared energy of one field (lens units) at `points` sizes from 0
    to the window's half-width (um)."""
    if centre not in CENTRES:
        raise InputError(None, "centre", f"expected one of {', '.join(CENTRES)}, got {centre!r}")
    spacing = default_spacing_um(lens, wavelengths_um) if spacing_um is None else spacing_um
    psf, transmitted, samples = polychromatic_psf(
        lens, field_value, wavelengths_um, weights, grid, spacing, pupil_samples, aiming, method
    )
    c = psf_centroid_um(psf, spacing) if centre == "centroid" else (0.0, 0.0)
    diffraction = method != "geometric"
    sizes = np.linspace(0.0, grid * spacing / 2.0, points)
    return EnergyCurves(
        field_value=field_value,
        sizes_um=sizes,
        encircled=enclosed_energy(psf, spacing, sizes, "circle", c, transmitted, band_limited=diffraction),
        ensquared=enclosed_energy(psf, spacing, sizes, "square", c, transmitted, band_limited=diffraction),
        energy_in_window=float(psf.sum() / transmitted),
        centre_um=c,
        spacing_um=spacing,
        grid=grid,
        pupil_samples=samples,
    )
