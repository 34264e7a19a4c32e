"""The optical MTF a chart's slanted edges see, for a lens that may be decentred or tilted.

An edge observation is a point on the sensor (x, y mm from the axis, x right, y up as the
lens's +y fields), the direction across the edge (angle_deg counter-clockwise from +x, the
direction the modulation is measured along) and the frequencies (lp/mm) of its SFR.

A perturbed lens is not rotationally symmetric: a field at azimuth phi (counter-clockwise
from +y) is traced as the +y field of the lens turned by phi
(lensim.calibrate.tolerance_report.lens_at_azimuth), and the direction across the edge
turns with it. The OTF along any direction comes from the 2-D pupil autocorrelation
(zero-padded FFT of lensim.psf.fourier.pupil_function, lags scaled per axis by
lensim.psf.fourier.direction_scale, bilinear between lags), polychromatic with each
wavelength's weight, transmission and chief-ray offset (lateral colour), as
lensim.psf.mtf does for the two axis cuts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lensim.calibrate.tolerance_report import lens_at_azimuth
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.psf.fourier import direction_scale, pupil_function
from lensim.psf.pupil_field import PupilField, pupil_field


@dataclass(frozen=True)
class Edge:
    """One slanted edge: x_mm, y_mm on the sensor; angle_deg across the edge (from +x,
    counter-clockwise); frequencies_lp_mm (F,) where its SFR is known."""

    x_mm: float
    y_mm: float
    angle_deg: float
    frequencies_lp_mm: tuple[float, ...]

    @property
    def radius_mm(self) -> float:
        return math.hypot(self.x_mm, self.y_mm)

    @property
    def azimuth_deg(self) -> float:
        """The field's azimuth, counter-clockwise from +y (0 on the axis)."""
        return 0.0 if self.radius_mm == 0 else math.degrees(math.atan2(-self.x_mm, self.y_mm))


def _otf_2d(pf: PupilField) -> np.ndarray:
    """The normalized OTF on the (2n, 2n) lag grid (rows: y lags, wrapped)."""
    n = pf.samples
    pupil = pupil_function(pf).numpy()
    spec = np.fft.fft2(pupil, s=(2 * n, 2 * n))
    auto = np.fft.ifft2(spec * spec.conj())
    return auto / auto[0, 0].real


def _bilinear(grid: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """Complex grid values at fractional wrapped lags (kx, ky); 0 beyond +-n lags."""
    m = grid.shape[0]
    n = m // 2
    inside = (np.abs(kx) < n) & (np.abs(ky) < n)
    x0, y0 = np.floor(kx).astype(int), np.floor(ky).astype(int)
    tx, ty = kx - x0, ky - y0
    out = np.zeros(kx.shape, dtype=np.complex128)
    for dy, wy in ((0, 1.0 - ty), (1, ty)):
        for dx, wx in ((0, 1.0 - tx), (1, tx)):
            out += wx * wy * grid[(y0 + dy) % m, (x0 + dx) % m]
    return np.where(inside, out, 0.0)


def otf_along(pf: PupilField, angle_deg: float, frequencies: np.ndarray) -> np.ndarray:
    """Complex OTF (F,) of one pupil field along the direction angle_deg (from +x) at the
    frequencies (lp/mm), relative to its chief-ray image point."""
    scale = pf.n_image * (2.0 / pf.samples) / pf.wavelength_mm  # lp/mm per lag per unit slope
    ax, ay = direction_scale(pf)
    a = math.radians(angle_deg)
    kx = frequencies * math.cos(a) / (ax * scale)
    ky = frequencies * math.sin(a) / (ay * scale)
    return _bilinear(_otf_2d(pf), kx, ky)


@dataclass
class _Spot:
    """The pupil fields (one per wavelength) of one sensor point, with their 2-D OTFs."""

    fields: list[PupilField]
    otfs: list[np.ndarray]


def _spot(lens: Lens, edge: Edge, wavelengths_um: Sequence[float], samples: int, aiming: str) -> _Spot:
    turned = lens_at_azimuth(lens, edge.azimuth_deg)
    probe = turned.with_changes(field_type="paraxial_image_height", fields=[max(edge.radius_mm, 1e-9)])
    para = paraxial_data(probe)
    pfs, aim = [], None
    for wl in wavelengths_um:
        pf = pupil_field(probe, edge.radius_mm, wl, samples, aiming, para, aim)  # type: ignore[arg-type]
        aim = pf.aim
        pfs.append(pf)
    return _Spot(pfs, [_otf_2d(pf) for pf in pfs])


def _edge_from_spot(spot: _Spot, edge: Edge, weights: Sequence[float]) -> np.ndarray:
    f = np.asarray(edge.frequencies_lp_mm, dtype=np.float64)
    angle = edge.angle_deg - edge.azimuth_deg
    direction = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
    total = np.zeros(f.shape, dtype=np.complex128)
    norm, ref = 0.0, spot.fields[0].chief[:2].numpy()
    a = math.radians(angle)
    for pf, otf, w in zip(spot.fields, spot.otfs, weights, strict=True):
        scale = pf.n_image * (2.0 / pf.samples) / pf.wavelength_mm
        ax, ay = direction_scale(pf)
        lags = _bilinear(otf, f * math.cos(a) / (ax * scale), f * math.sin(a) / (ay * scale))
        shift = float((pf.chief[:2].numpy() - ref) @ direction)
        weight = w * pf.transmission
        total += weight * lags * np.exp(-2j * np.pi * f * shift)
        norm += weight
    return np.abs(total) / max(norm, 1e-300)


def edge_mtf(
    lens: Lens,
    edge: Edge,
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 32,
    aiming: str = "paraxial",
) -> np.ndarray:
    """The polychromatic optical MTF (F,) across one edge of a lens (perturbed or not)."""
    return _edge_from_spot(_spot(lens, edge, wavelengths_um, samples, aiming), edge, weights)


def model_mtfs(
    lens: Lens,
    edges: Sequence[Edge],
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 32,
    aiming: str = "paraxial",
) -> list[np.ndarray]:
    """edge_mtf of every edge; edges at one sensor point share its trace."""
    spots: dict[tuple[float, float], _Spot] = {}
    out = []
    for e in edges:
        key = (e.x_mm, e.y_mm)
        if key not in spots:
            spots[key] = _spot(lens, e, wavelengths_um, samples, aiming)
        out.append(_edge_from_spot(spots[key], e, weights))
    return out
