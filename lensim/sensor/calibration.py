"""Derivations behind the colour numbers of the built-in sensor profiles.

The built-in profiles (lensim/assets/sensors/*.yaml) store plain numbers; this module
recomputes them from their public sources, so each number can be checked
(tests/test_sensor.py does) and a profile for another camera can be made the same way.

- :func:`ccm_from_dng_color_matrix`: Adobe DNG ``ColorMatrix`` (XYZ -> camera, the D65
  matrix that dcraw/LibRaw tabulate as ``adobe_coeff`` integers / 10000) to a camera RGB
  -> linear sRGB colour correction matrix whose rows sum to 1, exactly as Brooks et al.
  2019 ("Unprocessing images for learned raw denoising", CVPR) do: rgb2cam = xyz2cam @
  rgb2xyz(sRGB, D65), each row normalized to sum to 1, ccm = inverse(rgb2cam). Also
  returns the D65 white-balance gains implied by the matrix (green / red and green /
  blue of the camera's response to the D65 white).
- :func:`wb_gains_from_sensitivities`: white-balance gains at given colour temperatures
  from measured camera spectral sensitivities (colour-science's
  ``MSDS_CAMERA_SENSITIVITIES``): the camera's R, G, B response to a Planckian radiator
  (T < 5000 K) or a CIE daylight illuminant (T >= 5000 K, CIE D-series at the
  correlated colour temperature T), gains r = G/R and b = G/B.
- :func:`wb_table`: the table stored in a profile: the spectral gains' dependence on
  colour temperature, rescaled so that the 6504 K entry equals the D65 gains of the
  profile's DNG matrix (so the table and the CCM agree at D65).

colour-science is imported lazily (about a second).
"""

from __future__ import annotations

import numpy as np

# Linear sRGB (D65) -> CIE XYZ, IEC 61966-2-1 (the matrix Brooks et al. 2019 use).
SRGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)


def ccm_from_dng_color_matrix(color_matrix: list[float] | np.ndarray) -> tuple[np.ndarray, float, float]:
    """DNG ColorMatrix (XYZ -> camera, 9 numbers row-major or 3x3; dcraw's adobe_coeff
    integers divided by 10000) -> (ccm (3, 3) camera RGB -> linear sRGB with rows summing
    to 1, r_gain at D65, b_gain at D65)."""
    xyz2cam = np.asarray(color_matrix, dtype=np.float64).reshape(3, 3)
    rgb2cam = xyz2cam @ SRGB_TO_XYZ
    white = rgb2cam.sum(axis=1)  # camera response to the sRGB (D65) white
    rgb2cam = rgb2cam / white[:, None]
    ccm = np.linalg.inv(rgb2cam)
    return ccm, float(white[1] / white[0]), float(white[1] / white[2])


def _illuminant_spd(kelvin: float, wavelengths_nm: np.ndarray) -> np.ndarray:
    import colour

    lo, hi = float(wavelengths_nm[0]), float(wavelengths_nm[-1])
    if kelvin < 5000.0:
        sd = colour.sd_blackbody(kelvin, colour.SpectralShape(lo, hi, 1))
    else:
        # CIE D-series at CCT T: the xy formula takes the temperature on the old c2 scale.
        xy = colour.temperature.CCT_to_xy_CIE_D(kelvin * 1.4388 / 1.4380)
        sd = colour.sd_CIE_illuminant_D_series(xy)
    return np.interp(
        wavelengths_nm, np.asarray(sd.wavelengths, dtype=np.float64), np.asarray(sd.values, dtype=np.float64)
    )


def wb_gains_from_sensitivities(kelvins: list[float], camera: str = "Nikon 5100 (NPL)") -> np.ndarray:
    """(N, 2) array of (r_gain, b_gain) = (G/R, G/B) of the named colour-science camera's
    response to the illuminant at each colour temperature (K)."""
    import colour

    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    labels = [str(x).lower() for x in msds.labels]
    sens = np.asarray(msds.values, dtype=np.float64)[:, [labels.index(c) for c in ("red", "green", "blue")]]
    wl = np.asarray(msds.wavelengths, dtype=np.float64)
    out = []
    for k in kelvins:
        r, g, b = (sens * _illuminant_spd(float(k), wl)[:, None]).sum(axis=0)
        out.append((g / r, g / b))
    return np.asarray(out)


def wb_table(
    kelvins: list[float], color_matrix: list[float] | np.ndarray, camera: str = "Nikon 5100 (NPL)"
) -> list[dict]:
    """White-balance table for a profile: the spectral gains of ``camera`` at each
    colour temperature, scaled per channel so that 6504 K gives the D65 gains implied by
    the DNG ``color_matrix``. Gains rounded to 4 decimals."""
    _, r65, b65 = ccm_from_dng_color_matrix(color_matrix)
    gains = wb_gains_from_sensitivities(list(kelvins), camera)
    ref = wb_gains_from_sensitivities([6504.0], camera)[0]
    scale = np.array([r65 / ref[0], b65 / ref[1]])
    return [
        {"kelvin": float(k), "r_gain": round(float(g[0] * scale[0]), 4), "b_gain": round(float(g[1] * scale[1]), 4)}
        for k, g in zip(kelvins, gains)
    ]


def dng_color_matrix_from_ccm(ccm: list[list[float]] | np.ndarray, r_gain_d65: float, b_gain_d65: float) -> np.ndarray:
    """The inverse of :func:`ccm_from_dng_color_matrix`: a profile's CCM (3, 3; white-balanced
    camera RGB -> linear sRGB, rows summing to 1) and its white-balance gains at D65 ->
    the DNG ColorMatrix (3, 3; XYZ -> camera RGB, D65 calibration illuminant).

    The CCM alone fixes the matrix up to one scale per camera channel (the row
    normalization of the forward relation); the D65 gains restore it: the camera's
    response to the D65 white (XYZ with Y = 1) is (1 / r_gain, 1, 1 / b_gain), the DNG
    convention of a neutral whose largest (green) channel is 1 for gains above 1."""
    rgb2cam = np.linalg.inv(np.asarray(ccm, dtype=np.float64).reshape(3, 3))
    white = np.array([1.0 / r_gain_d65, 1.0, 1.0 / b_gain_d65])
    return (white[:, None] * rgb2cam) @ np.linalg.inv(SRGB_TO_XYZ)
