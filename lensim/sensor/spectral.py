"""The sensor's spectral response: per-channel weights C_wav(lambda) for the PSF bank.

The paper (Sec. "Wavelength Response and Relative Illumination", Eq. 10) weights each
wavelength's PSF by the sensor's colour-filter response. This module samples a camera's
red, green and blue spectral sensitivities at the bank wavelengths (nm), optionally
multiplies them by an illuminant's relative spectral power, and normalizes each channel's
weights to sum to 1 (so a kernel built from unit-sum PSFs sums to 1 per channel before
relative illumination).

Sources of sensitivities:
- a measured camera from the colour-science package's dataset
  ``colour.MSDS_CAMERA_SENSITIVITIES``, copied into lensim/assets/sensors/
  camera_sensitivities.json (National Physical Laboratory measurements:
  'Nikon 5100 (NPL)', 380-780 nm at 5 nm, the default; 'Sigma SDMerill (NPL)',
  400-680 nm at 10 nm);
- a user CSV table with the header ``wavelength_nm,r,g,b`` (wavelengths in nm,
  increasing; non-negative sensitivities in any common unit), linearly interpolated.

Illuminants: 'E' (equal energy, the default) or any name in
``colour.SDS_ILLUMINANTS`` such as 'D65' or 'A'.

colour-science takes seconds to import; it is imported only for a non-'E' illuminant.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lensim.errors import InputError

DEFAULT_CAMERA = "Nikon 5100 (NPL)"
DEFAULT_WAVELENGTHS_NM = tuple(float(w) for w in range(400, 701, 10))
CHANNELS = ("r", "g", "b")
CSV_COLUMNS = ("wavelength_nm", "r", "g", "b")


@dataclass
class SpectralResponse:
    """Per-channel spectral weights at the bank wavelengths.

    name: what the sensitivities came from (camera name or CSV path); source: a sentence
    naming the data set; illuminant: 'E' or a colour-science illuminant name;
    wavelengths_nm (W,); sensitivities (3, W): the raw camera sensitivities sampled at the
    wavelengths (R, G, B rows, the source's unit); weights (3, W): sensitivities times the
    illuminant, each row normalized to sum to 1.
    """

    name: str
    source: str
    illuminant: str
    wavelengths_nm: np.ndarray
    sensitivities: np.ndarray
    weights: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready description (for a bank manifest)."""
        return {
            "name": self.name,
            "source": self.source,
            "illuminant": self.illuminant,
            "wavelengths_nm": [float(w) for w in self.wavelengths_nm],
            "weights": [[float(v) for v in row] for row in self.weights],
        }


#: colour-science's camera sensitivities, copied (colour-science takes seconds to import)
CAMERA_TABLES = Path(__file__).resolve().parents[1] / "assets" / "sensors" / "camera_sensitivities.json"


def _camera_table(name: str) -> tuple[np.ndarray, np.ndarray, str]:
    """A named camera's table: wavelengths (N,) nm, R, G, B sensitivities (3, N) and the
    source line, from the copy of colour-science's MSDS_CAMERA_SENSITIVITIES in
    CAMERA_TABLES (the same numbers; tests/test_sensor.py checks them)."""
    tables = json.loads(CAMERA_TABLES.read_text(encoding="utf-8"))
    cameras = tables["cameras"]
    if name not in cameras:
        raise InputError(
            None,
            "response",
            f"unknown camera {name!r}; expected one of {', '.join(cameras)} "
            "or a CSV file with columns wavelength_nm,r,g,b",
        )
    camera = cameras[name]
    src = (
        f"colour-science {tables['colour_version']} MSDS_CAMERA_SENSITIVITIES[{name!r}] "
        "(camera spectral sensitivities measured by the National Physical Laboratory)"
    )
    table = np.asarray([camera[c] for c in ("red", "green", "blue")], dtype=np.float64)
    return np.asarray(camera["wavelengths_nm"], dtype=np.float64), table, src


def read_response_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a CSV table (header wavelength_nm,r,g,b) -> (wavelengths_nm (N,), (3, N)).
    Raises InputError naming the file, the row/column and what was expected."""
    path = Path(path)
    src = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as e:
        raise InputError(src, None, f"cannot read: {e.strerror or e}") from None
    rows = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError(src, "header", f"empty file; expected the header {','.join(CSV_COLUMNS)}")
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise InputError(
            src,
            "header",
            f"missing column(s) {', '.join(missing)}; expected the header {','.join(CSV_COLUMNS)}, got {','.join(header)}",
        )
    idx = [header.index(c) for c in CSV_COLUMNS]
    values = np.empty((len(rows) - 1, 4))
    for i, row in enumerate(rows[1:], start=2):
        for j, (col, k) in enumerate(zip(CSV_COLUMNS, idx)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                v = float(cell)
            except ValueError:
                raise InputError(src, f"line {i}, column {col}", f"expected a number, got {cell!r}") from None
            if not math.isfinite(v) or (j > 0 and v < 0):
                raise InputError(
                    src,
                    f"line {i}, column {col}",
                    f"expected a finite{' non-negative' if j else ''} number, got {cell!r}",
                )
            values[i - 2, j] = v
    if values.shape[0] < 2:
        raise InputError(src, "wavelength_nm", f"expected at least 2 data rows, got {values.shape[0]}")
    wl = values[:, 0]
    if np.any(np.diff(wl) <= 0):
        bad = int(np.nonzero(np.diff(wl) <= 0)[0][0]) + 3
        raise InputError(src, f"line {bad}, column wavelength_nm", "expected strictly increasing wavelengths")
    return wl, values[:, 1:].T


def _illuminant(name: str, wavelengths_nm: np.ndarray) -> np.ndarray:
    if name.upper() == "E":
        return np.ones_like(wavelengths_nm)
    import colour

    data = colour.SDS_ILLUMINANTS
    if name not in data:
        raise InputError(
            None, "illuminant", f"unknown illuminant {name!r}; expected E, D65, A or another colour-science illuminant"
        )
    sd = data[name]
    wl = np.asarray(sd.wavelengths, dtype=np.float64)
    if wavelengths_nm.min() < wl[0] - 1e-9 or wavelengths_nm.max() > wl[-1] + 1e-9:
        raise InputError(
            None, "illuminant", f"{name} is tabulated over {wl[0]:g}-{wl[-1]:g} nm; expected bank wavelengths inside"
        )
    return np.interp(wavelengths_nm, wl, np.asarray(sd.values, dtype=np.float64))


def spectral_response(
    wavelengths_nm: np.ndarray | list[float] | None = None,
    response: str | Path | None = None,
    illuminant: str = "E",
) -> SpectralResponse:
    """R, G, B weights at the wavelengths (nm; default 400-700 nm every 10 nm).

    response: a colour-science camera name (default 'Nikon 5100 (NPL)') or the path of a
    CSV table (columns wavelength_nm,r,g,b). The sensitivities are linearly interpolated
    onto the wavelengths, which must lie inside the table's range; they are multiplied by
    the illuminant's spectral power ('E': equal energy; 'D65' etc. from colour-science)
    and each channel is normalized to sum to 1 over the wavelengths.
    """
    wl = np.asarray(DEFAULT_WAVELENGTHS_NM if wavelengths_nm is None else wavelengths_nm, dtype=np.float64).reshape(-1)
    if wl.size == 0 or not np.all(np.isfinite(wl)):
        raise InputError(None, "wavelengths", "expected at least one finite wavelength (nm)")
    name = DEFAULT_CAMERA if response is None else str(response)
    if response is not None and (Path(name).suffix.lower() == ".csv" or Path(name).is_file()):
        table_wl, table = read_response_csv(name)
        where, column = name, "wavelength_nm"
        source = f"user table {name} (columns wavelength_nm,r,g,b)"
    else:
        table_wl, table, source = _camera_table(name)
        where, column = None, "response"
    lo, hi = float(table_wl[0]), float(table_wl[-1])
    if wl.min() < lo - 1e-9 or wl.max() > hi + 1e-9:
        raise InputError(
            where,
            column,
            f"{name} covers {lo:g}-{hi:g} nm; expected the bank wavelengths "
            f"({wl.min():g}-{wl.max():g} nm) inside that range",
        )
    sens = np.stack([np.interp(wl, table_wl, row) for row in table])
    weighted = sens * _illuminant(illuminant, wl)[None, :]
    sums = weighted.sum(axis=1)
    for c, s in zip(CHANNELS, sums):
        if not s > 0:
            raise InputError(
                where,
                c if where else "response",
                f"channel {c} has zero response at the bank wavelengths ({wl.min():g}-{wl.max():g} nm)",
            )
    return SpectralResponse(
        name=name,
        source=source,
        illuminant=illuminant,
        wavelengths_nm=wl,
        sensitivities=sens,
        weights=weighted / sums[:, None],
    )
