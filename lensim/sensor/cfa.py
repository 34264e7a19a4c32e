"""The Bayer colour filter array's vocabulary, in one place (plain Python, no NumPy or
torch: raw-file readers and the command line's help import it cheaply).

A pattern names the colours of the pixels (0,0) (0,1) (1,0) (1,1) of each 2x2 quad,
row-major, (0,0) the top-left pixel of the mosaic (lensim.sensor.isp's convention).
"""

from __future__ import annotations

from typing import Any, Literal, cast, get_args

from lensim.errors import InputError

CfaPattern = Literal["RGGB", "BGGR", "GRBG", "GBRG"]
#: every CfaPattern, in the order error messages list them
BAYER_PATTERNS: tuple[CfaPattern, ...] = get_args(CfaPattern)


def cfa_pattern(value: Any, src: str | None = None, field: str = "bayer_pattern") -> CfaPattern:
    """``value`` as a CfaPattern (any case; surrounding spaces ignored). Anything else:
    an InputError naming ``src`` (the file, None for a library argument) and ``field``."""
    text = value.strip().upper() if isinstance(value, str) else None
    if text not in BAYER_PATTERNS:
        raise InputError(src, field, f"expected one of {', '.join(BAYER_PATTERNS)}, got {value!r}")
    return cast(CfaPattern, text)
