"""The command line's input checks, shared by every command and run before any work:
paths (an input exists and is the right kind; an output's place can hold it), numbers
(finite, in range, the unit in the message) and names (devices, choices, formats).

Each check raises a one-line :class:`lensim.errors.InputError` naming the option (or the
file) and what was expected, and returns the checked value, so a command reads
``pitch = positive(pixel_um, "--pixel-um", "um")``.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TypeVar

from lensim.errors import InputError
from lensim.optics.aiming.modes import AIMINGS

T = TypeVar("T")


# ---------------------------------------------------------------- paths


def input_file(path: str | Path, option: str | None = None, what: str = "file") -> Path:
    """An existing, readable file (not a folder)."""
    p = Path(path)
    where = f" ({option})" if option else ""
    if not p.exists():
        raise InputError(str(p), None, f"no such {what}{where}")
    if p.is_dir():
        raise InputError(str(p), None, f"is a folder; expected a {what}{where}")
    if not os.access(p, os.R_OK):
        raise InputError(str(p), None, f"cannot be read (permission denied); expected a readable {what}{where}")
    return p


def input_folder(path: str | Path, option: str | None = None, what: str = "folder") -> Path:
    """An existing folder."""
    p = Path(path)
    where = f" ({option})" if option else ""
    if not p.exists():
        raise InputError(str(p), None, f"no such {what}{where}")
    if not p.is_dir():
        raise InputError(str(p), None, f"is a file; expected a {what}{where}")
    return p


def _nearest_existing(p: Path) -> Path:
    """The path itself or its nearest existing ancestor (the folder a write would start in)."""
    q = p.absolute()
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def _check_place(p: Path, option: str) -> None:
    """Every existing ancestor of ``p`` is a folder, and the nearest one takes new files."""
    base = _nearest_existing(p.parent)
    if not base.is_dir():
        raise InputError(str(p), option, f"cannot be created: {base} is a file, not a folder")
    try:  # os.access says yes to root everywhere; a real probe also catches /proc and read-only mounts
        fd, probe = tempfile.mkstemp(prefix=".lensim-probe-", dir=base)
    except OSError as e:
        raise InputError(str(p), option, f"cannot be written: {base}: {e.strerror or e}") from None
    os.close(fd)
    os.unlink(probe)


def output_file(path: str | Path, option: str = "--output", suffixes: Sequence[str] | None = None) -> Path:
    """A file to write: not an existing folder, its place writable, and (when given) one
    of ``suffixes`` (lower case, with the dot)."""
    p = Path(path)
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise InputError(str(p), option, f"expected a file name ending in {' or '.join(suffixes)}")
    if p.is_dir():
        raise InputError(str(p), option, "is a folder; expected a file name to write")
    _check_place(p, option)
    return p


def output_folder(path: str | Path, option: str = "--output") -> Path:
    """A folder to write into (made when missing): not an existing file, its place writable."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(str(p), option, "is a file; expected a folder (new or existing)")
    _check_place(p / "x", option)
    return p


def distinct_outputs(inputs: Iterable[Path], name: Callable[[Path], str], option: str = "--output") -> None:
    """Refuse inputs that would write the same output file name (two photos called x.png
    in different folders would overwrite each other's OUT/x.png)."""
    seen: dict[str, Path] = {}
    for p in inputs:
        key = name(p)
        if key in seen and seen[key] != p:
            raise InputError(
                str(p),
                option,
                f"would write the same output {key} as {seen[key]}; expected inputs with different names",
            )
        seen[key] = p


# ---------------------------------------------------------------- numbers


def _shown(value: float, unit: str) -> str:
    return f"{value:g}{' ' + unit if unit else ''}"


def finite(value: float, option: str, unit: str = "") -> float:
    if not math.isfinite(value):
        raise InputError(option, None, f"expected a finite number{' in ' + unit if unit else ''}, got {value}")
    return value


def positive(value: float, option: str, unit: str = "", what: str = "a value") -> float:
    """A finite value above 0."""
    finite(value, option, unit)
    if not value > 0:
        raise InputError(
            option, None, f"expected {what} above 0{' ' + unit if unit else ''}, got {_shown(value, unit)}"
        )
    return value


def at_least(value: float, low: float, option: str, unit: str = "", what: str = "a value") -> float:
    """A finite value >= low."""
    finite(value, option, unit)
    if value < low:
        raise InputError(option, None, f"expected {what} of at least {_shown(low, unit)}, got {_shown(value, unit)}")
    return value


def in_range(
    value: float, low: float, high: float, option: str, unit: str = "", what: str = "a value", high_open: bool = False
) -> float:
    """A finite value in [low, high] ([low, high) with high_open)."""
    finite(value, option, unit)
    if not (low <= value < high if high_open else low <= value <= high):
        end = ")" if high_open else "]"
        raise InputError(
            option,
            None,
            f"expected {what} in [{low:g}, {high:g}{end}{' ' + unit if unit else ''}, got {_shown(value, unit)}",
        )
    return value


def even(value: int, option: str, what: str = "a size in pixels") -> int:
    if value <= 0 or value % 2:
        raise InputError(option, None, f"expected {what} that is even and above 0, got {value}")
    return value


#: wavelengths lensim's glass data and PSFs make sense for (nm)
WAVELENGTH_RANGE_NM = (200.0, 15000.0)


def wavelength_nm(value: float, option: str = "--wavelength-nm") -> float:
    low, high = WAVELENGTH_RANGE_NM
    return in_range(value, low, high, option, "nm", "a wavelength")


def pixel_pitch_um(value: float, option: str = "--pixel-um") -> float:
    """A sensor pixel pitch in micrometres within lensim.sensor.profile.PIXEL_PITCH_RANGE_UM."""
    from lensim.sensor.profile import PIXEL_PITCH_RANGE_UM, pitch_out_of_range

    finite(value, option, "um")
    low, high = PIXEL_PITCH_RANGE_UM
    if not low <= value <= high:
        raise InputError(option, None, pitch_out_of_range(value))
    return value


# ---------------------------------------------------------------- names


def choice(value: T, choices: Sequence[T], option: str) -> T:
    """One of ``choices`` (names, or numbers such as bit depths)."""
    if value not in choices:
        raise InputError(option, None, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
    return value


def device(name: str, option: str = "--device") -> str:
    """A torch device this machine has: cpu, cuda or cuda:N with N below the GPU count
    (mps where PyTorch has it)."""
    import torch

    name = name.strip()
    if name == "cpu":
        return name
    if name == "mps" and getattr(torch.backends, "mps", None) is not None and torch.backends.mps.is_available():
        return name
    kind, _, index = name.partition(":")
    if kind != "cuda" or (index and not index.isdigit()):
        raise InputError(option, None, f"expected cpu, cuda or cuda:N, got {name!r}")
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if count == 0:
        raise InputError(option, None, f"{name!r} requested but CUDA is not available on this machine; expected cpu")
    if index and int(index) >= count:
        raise InputError(
            option, None, f"{name!r} requested but this machine has {count} CUDA device(s) (cuda:0..cuda:{count - 1})"
        )
    return name


#: the transports a Dask scheduler address may name (tcp://host:port, ...)
DASK_PROTOCOLS = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def scheduler_address(address: str | None, option: str = "--scheduler") -> str | None:
    """A Dask scheduler address: [PROTOCOL://]HOST[:PORT] (PROTOCOL one of
    DASK_PROTOCOLS, PORT 1..65535; an IPv6 host in brackets), or None. Whether a
    scheduler answers there is known only when connecting (lensim.workers.run_jobs)."""
    if address is None:
        return None
    text = address.strip()
    m = re.fullmatch(
        r"(?:(?P<proto>[a-z]+)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+)(?::(?P<port>\d{1,5}))?", text
    )
    ok = (
        m is not None
        and (m["proto"] is None or m["proto"] in DASK_PROTOCOLS)
        and (m["port"] is None or 1 <= int(m["port"]) <= 65535)
    )
    if not ok:
        raise InputError(
            option,
            None,
            f"expected a Dask scheduler address such as tcp://10.0.0.5:8786 "
            f"([{'|'.join(DASK_PROTOCOLS)}://]HOST[:PORT]), got {address!r}",
        )
    return text


__all__ = [
    "AIMINGS",
    "at_least",
    "choice",
    "device",
    "distinct_outputs",
    "even",
    "finite",
    "in_range",
    "input_file",
    "input_folder",
    "output_file",
    "output_folder",
    "pixel_pitch_um",
    "positive",
    "scheduler_address",
    "wavelength_nm",
]
