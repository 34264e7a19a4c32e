"""PSF banks: RGB pixel kernels over radial fields, stored on disk, resumable.

A bank samples the image field along +y at normalized fields 0..1 (of the lens's maximum
field). For each field and each bank wavelength lambda a fine PSF is computed (Huygens by
default) on a (k*P) x (k*P) grid with spacing pixel_pitch / k, centred on the field's
chief-ray point at the lens's PRIMARY wavelength (the reference point), so lateral colour
shows as a shift inside the kernel. The fine PSF is integrated exactly over the P x P
pixels (lensim.psf.pixels), normalized to unit sum, multiplied by the relative
illumination C_ill(fov, lambda) and by the camera's channel weights C_wav(lambda), and
summed over lambda into R, G, B kernels (the paper's Eq. 10):

    K_c(fov) = sum_lambda C_wav,c(lambda) * C_ill(fov, lambda) * PSF_pix(fov, lambda) / sum PSF_pix.

Each channel's weights sum to 1 (lensim.sensor.spectral), so a kernel sums to the
channel-weighted relative illumination: 1 on axis, less off axis.

Relative illumination comes from lensim.optics.field_analysis.relative_illumination
(projected solid angle of the image-space beam, with vignetting, normalized on axis),
evaluated per field and wavelength.

Getting a bank: get_bank (one bank, or a grid of banks over shooting settings) and
get_banks (many requests, BankRequest, computed together on one cluster) are the one public
way. BankSettings, the one set of bank defaults, says how the bank samples the lens; the
bank comes from its folder (given, or the cache), computed or finished when incomplete,
here, on local Dask workers or on a Dask cluster by address. bank_lens gives the lens a
bank was computed for, or checks that a given lens is that lens.

On disk a bank is a directory: ``manifest.json`` (every setting that shapes the kernels,
the lens as a native-format mapping, the spectral weights) and one ``field_XXXX.npz`` per
field, each written atomically. Rerunning with the same settings skips the fields already
on disk (resume after a kill); different settings are refused.

Modules: request (get_bank, get_banks, BankRequest: the one way to get banks), settings
(BankSettings: what a bank is asked for; field positions, the wavelength parser, kernel
sizing), types (BankField, PSFBank and its kernel lookup), store (manifest, field files,
resume guard), compute (private: per-field work, plans of banks computed together as one
job list), grid (GridBank: one bank per shooting setting under one manifest), grid_interp
(the nearest setting, kernels blended between settings), lens (bank_lens: the lens that
goes with a bank).
Kernel rotation lives in lensim.render.rotation, the bank's figures in lensim.plots.bank.

Units: lengths mm, pixel pitch and PSF spacing um, wavelengths nm in the manifest and the
API of this module (um inside the optics code), angles in degrees.
"""

from lensim.psf.bank.compute import alias_free_pixels, embed_centred
from lensim.psf.bank.grid import GridAxes, GridBank
from lensim.psf.bank.lens import bank_lens
from lensim.psf.bank.request import BankRequest, get_bank, get_banks
from lensim.psf.bank.settings import (
    BankSettings,
    default_fields,
    parse_wavelengths_nm,
    suggest_kernel_pixels,
)
from lensim.psf.bank.store import FORMAT, FORMAT_VERSION, MANIFEST, field_file, read_manifest
from lensim.psf.bank.types import BankField, Progress, PSFBank

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "MANIFEST",
    "BankField",
    "BankRequest",
    "BankSettings",
    "GridAxes",
    "GridBank",
    "PSFBank",
    "Progress",
    "alias_free_pixels",
    "bank_lens",
    "default_fields",
    "embed_centred",
    "field_file",
    "get_bank",
    "get_banks",
    "parse_wavelengths_nm",
    "read_manifest",
    "suggest_kernel_pixels",
]
