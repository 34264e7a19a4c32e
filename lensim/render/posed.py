"""Rendering a lens with poses (decentred or tilted elements, a tilted sensor) on the frame.

A PSF bank holds a lens's PSFs along +y and turns them to every azimuth
(lensim.psf.bank.azimuth), exact for a rotationally symmetric lens only. A lens with poses
is rendered instead through posed_banks: one bank per quadrant of the sensor, the lens
turned to that quadrant's diagonal (lensim.calibrate.tolerance_report.lens_at_azimuth),
and one of that turned lens mirrored (key + MIRROR) for the pixels where a bank takes its
kernel mirrored (mirrored_pixels). Every pixel then takes the image of its source
(pixel_sources): the quadrant of the sensor it lies in (by the signs of its sensor
position, so a frame anywhere on the sensor, a training crop included, is split where
the optical axis splits it), mirrored or not. compose_quadrants composes images already
rendered; compose_rendered renders only the sources that have pixels in the frame.

sensor_banks is the one rule every command follows: a lens with poses gets its posed
banks (over the whole sensor), any other lens its one bank; pairs made through posed
banks record them (the pairs manifest's "posed_banks"), and their Wiener stage, their
oracles and a restoration of their lens use them (lensim.evaluate.harness.record_banks).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, TypeVar

import numpy as np
import torch

if TYPE_CHECKING:
    from lensim.optics.lens import Lens
    from lensim.render.mapping import SensorMapping
    from lensim.sensor.profile import SensorProfile

#: the sensor's quadrants: (bottom half?, right half?), named by their corner
QUADRANTS = {"ur": (0, 1), "lr": (1, 1), "ul": (0, 0), "ll": (1, 0)}
#: the key suffix of a quadrant's bank of the mirrored lens (posed_banks)
MIRROR = "/mirror"
#: an image: (C, H, W) numpy array or torch tensor
Image = TypeVar("Image", np.ndarray, torch.Tensor)
#: what bank_of gives: a PSFBank, or anything standing for one (an index, a folder)
Bank = TypeVar("Bank")


def quadrant_azimuths(mapping: SensorMapping) -> dict[str, float]:
    """The azimuth (deg, counter-clockwise from +y) of each quadrant's outer corner of the
    frame the mapping places on the sensor (the whole sensor's mapping gives the
    sensor's diagonals)."""
    p = mapping.pitch_um * 1e-3
    out = {}
    for key, (row, col) in QUADRANTS.items():
        x = mapping.x0_mm + col * (mapping.width - 1) * p
        y = mapping.y0_mm + row * (mapping.height - 1) * p
        out[key] = math.degrees(math.atan2(-x, y))
    return out


def _pixel_mm(mapping: SensorMapping) -> tuple[np.ndarray, np.ndarray]:
    """The pixel centres' sensor x (1, W) and y (H, 1) in mm, broadcasting to (H, W)
    (a 24 MP frame's full grids would be 0.8 GB of temporaries)."""
    p = mapping.pitch_um * 1e-3
    cols, rows = np.arange(mapping.width)[None, :], np.arange(mapping.height)[:, None]
    return mapping.x0_mm + (cols + 0.5) * p, mapping.y0_mm + (rows + 0.5) * p


def mirrored_pixels(mapping: SensorMapping) -> np.ndarray:
    """(H, W) bool: the pixels where a bank along +y takes its kernel mirrored about +y
    (lensim.psf.bank.azimuth.azimuth_turn: half of every quadrant, split by the 45-degree
    lines)."""
    from lensim.psf.bank.azimuth import mirrored_at

    x, y = _pixel_mm(mapping)
    return mirrored_at(np.degrees(np.arctan2(y, x)) - 90.0)


def pixel_sources(shape: tuple[int, int], mapping: SensorMapping | None, mirrored: bool) -> dict[str, np.ndarray]:
    """Which pixels of an (H, W) frame take which quadrant's image: key -> (H, W) bool,
    the quadrant by the sign of the pixel's sensor position (mapping; without one the
    frame's halves, the frame being the whole sensor), and with mirrored the pixels of
    mirrored_pixels under key + MIRROR instead."""
    if mapping is None:
        if mirrored:
            raise ValueError("composing mirrored quadrants needs the mapping")
        rows, cols = np.mgrid[: shape[0], : shape[1]]
        bottom, right = rows >= shape[0] // 2, cols >= shape[1] // 2
    else:
        x, y = _pixel_mm(mapping)
        bottom, right = y > 0, x > 0
    flip = mirrored_pixels(mapping) if mirrored and mapping is not None else np.zeros(shape, dtype=bool)
    out = {}
    for key, (row, col) in QUADRANTS.items():
        inside = (bottom == bool(row)) & (right == bool(col))
        out[key] = inside & ~flip
        if mirrored:
            out[key + MIRROR] = inside & flip
    return out


def compose_rendered(
    render: Callable[[str], Image], keys: Iterable[str], mapping: SensorMapping | None, shape: tuple[int, int]
) -> Image:
    """One (C, H, W) image, each pixel from the image of its source (pixel_sources;
    mirrored sources when keys hold any key + MIRROR); render(key) is called once for
    each source with pixels in the frame, only; the single key "all" is rendered as it is."""
    keys = list(keys)
    if "all" in keys:
        return render("all")
    sources = pixel_sources(shape, mapping, any(k.endswith(MIRROR) for k in keys))
    out = None
    for key, mask in sources.items():
        if not mask.any():
            continue
        image = render(key)
        if out is None:
            out = image.clone() if isinstance(image, torch.Tensor) else np.array(image, copy=True)
        m = torch.from_numpy(mask) if isinstance(image, torch.Tensor) else mask
        out[..., m] = image[..., m]
    if out is None:
        raise ValueError("an empty frame has no image")
    return out


def compose_quadrants(images: Mapping[str, np.ndarray], mapping: SensorMapping | None = None) -> np.ndarray:
    """One (3, H, W) image from one per quadrant (QUADRANTS' keys), each quadrant from
    its own, and where a quadrant's key with MIRROR is given (posed_banks) that one's
    image at mirrored_pixels (mapping: where the image lies; needed then); a single
    image under "all" is returned as it is."""
    if "all" in images:
        return images["all"]
    shape = tuple(np.shape(images["lr"])[-2:])
    return compose_rendered(lambda k: np.asarray(images[k]), images, mapping, shape)


def posed_banks(lens: Lens, mapping: SensorMapping, bank_of: Callable[[Lens], Bank]) -> dict[str, Bank]:
    """The banks that render a lens on the frame: one ("all") for a rotationally symmetric
    lens; for a lens with poses (a bank turns its +y PSFs to every azimuth) one per
    quadrant, the lens turned to the quadrant's diagonal (quadrant_azimuths of the
    mapping: give the whole sensor's), and one of that turned lens mirrored (key + MIRROR;
    lensim.calibrate.tolerance_report.mirrored_lens) for the pixels where the bank's
    kernel is taken mirrored (mirrored_pixels), so that every pixel gets the lens's own
    PSF (compose_quadrants, compose_rendered)."""
    from lensim.calibrate.tolerance_report import lens_at_azimuth, mirrored_lens

    if not lens.has_poses:
        return {"all": bank_of(lens)}
    out = {}
    for k, a in quadrant_azimuths(mapping).items():
        turned = lens_at_azimuth(lens, a)
        out[k], out[k + MIRROR] = bank_of(turned), bank_of(mirrored_lens(turned))
    return out


def sensor_banks(lens: Lens, sensor: SensorProfile, bank_of: Callable[[Lens], Bank]) -> Bank | dict[str, Bank]:
    """What renders and restores a lens on the sensor (the rule every command follows):
    bank_of(lens) for a rotationally symmetric lens; for a lens with poses (an as-built lens
    from `lensim calibrate`, a tolerance draw with decentres or tilts) its posed banks by
    source over the whole sensor (posed_banks: 8 of them), which a frame anywhere on the
    sensor composes per pixel (pixel_sources)."""
    from lensim.render.mapping import native_mapping

    banks = posed_banks(lens, native_mapping(sensor.height, sensor.width, sensor, 0, 0), bank_of)
    return banks["all"] if "all" in banks else banks
