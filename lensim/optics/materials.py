"""Optical materials: air, vendor catalogue glasses and model glasses (nd/Vd).

Indices are relative to air (as in Zemax and CODE V catalogues); wavelengths in
micrometres. Catalogue data come from the `opticalglass` package (Schott, Ohara,
CDGM, Hikari, Hoya, Sumita), each glass with its vendor's own dispersion formula.
"""
from __future__ import annotations

import difflib
import functools
import re
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError, UnknownGlassError

CATALOGS: tuple[str, ...] = ("Schott", "Ohara", "CDGM", "Hikari", "Hoya", "Sumita")

# Fraunhofer lines (um) used for nd / Vd.
WAVELENGTH_D_UM = 0.5875618
WAVELENGTH_F_UM = 0.4861327
WAVELENGTH_C_UM = 0.6562725


class Material:
    """A medium with a refractive index n(lambda)."""

    name: str = "?"

    def index(self, wavelength_um: np.ndarray | float) -> np.ndarray:
        """Refractive index at the given wavelengths (um)."""
        raise NotImplementedError

    def spec(self) -> str | dict:
        """How this material is written in a native lens file."""
        return self.name

    @property
    def nd(self) -> float:
        return float(self.index(WAVELENGTH_D_UM))

    @property
    def vd(self) -> float:
        nd, nf, nc = self.index(np.array([WAVELENGTH_D_UM, WAVELENGTH_F_UM, WAVELENGTH_C_UM]))
        return float((nd - 1.0) / (nf - nc)) if nf != nc else float("inf")


@dataclass(frozen=True)
class Air(Material):
    """Air; all glass indices are relative to it, so n = 1 exactly."""

    name: str = "air"

    def index(self, wavelength_um):
        return np.ones_like(np.asarray(wavelength_um, dtype=np.float64))


@dataclass(frozen=True)
class ConstantIndex(Material):
    """A non-dispersive medium (tests, ideal lenses)."""

    n: float
    name: str = "constant"

    def index(self, wavelength_um):
        return np.full_like(np.asarray(wavelength_um, dtype=np.float64), self.n)

    def spec(self):
        return {"n": self.n}


@dataclass(frozen=True)
class ModelGlass(Material):
    """A model glass from nd and Vd.

    Dispersion: the two-term Cauchy law n = A + B / lambda^2 fitted exactly through
    nd at the d line and through nF - nC = (nd - 1) / Vd.
    """

    nd_value: float
    vd_value: float
    name: str = "model"

    def index(self, wavelength_um):
        lam = np.asarray(wavelength_um, dtype=np.float64)
        b = (self.nd_value - 1.0) / self.vd_value / (WAVELENGTH_F_UM**-2 - WAVELENGTH_C_UM**-2)
        a = self.nd_value - b / WAVELENGTH_D_UM**2
        return a + b / lam**2

    def spec(self):
        return {"nd": self.nd_value, "vd": self.vd_value}


class CatalogGlass(Material):
    """A vendor glass with the vendor's dispersion formula (via `opticalglass`)."""

    def __init__(self, name: str, catalog: str, medium):
        self.name = name
        self.catalog = catalog
        self._medium = medium

    def index(self, wavelength_um):
        lam_nm = np.asarray(wavelength_um, dtype=np.float64) * 1000.0
        return np.asarray(self._medium.calc_rindex(lam_nm), dtype=np.float64)

    def spec(self):
        return f"{self.name}@{self.catalog}"

    def __repr__(self):
        return f"CatalogGlass({self.name!r}, {self.catalog!r})"

    def __eq__(self, other):
        return isinstance(other, CatalogGlass) and (self.name, self.catalog) == (other.name, other.catalog)

    def __hash__(self):
        return hash((self.name, self.catalog))


def _normalize(name: str) -> str:
    return re.sub(r"[^A-Z0-9]", "", name.upper())


@functools.lru_cache(maxsize=None)
def _catalog_names(catalog: str) -> dict[str, str]:
    """Normalized name -> vendor name for one catalogue (loaded lazily, ~0.1-0.8 s each)."""
    import warnings

    from opticalglass import glassfactory

    with warnings.catch_warnings():
        # opticalglass's spreadsheet loading emits pandas deprecation noise
        warnings.simplefilter("ignore")
        cat = glassfactory.get_glass_catalog(catalog)
    return {_normalize(n): n for n in cat.get_glass_names()}


def _catalog_key(catalog: str) -> str:
    for c in CATALOGS:
        if c.lower() == catalog.strip().lower():
            return c
    raise InputError(None, "catalog", f"unknown glass catalogue {catalog!r}; expected one of {', '.join(CATALOGS)}")


@functools.lru_cache(maxsize=None)
def catalog_glass(name: str, catalog: str) -> CatalogGlass:
    """Look a glass up in one catalogue by name (case, dashes and spaces ignored)."""
    from opticalglass import glassfactory

    catalog = _catalog_key(catalog)
    vendor_name = _catalog_names(catalog).get(_normalize(name))
    if vendor_name is None:
        raise UnknownGlassError(None, "material", f"glass {name!r} is not in the {catalog} catalogue")
    return CatalogGlass(vendor_name, catalog, glassfactory.create_glass(vendor_name, catalog))


def _family(name: str) -> str:
    """A vendor-neutral key: the vendor prefix before a dash dropped (N-SK16, J-SK16,
    K-SK16 -> SK16; L-TIM28, S-TIM28 -> TIM28), then normalized."""
    return _normalize(re.sub(r"^[A-Z]{1,3}-", "", name.strip().upper()))


def resolve_glass(name: str, catalogs: tuple[str, ...] | list[str] | None = None) -> tuple[CatalogGlass, str | None]:
    """Find a glass by name; return it and a note when it is not an exact match.

    Order: the exact name (case, dashes, spaces and a Zemax '_MOLD' suffix ignored) in the
    given catalogues, then in every catalogue; then the same glass family without the
    vendor prefix (e.g. SK16 -> J-SK16, L-TIM28 -> S-TIM28), given catalogues first.
    Raises UnknownGlassError listing the closest names when nothing matches.
    """
    listed = [_catalog_key(c) for c in (catalogs or CATALOGS)]
    everywhere = listed + [c for c in CATALOGS if c not in listed]
    key = _normalize(re.sub(r"_MOLD$", "", name.strip(), flags=re.I))
    for cat in everywhere:
        if key in _catalog_names(cat):
            glass = catalog_glass(_catalog_names(cat)[key], cat)
            note = None if cat in listed else f"glass {name} is not in the catalogues {', '.join(listed)}; using {glass.name} from {cat}"
            return glass, note
    fam = _family(re.sub(r"_MOLD$", "", name.strip(), flags=re.I))
    for cat in everywhere:
        matches = sorted(v for v in _catalog_names(cat).values() if _family(v) == fam)
        if len(matches) >= 1:
            glass = catalog_glass(matches[0], cat)
            return glass, (f"glass {name} is in no catalogue; using the same family's {glass.name} from {cat} "
                           f"(nd {glass.nd:.5f}, Vd {glass.vd:.2f})")
    candidates = {k: (v, c) for c in everywhere for k, v in _catalog_names(c).items()}
    close = difflib.get_close_matches(key, list(candidates), n=5, cutoff=0.6)
    hint = ", ".join(f"{candidates[k][0]} ({candidates[k][1]})" for k in close) or "none"
    raise UnknownGlassError(None, "material", f"unknown glass {name!r} (searched {', '.join(everywhere)}); close names: {hint}")


def material_from_spec(spec, catalogs: list[str] | None = None, notes: list[str] | None = None) -> Material:
    """Build a material from its native-file form.

    Accepted: "air"; "N-BK7" (searched in all catalogues); "N-BK7@Schott";
    {"nd": 1.5168, "vd": 64.17} (model glass); {"n": 1.5} (constant index);
    {"glass": "L-TIM28", "catalog": "Ohara"}.
    """
    if isinstance(spec, Material):
        return spec
    if spec is None:
        return Air()
    if isinstance(spec, str):
        text = spec.strip()
        if text.lower() in ("air", ""):
            return Air()
        name, cats = text, catalogs
        if "@" in text:
            name, cat = (t.strip() for t in text.rsplit("@", 1))
            cats = [cat]
        glass, note = resolve_glass(name, cats)
        if note and notes is not None:
            notes.append(note)
        return glass
    if isinstance(spec, dict):
        if "n" in spec:
            return ConstantIndex(float(spec["n"]))
        if "nd" in spec and "vd" in spec:
            nd, vd = float(spec["nd"]), float(spec["vd"])
            if not (1.0 <= nd < 5.0) or vd <= 0:
                raise InputError(None, "material", f"model glass needs 1 <= nd < 5 and vd > 0, got nd={nd}, vd={vd}")
            return ModelGlass(nd, vd, name=str(spec.get("name", f"model {nd:.5f}/{vd:.2f}")))
        if "glass" in spec:
            name = str(spec["glass"]) + (f"@{spec['catalog']}" if "catalog" in spec else "")
            return material_from_spec(name, catalogs, notes)
    raise InputError(None, "material", f"expected a glass name, 'air', {{nd, vd}} or {{n}}, got {spec!r}")
