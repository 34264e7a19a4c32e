"""Camera raw files: reading them (rawpy/LibRaw) and developing them with the simulator's
own chain.

- :func:`read_raw(path) -> RawImage <lensim.raw.read.read_raw>`: the Bayer mosaic of the
  active area and its metadata. :class:`RawImage` fields: ``path``; ``mosaic`` (H, W)
  uint16 DN; ``cfa_pattern`` ('RGGB' | 'BGGR' | 'GRBG' | 'GBRG'); ``black_level`` (4 DN,
  CFA order); ``white_level`` (DN); ``as_shot_wb_gains`` ((r, 1, b) or None);
  ``color_matrix`` (3x3 XYZ -> camera or None) with ``color_matrix_illuminant`` (DNG
  CalibrationIlluminant code, 21 = D65) and ``color_matrices`` (every DNG ColorMatrix with
  its illuminant); ``orientation`` (EXIF 1..8); ``is_dng``; ``make``, ``model``, ``lens``;
  ``focal_length_mm``, ``fno``, ``focus_distance_m``, ``iso``, ``exposure_s``,
  ``pixel_pitch_um`` (None when absent); properties ``width``, ``height``, ``camera``;
  ``info()`` (the `lensim raw info --json` mapping).
- :func:`raw_files(paths) <lensim.raw.read.raw_files>`: files as given, folders expanded
  to their raw files.
- :func:`develop_raw(raw, sensor=None, wb="as-shot", method="ahd", bits=None, orient=True)
  <lensim.raw.develop.develop_raw>` -> (sRGB (3, H, W) float32 in [0, 1], CaptureParams):
  the simulator's chain on the real mosaic (:func:`normalized_mosaic
  <lensim.raw.develop.normalized_mosaic>` -> ``lensim.sensor.isp.raw_to_srgb`` ->
  :func:`apply_orientation <lensim.raw.develop.apply_orientation>`); ``orient=False``
  keeps the sensor's pixel order (for field-dependent work), orient afterwards with
  ``apply_orientation(img, raw.orientation)``. :func:`capture_params
  <lensim.raw.develop.capture_params>` gives the CaptureParams alone (CCM and WB table
  from ``sensor``, else from the raw's colour matrix).
- :func:`develop_files <lensim.raw.develop.develop_files>`: a batch into OUT/<stem>.tif
  (`lensim develop`).
- :func:`sensor_from_raw <lensim.raw.profile.sensor_from_raw>`: a sensor profile for the
  camera that wrote a raw file (`lensim sensor from-raw`).
"""

from lensim.raw.develop import (
    apply_orientation,
    capture_params,
    develop_files,
    develop_raw,
    normalized_mosaic,
)
from lensim.raw.read import RAW_SUFFIXES, RawImage, raw_files, read_raw

__all__ = [
    "RAW_SUFFIXES",
    "RawImage",
    "apply_orientation",
    "capture_params",
    "develop_files",
    "develop_raw",
    "normalized_mosaic",
    "raw_files",
    "read_raw",
]
