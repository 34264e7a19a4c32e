"""Reading camera raw files (DNG and the vendor formats LibRaw reads) with their metadata.

:func:`read_raw` opens a file with rawpy (LibRaw) and returns a :class:`RawImage`: the
Bayer mosaic of the active area (masked margins excluded), the CFA pattern, black level
per CFA position, white level, as-shot white balance, the camera colour matrix,
orientation and the EXIF shooting data. For TIFF-based files (DNG, CR2, NEF, ARW, PEF,
...) tags rawpy does not expose (Make, Model, ISO in IFD0, SubjectDistance,
FocalPlaneXResolution, the DNG ColorMatrix1/2 with their illuminants) are read with
tifffile. Anything that is not an RGB Bayer mosaic (X-Trans, Foveon, monochrome,
already-demosaiced LinearRaw DNG, CMYG) is refused with one line naming the file and
what was found; so are files that are missing, folders, other image types and
truncated raws.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lensim.errors import InputError
from lensim.raw.exif import Exif
from lensim.sensor.cfa import BAYER_PATTERNS, CfaPattern, cfa_pattern

RAW_SUFFIXES = (
    ".dng",
    ".cr2",
    ".cr3",
    ".crw",
    ".nef",
    ".nrw",
    ".arw",
    ".srf",
    ".sr2",
    ".raf",
    ".orf",
    ".rw2",
    ".rwl",
    ".pef",
    ".srw",
    ".3fr",
    ".fff",
    ".iiq",
    ".erf",
    ".kdc",
    ".dcr",
    ".mos",
    ".mef",
    ".mrw",
    ".x3f",
    ".raw",
)

# EXIF Orientation (1..8) from LibRaw's ``sizes.flip`` (dcraw maps tag 274 through "50132467").
ORIENTATION_FROM_FLIP = {0: 1, 1: 2, 3: 3, 2: 4, 4: 5, 6: 6, 7: 7, 5: 8}

# DNG CalibrationIlluminant codes (EXIF LightSource) -> correlated colour temperature (K).
ILLUMINANT_KELVIN = {
    1: 5500.0,
    2: 4200.0,
    3: 2856.0,
    4: 5500.0,
    9: 5500.0,
    10: 6500.0,
    11: 7500.0,
    12: 6430.0,
    13: 5000.0,
    14: 4150.0,
    15: 3450.0,
    16: 2940.0,
    17: 2856.0,
    18: 4874.0,
    19: 6774.0,
    20: 5503.0,
    21: 6504.0,
    22: 7504.0,
    23: 5003.0,
    24: 3200.0,
}
D65 = 21

# file signatures of things that are not raw files
_NOT_RAW_MAGIC = (
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x89PNG", "a PNG image"),
    (b"GIF8", "a GIF image"),
    (b"BM", "a BMP image"),
    (b"%PDF", "a PDF document"),
    (b"PK\x03\x04", "a ZIP archive"),
)
_FOVEON_MAGIC = b"FOVb"
_CFA_PHOTOMETRIC, _LINEAR_RAW = 32803, 34892
_PHOTOMETRIC_NAMES = {
    0: "monochrome (WhiteIsZero)",
    1: "monochrome (BlackIsZero)",
    2: "RGB",
    _LINEAR_RAW: "already-demosaiced LinearRaw",
}


@dataclass(frozen=True, kw_only=True)
class RawImage(Exif):
    """A camera raw file's Bayer mosaic and metadata (see :func:`read_raw`).

    mosaic: (H, W) uint16 digital numbers of the active area, (0, 0) its top-left pixel.
    cfa_pattern: 'RGGB' | 'BGGR' | 'GRBG' | 'GBRG', colours of the pixels (0,0) (0,1)
    (1,0) (1,1) of the mosaic (lensim.sensor.isp's convention).
    black_level: 4 numbers (DN), one per CFA position in that order.
    white_level: DN at which the sensor saturates.
    as_shot_wb_gains: (r, 1, b) multipliers of camera R, G, B that neutralize the scene's
    illuminant (the camera's as-shot white balance); None when the file has none.
    color_matrix: 3x3 XYZ -> camera RGB at ``color_matrix_illuminant`` (the DNG matrix
    nearest D65 in mired, else LibRaw's D65 matrix); None when the camera has none.
    color_matrices: every DNG ColorMatrix as (CalibrationIlluminant code, 3x3).
    orientation: EXIF Orientation 1..8 (1 = as stored).
    pixel_pitch_um: from EXIF FocalPlaneXResolution/ResolutionUnit, None when absent.
    make, model: strings or None. Shooting data (the fields of :class:`lensim.raw.exif.Exif`,
    None where the file does not say): exposure_s, fno, iso, focal_length_mm,
    focus_distance_m, lens.
    """

    path: str
    mosaic: np.ndarray
    cfa_pattern: CfaPattern
    black_level: tuple[float, float, float, float]
    white_level: float
    as_shot_wb_gains: tuple[float, float, float] | None
    color_matrix: list[list[float]] | None
    color_matrix_illuminant: int | None = None
    color_matrices: list[tuple[int, list[list[float]]]] = field(default_factory=list)
    orientation: int = 1
    is_dng: bool = False
    make: str | None = None
    model: str | None = None
    pixel_pitch_um: float | None = None

    @property
    def height(self) -> int:
        return int(self.mosaic.shape[0])

    @property
    def width(self) -> int:
        return int(self.mosaic.shape[1])

    @property
    def camera(self) -> str:
        """'Make Model' (or the file name when neither is known)."""
        text = " ".join(s for s in (self.make, self.model) if s)
        return text or Path(self.path).name

    def info(self) -> dict[str, Any]:
        """The metadata as `lensim raw info --json` prints it."""
        return {
            "make": self.make,
            "model": self.model,
            "lens": self.lens,
            "width": self.width,
            "height": self.height,
            "cfa_pattern": self.cfa_pattern,
            "black_level": list(self.black_level),
            "white_level": self.white_level,
            "as_shot_wb_gains": None if self.as_shot_wb_gains is None else list(self.as_shot_wb_gains),
            "color_matrix": self.color_matrix,
            "focal_length_mm": self.focal_length_mm,
            "fno": self.fno,
            "focus_distance_m": self.focus_distance_m,
            "iso": self.iso,
            "exposure_s": self.exposure_s,
            "orientation": self.orientation,
        }


# ---------------------------------------------------------------- file checks


def _check_file(path: Path) -> None:
    """One-line errors for what LibRaw would report vaguely: missing, a folder, empty,
    another image type, Foveon."""
    src = str(path)
    if not path.exists():
        raise InputError(src, None, "no such file")
    if path.is_dir():
        raise InputError(src, None, "is a directory; expected a camera raw file")
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as e:
        raise InputError(src, None, f"cannot read: {e.strerror or e}") from None
    if not head:
        raise InputError(src, None, "is empty; expected a camera raw file")
    for magic, what in _NOT_RAW_MAGIC:
        if head.startswith(magic):
            raise InputError(src, None, f"is {what}, not a camera raw file")
    if head.startswith(_FOVEON_MAGIC):
        raise InputError(src, "cfa", "found Foveon X3 data (three stacked colour layers); expected a Bayer mosaic")


@contextlib.contextmanager
def _quiet_c_stderr() -> Iterator[None]:
    """Silence LibRaw's own messages (it writes e.g. 'Unexpected end of file' to the C
    stderr); the failure reaches the user as one InputError line instead."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


# ---------------------------------------------------------------- TIFF tags (DNG, TIFF-based raws)


def _ratio(value: Any) -> float | None:
    """A TIFF RATIONAL (num, den) or number -> float (None for 0/0 or missing)."""
    if value is None:
        return None
    if isinstance(value, (tuple, list)):
        if len(value) == 2 and all(isinstance(v, (int, np.integer)) for v in value):
            return float(value[0]) / float(value[1]) if value[1] else None
        return _ratio(value[0]) if len(value) == 1 else None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _ratios(value: Any) -> list[float]:
    """A flat TIFF (S)RATIONAL array (n1, d1, n2, d2, ...) or a list of pairs -> floats."""
    flat = [float(v) for v in np.asarray(value, dtype=np.float64).ravel()]
    return [flat[i] / flat[i + 1] for i in range(0, len(flat) - 1, 2)]


def _raw_ifd(tf: Any) -> Any:
    """The full-resolution raw IFD of a TIFF/DNG (NewSubfileType 0), IFD0 or a SubIFD."""
    first = tf.pages[0]
    candidates = [first]
    sub = getattr(first, "pages", None)
    if sub is not None:
        candidates += [p for p in sub]
    for page in candidates:
        if hasattr(page, "tags") and int(page.tags.valueof("NewSubfileType", 0) or 0) == 0:
            return page
    return first


def _tiff_tags(path: Path) -> dict[str, Any]:
    """Tags of a TIFF-based raw: IFD0 and EXIF values by tifffile name, plus the raw IFD's
    photometric interpretation, samples per pixel and CFA repeat size under
    'raw_photometric', 'raw_samples' and 'raw_cfa_dims'. {} when tifffile cannot read the
    file (CR3, RAF, ORF, ...); what was read before an IFD tifffile cannot parse is kept."""
    import tifffile

    tags: dict[str, Any] = {}
    try:
        with tifffile.TiffFile(path) as tf:
            first: Any = tf.pages[0]
            tags.update({t.name: t.value for t in first.tags.values()})
            exif = tags.pop("ExifTag", None)
            if isinstance(exif, dict):
                for k, v in exif.items():
                    tags.setdefault(k, v)
            raw = _raw_ifd(tf)
            found = {t.name: t.value for t in raw.tags.values()}
            dims = raw.tags.valueof("CFARepeatPatternDim")
            found["raw_cfa_dims"] = tuple(int(d) for d in dims) if dims is not None else None
            found["raw_samples"] = int(raw.tags.valueof("SamplesPerPixel", 1) or 1)
            found["raw_photometric"] = int(raw.tags.valueof("PhotometricInterpretation", 0) or 0)
            for k, v in found.items():
                tags.setdefault(k, v)
    except Exception:  # noqa: BLE001 - not a TIFF container, or an IFD tifffile cannot parse: LibRaw's data then
        pass
    return tags


def _dng_refusal(src: str, tags: dict[str, Any]) -> None:
    """Refuse a DNG whose raw IFD is not a 2x2 colour filter array (LibRaw judges when
    tifffile could not read the raw IFD)."""
    if "raw_photometric" not in tags:
        return
    photometric = int(tags["raw_photometric"])
    if photometric != _CFA_PHOTOMETRIC:
        what = _PHOTOMETRIC_NAMES.get(photometric, f"PhotometricInterpretation {photometric}")
        raise InputError(
            src,
            "cfa",
            f"found {what} data with {tags.get('raw_samples', 1)} sample(s) per pixel; "
            "expected a Bayer colour filter array mosaic",
        )
    dims = tags.get("raw_cfa_dims")
    if dims is not None and tuple(dims) != (2, 2):
        kind = "X-Trans-like " if tuple(dims) == (6, 6) else ""
        raise InputError(
            src,
            "cfa",
            f"found a {dims[0]}x{dims[1]} {kind}colour filter pattern; expected a 2x2 "
            "Bayer pattern (RGGB, BGGR, GRBG or GBRG)",
        )


def _dng_color_matrices(tags: dict[str, Any]) -> list[tuple[int, list[list[float]]]]:
    """(CalibrationIlluminant, 3x3 XYZ -> camera) for ColorMatrix1 and ColorMatrix2."""
    out = []
    for k in (1, 2):
        m = tags.get(f"ColorMatrix{k}")
        if m is None:
            continue
        vals = _ratios(m)
        if len(vals) != 9:  # a 4-colour camera's 4x3 matrix: not a Bayer RGB camera
            continue
        illum = int(tags.get(f"CalibrationIlluminant{k}", 0) or 0)
        out.append((illum, [[float(v) for v in vals[i : i + 3]] for i in (0, 3, 6)]))
    return out


def _nearest_d65(matrices: list[tuple[int, list[list[float]]]]) -> tuple[int, list[list[float]]]:
    """The matrix whose calibration illuminant is nearest D65 in mired (unknown counts as D65)."""

    def distance(item: tuple[int, list[list[float]]]) -> float:
        kelvin = ILLUMINANT_KELVIN.get(item[0], 6504.0)
        return abs(1e6 / kelvin - 1e6 / 6504.0)

    return min(matrices, key=distance)


# ---------------------------------------------------------------- LibRaw


def _libraw_refusal(src: str, rp: Any) -> None:
    """Refuse data LibRaw opened that is not an RGB Bayer mosaic."""
    import rawpy

    if rp.raw_type != rawpy.RawType.Flat:
        raise InputError(
            src,
            "cfa",
            "found already-demosaiced (several samples per pixel) data; expected a Bayer colour filter array mosaic",
        )
    desc = rp.color_desc.decode("ascii", "replace")
    try:
        pattern = rp.raw_pattern
    except NotImplementedError:
        pattern = None
    if pattern is None or pattern.shape == (1, 1) or rp.num_colors == 1:
        raise InputError(src, "cfa", "found monochrome data (no colour filter array); expected a Bayer mosaic")
    if pattern.shape != (2, 2):
        kind = "X-Trans " if pattern.shape == (6, 6) else ""
        raise InputError(
            src,
            "cfa",
            f"found a {pattern.shape[0]}x{pattern.shape[1]} {kind}colour filter pattern; "
            "expected a 2x2 Bayer pattern (RGGB, BGGR, GRBG or GBRG)",
        )
    if desc not in ("RGBG", "RGB"):
        raise InputError(src, "cfa", f"found colour filters {desc!r}; expected red, green and blue (RGBG)")


def _cfa_indices(src: str, rp: Any) -> np.ndarray:
    """LibRaw colour indices (0..3 into color_desc) of the active area's top-left 2x2 quad,
    row-major; the visible area's offset on the sensor is accounted for."""
    colors = np.asarray(rp.raw_colors_visible)
    if colors.shape[0] < 4 or colors.shape[1] < 4:
        raise InputError(
            src, "size", f"active area is {colors.shape[1]}x{colors.shape[0]} pixels; expected at least 4x4"
        )
    quad = colors[:2, :2]
    if not (np.array_equal(colors[2:4, :2], quad) and np.array_equal(colors[:2, 2:4], quad)):
        raise InputError(
            src, "cfa", "found a colour filter pattern that does not repeat every 2 pixels; expected Bayer"
        )
    return quad.ravel()


def _pattern_name(src: str, rp: Any, indices: np.ndarray) -> CfaPattern:
    desc = rp.color_desc.decode("ascii", "replace")
    name = "".join(desc[int(i)] for i in indices)
    if name not in BAYER_PATTERNS:
        raise InputError(src, "cfa", f"found the 2x2 pattern {name!r}; expected RGGB, BGGR, GRBG or GBRG")
    return cfa_pattern(name, src, "cfa")


def _as_shot_gains(rp: Any, tags: dict[str, Any], desc: str) -> tuple[float, float, float] | None:
    """(r, 1, b) as-shot gains: 1 / DNG AsShotNeutral (full precision) where present,
    else LibRaw's camera multipliers (float32); None when the file gives none."""
    neutral = _ratios(tags["AsShotNeutral"]) if "AsShotNeutral" in tags else []
    if len(neutral) == 3 and all(v > 0 for v in neutral):
        return (neutral[1] / neutral[0], 1.0, neutral[1] / neutral[2])
    mul = [float(v) for v in rp.camera_whitebalance]
    red, green, blue = mul[desc.index("R")], mul[desc.index("G")], mul[desc.index("B")]
    if not (red > 0 and green > 0 and blue > 0):
        return None
    return (red / green, 1.0, blue / green)


def _open_libraw(src: str) -> Any:
    """rawpy.imread with LibRaw's errors as one-line InputErrors (data unpacked)."""
    import rawpy

    try:
        with _quiet_c_stderr():
            rp = rawpy.imread(src)
            rp.unpack()  # imread only parses the header; truncation shows up here
    except rawpy.LibRawFileUnsupportedError:
        raise InputError(src, None, "not a raw format LibRaw can read (or not a raw file)") from None
    except (rawpy.LibRawIOError, rawpy.LibRawDataError) as e:
        raise InputError(src, None, f"truncated or corrupt raw file: LibRaw reports {_libraw_message(e)}") from None
    except rawpy.LibRawError as e:
        raise InputError(src, None, f"cannot be read as a raw file: LibRaw reports {_libraw_message(e)}") from None
    return rp


def _libraw_message(e: Exception) -> str:
    msg = e.args[0] if e.args else e
    return (msg.decode("ascii", "replace") if isinstance(msg, bytes) else str(msg)).strip() or type(e).__name__


# ---------------------------------------------------------------- EXIF

_UNIT_UM = {2: 25400.0, 3: 10000.0, 4: 1000.0, 5: 1.0}  # EXIF FocalPlaneResolutionUnit -> um


def _text(value: Any) -> str | None:
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    text = str(value).strip("\x00 ").strip() if value is not None else ""
    return text or None


def _positive(*values: Any) -> float | None:
    """The first value that is a positive finite number (TIFF rationals accepted)."""
    for v in values:
        x = _ratio(v)
        if x is not None and x > 0:
            return x
    return None


def _pixel_pitch_um(tags: dict[str, Any]) -> float | None:
    """Pixel pitch (um) from FocalPlaneXResolution (pixels per ResolutionUnit)."""
    res = _positive(tags.get("FocalPlaneXResolution"))
    unit = tags.get("FocalPlaneResolutionUnit", 2)
    unit_um = _UNIT_UM.get(int(unit[0] if isinstance(unit, (tuple, list)) else unit or 2))
    if res is None or unit_um is None:
        return None
    return unit_um / res


def _focus_distance_m(tags: dict[str, Any]) -> float | None:
    """EXIF SubjectDistance (m); 0 means unknown, 0xFFFFFFFF/n infinity."""
    value = tags.get("SubjectDistance")
    if isinstance(value, (tuple, list)) and len(value) == 2 and value[0] == 0xFFFFFFFF:
        return math.inf
    return _positive(value)


def _exif(rp: Any, tags: dict[str, Any]) -> dict[str, Any]:
    """Shooting data: the TIFF/EXIF tags where the file has them, else LibRaw's values."""
    other, lens = rp.other, rp.lens
    iso = tags.get("ISOSpeedRatings", tags.get("PhotographicSensitivity"))
    if isinstance(iso, (tuple, list)):
        iso = iso[0] if iso else None
    return {
        "make": _text(tags.get("Make")),
        "model": _text(tags.get("Model")),
        "lens": _text(tags.get("LensModel")) or _text(lens.model),
        "focal_length_mm": _positive(tags.get("FocalLength"), other.focal_length),
        "fno": _positive(tags.get("FNumber"), other.aperture),
        "focus_distance_m": _focus_distance_m(tags),
        "iso": _positive(iso, other.iso_speed),
        "exposure_s": _positive(tags.get("ExposureTime"), other.shutter_speed),
        "pixel_pitch_um": _pixel_pitch_um(tags),
    }


# ---------------------------------------------------------------- the reader


def _colour(rp: Any, tags: dict[str, Any], is_dng: bool) -> dict[str, Any]:
    """The colour matrix fields of RawImage: DNG ColorMatrix1/2, else LibRaw's matrix."""
    matrices = _dng_color_matrices(tags) if is_dng else []
    if matrices:
        illum, matrix = _nearest_d65(matrices)
        return {"color_matrix": matrix, "color_matrix_illuminant": illum, "color_matrices": matrices}
    libraw = np.asarray(rp.rgb_xyz_matrix, dtype=np.float64)[:3]
    if not np.any(libraw):
        return {"color_matrix": None, "color_matrix_illuminant": None, "color_matrices": []}
    return {"color_matrix": libraw.tolist(), "color_matrix_illuminant": D65, "color_matrices": []}


def read_raw(path: str | Path) -> RawImage:
    """Read a camera raw file: the active area's Bayer mosaic and its metadata.

    Raises a one-line :class:`InputError` for a missing file, a folder, another image
    type (e.g. a JPEG named .dng), a truncated or corrupt raw, and for data that is not
    an RGB Bayer mosaic (X-Trans, Foveon, monochrome, LinearRaw DNG), naming what was
    found. See :class:`RawImage` for the fields and their units."""
    path = Path(path)
    src = str(path)
    _check_file(path)
    tags = _tiff_tags(path)
    is_dng = "DNGVersion" in tags
    if is_dng:
        _dng_refusal(src, tags)
    rp = _open_libraw(src)
    try:
        _libraw_refusal(src, rp)
        indices = _cfa_indices(src, rp)
        desc = rp.color_desc.decode("ascii", "replace")
        per_colour = [float(b) for b in rp.black_level_per_channel]
        mosaic = np.array(rp.raw_image_visible, dtype=np.uint16, copy=True)
        raw = RawImage(
            path=src,
            mosaic=mosaic,
            cfa_pattern=_pattern_name(src, rp, indices),
            black_level=tuple(per_colour[int(i)] for i in indices),  # type: ignore[arg-type]
            white_level=float(rp.white_level),
            as_shot_wb_gains=_as_shot_gains(rp, tags, desc),
            orientation=ORIENTATION_FROM_FLIP.get(int(rp.sizes.flip), 1),
            is_dng=is_dng,
            **_colour(rp, tags, is_dng),
            **_exif(rp, tags),
        )
    finally:
        rp.close()
    if not raw.white_level > max(raw.black_level):
        raise InputError(
            src,
            "white_level",
            f"found white level {raw.white_level:g} not above the black levels {list(raw.black_level)}",
        )
    return raw


#: EXIF tag numbers of the shooting settings (in the Exif IFD)
_SETTING_TAGS = {"FNumber": 33437, "SubjectDistance": 37382, "FocalLength": 37386}


def photo_exif_settings(path: str | Path) -> dict[str, float]:
    """Shooting settings a developed photo's EXIF records, {fno, focus_m, focal_mm} (those
    present): FNumber, SubjectDistance (0 unknown, 0xFFFFFFFF/n infinity) and FocalLength
    of a TIFF (tifffile) or a JPEG / PNG (Pillow's Exif IFD). {} when the file has none or
    its EXIF cannot be read (the photo itself is read and checked elsewhere)."""
    path = Path(path)
    tags: dict[str, Any] = {}
    if path.suffix.lower() in (".tif", ".tiff"):
        tags = _tiff_tags(path)
    else:
        try:
            from PIL import Image

            with Image.open(path) as im:
                im.load()  # a PNG's eXIf chunk may follow the image data
                ifd = im.getexif().get_ifd(0x8769)
                tags = {name: ifd[num] for name, num in _SETTING_TAGS.items() if num in ifd}
        except Exception:  # noqa: BLE001 - no EXIF to be had: no settings from it
            return {}
    for name, value in list(tags.items()):  # Pillow gives IFDRational
        if hasattr(value, "numerator") and hasattr(value, "denominator") and not isinstance(value, (int, float)):
            tags[name] = (int(value.numerator), int(value.denominator))
    found = {
        "fno": _positive(tags.get("FNumber")),
        "focus_m": _focus_distance_m(tags),
        "focal_mm": _positive(tags.get("FocalLength")),
    }
    return {k: v for k, v in found.items() if v is not None}


def raw_files(paths: list[str | Path]) -> list[Path]:
    """The raw files named: files as given, folders expanded to their files with a raw
    suffix (sorted). A folder without any is an InputError."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in RAW_SUFFIXES)
            if not found:
                raise InputError(str(p), None, f"folder holds no raw files ({', '.join(RAW_SUFFIXES[:8])}, ...)")
            out += found
        else:
            out.append(p)
    return out
