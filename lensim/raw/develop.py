"""Developing a camera raw file with the simulator's own chain (lensim.sensor.isp).

The real mosaic goes through exactly the functions a simulated capture goes through, so a
network trained on simulated captures sees real ones developed the same way:

    DN mosaic --normalized_mosaic--> normalized raw (0 at black, 1 at white, per CFA position)
      --isp.raw_to_srgb--> white balance on the mosaic, AHD demosaic, CCM, sRGB curve
      --apply_orientation--> the photo as the camera held it

No sharpening, no denoising, no tone curve: a vendor ISP's sharpening changes the very
blur the restoration network was trained to undo.

Colour comes from a sensor profile when one is given (its CCM and white-balance table),
else from the raw file itself (:func:`lensim.raw.profile.sensor_from_raw`: the CCM from
the DNG/LibRaw colour matrix, Brooks et al. 2019's construction). White balance is the
camera's as-shot one, or a preset colour temperature looked up in the profile's table.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from lensim.errors import InputError, ParameterError
from lensim.images import write_image
from lensim.raw.read import RawImage, read_raw
from lensim.sensor.isp import CaptureParams, quantize, raw_to_srgb
from lensim.sensor.profile import SensorProfile

# White-balance presets (K): what cameras and raw converters call them.
WB_PRESETS = {
    "tungsten": 2856.0,
    "incandescent": 2856.0,
    "fluorescent": 4000.0,
    "daylight": 5500.0,
    "flash": 5500.0,
    "cloudy": 6500.0,
    "d65": 6504.0,
    "shade": 7500.0,
}
AS_SHOT = "as-shot"


def parse_wb(text: str | float) -> str | float:
    """'as-shot', a preset name (:data:`WB_PRESETS`) or a colour temperature ('5000',
    '5000K') -> 'as-shot' or kelvin."""
    if isinstance(text, (int, float)):
        kelvin = float(text)
    else:
        t = str(text).strip().lower()
        if t == AS_SHOT:
            return AS_SHOT
        if t in WB_PRESETS:
            return WB_PRESETS[t]
        try:
            kelvin = float(t.removesuffix("k"))
        except ValueError:
            raise ParameterError(
                None,
                "wb",
                f"expected as-shot, a preset ({', '.join(WB_PRESETS)}) or a colour "
                f"temperature such as 5000K, got {text!r}",
            ) from None
    if not (math.isfinite(kelvin) and 1000.0 <= kelvin <= 50000.0):
        raise ParameterError(None, "wb", f"expected a colour temperature between 1000 and 50000 K, got {text!r}")
    return kelvin


def normalized_mosaic(raw: RawImage) -> torch.Tensor:
    """(H, W) float32 normalized raw values: (DN - black) / (white - black) with the black
    level of each pixel's CFA position, DN clipped to [0, white_level] first. The inverse
    of the simulator's ADC (:func:`lensim.sensor.isp.quantize_raw`), computed the same way."""
    dn = torch.from_numpy(raw.mosaic.astype("float32")).clamp(0.0, raw.white_level)
    black = torch.empty_like(dn)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        black[dy::2, dx::2] = raw.black_level[k]
    return (dn - black) / (raw.white_level - black)


def _estimate_kelvin(sensor: SensorProfile, r_gain: float, b_gain: float) -> float:
    """The colour temperature (K) in the profile's table whose gains are nearest (r, b) in
    log space, searched every mired between its ends."""
    lo, hi = sensor.white_balance[0].kelvin, sensor.white_balance[-1].kelvin
    best, best_d = lo, math.inf
    for mired in range(int(1e6 / hi), int(1e6 / lo) + 1):
        k = 1e6 / max(mired, 1)
        r, b = sensor.wb_gains(k)
        d = math.log(r / r_gain) ** 2 + math.log(b / b_gain) ** 2
        if d < best_d:
            best, best_d = k, d
    return best


def capture_params(raw: RawImage, sensor: SensorProfile | None = None, wb: str | float = AS_SHOT) -> CaptureParams:
    """The develop settings of a raw file as the simulator's :class:`CaptureParams`: the
    raw's CFA pattern; the CCM of ``sensor``, else the one the raw's colour matrix gives
    (:func:`lensim.raw.profile.ccm_from_raw`); the as-shot gains, or for a preset ``wb``
    (see :func:`parse_wb`) the gains of the white-balance table of ``sensor``, else of the
    profile built from the raw (:func:`lensim.raw.profile.sensor_from_raw`). ``kelvin``
    is the preset, or for as-shot the sensor table's temperature nearest the gains (NaN,
    unknown, without a sensor profile)."""
    from lensim.raw.profile import ccm_from_raw, sensor_from_raw

    choice = parse_wb(wb)
    if choice == AS_SHOT:
        if raw.as_shot_wb_gains is None:
            raise InputError(
                raw.path,
                "white balance",
                "the file has no as-shot white balance; give a white balance (`wb`): a "
                f"preset ({', '.join(WB_PRESETS)}) or a colour temperature",
            )
        r_gain, _, b_gain = raw.as_shot_wb_gains
        kelvin = _estimate_kelvin(sensor, r_gain, b_gain) if sensor is not None else math.nan
        ccm = [list(map(float, row)) for row in sensor.ccm] if sensor is not None else ccm_from_raw(raw)
    else:
        # developing uses the profile's colour only: any pitch will do when the file has none
        table = sensor if sensor is not None else sensor_from_raw(raw, pixel_pitch_um=raw.pixel_pitch_um or 1.0)
        kelvin = float(choice)
        r_gain, b_gain = table.wb_gains(kelvin)
        ccm = [list(map(float, row)) for row in table.ccm]
    return CaptureParams(
        kelvin=kelvin,
        r_gain=float(r_gain),
        b_gain=float(b_gain),
        ccm=ccm,
        bayer_pattern=raw.cfa_pattern,
        extra={"source": raw.path, "sensor": None if sensor is None else sensor.name, "wb": wb},
    )


def apply_orientation(img: torch.Tensor, orientation: int) -> torch.Tensor:
    """Turn an image (..., H, W) stored in the sensor's order into the way it is viewed,
    per EXIF Orientation: 1 as is, 2 mirrored left-right, 3 rotated 180 degrees, 4 mirrored
    top-bottom, 5 transposed, 6 rotated 90 degrees clockwise, 7 transverse, 8 rotated 90
    degrees counter-clockwise."""
    hw = (-2, -1)
    ops = {
        1: lambda x: x,
        2: lambda x: x.flip(-1),
        3: lambda x: x.flip(hw),
        4: lambda x: x.flip(-2),
        5: lambda x: x.transpose(-2, -1),
        6: lambda x: torch.rot90(x, -1, hw),
        7: lambda x: torch.rot90(x, -1, hw).flip(-2),
        8: lambda x: torch.rot90(x, 1, hw),
    }
    if orientation not in ops:
        raise InputError(None, "orientation", f"expected an EXIF orientation 1..8, got {orientation!r}")
    return ops[orientation](img).contiguous()


# Developing in strips of rows bounds memory: AHD needs about 430 bytes per pixel of a
# block (one block per thread), so a 24-megapixel frame developed whole peaks at ~3.5 GB.
DEVELOP_STRIP_ROWS = 256
DEVELOP_HALO_ROWS = 16  # even (keeps the CFA phase) and beyond AHD's reach (8 rows with one median pass)
DEVELOP_AHD_BLOCK_ROWS = 64


def develop_raw(
    raw: RawImage,
    sensor: SensorProfile | None = None,
    wb: str | float = AS_SHOT,
    method: str = "ahd",
    bits: int | None = None,
    orient: bool = True,
    strip_rows: int = DEVELOP_STRIP_ROWS,
) -> tuple[torch.Tensor, CaptureParams]:
    """Develop a raw file with the simulator's chain: :func:`normalized_mosaic`, then
    :func:`lensim.sensor.isp.raw_to_srgb` (white balance on the mosaic, demosaic
    ``method`` (AHD), CCM, sRGB curve, rounding to ``bits``; None: no rounding), then
    :func:`apply_orientation` when ``orient``. Returns (sRGB (3, H, W) float32 in [0, 1];
    (3, W, H) for orientations 5-8, capture parameters used).

    With AHD the frame is developed in strips of ``strip_rows`` rows, each with
    DEVELOP_HALO_ROWS rows of context above and below, which the chain's reach (pointwise
    levels, white balance, CCM and curve; AHD and its median filter within 8 rows) never
    crosses, so the result is the whole frame's (tested); AHD runs in blocks of
    DEVELOP_AHD_BLOCK_ROWS rows. Peak memory: the (3, H, W) float32 output plus one strip's
    temporaries (24 MP, measured: about 0.5 GB above the 0.3 GB output)."""
    params = capture_params(raw, sensor, wb)
    if str(method).lower() == "ahd":
        out = _develop_in_strips(raw, params, strip_rows)
    else:  # the other demosaicers' reach is not bounded here: the whole frame at once
        out = raw_to_srgb(normalized_mosaic(raw), params, method=method, bits=None)
    if bits is not None:
        out = quantize(out, bits)
    return (apply_orientation(out, raw.orientation) if orient else out), params


def _develop_in_strips(raw: RawImage, params: CaptureParams, rows: int) -> torch.Tensor:
    """AHD development of ``raw`` strip by strip (see :func:`develop_raw`): (3, H, W)."""
    h, w = raw.height, raw.width
    step = max(2, rows // 2 * 2)
    out = torch.empty(3, h, w, dtype=torch.float32)
    for y0 in range(0, h, step):
        y1 = min(h, y0 + step)
        a, b = max(0, y0 - DEVELOP_HALO_ROWS), min(h, y1 + DEVELOP_HALO_ROWS)
        strip = normalized_mosaic(replace(raw, mosaic=raw.mosaic[a:b]))
        out[:, y0:y1] = raw_to_srgb(strip, params, bits=None, block_rows=DEVELOP_AHD_BLOCK_ROWS)[:, y0 - a : y1 - a]
    return out


# ---------------------------------------------------------------- batches of files

OUTPUT_FORMATS = ("tif", "png")


def plan_outputs(files: list[Path], out_dir: Path, fmt: str) -> list[tuple[Path, Path]]:
    """(input, OUT/<stem>.<fmt>) for each file; two inputs with one stem are refused."""
    if fmt not in OUTPUT_FORMATS:
        raise ParameterError(None, "fmt", f"expected tif or png, got {fmt!r}")
    seen: dict[Path, Path] = {}
    for f in files:
        target = out_dir / f"{f.stem}.{fmt}"
        if target in seen:
            raise InputError(
                str(f), None, f"has the same name stem as {seen[target]}; both would be written to {target}"
            )
        seen[target] = f
    return [(f, t) for t, f in seen.items()]


def develop_files(
    files: list[Path],
    out_dir: Path,
    sensor: SensorProfile | None = None,
    wb: str | float = AS_SHOT,
    bits: int = 16,
    fmt: str = "tif",
    progress: Callable[[int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Develop raw files into OUT/<stem>.<fmt> (sRGB, tagged as such, ``bits`` 8 or 16).

    Every input that still needs developing is read and checked (its develop settings
    included) before the first output is written; finished outputs (already in
    ``out_dir``) are skipped, so a rerun resumes. Each output is written atomically.
    ``progress(done, total)`` is called after each file. Returns one record per file:
    input, output, skipped, and the capture parameters used."""
    if bits not in (8, 16):
        raise ParameterError(None, "bits", f"expected 8 or 16, got {bits!r}")
    choice = parse_wb(wb)
    jobs = plan_outputs(files, out_dir, fmt)
    todo = [(f, t) for f, t in jobs if not t.exists()]
    for f, _ in todo:  # validate everything first: nothing is written for a bad batch
        capture_params(read_raw(f), sensor, choice)
    records = [{"input": str(f), "output": str(t), "skipped": True} for f, t in jobs if t.exists()]
    if progress:
        progress(len(records), len(jobs))
    for f, target in todo:
        raw = read_raw(f)
        img, params = develop_raw(raw, sensor, choice, bits=None)
        write_image(target, img, bits, srgb_tag=True)
        records.append({"input": str(f), "output": str(target), "skipped": False, **params.to_dict()})
        if progress:
            progress(len(records), len(jobs))
    return records
