"""The PSF choices and defaults the command line shows in its help, in plain Python (no
NumPy or torch), so that `lensim --help` loads none of the PSF stack. lensim.psf.compute
and lensim.psf.bank.settings (BankSettings) take them from here.

Units: wavelengths nm.
"""

from __future__ import annotations

#: the PSF models of lensim.psf.compute.compute_psf (and of the banks)
METHODS = ("huygens", "fft", "geometric")

#: BankSettings' defaults, shared by `psf bank`, `simulate` and `dataset make`: radial
#: fields, pupil samples across the diameter, wavelengths as typed on the command line (16, nm)
BANK_FIELDS = 32
BANK_PUPIL_SAMPLES = 128
DEFAULT_WAVELENGTHS_TEXT = "400:700:20"
