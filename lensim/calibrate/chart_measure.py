"""Measuring a photographed (or simulated) chart: the slanted-edge SFR of every side of
every edge square, lateral colour across each, checkerboard crops, and their summary per
field zone.

Definitions (reported in every result):
* MTF area: the integral of the SFR (ISO 12233 slanted edge,
  lensim.evaluate.slanted_edge) from 0 to Nyquist, 0.5 cycles/pixel, in cycles/pixel
  units (0.5 for a perfect system with no pixel aperture; a 100 % fill-factor pixel
  alone gives about 0.40). The SFR is measured on the luminance of the linearized image
  (inverse sRGB curve, then Y = 0.2126 R + 0.7152 G + 0.0722 B), so it is the lens's
  plus the pixel's and the demosaicer's.
* MTF50: the lowest frequency (cycles/pixel) where the SFR falls to 0.5.
* Lateral colour: the R - G and B - G shifts (pixels) of each channel's fitted edge
  (lensim.evaluate.chromatic.lateral_color_edge), signed positive away from the photo's
  centre (outwards along the edge normal).
* Field: distance of a feature's centre from the photo's centre over the photo's
  half-diagonal (0 centre, 1 corner); each feature belongs to the nearest of ZONES.

Regions: an edge region is centred on the side's midpoint, ACROSS_FRACTION of the side
long across the edge each way and ALONG_FRACTION along it each way (clear of the square's
corners); a checker crop is CROP_PX square (the paper's 100 x 100) or, on a small photo,
the largest even size inside 80 % of the patch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lensim.calibrate.chart import ChartLayout
from lensim.calibrate.chart_draw import project
from lensim.errors import InputError
from lensim.evaluate.chromatic import lateral_color_edge
from lensim.evaluate.slanted_edge import MTFCurve, default_frequencies, mtf_area, slanted_edge_mtf

#: Nominal field zones (normalized fields of the photo's half-diagonal; the paper's Table 1).
ZONES = (0.0, 0.3, 0.5, 0.7, 0.9)
SIDES = ("top", "right", "bottom", "left")
ACROSS_FRACTION = 0.4
ALONG_FRACTION = 0.35
CROP_PX = 100
NYQUIST = 0.5
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: The frequency axis every zone curve is resampled on (cycles/pixel, 0 .. Nyquist).
ZONE_FREQ = default_frequencies(NYQUIST)

Box = tuple[int, int, int, int]  # (top, left, rows, cols), pixels


@dataclass(frozen=True)
class EdgeRegion:
    """Where one side of one edge square lies in a photo: square id, side name, the
    region box (top, left, rows, cols), the side's midpoint (column, row) and its field."""

    square: int
    side: str
    box: Box
    centre_px: tuple[float, float]
    field: float


@dataclass(frozen=True)
class EdgeMeasurement:
    """The slanted-edge measurement of one region: sfr (luminance; None when it failed,
    then ``error`` says why), mtf_area (cycles/pixel, 0..Nyquist), mtf50_cy_px, and the
    outward lateral colour shifts r_minus_g_px, b_minus_g_px (NaN when not measured)."""

    region: EdgeRegion
    sfr: MTFCurve | None
    mtf_area: float
    mtf50_cy_px: float
    r_minus_g_px: float
    b_minus_g_px: float
    error: str | None = None

    def to_dict(self) -> dict:
        r = self.region
        return {
            "square": r.square,
            "side": r.side,
            "box": list(r.box),
            "centre_px": list(r.centre_px),
            "field": r.field,
            "zone": nearest_zone(r.field),
            "mtf_area": self.mtf_area,
            "mtf50_cy_px": self.mtf50_cy_px,
            "r_minus_g_px": self.r_minus_g_px,
            "b_minus_g_px": self.b_minus_g_px,
            "error": self.error,
        }


@dataclass(frozen=True)
class CheckerRegion:
    """A checkerboard crop: patch id, box (top, left, rows, cols) and field."""

    patch: int
    box: Box
    field: float


@dataclass(frozen=True)
class ZoneSummary:
    """The edges of one field zone: zone (nominal field), fields (of its edges), mean SFR
    on ZONE_FREQ, its area (cycles/pixel) and MTF50 (cycles/pixel), mean outward lateral
    colour (pixels), and the number of edges measured."""

    zone: float
    fields: tuple[float, ...]
    mtf: np.ndarray
    mtf_area: float
    mtf50_cy_px: float
    r_minus_g_px: float
    b_minus_g_px: float
    edges: int

    def to_dict(self) -> dict:
        return {
            "zone": self.zone,
            "mean_field": float(np.mean(self.fields)) if self.fields else math.nan,
            "edges": self.edges,
            "mtf_area": self.mtf_area,
            "mtf50_cy_px": self.mtf50_cy_px,
            "r_minus_g_px": self.r_minus_g_px,
            "b_minus_g_px": self.b_minus_g_px,
        }


@dataclass(frozen=True)
class ChartMeasurement:
    """Everything measured on one image: per edge, the checker crops, per zone."""

    edges: tuple[EdgeMeasurement, ...]
    checkers: tuple[CheckerRegion, ...]
    zones: tuple[ZoneSummary, ...] = field(default_factory=tuple)


def nearest_zone(f: float, zones: tuple[float, ...] = ZONES) -> float:
    """The zone (nominal field) nearest a normalized field."""
    return min(zones, key=lambda z: abs(z - f))


def _field(shape: tuple[int, int], col: float, row: float) -> float:
    rows, cols = shape
    half_diag = math.hypot((cols - 1) / 2.0, (rows - 1) / 2.0)
    return math.hypot(col - (cols - 1) / 2.0, row - (rows - 1) / 2.0) / half_diag


def _inside(box: Box, shape: tuple[int, int]) -> bool:
    top, left, rows, cols = box
    return top >= 0 and left >= 0 and top + rows <= shape[0] and left + cols <= shape[1]


def edge_regions(layout: ChartLayout, homography: np.ndarray, shape: tuple[int, int]) -> list[EdgeRegion]:
    """The regions of every side of every edge square that lies inside a photo of
    shape (rows, cols) under the homography (chart mm -> pixels)."""
    out = []
    for e in layout.edges:
        q = project(homography, e.corners_mm())
        for k, side in enumerate(SIDES):
            p0, p1 = q[k], q[(k + 1) % 4]
            mid = (p0 + p1) / 2.0
            length = float(np.linalg.norm(p1 - p0))
            vertical = abs(p1[1] - p0[1]) >= abs(p1[0] - p0[0])
            across, along = ACROSS_FRACTION * length, ALONG_FRACTION * length
            half_rows, half_cols = (along, across) if vertical else (across, along)
            top, left = int(round(mid[1] - half_rows)), int(round(mid[0] - half_cols))
            box = (top, left, int(round(2 * half_rows)) + 1, int(round(2 * half_cols)) + 1)
            if _inside(box, shape):
                out.append(EdgeRegion(e.id, side, box, (float(mid[0]), float(mid[1])), _field(shape, *mid)))
    return out


def checker_regions(
    layout: ChartLayout, homography: np.ndarray, shape: tuple[int, int], size: int = CROP_PX
) -> list[CheckerRegion]:
    """The crop of every checkerboard patch inside the photo: size x size pixels (or the
    largest even size inside 80 % of the patch's smallest side in the photo)."""
    out = []
    for c in layout.checkers:
        h = c.side_mm / 2.0
        q = project(homography, np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) + np.asarray(c.centre_mm))
        side = float(np.min(np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1)))
        n = min(size, int(0.8 * side) // 2 * 2)
        centre = project(homography, np.asarray(c.centre_mm))[0]
        box = (int(round(centre[1])) - n // 2, int(round(centre[0])) - n // 2, n, n)
        if n >= 8 and _inside(box, shape):
            out.append(CheckerRegion(c.id, box, _field(shape, *centre)))
    return out


def linear_rgb(image: np.ndarray) -> np.ndarray:
    """(3, H, W) sRGB-encoded values in [0, 1] -> linear RGB (the inverse sRGB curve)."""
    a = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
    return np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)


def _crop(img: np.ndarray, box: Box) -> np.ndarray:
    top, left, rows, cols = box
    return img[..., top : top + rows, left : left + cols]


def _outward(region: EdgeRegion, shape: tuple[int, int], normal_xy: tuple[float, float]) -> float:
    """+1 when the edge normal points away from the photo's centre, else -1."""
    rx = region.centre_px[0] - (shape[1] - 1) / 2.0
    ry = region.centre_px[1] - (shape[0] - 1) / 2.0
    return 1.0 if normal_xy[0] * rx + normal_xy[1] * ry >= 0 else -1.0


def measure_edge(linear: np.ndarray, region: EdgeRegion, pitch_um: float | None = None) -> EdgeMeasurement:
    """The SFR and lateral colour of one region of a linear (3, H, W) image; a region
    that holds no measurable edge gives NaNs and its reason in ``error``."""
    roi = _crop(linear, region.box)
    luma = np.tensordot(LUMA, roi, axes=1)
    try:
        sfr = slanted_edge_mtf(luma, pitch_um, name=f"square {region.square} {region.side}")
    except InputError as e:
        return EdgeMeasurement(region, None, math.nan, math.nan, math.nan, math.nan, e.message)
    rg = bg = math.nan
    try:
        lc = lateral_color_edge(np.moveaxis(roi, 0, -1), orientation=sfr.edge.orientation if sfr.edge else None)
        sign = _outward(region, linear.shape[-2:], lc.normal_xy)
        rg, bg = sign * lc.r_minus_g_px, sign * lc.b_minus_g_px
    except InputError:
        pass
    return EdgeMeasurement(region, sfr, sfr.area(NYQUIST), sfr.mtf50, rg, bg)


def _mtf50(freq: np.ndarray, mtf: np.ndarray) -> float:
    below = np.nonzero(mtf <= 0.5)[0]
    if below.size == 0 or below[0] == 0:
        return math.nan if below.size == 0 else float(freq[0])
    i = int(below[0])
    return float(freq[i - 1] + (mtf[i - 1] - 0.5) * (freq[i] - freq[i - 1]) / (mtf[i - 1] - mtf[i]))


def summarize_zones(edges: list[EdgeMeasurement], zones: tuple[float, ...] = ZONES) -> list[ZoneSummary]:
    """Per zone (the edges nearest it that were measured): the mean SFR on ZONE_FREQ, its
    area and MTF50, the mean outward lateral colour. Zones with no edge are left out."""
    out = []
    for z in zones:
        mine = [e for e in edges if e.sfr is not None and nearest_zone(e.region.field, zones) == z]
        if not mine:
            continue
        curves = np.stack([np.interp(ZONE_FREQ, e.sfr.freq_cy_px, e.sfr.mtf) for e in mine if e.sfr is not None])
        mean = curves.mean(axis=0)
        rg = [e.r_minus_g_px for e in mine if math.isfinite(e.r_minus_g_px)]
        bg = [e.b_minus_g_px for e in mine if math.isfinite(e.b_minus_g_px)]
        out.append(
            ZoneSummary(
                zone=z,
                fields=tuple(e.region.field for e in mine),
                mtf=mean,
                mtf_area=mtf_area(ZONE_FREQ, mean, NYQUIST),
                mtf50_cy_px=_mtf50(ZONE_FREQ, mean),
                r_minus_g_px=float(np.mean(rg)) if rg else math.nan,
                b_minus_g_px=float(np.mean(bg)) if bg else math.nan,
                edges=len(mine),
            )
        )
    return out


def measure_chart(
    image: np.ndarray,
    layout: ChartLayout,
    homography: np.ndarray,
    pitch_um: float | None = None,
    regions: list[EdgeRegion] | None = None,
) -> ChartMeasurement:
    """Measure a chart in a (3, H, W) sRGB image in [0, 1] (a photo or a simulation)
    whose chart -> pixel homography is known (lensim.calibrate.chart_detect.detect_chart):
    every edge region (or the given ``regions``), the checker crops, per zone.
    pitch_um: the image's pixel pitch on the sensor (um), to also give cycles/mm."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 3 or img.shape[0] != 3:
        raise InputError(None, "image", f"expected a (3, H, W) RGB image, got shape {img.shape}")
    shape = (int(img.shape[1]), int(img.shape[2]))
    regions = edge_regions(layout, homography, shape) if regions is None else regions
    lin = linear_rgb(img)
    edges = [measure_edge(lin, r, pitch_um) for r in regions]
    return ChartMeasurement(
        tuple(edges), tuple(checker_regions(layout, homography, shape)), tuple(summarize_zones(edges))
    )
