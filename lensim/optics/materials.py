"""Optical materials: air, vendor catalogue glasses and model glasses (nd, Vd, dPgF).

Indices are relative to air (as in Zemax and CODE V catalogues); wavelengths in
micrometres. Catalogue data come from the `opticalglass` package (Schott, Ohara,
CDGM, Hikari, Hoya, Sumita), each glass with its vendor's own dispersion formula.
"""

from __future__ import annotations

import difflib
import functools
import math
import re
from dataclasses import dataclass

import numpy as np

from lensim.errors import InputError, ParameterError, UnknownGlassError
from lensim.optics import glass_cache

CATALOGS: tuple[str, ...] = ("Schott", "Ohara", "CDGM", "Hikari", "Hoya", "Sumita")

# Fraunhofer lines (um) used for nd / Vd.
WAVELENGTH_D_UM = 0.5875618
WAVELENGTH_F_UM = 0.4861327
WAVELENGTH_C_UM = 0.6562725
WAVELENGTH_G_UM = 0.4358343  # mercury g line, for the partial dispersion P_g,F


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

    @property
    def dpgf(self) -> float:
        """Departure of P_g,F = (ng - nF) / (nF - nC) from Schott's normal line (0 without dispersion)."""
        nf, nc, ng = self.index(np.array([WAVELENGTH_F_UM, WAVELENGTH_C_UM, WAVELENGTH_G_UM]))
        if nf == nc:
            return 0.0
        return float((ng - nf) / (nf - nc)) - normal_line_pgf(self.vd)

    def as_model(self, on_normal_line: bool = False) -> ModelGlass:
        """The model glass with this material's nd, Vd and dPgF (dPgF 0 when on_normal_line)."""
        return ModelGlass(self.nd, self.vd, 0.0 if on_normal_line else self.dpgf, name=f"model of {self.name}")


@dataclass(frozen=True)
class Air(Material):
    """Air; all glass indices are relative to it, so n = 1 exactly."""

    name: str = "air"

    def index(self, wavelength_um):
        return np.ones_like(np.asarray(wavelength_um, dtype=np.float64))


def _constant_index(value: object) -> float:
    """A constant refractive index from a file: a finite number of at least 1."""
    try:
        n = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(None, "material", f"expected a refractive index n (a number), got {value!r}") from None
    if not (math.isfinite(n) and n >= 1.0):
        raise InputError(None, "material", f"expected a refractive index n of at least 1, got {value!r}")
    return n


@dataclass(frozen=True)
class ConstantIndex(Material):
    """A non-dispersive medium (tests, ideal lenses)."""

    n: float
    name: str = "constant"

    def index(self, wavelength_um):
        return np.full_like(np.asarray(wavelength_um, dtype=np.float64), self.n)

    def spec(self):
        return {"n": self.n}


# Schott's normal line of the relative partial dispersion P_g,F against Vd, through the
# normal glasses K7 and F2: P_g,F = 0.6438 - 0.001682 Vd (Schott TIE-29; Zemax's model
# glass measures its dPgF from the same line).
NORMAL_LINE_PGF_INTERCEPT = 0.6438
NORMAL_LINE_PGF_SLOPE = -0.001682
# Buchdahl's chromatic coordinate omega = dl / (1 + alpha dl), dl = lambda - lambda_d in um
BUCHDAHL_ALPHA_PER_UM = 2.5


def normal_line_pgf(vd: float) -> float:
    """P_g,F of a normal glass with Abbe number vd (Schott's normal line through K7 and F2)."""
    return NORMAL_LINE_PGF_INTERCEPT + NORMAL_LINE_PGF_SLOPE * vd


def _buchdahl_omega(wavelength_um):
    dl = np.asarray(wavelength_um, dtype=np.float64) - WAVELENGTH_D_UM
    return dl / (1.0 + BUCHDAHL_ALPHA_PER_UM * dl)


@dataclass(frozen=True)
class ModelGlass(Material):
    """A model glass from nd, Vd and dPgF, the three numbers of Zemax's MODEL glass.

    The numbers mean what they mean in Zemax: nd the index at the d line (587.5618 nm),
    Vd = (nd - 1) / (nF - nC), and dPgF the departure of the relative partial dispersion
    P_g,F = (ng - nF) / (nF - nC) from Schott's normal line P_g,F = 0.6438 - 0.001682 Vd
    (through K7 and F2; `normal_line_pgf`). dPgF = 0 puts the glass on the normal line,
    which is what a patent's bare nd/Vd pair means.

    Zemax calls its own n(lambda) for these three numbers proprietary (its knowledge-base
    article "How to Use the Model Glass" gives the inputs and an accuracy of about 1e-4 in
    the visible, not the formula). lensim uses the quadratic Buchdahl dispersion model
    (H. A. Buchdahl 1962; P. N. Robb and R. I. Mercado, Appl. Opt. 22, 1198 (1983)):

        n(lambda) = nd + v1 w + v2 w^2,   w = (lambda - lambda_d) / (1 + 2.5 (lambda - lambda_d))

    (lambda in um), with v1 and v2 solved so that nF - nC = (nd - 1) / Vd and
    ng - nF = P_g,F (nF - nC) hold exactly. Built from a catalogue glass's own nd, Vd and
    dPgF, the model's largest index error over 400-700 nm is, across the 981 glasses of the
    six catalogues, 6e-5 at the median, 1.2e-4 at the 90th percentile and 1.2e-3 at worst
    (an extreme dense flint); for the dozen glasses of tests/test_model_glass.py at most
    9.9e-5. Outside the visible it is not meant to be used.
    """

    nd_value: float
    vd_value: float
    dpgf_value: float = 0.0
    name: str = "model"
    #: kept as the model even where a catalogue glass matches nd/Vd (native ``model: true``;
    #: :func:`catalogue_twin`)
    forced: bool = False

    @property
    def pgf(self) -> float:
        """The relative partial dispersion P_g,F = (ng - nF) / (nF - nC)."""
        return normal_line_pgf(self.vd_value) + self.dpgf_value

    def buchdahl_coefficients(self) -> tuple[float, float]:
        """(v1, v2) of n = nd + v1 w + v2 w^2 (dimensionless)."""
        w_f, w_c, w_g = (float(_buchdahl_omega(x)) for x in (WAVELENGTH_F_UM, WAVELENGTH_C_UM, WAVELENGTH_G_UM))
        d_fc = (self.nd_value - 1.0) / self.vd_value
        d_gf = self.pgf * d_fc
        # v1 (wF - wC) + v2 (wF^2 - wC^2) = d_fc;  v1 (wg - wF) + v2 (wg^2 - wF^2) = d_gf
        a11, a12 = w_f - w_c, w_f * w_f - w_c * w_c
        a21, a22 = w_g - w_f, w_g * w_g - w_f * w_f
        det = a11 * a22 - a12 * a21
        return (d_fc * a22 - a12 * d_gf) / det, (a11 * d_gf - a21 * d_fc) / det

    def index(self, wavelength_um):
        v1, v2 = self.buchdahl_coefficients()
        w = _buchdahl_omega(wavelength_um)
        return self.nd_value + w * (v1 + v2 * w)

    def spec(self):
        out: dict = {"nd": self.nd_value, "vd": self.vd_value}
        if self.dpgf_value:
            out["dpgf"] = self.dpgf_value
        if self.forced:
            out["model"] = True
        return out


class CatalogGlass(Material):
    """A vendor glass with the vendor's dispersion formula (via `opticalglass`). The
    opticalglass medium is created on the first index not yet in lensim's index cache
    (lensim.optics.glass_cache), so a lens whose indices are cached never imports it."""

    def __init__(self, name: str, catalog: str, medium=None):
        self.name = name
        self.catalog = catalog
        self._medium = medium
        self._cache = glass_cache.IndexCache(name, catalog)

    def _rindex(self, lam_nm: np.ndarray) -> np.ndarray:
        if self._medium is None:
            from opticalglass import glassfactory

            self._medium = glassfactory.create_glass(self.name, self.catalog)
        return np.asarray(self._medium.calc_rindex(lam_nm), dtype=np.float64)

    def index(self, wavelength_um):
        lam_nm = np.asarray(wavelength_um, dtype=np.float64) * 1000.0
        return self._cache.indices(lam_nm, self._rindex)

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


@functools.cache
def _catalog_names(catalog: str) -> dict[str, str]:
    """Normalized name -> vendor name for one catalogue, its names cached on disk
    (lensim.optics.glass_cache; loading a catalogue takes ~0.1-0.8 s plus ~0.9 s to import
    opticalglass). A glass that is not an exact vendor name (SK16 for N-SK16) searches
    every catalogue's names first: resolving the Cooke triplet's SK16 in a fresh process
    took 3.1 s without the names cache and 1.4 s with it (most of that opticalglass's
    import, to create the glass itself, which the index cache now also avoids)."""
    return {_normalize(n): n for n in glass_cache.catalog_names(catalog, _load_catalog_names)}


def _load_catalog_names(catalog: str) -> list[str]:
    """The vendor names of one catalogue, loaded through opticalglass."""
    import warnings

    from opticalglass import glassfactory

    with warnings.catch_warnings():
        # opticalglass's spreadsheet loading emits pandas deprecation noise
        warnings.simplefilter("ignore")
        cat = glassfactory.get_glass_catalog(catalog)
    return [str(n) for n in cat.get_glass_names()]


def _catalog_key(catalog: str) -> str:
    for c in CATALOGS:
        if c.lower() == catalog.strip().lower():
            return c
    raise InputError(None, "catalog", f"unknown glass catalogue {catalog!r}; expected one of {', '.join(CATALOGS)}")


def glass_makers(makers: str | list[str] | tuple[str, ...]) -> list[str]:
    """The catalogues (their CATALOGS spelling) of glass makers named in any case, as a list
    or a comma-separated string ("ohara, Schott"): what match_glasses and
    nearest_catalog_glass search. None named, or an unknown one, is a ParameterError naming
    ``makers``."""
    given = makers.split(",") if isinstance(makers, str) else list(makers)
    names = [str(m).strip() for m in given if str(m).strip()]
    known = {c.lower(): c for c in CATALOGS}
    unknown = [m for m in names if m.lower() not in known]
    if unknown or not names:
        raise ParameterError(
            None,
            "makers",
            f"unknown glass maker(s) {', '.join(unknown) or repr(makers)}; expected some of {', '.join(CATALOGS)}",
        )
    return [known[m.lower()] for m in names]


@functools.cache
def catalog_glass(name: str, catalog: str) -> CatalogGlass:
    """Look a glass up in one catalogue by name (case, dashes and spaces ignored)."""
    catalog = _catalog_key(catalog)
    vendor_name = _catalog_names(catalog).get(_normalize(name))
    if vendor_name is None:
        raise UnknownGlassError(None, "material", f"glass {name!r} is not in the {catalog} catalogue")
    return CatalogGlass(vendor_name, catalog)


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
            note = (
                None
                if cat in listed
                else f"glass {name} is not in the catalogues {', '.join(listed)}; using {glass.name} from {cat}"
            )
            return glass, note
    fam = _family(re.sub(r"_MOLD$", "", name.strip(), flags=re.I))
    for cat in everywhere:
        matches = sorted(v for v in _catalog_names(cat).values() if _family(v) == fam)
        if len(matches) >= 1:
            glass = catalog_glass(matches[0], cat)
            return glass, (
                f"glass {name} is in no catalogue; using the same family's {glass.name} from {cat} "
                f"(nd {glass.nd:.5f}, Vd {glass.vd:.2f})"
            )
    candidates = {k: (v, c) for c in everywhere for k, v in _catalog_names(c).items()}
    close = difflib.get_close_matches(key, list(candidates), n=5, cutoff=0.6)
    hint = ", ".join(f"{candidates[k][0]} ({candidates[k][1]})" for k in close) or "none"
    raise UnknownGlassError(
        None, "material", f"unknown glass {name!r} (searched {', '.join(everywhere)}); close names: {hint}"
    )


# Wavelengths (um) over which glasses are matched: the visible, where model glasses hold.
MATCH_WAVELENGTHS_UM = np.linspace(0.40, 0.70, 31)


@functools.cache
def _catalog_index_table(catalog: str) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, indices (N, len(MATCH_WAVELENGTHS_UM))) of every glass of one catalogue whose
    data give finite indices over the matching range (a few vendor rows are incomplete)."""
    import warnings

    names, rows = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for vendor_name in sorted(_catalog_names(catalog).values()):
            try:
                n = catalog_glass(vendor_name, catalog).index(MATCH_WAVELENGTHS_UM)
            except Exception:  # noqa: BLE001 - opticalglass raises several kinds on an incomplete row
                continue
            if np.all(np.isfinite(n)) and np.all(n > 1.0):
                names.append(vendor_name)
                rows.append(n)
    return tuple(names), np.array(rows)


def nearest_catalog_glass(
    material: Material, makers: list[str] | tuple[str, ...] | None = None
) -> tuple[CatalogGlass, float]:
    """The catalogue glass closest to `material` and the RMS index difference to it.

    Closest as in Zemax's "best fit glass": the smallest root-mean-square difference of the
    refractive indices, here over 400-700 nm in 10 nm steps (MATCH_WAVELENGTHS_UM).
    makers: the catalogues searched (any of CATALOGS; default all of them).
    """
    cats = [_catalog_key(c) for c in (makers or CATALOGS)]
    target = np.asarray(material.index(MATCH_WAVELENGTHS_UM), dtype=np.float64)
    best: tuple[float, str, str] | None = None
    for cat in cats:
        names, table = _catalog_index_table(cat)
        if not names:
            continue
        rms = np.sqrt(np.mean((table - target) ** 2, axis=1))
        i = int(np.argmin(rms))
        if best is None or rms[i] < best[0]:
            best = (float(rms[i]), names[i], cat)
    if best is None:
        raise InputError(None, "makers", f"no usable glass in the catalogues {', '.join(cats)}")
    return catalog_glass(best[1], best[2]), best[0]


def _model_glass_from_spec(spec: dict) -> ModelGlass:
    """{nd, vd[, dpgf][, name][, model]} -> ModelGlass, with the ranges checked."""
    unknown = sorted(set(spec) - {"nd", "vd", "dpgf", "name", "model"})
    if unknown:
        raise InputError(
            None,
            "material",
            f"unknown model-glass key(s) {', '.join(map(str, unknown))}; expected nd, vd, dpgf, name, model",
        )
    forced = spec.get("model", False)
    if not isinstance(forced, bool):
        raise InputError(None, "material", f"model glass 'model' must be true or false, got {forced!r}")
    try:
        nd, vd, dpgf = float(spec["nd"]), float(spec["vd"]), float(spec.get("dpgf", 0.0))
    except (TypeError, ValueError):
        raise InputError(None, "material", f"model glass nd, vd and dpgf must be numbers, got {spec!r}") from None
    if not (1.0 <= nd < 5.0) or not (0 < vd < math.inf):
        raise InputError(None, "material", f"model glass needs 1 <= nd < 5 and vd > 0, got nd={nd}, vd={vd}")
    if not abs(dpgf) < 0.2:
        raise InputError(None, "material", f"model glass dpgf must lie between -0.2 and 0.2, got {dpgf}")
    return ModelGlass(nd, vd, dpgf, name=str(spec.get("name", f"model {nd:.5f}/{vd:.2f}")), forced=forced)


def material_from_spec(spec, catalogs: list[str] | None = None, notes: list[str] | None = None) -> Material:
    """Build a material from its native-file form.

    Accepted: "air"; "N-BK7" (searched in all catalogues); "N-BK7@Schott";
    {"nd": 1.5168, "vd": 64.17[, "dpgf": -0.0009][, "model": true]} (model glass; dpgf 0: on
    the normal line; "model": true keeps it a model where a catalogue glass matches);
    {"n": 1.5} (constant index);
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
            return ConstantIndex(_constant_index(spec["n"]))
        if "nd" in spec and "vd" in spec:
            return _model_glass_from_spec(spec)
        if "glass" in spec:
            name = str(spec["glass"]) + (f"@{spec['catalog']}" if "catalog" in spec else "")
            return material_from_spec(name, catalogs, notes)
    raise InputError(None, "material", f"expected a glass name, 'air', {{nd, vd}} or {{n}}, got {spec!r}")


# ---------------------------------------------------------------- catalogue twins of nd/Vd pairs

#: a vendor's dispersion formula gives its catalogue's nominal nd to about 2e-5 and Vd to
#: about 0.05 (measured over the six catalogues): added to a pair's own rounding
TWIN_SLACK_ND = 2.5e-5
TWIN_SLACK_VD = 0.05
#: the table of every catalogue glass's nd and Vd (from its own formula), shipped so that a
#: pair is matched without loading the six catalogues (lensim.optics.materials.twin_table_rows
#: writes it; tests/test_glass_twins.py checks it against opticalglass)
TWIN_TABLE = "glasses/nd_vd.json"


def written_rounding(x: float, finest: float, coarsest: float) -> float:
    """Half a unit in the last decimal place of x as written (the shortest decimal that reads
    back as x: 1.497 -> 5e-4, 81.61 -> 5e-3), kept within [finest, coarsest] (trailing zeros
    of the printed value, 1.49700, are lost in a float)."""
    import decimal

    exponent = decimal.Decimal(repr(float(x))).normalize().as_tuple().exponent
    half = 0.5 * 10.0 ** int(exponent)  # normalize() never leaves a special exponent for a finite x
    return min(max(half, finest), coarsest)


def twin_table_rows(catalogs: tuple[str, ...] = CATALOGS) -> list[list]:
    """[catalogue, name, nd, Vd] of every glass of the catalogues whose formula gives finite
    indices at d, F and C (what TWIN_TABLE holds; nd to 1e-7, Vd to 1e-4)."""
    import warnings

    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for cat in catalogs:
            for name in sorted(_catalog_names(cat).values()):
                try:
                    glass = catalog_glass(name, cat)
                    nd, vd = glass.nd, glass.vd
                except Exception:  # noqa: BLE001 - opticalglass raises several kinds on an incomplete row
                    continue
                if math.isfinite(nd) and math.isfinite(vd) and nd > 1.0 and vd > 0:
                    rows.append([cat, name, round(nd, 7), round(vd, 4)])
    return rows


@functools.cache
def _twin_table() -> tuple[tuple[str, ...], tuple[str, ...], np.ndarray]:
    """(catalogues, names, (N, 2) nd and Vd) of TWIN_TABLE."""
    import json

    from lensim.assets import ASSETS_DIR

    rows = json.loads((ASSETS_DIR / TWIN_TABLE).read_text())["glasses"]
    return (
        tuple(r[0] for r in rows),
        tuple(r[1] for r in rows),
        np.array([[r[2], r[3]] for r in rows], dtype=np.float64),
    )


def twin_tolerances(model: ModelGlass) -> tuple[float, float]:
    """(nd, Vd) tolerances of a pair: its written rounding (nd 5e-6 to 5e-4, Vd 5e-3 to 0.05)
    plus the formula slack TWIN_SLACK_ND, TWIN_SLACK_VD."""
    return (
        written_rounding(model.nd_value, 5e-6, 5e-4) + TWIN_SLACK_ND,
        written_rounding(model.vd_value, 5e-3, 0.05) + TWIN_SLACK_VD,
    )


@functools.cache
def catalogue_twin(model: ModelGlass, makers: tuple[str, ...] | None = None) -> CatalogGlass | None:
    """The catalogue glass a bare nd/Vd pair (a patent's glass: a model glass with dPgF 0 that
    is not ``forced``) stands for: of the glasses whose nd and Vd lie within the pair's
    rounding (twin_tolerances), the nearest in units of those tolerances, searched in
    ``makers``' catalogues (default all; ties go to the first in CATALOGS order, then by
    name). None when no glass matches, or for any other material."""
    if not isinstance(model, ModelGlass) or model.forced or model.dpgf_value != 0.0:
        return None
    cats, names, table = _twin_table()
    wanted = {_catalog_key(c) for c in (makers or CATALOGS)}
    tol = np.array(twin_tolerances(model))
    dist = np.abs(table - np.array([model.nd_value, model.vd_value])) / tol
    order = np.lexsort((np.arange(len(names)), (dist**2).sum(axis=1)))
    for i in order:
        if dist[i].max() > 1.0:
            break
        if cats[i] not in wanted:
            continue
        try:
            glass = catalog_glass(names[i], cats[i])
        except UnknownGlassError:  # an opticalglass release without this glass
            continue
        if abs(glass.nd - model.nd_value) <= tol[0] and abs(glass.vd - model.vd_value) <= tol[1]:
            return glass
    return None


def twin_note(replaced: list[tuple[list[int], ModelGlass, CatalogGlass]]) -> str:
    """One note line for the pairs replaced by their catalogue twins: [(surface indices,
    model, glass)]."""
    each = "; ".join(
        f"surfaces[{', '.join(map(str, idx))}] nd {m.nd_value:g} Vd {m.vd_value:g} = {g.name} ({g.catalog}, "
        f"nd {g.nd:.5f} Vd {g.vd:.2f} dPgF {g.dpgf:+.4f})"
        for idx, m, g in replaced
    )
    return (
        "glass nd/Vd pairs that match a catalogue glass within their rounding are that glass, "
        f"with its partial dispersion: {each}"
    )
