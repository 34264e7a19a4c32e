"""Imaging simulation: a sharp sRGB photo -> what the camera would deliver (the paper's
"Imaging Simulation Pipeline", Eq. 11).

The capture stages, listed once in :func:`simulate_capture`: unprocess to the energy
domain (inverse sRGB curve, inverse CCM, inverse white balance at a random colour
temperature), the lens (a ``blur`` hook: here the spatially-variant blur with the PSF bank,
lensim.render.blur, and optionally the distortion warp), Bayer mosaic, heteroscedastic
shot + read noise, ADC, then the develop chain (demosaic, AHD by default, white balance,
CCM, sRGB curve; lensim.sensor.isp.raw_to_srgb). The raw mosaic is handed to an ``on_raw``
hook after the ADC (e.g. :func:`dng_writer`: a CFA DNG, lensim.raw.dng), so writing raw
output never repeats the stages.

Where the image lies on the sensor: lensim.render.mapping; kernels from the bank:
lensim.render.kernels; the bank itself (cached): lensim.psf.bank.get_bank.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from lensim.errors import InputError
from lensim.render.blur import spatially_variant_blur
from lensim.render.distortion import apply_distortion
from lensim.render.kernels import check_bank_fits, kernel_function
from lensim.render.mapping import SensorMapping, map_to_sensor
from lensim.render.posed import compose_rendered
from lensim.sensor.isp import CaptureParams, add_noise, mosaic, quantize_raw, raw_to_srgb, unprocess
from lensim.sensor.profile import SensorProfile

if TYPE_CHECKING:
    from lensim.psf.bank import PSFBank

#: Called with the normalized raw mosaic (H, W) float32 after the ADC and the capture's
#: draws so far (the develop chain has not run yet).
RawHook = Callable[[torch.Tensor, CaptureParams], None]


def simulate_capture(
    img: torch.Tensor,
    profile: SensorProfile,
    generator: torch.Generator | None = None,
    blur: Callable[[torch.Tensor], torch.Tensor] | None = None,
    noise: bool = True,
    kelvin: float | None = None,
    method: str = "ahd",
    bits: int | None = 8,
    adc: bool = True,
    on_raw: RawHook | None = None,
) -> tuple[torch.Tensor, CaptureParams]:
    """sRGB image (3, H, W) -> what the camera delivers (3, H, W) sRGB, with every draw
    recorded: unprocess (random colour temperature unless ``kelvin``), ``blur`` (a function
    of the energy-domain camera RGB image, e.g. the spatially-variant PSF convolution;
    None: no blur), mosaic, noise drawn from the profile (when ``noise``), the ADC
    (:func:`~lensim.sensor.isp.quantize_raw`, when ``adc``), ``on_raw`` (when given), then
    :func:`~lensim.sensor.isp.raw_to_srgb`.
    Draw order with the generator: colour temperature, then (shot, read), then the noise."""
    cam, params = unprocess(img, profile, generator, kelvin)
    if blur is not None:
        cam = blur(cam)
    raw = mosaic(cam, profile.bayer_pattern)
    if noise:
        params.shot, params.read = profile.sample_noise(generator)
        raw = add_noise(raw, params.shot, params.read, generator)
    if adc:
        raw = quantize_raw(raw, profile)
    if on_raw is not None:
        on_raw(raw, params)
    return raw_to_srgb(raw, params, method=method, bits=bits), params


def dng_writer(path: str | Path, sensor: SensorProfile, mapping: SensorMapping | None = None) -> RawHook:
    """An ``on_raw`` hook writing the mosaic as a CFA DNG that LibRaw and raw converters
    open (lensim.raw.dng.write_capture_dng: the sensor's pattern, levels, colour matrix and
    names, the capture's white balance, and where the frame lies on the sensor)."""
    from lensim.raw.dng import write_capture_dng

    def write(raw: torch.Tensor, params: CaptureParams) -> None:
        write_capture_dng(path, raw, sensor, params, mapping)

    return write


def blur_energy_image(
    cam: torch.Tensor, bank: PSFBank, mapping: SensorMapping, relative_illumination: bool = True, tile: int = 64
) -> torch.Tensor:
    """Spatially-variant blur of an energy-domain (3, H, W) image with the bank; tile is the
    spacing of the kernels' grid (pixels)."""
    return spatially_variant_blur(cam, kernel_function(bank, mapping, relative_illumination), tile=tile)


def simulate(
    image: torch.Tensor,
    bank: PSFBank | Mapping[str, PSFBank],
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
    on_raw: RawHook | None = None,
) -> tuple[torch.Tensor, CaptureParams]:
    """What the camera would deliver for a sharp sRGB image (3, H, W) in [0, 1].

    bank: a PSF bank, or the banks of a lens with poses (lensim.render.posed.posed_banks:
    each pixel blurred through its quadrant's, mirrored or not; no distortion then).
    mapping: where the image lies on the sensor (default: fitted to the whole sensor).
    raw_path: also write the noisy, quantized Bayer mosaic there (a CFA DNG, :func:`dng_writer`);
    on_raw: any other raw hook (not both).
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
        for one in bank.values() if isinstance(bank, Mapping) else [bank]:
            check_bank_fits(one, mapping, str(one.directory or "<bank>"))
        if distortion and isinstance(bank, Mapping):
            raise ValueError("distortion through posed banks is not modelled")
    if raw_path is not None:
        if on_raw is not None:
            raise ValueError("give raw_path or on_raw, not both")
        on_raw = dng_writer(raw_path, sensor, mapping)

    def lens(cam: torch.Tensor) -> torch.Tensor:
        if distortion:
            cam = apply_distortion(cam, bank, mapping)  # type: ignore[arg-type]
        if not blur:
            return cam
        if isinstance(bank, Mapping):
            return compose_rendered(
                lambda k: blur_energy_image(cam, bank[k], mapping, relative_illumination, tile),
                bank,
                mapping,
                (cam.shape[-2], cam.shape[-1]),
            )
        return blur_energy_image(cam, bank, mapping, relative_illumination, tile)

    out, params = simulate_capture(
        image,
        sensor,
        generator,
        blur=lens if (blur or distortion) else None,
        noise=noise,
        kelvin=kelvin,
        method=demosaic,
        bits=bits,
        on_raw=on_raw,
    )
    params.extra.update(
        {
            "pitch_um": mapping.pitch_um,
            "x0_mm": mapping.x0_mm,
            "y0_mm": mapping.y0_mm,
            "distortion": distortion,
            "relative_illumination": relative_illumination,
            "blur": blur,
            "demosaic": demosaic,
        }
    )
    return out, params
