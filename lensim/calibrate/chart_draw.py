"""Drawing a chart (lensim.calibrate.chart): its reflectance at any point, the printable
page (PNG or PDF at an exact print size) and the chart as a camera sees it through a
homography (the sharp scene the simulation blurs).

Reflectance: 1 on white paper, 0 on black ink; outside the page the scene is taken as
white paper too.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Protocol

import numpy as np

from lensim.calibrate.chart import DICTIONARY, MARKER_CELLS, ChartLayout, CheckerPatch, EdgeSquare, Marker
from lensim.errors import InputError
from lensim.io import atomic_writer


class PixelWarp(Protocol):
    """A lens's distortion on a photo's pixel grid: where a real (distorted) pixel position
    would be without distortion, and back. u: columns, v: rows (pixel centres), arrays."""

    def to_ideal(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def to_real(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


@lru_cache(maxsize=64)
def marker_cells(marker_id: int, dictionary: str = DICTIONARY) -> np.ndarray:
    """(MARKER_CELLS, MARKER_CELLS) reflectance of an ArUco marker's cells (0 black, 1
    white; the one-cell black border included), from OpenCV's dictionary."""
    import cv2

    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    img = cv2.aruco.generateImageMarker(d, int(marker_id), MARKER_CELLS, borderBits=1)
    return (np.asarray(img) > 127).astype(np.float64)


def _inside_box(x: np.ndarray, y: np.ndarray, cx: float, cy: float, half: float) -> np.ndarray:
    return (np.abs(x - cx) <= half) & (np.abs(y - cy) <= half)


def chart_reflectance(layout: ChartLayout, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Reflectance (0 black .. 1 white) at chart points (x_mm, y_mm), any matching shapes
    (mm, chart coordinates: origin at the centre, y down). Points off the page are white."""
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(y_mm, dtype=np.float64)
    out = np.ones(np.broadcast(x, y).shape)
    x, y = np.broadcast_to(x, out.shape), np.broadcast_to(y, out.shape)
    for e in layout.edges:
        sel = _inside_box(x, y, e.centre_mm[0], e.centre_mm[1], e.half_extent_mm())
        if not sel.any():
            continue
        t = math.radians(e.angle_deg)
        dx, dy = x[sel] - e.centre_mm[0], y[sel] - e.centre_mm[1]
        lx, ly = math.cos(t) * dx + math.sin(t) * dy, -math.sin(t) * dx + math.cos(t) * dy  # turn back
        h = e.side_mm / 2.0
        out[sel] = np.where((np.abs(lx) <= h) & (np.abs(ly) <= h), 0.0, out[sel])
    for c in layout.checkers:
        sel = _inside_box(x, y, c.centre_mm[0], c.centre_mm[1], c.side_mm / 2.0)
        if not sel.any():
            continue
        step = c.side_mm / c.checks
        i = np.floor((y[sel] - c.centre_mm[1] + c.side_mm / 2.0) / step)
        j = np.floor((x[sel] - c.centre_mm[0] + c.side_mm / 2.0) / step)
        out[sel] = np.mod(i + j, 2.0)  # top-left check (0, 0) black
    for m in layout.markers:
        sel = _inside_box(x, y, m.centre_mm[0], m.centre_mm[1], m.side_mm / 2.0)
        if not sel.any():
            continue
        cells = marker_cells(m.id, layout.dictionary)
        cell = m.side_mm / MARKER_CELLS
        i = np.clip(np.floor((y[sel] - m.centre_mm[1] + m.side_mm / 2.0) / cell), 0, MARKER_CELLS - 1)
        j = np.clip(np.floor((x[sel] - m.centre_mm[0] + m.side_mm / 2.0) / cell), 0, MARKER_CELLS - 1)
        out[sel] = cells[i.astype(int), j.astype(int)]
    return out


def render_page(layout: ChartLayout, dpi: float, oversample: int = 2) -> np.ndarray:
    """The printable page, (rows, cols) uint8 grey (0 black, 255 white) at dpi dots per
    inch, each pixel the mean of oversample x oversample point samples (only the features'
    boxes are sampled: the rest is paper)."""
    if not (math.isfinite(dpi) and 50 <= dpi <= 2400):
        raise InputError(None, "dpi", f"expected 50-2400 dots per inch, got {dpi}")
    per_mm = dpi / 25.4
    cols, rows = round(layout.width_mm * per_mm), round(layout.height_mm * per_mm)
    to_page = np.array(  # chart mm -> page pixel centres
        [[per_mm, 0.0, layout.width_mm / 2.0 * per_mm - 0.5], [0.0, per_mm, layout.height_mm / 2.0 * per_mm - 0.5],
         [0.0, 0.0, 1.0]]
    )  # fmt: skip
    page = np.full((rows, cols), 255, dtype=np.uint8)
    for part, corners in _parts(layout):
        q = project(to_page, corners)
        r0, r1 = max(0, math.floor(q[:, 1].min()) - 1), min(rows, math.ceil(q[:, 1].max()) + 2)
        c0, c1 = max(0, math.floor(q[:, 0].min()) - 1), min(cols, math.ceil(q[:, 0].max()) + 2)
        if r1 > r0 and c1 > c0:
            sub = np.round(255.0 * _view(part, to_page, (r0, c0, r1 - r0, c1 - c0), oversample)).astype(np.uint8)
            page[r0:r1, c0:c1] = np.minimum(page[r0:r1, c0:c1], sub)
    return page


def write_page(layout: ChartLayout, path: str | Path, dpi: float = 300.0) -> Path:
    """Write the printable page as PNG (with its dpi recorded) or PDF (one page exactly
    width_mm x height_mm), atomically. Print it at 100 % scale ("actual size")."""
    from PIL import Image

    path = Path(path)
    fmt = {".png": "PNG", ".pdf": "PDF"}.get(path.suffix.lower())
    if fmt is None:
        raise InputError(str(path), "format", "expected a file name ending in .pdf or .png")
    img = Image.fromarray(render_page(layout, dpi), "L")
    with atomic_writer(path, suffix=path.suffix) as fh:
        if fmt == "PDF":
            img.save(fh, format="PDF", resolution=float(dpi))
        else:
            img.save(fh, format="PNG", dpi=(float(dpi), float(dpi)))
    return path


def render_view(
    layout: ChartLayout,
    homography: np.ndarray,
    box: tuple[int, int, int, int],
    levels: tuple[np.ndarray, np.ndarray] | None = None,
    oversample: int = 4,
    warp: PixelWarp | None = None,
) -> np.ndarray:
    """The chart as the camera sees it through ``homography`` (3x3: chart mm (x, y, 1) ->
    photo pixel centres (column, row, 1)), in the photo's pixel box (top, left, rows,
    cols): (3, rows, cols) float64, each pixel the mean reflectance over oversample x
    oversample points mapped back to the chart, scaled to levels = (black (3,), white
    (3,)) per channel (default 0 and 1). warp: the lens's distortion; then ``homography``
    maps the chart to undistorted pixel positions and each sample point is taken there
    (warp.to_ideal) before mapping back to the chart: the chart drawn as the distorted lens
    images it, sampled exactly (no resampling of a rendered image)."""
    top, left, rows, cols = box
    refl = np.ones((rows, cols))
    for part, corners in _parts(layout):
        q = project(homography, corners)
        if warp is not None:
            q = np.stack(warp.to_real(q[:, 0], q[:, 1]), axis=1)
        r0, r1 = max(top, math.floor(q[:, 1].min()) - 1), min(top + rows, math.ceil(q[:, 1].max()) + 2)
        c0, c1 = max(left, math.floor(q[:, 0].min()) - 1), min(left + cols, math.ceil(q[:, 0].max()) + 2)
        if r1 > r0 and c1 > c0:
            sub = _view(part, homography, (r0, c0, r1 - r0, c1 - c0), oversample, warp)
            refl[r0 - top : r1 - top, c0 - left : c1 - left] = np.minimum(
                refl[r0 - top : r1 - top, c0 - left : c1 - left], sub
            )
    black, white = (np.zeros(3), np.ones(3)) if levels is None else (np.asarray(lv, float) for lv in levels)
    return black[:, None, None] + (white - black)[:, None, None] * refl[None]


def _parts(layout: ChartLayout) -> list[tuple[ChartLayout, np.ndarray]]:
    """Each feature alone as a layout, with the (4, 2) corners (mm) of a box holding it."""
    alone = [replace(layout, edges=(e,), checkers=(), markers=()) for e in layout.edges]
    alone += [replace(layout, edges=(), checkers=(c,), markers=()) for c in layout.checkers]
    alone += [replace(layout, edges=(), checkers=(), markers=(m,)) for m in layout.markers]
    out = []
    for part in alone:
        items: list[EdgeSquare | CheckerPatch | Marker] = [*part.edges, *part.checkers, *part.markers]
        item = items[0]
        h = item.half_extent_mm()
        out.append((part, np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) + np.asarray(item.centre_mm)))
    return out


def _view(
    layout: ChartLayout,
    homography: np.ndarray,
    box: tuple[int, int, int, int],
    oversample: int,
    warp: PixelWarp | None = None,
) -> np.ndarray:
    """(rows, cols) mean reflectance over oversample x oversample points per pixel of box."""
    top, left, rows, cols = box
    hinv = np.linalg.inv(np.asarray(homography, dtype=np.float64))
    s = int(oversample)
    sub = (np.arange(s) + 0.5) / s - 0.5
    u = (left + np.arange(cols)[:, None] + sub[None, :]).ravel()  # photo columns
    v = (top + np.arange(rows)[:, None] + sub[None, :]).ravel()  # photo rows
    uu, vv = np.meshgrid(u, v)
    if warp is not None:
        uu, vv = warp.to_ideal(uu, vv)
    w = hinv[2, 0] * uu + hinv[2, 1] * vv + hinv[2, 2]
    x = (hinv[0, 0] * uu + hinv[0, 1] * vv + hinv[0, 2]) / w
    y = (hinv[1, 0] * uu + hinv[1, 1] * vv + hinv[1, 2]) / w
    return chart_reflectance(layout, x, y).reshape(rows, s, cols, s).mean(axis=(1, 3))


def project(homography: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """(N, 2) chart points (mm) -> (N, 2) photo pixel centres (column, row)."""
    p = np.asarray(points_mm, dtype=np.float64).reshape(-1, 2)
    q = np.c_[p, np.ones(len(p))] @ np.asarray(homography, dtype=np.float64).T
    return q[:, :2] / q[:, 2:3]
