"""Small DNG fixtures written with an independent writer (pidng), for the raw tests.

Every value a test checks is chosen here and written as plain DNG/EXIF tags, so what
lensim reads back can be compared with what was written."""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from pidng.core import RAW2DNG, DNGTags, Tag
from pidng.dng import dngIFD, dngTag

CFA_CODES = {"R": 0, "G": 1, "B": 2}
SONY_ILCE7_MATRIX = [0.5271, -0.0712, -0.0347, -0.6153, 1.3653, 0.2763, -0.1601, 0.2366, 0.7242]  # dcraw adobe_coeff


def rational(x: float, max_den: int = 1_000_000_000) -> list[int]:
    """An unsigned TIFF RATIONAL close to x (relative error ~1e-18 for x ~ 1)."""
    f = Fraction(float(x)).limit_denominator(max_den)
    return [f.numerator, f.denominator]


def srational(x: float) -> list[int]:
    f = Fraction(float(x)).limit_denominator(100_000_000)
    return [f.numerator, f.denominator]


def write_dng(
    path: Path,
    mosaic: np.ndarray,
    pattern: str = "RGGB",
    black: Sequence[float] = (512, 512, 512, 512),
    white: int = 16383,
    wb_gains: tuple[float, float] | None = (2.0, 1.5),
    color_matrix: Sequence[float] | None = SONY_ILCE7_MATRIX,
    illuminant: int = 21,
    color_matrix2: Sequence[float] | None = None,
    illuminant2: int = 17,
    orientation: int = 1,
    make: str = "Acme",
    model: str = "Model 1",
    exif: dict[str, Any] | None = None,
    active_area: Sequence[int] | None = None,
    photometric: int = 32803,
    cfa_dims: tuple[int, int] = (2, 2),
    cfa_codes: Sequence[int] | None = None,
) -> Path:
    """Write ``mosaic`` ((H, W) uint16 DN, or (H, W, 3) for LinearRaw) as an uncompressed
    DNG. black: 4 levels in CFA order (BlackLevelRepeatDim 2x2); wb_gains: (r, b) as-shot
    multipliers (AsShotNeutral = 1/gain); exif: optional focal_length_mm, fno, iso,
    exposure_s, lens, focus_distance_m, pixel_um (written to the Exif IFD, the pitch as
    FocalPlaneXResolution in pixels per mm)."""
    arr = np.ascontiguousarray(mosaic, dtype=np.uint16)
    h, w = arr.shape[:2]
    spp = 1 if arr.ndim == 2 else arr.shape[2]
    t = DNGTags()
    t.set(Tag.ImageWidth, w)
    t.set(Tag.ImageLength, h)
    t.set(Tag.TileWidth, w)
    t.set(Tag.TileLength, h)
    t.set(Tag.PhotometricInterpretation, photometric)
    t.set(Tag.SamplesPerPixel, spp)
    t.set(Tag.BitsPerSample, [16] * spp)
    t.set(Tag.Orientation, orientation)
    t.set(Tag.Make, make)
    t.set(Tag.Model, model)
    t.set(Tag.UniqueCameraModel, f"{make} {model}")
    if photometric == 32803:
        t.set(Tag.CFARepeatPatternDim, list(cfa_dims))
        t.set(Tag.CFAPattern, list(cfa_codes) if cfa_codes is not None else [CFA_CODES[c] for c in pattern])
        t.set(Tag.BlackLevelRepeatDim, [2, 2])
        t.set(Tag.BlackLevel, [int(b) for b in black])
    else:
        t.set(Tag.BlackLevel, [int(black[0])] * spp)
    t.set(Tag.WhiteLevel, [int(white)] * (1 if photometric == 32803 else spp))
    if color_matrix is not None:
        t.set(Tag.ColorMatrix1, [srational(v) for v in color_matrix])
        t.set(Tag.CalibrationIlluminant1, illuminant)
    if color_matrix2 is not None:
        t.set(Tag.ColorMatrix2, [srational(v) for v in color_matrix2])
        t.set(Tag.CalibrationIlluminant2, illuminant2)
    if wb_gains is not None:
        t.set(Tag.AsShotNeutral, [rational(1.0 / wb_gains[0]), [1, 1], rational(1.0 / wb_gains[1])])
    if active_area is not None:
        t.set(Tag.ActiveArea, list(active_area))
    if exif:
        _exif_ifd(t, exif)
    writer = RAW2DNG()
    writer.options(t, path="", compress=False)
    Path(path).write_bytes(bytes(writer.convert(arr)))
    return Path(path)


def _exif_ifd(tags: DNGTags, exif: dict[str, Any]) -> None:
    """Shooting data in an Exif IFD, as cameras write it."""
    ifd = dngIFD()
    if "exposure_s" in exif:
        ifd.tags.append(dngTag(Tag.ExposureTime, [rational(exif["exposure_s"], 100000)]))
    if "fno" in exif:
        ifd.tags.append(dngTag(Tag.FNumber, [rational(exif["fno"], 1000)]))
    if "iso" in exif:
        ifd.tags.append(dngTag(Tag.PhotographicSensitivity, [int(exif["iso"])]))
    if "focal_length_mm" in exif:
        ifd.tags.append(dngTag(Tag.FocalLength, [rational(exif["focal_length_mm"], 1000)]))
    if "focus_distance_m" in exif:
        ifd.tags.append(dngTag(Tag.SubjectDistance, [rational(exif["focus_distance_m"], 1000)]))
    if "lens" in exif:
        ifd.tags.append(dngTag(Tag.EXIFPhotoLensModel, exif["lens"]))
    if "pixel_um" in exif:
        ifd.tags.append(dngTag(Tag.FocalPlaneXResolution, [rational(1000.0 / exif["pixel_um"], 100000)]))
        ifd.tags.append(dngTag(Tag.FocalPlaneYResolution, [rational(1000.0 / exif["pixel_um"], 100000)]))
        ifd.tags.append(dngTag(Tag.FocalPlaneResolutionUnit, [4]))  # mm
    tags.__tags__[Tag.EXIF_IFD] = _IFDTag(Tag.EXIF_IFD, [ifd])


class _IFDTag(dngTag):
    """pidng 4.0.9's IFD-valued tag builds its placeholder from str (a TypeError under
    Python 3); this one uses bytes."""

    def setValue(self, value: list) -> None:
        self.Value = b"\x00\x00\x00\x00"
        self.subIFD = value[0]


def random_mosaic(h: int = 64, w: int = 96, lo: int = 0, hi: int = 4095, seed: int = 0) -> np.ndarray:
    """Distinct-looking random DN values (uint16) in [lo, hi]."""
    return np.random.default_rng(seed).integers(lo, hi + 1, (h, w)).astype(np.uint16)
