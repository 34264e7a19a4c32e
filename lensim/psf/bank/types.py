"""The in-memory types of a PSF bank: one field (BankField) and the whole bank (PSFBank),
with the kernel lookup at any image point."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lensim.errors import InputError

#: progress(done, total): fields finished so far out of all the bank's fields
Progress = Callable[[int, int], None]
#: a bank direction (deg) this close to an axis is taken as that axis (reference_azimuth_deg)
AXIS_SNAP_DEG = 0.5


@dataclass
class BankField:
    """One field of a bank.

    rgb (3, P, P) float32: R, G, B pixel kernels (energy per pixel; sums to the
    channel-weighted relative illumination); field: normalized 0..1; field_value: in the
    lens's field unit; reference_xy_mm: the primary-wavelength chief-ray image point (the
    kernel's centre pixel); paraxial_xy_mm: the paraxial image point (primary wavelength);
    chief_offsets_mm (W, 2): each wavelength's chief-ray point minus the reference point;
    relative_illumination (W,); transmission (W,): transmitted fraction of the beam;
    window_energy (W,): fraction of the transmitted energy inside the kernel window;
    strehl: Strehl ratio at the primary wavelength (sampled peak over the aberration-free
    peak on the fine grid; NaN for the geometric method); working_fno: image-space
    F-number at the primary wavelength; primary_fine (kP, kP) float32: the fine PSF at the
    primary wavelength (energy per fine sample); warnings: sampling warnings raised while
    computing this field; settings_key: the key of the bank settings it was computed with
    (lensim.psf.bank.store.settings_key; '' in files written before keys were stored);
    rgb_azimuths (A, 3, P, P) float32: the kernels at the azimuth offsets
    lensim.psf.bank.azimuth.AZIMUTHS_DEG, turned on the fine grid before pixel
    integration (None in files written before 2026-11: psf_at then turns rgb itself).
    """

    index: int
    field: float
    field_value: float
    rgb: np.ndarray
    reference_xy_mm: np.ndarray
    paraxial_xy_mm: np.ndarray
    chief_offsets_mm: np.ndarray
    relative_illumination: np.ndarray
    transmission: np.ndarray
    window_energy: np.ndarray
    strehl: float
    working_fno: float
    primary_fine: np.ndarray
    warnings: list[str] = dataclasses.field(default_factory=list)
    settings_key: str = ""
    rgb_azimuths: np.ndarray | None = None

    def to_npz_bytes(self) -> bytes:
        """The field as an .npz file's bytes (the bank's field file, and what worker
        processes send back)."""
        arrays: dict[str, Any] = dict(
            index=np.int64(self.index),
            field=np.float64(self.field),
            field_value=np.float64(self.field_value),
            rgb=self.rgb.astype(np.float32),
            reference_xy_mm=self.reference_xy_mm,
            paraxial_xy_mm=self.paraxial_xy_mm,
            chief_offsets_mm=self.chief_offsets_mm,
            relative_illumination=self.relative_illumination,
            transmission=self.transmission,
            window_energy=self.window_energy,
            strehl=np.float64(self.strehl),
            working_fno=np.float64(self.working_fno),
            primary_fine=self.primary_fine.astype(np.float32),
            warnings=np.array(json.dumps(self.warnings)),
            settings_key=np.array(self.settings_key),
        )
        if self.rgb_azimuths is not None:
            arrays["rgb_azimuths"] = self.rgb_azimuths.astype(np.float32)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        return buf.getvalue()

    @classmethod
    def from_npz(cls, path: str | Path | io.BytesIO) -> BankField:
        """Read a field from an .npz file (or its bytes in a BytesIO); a one-line
        InputError when it is not a readable field file."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(
                    index=int(z["index"]),
                    field=float(z["field"]),
                    field_value=float(z["field_value"]),
                    rgb=z["rgb"],
                    reference_xy_mm=z["reference_xy_mm"],
                    paraxial_xy_mm=z["paraxial_xy_mm"],
                    chief_offsets_mm=z["chief_offsets_mm"],
                    relative_illumination=z["relative_illumination"],
                    transmission=z["transmission"],
                    window_energy=z["window_energy"],
                    strehl=float(z["strehl"]),
                    working_fno=float(z["working_fno"]),
                    primary_fine=z["primary_fine"],
                    warnings=list(json.loads(str(z["warnings"]))),
                    settings_key=str(z["settings_key"]) if "settings_key" in z.files else "",
                    rgb_azimuths=z["rgb_azimuths"] if "rgb_azimuths" in z.files else None,
                )
        except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as e:  # truncated, foreign
            raise InputError(
                str(path),
                None,
                f"not a readable bank field file ({type(e).__name__}: {e}); "
                "rerun `lensim psf bank` with the same settings to recompute it",
            ) from None


@dataclass
class PSFBank:
    """A PSF bank: manifest (settings) and the fields (sorted by field index).

    psf_at(x_mm, y_mm) gives the RGB kernel at any image point."""

    manifest: dict
    fields: list[BankField]
    directory: Path | None = None

    # ---- settings ----------------------------------------------------------------
    @property
    def pixel_pitch_um(self) -> float:
        return float(self.manifest["pixel_pitch_um"])

    @property
    def kernel_pixels(self) -> int:
        return int(self.manifest["kernel_pixels"])

    @property
    def oversampling(self) -> int:
        return int(self.manifest["oversampling"])

    @property
    def fine_spacing_um(self) -> float:
        return float(self.manifest["fine_spacing_um"])

    @property
    def wavelengths_nm(self) -> np.ndarray:
        return np.asarray(self.manifest["wavelengths_nm"], dtype=np.float64)

    @property
    def primary_wavelength_nm(self) -> float:
        return float(self.manifest["primary_wavelength_nm"])

    @property
    def field_positions(self) -> np.ndarray:
        """Normalized fields (0..1)."""
        return np.asarray([f.field for f in self.fields])

    @property
    def radii_mm(self) -> np.ndarray:
        """Image radius (mm) of each field's reference point."""
        return np.asarray([float(np.hypot(*f.reference_xy_mm)) for f in self.fields])

    @property
    def kernels(self) -> np.ndarray:
        """(F, 3, P, P) float32 kernels of all fields."""
        return np.stack([f.rgb for f in self.fields])

    # ---- loading -------------------------------------------------------------------
    @classmethod
    def load(cls, directory: str | Path) -> PSFBank:
        """Load a complete bank directory (manifest.json + one npz per field)."""
        from lensim.psf.bank.store import (
            load_bank,  # the store builds PSFBanks: imported here
        )

        return load_bank(directory)

    # ---- lookup --------------------------------------------------------------------
    def reference_azimuth_deg(self) -> float:
        """Azimuth (deg, from +x towards +y) of the stored fields' reference points (the
        outermost off-axis field decides: +90 for an image on +y, -90 if inverted). A
        direction within AXIS_SNAP_DEG of an axis is that axis: a lens with decentred or
        tilted surfaces, computed along +y like any, moves its reference points sideways
        by microns (89.99 deg for an element decentred 12 um in phone_wide), and off an
        axis psf_at cannot use the stored azimuth kernels (the spline turn of the pixel
        kernel it falls back to lost 11 % of the MTF at 0.16 cycles/pixel on the
        diagonals at a 3.8 um pitch)."""
        for f in reversed(self.fields):
            x, y = (float(v) for v in f.reference_xy_mm)
            if math.hypot(x, y) > 0:
                angle = math.degrees(math.atan2(y, x))
                axis = 90.0 * round(angle / 90.0)
                return axis if abs(angle - axis) <= AXIS_SNAP_DEG else angle
        return 90.0

    def radial_kernel(self, radius_mm: float) -> np.ndarray:
        """(3, P, P) kernel at an image radius along the stored direction: linear
        interpolation between the two fields whose reference radii bracket it (clamped to
        the first and last field)."""
        return self._radial(radius_mm, lambda f: f.rgb)

    def _radial(self, radius_mm: float, part: Callable[[BankField], np.ndarray]) -> np.ndarray:
        """part(field) (float64) at an image radius, interpolated as radial_kernel says."""
        radii = self.radii_mm
        if len(radii) > 1 and np.any(np.diff(radii) <= 0):
            raise InputError(
                str(self.directory or "<bank>"),
                "fields",
                "the reference-point radii do not increase with "
                "field; expected a lens whose image height grows with field",
            )
        r = float(radius_mm)
        if len(radii) == 1 or r <= radii[0]:
            return part(self.fields[0]).astype(np.float64)
        if r >= radii[-1]:
            return part(self.fields[-1]).astype(np.float64)
        j = int(np.searchsorted(radii, r, side="right"))
        t = (r - radii[j - 1]) / (radii[j] - radii[j - 1])
        return (1.0 - t) * part(self.fields[j - 1]).astype(np.float64) + t * part(self.fields[j]).astype(np.float64)

    def psf_at(self, x_mm: float, y_mm: float) -> np.ndarray:
        """(3, P, P) float32 RGB kernel at image point (x_mm, y_mm) (real image-plane
        coordinates, origin on the axis): the radially interpolated kernel rotated to the
        point's azimuth about its centre pixel. Where the fields store kernels at other
        azimuths (rgb_azimuths, turned before pixel integration) the turn comes from them
        (lensim.psf.bank.azimuth.kernel_at_azimuth); in banks without them the pixel
        kernel itself is turned (lensim.render.rotation.rotate_kernel: cubic spline, sum
        kept, centre fixed), which over-blurs off the axes at a coarse pitch."""
        # imported here: lensim.render builds on banks, so the bank must not need it loaded
        from lensim.psf.bank.azimuth import kernel_at_azimuth, supported
        from lensim.render.rotation import rotate_kernel

        r = math.hypot(x_mm, y_mm)
        if r == 0:
            return self.radial_kernel(r).astype(np.float32)
        reference = self.reference_azimuth_deg()
        angle = math.degrees(math.atan2(y_mm, x_mm)) - reference
        if supported(reference) and all(f.rgb_azimuths is not None for f in self.fields):
            stack = self._radial(r, lambda f: np.concatenate([f.rgb[None], f.rgb_azimuths]))  # type: ignore[list-item]
            return kernel_at_azimuth(stack, angle, reference).astype(np.float32)
        return rotate_kernel(self.radial_kernel(r), angle).astype(np.float32)

    def psfs_at(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """(N, 3, P, P) float32 kernels at image points (x_mm, y_mm) ((N,) each, mm):
        :func:`psf_at` at each point, with the spline turns of all points done in one pass
        (lensim.render.rotation.rotate_kernels) and only each point's own stored azimuth
        kernel interpolated. Equal to psf_at to rounding (tests/test_render_kernels.py);
        banks without azimuth kernels take psf_at point by point."""
        from lensim.psf.bank.azimuth import supported

        xs = [float(v) for v in np.asarray(x_mm, dtype=np.float64).ravel()]
        ys = [float(v) for v in np.asarray(y_mm, dtype=np.float64).ravel()]
        if len(xs) != len(ys):
            raise ValueError(f"expected as many x as y positions, got {len(xs)} and {len(ys)}")
        if not xs:
            return np.zeros((0, 3, self.kernel_pixels, self.kernel_pixels), np.float32)
        if not (supported(self.reference_azimuth_deg()) and all(f.rgb_azimuths is not None for f in self.fields)):
            return np.stack([self.psf_at(x, y) for x, y in zip(xs, ys, strict=True)])
        return self._turned_kernels(xs, ys)

    def _turned_kernels(self, xs: list[float], ys: list[float]) -> np.ndarray:
        """psfs_at for a bank with azimuth kernels: per point the radially interpolated
        stored kernel nearest its azimuth (as psf_at), then all the small turns at once,
        then each point's mirror and quarter turns."""
        from lensim.psf.bank.azimuth import azimuth_turn, finish_turn
        from lensim.render.rotation import rotate_kernels

        reference = self.reference_azimuth_deg()
        kernels: list[np.ndarray] = []
        turns: list[tuple[float, bool, int] | None] = []
        for x, y in zip(xs, ys, strict=True):
            r = math.hypot(x, y)
            if r == 0:  # the axis: no turn (psf_at)
                kernels.append(self.radial_kernel(r))
                turns.append(None)
                continue
            i, rest, mirrored, quarter = azimuth_turn(math.degrees(math.atan2(y, x)) - reference)
            kernels.append(self._radial(r, _stored_azimuth(i)))
            turns.append((rest, mirrored, quarter))
        batch = np.stack(kernels)
        rests = np.array([0.0 if t is None else t[0] for t in turns])
        small = np.abs(rests) > 1e-9
        batch[small] = rotate_kernels(batch[small], rests[small])
        out = [k if t is None else finish_turn(k, t[1], t[2], reference) for k, t in zip(batch, turns, strict=True)]
        return np.stack(out).astype(np.float32)


def _stored_azimuth(i: int) -> Callable[[BankField], np.ndarray]:
    """A field's stored kernel i: 0 its own (rgb), i >= 1 rgb_azimuths[i - 1]."""

    def part(f: BankField) -> np.ndarray:
        return f.rgb if i == 0 else f.rgb_azimuths[i - 1]  # type: ignore[index]

    return part
