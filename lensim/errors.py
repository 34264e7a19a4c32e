"""Error types with one-line messages that name the file, the field and what was expected."""

from __future__ import annotations


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
