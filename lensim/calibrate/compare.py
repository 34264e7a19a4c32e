"""The paper's chart check: a photographed chart against lensim's simulation of the same
chart at the same pose (Chen et al. 2021, "Authenticity", Table 1).

The simulation takes the photo's own path: the chart as the camera sees it is rendered
sharp in linear light at the photo's local black and white levels, encoded to sRGB and
run through lensim.render.pipeline.simulate (unprocess, the PSF bank's spatially-variant
blur, mosaic, noise, ADC, AHD demosaic, white balance, CCM, sRGB curve): crop by crop
around each feature, each crop placed on the sensor where it lies in the photo (so the
blur is the bank's at that field and azimuth), an edge square's crop on the blur's kernel
grid of the whole frame. The crop's levels are measured on the photo (local_levels: the medians of its white
paper and of its ink), so they hold the photo's shading and lighting; they are divided by
the lens's relative illumination at the crop's centre and the simulation applies it again,
which puts its fall across the crop back. Each matters, though the blur is linear in
light (the AHD demosaicer is not): a lensim photo of the phone lens (noise-free) and this
simulation of it through the same bank differed per edge SFR by 0.028 RMS (single edges
up to 0.17) with the black taken from the crop's mean and no fall across the crop, and by
0.033 on a lens with a decentred element with each crop on its own kernel grid; 0.005 and
0.007 with all three (benchmarks/results/calibration/v3/README.md). "As the camera
sees it": the photo's marker corners (lensim.calibrate.chart_detect) are moved to where
they would be without the lens's distortion (the bank's chief-ray heights against the
paraxial ones), a homography is fitted to those, and every sample point of the sharp
chart is taken through the distortion and that homography (PixelDistortion,
ideal_homography; exact point sampling, no resampling of a rendered image).

Then both images are measured at the same regions (lensim.calibrate.chart_measure) and
compared per field zone: MTF area (integral of the SFR from 0 to Nyquist, cycles/pixel)
of the photo and the simulation and their ratio simulation / photo (the paper's Table 1
ratio), MTF50, lateral colour, and the PSNR (dB, sRGB in [0, 1]) of the simulation's
checkerboard crops against the photo's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from lensim.calibrate.chart import ChartLayout, CheckerPatch, EdgeSquare
from lensim.calibrate.chart_detect import ChartDetection, ChartPose
from lensim.calibrate.chart_draw import project, render_view
from lensim.calibrate.chart_measure import ZONE_FREQ, ChartMeasurement, linear_rgb, measure_chart, nearest_zone
from lensim.evaluate.metrics import psnr
from lensim.render.mapping import SensorMapping

if TYPE_CHECKING:
    from lensim.psf.bank import PSFBank
    from lensim.sensor.profile import SensorProfile

#: Context (pixels) simulated around each feature beyond its measured regions, on top of
#: the kernel's radius: the demosaicer's reach (AHD: 8 rows) with margin.
CONTEXT_PX = 16
#: Fraction of a feature's side added around it for its edge regions (chart_measure.ACROSS_FRACTION + margin).
REGION_MARGIN = 0.5
#: the fewest ink pixels beyond the blur's reach whose median is a crop's black (local_levels)
INK_PIXELS = 64
DEFINITIONS = {
    "mtf_area": "integral of the slanted-edge SFR (ISO 12233, luminance of the linearized image) from 0 to "
    "Nyquist (0.5 cycles/pixel), cycles/pixel units",
    "mtf_area_ratio": "simulation MTF area / photo MTF area (the paper's Table 1 ratio)",
    "mtf50_cy_px": "lowest frequency (cycles/pixel) where the SFR falls to 0.5",
    "lateral_colour_px": "R-G and B-G edge shifts in pixels, positive away from the photo's centre",
    "psnr_db": "PSNR of the simulation's checkerboard crops against the photo's (sRGB in [0, 1])",
    "field": "distance from the photo's centre over its half-diagonal",
}


@dataclass(frozen=True)
class ZoneComparison:
    """One field zone, photo vs simulation: MTF areas (cycles/pixel), their ratio
    (simulation / photo), MTF50s (cycles/pixel), lateral colour (pixels, outwards),
    checker-crop PSNR (dB; NaN without a checker in the zone), and the mean SFR curves on
    ZONE_FREQ for the figure."""

    zone: float
    mean_field: float
    edges: int
    photo_mtf_area: float
    sim_mtf_area: float
    mtf_area_ratio: float
    photo_mtf50_cy_px: float
    sim_mtf50_cy_px: float
    photo_lateral_colour_px: tuple[float, float]
    sim_lateral_colour_px: tuple[float, float]
    psnr_db: float
    checkers: int
    photo_mtf: np.ndarray
    sim_mtf: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k not in ("photo_mtf", "sim_mtf")}
        d["photo_lateral_colour_px"] = list(self.photo_lateral_colour_px)
        d["sim_lateral_colour_px"] = list(self.sim_lateral_colour_px)
        return d


@dataclass(frozen=True)
class ChartComparison:
    """The photo's and the simulation's measurements, per zone and per feature."""

    zones: tuple[ZoneComparison, ...]
    photo: ChartMeasurement
    sim: ChartMeasurement
    psnr_db: tuple[tuple[int, float, float], ...]  # (patch id, field, PSNR dB) per checker crop
    simulated: np.ndarray  # (3, H, W) the photo with every feature's crop replaced by its simulation
    noise: tuple[float, float] | None = None  # (shot, read) of the simulation, normalized raw units

    def to_dict(self) -> dict[str, Any]:
        return {
            "definitions": DEFINITIONS,
            "noise": None if self.noise is None else {"shot": self.noise[0], "read": self.noise[1]},
            "frequencies_cy_px": ZONE_FREQ.tolist(),
            "zones": [
                z.to_dict() | {"photo_mtf": z.photo_mtf.tolist(), "sim_mtf": z.sim_mtf.tolist()} for z in self.zones
            ],
            "edges": [
                p.to_dict() | {"sim_mtf_area": s.mtf_area, "sim_mtf50_cy_px": s.mtf50_cy_px}
                for p, s in zip(self.photo.edges, self.sim.edges, strict=True)
            ],
            "checkers": [{"patch": i, "field": f, "zone": nearest_zone(f), "psnr_db": v} for i, f, v in self.psnr_db],
        }


@dataclass(frozen=True)
class PixelDistortion:
    """The lens's radial distortion on a photo's pixel grid (a chart_draw.PixelWarp): the
    bank's chief-ray image heights (real) against the paraxial ones (ideal) at its fields,
    primary wavelength, interpolated linearly in radius on the sensor (as
    lensim.render.distortion.apply_distortion reads them); mapping places the pixels on
    the sensor."""

    mapping: SensorMapping
    r_real_mm: np.ndarray
    r_ideal_mm: np.ndarray

    @classmethod
    def from_bank(cls, bank: PSFBank, mapping: SensorMapping) -> PixelDistortion:
        real = np.array([float(np.hypot(*f.reference_xy_mm)) for f in bank.fields])
        ideal = np.array([float(np.hypot(*f.paraxial_xy_mm)) for f in bank.fields])
        return cls(mapping, real, ideal)

    def _radial(
        self, u: np.ndarray, v: np.ndarray, r_from: np.ndarray, r_to: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        p = self.mapping.pitch_um * 1e-3
        x = self.mapping.x0_mm + (np.asarray(u, dtype=np.float64) + 0.5) * p
        y = self.mapping.y0_mm + (np.asarray(v, dtype=np.float64) + 0.5) * p
        r = np.hypot(x, y)
        scale = np.where(r > 0, np.interp(r, r_from, r_to) / np.maximum(r, 1e-300), r_to[1] / r_from[1])
        return (x * scale - self.mapping.x0_mm) / p - 0.5, (y * scale - self.mapping.y0_mm) / p - 0.5

    def to_ideal(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Real (distorted) pixel positions -> where they would be without distortion."""
        return self._radial(u, v, self.r_real_mm, self.r_ideal_mm)

    def to_real(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted pixel positions -> where the lens puts them."""
        return self._radial(u, v, self.r_ideal_mm, self.r_real_mm)


def undistorted(detection: ChartDetection, warp: PixelDistortion) -> ChartDetection:
    """The detection with its marker corners moved to where they would be without the
    lens's distortion and the homography fitted to those as detect_chart fits it (RANSAC
    at 3 px, then least squares on the inliers): the input of estimate_pose for a lens
    with distortion, and the homography the simulation draws the chart with."""
    import cv2

    from lensim.calibrate.chart_draw import project

    u, v = warp.to_ideal(detection.image_points_px[:, 0], detection.image_points_px[:, 1])
    img = np.stack([u, v], axis=1)
    h, inliers = cv2.findHomography(detection.chart_points_mm, img, cv2.RANSAC, 3.0)
    if h is None:
        return detection
    keep = inliers.ravel().astype(bool)
    h, _ = cv2.findHomography(detection.chart_points_mm[keep], img[keep], 0)
    h = np.asarray(h, dtype=np.float64) / h[2, 2]
    rms = float(np.sqrt(np.mean(np.sum((project(h, detection.chart_points_mm) - img) ** 2, axis=1))))
    return replace(detection, homography=h, image_points_px=img, reprojection_rms_px=rms)


def ideal_homography(detection: ChartDetection, warp: PixelDistortion) -> np.ndarray:
    """The chart -> undistorted pixel homography (undistorted(detection, warp)'s)."""
    return undistorted(detection, warp).homography


def crop_mapping(mapping: SensorMapping, box: tuple[int, int, int, int]) -> SensorMapping:
    """Where a (top, left, rows, cols) crop of an image mapped by ``mapping`` lies on the sensor."""
    top, left, rows, cols = box
    p = mapping.pitch_um * 1e-3
    return SensorMapping(rows, cols, mapping.pitch_um, mapping.x0_mm + left * p, mapping.y0_mm + top * p)


def feature_boxes(
    layout: ChartLayout, homography: np.ndarray, shape: tuple[int, int], margin_px: int, edge_grid: int = 2
) -> list[tuple[int, int, int, int]]:
    """(top, left, rows, cols) of the crop simulated around each checker patch and then
    each edge square (an edge's crop is written over any checker crop it overlaps): its
    box in the photo, REGION_MARGIN of its size and margin_px more on each side, top/left
    even (the Bayer phase of the whole frame) and an edge square's on multiples of
    edge_grid (even; a multiple of the blur's tile puts the crop on the frame's kernel
    grid), clipped to the photo."""
    out = []
    items: list[EdgeSquare | CheckerPatch] = [*layout.checkers, *layout.edges]
    for item in items:
        h = item.half_extent_mm()
        q = project(homography, np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) + np.asarray(item.centre_mm))
        extra = REGION_MARGIN * float(np.ptp(q[:, 0])) + margin_px
        grid = edge_grid if isinstance(item, EdgeSquare) else 2
        top = max(0, int(math.floor(q[:, 1].min() - extra)) // grid * grid)
        left = max(0, int(math.floor(q[:, 0].min() - extra)) // grid * grid)
        bottom = min(shape[0], int(math.ceil(q[:, 1].max() + extra)) + 1)
        right = min(shape[1], int(math.ceil(q[:, 0].max() + extra)) + 1)
        if bottom - top >= 16 and right - left >= 16:
            out.append((top, left, bottom - top, right - left))
    return out


def local_levels(photo_linear: np.ndarray, sharp: np.ndarray, reach_px: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(black (3,), white (3,)) linear levels of a crop: white is the median of the photo
    where the sharp reflectance map (same shape (rows, cols), 0..1) is white at least 3 px
    away from any ink; black the median where it is ink at least max(3, reach_px) px
    (the blur's reach) away from any paper, or where the crop has fewer than INK_PIXELS
    such pixels, from the crop's mean (blur keeps it): mean = black + (white - black) *
    mean(reflectance) (amplified 1 / (1 - mean(reflectance)) times, its errors put the
    black of a square mostly paper at up to 1.8 times the photo's)."""
    from scipy.ndimage import binary_erosion

    white_mask = binary_erosion(sharp > 0.999, iterations=3)
    if white_mask.sum() < 16:
        white_mask = sharp > 0.999
    white = np.median(photo_linear[:, white_mask], axis=1) if white_mask.any() else photo_linear.max(axis=(1, 2))
    ink = binary_erosion(sharp < 0.001, iterations=max(3, reach_px))
    if ink.sum() >= INK_PIXELS:
        black = np.median(photo_linear[:, ink], axis=1)
    else:
        m = float(sharp.mean())
        black = (photo_linear.mean(axis=(1, 2)) - white * m) / max(1.0 - m, 1e-6)
    return np.clip(black, 0.0, None), np.maximum(white, black + 1e-3)


def noise_sigma(linear: np.ndarray, mask: np.ndarray) -> float:
    """Robust noise level of a (3, H, W) linear image where mask (H, W) is flat: 1.4826
    times the median absolute deviation of horizontal neighbour differences of the green
    channel, over sqrt(2). The demosaicer correlates neighbours, so this is comparable
    only between images developed alike (the photo and its simulation)."""
    d = np.diff(linear[1], axis=1)[mask[:, 1:] & mask[:, :-1]]
    if d.size < 16:
        return math.nan
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def matched_noise(
    photo_sigma: float,
    white_linear: float,
    sensor: SensorProfile,
    generator: torch.Generator | None,
    kelvin: float,
) -> tuple[float, float]:
    """(shot, read) noise (normalized raw units) that gives a simulated flat patch at the
    linear level white_linear the noise level photo_sigma (noise_sigma's measure): one
    draw from the sensor's noise model, scaled (variance shot x + read^2 scales by k,
    shot by k and read by sqrt(k)) after simulating a 64 x 64 flat patch with it."""
    from lensim.render.pipeline import simulate_capture
    from lensim.sensor.isp import linear_to_srgb
    from lensim.sensor.profile import NoiseModel

    if not (math.isfinite(photo_sigma) and photo_sigma > 0):
        return 0.0, 0.0
    shot0, read0 = sensor.sample_noise(generator)
    probe = replace(sensor, noise=NoiseModel((shot0, shot0), (read0, read0)))
    flat = linear_to_srgb(torch.full((3, 64, 64), float(np.clip(white_linear, 1e-3, 1.0)), dtype=torch.float64))
    sim, _ = simulate_capture(flat.float(), probe, generator, kelvin=kelvin, bits=None)
    inner = np.zeros((64, 64), dtype=bool)
    inner[8:-8, 8:-8] = True
    sigma0 = noise_sigma(linear_rgb(sim.double().numpy()), inner)
    k = (photo_sigma / sigma0) ** 2 if sigma0 > 0 else 0.0
    return shot0 * k, read0 * math.sqrt(k)


def _scenes(
    photo_linear: np.ndarray,
    layout: ChartLayout,
    detection: ChartDetection,
    margin_px: int,
    warp: PixelDistortion | None,
    reach_px: int = 0,
    grid: int = 2,
) -> list[tuple[tuple[int, int, int, int], np.ndarray, np.ndarray, np.ndarray]]:
    """(box, sharp reflectance (rows, cols), black (3,), white (3,)) of every feature crop
    (feature_boxes on the grid; local_levels, the blur reaching reach_px), drawn through
    the lens's distortion when ``warp`` is given."""
    shape = (int(photo_linear.shape[1]), int(photo_linear.shape[2]))
    h = detection.homography if warp is None else ideal_homography(detection, warp)
    out = []
    for box in feature_boxes(layout, detection.homography, shape, margin_px, grid):
        top, left, rows, cols = box
        sharp = render_view(layout, h, box, warp=warp)[0]
        black, white = local_levels(photo_linear[:, top : top + rows, left : left + cols], sharp, reach_px)
        out.append((box, sharp, black, white))
    return out


def crop_illumination(bank: PSFBank, mapping: SensorMapping, box: tuple[int, int, int, int]) -> float:
    """The lens's relative illumination (its kernel's sum, the mean of the channels) at the
    centre of a crop (top, left, rows, cols) of the image the mapping places on the sensor."""
    from lensim.render.kernels import kernels_at

    top, left, rows, cols = box
    k = kernels_at(bank, mapping, [top + 0.5 * (rows - 1)], [left + 0.5 * (cols - 1)])
    return max(float(k.sum(dim=(-2, -1)).mean()), 1e-6)


def _photo_noise(photo_linear: np.ndarray, scenes: list) -> tuple[float, float]:
    """(median noise_sigma, median green white level) over the feature crops' white paper."""
    from scipy.ndimage import binary_erosion

    sigmas, whites = [], []
    for (top, left, rows, cols), sharp, _, white in scenes:
        mask = binary_erosion(sharp > 0.999, iterations=4)
        sigma = noise_sigma(photo_linear[:, top : top + rows, left : left + cols], mask)
        if math.isfinite(sigma):
            sigmas.append(sigma)
            whites.append(float(white[1]))
    return (float(np.median(sigmas)), float(np.median(whites))) if sigmas else (math.nan, math.nan)


def simulate_chart(
    photo: np.ndarray,
    layout: ChartLayout,
    detection: ChartDetection,
    bank: PSFBank,
    sensor: SensorProfile,
    mapping: SensorMapping,
    *,
    generator: torch.Generator | None = None,
    noise: bool | tuple[float, float] = True,
    kelvin: float = 5000.0,
    demosaic: str = "ahd",
    distortion: bool = True,
    tile: int = 64,
) -> tuple[np.ndarray, tuple[float, float]]:
    """The simulation of the photographed chart: ((3, H, W) float64 sRGB, the photo with
    the crop around every edge square and checker patch (feature_boxes) replaced by
    lensim's simulation of it (see the module docstring); the (shot, read) noise used).
    photo: (3, H, W) sRGB in [0, 1]; mapping: where the photo lies on the sensor (its
    pitch is the bank's); noise: True matches the photo's noise level on the chart's white
    paper (matched_noise), False adds none, (shot, read) fixes it (normalized raw units);
    kelvin: the colour temperature unprocessed and developed with (a neutral chart comes
    back neutral at any); distortion: draw the chart through the lens's distortion (the
    bank's; PixelDistortion), placed by the homography of the undistorted marker corners
    (ideal_homography), else through the homography fitted to the photo's corners; tile:
    the spacing (pixels) of the blur's kernel grid (lensim.render.blur)."""
    from lensim.render.pipeline import simulate
    from lensim.sensor.isp import linear_to_srgb
    from lensim.sensor.profile import NoiseModel

    radius = int(bank.psf_at(0.0, 0.0).shape[-1]) // 2
    lin = linear_rgb(photo)
    warp = PixelDistortion.from_bank(bank, mapping) if distortion else None
    grid = math.lcm(tile, 2)  # the Bayer phase and the blur's kernel grid of the whole frame
    scenes = _scenes(lin, layout, detection, radius + CONTEXT_PX, warp, radius, grid)
    if noise is True:
        noise = matched_noise(*_photo_noise(lin, scenes), sensor, generator, kelvin)
    levels = (0.0, 0.0) if noise is False else (float(noise[0]), float(noise[1]))
    fixed = replace(sensor, noise=NoiseModel((levels[0],) * 2, (levels[1],) * 2))
    out = np.array(photo, dtype=np.float64, copy=True)
    keep = CONTEXT_PX // 2  # the crop's own border (the demosaicer's edge) stays the photo's
    for box, sharp, black, white in scenes:
        top, left, rows, cols = box
        ri = crop_illumination(bank, mapping, box)
        scene = torch.from_numpy((black[:, None, None] + (white - black)[:, None, None] * sharp[None]) / ri)
        sim, _ = simulate(
            linear_to_srgb(scene.clamp(0.0, 1.0)).float(),
            bank,
            fixed,
            generator,
            noise=levels != (0.0, 0.0),
            relative_illumination=True,
            demosaic=demosaic,
            bits=None,
            kelvin=kelvin,
            tile=tile,
            mapping=crop_mapping(mapping, box),
        )
        out[:, top + keep : top + rows - keep, left + keep : left + cols - keep] = sim.double().numpy()[
            :, keep : rows - keep, keep : cols - keep
        ]
    return out, levels


def _zone(z: Any, s: Any, crops: list[tuple[int, float, float]]) -> ZoneComparison:
    mine = [v for _, f, v in crops if nearest_zone(f) == z.zone and math.isfinite(v)]
    return ZoneComparison(
        zone=z.zone,
        mean_field=float(np.mean(z.fields)),
        edges=z.edges,
        photo_mtf_area=z.mtf_area,
        sim_mtf_area=s.mtf_area,
        mtf_area_ratio=s.mtf_area / z.mtf_area if z.mtf_area > 0 else math.nan,
        photo_mtf50_cy_px=z.mtf50_cy_px,
        sim_mtf50_cy_px=s.mtf50_cy_px,
        photo_lateral_colour_px=(z.r_minus_g_px, z.b_minus_g_px),
        sim_lateral_colour_px=(s.r_minus_g_px, s.b_minus_g_px),
        psnr_db=float(np.mean(mine)) if mine else math.nan,
        checkers=len(mine),
        photo_mtf=z.mtf,
        sim_mtf=s.mtf,
    )


def compare_images(
    photo: np.ndarray, simulated: np.ndarray, layout: ChartLayout, detection: ChartDetection, pitch_um: float | None
) -> ChartComparison:
    """Measure the photo and its simulation at the same regions and compare them per zone
    (photo, simulated: (3, H, W) sRGB in [0, 1], the same shape). Only edges measured in
    both count."""
    from lensim.calibrate.chart_measure import summarize_zones

    p = measure_chart(photo, layout, detection.homography, pitch_um)
    s = measure_chart(simulated, layout, detection.homography, pitch_um, regions=[e.region for e in p.edges])
    both = [(a, b) for a, b in zip(p.edges, s.edges, strict=True) if a.sfr is not None and b.sfr is not None]
    pz = {z.zone: z for z in summarize_zones([a for a, _ in both])}
    sz = {z.zone: z for z in summarize_zones([b for _, b in both])}
    crops = []
    for c in p.checkers:
        top, left, rows, cols = c.box
        window = (slice(None), slice(top, top + rows), slice(left, left + cols))
        crops.append((c.patch, c.field, psnr(np.clip(simulated[window], 0, 1), np.clip(photo[window], 0, 1))))
    zones = tuple(_zone(pz[k], sz[k], crops) for k in sorted(pz) if k in sz)
    return ChartComparison(zones, p, s, tuple(crops), simulated)


def compare_chart(
    photo: np.ndarray,
    layout: ChartLayout,
    detection: ChartDetection,
    bank: PSFBank,
    sensor: SensorProfile,
    mapping: SensorMapping,
    *,
    seed: int = 0,
    noise: bool | tuple[float, float] = True,
    kelvin: float = 5000.0,
    distortion: bool = True,
) -> ChartComparison:
    """simulate_chart then compare_images: the photographed chart against lensim's
    simulation at the detected pose (bank: the lens at the photo's settings and distance,
    at mapping's pitch; seed: the noise draws)."""
    sim, levels = simulate_chart(
        photo,
        layout,
        detection,
        bank,
        sensor,
        mapping,
        generator=torch.Generator().manual_seed(seed),
        noise=noise,
        kelvin=kelvin,
        distortion=distortion,
    )
    return replace(compare_images(photo, sim, layout, detection, mapping.pitch_um), noise=levels)


def report(comparison: ChartComparison, detection: ChartDetection, pose: ChartPose | None) -> dict[str, Any]:
    """The JSON record of a comparison: definitions, the detection and pose, per zone,
    per edge and per checker."""
    out = {"detection": detection.to_dict(), "pose": None if pose is None else pose.to_dict()}
    return out | comparison.to_dict()
