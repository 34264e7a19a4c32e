"""The printable test chart: its layout (every slanted-edge square, checkerboard patch and
ArUco marker, in mm) designed for a lens, a sensor and a shooting distance, and its JSON
sidecar.

Chart coordinates: millimetres on the print, origin at the chart's centre, x to the right,
y DOWN (as an image's rows), so a frontal photo maps chart (x, y) to photo (column, row)
by a homography. The layout fills the frame footprint at the design distance (the sensor
size divided by the lens's paraxial magnification there); the page is ``print_width_mm``
wide with the frame's aspect, the footprint centred on it.

Features, placed in the footprint's normalized coordinates (u = x / half-width, v = y /
half-height, so u = v = +-h is the diagonal at normalized field h of the half-diagonal):
* slanted-edge squares (black on white, turned by ``SLANT_DEG``) at the fields of
  ``EDGE_FIELDS`` (the paper's Table 1 fields) along all four diagonals, the first at the
  centre: 17 squares, 68 edges. Squares on both sides of the centre, left and right and
  up and down, tell a sensor tilt (which defocuses one side and sharpens the other) from
  a focus shift (which defocuses both); each square's sides measure across x and y;
* checkerboard patches off the diagonals (``CHECKER_UV``): near the centre (field about
  0.1), on the axes (about 0.3 and 0.45) and towards the sides (about 0.7 and 0.85);
* eight ArUco markers (OpenCV's DICT_4X4_50, ids 0-7) in the free space between, so a
  photo taken with some perspective can be registered (lensim.calibrate.chart_detect).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lensim.errors import InputError

#: Turn of the slanted-edge squares, degrees (ISO 12233 recommends about 5).
SLANT_DEG = 5.0
#: Normalized fields (of the frame's half-diagonal) of the squares along each diagonal.
EDGE_FIELDS = (0.0, 0.3, 0.5, 0.7, 0.9)
#: Sizes as fractions of the frame footprint's height.
SQUARE_SIDE = 0.07
CHECKER_SIDE = 0.08
CHECKS_PER_SIDE = 10
MARKER_SIDE = 0.09
#: ArUco dictionary of the markers (OpenCV name) and the cells across one marker (4 data + 2 border).
DICTIONARY = "DICT_4X4_50"
MARKER_CELLS = 6
#: Marker centres in the footprint's normalized coordinates (u, v).
MARKER_UV = ((-0.8, 0.0), (0.8, 0.0), (0.0, -0.75), (0.0, 0.75), (-0.4, -0.75), (0.4, -0.75), (-0.4, 0.75), (0.4, 0.75))
CHART_VERSION = 1


@dataclass(frozen=True)
class EdgeSquare:
    """A black square turned by angle_deg (mm, chart coordinates), whose four sides are
    slanted edges. field: the normalized field it was designed for; azimuth_deg: its
    direction from the centre, counter-clockwise from +x as a viewer sees the chart."""

    id: int
    centre_mm: tuple[float, float]
    side_mm: float
    angle_deg: float
    field: float
    azimuth_deg: float

    def corners_mm(self) -> np.ndarray:
        """(4, 2) corners (x, y) in mm: top-left, top-right, bottom-right, bottom-left of
        the unturned square, turned by angle_deg about the centre (x' = c x - s y,
        y' = s x + c y)."""
        h = self.side_mm / 2.0
        base = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
        return _turn(base, self.angle_deg) + np.asarray(self.centre_mm)

    def half_extent_mm(self) -> float:
        """Half the side of the axis-aligned box holding the turned square, mm."""
        t = math.radians(self.angle_deg)
        return self.side_mm / 2.0 * (abs(math.cos(t)) + abs(math.sin(t)))


@dataclass(frozen=True)
class CheckerPatch:
    """An axis-aligned checkerboard of checks x checks squares, side_mm wide, its top-left
    check black."""

    id: int
    centre_mm: tuple[float, float]
    side_mm: float
    checks: int
    field: float
    azimuth_deg: float

    def half_extent_mm(self) -> float:
        return self.side_mm / 2.0


@dataclass(frozen=True)
class Marker:
    """An ArUco marker (its black border included) side_mm wide, axis-aligned."""

    id: int
    centre_mm: tuple[float, float]
    side_mm: float

    def corners_mm(self) -> np.ndarray:
        """(4, 2) corners in OpenCV's order: top-left, top-right, bottom-right, bottom-left."""
        h = self.side_mm / 2.0
        return np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) + np.asarray(self.centre_mm)

    def half_extent_mm(self) -> float:
        return self.side_mm / 2.0


@dataclass(frozen=True)
class ChartLayout:
    """A chart: page size (mm), the frame footprint it was designed to fill (mm), its
    features and how it was designed (lens, sensor, distance, magnification)."""

    width_mm: float
    height_mm: float
    frame_mm: tuple[float, float]
    edges: tuple[EdgeSquare, ...]
    checkers: tuple[CheckerPatch, ...]
    markers: tuple[Marker, ...]
    dictionary: str = DICTIONARY
    design: dict[str, Any] = field(default_factory=dict)

    def marker_by_id(self) -> dict[int, Marker]:
        return {m.id: m for m in self.markers}


def _turn(points: np.ndarray, angle_deg: float) -> np.ndarray:
    """(N, 2) points turned by angle_deg: x' = c x - s y, y' = s x + c y."""
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    return np.stack([c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]], axis=1)


def _place(u: float, v: float, half_w: float, half_h: float) -> tuple[tuple[float, float], float, float]:
    """(centre mm, normalized field, azimuth deg) of the footprint point (u, v)."""
    x, y = u * half_w, v * half_h
    return (x, y), math.hypot(x, y) / math.hypot(half_w, half_h), math.degrees(math.atan2(-y, x)) % 360.0


#: Checkerboard centres in the footprint's normalized coordinates (u, v), off the diagonals:
#: near the centre, on the axes and between the diagonals towards the sides.
CHECKER_UV = ((-0.15, 0.0), (0.0, -0.45), (0.0, 0.45), (-0.55, 0.0), (0.55, 0.0))
CHECKER_UV_SIDES = tuple((su * u, sv * v) for u, v in ((0.85, 0.4), (0.92, 0.65)) for su in (-1, 1) for sv in (-1, 1))
#: The four diagonals (signs of u, v) the squares lie on beyond the centre.
DIAGONALS = ((1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0))


def _features(half_w: float, half_h: float) -> tuple[list[EdgeSquare], list[CheckerPatch], list[Marker]]:
    """The features of a footprint of half-width half_w and half-height half_h (mm)."""
    fh = 2.0 * half_h
    edges: list[EdgeSquare] = []
    for h in EDGE_FIELDS:
        for su, sv in DIAGONALS if h > 0 else DIAGONALS[:1]:
            c, f, az = _place(su * h, sv * h, half_w, half_h)
            edges.append(EdgeSquare(len(edges), c, SQUARE_SIDE * fh, SLANT_DEG, f, az))
    checkers: list[CheckerPatch] = []
    for u, v in CHECKER_UV + CHECKER_UV_SIDES:
        c, f, az = _place(u, v, half_w, half_h)
        checkers.append(CheckerPatch(len(checkers), c, CHECKER_SIDE * fh, CHECKS_PER_SIDE, f, az))
    markers = [Marker(i, _place(u, v, half_w, half_h)[0], MARKER_SIDE * fh) for i, (u, v) in enumerate(MARKER_UV)]
    return edges, checkers, markers


def _check_fits(items: list[Any], half_w: float, half_h: float, what: str) -> None:
    """Every feature inside the footprint and no two closer than a marker cell (boxes)."""
    gap = MARKER_SIDE * 2.0 * half_h / MARKER_CELLS
    boxes = [(float(it.centre_mm[0]), float(it.centre_mm[1]), it.half_extent_mm() + gap / 2.0) for it in items]
    for x, y, r in boxes:
        if abs(x) + r > half_w or abs(y) + r > half_h:
            raise InputError(None, what, f"the chart's features do not fit a {2 * half_w:.4g} x {2 * half_h:.4g} frame")
    for i, (x, y, r) in enumerate(boxes):
        for x2, y2, r2 in boxes[i + 1 :]:
            if abs(x - x2) < r + r2 and abs(y - y2) < r + r2:
                raise InputError(
                    None,
                    what,
                    f"the chart's features overlap on a {2 * half_w:.4g} x {2 * half_h:.4g} frame "
                    "(expected an aspect ratio between about 1:1 and 2:1)",
                )


def design_chart(
    frame_mm: tuple[float, float], print_width_mm: float, design: dict[str, Any] | None = None
) -> ChartLayout:
    """The chart that fills a frame footprint of frame_mm = (width, height) mm, on a page
    print_width_mm wide with the footprint's aspect. design: what it was made for (lens,
    sensor, distance, magnification), kept in the layout. Raises InputError (field
    ``print_width_mm``) when the footprint is wider than the page, (``frame``) when the
    features do not fit the frame's aspect."""
    fw, fh = (float(v) for v in frame_mm)
    if not (math.isfinite(fw) and math.isfinite(fh) and fw > 0 and fh > 0):
        raise InputError(None, "frame", f"expected a positive frame footprint in mm, got {frame_mm}")
    if not (math.isfinite(print_width_mm) and print_width_mm > 0):
        raise InputError(None, "print_width_mm", f"expected a positive width in mm, got {print_width_mm}")
    if fw > print_width_mm * (1 + 1e-9):
        raise InputError(
            None,
            "print_width_mm",
            f"the frame spans {fw:.0f} x {fh:.0f} mm at this distance, wider than the {print_width_mm:g} mm print; "
            f"expected a print at least {math.ceil(fw)} mm wide or a shorter distance",
        )
    edges, checkers, markers = _features(fw / 2.0, fh / 2.0)
    _check_fits([*edges, *checkers, *markers], fw / 2.0, fh / 2.0, "frame")
    return ChartLayout(
        width_mm=float(print_width_mm),
        height_mm=float(print_width_mm) * fh / fw,
        frame_mm=(fw, fh),
        edges=tuple(edges),
        checkers=tuple(checkers),
        markers=tuple(markers),
        design=dict(design or {}),
    )


# ----------------------------------------------------------------------------- JSON


def chart_to_dict(layout: ChartLayout) -> dict[str, Any]:
    """The JSON sidecar: every position in mm (chart coordinates, y down), with each
    square's corners and each marker's corners spelled out for other tools."""
    return {
        "lensim_chart": CHART_VERSION,
        "units": "mm; origin at the chart centre, x right, y down",
        "width_mm": layout.width_mm,
        "height_mm": layout.height_mm,
        "frame_mm": list(layout.frame_mm),
        "dictionary": layout.dictionary,
        "design": layout.design,
        "edges": [
            {
                "id": e.id,
                "centre_mm": list(e.centre_mm),
                "side_mm": e.side_mm,
                "angle_deg": e.angle_deg,
                "field": e.field,
                "azimuth_deg": e.azimuth_deg,
                "corners_mm": e.corners_mm().tolist(),
            }
            for e in layout.edges
        ],
        "checkers": [
            {
                "id": c.id,
                "centre_mm": list(c.centre_mm),
                "side_mm": c.side_mm,
                "checks": c.checks,
                "field": c.field,
                "azimuth_deg": c.azimuth_deg,
            }
            for c in layout.checkers
        ],
        "markers": [
            {"id": m.id, "centre_mm": list(m.centre_mm), "side_mm": m.side_mm, "corners_mm": m.corners_mm().tolist()}
            for m in layout.markers
        ],
    }


def _num(src: str, key: str, value: Any, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(src, key, f"expected a number, got {value!r}")
    if positive and not value > 0:
        raise InputError(src, key, f"expected a positive number, got {value!r}")
    return float(value)


def _pair(src: str, key: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise InputError(src, key, f"expected [x, y] in mm, got {value!r}")
    return _num(src, key, value[0]), _num(src, key, value[1])


def _items(src: str, data: dict, key: str, need: tuple[str, ...]) -> list[dict]:
    items = data.get(key)
    if not isinstance(items, list) or not items:
        raise InputError(src, key, "expected a non-empty list")
    for i, it in enumerate(items):
        if not isinstance(it, dict) or not set(need) <= set(it):
            raise InputError(src, f"{key}[{i}]", f"expected an object with {', '.join(need)}")
    return items


def chart_from_dict(data: Any, src: str = "<chart>") -> ChartLayout:
    """A ChartLayout from its JSON sidecar (chart_to_dict's form), checked: one-line
    InputError naming ``src`` and the key."""
    if not isinstance(data, dict) or data.get("lensim_chart") != CHART_VERSION:
        raise InputError(src, "lensim_chart", f"expected a lensim chart sidecar (version {CHART_VERSION})")
    edges = tuple(
        EdgeSquare(
            int(_num(src, f"edges[{i}].id", e["id"])),
            _pair(src, f"edges[{i}].centre_mm", e["centre_mm"]),
            _num(src, f"edges[{i}].side_mm", e["side_mm"], positive=True),
            _num(src, f"edges[{i}].angle_deg", e["angle_deg"]),
            _num(src, f"edges[{i}].field", e.get("field", 0.0)),
            _num(src, f"edges[{i}].azimuth_deg", e.get("azimuth_deg", 0.0)),
        )
        for i, e in enumerate(_items(src, data, "edges", ("id", "centre_mm", "side_mm", "angle_deg")))
    )
    checkers = tuple(
        CheckerPatch(
            int(_num(src, f"checkers[{i}].id", c["id"])),
            _pair(src, f"checkers[{i}].centre_mm", c["centre_mm"]),
            _num(src, f"checkers[{i}].side_mm", c["side_mm"], positive=True),
            int(_num(src, f"checkers[{i}].checks", c["checks"], positive=True)),
            _num(src, f"checkers[{i}].field", c.get("field", 0.0)),
            _num(src, f"checkers[{i}].azimuth_deg", c.get("azimuth_deg", 0.0)),
        )
        for i, c in enumerate(_items(src, data, "checkers", ("id", "centre_mm", "side_mm", "checks")))
    )
    markers = tuple(
        Marker(
            int(_num(src, f"markers[{i}].id", m["id"])),
            _pair(src, f"markers[{i}].centre_mm", m["centre_mm"]),
            _num(src, f"markers[{i}].side_mm", m["side_mm"], positive=True),
        )
        for i, m in enumerate(_items(src, data, "markers", ("id", "centre_mm", "side_mm")))
    )
    if data.get("dictionary") != DICTIONARY:
        raise InputError(src, "dictionary", f"expected {DICTIONARY!r}, got {data.get('dictionary')!r}")
    design = data.get("design", {})
    return ChartLayout(
        width_mm=_num(src, "width_mm", data.get("width_mm"), positive=True),
        height_mm=_num(src, "height_mm", data.get("height_mm"), positive=True),
        frame_mm=_pair(src, "frame_mm", data.get("frame_mm")),
        edges=edges,
        checkers=checkers,
        markers=markers,
        design=design if isinstance(design, dict) else {},
    )


def load_chart(path: str | Path) -> ChartLayout:
    """Read a chart's JSON sidecar (lensim.io.read_json; errors name the file)."""
    from lensim.io import read_json

    return chart_from_dict(read_json(path, "chart file"), str(path))
