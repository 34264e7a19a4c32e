"""The PSF choices and defaults the command line shows in its help, in plain Python (no
NumPy or torch), so that `lensim --help` loads none of the PSF stack. lensim.psf.compute
and lensim.psf.bank.settings (BankSettings) take them from here.

Units: wavelengths nm.
"""

from __future__ import annotations

from typing import Any, Literal, cast, get_args

from lensim.errors import InputError

#: the PSF models of lensim.psf.compute.compute_psf (and of the banks): the Huygens sum
#: over the exit pupil, the FFT of the pupil function, or the geometric spot histogram
PsfMethod = Literal["huygens", "fft", "geometric"]
METHODS: tuple[PsfMethod, ...] = get_args(PsfMethod)

#: BankSettings' defaults, shared by `psf bank`, `simulate` and `dataset make`: radial
#: fields, pupil samples across the diameter, wavelengths as typed on the command line (16, nm)
BANK_FIELDS = 32
BANK_PUPIL_SAMPLES = 128
DEFAULT_WAVELENGTHS_TEXT = "400:700:20"


def psf_method(value: Any, src: str | None = None, field: str | None = "method") -> PsfMethod:
    """``value`` as a PsfMethod; anything else is an InputError naming ``src`` (a file, or
    None for a library argument) and ``field``."""
    if value not in METHODS:
        raise InputError(src, field, f"expected one of {', '.join(METHODS)}, got {value!r}")
    return cast(PsfMethod, value)
