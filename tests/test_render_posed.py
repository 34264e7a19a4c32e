"""A lens with poses rendered on the frame (lensim.render.posed): each pixel from its sensor
quadrant's image, split where the optical axis lies, only the sources the frame holds rendered."""

import numpy as np
import pytest
import torch

from lensim.render.mapping import SensorMapping
from lensim.render.posed import MIRROR, QUADRANTS, compose_rendered, mirrored_pixels, pixel_sources


def test_a_frame_off_the_centre_splits_at_the_axis_not_at_its_half():
    # 4 x 6 pixels of 1 mm, x from -1 to 5 mm: the axis lies after the first column
    mapping = SensorMapping(4, 6, 1000.0, -1.0, -2.0)
    src = pixel_sources((4, 6), mapping, mirrored=False)
    assert src["ul"][0, 0] and src["ur"][0, 1] and src["ur"][1, 5] and src["lr"][2, 1] and src["ll"][3, 0]
    assert sum(m.astype(int) for m in src.values()).tolist() == np.ones((4, 6), dtype=int).tolist()
    with_mirror = pixel_sources((4, 6), mapping, mirrored=True)
    flip = mirrored_pixels(mapping)
    assert (with_mirror["lr" + MIRROR] == (src["lr"] & flip)).all()
    with pytest.raises(ValueError):
        pixel_sources((4, 6), None, mirrored=True)


def test_only_the_sources_with_pixels_in_the_frame_are_rendered():
    # a training crop inside the lower-right quadrant: its bank and its mirrored lens's only
    mapping = SensorMapping(4, 6, 1000.0, 1.0, 2.0)
    asked = []

    def render(key):
        asked.append(key)
        return torch.full((3, 4, 6), float(list(QUADRANTS).index(key.split("/")[0]) + (10 if MIRROR in key else 0)))

    keys = [k + m for k in QUADRANTS for m in ("", MIRROR)]
    out = compose_rendered(render, keys, mapping, (4, 6))
    assert sorted(asked) == ["lr", "lr" + MIRROR]
    flip = torch.from_numpy(mirrored_pixels(mapping))
    assert isinstance(out, torch.Tensor) and (out[0] == torch.where(flip, 11.0, 1.0)).all()


def test_mirrored_pixels_are_azimuth_turns_mirror_flag_elementwise():
    """mirrored_pixels (numpy) gives, pixel by pixel, what azimuth_turn (one offset at a
    time) says, on a frame across the axis, the 45-degree lines included."""
    from lensim.psf.bank.azimuth import azimuth_turn, mirrored_at

    mapping = SensorMapping(41, 37, 1000.0, -18.5, -20.5)  # pixel centres on the axes and diagonals
    x = mapping.x0_mm + (np.arange(37) + 0.5)
    y = mapping.y0_mm + (np.arange(41) + 0.5)
    yy, xx = np.meshgrid(y, x, indexing="ij")
    offsets = np.degrees(np.arctan2(yy, xx)) - 90.0
    want = np.array([[azimuth_turn(float(a))[2] for a in row] for row in offsets])
    assert (mirrored_pixels(mapping) == want).all() and want.any() and not want.all()
    angles = np.array([-720.0, -405.0, -225.0, -135.0, -45.0, -0.0, 0.0, 45.0, 135.0, 225.0, 315.0, 540.0, 1e-9])
    assert mirrored_at(angles).tolist() == [azimuth_turn(float(a))[2] for a in angles]
