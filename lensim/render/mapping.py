"""Where an image lies on the sensor.

"Fit" (:func:`map_to_sensor`): the image is centred on the sensor and scaled to fit inside
it (the limiting side spans the sensor), so every image pixel has a physical position and
an effective pitch = sensor side / image side. "Native" (:func:`native_mapping`): image
pixels are sensor pixels, the image's top-left pixel at a given sensor pixel. Image rows
run along +y and columns along +x of the image plane, the same orientation as a PSF bank's
kernels; a bank used on a mapping must be computed at the mapping's pitch
(lensim.render.kernels.check_bank_fits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lensim.errors import InputError
from lensim.sensor.profile import SensorProfile


@dataclass(frozen=True)
class SensorMapping:
    """Where an image of height x width pixels lies on the sensor: pixel pitch (um) and the
    sensor position (mm, relative to the optical axis) of the image's top-left corner."""

    height: int
    width: int
    pitch_um: float
    x0_mm: float
    y0_mm: float

    def pixel_to_mm(self, rows: torch.Tensor, cols: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sensor position (x, y) in mm of pixel centres; rows, cols any shape (pixels)."""
        p = self.pitch_um * 1e-3
        return self.x0_mm + (cols + 0.5) * p, self.y0_mm + (rows + 0.5) * p

    @property
    def half_diagonal_mm(self) -> float:
        """Distance (mm) of the image corner farthest from the axis."""
        p = self.pitch_um * 1e-3
        xs = (self.x0_mm, self.x0_mm + self.width * p)
        ys = (self.y0_mm, self.y0_mm + self.height * p)
        return max(math.hypot(x, y) for x in xs for y in ys)


def map_to_sensor(height: int, width: int, sensor: SensorProfile) -> SensorMapping:
    """Fit an image inside the sensor, centred; the limiting side spans the sensor, and the
    effective pitch is that side's length over the image's pixels."""
    sw, sh = sensor.sensor_size_mm
    pitch_mm = min(sw / width, sh / height)
    return SensorMapping(height, width, pitch_mm * 1e3, -width * pitch_mm / 2.0, -height * pitch_mm / 2.0)


def native_mapping(height: int, width: int, sensor: SensorProfile, top: int, left: int) -> SensorMapping:
    """An image (or crop) whose pixels are sensor pixels, its top-left pixel at sensor pixel
    (top, left)."""
    if not (0 <= top <= sensor.height - height and 0 <= left <= sensor.width - width):
        raise InputError(
            sensor.name,
            "resolution",
            f"a {width}x{height} crop at ({left}, {top}) does not fit on the {sensor.width}x{sensor.height} sensor",
        )
    p = sensor.pixel_pitch_um * 1e-3
    return SensorMapping(
        height, width, sensor.pixel_pitch_um, (left - sensor.width / 2.0) * p, (top - sensor.height / 2.0) * p
    )
