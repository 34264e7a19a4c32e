"""glibc allocator settings for the CLI process.

PyTorch on CPU frees and reallocates large activation buffers at every training step. With
glibc's defaults each such buffer is a fresh mmap that the kernel must zero, then an
munmap: on the 2-core machines measured (the project notes' FACTS.md) this made system time dominate.
Serving large blocks from the heap and never trimming it (the effect of the environment
variables MALLOC_MMAP_MAX_=0 and MALLOC_TRIM_THRESHOLD_=1e11) sped a training step of the
default field-aware network up 1.13x at 96-px crops and 1.4x with deformable blocks at two
decoder scales; applied through mallopt as here, it halved the time to restore a
24-megapixel frame (benchmarks/restore_speed.py: 118 s against 239 s). The price is that
freed memory stays with the process until it exits (peak 1.60 against 1.45 GB for that
frame), which suits a command-line run. Library users who want the same set those variables
before starting Python.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

_M_TRIM_THRESHOLD = -1  # mallopt parameter numbers from glibc's malloc.h
_M_MMAP_MAX = -4


def keep_freed_memory() -> bool:
    """Apply the settings above through glibc's mallopt; True if applied. Does nothing
    (False) off glibc or when the user set either variable themselves."""
    if "MALLOC_MMAP_MAX_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS, Windows)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
