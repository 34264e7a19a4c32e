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

On disk a bank is a directory: ``manifest.json`` (every setting that shapes the kernels,
the lens as a native-format mapping, the spectral weights) and one ``field_XXXX.npz`` per
field, each written atomically. Rerunning with the same settings skips the fields already
on disk (resume after a kill); different settings are refused.

Modules: types (BankField, PSFBank and its kernel lookup), store (manifest, field files,
resume guard), compute (per-field work, plans of banks computed together as one job list,
build_bank), settings (BankSettings: what a bank is asked for; field positions, the
wavelength parser, kernel sizing), grid (GridBank: one bank per shooting setting under one
manifest), grid_interp (the nearest setting, kernels blended between settings).
Kernel rotation lives in lensim.render.rotation, the bank's figures in lensim.plots.bank.

Units: lengths mm, pixel pitch and PSF spacing um, wavelengths nm in the manifest and the
API of this module (um inside the optics code), angles in degrees.
"""

from lensim.psf.bank.compute import alias_free_pixels, build_bank, compute_bank, embed_centred
from lensim.psf.bank.grid import GridAxes, GridBank, compute_grid
from lensim.psf.bank.settings import (
    DEFAULT_FIELDS,
    BankSettings,
    default_fields,
    parse_wavelengths_nm,
    suggest_kernel_pixels,
)
from lensim.psf.bank.store import FORMAT, FORMAT_VERSION, MANIFEST, field_file, read_manifest
from lensim.psf.bank.types import BankField, Progress, PSFBank

__all__ = [
    "DEFAULT_FIELDS",
    "FORMAT",
    "FORMAT_VERSION",
    "MANIFEST",
    "BankField",
    "BankSettings",
    "GridAxes",
    "GridBank",
    "PSFBank",
    "Progress",
    "compute_grid",
    "alias_free_pixels",
    "build_bank",
    "compute_bank",
    "default_fields",
    "embed_centred",
    "field_file",
    "parse_wavelengths_nm",
    "read_manifest",
    "suggest_kernel_pixels",
]
