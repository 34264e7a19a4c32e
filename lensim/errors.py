"""Error types with one-line messages that name the file, the field and what was expected."""

from __future__ import annotations

import re
from collections.abc import Mapping


class LensimError(ValueError):
    """Base class of every error lensim raises on bad input."""


class InputError(LensimError):
    """Bad user input: names the source (file), the field and what was expected.

    str(err) is a single line: ``FILE: FIELD: MESSAGE``.
    """

    def __init__(self, source: str | None, field: str | None, message: str):
        self.source = source
        self.field = field
        self.message = message
        parts = [p for p in (source, field, message) if p]
        super().__init__(": ".join(str(p) for p in parts).replace("\n", " "))

    def __reduce__(self):
        """Pickle by the three parts, so an error raised in a worker process (psf bank and
        dataset make --workers) reaches the parent as the same one-line error."""
        return self.__class__, (self.source, self.field, self.message)


class ParameterError(InputError):
    """A bad argument: ``field`` is the parameter's Python name (``workers``, ``fno``; several
    joined by ", " or "/" when the error is about their combination), ``source`` the file it
    concerns or None. A message that points at another parameter quotes its name in
    backticks (`` `fno` ``).

    The library names parameters, never command-line options; the command line shows each
    name as its option (lensim.cli.common.error_for_command_line)."""

    @property
    def parameter(self) -> str:
        """The parameter's name (or names), as ``field``."""
        return self.field or ""


def renamed(error: ParameterError, names: Mapping[str, str]) -> ParameterError:
    """The error with the parameters it names (its field, and the `name`s its message quotes)
    renamed by ``names`` ({inner name: outer name}): for a function that passes its own
    parameters to another under that one's names (lensfun_profile's ``aperture`` is
    lens_at's ``fno``)."""

    def name(m: re.Match[str]) -> str:
        return names.get(m.group(0), m.group(0))

    def quoted(m: re.Match[str]) -> str:
        return f"`{names.get(m.group(1), m.group(1))}`"

    field = re.sub(r"[A-Za-z_][A-Za-z0-9_]*", name, error.field or "") or None
    return ParameterError(error.source, field, re.sub(r"`([A-Za-z_][A-Za-z0-9_]*)`", quoted, error.message))


class PupilSamplingError(InputError):
    """A pupil grid too coarse for the PSF window: its PSF would wrap around. ``needed``
    is the number of pupil samples across that the window needs."""

    def __init__(self, source: str | None, field: str | None, message: str, needed: int):
        super().__init__(source, field, message)
        self.needed = needed

    def __reduce__(self):
        return self.__class__, (self.source, self.field, self.message, self.needed)


class UnknownGlassError(InputError):
    """A material name that no catalogue knows."""


class RayTraceError(LensimError):
    """A ray that must reach the image (a chief ray, an aiming ray) could not be traced."""


class OutputError(InputError):
    """A file lensim could not write (the disk is full, a quota is reached, a read-only
    file system, ...): names the file, why, and what to do. The file itself is not left
    half-written (lensim.io.atomic_writer)."""


class OutOfMemory(InputError):
    """Not enough memory for a step of the work. ``field`` names the parameter that sizes
    it (the CLI names its option)."""


class NonFiniteError(InputError):
    """Training met a non-finite (NaN or infinite) loss or weights: ``field`` names the
    step ("step N"); the run folder keeps its last good checkpoint."""


class WorkerLostError(InputError):
    """A job's worker processes died (killed, out of memory) more often than the cluster
    retries a job: names the job."""


def out_of_memory(error: BaseException) -> bool:
    """Whether an exception is an allocation failure: MemoryError, or an engine's (PyTorch's
    CPU allocator or CUDA, onnxruntime) error that says so."""
    if isinstance(error, MemoryError):
        return True
    if isinstance(error, LensimError) or not isinstance(error, Exception):
        return False
    if type(error).__name__ == "OutOfMemoryError":  # torch.OutOfMemoryError (CUDA)
        return True
    text = str(error)
    return any(k in text for k in _ALLOCATION_FAILED)


#: what allocation failures say (PyTorch's CPU allocator, CUDA, onnxruntime, C++)
_ALLOCATION_FAILED = ("DefaultCPUAllocator", "can't allocate memory", "out of memory", "allocate memory", "bad_alloc")
