"""A sensor profile (lensim.sensor.profile's format) from a camera raw file.

:func:`profile_dict_from_raw` fills every field a profile needs:

- geometry: the active area (width x height, rounded down to whole Bayer quads) at the
  pixel pitch given, else EXIF FocalPlaneXResolution's;
- CFA pattern, white level, black level (the mean of the 4 CFA positions' levels; the
  develop chain uses each position's own level from the file) and the ADC bit depth
  (the bits the white level needs);
- colour: the CCM from the file's colour matrix and the white-balance table over
  :data:`WB_KELVINS`, both as lensim.sensor.calibration derives the built-in profiles'
  (Brooks et al. 2019's CCM construction; the table's temperature dependence from the NPL
  Nikon D5100 sensitivities, scaled to the matrix's D65 gains);
- noise: estimated from a dark frame and flat fields (:mod:`lensim.raw.noise`) when given,
  else :data:`DEFAULT_NOISE`, the built-in profiles' ranges (Brooks et al. 2019).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lensim.errors import InputError, ParameterError
from lensim.raw.read import RawImage
from lensim.sensor.profile import SensorProfile, sensor_from_dict

WB_KELVINS = (2500.0, 2856.0, 3200.0, 3500.0, 4000.0, 4500.0, 5000.0, 5500.0, 6000.0, 6504.0, 7500.0, 9000.0)
KELVIN_RANGE = (2856.0, 7500.0)
SPECTRAL_STAND_IN = "Nikon 5100 (NPL)"
DEFAULT_NOISE: dict[str, Any] = {
    "shot": [1.0e-4, 3.0e-3],
    "read_from_shot": {"slope": 2.18, "intercept": 1.20, "sigma": 0.26},
}


def ccm_from_raw(raw: RawImage) -> list[list[float]]:
    """CCM (camera RGB -> linear sRGB, rows summing to 1) from the raw's colour matrix, by
    Brooks et al. 2019's construction (lensim.sensor.calibration); numpy only."""
    from lensim.sensor.calibration import ccm_from_dng_color_matrix

    if raw.color_matrix is None:
        raise InputError(
            raw.path,
            "color_matrix",
            "the file has no colour matrix (LibRaw does not know this camera); give a sensor profile (`sensor`)",
        )
    ccm, _, _ = ccm_from_dng_color_matrix(np.asarray(raw.color_matrix))
    return [[float(v) for v in row] for row in ccm]


def _colour(raw: RawImage) -> tuple[list[list[float]], list[dict]]:
    """(CCM, white-balance table over WB_KELVINS) from the raw's colour matrix (the table
    needs colour-science: about a second to import)."""
    from lensim.sensor.calibration import wb_table

    ccm = ccm_from_raw(raw)  # raises when the file has no colour matrix
    return ccm, wb_table(list(WB_KELVINS), np.asarray(raw.color_matrix), SPECTRAL_STAND_IN)


def _pitch_um(raw: RawImage, pixel_pitch_um: float | None) -> float:
    pitch = pixel_pitch_um if pixel_pitch_um is not None else raw.pixel_pitch_um
    if pitch is None:
        raise InputError(
            raw.path,
            "pixel pitch",
            "the file gives no pixel pitch (EXIF FocalPlaneXResolution); give it (`pixel_pitch_um`)",
        )
    if not (math.isfinite(pitch) and pitch > 0):
        raise ParameterError(None, "pixel_pitch_um", f"expected a positive pixel pitch in micrometres, got {pitch!r}")
    return float(pitch)


def profile_dict_from_raw(
    raw: RawImage, pixel_pitch_um: float | None = None, noise: dict[str, Any] | None = None, name: str | None = None
) -> dict[str, Any]:
    """The sensor profile mapping (file format of lensim.sensor.profile) for the camera
    that wrote ``raw``. ``pixel_pitch_um`` overrides the EXIF pitch (one of them is
    required); ``noise`` is a profile noise mapping (default :data:`DEFAULT_NOISE`)."""
    pitch = _pitch_um(raw, pixel_pitch_um)
    ccm, table = _colour(raw)
    width, height = raw.width - raw.width % 2, raw.height - raw.height % 2
    bit_depth = min(16, max(8, math.ceil(math.log2(raw.white_level + 1))))
    black = sum(raw.black_level) / 4.0
    pitch_from = "the one given" if pixel_pitch_um is not None else "EXIF FocalPlaneXResolution"
    return {
        "name": name or raw.camera,
        "description": f"Made by lensim sensor from-raw from {raw.path} ({raw.camera}, active area "
        f"{raw.width} x {raw.height} px).",
        "source": f"Geometry: the file's active area, pitch from {pitch_from}. CFA, levels: the file (black level "
        f"per CFA position {list(raw.black_level)}, mean stored). CCM: the file's colour matrix (XYZ -> "
        "camera, illuminant code "
        f"{raw.color_matrix_illuminant}) by Brooks et al. 2019's construction (lensim.sensor.calibration). "
        f"White balance: {SPECTRAL_STAND_IN} sensitivities scaled to the matrix's D65 gains. Noise: "
        + (
            "estimated from dark/flat frames."
            if noise is not None
            else "lensim's defaults (Brooks et al. 2019 ranges), not measured."
        ),
        "pixel_pitch_um": pitch,
        "resolution": [width, height],
        "bayer_pattern": raw.cfa_pattern,
        "spectral_response": SPECTRAL_STAND_IN,
        "ccm": ccm,
        "white_balance": table,
        "kelvin_range": list(KELVIN_RANGE),
        "black_level": black,
        "white_level": raw.white_level,
        "bit_depth": bit_depth,
        "noise": noise if noise is not None else DEFAULT_NOISE,
    }


def sensor_from_raw(
    raw: RawImage, pixel_pitch_um: float | None = None, noise: dict[str, Any] | None = None, name: str | None = None
) -> SensorProfile:
    """The validated :class:`SensorProfile` of :func:`profile_dict_from_raw`."""
    return sensor_from_dict(profile_dict_from_raw(raw, pixel_pitch_um, noise, name), source=raw.path)
