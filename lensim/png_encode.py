"""A PNG encoder for 8- and 16-bit RGB frames that compresses on several threads.

Pillow's and pypng's encoders deflate the whole image on one thread (a 24 MP restored
photo: 2.5-3.6 s at zlib level 3, the last step of every `lensim restore`). Here every
row is given the PNG "Up" filter (each byte minus the byte above it, modulo 256: PNG spec
9.2, filter type 2), which numpy computes for the whole frame at once, and the filtered
rows are cut into blocks that zlib deflates side by side (it releases the GIL). Each block
but the last ends with a full flush, so the raw deflate blocks concatenate into one valid
zlib stream (RFC 1950: header, the deflate data, the Adler-32 of all the filtered bytes),
written as one IDAT chunk. Measured on a restored 6000 x 4000 8-bit photo, 2 threads of
this machine's CPU, others paused: 0.9 s instead of Pillow's 2.5-2.6 s (adaptive filters),
a file 1.3 % larger (23.60 against 23.30 MB); the Average filter would make it 4.7 %
smaller but costs 1.9 s to compute in numpy, Paeth 4.5 s.
"""

from __future__ import annotations

import struct
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: zlib's header for a 32 KiB window and FLEVEL 1 ("fast", levels 2-5), FCHECK making it a
#: multiple of 31 (RFC 1950 2.2)
_ZLIB_HEADER = b"\x78\x5e"
#: filtered bytes per deflate block (about 1 MB: 90 blocks for a 24 MP 8-bit frame, so the
#: threads stay busy until the end; each full flush costs a few bytes)
BLOCK_BYTES = 1 << 20


def _chunk(kind: bytes, body: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type and data."""
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)


def up_filtered(samples: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 or uint16 samples -> (H, 1 + W * 3 * bytes) uint8 scanlines, each
    led by filter type 2 (Up) and holding its big-endian bytes minus the row above's."""
    h, w, c = samples.shape
    data = samples.astype(">u2", copy=False) if samples.dtype == np.uint16 else samples
    rows = np.ascontiguousarray(data).view(np.uint8).reshape(h, -1)
    out = np.empty((h, rows.shape[1] + 1), dtype=np.uint8)
    out[:, 0] = 2
    out[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=out[1:, 1:])  # uint8 arithmetic wraps modulo 256
    return out


def _deflate_blocks(data: memoryview, level: int, threads: int) -> bytes:
    """A zlib stream of ``data`` deflated in blocks of BLOCK_BYTES on ``threads`` threads."""
    starts = list(range(0, len(data), BLOCK_BYTES)) or [0]

    def block(i: int) -> bytes:
        part = data[starts[i] : starts[i] + BLOCK_BYTES]
        co = zlib.compressobj(level, zlib.DEFLATED, -15)
        return co.compress(part) + co.flush(zlib.Z_FINISH if i == len(starts) - 1 else zlib.Z_FULL_FLUSH)

    if threads <= 1 or len(starts) == 1:
        body = b"".join(block(i) for i in range(len(starts)))
    else:
        with ThreadPoolExecutor(threads) as pool:
            body = b"".join(pool.map(block, range(len(starts))))
    return _ZLIB_HEADER + body + struct.pack(">I", zlib.adler32(data) & 0xFFFFFFFF)


def encode_png(samples: np.ndarray, level: int = 3, threads: int = 1, srgb: bool = False) -> bytes:
    """The bytes of an RGB PNG of ``samples`` ((H, W, 3) uint8 or uint16: bit depth 8 or
    16), deflated at zlib ``level`` on ``threads`` threads; ``srgb`` adds the sRGB chunk
    (rendering intent 0, perceptual: PNG spec 11.3.3.5)."""
    if samples.ndim != 3 or samples.shape[2] != 3 or samples.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"expected (H, W, 3) uint8 or uint16 samples, got {samples.shape} {samples.dtype}")
    h, w, _ = samples.shape
    bits = 8 if samples.dtype == np.uint8 else 16
    header = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bits, 2, 0, 0, 0))  # colour type 2: RGB
    srgb_chunk = _chunk(b"sRGB", b"\x00") if srgb else b""
    scanlines = up_filtered(samples).reshape(-1)  # contiguous: a view
    idat = _chunk(b"IDAT", _deflate_blocks(memoryview(scanlines.data), level, threads))
    return PNG_SIGNATURE + header + srgb_chunk + idat + _chunk(b"IEND", b"")
