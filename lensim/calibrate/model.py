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

The points at one azimuth are traced in one batch with every wavelength
(lensim.psf.pupil_field.focus_stacks: measured 1.8 s for 17 points x 3 wavelengths at 32
pupil samples against about 12 s one field and wavelength at a time). A change of the
image plane (focus, sensor tilt) needs no new trace: each point's rays are carried to
where the moved and turned sensor is at that point (sensor_shift_mm); to first order in
the tilt this is the tilted sensor (the PSF spans microns; measured within a tenth of the
change it makes on the Cooke triplet, tests/test_calibrate_fit.py).

An edge measured on lensim's rendering (an edge with pitch_um) does not see the optical
MTF times the pixel's sinc: lensim blurs with kernels sampled at the pixel pitch, and an
edge's SFR in such an image is the transfer of that sampled kernel, the sum of the
pixel-integrated OTF over the aliases (n, m) / pitch (|n|, |m| <= ALIAS_ORDERS), the kernel's
centre sample on the chief ray. At phone_wide's 3.8 um the optics pass much beyond
Nyquist, and the aliases changed differently with a decentre than the optical MTF:
modelled without them, an element decentred 12 um lowered the rendered edges' MTF by 0.07
more than the model said (benchmarks/calibration_validation.py's camera), which the fit
took as extra focus.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from lensim.calibrate.tolerance_report import lens_at_azimuth
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.psf.fourier import direction_scale, pupil_function
from lensim.psf.pupil_field import PupilField, focus_stacks


@dataclass(frozen=True)
class Edge:
    """One slanted edge: x_mm, y_mm on the sensor; angle_deg across the edge (from +x,
    counter-clockwise); frequencies_lp_mm (F,) where its SFR is known; pitch_um: the pixel
    pitch (um) of lensim's kernels when its SFR is that of lensim's rendering (the model is
    then the sampled kernel's transfer, module docstring), None for an optical MTF."""

    x_mm: float
    y_mm: float
    angle_deg: float
    frequencies_lp_mm: tuple[float, ...]
    pitch_um: float | None = None

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


#: a sensor point's focus stacks, one per wavelength (lensim.psf.pupil_field.focus_stacks)
Stacks = list[Callable[[float], PupilField]]


def trace_points(
    lens: Lens, edges: Sequence[Edge], wavelengths_um: Sequence[float], samples: int = 32, aiming: str = "paraxial"
) -> dict[tuple[float, float], Stacks]:
    """The focus stacks of every distinct sensor point of the edges, keyed by (x_mm, y_mm):
    the points at one azimuth are traced together, as +y fields of the lens turned there."""
    groups: dict[float, dict[tuple[float, float], float]] = {}
    for e in edges:
        groups.setdefault(round(e.azimuth_deg, 9), {})[(e.x_mm, e.y_mm)] = max(e.radius_mm, 1e-9)
    out: dict[tuple[float, float], Stacks] = {}
    for azimuth, points in groups.items():
        turned = lens_at_azimuth(lens, azimuth)
        radii = list(points.values())
        probe = turned.with_changes(field_type="paraxial_image_height", fields=[max(radii)])
        stacks = focus_stacks(probe, radii, list(wavelengths_um), samples, aiming, paraxial_data(probe))  # type: ignore[arg-type]
        out.update(zip(points, stacks, strict=True))
    return out


def sensor_shift_mm(x_mm: float, y_mm: float, image: Sequence[float]) -> float:
    """How far (mm, away from the lens) the sensor at (x, y) mm moves for an image-plane
    change image = (focus mm, tilt_x deg, tilt_y deg): the plane turned about the axis
    point (lensim.optics.pose: tilt_x about x, tilt_y about y) and moved along the axis."""
    focus, tilt_x, tilt_y = image
    return focus + y_mm * math.tan(math.radians(tilt_x)) - x_mm * math.tan(math.radians(tilt_y))


#: alias orders (each axis) summed by a pixel-sampled model (mtfs_from's pitch_um)
ALIAS_ORDERS = 2


def mtfs_from(
    stacks: dict[tuple[float, float], Stacks],
    edges: Sequence[Edge],
    weights: Sequence[float],
    image: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[np.ndarray]:
    """The MTF (F,) of every edge from its point's stacks (trace_points), the sensor moved
    and turned by image = (focus mm, tilt_x deg, tilt_y deg) on top of the traced lens's
    (with an edge's pitch_um, its pixel kernel's transfer)."""
    spots: dict[tuple[float, float], _Spot] = {}
    out = []
    for e in edges:
        key = (e.x_mm, e.y_mm)
        if key not in spots:
            dz = sensor_shift_mm(e.x_mm, e.y_mm, image)
            pfs = [at(dz) for at in stacks[key]]
            spots[key] = _Spot(pfs, [_otf_2d(pf) for pf in pfs])
        out.append(_edge_from_spot(spots[key], e, weights))
    return out


def _frequency_vectors(edge: Edge) -> tuple[np.ndarray, np.ndarray]:
    """(F, A, 2) frequency vectors (lp/mm) in the sensor's frame: the edge's frequencies
    across it, each with the A alias offsets (n, m) / pitch (|n|, |m| <= ALIAS_ORDERS; one,
    (0, 0), without the edge's pitch); and the same turned into the frame of the lens turned to the
    edge's azimuth (trace_points)."""
    f = np.asarray(edge.frequencies_lp_mm, dtype=np.float64)
    a = math.radians(edge.angle_deg)
    base = f[:, None] * np.array([math.cos(a), math.sin(a)])
    pitch_um = edge.pitch_um
    if pitch_um is None:
        offsets = np.zeros((1, 2))
    else:
        n = np.arange(-ALIAS_ORDERS, ALIAS_ORDERS + 1, dtype=np.float64)
        offsets = np.stack(np.meshgrid(n, n, indexing="ij"), axis=-1).reshape(-1, 2) / (pitch_um * 1e-3)
    sensor = base[:, None, :] + offsets[None]
    z = math.radians(edge.azimuth_deg)  # the turned frame: vectors turned by -azimuth
    c, s = math.cos(z), math.sin(z)
    turned = np.stack([c * sensor[..., 0] + s * sensor[..., 1], -s * sensor[..., 0] + c * sensor[..., 1]], axis=-1)
    return sensor, turned


def _edge_from_spot(spot: _Spot, edge: Edge, weights: Sequence[float]) -> np.ndarray:
    """The polychromatic transfer (F,) across one edge, relative to the spot's weighted
    mean chief-ray point (each wavelength's offset from it is the lateral colour); with
    the edge's pitch_um, that of the pixel kernel (module docstring)."""
    sensor, turned = _frequency_vectors(edge)
    w = [wt * pf.transmission for wt, pf in zip(weights, spot.fields, strict=True)]
    norm = max(sum(w), 1e-300)
    chiefs = np.stack([pf.chief[:2].numpy() for pf in spot.fields])
    ref = np.asarray(w) @ chiefs / norm
    total = np.zeros(turned.shape[:2], dtype=np.complex128)
    for pf, otf, weight, chief in zip(spot.fields, spot.otfs, w, chiefs, strict=True):
        scale = pf.n_image * (2.0 / pf.samples) / pf.wavelength_mm
        ax, ay = direction_scale(pf)
        lags = _bilinear(otf, turned[..., 0] / (ax * scale), turned[..., 1] / (ay * scale))
        total += weight * lags * np.exp(-2j * np.pi * (turned @ (chief - ref)))
    if edge.pitch_um is not None:
        p = edge.pitch_um * 1e-3
        total *= np.sinc(sensor[..., 0] * p) * np.sinc(sensor[..., 1] * p)
    return np.abs(total.sum(axis=1)) / norm


def edge_mtf(
    lens: Lens,
    edge: Edge,
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 32,
    aiming: str = "paraxial",
) -> np.ndarray:
    """The polychromatic optical MTF (F,) across one edge of a lens (perturbed or not);
    with the edge's pitch_um, the transfer of lensim's pixel kernel there."""
    return model_mtfs(lens, [edge], wavelengths_um, weights, samples, aiming)[0]


def model_mtfs(
    lens: Lens,
    edges: Sequence[Edge],
    wavelengths_um: Sequence[float],
    weights: Sequence[float],
    samples: int = 32,
    aiming: str = "paraxial",
    image: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[np.ndarray]:
    """edge_mtf of every edge (edges at one sensor point share its trace, points at one
    azimuth one batched trace); image: a sensor change on top (mtfs_from)."""
    return mtfs_from(trace_points(lens, edges, wavelengths_um, samples, aiming), edges, weights, image)
