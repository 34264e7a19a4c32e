"""The lens library: published prescriptions (patent examples, textbook designs and the
sample lenses of permissively licensed peers) written as lensim's native YAML, one file
per prescription, with an index (``index.yaml``) that records for every entry its
family, source, licence, design focal length, F-number, field and whether it is held out.

An entry is one lens at one setting of its zoom: a zoom prescription appears once per
zoom position, each entry naming the file and its configuration. Held-out entries
(``holdout: true``) are for evaluation only; nothing may ever train on them, and every
entry of a held-out prescription is held out (its other zoom positions too).

The sources, licences and the checks every entry passes are in ``README.md`` beside this
file; ``tests/test_library.py`` runs those checks.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.optics.lens import Lens

LIBRARY_DIR = Path(__file__).parent
INDEX_PATH = LIBRARY_DIR / "index.yaml"

# Families an entry may name (index.yaml's `family`).
FAMILIES = (
    "triplet",
    "tessar",
    "double_gauss",
    "sonnar",
    "telephoto",
    "retrofocus",
    "wide_angle",
    "fisheye",
    "zoom",
    "phone",
    "catadioptric",
    "petzval",
    "objective",
)
# How the focal length in the index was stated by the source: the design value (the
# prescription's own EFL, as a table or design report gives it) or the marked focal
# length of the product the patent example describes (ISO 517 allows the marking to
# differ from the design EFL by up to 5 %), or, where no stated value was available,
# lensim's paraxial EFL of the transcribed table (a regression value, not an independent check).
FOCAL_BASES = ("design", "marked", "computed")
# Relative tolerance of lensim's EFL against focal_mm, per basis.
FOCAL_TOLERANCE = {"design": 0.01, "marked": 0.05, "computed": 1e-4}


@dataclass(frozen=True)
class LibraryLens:
    """One library entry. focal_mm: the source's focal length (mm, see ``focal_basis``);
    fno: the F-number the entry is traced at (its maximum aperture); half_field_deg: the
    half field of view (deg) at its largest field; image_height_mm: the largest real
    image height (mm) the entry is traced to; track_mm: the lens's length (mm, its first
    vertex's distance from the image plane); config: the zoom configuration (None for a
    lens without configurations)."""

    name: str
    file: str
    family: str
    source: str
    licence: str
    focal_mm: float
    focal_basis: str
    fno: float
    half_field_deg: float
    image_height_mm: float
    track_mm: float
    holdout: bool
    config: str | None = None

    @property
    def path(self) -> Path:
        """The prescription file (native YAML; a built-in lens's file for an entry that
        names one, such as ``../lenses/cooke_triplet.yaml``)."""
        return (LIBRARY_DIR / self.file).resolve()


_FIELDS = {
    "name": str,
    "file": str,
    "family": str,
    "source": str,
    "licence": str,
    "focal_mm": float,
    "focal_basis": str,
    "fno": float,
    "half_field_deg": float,
    "image_height_mm": float,
    "track_mm": float,
    "holdout": bool,
}


def _entry(i: int, raw: object) -> LibraryLens:
    """One index entry, checked: every key present with its type, known family and basis."""
    where = f"entries[{i}]"
    if not isinstance(raw, dict):
        raise InputError(str(INDEX_PATH), where, "expected a mapping")
    unknown = set(raw) - set(_FIELDS) - {"config"}
    if unknown:
        raise InputError(str(INDEX_PATH), where, f"unknown key(s) {sorted(unknown)}")
    values: dict[str, object] = {}
    for key, kind in _FIELDS.items():
        value = raw.get(key)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind):
            raise InputError(str(INDEX_PATH), f"{where}.{key}", f"expected a {kind.__name__}, got {value!r}")
        values[key] = value
    if values["family"] not in FAMILIES:
        raise InputError(str(INDEX_PATH), f"{where}.family", f"expected one of {', '.join(FAMILIES)}")
    if values["focal_basis"] not in FOCAL_BASES:
        raise InputError(str(INDEX_PATH), f"{where}.focal_basis", f"expected one of {', '.join(FOCAL_BASES)}")
    config = raw.get("config")
    if config is not None and not isinstance(config, str):
        raise InputError(str(INDEX_PATH), f"{where}.config", f"expected a configuration name, got {config!r}")
    return LibraryLens(config=config, **values)  # type: ignore[arg-type]


def library_index() -> list[LibraryLens]:
    """Every entry of the library, in the index's order."""
    import yaml

    data = yaml.safe_load(INDEX_PATH.read_text(encoding="utf-8"))
    if not isinstance(data, dict) or not isinstance(data.get("entries"), list):
        raise InputError(str(INDEX_PATH), "entries", "expected a list of entries")
    return [_entry(i, raw) for i, raw in enumerate(data["entries"])]


def list_lenses(holdout: bool | None = None, family: str | None = None) -> list[LibraryLens]:
    """The library's entries; holdout True: only the held-out ones, False: only those that
    may be trained on, None: all. family: only that family (one of FAMILIES)."""
    if family is not None and family not in FAMILIES:
        raise InputError(None, "family", f"unknown lens family {family!r}; expected one of {', '.join(FAMILIES)}")
    return [
        e
        for e in library_index()
        if (holdout is None or e.holdout == holdout) and (family is None or e.family == family)
    ]


def library_entry(name: str) -> LibraryLens:
    """The entry called ``name`` (an unknown name is one line listing close names)."""
    entries = library_index()
    for e in entries:
        if e.name == name:
            return e
    import difflib

    close = difflib.get_close_matches(name, [e.name for e in entries], n=5, cutoff=0.3)
    hint = f"; close names: {', '.join(close)}" if close else ""
    raise InputError(None, "lens", f"no library lens named {name!r} ({len(entries)} in the library){hint}")


def load_library_lens(name: str) -> Lens:
    """The entry's lens, at its zoom configuration when it has one (lens.name says which)."""
    from lensim.optics.configurations import apply_configuration
    from lensim.optics.lens_file import load_lens

    entry = library_entry(name)
    lens = load_lens(entry.path, warn=False)
    return apply_configuration(lens, entry.config) if entry.config is not None else lens
