"""ISO 12233-style slanted-edge SFR (MTF) measurement and the MTF a slanted edge should
measure for a given PSF (synthetic edge targets: lensim.evaluate.edge_target; the MTF curve
type, its area and the PSF's expected MTF live in lensim.evaluate.mtf_curve and are
re-exported here).

Geometry (pixel-centre coordinates: column x to the right, row y down, pixel (i, j) has its
centre at x = j, y = i and covers [j-0.5, j+0.5] x [i-0.5, i+0.5]):

* A *vertical* edge slanted by ``angle_deg`` = theta is the line
  ``x = x0 + tan(theta) (y - y0)``: for positive theta it moves right going down the image.
  Its unit normal is ``n = (cos theta, -sin theta)`` (in (x, y)), the side with positive
  x component. A *horizontal* edge is the transpose: ``y = y0 + tan(theta) (x - x0)``,
  ``n = (-sin theta, cos theta)``.
* Frequencies are measured along the edge normal, in cycles per pixel (and cycles per mm
  when the pixel pitch is given); Nyquist is 0.5 cycles/pixel.

Measurement (after ISO 12233 / sfrmat3, Burns 2000): per row of the region, the edge is
located by the centroid of the derivative across the edge, weighted by a Hamming window
(first centred on the region, then three times on the line fitted so far); a
least-squares line (polynomial order 1) is fitted to the row locations; the rows used are
trimmed to a whole number of phase cycles (the edge crosses a whole number of pixels);
every pixel is projected onto the edge normal and binned at 1/4 pixel into an oversampled
edge spread function (ESF) -- each bin's mean value is placed at its samples' mean
distance and linearly interpolated back to the bin centres, which removes the ripple of
unevenly filled bins (up to 0.015 of MTF at Nyquist on a sharp edge at 3 or 10 degrees
otherwise); a centred difference gives the line spread function (LSF), which is
Hamming-windowed about its centroid and Fourier transformed; the modulus is normalized at
DC and divided by the transfer function of the centred difference, sinc(2 f / 4) (the ISO
derivative correction). Unlike sfrmat3 the 1/4-pixel bin average, sinc(f / 4), is also
divided out by default (``correct_binning``): it is a 2.6 % loss at Nyquist that is not
part of the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError
from lensim.evaluate.mtf_curve import (
    MTFCurve,
    MTFLike,
    Orientation,
    crossing_frequency,
    default_frequencies,
    mtf_area,
    mtf_area_ratio,
    mtf_from_psf,
    pixel_aperture_mtf,
)

#: Bins per pixel of the oversampled ESF (ISO 12233: 4).
BINS_PER_PIXEL = 4
#: Smallest region side accepted, pixels.
MIN_REGION_PX = 12
#: Smallest extent of the edge profile kept on each side of the edge, pixels.
MIN_HALF_PROFILE_PX = 4.0


@dataclass(frozen=True)
class EdgeFit:
    """A straight edge located in a 2-D region.

    In the edge's own frame (the region itself for a vertical edge, its transpose for a
    horizontal one) the edge is ``x = intercept_px + slope * y``, with x across and y along
    the edge (pixel-centre coordinates). row_locations_px: the per-row centroid locations
    (NaN where a row gave none);
    residual_rms_px: RMS scatter of those about the line; polarity: +1 when values rise
    along the edge normal, -1 otherwise; shape: the region's (rows, cols).
    """

    orientation: Orientation
    intercept_px: float
    slope: float
    row_locations_px: np.ndarray
    residual_rms_px: float
    polarity: int
    shape: tuple[int, int]

    @property
    def angle_deg(self) -> float:
        """Signed slant of the edge from the vertical (or horizontal) axis, degrees."""
        return math.degrees(math.atan(self.slope))

    @property
    def normal_xy(self) -> tuple[float, float]:
        """Unit normal of the edge in image (x = column, y = row) coordinates."""
        t = math.atan(self.slope)
        if self.orientation == "vertical":
            return (math.cos(t), -math.sin(t))
        return (-math.sin(t), math.cos(t))

    def position_px(self) -> float:
        """Signed distance (pixels) of the edge from the region centre along the normal."""
        n_along, n_across = _frame_shape(self.shape, self.orientation)
        yc, xc = (n_along - 1) / 2.0, (n_across - 1) / 2.0
        return (self.intercept_px + self.slope * yc - xc) * math.cos(math.atan(self.slope))


@dataclass(frozen=True)
class SFRResult(MTFCurve):
    """A slanted-edge measurement of one channel.

    freq_cy_px, mtf: the spatial frequency response along the edge normal (cycles/pixel,
    up to ``max_frequency``), with the inherited mtf50 (cycles/pixel) and area_to_nyquist
    (the paper's "MTF area": area under the MTF from 0 to 0.5 cycles/pixel, cycles/pixel
    units; 0.5 for a perfect system without a pixel aperture); edge: the fitted edge;
    esf_distance_px / esf: the binned edge spread function (image units) at distances
    (pixels) along the normal from the edge; lsf: its centred difference (image units per
    pixel, positive, at esf_distance_px[1:-1]); rows_used: number of rows projected.
    """

    edge: EdgeFit | None = None
    esf_distance_px: np.ndarray | None = None
    esf: np.ndarray | None = None
    lsf: np.ndarray | None = None
    rows_used: int = 0

    @property
    def angle_deg(self) -> float:
        """Signed slant of the measured edge, degrees (NaN without an edge fit)."""
        return math.nan if self.edge is None else self.edge.angle_deg


# ----------------------------------------------------------------------------- helpers


def _frame_shape(shape: tuple[int, int], orientation: Orientation) -> tuple[int, int]:
    """(rows along the edge, columns across it) of the edge's own frame."""
    return shape if orientation == "vertical" else (shape[1], shape[0])


def _hamming(n: int, mid: float) -> np.ndarray:
    """Hamming window over indices 0..n-1 centred at `mid` (fractional), half-width the
    larger distance from mid to an end (sfrmat3's ahamming)."""
    idx = np.arange(n, dtype=np.float64)
    half = max(mid, n - 1 - mid, 1.0)
    return 0.54 + 0.46 * np.cos(np.pi * (idx - mid) / half)


def _as_region(region: np.ndarray, name: str = "region") -> np.ndarray:
    a = np.asarray(region)
    if a.ndim != 2:
        raise InputError(None, name, f"expected a 2-D array (one channel), got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise InputError(None, name, f"expected real numbers, got dtype {a.dtype}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise InputError(None, name, "contains NaN or infinite values")
    if min(a.shape) < MIN_REGION_PX:
        raise InputError(
            None, name, f"too small: {a.shape[0]}x{a.shape[1]} px, need at least {MIN_REGION_PX} px on each side"
        )
    return a


def detect_orientation(region: np.ndarray) -> Orientation:
    """'vertical' (the edge runs top to bottom) when the summed absolute difference between
    neighbouring columns is at least that between neighbouring rows, else 'horizontal'.
    A multi-channel (H, W, C) region is judged on its channel mean."""
    a = np.asarray(region, dtype=np.float64)
    if a.ndim == 3:
        a = a.mean(axis=2)
    gx = np.abs(np.diff(a, axis=1)).sum()
    gy = np.abs(np.diff(a, axis=0)).sum()
    return "vertical" if gx >= gy else "horizontal"


def _row_centroids(deriv: np.ndarray, centres: np.ndarray | None) -> np.ndarray:
    """Windowed centroid (in derivative-column units) of each row of deriv; NaN where the
    windowed derivative sums to (about) zero. centres: per-row window centres or None for
    the middle of the row."""
    n_rows, n = deriv.shape
    idx = np.arange(n, dtype=np.float64)
    mid = np.full(n_rows, (n - 1) / 2.0) if centres is None else np.clip(centres, 0, n - 1)
    half = np.maximum(np.maximum(mid, n - 1 - mid), 1.0)
    win = 0.54 + 0.46 * np.cos(np.pi * (idx[None, :] - mid[:, None]) / half[:, None])
    w = deriv * win
    s = w.sum(axis=1)
    scale = np.abs(deriv).sum(axis=1)
    good = (scale > 0) & (s > 1e-6 * scale)
    out = np.full(n_rows, np.nan)
    out[good] = (w[good] * idx).sum(axis=1) / s[good]
    return out


# ----------------------------------------------------------------------------- edge fitting


def locate_edge(
    region: np.ndarray,
    orientation: Orientation | None = None,
    min_angle_deg: float = 1.0,
    max_angle_deg: float = 15.0,
    name: str = "region",
) -> EdgeFit:
    """Find the straight edge in a 2-D region and fit a line to it.

    The edge is located per row (of the edge's frame) by the Hamming-windowed centroid of
    the centred derivative across it, then fitted by least squares (order 1); the window is
    re-centred on the fitted line three times. orientation: force 'vertical'/'horizontal' (None:
    detect). Raises InputError (field `name`) for a region that is too small, flat, holds
    no localized straight edge, whose edge is slanted by less than min_angle_deg or more
    than max_angle_deg (degrees), or whose slant is too small for the number of rows.
    """
    a = _as_region(region, name)
    if np.ptp(a) <= 1e-12 * max(1.0, float(np.abs(a).max())):
        raise InputError(None, name, "no edge found: the region is flat")
    if orientation is None:
        orientation = detect_orientation(a)
    elif orientation not in ("vertical", "horizontal"):
        raise InputError(None, "orientation", f"expected 'vertical' or 'horizontal', got {orientation!r}")
    v = a if orientation == "vertical" else a.T
    n_rows, n_cols = v.shape
    deriv, polarity = _edge_derivative(v, name)
    y = np.arange(n_rows, dtype=np.float64)
    loc = _row_centroids(deriv, None)
    for _ in range(3):
        ok = _located_rows(loc, name)
        slope, intercept = np.polyfit(y[ok], loc[ok] + 1.0, 1)  # +1: derivative column 0 is pixel 1
        loc = _row_centroids(deriv, intercept + slope * y - 1.0)
    ok = _located_rows(loc, name)
    slope, intercept = np.polyfit(y[ok], loc[ok] + 1.0, 1)
    resid = loc[ok] + 1.0 - (intercept + slope * y[ok])
    rms = float(np.sqrt(np.mean(resid**2)))
    limit = max(1.0, 0.05 * n_cols)
    if rms > limit:
        raise InputError(
            None,
            name,
            f"no straight edge found: per-row edge locations scatter {rms:.2g} px RMS about the fitted line "
            f"(limit {limit:.2g} px)",
        )
    _check_slant(slope, intercept, v.shape, orientation, (min_angle_deg, max_angle_deg), name)
    loc_full = np.where(ok, loc + 1.0, np.nan)
    return EdgeFit(
        orientation=orientation,
        intercept_px=float(intercept),
        slope=float(slope),
        row_locations_px=loc_full,
        residual_rms_px=rms,
        polarity=polarity,
        shape=(int(a.shape[0]), int(a.shape[1])),
    )


def _edge_derivative(v: np.ndarray, name: str) -> tuple[np.ndarray, int]:
    """(centred derivative across the edge (n_rows, n_cols - 2), columns 1..n_cols-2,
    signed so that the edge rises; polarity +1 dark-to-bright along a row, -1 the other
    way) of a region in the edge's frame (v: (n_rows, n_cols), the edge along the rows)."""
    quarter = max(2, v.shape[1] // 4)
    step = v[:, -quarter:].mean() - v[:, :quarter].mean()
    if step == 0:
        raise InputError(None, name, "no edge found: both sides of the region have the same mean level")
    polarity = 1 if step > 0 else -1
    deriv = polarity * 0.5 * (v[:, 2:] - v[:, :-2])
    # A step is localized: each row's derivative peaks well above its typical magnitude.
    # Flat shading or a ramp gives a ratio near 1, white noise about 3.5 (caught below).
    med = np.median(np.abs(deriv), axis=1)
    peak = deriv.max(axis=1)
    ratio = float(np.median(peak / np.maximum(med, 1e-300)))
    if not ratio > 3.0:
        raise InputError(
            None,
            name,
            "no edge found: the derivative across the region has no localized peak "
            f"(peak/median {ratio:.2g}, need > 3)",
        )
    return deriv, polarity


def _located_rows(loc: np.ndarray, name: str) -> np.ndarray:
    """The rows where the edge was located (finite loc), at least max(3, half the rows)."""
    ok = np.isfinite(loc)
    n_rows = len(loc)
    if ok.sum() < max(3, n_rows // 2):
        raise InputError(
            None, name, f"no edge found: the edge could be located in only {int(ok.sum())} of {n_rows} rows"
        )
    return ok


def _check_slant(
    slope: float,
    intercept: float,
    shape: tuple[int, int],
    orientation: str,
    angles_deg: tuple[float, float],
    name: str,
) -> None:
    """The fitted line x = intercept + slope * row (edge frame, shape (n_rows, n_cols)) is
    slanted within angles_deg (min, max; degrees), crosses at least one pixel over the rows
    and stays inside the region."""
    n_rows, n_cols = shape
    lo, hi = angles_deg
    angle = abs(math.degrees(math.atan(slope)))
    if angle < lo:
        raise InputError(
            None, name, f"edge slant too small: {angle:.2f} deg from {orientation}, need {lo:g}-{hi:g} deg"
        )
    if angle > hi:
        raise InputError(
            None, name, f"edge slant too large: {angle:.2f} deg from {orientation}, need {lo:g}-{hi:g} deg"
        )
    if math.floor(n_rows * abs(slope)) < 1:
        raise InputError(
            None,
            name,
            f"edge slant too small for the region: the edge crosses {n_rows * abs(slope):.2f} px over {n_rows} "
            "rows, need >= 1 px (more rows or more slant)",
        )
    x_ends = intercept + slope * np.array([0.0, n_rows - 1.0])
    if x_ends.min() < 0 or x_ends.max() > n_cols - 1:
        raise InputError(
            None,
            name,
            f"edge leaves the region: it runs from column {x_ends[0]:.1f} to {x_ends[1]:.1f} of 0..{n_cols - 1}",
        )


def _phase_rows(n_rows: int, slope: float) -> tuple[int, int]:
    """Centred row range spanning a whole number of phase cycles (the edge crosses an
    integer number of pixels), so every 1/4-pixel bin is fed evenly."""
    cycles = math.floor(n_rows * abs(slope))
    used = min(n_rows, max(1, round(cycles / abs(slope))))
    start = (n_rows - used) // 2
    return start, start + used


def edge_spread_function(
    region: np.ndarray, edge: EdgeFit, bins_per_pixel: int = BINS_PER_PIXEL, name: str = "region"
) -> tuple[np.ndarray, np.ndarray, int]:
    """Project the pixels of a 2-D region onto the normal of `edge` and bin them.

    Returns (distance_px, esf, rows_used): bin centres k / bins_per_pixel (pixels along the
    normal from the edge line, symmetric about 0, covering only distances that every row
    used reaches) and the mean pixel value in each bin (image units; empty bins, if any,
    interpolated). Raises InputError when the edge is closer than MIN_HALF_PROFILE_PX to
    the region border."""
    a = _as_region(region, name)
    if a.shape != edge.shape:
        raise InputError(None, name, f"region shape {a.shape} differs from the fitted edge's {edge.shape}")
    v = a if edge.orientation == "vertical" else a.T
    n_rows, n_cols = v.shape
    r0, r1 = _phase_rows(n_rows, edge.slope)
    cos_t = 1.0 / math.sqrt(1.0 + edge.slope**2)
    y = np.arange(r0, r1, dtype=np.float64)[:, None]
    x = np.arange(n_cols, dtype=np.float64)[None, :]
    x_edge = edge.intercept_px + edge.slope * y
    d = (x - x_edge) * cos_t
    half = min(-(d[:, 0].max()), d[:, -1].min())
    if half < MIN_HALF_PROFILE_PX:
        raise InputError(
            None,
            name,
            f"edge too close to the region border: {max(half, 0.0):.1f} px of profile on one side, "
            f"need >= {MIN_HALF_PROFILE_PX:g} px",
        )
    fac = int(bins_per_pixel)
    k_max = math.floor(half * fac - 0.5)
    k = np.floor(d * fac + 0.5).astype(np.int64)
    keep = np.abs(k) <= k_max
    idx = (k[keep] + k_max).ravel()
    n_bins = 2 * k_max + 1
    counts = np.bincount(idx, minlength=n_bins)
    sums = np.bincount(idx, weights=v[r0:r1][keep].ravel(), minlength=n_bins)
    filled = counts > 0
    if filled.sum() < 0.9 * n_bins:
        raise InputError(
            None,
            name,
            f"edge slant too small for the region: {n_bins - int(filled.sum())} of {n_bins} ESF bins are empty",
        )
    centres = np.arange(-k_max, k_max + 1, dtype=np.float64) / fac
    dsum = np.bincount(idx, weights=d[keep].ravel(), minlength=n_bins)
    # Each bin's mean value belongs at its samples' mean distance, which is off the bin
    # centre when the row phases do not fill the bin evenly; interpolate back to centres.
    pos = dsum[filled] / counts[filled]
    esf = np.interp(centres, pos, sums[filled] / counts[filled])
    return centres, esf, r1 - r0


def _mtf_from_esf(
    distance_px: np.ndarray,
    esf: np.ndarray,
    polarity: int,
    bins_per_pixel: int,
    max_frequency: float,
    correct_binning: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(freq_cy_px, mtf, lsf) from a binned ESF: centred difference, Hamming window about
    the LSF centroid, zero-padded FFT, DC normalization, derivative (and bin) correction."""
    fac = bins_per_pixel
    lsf = polarity * (esf[2:] - esf[:-2]) * 0.5 * fac  # per pixel
    n = lsf.size
    idx = np.arange(n, dtype=np.float64)
    total = lsf.sum()
    if not total > 0:
        raise InputError(None, "region", "no edge found: the edge profile has no net step")
    mid = float((lsf * idx).sum() / total)
    mid = float(np.clip(mid, 0, n - 1))
    win = _hamming(n, mid)
    nfft = max(1024, 1 << math.ceil(math.log2(n)))
    spec = np.abs(np.fft.rfft(lsf * win, nfft))
    freq = np.arange(spec.size) * fac / nfft
    mtf = spec / spec[0]
    f_top = min(max_frequency, fac / 2.0)
    sel = freq <= f_top + 1e-12
    freq, mtf = freq[sel], mtf[sel]
    # Centred difference over bins 1/fac apart: transfer sin(2 pi f / fac) / (2 pi f / fac).
    mtf = mtf / np.sinc(2.0 * freq / fac)
    if correct_binning:
        mtf = mtf / np.sinc(freq / fac)
    return freq, mtf, lsf


def slanted_edge_mtf(
    region: np.ndarray,
    pixel_pitch_um: float | None = None,
    *,
    orientation: Orientation | None = None,
    bins_per_pixel: int = BINS_PER_PIXEL,
    max_frequency: float = 1.0,
    correct_binning: bool = True,
    min_angle_deg: float = 1.0,
    max_angle_deg: float = 15.0,
    name: str = "region",
) -> SFRResult:
    """ISO 12233-style slanted-edge SFR of one channel.

    region: 2-D float array (any units; linear data gives the optical MTF) holding one
    straight edge slanted 1-15 degrees (2-10 recommended) from vertical or horizontal, with
    at least 4 px of flat-ish profile on both sides. pixel_pitch_um: the pixel pitch (um),
    to report cycles/mm. max_frequency: highest frequency returned, cycles/pixel (at most
    bins_per_pixel / 4, where the derivative correction is still 1 / 0.64).
    correct_binning: also divide out the 1/bins_per_pixel bin average (see the module
    docstring). Returns an SFRResult (frequencies along the edge normal, cycles/pixel).
    Raises InputError (field `name`) when no edge is found, the slant is out of range or
    the region is too small.
    """
    if pixel_pitch_um is not None and not pixel_pitch_um > 0:
        raise InputError(None, "pixel_pitch_um", f"expected a positive pitch in um, got {pixel_pitch_um}")
    if int(bins_per_pixel) != bins_per_pixel or bins_per_pixel < 2:
        raise InputError(None, "bins_per_pixel", f"expected an integer >= 2, got {bins_per_pixel}")
    if not 0.5 < max_frequency <= bins_per_pixel / 4.0:
        raise InputError(
            None,
            "max_frequency",
            f"expected above 0.5 cycles/pixel (Nyquist) and at most {bins_per_pixel / 4.0:g} "
            f"(bins_per_pixel / 4), got {max_frequency}",
        )
    a = _as_region(region, name)
    edge = locate_edge(a, orientation, min_angle_deg, max_angle_deg, name)
    dist, esf, rows_used = edge_spread_function(a, edge, bins_per_pixel, name)
    freq, mtf, lsf = _mtf_from_esf(dist, esf, edge.polarity, int(bins_per_pixel), max_frequency, correct_binning)
    return SFRResult(
        freq_cy_px=freq,
        mtf=mtf,
        pixel_pitch_um=pixel_pitch_um,
        edge=edge,
        esf_distance_px=dist,
        esf=esf,
        lsf=lsf,
        rows_used=rows_used,
    )


def slanted_edge_mtf_channels(
    region: np.ndarray, pixel_pitch_um: float | None = None, **kwargs: object
) -> list[SFRResult]:
    """slanted_edge_mtf for each channel of an (H, W, C) region (e.g. RGB), each channel
    fitted on its own, all in the orientation detected on the channel mean. A 2-D region
    gives a list of one. Keyword arguments as for slanted_edge_mtf."""
    a = np.asarray(region)
    if a.ndim == 2:
        return [slanted_edge_mtf(a, pixel_pitch_um, **kwargs)]  # type: ignore[arg-type]
    if a.ndim != 3:
        raise InputError(None, "region", f"expected (H, W) or (H, W, C), got shape {a.shape}")
    kw = dict(kwargs)
    if kw.get("orientation") is None:
        kw["orientation"] = detect_orientation(np.asarray(a, dtype=np.float64))
    return [
        slanted_edge_mtf(a[:, :, c], pixel_pitch_um, name=f"region[..., {c}]", **kw)  # type: ignore[arg-type]
        for c in range(a.shape[2])
    ]


__all__ = [
    "BINS_PER_PIXEL",
    "EdgeFit",
    "MTFCurve",
    "MTFLike",
    "Orientation",
    "SFRResult",
    "crossing_frequency",
    "default_frequencies",
    "detect_orientation",
    "edge_spread_function",
    "locate_edge",
    "mtf_area",
    "mtf_area_ratio",
    "mtf_from_psf",
    "pixel_aperture_mtf",
    "slanted_edge_mtf",
    "slanted_edge_mtf_channels",
]
