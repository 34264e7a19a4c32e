"""The diffraction MTF of a lens: sagittal and tangential, polychromatic, through focus.

The optical transfer function (OTF) of one field at one wavelength is the autocorrelation
of the complex pupil function (lensim.psf.fourier.pupil_function: the pupil field's
amplitudes and OPD on its samples x samples grid), computed by a zero-padded FFT: lag k
(pupil cells) along x is the image-plane frequency k * n' |a_x| (2 / samples) / lambda
(cycles/mm), a_x the pupil-to-direction-cosine slope the FFT PSF uses
(lensim.psf.fourier.direction_scale), so off-axis pupils keep their anamorphism; the
cutoff (lag = samples, the full pupil) is 2 n' |a_x| / lambda = 1 / (lambda N_w). This is
the FFT MTF of design programs; it equals the Fourier transform of lensim's FFT PSF, and of
its Huygens PSF where the two PSFs agree. Between lags the complex OTF is interpolated
linearly; beyond the cutoff it is 0.

Fields lie along +y: the tangential MTF is the modulation of a pattern varying along y
(OTF(0, f)), the sagittal one along x (OTF(f, 0)).

Polychromatic: OTF = sum_l w_l T_l OTF_l(f) exp(-2 pi i f d_l) / sum_l w_l T_l, with w_l
the wavelength's weight, T_l its transmitted fraction and d_l its chief-ray image point
relative to the first wavelength's: each wavelength's PSF keeps its place, so lateral
colour lowers the polychromatic MTF as it blurs the image. Units: mm, um for wavelengths,
cycles/mm (lp/mm) for frequencies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError
from lensim.optics.aiming import Aiming
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData, paraxial_data
from lensim.psf.fourier import direction_scale, pupil_function
from lensim.psf.pupil_field import PupilField, pupil_field, pupil_fields_through_focus


@dataclass
class OTFCuts:
    """The OTF of one field and wavelength along the two axes, at lags 0..samples.

    step_x, step_y: cycles/mm per lag (positive); otf_x (samples + 1,) complex, OTF(k
    step_x, 0), and otf_y, OTF(0, k step_y), both 1 at lag 0 and relative to the chief-ray
    image point chief_xy_mm; weight: the wavelength's weight times its transmission."""

    step_x: float
    step_y: float
    otf_x: np.ndarray
    otf_y: np.ndarray
    chief_xy_mm: np.ndarray
    weight: float

    @property
    def cutoff_lp_mm(self) -> float:
        """The larger of the two axes' cutoff frequencies (cycles/mm)."""
        return (self.otf_x.size - 1) * max(self.step_x, self.step_y)


def otf_cuts(pf: PupilField, weight: float = 1.0) -> OTFCuts:
    """The OTF cuts of a pupil field (weight: the wavelength's spectral weight; the
    transmission is multiplied in)."""
    n = pf.samples
    pupil = pupil_function(pf).numpy()
    spec = np.fft.fft2(pupil, s=(2 * n, 2 * n))
    auto = np.fft.ifft2(spec * spec.conj())  # auto[k] = sum_m P[m + k] P*[m]
    auto = auto / auto[0, 0].real
    ax, ay = direction_scale(pf)
    scale = pf.n_image * (2.0 / n) / pf.wavelength_mm  # cycles/mm per lag per unit slope
    # a negative slope turns lag +k into frequency -f: OTF(+f) is then the conjugate
    otf_x = auto[0, : n + 1] if ax > 0 else auto[0, : n + 1].conj()
    otf_y = auto[: n + 1, 0] if ay > 0 else auto[: n + 1, 0].conj()
    return OTFCuts(
        step_x=abs(ax) * scale,
        step_y=abs(ay) * scale,
        otf_x=otf_x,
        otf_y=otf_y,
        chief_xy_mm=pf.chief[:2].numpy().copy(),
        weight=weight * pf.transmission,
    )


def _interp(otf: np.ndarray, step: float, f: np.ndarray) -> np.ndarray:
    """The complex OTF at frequencies f (cycles/mm) from its values every `step`, 0 past the last lag."""
    k = f / step
    k0 = np.floor(k).astype(int)
    t = k - k0
    n = otf.size - 1
    inside = k0 < n
    k0c = np.clip(k0, 0, n - 1)
    out = otf[k0c] * (1.0 - t) + otf[k0c + 1] * t
    return np.where(inside, out, 0.0)


@dataclass
class FieldOTF:
    """The OTF cuts of one field at each wavelength (field_value in the lens's unit)."""

    field_value: float
    cuts: list[OTFCuts]

    @property
    def cutoff_lp_mm(self) -> float:
        """The highest cutoff frequency among the wavelengths (cycles/mm)."""
        return max(c.cutoff_lp_mm for c in self.cuts)

    def otf(self, frequencies: np.ndarray | Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """(sagittal, tangential) polychromatic complex OTF at the frequencies (cycles/mm)."""
        f = np.asarray(frequencies, dtype=np.float64)
        ref = self.cuts[0].chief_xy_mm
        total = sum(c.weight for c in self.cuts)
        if not total > 0:
            raise InputError(None, "wavelength_weights", "expected weights whose sum over the wavelengths is above 0")
        sag = np.zeros(f.shape, dtype=np.complex128)
        tan = np.zeros(f.shape, dtype=np.complex128)
        for c in self.cuts:
            dx, dy = c.chief_xy_mm - ref
            sag += c.weight * _interp(c.otf_x, c.step_x, f) * np.exp(-2j * np.pi * f * dx)
            tan += c.weight * _interp(c.otf_y, c.step_y, f) * np.exp(-2j * np.pi * f * dy)
        return sag / total, tan / total

    def mtf(self, frequencies: np.ndarray | Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """(sagittal, tangential) polychromatic MTF at the frequencies (cycles/mm)."""
        sag, tan = self.otf(frequencies)
        return np.abs(sag), np.abs(tan)


def field_otf(
    lens: Lens,
    field_value: float,
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 64,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
) -> FieldOTF:
    """The OTF cuts of one field (in the lens's unit) at each wavelength (um) with its
    weight, on a samples x samples pupil grid."""
    if len(weights) != len(wavelengths_um):
        raise InputError(None, "wavelength_weights", f"expected {len(wavelengths_um)} weights, got {len(weights)}")
    para = para or paraxial_data(lens)
    cuts = []
    aim = None  # each wavelength's real aiming starts from the last one's solution
    for wl, w in zip(wavelengths_um, weights, strict=True):
        pf = pupil_field(lens, field_value, wl, samples, aiming, para, aim)
        aim = pf.aim
        cuts.append(otf_cuts(pf, w))
    return FieldOTF(field_value, cuts)


def refocused(lens: Lens, shift_mm: float) -> Lens:
    """The lens with its image plane moved by shift_mm along the image-space light
    direction (positive: away from the lens)."""
    direction = float(lens.directions()[-1])
    return lens.with_changes(image_defocus=lens.image_defocus + direction * shift_mm)


def through_focus(
    lens: Lens,
    field_value: float,
    shifts_mm: Sequence[float],
    frequencies: Sequence[float],
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 64,
    aiming: Aiming = "real",
    para: ParaxialData | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(sagittal, tangential) MTF of one field, each (frequencies, shifts), with the image
    plane moved by each shift (mm, positive away from the lens; one trace per wavelength,
    lensim.psf.pupil_field.pupil_fields_through_focus)."""
    para = para or paraxial_data(lens)
    shifts = [float(z) for z in shifts_mm]
    per_wl: list[list[PupilField]] = []
    for wl in wavelengths_um:  # real aiming warm-started as in field_otf
        aim = per_wl[-1][0].aim if per_wl else None
        per_wl.append(pupil_fields_through_focus(lens, field_value, wl, shifts, samples, aiming, para, aim))
    sag = np.zeros((len(frequencies), len(shifts)))
    tan = np.zeros_like(sag)
    for k in range(len(shifts)):
        cuts = [otf_cuts(pfs[k], w) for pfs, w in zip(per_wl, weights, strict=True)]
        sag[:, k], tan[:, k] = FieldOTF(field_value, cuts).mtf(frequencies)
    return sag, tan


def diffraction_limited_mtf(frequency_lp_mm: np.ndarray, wavelength_um: float, fno: float) -> np.ndarray:
    """The incoherent MTF of an aberration-free circular pupil: (2/pi)(acos v - v sqrt(1 - v^2)),
    v = f lambda N (0 beyond the cutoff)."""
    v = np.clip(np.asarray(frequency_lp_mm, dtype=np.float64) * wavelength_um * 1e-3 * fno, 0.0, 1.0)
    return (2.0 / np.pi) * (np.arccos(v) - v * np.sqrt(1.0 - v * v))
