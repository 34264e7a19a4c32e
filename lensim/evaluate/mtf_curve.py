"""MTF curves and what they are measured against: the curve type (:class:`MTFCurve`: MTF50,
area to Nyquist, cycles/mm), the area under a curve and the ratio of two areas (the paper's
Table 1 criterion), the MTF of a square pixel aperture, and the MTF a slanted edge should
measure through a given PSF (:func:`mtf_from_psf`, the Fourier slice of the PSF along the
edge normal). Frequencies in cycles/pixel (Nyquist 0.5) unless a name says cycles/mm.

The slanted-edge measurement itself is lensim.evaluate.slanted_edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from lensim.errors import InputError

Orientation = Literal["vertical", "horizontal"]


class MTFLike(Protocol):
    """Anything carrying an MTF curve: frequencies in cycles/pixel and the MTF there."""

    freq_cy_px: np.ndarray
    mtf: np.ndarray


@dataclass(frozen=True)
class MTFCurve:
    """An MTF curve along one direction.

    freq_cy_px: frequencies, cycles/pixel (Nyquist = 0.5); mtf: modulation transfer at
    those frequencies (1 at DC); pixel_pitch_um: the pixel pitch (um) that turns them into
    cycles/mm, or None when unknown.
    """

    freq_cy_px: np.ndarray
    mtf: np.ndarray
    pixel_pitch_um: float | None = None

    @property
    def freq_cy_mm(self) -> np.ndarray | None:
        """Frequencies in cycles/mm (None without a pixel pitch)."""
        return None if self.pixel_pitch_um is None else self.freq_cy_px / (self.pixel_pitch_um * 1e-3)

    def at(self, freq_cy_px: float | np.ndarray) -> float | np.ndarray:
        """MTF interpolated linearly at the given frequencies (cycles/pixel)."""
        return np.interp(freq_cy_px, self.freq_cy_px, self.mtf)

    def area(self, f_max_cy_px: float = 0.5) -> float:
        """Area under the curve from 0 to f_max (cycles/pixel units; 0.5 is Nyquist)."""
        return mtf_area(self.freq_cy_px, self.mtf, f_max_cy_px)

    @property
    def mtf50(self) -> float:
        """Lowest frequency (cycles/pixel) where the MTF falls to 0.5 (linear interpolation
        between samples); NaN if it never does within the curve."""
        return crossing_frequency(self.freq_cy_px, self.mtf, 0.5)

    @property
    def mtf50_cy_mm(self) -> float | None:
        """MTF50 in cycles/mm (None without a pixel pitch)."""
        return None if self.pixel_pitch_um is None else self.mtf50 / (self.pixel_pitch_um * 1e-3)

    @property
    def area_to_nyquist(self) -> float:
        """Area under the MTF from 0 to Nyquist (0.5 cycles/pixel), cycles/pixel units."""
        return self.area(0.5)


def crossing_frequency(freq: np.ndarray, mtf: np.ndarray, level: float) -> float:
    """First frequency where mtf drops to `level` (linear interpolation); NaN if never."""
    below = np.nonzero(mtf <= level)[0]
    if below.size == 0:
        return math.nan
    i = int(below[0])
    if i == 0:
        return float(freq[0])
    f0, f1, m0, m1 = freq[i - 1], freq[i], mtf[i - 1], mtf[i]
    return float(f0 + (m0 - level) * (f1 - f0) / (m0 - m1))


def mtf_area(freq_cy_px: np.ndarray, mtf: np.ndarray, f_max_cy_px: float = 0.5) -> float:
    """Area under an MTF curve from 0 to f_max (trapezoids; the curve is linearly
    interpolated at f_max). Units: cycles/pixel when freq is in cycles/pixel."""
    freq = np.asarray(freq_cy_px, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    if freq.ndim != 1 or freq.shape != m.shape or freq.size < 2:
        raise InputError(None, "mtf", f"expected matching 1-D frequency and MTF arrays, got {freq.shape} and {m.shape}")
    if not 0 < f_max_cy_px <= freq[-1] + 1e-12:
        raise InputError(
            None, "f_max", f"expected 0 < f_max <= {freq[-1]:.4g} cycles/pixel (the curve's range), got {f_max_cy_px}"
        )
    keep = freq < f_max_cy_px
    f = np.append(freq[keep], f_max_cy_px)
    v = np.append(m[keep], np.interp(f_max_cy_px, freq, m))
    return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(f)))


def mtf_area_ratio(
    measured: MTFLike | tuple[np.ndarray, np.ndarray],
    reference: MTFLike | tuple[np.ndarray, np.ndarray],
    f_max: float = 0.5,
) -> float:
    """Ratio of the areas under two MTF curves from 0 to f_max cycles/pixel (the paper's
    Table 1 criterion: simulated MTF area / reference MTF area). Each curve is an object
    with ``freq_cy_px`` and ``mtf`` (SFRResult, MTFCurve) or a (freq_cy_px, mtf) tuple; the
    two need not share a frequency axis."""
    fm, mm = (measured.freq_cy_px, measured.mtf) if not isinstance(measured, tuple) else measured
    fr, mr = (reference.freq_cy_px, reference.mtf) if not isinstance(reference, tuple) else reference
    a_ref = mtf_area(fr, mr, f_max)
    if a_ref <= 0:
        raise InputError(None, "reference", f"the reference MTF has no area up to {f_max} cycles/pixel")
    return mtf_area(fm, mm, f_max) / a_ref


def pixel_aperture_mtf(freq_cy_px: np.ndarray, angle_deg: float = 0.0) -> np.ndarray:
    """MTF of a square pixel with 100 % fill factor along the normal of an edge slanted by
    angle_deg: the pixel box projected onto the normal is the convolution of boxes
    cos(theta) and sin(theta) pixels wide, so |sinc(f cos theta) sinc(f sin theta)|
    (f in cycles/pixel; sinc(x) = sin(pi x) / (pi x)). Equal for vertical and horizontal
    edges and for +/- theta."""
    f = np.asarray(freq_cy_px, dtype=np.float64)
    t = math.radians(angle_deg)
    return np.abs(np.sinc(f * math.cos(t)) * np.sinc(f * math.sin(t)))


def default_frequencies(max_frequency: float = 1.0, step: float = 1.0 / 256.0) -> np.ndarray:
    """The frequency axis slanted_edge_mtf returns by default (cycles/pixel, 1/256 apart)."""
    return np.arange(0.0, max_frequency + 1e-12, step)


def mtf_from_psf(
    psf: np.ndarray,
    spacing_um: float,
    angle_deg: float,
    *,
    pixel_pitch_um: float | None = None,
    pixel_integrated: bool = False,
    orientation: Orientation = "vertical",
    freq_cy_px: np.ndarray | None = None,
) -> MTFCurve:
    """The MTF a slanted edge at angle_deg should measure through a given PSF.

    psf: 2-D samples (energy per sample) spaced spacing_um apart, oriented like the image
    it blurs (row index = y). The PSF's line spread function perpendicular to the edge is
    its projection onto the edge normal; by the Fourier slice theorem its 1-D transform is
    the 2-D transform of the samples along the normal, evaluated here exactly (a direct
    sum over the samples, no binning) and normalized at DC.

    pixel_pitch_um: the pixel pitch (um) defining cycles/pixel; None means the PSF is on
    the pixel grid (pitch = spacing_um). pixel_integrated: True when the samples already
    include the pixel aperture (each is an integral over a pixel-sized area, e.g. a PSF
    bank's pixel PSF); False multiplies by the pixel aperture MTF along the normal
    (pixel_aperture_mtf). Note that a target which is itself area-sampled and then
    convolved with a pixel-integrated PSF (what a simulation that blurs a pixel image with
    a pixel PSF does) carries the aperture twice: its slanted edge measures
    pixel_aperture_mtf x mtf_from_psf(..., pixel_integrated=True).

    freq_cy_px: frequencies (cycles/pixel) to evaluate at, e.g. an SFRResult's;
    default default_frequencies(). Returns an MTFCurve.
    """
    p = np.asarray(psf, dtype=np.float64)
    if p.ndim != 2 or not np.all(np.isfinite(p)):
        raise InputError(None, "psf", f"expected a finite 2-D array, got shape {p.shape}")
    total = p.sum()
    if not total > 0:
        raise InputError(None, "psf", "the PSF sums to zero or less")
    if not spacing_um > 0:
        raise InputError(None, "spacing_um", f"expected a positive sample spacing in um, got {spacing_um}")
    pitch = spacing_um if pixel_pitch_um is None else float(pixel_pitch_um)
    if not pitch > 0:
        raise InputError(None, "pixel_pitch_um", f"expected a positive pitch in um, got {pixel_pitch_um}")
    if orientation not in ("vertical", "horizontal"):
        raise InputError(None, "orientation", f"expected 'vertical' or 'horizontal', got {orientation!r}")
    f = default_frequencies() if freq_cy_px is None else np.asarray(freq_cy_px, dtype=np.float64)
    t = math.radians(angle_deg)
    nx, ny = (math.cos(t), -math.sin(t)) if orientation == "vertical" else (-math.sin(t), math.cos(t))
    rows, cols = p.shape
    # Sample positions in pixels about the array centre (the origin only sets a phase).
    s = spacing_um / pitch
    x = (np.arange(cols) - cols // 2) * s
    y = (np.arange(rows) - rows // 2) * s
    ax = np.exp(-2j * np.pi * np.outer(f, x * nx))  # (F, cols)
    ay = np.exp(-2j * np.pi * np.outer(f, y * ny))  # (F, rows)
    otf = np.einsum("fr,rc,fc->f", ay, p, ax, optimize=True) / total
    mtf = np.abs(otf)
    if not pixel_integrated:
        mtf = mtf * pixel_aperture_mtf(f, angle_deg)
    return MTFCurve(freq_cy_px=f, mtf=mtf, pixel_pitch_um=pixel_pitch_um if pixel_pitch_um is not None else spacing_um)
