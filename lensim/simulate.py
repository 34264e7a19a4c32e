"""Imaging simulation: a sharp sRGB photo -> what the camera would deliver (the paper's
"Imaging Simulation Pipeline", Eq. 11).

Stages: unprocess to the energy domain (inverse sRGB curve, inverse CCM, inverse white
balance at a random colour temperature), spatially-variant blur with the PSF bank
(lensim.render.blur: seam-free blend of per-tile kernels rotated to their azimuth; the
kernels carry lateral colour and, optionally, relative illumination), Bayer mosaic,
heteroscedastic shot + read noise, ADC, demosaic (AHD by default), white balance, CCM and
sRGB curve (lensim.sensor.isp).

Mapping an image onto the sensor: the image is centred on the sensor and scaled to fit
inside it (the limiting side spans the sensor), so every image pixel has a physical
position and an effective pitch = sensor side / image side. Image rows run along +y and
columns along +x of the image plane, the same orientation as the bank's kernels. The bank
must be computed at that effective pitch (`ensure_bank` does it and caches the result).
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_to_dict
from lensim.psf.bank import PSFBank, compute_bank
from lensim.render.blur import spatially_variant_blur
from lensim.sensor.isp import CaptureParams, simulate_capture
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
        """Sensor position (mm) of pixel centres."""
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
        raise InputError(sensor.name, "resolution", f"a {width}x{height} crop at ({left}, {top}) does not fit on the "
                         f"{sensor.width}x{sensor.height} sensor")
    p = sensor.pixel_pitch_um * 1e-3
    return SensorMapping(height, width, sensor.pixel_pitch_um, (left - sensor.width / 2.0) * p, (top - sensor.height / 2.0) * p)


def kernel_function(bank: PSFBank, mapping: SensorMapping, relative_illumination: bool = True) -> Callable:
    """kernel_at(rows, cols) for lensim.render.blur: the bank's RGB kernel at each pixel's
    sensor position (rotated to its azimuth); with relative_illumination False each
    channel is normalized to unit sum (no lens shading)."""
    def kernel_at(rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
        x, y = mapping.pixel_to_mm(rows, cols)
        ks = np.stack([bank.psf_at(float(a), float(b)) for a, b in zip(x.tolist(), y.tolist())]).astype(np.float64)
        if not relative_illumination:
            ks /= ks.sum(axis=(-2, -1), keepdims=True)
        return torch.from_numpy(ks)
    return kernel_at


def check_bank_fits(bank: PSFBank, mapping: SensorMapping, source: str = "<bank>") -> None:
    """The bank must be at the mapping's pitch and cover the image's half-diagonal."""
    if abs(bank.pixel_pitch_um / mapping.pitch_um - 1.0) > 1e-6:
        raise InputError(source, "pixel_pitch_um", f"the bank is at {bank.pixel_pitch_um:.6g} um but the image maps onto "
                         f"the sensor at {mapping.pitch_um:.6g} um per pixel; expected a bank computed at that pitch")
    r_max = float(bank.radii_mm[-1])
    if mapping.half_diagonal_mm > r_max * (1 + 1e-6) + 0.5 * mapping.pitch_um * 1e-3:
        raise InputError(source, "fields", f"the image's corners lie {mapping.half_diagonal_mm:.4g} mm off axis but the bank "
                         f"(the lens's field) reaches {r_max:.4g} mm; expected a lens covering the sensor diagonal")


def apply_distortion(cam: torch.Tensor, bank: PSFBank, mapping: SensorMapping) -> torch.Tensor:
    """Warp an image (C, H, W) as the lens distorts it: the pixel at real image radius r
    shows the scene point whose paraxial (undistorted) image radius r' has its real chief
    ray at r. r(r') comes from the bank's stored chief-ray and paraxial points (primary
    wavelength; lateral colour stays in the kernels). Bilinear resampling, edge values
    repeated outside the image."""
    import torch.nn.functional as F

    r_real = np.array([float(np.hypot(*f.reference_xy_mm)) for f in bank.fields])
    r_par = np.array([float(np.hypot(*f.paraxial_xy_mm)) for f in bank.fields])
    c, h, w = cam.shape
    rows = torch.arange(h, dtype=torch.float64).unsqueeze(1).expand(h, w)
    cols = torch.arange(w, dtype=torch.float64).unsqueeze(0).expand(h, w)
    x, y = mapping.pixel_to_mm(rows, cols)
    r = torch.sqrt(x * x + y * y)
    r_src = torch.from_numpy(np.interp(r.numpy().ravel(), r_real, r_par).reshape(h, w))
    scale = torch.where(r > 0, r_src / r.clamp_min(1e-12), torch.ones_like(r))
    p = mapping.pitch_um * 1e-3
    src_col = (x * scale - mapping.x0_mm) / p - 0.5
    src_row = (y * scale - mapping.y0_mm) / p - 0.5
    grid = torch.stack([src_col / (w - 1) * 2 - 1, src_row / (h - 1) * 2 - 1], -1).unsqueeze(0).to(cam.dtype)
    return F.grid_sample(cam.unsqueeze(0), grid, mode="bilinear", padding_mode="border", align_corners=True)[0]


def blur_energy_image(cam: torch.Tensor, bank: PSFBank, mapping: SensorMapping, relative_illumination: bool = True,
                      tile: int = 64) -> torch.Tensor:
    """Spatially-variant blur of an energy-domain (3, H, W) image with the bank."""
    return spatially_variant_blur(cam, kernel_function(bank, mapping, relative_illumination), tile=tile)


def simulate(
    image: torch.Tensor,
    bank: PSFBank,
    sensor: SensorProfile,
    generator: torch.Generator | None = None,
    blur: bool = True,
    noise: bool = True,
    relative_illumination: bool = True,
    demosaic: str = "ahd",
    bits: int | None = 8,
    kelvin: float | None = None,
    tile: int = 64,
    mapping: SensorMapping | None = None,
    raw_path: str | Path | None = None,
    distortion: bool = False,
) -> tuple[torch.Tensor, CaptureParams]:
    """What the camera would deliver for a sharp sRGB image (3, H, W) in [0, 1].

    mapping: where the image lies on the sensor (default: fitted to the whole sensor).
    raw_path: also write the noisy, quantized Bayer mosaic there (16-bit TIFF + JSON).
    distortion: also warp the image by the lens's distortion (off by default, so training
    pairs stay pixel-aligned with their targets).
    Returns the simulated sRGB image (3, H, W) float32 and every random draw (colour
    temperature, noise levels) in CaptureParams; the same generator state gives the same
    result."""
    _, h, w = image.shape
    mapping = mapping or map_to_sensor(h, w, sensor)
    if blur or distortion:
        if bank is None:
            raise InputError("<simulate>", "bank", "blur and distortion need a PSF bank")
        check_bank_fits(bank, mapping, str(bank.directory or "<bank>"))

    def hook(cam: torch.Tensor) -> torch.Tensor:
        if distortion:
            cam = apply_distortion(cam, bank, mapping)
        return blur_energy_image(cam, bank, mapping, relative_illumination, tile) if blur else cam

    if raw_path is None:
        out, params = simulate_capture(image, sensor, generator, blur=hook if (blur or distortion) else None, noise=noise,
                                       kelvin=kelvin,
                                       method=demosaic, bits=bits)
    else:
        from lensim.sensor.isp import add_noise, mosaic, quantize_raw, raw_to_srgb, unprocess, write_raw_tiff

        # the same stages and draw order as simulate_capture, keeping the mosaic
        cam, params = unprocess(image, sensor, generator, kelvin)
        cam = hook(cam)
        raw = mosaic(cam, sensor.bayer_pattern)
        if noise:
            params.shot, params.read = sensor.sample_noise(generator)
            raw = add_noise(raw, params.shot, params.read, generator)
        raw = quantize_raw(raw, sensor)
        write_raw_tiff(raw_path, raw, sensor, params)
        out = raw_to_srgb(raw, params, method=demosaic, bits=bits)
    params.extra.update({"pitch_um": mapping.pitch_um, "x0_mm": mapping.x0_mm, "y0_mm": mapping.y0_mm,
                         "distortion": distortion,
                         "relative_illumination": relative_illumination,
                         "blur": blur, "demosaic": demosaic})
    return out, params


def suggest_kernel_pixels(lens: Lens, pitch_um: float, limit: int = 99) -> int:
    """An odd kernel size (pixels) holding the polychromatic spot at every field: twice the
    radius (about the primary chief ray) that holds 98 % of the traced rays at the worst
    field (400-700 nm, fields 0..1), plus 3 Airy radii of margin for diffraction, at least
    7 and at most `limit`."""
    from lensim.optics.aiming import generate_rays, object_field
    from lensim.optics.paraxial import paraxial_data
    from lensim.optics.pupil import hexapolar
    from lensim.optics.trace import trace

    para = paraxial_data(lens)
    fields = [object_field(lens, f * lens.max_field, "real", para) for f in (0.0, 0.5, 0.7, 0.85, 1.0)]
    pupil = torch.cat([torch.zeros(1, 2, dtype=torch.float64), hexapolar(8)])
    rays, wl = generate_rays(lens, fields, pupil, [lens.primary_wavelength_um, 0.40, 0.70], "real", para)
    res = trace(lens, rays, wl)
    chief = res.rays.position[0, :, 0, :2]  # primary wavelength
    d = torch.linalg.norm(res.rays.position[..., :2] - chief.unsqueeze(0).unsqueeze(2), dim=-1)
    reach_um = 0.0
    for fi in range(len(fields)):
        ok = res.rays.valid[:, fi]
        if bool(ok.any()):
            reach_um = max(reach_um, float(torch.quantile(d[:, fi][ok], 0.98)) * 1e3)
    reach_um += 3 * 1.22 * 0.7 * para.working_fno
    p = 2 * math.ceil(reach_um / pitch_um) + 1
    return int(min(max(p, 7), limit if limit % 2 else limit - 1))


def bank_key(lens: Lens, pitch_um: float, kernel_pixels: int, settings: dict) -> str:
    """A short hash naming a cached bank: the lens as a native mapping, pitch, kernel and
    every other bank setting."""
    blob = json.dumps({"lens": lens_to_dict(lens), "pitch_um": round(pitch_um, 9), "kernel": kernel_pixels, **settings},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def ensure_bank(lens: Lens, pitch_um: float, cache_dir: str | Path, kernel_pixels: int | None = None,
                progress: Callable[[int, int], None] | None = None, **settings) -> PSFBank:
    """The bank for this lens at this pitch: loaded from cache_dir/<key> when complete,
    computed (or finished, after a kill) otherwise. settings go to compute_bank."""
    kernel_pixels = kernel_pixels or suggest_kernel_pixels(lens, pitch_um)
    key = bank_key(lens, pitch_um, kernel_pixels, settings)
    out = Path(cache_dir) / f"bank-{key}"
    return compute_bank(lens, pitch_um, kernel_pixels, out_dir=out, progress=progress, **settings)
