"""Reading and writing photos: 8/16-bit PNG, TIFF and JPEG in; PNG and TIFF out.

Images are float32 tensors (3, H, W) in [0, 1] (sRGB-encoded values as stored in the
file). Grayscale is expanded to three equal channels; an alpha channel is refused unless
it is fully opaque (then dropped), since transparent pixels have no defined colour.
Writes are atomic (temporary name, then rename).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lensim.errors import InputError
from lensim.io import atomic_write_bytes, atomic_writer

READ_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")
WRITE_SUFFIXES = (".png", ".tif", ".tiff")


def read_image(path: str | Path) -> tuple[torch.Tensor, int]:
    """(image (3, H, W) float32 in [0, 1], bit depth 8 or 16) from a PNG/TIFF/JPEG file."""
    path = Path(path)
    src = str(path)
    if path.suffix.lower() not in READ_SUFFIXES:
        raise InputError(src, "format", f"expected one of {', '.join(READ_SUFFIXES)}")
    if not path.is_file():
        raise InputError(src, None, "no such file")
    try:
        arr = _decode(path, src)
    except InputError:
        raise
    except Exception as e:  # a corrupt or truncated file
        raise InputError(src, None, f"cannot be decoded as an image ({type(e).__name__}: {e})") from None
    arr, bits = _opaque_rgb(np.asarray(arr), src)
    if min(arr.shape[:2]) < 16:
        raise InputError(src, "size", f"image is {arr.shape[1]}x{arr.shape[0]}; expected at least 16x16 pixels")
    scale = 255.0 if bits == 8 else 65535.0
    # in torch (multithreaded): 0.3 s instead of numpy's 0.9-1.8 s for a 24 MP photo, same values
    img = torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1)
    return img.to(torch.float32, memory_format=torch.contiguous_format).div_(scale), bits


def _decode(path: Path, src: str) -> np.ndarray:
    """The file's samples as stored: (H, W) or (H, W, channels), bool, uint8 or uint16."""
    if path.suffix.lower() in (".tif", ".tiff"):
        return _read_tiff(path, src)
    from PIL import Image

    if _png_bit_depth(path) == 16:
        return _read_png16(path)
    with Image.open(path) as im:
        if im.mode in ("I;16", "I;16B", "I;16L", "I"):
            return np.array(im).astype(np.uint16)
        if im.mode in ("P", "PA"):
            return np.array(im.convert("RGBA"))
        if im.mode in ("1", "L", "LA", "RGB", "RGBA"):
            return np.array(im)
        raise InputError(src, "mode", f"unsupported pixel mode {im.mode}; expected grayscale, RGB or RGBA")


def _opaque_rgb(arr: np.ndarray, src: str) -> tuple[np.ndarray, int]:
    """(H, W, 3) samples and their bit depth (8 or 16) from decoded samples: gray expanded
    to three channels, a fully opaque alpha channel dropped (a transparent one refused)."""
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8) * 255
    if arr.dtype == np.uint8:
        bits = 8
    elif arr.dtype == np.uint16:
        bits = 16
    else:
        raise InputError(src, "bit depth", f"expected 8- or 16-bit integer samples, got {arr.dtype}")
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (2, 3, 4):
        raise InputError(src, "channels", f"expected 1 (gray), 3 (RGB) or 4 (RGBA) channels, got shape {arr.shape}")
    if arr.shape[2] in (2, 4):
        alpha = arr[..., -1]
        if alpha.min() < (255 if bits == 8 else 65535):
            raise InputError(src, "alpha", "has transparent pixels; expected an opaque image (flatten it first)")
        arr = arr[..., :-1]
        if arr.shape[2] == 1:
            arr = np.repeat(arr, 3, axis=2)
    return arr, bits


def _read_tiff(path: Path, src: str) -> np.ndarray:
    """A TIFF's first series as (H, W) or (H, W, samples), planar RGB (one plane per
    channel) included; CMYK (photometric "separated") is refused, never read as RGB."""
    import tifffile

    with tifffile.TiffFile(path) as tf:
        page = tf.pages.first
        if int(page.photometric) == int(tifffile.PHOTOMETRIC.SEPARATED):
            raise InputError(
                src,
                "photometric",
                f"is a CMYK (separated) TIFF with {page.samplesperpixel} inks; "
                "expected RGB or grayscale (convert it to RGB first)",
            )
        arr = tf.asarray()  # the first series (all its pages), as tifffile.imread reads it
        planar = int(page.planarconfig) == int(tifffile.PLANARCONFIG.SEPARATE)
        rgb = int(page.photometric) == int(tifffile.PHOTOMETRIC.RGB)
        if planar and rgb and arr.ndim == 3 and arr.shape[0] == page.samplesperpixel:
            arr = np.moveaxis(arr, 0, -1)  # (samples, H, W) -> (H, W, samples)
    return arr


def _png_bit_depth(path: Path) -> int:
    """Bit depth from the PNG header (byte 24 of the IHDR chunk)."""
    with open(path, "rb") as fh:
        head = fh.read(25)
    return head[24] if len(head) == 25 and head[:8] == b"\x89PNG\r\n\x1a\n" else 8


def _read_png16(path: Path) -> np.ndarray:
    """A 16-bit PNG as uint16 (H, W) or (H, W, C), C = 3 (RGB) or 4 (RGBA; OpenCV gives
    gray with alpha as RGBA too), through OpenCV (Pillow truncates 16-bit RGB to 8 bits). A
    24 MP frame: 2.4 s instead of pypng's 28.5 s."""
    import cv2

    data = np.fromfile(path, dtype=np.uint8)  # not cv2.imread: any path, and no silent None
    arr = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if arr is None:
        raise ValueError("OpenCV could not decode it")
    if arr.ndim == 3:  # OpenCV's channel order is BGR(A)
        arr = cv2.cvtColor(arr, cv2.COLOR_BGRA2RGBA if arr.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return arr


#: zlib level of the PNGs lensim writes (lensim.png_encode). Level 3 instead of zlib's
#: default 6: a 24 MP 8-bit restored photo took 3.1-3.3 s of CPU instead of 9.5-9.8 s with
#: Pillow's encoder, and its file grew from 19.1 to 21.0 MB (level 1: 2.3 s, 22.4 MB).
PNG_COMPRESS_LEVEL = 3


def write_image(path: str | Path, image: torch.Tensor, bits: int = 8, srgb_tag: bool = False) -> None:
    """Write a (3, H, W) float image in [0, 1] as 8- or 16-bit PNG or TIFF, atomically.
    ``srgb_tag`` marks the file as sRGB: an embedded sRGB ICC profile in a TIFF, the
    sRGB chunk (rendering intent perceptual) in a PNG."""
    path = Path(path)
    if path.suffix.lower() not in WRITE_SUFFIXES:
        raise InputError(str(path), "format", f"expected one of {', '.join(WRITE_SUFFIXES)} for output")
    if bits not in (8, 16):
        raise InputError(str(path), "bit depth", f"expected 8 or 16, got {bits}")
    q = _quantized(image, bits)
    if path.suffix.lower() != ".png":
        import tifffile

        with atomic_writer(path, suffix=path.suffix) as fh:  # straight to the file: no second copy in memory
            tifffile.imwrite(fh, q, photometric="rgb", iccprofile=srgb_icc_profile() if srgb_tag else None)
        return
    from lensim.png_encode import encode_png

    # deflated on as many threads as torch computes with
    atomic_write_bytes(path, encode_png(q, PNG_COMPRESS_LEVEL, max(1, torch.get_num_threads()), srgb_tag))


def _quantized(image: torch.Tensor, bits: int, block_rows: int = 256) -> np.ndarray:
    """(3, H, W) float in [0, 1] -> (H, W, 3) uint8 or uint16, round(clip(x) * max), in
    blocks of rows so that a large frame needs no float copies of itself."""
    _, h, w = image.shape
    q = np.empty((h, w, 3), dtype=np.uint8 if bits == 8 else np.uint16)
    maxv = 255 if bits == 8 else 65535
    for y0 in range(0, h, block_rows):
        blk = image[:, y0 : y0 + block_rows].detach().cpu().clamp(0, 1).numpy().transpose(1, 2, 0)
        q[y0 : y0 + block_rows] = np.round(blk * maxv)
    return q


#: the creation date written into the sRGB ICC profile's header (ICC.1 7.2.8: year, month,
#: day, hours, minutes, seconds as big-endian uInt16), fixed so that the same photo always
#: gives the same file (LittleCMS writes the time it made the profile)
_ICC_DATE = (2024, 1, 1, 0, 0, 0)


def srgb_icc_profile() -> bytes:
    """An sRGB ICC profile (LittleCMS's built-in sRGB, through Pillow's ImageCms), the
    same bytes every time (its creation date set to _ICC_DATE; it carries no profile ID)."""
    import struct

    from PIL import ImageCms

    data = bytearray(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    data[24:36] = struct.pack(">6H", *_ICC_DATE)
    return bytes(data)
