"""Best focus: where a camera's autofocus puts the image plane.

The criterion (``FOCUS_CRITERION``): the minimum of the polychromatic RMS wavefront error
on axis,

    E(dz) = sum_l w_l rms_l(dz)^2 / sum_l w_l     (waves^2),

with w_l the lens file's wavelength weights and rms_l the RMS of the on-axis OPD at
wavelength l (lensim.psf.wavefront: piston and tilt removed, equal weights over a uniform
pupil grid, reference sphere centred on the chief-ray point of the plane moved by dz).
Each wavelength's RMS is in its own waves, so E is what sets the Strehl ratio of a
nearly corrected lens (Marechal); minimizing it is a contrast-detect autofocus on the
central subject at the taking aperture.

dz is the image plane's shift (mm) along the image-space light direction, positive away
from the lens. One trace per wavelength is carried to other planes along its straight
image-space paths (lensim.psf.pupil_field.pupil_fields_through_focus), where the OPD is
linear in dz to first order, so E is nearly a parabola: it is fitted over the span of the
rays' axis crossings, then refitted over a span 20 times narrower around the vertex.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from lensim.optics.aiming import Aiming
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.psf.pupil_field import PupilField, focus_stack
from lensim.psf.wavefront import remove_piston_tilt

#: the documented criterion, as records name it
FOCUS_CRITERION = "minimum polychromatic RMS wavefront error on axis"
#: pupil samples per side for the criterion
FOCUS_SAMPLES = 32
_POINTS = 9
_REFITS = 4


def _rms2(pf: PupilField) -> float:
    """The squared RMS (waves^2) of one pupil field's OPD, piston and tilt removed."""
    w = (-pf.opl / pf.wavelength_mm).numpy()
    resid = remove_piston_tilt(pf.pupil_xy.numpy(), w)
    return float(np.mean(resid**2))


class FocusError:
    """E(dz) of one lens, from one trace per wavelength (lensim.psf.pupil_field.focus_stack)."""

    def __init__(self, lens: Lens, samples: int = FOCUS_SAMPLES, aiming: Aiming = "real") -> None:
        para = paraxial_data(lens)
        self.stacks: list[Callable[[float], PupilField]] = []
        aim = None
        for wl in lens.wavelengths_um:  # real aiming warm-started from the last wavelength
            stack = focus_stack(lens, 0.0, wl, samples, aiming, para, aim)
            aim = stack(0.0).aim
            self.stacks.append(stack)
        weights = np.asarray(lens.wavelength_weights, dtype=np.float64)
        self.weights = weights / max(float(weights.sum()), 1e-300)
        primary = self.stacks[lens.primary](0.0)
        self.span = _crossing_span(primary)

    def __call__(self, shifts_mm: np.ndarray) -> np.ndarray:
        """E (waves^2, shape (S,)) at the image-plane shifts (mm, shape (S,))."""
        return np.array(
            [
                sum(w * _rms2(stack(float(z))) for w, stack in zip(self.weights, self.stacks, strict=True))
                for z in shifts_mm
            ]
        )


def focus_error(lens: Lens, shifts_mm: np.ndarray, samples: int = FOCUS_SAMPLES, aiming: Aiming = "real") -> np.ndarray:
    """E(dz) (waves^2, shape (S,)) at the image-plane shifts (mm, shape (S,), positive away
    from the lens), on axis."""
    return FocusError(lens, samples, aiming)(np.asarray(shifts_mm, dtype=np.float64))


def _crossing_span(pf: PupilField) -> tuple[float, float]:
    """(low, high) shifts (mm) between which a pupil field's rays cross the axis, at least
    four depths of focus (4 lambda N^2) either side of the plane."""
    d = pf.directions
    xy, dxy = pf.image_xy, d[:, :2]
    t = -(xy * dxy).sum(-1) / (dxy * dxy).sum(-1).clamp_min(1e-300)
    along = t * d[:, 2].abs()  # the path's z extent, along the light
    along = along[torch.isfinite(along)]
    fno = max(pf.working_fno(), 0.5)
    depth = 4.0 * pf.wavelength_mm * fno * fno
    if along.numel() == 0:
        return -depth, depth
    return min(float(along.min()), -depth), max(float(along.max()), depth)


def _vertex(shifts: np.ndarray, err: np.ndarray) -> float:
    """The minimum of the parabola fitted to err(shifts); the lowest sample where the fit
    is not convex."""
    a, b, _ = np.polyfit(shifts, err, 2)
    if a <= 0:
        return float(shifts[int(np.argmin(err))])
    return float(np.clip(-b / (2 * a), shifts.min(), shifts.max()))


def best_focus_shift(lens: Lens, samples: int = FOCUS_SAMPLES, aiming: Aiming = "real") -> float:
    """The image-plane shift (mm, along the light, positive away from the lens) from the
    lens's image plane to its best focus by FOCUS_CRITERION."""
    error = FocusError(lens, samples, aiming)
    lo, hi = error.span
    shifts = np.linspace(lo, hi, _POINTS)
    z = _vertex(shifts, error(shifts))
    half = (hi - lo) / 40.0
    for _ in range(_REFITS):
        shifts = np.linspace(z - half, z + half, _POINTS)
        new = _vertex(shifts, error(shifts))
        if abs(new - z) < 0.25 * half:  # inside the bracket: done
            return new
        z = new
    return z
