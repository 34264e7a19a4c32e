"""Writing DNG files (Adobe DNG 1.4) that LibRaw, darktable, RawTherapee and Lightroom open.

Two kinds, both uncompressed 16-bit, one IFD (no preview), written with tifffile:

- **CFA DNG** (:func:`write_cfa_dng`): a Bayer mosaic of digital numbers, Photometric CFA
  (32803), CFARepeatPatternDim 2x2 and CFAPattern (0 = R, 1 = G, 2 = B for the pixels
  (0,0) (0,1) (1,0) (1,1)), BlackLevel per CFA position (BlackLevelRepeatDim 2x2),
  WhiteLevel. What ``lensim simulate --raw`` writes.
- **LinearRaw DNG** (:func:`write_linear_dng`): demosaiced camera RGB (Photometric
  LinearRaw 34892, 3 samples per pixel), black 0, white 65535. What ``lensim restore
  --dng`` writes for a restored raw photo (after DxO PureRAW's output).

Both carry the colour metadata of a raw converter (:class:`DngColour`): ColorMatrix1
(XYZ -> camera RGB) with CalibrationIlluminant1 (EXIF LightSource code, 21 = D65) and
AsShotNeutral (camera RGB of a neutral: 1 / white-balance gain per channel), the camera's
names (:class:`DngCamera`: Make, Model, UniqueCameraModel), DNGVersion 1.4.0.0,
DNGBackwardVersion 1.1.0.0 and the Orientation (TIFF codes 1-8; the pixels are stored as
the sensor saw them). Shooting data (:class:`DngExif`: exposure time, f-number, ISO,
focal length, focus distance, lens) goes into an EXIF IFD, where LibRaw reads it.

Files are written through :func:`lensim.io.atomic_writer` (a temporary file renamed
when complete).
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from lensim.errors import InputError
from lensim.io import atomic_writer
from lensim.raw.exif import Exif
from lensim.sensor.cfa import CfaPattern, cfa_pattern

if TYPE_CHECKING:
    from lensim.render.mapping import SensorMapping
    from lensim.sensor.isp import CaptureParams
    from lensim.sensor.profile import SensorProfile

D65_ILLUMINANT = 21  # EXIF LightSource code of CIE D65 (CalibrationIlluminant1)
DNG_VERSION = bytes([1, 4, 0, 0])
DNG_BACKWARD_VERSION = bytes([1, 1, 0, 0])
CFA_CODES = {"R": 0, "G": 1, "B": 2}
ORIENTATIONS = range(1, 9)
MIN_SIDE = 22  # LibRaw refuses images smaller than this (pixels a side)
SIMULATED_MAKE = "lensim"  # the Make of DNGs written by the simulator
SIMULATION_RECORD = "lensim_simulation"  # key of the simulator's JSON record in ImageDescription
_RATIONAL_DENOMINATOR = 1_000_000

# TIFF tag types and codes used here
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _SRATIONAL = 1, 2, 3, 4, 5, 10
_TAG = {
    "ImageDescription": 270,
    "Make": 271,
    "Model": 272,
    "Orientation": 274,
    "CFARepeatPatternDim": 33421,
    "CFAPattern": 33422,
    "ExifIFD": 34665,
    "ExifIFDPlaceholder": 34664,
    "DNGVersion": 50706,
    "DNGBackwardVersion": 50707,
    "UniqueCameraModel": 50708,
    "CFAPlaneColor": 50710,
    "CFALayout": 50711,
    "BlackLevelRepeatDim": 50713,
    "BlackLevel": 50714,
    "WhiteLevel": 50717,
    "ColorMatrix1": 50721,
    "ColorMatrix2": 50722,
    "AsShotNeutral": 50728,
    "CalibrationIlluminant1": 50778,
    "CalibrationIlluminant2": 50779,
}
_EXIF_TAG = {
    "exposure_s": 33434,
    "fno": 33437,
    "iso": 34855,
    "exif_version": 36864,
    "focus_distance_m": 37382,
    "focal_length_mm": 37386,
    "lens": 42036,
}


def _matrix_rows(matrix: Any) -> tuple[tuple[float, float, float], ...]:
    m = np.asarray(matrix, dtype=np.float64).reshape(3, 3)
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in m)


@dataclass(frozen=True)
class DngColour:
    """Colour metadata of a DNG.

    color_matrix: (3, 3) XYZ -> camera RGB at the calibration illuminant (DNG ColorMatrix1;
        lensim.sensor.calibration.dng_color_matrix_from_ccm makes it from a profile's CCM).
    as_shot_neutral: camera RGB of a neutral grey, (1 / r_gain, 1, 1 / b_gain) for
        white-balance gains r_gain, b_gain (DNG AsShotNeutral).
    calibration_illuminant: EXIF LightSource code of the matrix's illuminant (21 = D65).
    """

    color_matrix: tuple[tuple[float, float, float], ...]
    as_shot_neutral: tuple[float, float, float]
    calibration_illuminant: int = D65_ILLUMINANT
    color_matrix2: tuple[tuple[float, float, float], ...] | None = None
    calibration_illuminant2: int | None = None

    def with_second_matrix(self, color_matrix: Any, calibration_illuminant: int) -> DngColour:
        """A copy that also carries ColorMatrix2 with CalibrationIlluminant2 (raw
        converters interpolate between the two by the white balance)."""
        return replace(
            self, color_matrix2=_matrix_rows(color_matrix), calibration_illuminant2=int(calibration_illuminant)
        )

    @classmethod
    def from_gains(
        cls, color_matrix: Any, r_gain: float, b_gain: float, calibration_illuminant: int = D65_ILLUMINANT
    ) -> DngColour:
        """From a 3x3 XYZ -> camera matrix and the as-shot white-balance gains (green 1)."""
        return cls(_matrix_rows(color_matrix), (1.0 / r_gain, 1.0, 1.0 / b_gain), int(calibration_illuminant))


@dataclass(frozen=True)
class DngCamera:
    """The camera's names: Make, Model, and UniqueCameraModel (default 'Make Model')."""

    make: str
    model: str
    unique_camera_model: str = ""

    @property
    def unique(self) -> str:
        return self.unique_camera_model or f"{self.make} {self.model}".strip()


#: the shooting data written to the EXIF IFD (None fields are left out): lensim.raw.exif.Exif
DngExif = Exif


# ----------------------------------------------------------------------------- tag values


def _rationals(values: Sequence[float] | np.ndarray, signed: bool = False) -> tuple[int, ...]:
    """(numerator, denominator) pairs, flattened, closest within 1e-6 relative."""
    out: list[int] = []
    for v in values:
        x = float(v)
        if not np.isfinite(x) or (x < 0 and not signed):
            raise InputError(None, "dng", f"expected a finite{'' if signed else ' non-negative'} number, got {v!r}")
        f = Fraction(x).limit_denominator(_RATIONAL_DENOMINATOR)
        limit = 2**31 - 1 if signed else 2**32 - 1
        while abs(f.numerator) > limit:  # large values: a coarser denominator
            f = Fraction(x).limit_denominator(max(1, f.denominator // 10))
        out += [f.numerator, f.denominator]
    return tuple(out)


def _cfa_codes(pattern: CfaPattern) -> bytes:
    return bytes(CFA_CODES[c] for c in cfa_pattern(pattern, field="cfa_pattern"))


def _check_orientation(orientation: int) -> int:
    if int(orientation) not in ORIENTATIONS or int(orientation) != orientation:
        raise InputError(None, "orientation", f"expected a TIFF orientation code 1-8, got {orientation!r}")
    return int(orientation)


def _common_tags(colour: DngColour, camera: DngCamera, orientation: int, description: str = "") -> list[tuple]:
    """tifffile extratags shared by both kinds: version, names, orientation, colour,
    ImageDescription (when given)."""
    t = _TAG
    tags = [
        (t["Make"], _ASCII, 0, camera.make, True),
        (t["Model"], _ASCII, 0, camera.model, True),
        (t["Orientation"], _SHORT, 1, _check_orientation(orientation), True),
        (t["DNGVersion"], _BYTE, 4, DNG_VERSION, True),
        (t["DNGBackwardVersion"], _BYTE, 4, DNG_BACKWARD_VERSION, True),
        (t["UniqueCameraModel"], _ASCII, 0, camera.unique, True),
        (t["ColorMatrix1"], _SRATIONAL, 9, _rationals(np.ravel(colour.color_matrix), signed=True), True),
        (t["AsShotNeutral"], _RATIONAL, 3, _rationals(colour.as_shot_neutral), True),
        (t["CalibrationIlluminant1"], _SHORT, 1, int(colour.calibration_illuminant), True),
    ]
    if colour.color_matrix2 is not None and colour.calibration_illuminant2 is not None:
        tags += [
            (t["ColorMatrix2"], _SRATIONAL, 9, _rationals(np.ravel(colour.color_matrix2), signed=True), True),
            (t["CalibrationIlluminant2"], _SHORT, 1, int(colour.calibration_illuminant2), True),
        ]
    if description:
        tags.append((t["ImageDescription"], _ASCII, 0, description, True))
    return tags


# ----------------------------------------------------------------------------- EXIF IFD


def _exif_entries(exif: DngExif) -> list[tuple[int, int, int, bytes]]:
    """(tag, type, count, little-endian value bytes) of the EXIF IFD, sorted by tag."""
    e = _EXIF_TAG
    rows: list[tuple[int, int, int, bytes]] = [(e["exif_version"], 7, 4, b"0231")]  # UNDEFINED
    for key in ("exposure_s", "fno", "focal_length_mm", "focus_distance_m"):
        value = getattr(exif, key)
        if key == "focus_distance_m" and value == np.inf:  # EXIF: 0xFFFFFFFF/n is infinity
            rows.append((e[key], _RATIONAL, 1, struct.pack("<2I", 0xFFFFFFFF, 1)))
        elif value is not None:
            rows.append((e[key], _RATIONAL, 1, struct.pack("<2I", *_rationals([value]))))
    if exif.iso is not None:
        rows.append((e["iso"], _SHORT, 1, struct.pack("<H", int(min(65535, round(float(exif.iso)))))))
    if exif.lens:
        text = str(exif.lens).encode("ascii", "replace") + b"\0"
        rows.append((e["lens"], _ASCII, len(text), text))
    return sorted(rows)


def _ifd_bytes(entries: list[tuple[int, int, int, bytes]], offset: int) -> bytes:
    """A classic little-endian TIFF IFD placed at ``offset``: entry count, 12-byte
    entries, next-IFD offset 0, then the values longer than 4 bytes."""
    head = struct.pack("<H", len(entries))
    data_start = offset + 2 + 12 * len(entries) + 4
    blobs = b""
    for tag, typ, count, value in entries:
        if len(value) <= 4:
            head += struct.pack("<HHI", tag, typ, count) + value.ljust(4, b"\0")
        else:
            head += struct.pack("<HHII", tag, typ, count, data_start + len(blobs))
            blobs += value + b"\0" * (len(value) % 2)
    return head + struct.pack("<I", 0) + blobs


def _link_exif_ifd(fh: IO[bytes], exif: DngExif) -> None:
    """Append the EXIF IFD to the TIFF that tifffile has just written to ``fh`` (open for
    reading and writing) and point IFD0 at it. tifffile refuses to write the ExifIFD tag
    itself, so it writes a placeholder entry with the next lower (unused) code, which is
    patched into ExifIFD (LONG offset) in place: the entries stay sorted."""
    fh.seek(0)
    header = fh.read(8)
    if header[:4] != b"II*\0":
        raise RuntimeError("expected a classic little-endian TIFF from tifffile")
    ifd0 = struct.unpack("<I", header[4:8])[0]
    fh.seek(ifd0)
    count = struct.unpack("<H", fh.read(2))[0]
    table = fh.read(12 * count)
    tags = [struct.unpack_from("<H", table, 12 * i)[0] for i in range(count)]
    entry = ifd0 + 2 + 12 * tags.index(_TAG["ExifIFDPlaceholder"])
    end = fh.seek(0, os.SEEK_END)
    offset = end + end % 2  # IFDs start on a word boundary
    fh.write(b"\0" * (offset - end) + _ifd_bytes(_exif_entries(exif), offset))
    fh.seek(entry)
    fh.write(struct.pack("<HHII", _TAG["ExifIFD"], _LONG, 1, offset))
    fh.seek(0, os.SEEK_END)


def _write(path: str | Path, data: np.ndarray, photometric: int, tags: list[tuple], exif: DngExif | None) -> Path:
    """Write one uncompressed IFD with tifffile through the atomic writer."""
    import tifffile

    path = Path(path)
    if exif is not None:
        tags = tags + [(_TAG["ExifIFDPlaceholder"], _LONG, 1, 0, True)]
    with atomic_writer(path, suffix=".dng") as fh:
        tifffile.imwrite(
            fh,
            data,
            photometric=photometric,
            planarconfig="contig" if data.ndim == 3 else None,
            extratags=tags,
            metadata=None,
            subfiletype=0,
            software="lensim",
            byteorder="<",
            bigtiff=False,
        )
        if exif is not None:
            _link_exif_ifd(fh, exif)
    return path


# ----------------------------------------------------------------------------- writers


def _black_level_tag(black_level: float | Sequence[float], white_level: int) -> tuple:
    """BlackLevel for the 2x2 repeat (row-major CFA positions): LONG when whole numbers,
    else RATIONAL."""
    levels = np.asarray(black_level, dtype=np.float64).ravel()
    if levels.size == 1:
        levels = np.repeat(levels, 4)
    if levels.size != 4 or not np.all(np.isfinite(levels)) or levels.min() < 0 or levels.max() >= white_level:
        raise InputError(
            None,
            "black_level",
            f"expected 1 or 4 numbers in [0, white_level={white_level}), got {np.asarray(black_level).tolist()!r}",
        )
    if np.all(levels == np.round(levels)):
        return (_TAG["BlackLevel"], _LONG, 4, tuple(int(v) for v in levels), True)
    return (_TAG["BlackLevel"], _RATIONAL, 4, _rationals(levels), True)


def write_cfa_dng(
    path: str | Path,
    mosaic: np.ndarray,
    cfa_pattern: CfaPattern,
    black_level: float | Sequence[float],
    white_level: int,
    colour: DngColour,
    camera: DngCamera,
    orientation: int = 1,
    exif: DngExif | None = None,
    description: str = "",
) -> Path:
    """Write a Bayer mosaic as a CFA DNG.

    Args:
        path: the .dng file (written atomically).
        mosaic: (H, W) digital numbers (integers in [0, white_level], stored as uint16),
            the sensor's active area, pixel (0, 0) top-left.
        cfa_pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (colours of pixels (0,0) (0,1) (1,0) (1,1)).
        black_level: DN, one number or four (the CFA positions in the same order).
        white_level: DN of saturation (< 65536).
        colour, camera, orientation, exif: see the module docstring.
        description: ImageDescription text (lensim's simulator stores a JSON record there).
    Returns the path.
    """
    arr = np.asarray(mosaic)
    if arr.ndim != 2 or min(arr.shape) < MIN_SIDE:
        raise InputError(
            str(path),
            "mosaic",
            f"expected an (H, W) mosaic of at least {MIN_SIDE} pixels a side (LibRaw's least), got shape {arr.shape}",
        )
    if not 0 < int(white_level) < 65536 or int(white_level) != white_level:
        raise InputError(str(path), "white_level", f"expected an integer in [1, 65535], got {white_level!r}")
    if not np.issubdtype(arr.dtype, np.integer) or arr.min() < 0 or arr.max() > white_level:
        raise InputError(str(path), "mosaic", f"expected integer digital numbers in [0, {int(white_level)}]")
    tags = _common_tags(colour, camera, orientation, description) + [
        (_TAG["CFARepeatPatternDim"], _SHORT, 2, (2, 2), True),
        (_TAG["CFAPattern"], _BYTE, 4, _cfa_codes(cfa_pattern), True),
        (_TAG["CFAPlaneColor"], _BYTE, 3, bytes([0, 1, 2]), True),
        (_TAG["CFALayout"], _SHORT, 1, 1, True),
        (_TAG["BlackLevelRepeatDim"], _SHORT, 2, (2, 2), True),
        _black_level_tag(black_level, int(white_level)),
        (_TAG["WhiteLevel"], _LONG, 1, int(white_level), True),
    ]
    return _write(path, arr.astype(np.uint16, copy=False), 32803, tags, exif)


def _linear_uint16(image: Any, block_rows: int, to_camera: Callable[[Any], Any] | None = None) -> np.ndarray:
    """(3, H, W) image -> (H, W, 3) uint16 camera RGB, round(clip(x, 0, 1) * 65535), in
    blocks of rows (``to_camera`` converts each block first) to bound memory."""
    c, h, w = tuple(image.shape)
    if c != 3 or min(h, w) < MIN_SIDE:
        raise InputError(
            None,
            "image",
            f"expected a (3, H, W) image of at least {MIN_SIDE} pixels a side (LibRaw's "
            f"least), got shape {tuple(image.shape)}",
        )
    out = np.empty((h, w, 3), dtype=np.uint16)
    for y0 in range(0, h, block_rows):
        blk = image[:, y0 : y0 + block_rows]
        blk = np.asarray(to_camera(blk) if to_camera is not None else blk, dtype=np.float32)
        out[y0 : y0 + block_rows] = np.rint(np.clip(blk, 0.0, 1.0) * 65535.0).astype(np.uint16).transpose(1, 2, 0)
    return out


def _write_linear(
    path: str | Path, data: np.ndarray, colour: DngColour, camera: DngCamera, orientation: int, exif: DngExif | None
) -> Path:
    tags = _common_tags(colour, camera, orientation) + [
        (_TAG["BlackLevel"], _LONG, 1, 0, True),
        (_TAG["WhiteLevel"], _LONG, 1, 65535, True),
    ]
    return _write(path, data, 34892, tags, exif)


def write_linear_dng(
    path: str | Path,
    camera_rgb: Any,
    colour: DngColour,
    camera: DngCamera,
    orientation: int = 1,
    exif: DngExif | None = None,
    block_rows: int = 512,
) -> Path:
    """Write demosaiced camera RGB as a LinearRaw DNG (16 bits, black 0, white 65535).

    Args:
        camera_rgb: (3, H, W) linear camera RGB before white balance (numpy or torch),
            normalized so 1 is the white level; clipped to [0, 1] and rounded to 1/65535.
        colour: ColorMatrix1 and AsShotNeutral (the raw's, so that converters
            white-balance and colour-convert the data as they would the original raw).
    Returns the path.
    """
    return _write_linear(path, _linear_uint16(camera_rgb, block_rows), colour, camera, orientation, exif)


def write_srgb_as_linear_dng(
    path: str | Path,
    srgb: Any,
    ccm: Any,
    colour: DngColour,
    camera: DngCamera,
    orientation: int = 1,
    exif: DngExif | None = None,
    block_rows: int = 512,
) -> Path:
    """Write a developed photo back as a LinearRaw DNG in the raw's camera space.

    srgb: (3, H, W) torch tensor in [0, 1], developed by lensim's chain with ``ccm`` (3x3
    camera RGB -> linear sRGB) and the white-balance gains of ``colour.as_shot_neutral``;
    the chain is inverted (lensim.sensor.isp.srgb_to_camera) block by block. Colours
    outside the camera's [0, 1] range are clipped."""
    from lensim.sensor.isp import srgb_to_camera

    n = colour.as_shot_neutral
    r_gain, b_gain = n[1] / n[0], n[1] / n[2]
    data = _linear_uint16(srgb, block_rows, lambda blk: srgb_to_camera(blk, ccm, r_gain, b_gain))
    return _write_linear(path, data, colour, camera, orientation, exif)


# ----------------------------------------------------------------------------- lensim's sensors


def profile_camera(profile: SensorProfile) -> DngCamera:
    """The camera names of a simulated capture: Make 'lensim', Model the profile's name."""
    return DngCamera(make=SIMULATED_MAKE, model=profile.name, unique_camera_model=f"{SIMULATED_MAKE} {profile.name}")


def profile_colour(profile: SensorProfile, r_gain: float, b_gain: float) -> DngColour:
    """A profile's colour as DNG metadata: ColorMatrix1 (D65) from its CCM and its D65
    (6504 K) white-balance gains, AsShotNeutral from the capture's gains."""
    from lensim.sensor.calibration import dng_color_matrix_from_ccm

    r65, b65 = profile.wb_gains(6504.0)
    return DngColour.from_gains(dng_color_matrix_from_ccm(np.array(profile.ccm), r65, b65), r_gain, b_gain)


def write_capture_dng(
    path: str | Path,
    raw: Any,
    profile: SensorProfile,
    params: CaptureParams,
    mapping: SensorMapping | None = None,
    orientation: int = 1,
    exif: DngExif | None = None,
) -> Path:
    """Write a simulated capture as a CFA DNG: ``raw`` (H, W) normalized mosaic (0 at the
    black level, 1 at the white level; torch or numpy) turned into the profile's digital
    numbers exactly as the simulated ADC does (lensim.sensor.isp.digital_numbers), the
    profile's pattern, levels and camera names, the capture's white balance. ImageDescription
    holds the simulation record (:func:`read_simulation_record`): the sensor's name, where
    the frame lay on it (``mapping``: pitch_um, x0_mm, y0_mm; default the whole sensor at
    its own pitch) and the capture's draws."""
    import torch

    from lensim.sensor.isp import digital_numbers

    dn = digital_numbers(torch.as_tensor(raw), profile).to(torch.int32).cpu().numpy()
    if mapping is None:
        place = {
            "pitch_um": profile.pixel_pitch_um,
            "x0_mm": -profile.sensor_size_mm[0] / 2,
            "y0_mm": -profile.sensor_size_mm[1] / 2,
        }
    else:
        place = {"pitch_um": mapping.pitch_um, "x0_mm": mapping.x0_mm, "y0_mm": mapping.y0_mm}
    record = {SIMULATION_RECORD: {"sensor": profile.name, **place, "capture": params.to_dict()}}
    return write_cfa_dng(
        path,
        dn,
        params.bayer_pattern,
        profile.black_level,
        int(profile.white_level),
        profile_colour(profile, params.r_gain, params.b_gain),
        profile_camera(profile),
        orientation,
        exif,
        description=json.dumps(record, default=str),
    )


def read_simulation_record(path: str | Path) -> dict[str, Any] | None:
    """The simulation record of a DNG written by :func:`write_capture_dng` (sensor,
    pitch_um, x0_mm, y0_mm, capture), or None for any other file (camera raws included)."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tf:
            text = tf.pages.first.description
        record = json.loads(text).get(SIMULATION_RECORD)
    except Exception:  # noqa: BLE001 - not a TIFF, no description, not our JSON: not a simulated DNG
        return None
    return record if isinstance(record, dict) else None


__all__ = [
    "DngCamera",
    "DngColour",
    "DngExif",
    "profile_camera",
    "profile_colour",
    "read_simulation_record",
    "write_capture_dng",
    "write_cfa_dng",
    "write_linear_dng",
    "write_srgb_as_linear_dng",
]
