"""Lateral colour (transverse chromatic aberration) measured on an edge or a point.

Edge: each channel's straight edge is located and fitted exactly as for the slanted-edge
MTF (lensim.evaluate.slanted_edge.locate_edge: Hamming-windowed derivative centroids per
row, least-squares line); its position is the signed distance (pixels) of the fitted line
from the region centre along the edge normal, and the R-G / B-G shifts are differences of
those positions. The normal follows the slanted-edge convention (positive x component for a
near-vertical edge, positive y component -- downwards -- for a near-horizontal one).

Point: each channel's background-subtracted intensity centroid (pixels), iterated in a
circular window; shifts are (dx, dy) vectors in pixels, projectable on any direction
(e.g. the radial direction from the image centre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError
from lensim.evaluate.slanted_edge import EdgeFit, Orientation, detect_orientation, locate_edge


def _as_channels(region: np.ndarray, reference: int) -> np.ndarray:
    a = np.asarray(region)
    if a.ndim != 3 or a.shape[2] < 2:
        raise InputError(None, "region", f"expected an (H, W, C) array with C >= 2 channels, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise InputError(None, "region", f"expected real numbers, got dtype {a.dtype}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise InputError(None, "region", "contains NaN or infinite values")
    if not -a.shape[2] <= reference < a.shape[2]:
        raise InputError(None, "reference", f"expected a channel index below {a.shape[2]}, got {reference}")
    return a


@dataclass(frozen=True)
class EdgeShiftResult:
    """Per-channel edge positions and shifts.

    positions_px: (C,) signed distance of each channel's fitted edge from the region
    centre along the normal, pixels; shifts_px: positions minus the reference channel's,
    pixels; normal_xy: unit normal (x = column, y = row) of the reference channel's edge;
    angle_deg: its slant; orientation: 'vertical' or 'horizontal'; fits: the per-channel
    EdgeFit.
    """

    positions_px: np.ndarray
    shifts_px: np.ndarray
    reference: int
    normal_xy: tuple[float, float]
    angle_deg: float
    orientation: Orientation
    fits: tuple[EdgeFit, ...]

    @property
    def r_minus_g_px(self) -> float:
        """Red edge position minus green, pixels along the normal (RGB channel order)."""
        return float(self.positions_px[0] - self.positions_px[1])

    @property
    def b_minus_g_px(self) -> float:
        """Blue edge position minus green, pixels along the normal (RGB channel order)."""
        if self.positions_px.size < 3:
            raise InputError(None, "region", "no blue channel: the region has fewer than 3 channels")
        return float(self.positions_px[2] - self.positions_px[1])


def lateral_color_edge(
    region: np.ndarray,
    reference: int = 1,
    *,
    orientation: Orientation | None = None,
    min_angle_deg: float = 1.0,
    max_angle_deg: float = 15.0,
) -> EdgeShiftResult:
    """Lateral colour across one slanted edge in an (H, W, C) region (RGB: C = 3, reference
    green).

    Every channel is fitted on its own (same routine and limits as slanted_edge_mtf) in the
    orientation detected on the channel mean. Returns an EdgeShiftResult; ``r_minus_g_px``
    and ``b_minus_g_px`` are the R-G and B-G shifts in pixels along the edge normal.
    Raises InputError when a channel has no usable edge.
    """
    a = _as_channels(region, reference)
    if orientation is None:
        orientation = detect_orientation(a)
    fits = tuple(
        locate_edge(a[:, :, c], orientation, min_angle_deg, max_angle_deg, name=f"region[..., {c}]")
        for c in range(a.shape[2])
    )
    pos = np.array([f.position_px() for f in fits])
    ref = fits[reference]
    return EdgeShiftResult(
        positions_px=pos,
        shifts_px=pos - pos[reference],
        reference=reference % a.shape[2],
        normal_xy=ref.normal_xy,
        angle_deg=ref.angle_deg,
        orientation=orientation,
        fits=fits,
    )


@dataclass(frozen=True)
class PointShiftResult:
    """Per-channel centroids of a point image and their shifts.

    centroids_xy: (C, 2) centroid (x = column, y = row) of each channel, pixels;
    shifts_xy: (C, 2) centroid minus the reference channel's, pixels.
    """

    centroids_xy: np.ndarray
    shifts_xy: np.ndarray
    reference: int

    @property
    def r_minus_g_xy(self) -> np.ndarray:
        """(dx, dy) of red minus green, pixels (RGB channel order)."""
        return self.centroids_xy[0] - self.centroids_xy[1]

    @property
    def b_minus_g_xy(self) -> np.ndarray:
        """(dx, dy) of blue minus green, pixels (RGB channel order)."""
        if self.centroids_xy.shape[0] < 3:
            raise InputError(None, "region", "no blue channel: the region has fewer than 3 channels")
        return self.centroids_xy[2] - self.centroids_xy[1]

    def along(self, direction_xy: tuple[float, float]) -> np.ndarray:
        """Shifts (pixels) projected on a direction (x, y), e.g. radial; it is normalized."""
        d = np.asarray(direction_xy, dtype=np.float64)
        norm = float(np.hypot(*d))
        if d.shape != (2,) or not norm > 0:
            raise InputError(None, "direction_xy", f"expected a non-zero (x, y) vector, got {direction_xy}")
        return self.shifts_xy @ (d / norm)


def _centroid(img: np.ndarray, radius: float, name: str) -> np.ndarray:
    """Centroid (x, y) of a background-free image in a circular window of `radius` pixels,
    re-centred until it moves less than 1e-6 px (at most 50 times)."""
    rows, cols = img.shape
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    r0, c0 = np.unravel_index(int(np.argmax(img)), img.shape)
    cx, cy = float(c0), float(r0)
    for _ in range(50):
        w = np.where((x - cx) ** 2 + (y - cy) ** 2 <= radius**2, img, 0.0)
        s = w.sum()
        if not s > 0:
            raise InputError(None, name, "no point found: no positive signal above the background")
        nx, ny = float((w * x).sum() / s), float((w * y).sum() / s)
        moved = math.hypot(nx - cx, ny - cy)
        cx, cy = nx, ny
        if moved < 1e-6:
            break
    return np.array([cx, cy])


def lateral_color_point(
    region: np.ndarray,
    reference: int = 1,
    *,
    radius_px: float | None = None,
    background: float | np.ndarray | None = None,
) -> PointShiftResult:
    """Lateral colour from the image of a point source in an (H, W, C) region.

    background: per-channel level (image units) subtracted first; None takes the median of
    the region's one-pixel border per channel. radius_px: radius of the centroid window,
    pixels; default 4x the spot's half-maximum radius (the radius of a disc with the area
    above half the peak; 4.7 sigma for a Gaussian), at least 3, at most the distance from
    the brightest pixel to the region border (at least 2) -- the window keeps noise far
    from the spot out, so a long faint flare outside it does not count. Raises InputError when a channel shows no point (peak less than 5 noise
    standard deviations above the background, the noise estimated from the border).
    """
    a = _as_channels(region, reference)
    rows, cols, n_ch = a.shape
    if min(rows, cols) < 5:
        raise InputError(None, "region", f"region too small: {rows}x{cols} px, need at least 5 px on each side")
    border = np.concatenate([a[0], a[-1], a[1:-1, 0], a[1:-1, -1]], axis=0)  # (n, C)
    if background is None:
        bg = np.median(border, axis=0)
    else:
        bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (n_ch,))
    noise = 1.4826 * np.median(np.abs(border - np.median(border, axis=0)), axis=0)
    cents = np.empty((n_ch, 2))
    for c in range(n_ch):
        img = a[:, :, c] - bg[c]
        peak = float(img.max())
        if not peak > 5.0 * noise[c] or not peak > 0:
            raise InputError(
                None, f"region[..., {c}]", f"no point found: peak {peak:.3g} above background, noise {noise[c]:.3g}"
            )
        if radius_px is None:
            r0, c0 = np.unravel_index(int(np.argmax(img)), img.shape)
            to_border = float(min(r0, c0, rows - 1 - r0, cols - 1 - c0))
            r_half = math.sqrt(float((img >= 0.5 * peak).sum()) / math.pi)
            rad = min(max(2.0, to_border), max(3.0, 4.0 * r_half))
        else:
            if not radius_px > 0:
                raise InputError(None, "radius_px", f"expected a positive radius in pixels, got {radius_px}")
            rad = float(radius_px)
        cents[c] = _centroid(img, rad, f"region[..., {c}]")
    ref = reference % n_ch
    return PointShiftResult(centroids_xy=cents, shifts_xy=cents - cents[ref], reference=ref)
