"""Finding a chart (lensim.calibrate.chart) in a photo: its ArUco markers (OpenCV), the
homography from chart millimetres to photo pixels fitted to every detected marker corner,
the checks that the chart is large enough in the frame, and the camera's pose (the chart's
distance and tilt) from the lens's paraxial imaging.

Pixel coordinates: (column, row) of pixel centres, (0, 0) the centre of the top-left
pixel. The homography H maps chart (x_mm, y_mm, 1) to (column, row, 1) up to scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lensim.calibrate.chart import ChartLayout
from lensim.calibrate.chart_draw import project
from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.optics.lens import Lens

#: Markers needed for a homography (4 corners each; 2 would do, 4 spread them over the frame).
MIN_MARKERS = 4
#: Smallest side (pixels) of an edge square in the photo: its edge regions are then at
#: least 12 px across (lensim.evaluate.slanted_edge.MIN_REGION_PX) with room to spare.
MIN_SQUARE_PX = 30.0
#: Smallest fraction of the photo's width the chart's frame footprint must span.
MIN_FILL = 0.5


@dataclass(frozen=True)
class ChartDetection:
    """Markers found in a photo and the chart -> photo homography.

    homography: (3, 3), chart mm -> photo pixel centres (column, row); marker_ids: ids
    found (ascending); chart_points_mm / image_points_px: (4 N, 2) the marker corners on
    the chart and where they were found; reprojection_rms_px: RMS distance (pixels)
    between the found corners and the chart corners mapped by the homography;
    shape: the photo's (rows, cols)."""

    homography: np.ndarray
    marker_ids: tuple[int, ...]
    chart_points_mm: np.ndarray
    image_points_px: np.ndarray
    reprojection_rms_px: float
    shape: tuple[int, int]

    def to_dict(self) -> dict:
        return {
            "homography": self.homography.tolist(),
            "marker_ids": list(self.marker_ids),
            "reprojection_rms_px": self.reprojection_rms_px,
        }


@dataclass(frozen=True)
class ChartPose:
    """The camera's pose towards the chart from a detection and the lens's paraxial
    imaging (a pinhole at the entrance pupil whose scale is the paraxial magnification).

    distance_m: object distance from the image plane (lensim's convention for
    --object-m / --focus-m), metres; tilt_deg: angle between the chart's normal and the
    optical axis, degrees; roll_deg: the chart's x axis turned about the optical axis in
    the image, degrees; rotation / translation_mm: chart -> camera (OpenCV solvePnP, x
    right, y down, z along the axis; mm from the entrance pupil); focal_px: the pinhole's
    focal length in pixels used."""

    distance_m: float
    tilt_deg: float
    roll_deg: float
    rotation: np.ndarray
    translation_mm: np.ndarray
    focal_px: float

    def to_dict(self) -> dict:
        return {
            "distance_m": self.distance_m,
            "tilt_deg": self.tilt_deg,
            "roll_deg": self.roll_deg,
            "rotation": self.rotation.tolist(),
            "translation_mm": self.translation_mm.tolist(),
            "focal_px": self.focal_px,
        }


def to_gray8(image: np.ndarray) -> np.ndarray:
    """(3, H, W) or (H, W) float image in [0, 1] -> (H, W) uint8 grey, contrast stretched
    between its 1st and 99th percentiles (dim or flat-lit photos detect as well)."""
    a = np.asarray(image, dtype=np.float64)
    g = a.mean(axis=0) if a.ndim == 3 else a
    lo, hi = np.percentile(g, [1.0, 99.0])
    if not hi > lo:
        return np.zeros(g.shape, dtype=np.uint8)
    return np.clip(np.round((g - lo) / (hi - lo) * 255.0), 0, 255).astype(np.uint8)


def find_markers(gray: np.ndarray, dictionary: str) -> dict[int, np.ndarray]:
    """ArUco markers of ``dictionary`` in a (H, W) uint8 image: {id: (4, 2) corners
    (column, row), OpenCV's order: top-left, top-right, bottom-right, bottom-left of the
    marker as printed}, refined to sub-pixel. A marker found twice is dropped (ambiguous)."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)
    corners, ids, _ = detector.detectMarkers(gray)
    found: dict[int, np.ndarray] = {}
    twice: set[int] = set()
    for c, i in zip(corners, [] if ids is None else ids.ravel(), strict=True):
        key = int(i)
        if key in found:
            twice.add(key)
        found[key] = np.asarray(c, dtype=np.float64).reshape(4, 2)
    return {k: v for k, v in found.items() if k not in twice}


def detect_chart(image: np.ndarray, layout: ChartLayout, src: str = "photo") -> ChartDetection:
    """Find the chart's markers in a (3, H, W) or (H, W) float image in [0, 1] and fit the
    chart -> photo homography (least squares on every corner, after a RANSAC pass that
    drops corners more than 3 px off). Raises InputError naming ``src``, field 'chart',
    when fewer than MIN_MARKERS of the chart's markers are found."""
    import cv2

    a = np.asarray(image)
    found = find_markers(to_gray8(a), layout.dictionary)
    by_id = layout.marker_by_id()
    ids = sorted(k for k in found if k in by_id)
    if len(ids) < MIN_MARKERS:
        what = "no chart markers found" if not ids else f"only {len(ids)} of the chart's {len(by_id)} markers found"
        raise InputError(
            src,
            "chart",
            f"{what}; expected a photo of the chart (at least {MIN_MARKERS} markers visible, sharp and unclipped)",
        )
    obj = np.concatenate([by_id[k].corners_mm() for k in ids])
    img = np.concatenate([found[k] for k in ids])
    h, inliers = cv2.findHomography(obj, img, cv2.RANSAC, 3.0)
    if h is None:
        raise InputError(src, "chart", "the markers found do not fit one plane; expected a flat chart")
    keep = inliers.ravel().astype(bool)
    h, _ = cv2.findHomography(obj[keep], img[keep], 0)
    h = np.asarray(h, dtype=np.float64) / h[2, 2]
    rms = float(np.sqrt(np.mean(np.sum((project(h, obj) - img) ** 2, axis=1))))
    shape = (int(a.shape[-2]), int(a.shape[-1]))
    return ChartDetection(h, tuple(ids), obj, img, rms, shape)


def square_sides_px(layout: ChartLayout, homography: np.ndarray) -> np.ndarray:
    """(n_edges,) shortest side (pixels) of each edge square in the photo."""
    sides = []
    for e in layout.edges:
        q = project(homography, e.corners_mm())
        sides.append(float(np.min(np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1))))
    return np.asarray(sides)


def check_coverage(layout: ChartLayout, detection: ChartDetection, src: str = "photo") -> None:
    """Refuse a chart too small in the frame (InputError naming ``src``, field 'chart'):
    its frame footprint must span at least MIN_FILL of the photo's width and its edge
    squares at least MIN_SQUARE_PX pixels."""
    fw, fh = layout.frame_mm
    box = np.array([[-fw, -fh], [fw, -fh], [fw, fh], [-fw, fh]]) / 2.0
    span = np.ptp(project(detection.homography, box)[:, 0]) / detection.shape[1]
    side = float(np.min(square_sides_px(layout, detection.homography)))
    if span < MIN_FILL or side < MIN_SQUARE_PX:
        raise InputError(
            src,
            "chart",
            f"too small in the frame: the chart spans {100 * span:.0f} % of the photo's width and its squares "
            f"{side:.0f} px; expected >= {100 * MIN_FILL:.0f} % and >= {MIN_SQUARE_PX:.0f} px (shoot closer, "
            "or print the chart larger)",
        )


def _paraxial_scale(lens: Lens, distance_m: float) -> tuple[float, float, float]:
    """(|magnification|, entrance pupil z, image plane z) of the lens focused at distance_m
    (object distance from the image plane, m); z in the lens's coordinates, mm."""
    from lensim.optics.paraxial import paraxial_data
    from lensim.optics.shooting import ShootingSettings, lens_at

    at = lens_at(lens, ShootingSettings(object_m=distance_m, focus_m=distance_m))
    p = paraxial_data(at)
    return abs(p.magnification), p.entrance_pupil_z_mm, p.paraxial_image_z_mm


def estimate_pose(
    detection: ChartDetection, lens: Lens, pitch_um: float, guess_m: float = 2.0, iterations: int = 4
) -> ChartPose:
    """The chart's distance and tilt from a detection: a pinhole at the lens's entrance
    pupil with focal length |m| u / pitch (m the paraxial magnification at object distance
    u from the pupil, which depends on the distance: iterated from guess_m), the principal
    point at the photo's centre (the photo maps onto the sensor centred), OpenCV's
    solvePnP on the marker corners. pitch_um: the photo's pixel pitch on the sensor (um)."""
    import cv2

    rows, cols = detection.shape
    centre = ((cols - 1) / 2.0, (rows - 1) / 2.0)
    obj = np.c_[detection.chart_points_mm, np.zeros(len(detection.chart_points_mm))]
    dist_m = float(guess_m)
    for _ in range(iterations):
        mag, ep_z, img_z = _paraxial_scale(lens, dist_m)
        u_mm = dist_m * 1e3 - (img_z - ep_z)
        f_px = mag * u_mm / (pitch_um * 1e-3)
        k = np.array([[f_px, 0.0, centre[0]], [0.0, f_px, centre[1]], [0.0, 0.0, 1.0]])
        ok, rvec, tvec = cv2.solvePnP(obj, detection.image_points_px, k, None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise InputError(None, "chart", "the camera's pose could not be estimated from the markers")
        dist_m = (float(tvec[2, 0]) + (img_z - ep_z)) * 1e-3
        if not (math.isfinite(dist_m) and dist_m > 0):
            raise InputError(None, "chart", "the camera's pose puts the chart behind the lens")
    rot, _ = cv2.Rodrigues(rvec)
    tilt = math.degrees(math.acos(min(1.0, abs(float(rot[2, 2])))))
    roll = math.degrees(math.atan2(float(rot[1, 0]), float(rot[0, 0])))
    return ChartPose(dist_m, tilt, roll, rot, tvec.ravel().astype(np.float64), float(f_px))
