"""The shooting data a photo's EXIF records, declared once: read from raw files
(:class:`lensim.raw.read.RawImage` carries these fields) and written into the EXIF IFD of
the DNGs lensim writes (:data:`lensim.raw.dng.DngExif` is this class)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Exif:
    """Shooting data; None where unknown (a DNG leaves those tags out). Units: seconds,
    f-number, ISO speed, millimetres, metres (focus distance, EXIF SubjectDistance; inf is
    written as 0xFFFFFFFF/1, EXIF's infinity)."""

    exposure_s: float | None = None
    fno: float | None = None
    iso: float | None = None
    focal_length_mm: float | None = None
    focus_distance_m: float | None = None
    lens: str | None = None

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None) -> Exif:
        """From a mapping with (some of) the keys above, e.g. `lensim raw info --json`'s
        output; other keys are ignored, and so are empty values."""
        data = data or {}
        vals = {k: data.get(k) for k in EXIF_FIELDS}
        return Exif(**{k: v for k, v in vals.items() if v not in (None, "", 0, 0.0)})


#: the names of Exif's fields, in order
EXIF_FIELDS = ("exposure_s", "fno", "iso", "focal_length_mm", "focus_distance_m", "lens")
