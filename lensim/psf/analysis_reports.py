"""The lens analyses as JSON-ready reports (what `lensim lens mtf / wavefront / energy`
print and draw): MTF against frequency, field and focus; the wavefront of one field
with its Zernike coefficients; encircled and ensquared energy per field.

Fields are given in the lens's unit (degrees or mm) along +y, wavelengths in um with
their weights; frequencies in cycles/mm (lp/mm), lengths in mm or um as keys say.
progress(done, total), when given, is called as the work advances.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from lensim.optics.aiming import Aiming
from lensim.optics.field_analysis import _field_unit
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.psf.defaults import PsfMethod
from lensim.psf.energy import energy_curves
from lensim.psf.mtf import field_otf, through_focus
from lensim.psf.wavefront import wavefront, wavefront_figures, zernike_fit

Progress = Callable[[float, float], None] | None


def _header(lens: Lens, wavelengths_um: Sequence[float], weights: Sequence[float], aiming: str) -> dict:
    return {
        "name": lens.name,
        "source": lens.source,
        "field_unit": _field_unit(lens),
        "wavelengths_nm": [w * 1000.0 for w in wavelengths_um],
        "wavelength_weights": [float(w) for w in weights],
        "aiming": aiming,
    }


def _tick(progress: Progress, done: int, total: int) -> int:
    if progress is not None:
        progress(done, total)
    return done + 1


def mtf_report(
    lens: Lens,
    fields: Sequence[float],
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    frequencies: Sequence[float],
    sweep_fields: Sequence[float],
    focus_shifts_mm: Sequence[float] = (),
    max_frequency: float | None = None,
    frequency_points: int = 51,
    samples: int = 64,
    aiming: Aiming = "real",
    progress: Progress = None,
) -> dict:
    """MTF (lensim.psf.mtf) of each field against frequency (frequency_points from 0 to
    max_frequency, default the highest cutoff among the fields), of each of sweep_fields
    at the frequencies, and through focus (each field, each frequency, each shift in mm,
    positive away from the lens; none when focus_shifts_mm is empty)."""
    para = paraxial_data(lens)
    total = len(fields) * (2 if len(focus_shifts_mm) else 1) + len(sweep_fields)
    done = _tick(progress, 0, total)
    otfs = []
    for fv in fields:
        otfs.append(field_otf(lens, fv, wavelengths_um, weights, samples, aiming, para))
        done = _tick(progress, done, total)
    top = max(o.cutoff_lp_mm for o in otfs) if max_frequency is None else max_frequency
    axis = np.linspace(0.0, top, frequency_points)
    per_field = []
    for o in otfs:
        sag, tan = o.mtf(axis)
        per_field.append(
            {
                "field": o.field_value,
                "cutoff_lp_mm": o.cutoff_lp_mm,
                "frequency_lp_mm": axis.tolist(),
                "sagittal": sag.tolist(),
                "tangential": tan.tolist(),
            }
        )
    sweep_s, sweep_t = [], []
    for fv in sweep_fields:
        sag, tan = field_otf(lens, fv, wavelengths_um, weights, samples, aiming, para).mtf(frequencies)
        sweep_s.append(sag)
        sweep_t.append(tan)
        done = _tick(progress, done, total)
    report = _header(lens, wavelengths_um, weights, aiming) | {
        "method": "fft (pupil autocorrelation)",
        "pupil_samples": samples,
        "fields": per_field,
        "against_field": {
            "frequency_lp_mm": [float(f) for f in frequencies],
            "fields": [float(f) for f in sweep_fields],
            "sagittal": np.asarray(sweep_s).T.tolist(),
            "tangential": np.asarray(sweep_t).T.tolist(),
        },
    }
    if len(focus_shifts_mm):
        report["through_focus"] = _through_focus(
            lens, fields, focus_shifts_mm, frequencies, wavelengths_um, weights, samples, aiming, progress, done, total
        )
    return report


def _through_focus(lens, fields, shifts, frequencies, wavelengths_um, weights, samples, aiming, progress, done, total):
    para = paraxial_data(lens)
    rows = []
    for fv in fields:
        sag, tan = through_focus(lens, fv, shifts, frequencies, wavelengths_um, weights, samples, aiming, para)
        rows.append({"field": float(fv), "sagittal": sag.tolist(), "tangential": tan.tolist()})
        done = _tick(progress, done, total)
    return {
        "focus_shift_mm": [float(z) for z in shifts],
        "frequency_lp_mm": [float(f) for f in frequencies],
        "fields": rows,
    }


def wavefront_report(
    lens: Lens,
    field_value: float,
    wavelength_um: float,
    convention: str = "noll",
    terms: int = 37,
    samples: int = 64,
    aiming: Aiming = "real",
) -> tuple[dict, np.ndarray]:
    """(the report, the (samples, samples) OPD map in waves, piston and tilt removed, NaN
    outside the beam) of one field at one wavelength."""
    wf = wavefront(lens, field_value, wavelength_um, samples, aiming)
    report = _header(lens, [wavelength_um], [1.0], aiming) | {
        "field": field_value,
        "wavelength_nm": wavelength_um * 1000.0,
        "pupil_samples": samples,
        "opd_sign": "OPD = (chief ray's optical path - ray's) / wavelength; image plane moved away "
        "from the lens: positive defocus",
        "reference": "sphere centred on the real chief-ray image point, through the exit pupil",
        "transmission": wf.transmission,
        **wavefront_figures(wf),
        "zernike": zernike_fit(wf, convention, terms),
    }
    return report, wf.opd_map()


def energy_report(
    lens: Lens,
    fields: Sequence[float],
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    grid: int = 128,
    spacing_um: float | None = None,
    pupil_samples: int | None = None,
    aiming: Aiming = "real",
    method: PsfMethod = "huygens",
    centre: str = "centroid",
    progress: Progress = None,
) -> dict:
    """Encircled and ensquared energy of each field (lensim.psf.energy)."""
    done = _tick(progress, 0, len(fields))
    curves = []
    for fv in fields:
        c = energy_curves(lens, fv, wavelengths_um, weights, grid, spacing_um, pupil_samples, aiming, method, centre)
        curves.append(c.to_dict())
        done = _tick(progress, done, len(fields))
    return _header(lens, wavelengths_um, weights, aiming) | {
        "method": method,
        "centre": centre,
        "normalization": "fraction of the transmitted energy (weights x transmission)",
        "fields": curves,
    }
