"""Lateral colour: per-channel edge positions (R-G, B-G shifts along the edge normal) and
point-image centroid shifts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import shift as nd_shift
from scipy.special import erf

from lensim.errors import InputError
from lensim.evaluate import lateral_color_edge, lateral_color_point, make_slanted_edge

K = 8


def gaussian_psf(sigma: float, k: int = K, half_px: float = 5.0) -> np.ndarray:
    n = int(round(half_px * k))
    g = np.exp(-((np.arange(-n, n + 1) / k) ** 2) / (2 * sigma**2))
    return np.outer(g, g)


def rgb_edge(
    size: int,
    angle: float,
    shifts: tuple[float, float, float],
    sigmas: tuple[float, float, float],
    orientation: str = "vertical",
    noise: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Channels shifted along the edge normal by `shifts` (pixels), blurred by Gaussians."""
    chans = [
        make_slanted_edge(size, angle, 0.15, 0.85, psf=gaussian_psf(s), offset_px=o, orientation=orientation)  # type: ignore[arg-type]
        for o, s in zip(shifts, sigmas)
    ]
    img = np.stack(chans, axis=-1)
    if noise:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return img


@pytest.mark.parametrize("orientation", ["vertical", "horizontal"])
@pytest.mark.parametrize("angle", [3.0, 5.0, -8.0])
def test_edge_shifts_recovered(angle: float, orientation: str) -> None:
    """R shifted +0.3 px and B -0.5 px from G along the normal, each channel blurred
    differently (sigma 0.9 / 0.5 / 1.2 px, as lateral colour comes with chromatic blur),
    noise 0.003 on a contrast of 0.7: brief tolerance 0.05 px (measured <= 0.012 px)."""
    img = rgb_edge(
        80,
        angle,
        (0.3, 0.0, -0.5),
        (0.9, 0.5, 1.2),
        orientation,
        noise=0.003,
        seed=int(abs(angle) * 10) + (orientation == "vertical"),
    )
    res = lateral_color_edge(img)
    assert res.orientation == orientation
    assert res.angle_deg == pytest.approx(angle, abs=0.05)
    assert res.r_minus_g_px == pytest.approx(0.3, abs=0.05)
    assert res.b_minus_g_px == pytest.approx(-0.5, abs=0.05)
    assert res.shifts_px[1] == 0.0
    assert np.allclose(res.shifts_px, res.positions_px - res.positions_px[1])


def test_edge_shifts_exact_without_noise() -> None:
    """Noise-free, equal blur: the windowed-centroid line fit is unbiased (measured error
    below 1e-4 px; bound 0.005 px); absolute positions are the offsets given."""
    img = rgb_edge(70, 6.0, (0.3, 0.1, -0.5), (0.7, 0.7, 0.7))
    res = lateral_color_edge(img)
    assert res.positions_px == pytest.approx([0.3, 0.1, -0.5], abs=0.005)
    assert res.r_minus_g_px == pytest.approx(0.2, abs=0.005)
    assert res.b_minus_g_px == pytest.approx(-0.6, abs=0.005)


@pytest.mark.parametrize("orientation", ["vertical", "horizontal"])
def test_edge_shift_sign_convention(orientation: str) -> None:
    """Independent of make_slanted_edge's offset: moving the red channel by +d px along x
    (vertical edge) or y (horizontal edge) by spline interpolation is a shift of
    d cos(angle) along the normal, whose component along that axis is positive."""
    angle, d = 5.0, 0.4
    g = make_slanted_edge(80, angle, 0.2, 0.8, psf=gaussian_psf(1.0), orientation=orientation)  # type: ignore[arg-type]
    move = (0.0, d) if orientation == "vertical" else (d, 0.0)
    r = nd_shift(g, move, order=5, mode="nearest")
    res = lateral_color_edge(np.stack([r, g, g], axis=-1))
    assert res.r_minus_g_px == pytest.approx(d * math.cos(math.radians(angle)), abs=0.01)
    assert res.b_minus_g_px == pytest.approx(0.0, abs=1e-9)
    nx, ny = res.normal_xy
    assert (nx if orientation == "vertical" else ny) > 0.99


def area_sampled_spot(n: int, cx: float, cy: float, sigma: float) -> np.ndarray:
    """A Gaussian spot integrated exactly over each pixel (centre (cx, cy), pixels)."""

    def axis(c: float) -> np.ndarray:
        edges = np.arange(n + 1) - 0.5
        cdf = 0.5 * (1 + erf((edges - c) / (math.sqrt(2) * sigma)))
        return np.diff(cdf)

    return np.outer(axis(cy), axis(cx))


def test_point_shifts_recovered() -> None:
    """Spots with R at (+0.3, -0.2) and B at (-0.5, +0.4) px from G, different widths, a
    background of 0.05 and noise 1e-4 on a peak of about 0.1: shifts within 0.05 px, the
    edge brief's bound (measured 0.004 px with this seed, <= 0.023 px over 10 seeds: the
    noise inside the centroid window); the radial projection is the dot product."""
    cx, cy = 20.3, 19.8
    spots = [
        area_sampled_spot(41, cx + 0.3, cy - 0.2, 1.6),
        area_sampled_spot(41, cx, cy, 1.2),
        area_sampled_spot(41, cx - 0.5, cy + 0.4, 1.9),
    ]
    img = np.stack(spots, axis=-1) + 0.05 + np.random.default_rng(3).normal(0.0, 1e-4, (41, 41, 3))
    res = lateral_color_point(img)
    assert res.r_minus_g_xy == pytest.approx([0.3, -0.2], abs=0.05)
    assert res.b_minus_g_xy == pytest.approx([-0.5, 0.4], abs=0.05)
    assert res.centroids_xy[1] == pytest.approx([cx, cy], abs=0.05)
    radial = res.along((3.0, 4.0))
    assert radial == pytest.approx(res.shifts_xy @ np.array([0.6, 0.8]), abs=1e-12)
    assert radial[0] == pytest.approx((0.3 * 3 - 0.2 * 4) / 5, abs=0.05)
    assert radial[2] == pytest.approx((-0.5 * 3 + 0.4 * 4) / 5, abs=0.05)


def test_errors() -> None:
    edge = make_slanted_edge(60, 5.0, 0.0, 1.0)
    with pytest.raises(InputError, match="C >= 2"):
        lateral_color_edge(edge)
    flat_blue = np.stack([edge, edge, np.full_like(edge, 0.5)], axis=-1)
    with pytest.raises(InputError, match=r"region\[\.\.\., 2\]: no edge found") as info:
        lateral_color_edge(flat_blue)
    assert "\n" not in str(info.value)
    with pytest.raises(InputError, match="reference"):
        lateral_color_edge(np.stack([edge, edge, edge], axis=-1), reference=3)
    noise = np.random.default_rng(0).normal(0.5, 0.01, (31, 31, 3))
    with pytest.raises(InputError, match="no point found"):
        lateral_color_point(noise)
    res = lateral_color_point(np.stack([area_sampled_spot(21, 10, 10, 1.0)] * 2, axis=-1))
    with pytest.raises(InputError, match="no blue channel"):
        _ = res.b_minus_g_xy
    with pytest.raises(InputError, match="direction_xy"):
        res.along((0.0, 0.0))
