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
"""
from lensim.raw.read import RAW_SUFFIXES, RawImage, raw_files, read_raw

__all__ = ["RAW_SUFFIXES", "RawImage", "raw_files", "read_raw"]
