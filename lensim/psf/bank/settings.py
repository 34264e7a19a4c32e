"""What a PSF bank is asked for: BankSettings (fields, their spacing, wavelengths, pupil
samples, ray aiming, kernel size, PSF method, sampling, illuminant, cache location), the
one set of bank defaults and the one way every command, the demo and the Python API
(lensim.psf.bank.get_bank) ask for a bank, so the same request always names the same
cached bank.

Also the field positions (square-root spacing, denser towards the edge) and the one
parser of wavelength lists typed on the command line.

Units: wavelengths nm, normalized fields 0..1 (of the lens's maximum field), spacings um.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np

from lensim.errors import InputError, ParameterError, PupilSamplingError
from lensim.io import default_cache_dir
from lensim.optics.aiming.modes import Aiming
from lensim.optics.lens import Lens
from lensim.psf.defaults import BANK_FIELDS, BANK_PUPIL_SAMPLES, DEFAULT_WAVELENGTHS_TEXT, PsfMethod, psf_method

FIELD_SPACINGS = ("sqrt", "linear")
_SOURCE = "bank settings"


def default_fields(n: int) -> np.ndarray:
    """n normalized radial fields 0..1 spaced as sqrt(t), t uniform: denser towards the
    edge, where the PSF changes fastest and where the image area per field is largest.
    One field is the axis alone."""
    if n < 1:
        raise InputError(None, "fields", f"expected at least 1 field, got {n}")
    if n == 1:
        return np.zeros(1)
    return np.sqrt(np.arange(n) / (n - 1))


def field_positions(n: int, spacing: str = "sqrt") -> np.ndarray:
    """n normalized fields 0..1: 'sqrt' (default_fields) or 'linear' (evenly spaced)."""
    if spacing not in FIELD_SPACINGS:
        raise InputError(_SOURCE, "field_spacing", f"expected one of {', '.join(FIELD_SPACINGS)}, got {spacing!r}")
    if spacing == "linear" and n > 1:
        return np.arange(n) / (n - 1)
    return default_fields(n)


def parse_wavelengths_nm(text: str) -> tuple[float, ...]:
    """Wavelengths (nm) as typed: 'START:STOP:STEP' or a comma list.

    A range runs from START in steps of STEP and includes STOP only when a step lands on
    it: '400:700:10' gives 31 values 400..700, '400:700:7' gives 43 values 400..694. The
    values must be positive and strictly increasing."""
    spec = text.strip()
    try:
        if ":" in spec:
            start, stop, step = (float(p) for p in spec.split(":"))  # not three parts: ValueError
            if not all(math.isfinite(v) for v in (start, stop, step)) or step <= 0 or stop < start:
                raise ValueError
            count = math.floor((stop - start) / step + 1e-9) + 1
            values = tuple(start + step * i for i in range(count))
        else:
            values = tuple(float(p) for p in spec.split(",") if p.strip())
    except ValueError:
        raise ParameterError(
            None,
            "wavelengths_nm",
            f"expected START:STOP:STEP (e.g. 400:700:10) or a comma list in nm, got {text!r}",
        ) from None
    if (
        not values
        or not all(math.isfinite(v) and v > 0 for v in values)
        or any(b <= a for a, b in zip(values, values[1:]))
    ):
        raise ParameterError(
            None,
            "wavelengths_nm",
            f"expected positive, strictly increasing wavelengths in nm, got {text!r}",
        )
    return values


def suggest_kernel_pixels(lens: Lens, pitch_um: float, limit: int = 99) -> int:
    """An odd kernel size (pixels) holding the polychromatic spot at every field: twice the
    radius (about the primary chief ray) that holds 98 % of the traced rays at the worst
    field (400-700 nm, fields 0..1), plus 3 Airy radii of margin for diffraction, at least
    7 and at most `limit`."""
    import torch

    from lensim.optics.aiming.rays import generate_rays, object_field, trace_chief_rays
    from lensim.optics.aiming.sampling import hexapolar
    from lensim.optics.paraxial import paraxial_data
    from lensim.optics.trace import trace, without_fused_kernel

    para = paraxial_data(lens)
    with without_fused_kernel():  # a few thousand rays, before a cached bank is found: no numba start-up
        fields = [object_field(lens, f * lens.max_field, "real", para) for f in (0.0, 0.5, 0.7, 0.85, 1.0)]
        pupil = torch.cat([torch.zeros(1, 2, dtype=torch.float64), hexapolar(8)])
        rays, wl = generate_rays(lens, fields, pupil, [lens.primary_wavelength_um, 0.40, 0.70], "real", para)
        chief = trace_chief_rays(lens, rays.select(0), wl, fields, "real", para).rays.position[0, :, 0, :2]
        res = trace(lens, rays.select(slice(1, None)), wl)
    d = torch.linalg.norm(res.rays.position[..., :2] - chief.unsqueeze(0).unsqueeze(2), dim=-1)
    reach_um = 0.0
    for fi in range(len(fields)):
        ok = res.rays.valid[:, fi]
        if bool(ok.any()):
            reach_um = max(reach_um, float(torch.quantile(d[:, fi][ok], 0.98)) * 1e3)
    reach_um += 3 * 1.22 * 0.7 * para.working_fno
    p = 2 * math.ceil(reach_um / pitch_um) + 1
    return int(min(max(p, 7), limit if limit % 2 else limit - 1))


#: the default bank wavelengths as typed on the command line (lensim.psf.defaults), and their values (16, nm)
DEFAULT_WAVELENGTHS_NM = parse_wavelengths_nm(DEFAULT_WAVELENGTHS_TEXT)


#: the settings that joined BankSettings later: in a cache key only when they differ from
#: these defaults, so the banks cached before keep their folders
_KEYED_WHEN_SET = {"method": "huygens", "max_spacing_um": None, "illuminant": "E", "ri_samples": 32}


@dataclass(frozen=True)
class BankSettings:
    """How a bank samples the lens, apart from the lens, the pixel pitch and the spectral
    response: the one set of bank defaults, and the one way the CLI commands, the demo and
    lensim.psf.bank.get_bank ask for a bank.

    fields: the number of normalized radial fields 0..1 (at least 2: the axis and the
    edge; kernels are interpolated between them), spaced by field_spacing ('sqrt': denser
    towards the edge, or 'linear'), or the normalized fields themselves (a strictly
    increasing tuple in 0..1); wavelengths_nm: strictly increasing (nm); pupil_samples:
    pupil grid across the diameter; aiming: 'real' or 'paraxial'; kernel_pixels: odd
    kernel size, or None to size it from the lens's spots (suggest_kernel_pixels, at most
    kernel_limit); method: 'huygens', 'fft' or 'geometric'; max_spacing_um: the largest
    fine PSF sample spacing (um), None for half the Airy radius 1.22 lambda_min N_w at the
    shortest wavelength (N_w the on-axis working F-number; the fine spacing is pitch / k
    with k the smallest odd integer that meets it); illuminant: the light the spectral
    response is weighted under ('E' equal energy, 'D65', ...); ri_samples: pupil samples
    of the relative-illumination calculation; cache_dir: the bank cache (None:
    $LENSIM_CACHE or ~/.cache/lensim).

    The defaults, shared by `psf bank`, `simulate`, `dataset make` and the Python API: 32
    sqrt-spaced fields, 400-700 nm every 20 nm, 128 pupil samples, real aiming, kernels
    sized from the spots, Huygens PSFs under equal-energy light. At native sensor pitch 128
    pupil samples keep the alias-free window as wide as the kernel down to 400 nm (64 leave
    29 of the Cooke triplet's 35 px on APS-C)."""

    fields: int | tuple[float, ...] = BANK_FIELDS
    field_spacing: str = "sqrt"
    wavelengths_nm: tuple[float, ...] = DEFAULT_WAVELENGTHS_NM
    pupil_samples: int = BANK_PUPIL_SAMPLES
    aiming: Aiming = "real"
    kernel_pixels: int | None = None
    kernel_limit: int = 99
    method: PsfMethod = "huygens"
    max_spacing_um: float | None = None
    illuminant: str = "E"
    ri_samples: int = 32
    cache_dir: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "wavelengths_nm", tuple(float(w) for w in self.wavelengths_nm))
        self._check_fields()
        wl = self.wavelengths_nm
        if not wl or not all(math.isfinite(w) and w > 0 for w in wl) or any(b <= a for a, b in zip(wl, wl[1:])):
            raise InputError(
                _SOURCE, "wavelengths_nm", f"expected positive, strictly increasing wavelengths (nm), got {wl}"
            )
        if self.pupil_samples < 8:
            raise InputError(_SOURCE, "pupil_samples", f"expected at least 8 pupil samples, got {self.pupil_samples}")
        if self.aiming not in ("real", "paraxial"):
            raise InputError(_SOURCE, "aiming", f"expected real or paraxial, got {self.aiming!r}")
        psf_method(self.method, _SOURCE)
        spacing = self.max_spacing_um
        if spacing is not None and not (math.isfinite(spacing) and spacing > 0):
            raise InputError(_SOURCE, "max_spacing_um", f"expected a positive spacing (um), got {spacing}")
        if self.ri_samples < 1:
            raise InputError(_SOURCE, "ri_samples", f"expected at least 1 pupil sample, got {self.ri_samples}")
        for name in ("kernel_pixels", "kernel_limit"):
            value = getattr(self, name)
            if value is not None and (value < 1 or (name == "kernel_pixels" and value % 2 == 0)):
                raise InputError(
                    _SOURCE,
                    name,
                    f"expected a positive{' odd' if name == 'kernel_pixels' else ''} number of pixels, got {value}",
                )

    def _check_fields(self) -> None:
        """fields: a count of at least 2, or strictly increasing normalized fields 0..1."""
        field_positions(2, self.field_spacing)  # checks the spacing's name
        if isinstance(self.fields, (int, np.integer)):
            if self.fields < 2:
                raise InputError(
                    _SOURCE,
                    "fields",
                    f"expected at least 2 fields (the axis and the edge of the field), got {self.fields}",
                )
            return
        f = tuple(float(v) for v in self.fields)
        object.__setattr__(self, "fields", f)
        if not f:
            raise InputError(_SOURCE, "fields", "expected at least one normalized field")
        if not all(math.isfinite(v) for v in f) or min(f) < 0 or max(f) > 1 + 1e-9:
            raise InputError(
                _SOURCE, "fields", f"expected normalized fields between 0 and 1, got {min(f):g}..{max(f):g}"
            )
        if any(b <= a for a, b in zip(f, f[1:])):
            raise InputError(_SOURCE, "fields", "expected strictly increasing normalized fields")

    def field_positions(self) -> np.ndarray:
        """(fields,) normalized field positions 0..1."""
        if isinstance(self.fields, tuple):
            return np.asarray(self.fields, dtype=np.float64)
        return field_positions(self.fields, self.field_spacing)

    def kernel_size(self, lens: Lens, pitch_um: float) -> int:
        """The kernel size (pixels) for this lens at this pitch (um)."""
        return self.kernel_pixels or suggest_kernel_pixels(lens, pitch_um, self.kernel_limit)

    def cache_root(self) -> Path:
        """The bank cache folder."""
        return Path(self.cache_dir) if self.cache_dir is not None else default_cache_dir()

    def key_options(self) -> dict:
        """The settings that shape the kernels, as a cache key holds them (the lens, pitch,
        kernel size and response aside)."""
        keyed = {
            "fields": [float(f) for f in self.field_positions()],
            "wavelengths_nm": list(self.wavelengths_nm),
            "pupil_samples": int(self.pupil_samples),
            "aiming": self.aiming,
        }
        keyed.update({k: getattr(self, k) for k, v in _KEYED_WHEN_SET.items() if getattr(self, k) != v})
        return keyed

    def cache_key(self, lens: Lens, pitch_um: float, kernel_pixels: int, response: object) -> str:
        """A short hash naming the cached bank of this lens (as a native mapping) at this
        pitch (um), kernel size and spectral response (a name, path or mapping; None for
        the default camera) with these settings."""
        from lensim.optics.lens_file import lens_to_dict

        blob = json.dumps(
            {
                "lens": lens_to_dict(lens),
                "pitch_um": round(pitch_um, 9),
                "kernel": kernel_pixels,
                "response": response,
                **self.key_options(),
            },
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


T = TypeVar("T")
#: how many banks with_enough_pupil_samples computes at most (the first, then one per raise)
PUPIL_TRIES = 4


def pupil_samples_for(needed: int) -> int:
    """The pupil samples to compute with when a kernel window needs ``needed``: 15 % more,
    rounded up to a multiple of 8."""
    return -(-int(needed * 1.15) // 8) * 8


def with_enough_pupil_samples(
    compute: Callable[[BankSettings], T],
    settings: BankSettings,
    fixed: bool = False,
    source: str | None = None,
    context: str = "",
) -> T:
    """``compute(settings)`` (a bank: get it however), again with more pupil samples while
    the pupil grid is too coarse for the kernel window (a PupilSamplingError, raised when
    the PSF would wrap around: coarse pixels make wide windows). The samples are raised to
    pupil_samples_for what the window needs, each raise said in one UserWarning line, at
    most PUPIL_TRIES computations in all. When ``fixed`` (the caller chose pupil_samples)
    the first such error is a ParameterError naming pupil_samples and the number to give.
    ``source`` (the file the bank is for) and ``context`` (why its pixels are coarse, e.g.
    how a photo maps onto the sensor) go into the messages."""
    lead = f"{source}: " if source else ""
    where = f"{context}, " if context else ""
    for _ in range(PUPIL_TRIES):
        try:
            return compute(settings)
        except PupilSamplingError as e:
            need = pupil_samples_for(e.needed)
            if fixed:
                raise ParameterError(
                    source,
                    "pupil_samples",
                    f"{where}too coarse for {settings.pupil_samples} pupil samples; expected `pupil_samples` "
                    f"{need} or more (or leave it out to have it chosen)",
                ) from None
            warnings.warn(
                f"{lead}{context + '; ' if context else ''}pupil samples raised from "
                f"{settings.pupil_samples} to {need} for the PSF bank",
                UserWarning,
                stacklevel=2,
            )
            settings = dataclasses.replace(settings, pupil_samples=need)
    raise ParameterError(
        source,
        "pupil_samples",
        f"{where}no pupil sampling up to {settings.pupil_samples} samples resolves the bank's kernels",
    )
