"""Import Zemax OpticStudio sequential lens files (.zmx, ASCII/UTF-8 or UTF-16 LE/BE).

Read: surfaces (TYPE STANDARD, EVENASPH or ODDASPHE only; CURV, CONI, PARM 1..8 = the
r^2..r^16 coefficients of EVENASPH and the r^1..r^8 coefficients of ODDASPHE, DISZ, GLAS, STOP, DIAM, CLAP, OBSC, FLAP, COMM), the system aperture (ENPD,
FNUM image-space or paraxial working F/# for an object at infinity, FLOA), UNIT (MM only),
NAME, GCAT, FTYP (field type, numbers of fields and wavelengths; telecentric object space
and afocal image space are refused), XFLN/YFLN (older XFLD/YFLD), WAVM (older WAVL/WWGT),
PWAV, and the multi-configuration editor: MNUM (number of configurations, the active one)
and its THIC operands (``THIC surface configuration value ...``, one line per operand and
configuration), read into ``Lens.configurations`` named 1..n (a zoom's positions; the
lens data as saved are the active configuration's). Vignetting factors, ray aiming (RAIM)
and other multi-configuration operands (curvatures, glasses, apertures, fields, the object
distance's THIC 0, ...) are not applied; the lens's notes say so. Every other keyword (drawing, tolerancing, merit function,
solves whose results the file already holds) is ignored. Surface 0 is the object (DISZ =
object distance), the last surface the image; DIAM is the drawn semi-diameter, and
clips rays only with FLAP (floating aperture) or FLOA (the stop's size).

Glass: MIRROR makes a mirror; ___BLANK a model glass from the line's nd, Vd and dPgF
(GLAS ___BLANK 1 0 nd Vd dPgF ...; Vd 0: constant index); other names are looked up in the file's GCAT catalogues, then in every
catalogue, then by glass family (notes record substitutions); a name found nowhere falls
back to the line's nd/Vd as a model glass (with a note) when the line carries real
values, otherwise it is an error listing close names. Lengths in mm, wavelengths in um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from lensim.errors import InputError, UnknownGlassError
from lensim.io import decode_text, read_bytes
from lensim.optics.lens import Lens
from lensim.optics.materials import CATALOGS, Air, ConstantIndex, Material, ModelGlass, resolve_glass
from lensim.optics.surfaces import Surface

SUPPORTED_TYPES = ("STANDARD", "EVENASPH", "ODDASPHE")
# PARM k's power: EVENASPH r^(2k), ODDASPHE (Zemax's "Odd Asphere") r^k
_PARM_POWER = {"EVENASPH": 2, "ODDASPHE": 1}
FIELD_TYPES = {0: "angle", 1: "object_height", 2: "paraxial_image_height", 3: "real_image_height"}
# Zemax's default nd/Vd on a catalogue glass's GLAS line: no real model data.
PLACEHOLDER_ND_VD = (1.5, 40.0)
_CATALOG_NAMES = {c.upper(): c for c in CATALOGS}
_NON_CIRCULAR_APERTURES = {
    "SQAP": "rectangular aperture",
    "ELAP": "elliptical aperture",
    "SQOB": "rectangular obscuration",
    "ELOB": "elliptical obscuration",
    "UDAP": "user-defined aperture",
    "UDOB": "user-defined obscuration",
}
_RAY_AIMING = {1: "paraxial", 2: "real"}
# per-field columns (older files: XFLD/YFLD)
# multi-configuration operands other than THIC (noted as not applied when they are in the file)
_MCE_OPERANDS = {
    "CRVT",
    "CONN",
    "GLSS",
    "PRAM",
    "PAR1",
    "PAR2",
    "PAR3",
    "PAR4",
    "PAR5",
    "PAR6",
    "PAR7",
    "PAR8",
    "APER",
    "WAVE",
    "WLWT",
    "PWAV",
    "XFIE",
    "YFIE",
    "FLWT",
    "FVDX",
    "FVDY",
    "FVCX",
    "FVCY",
    "FVAN",
    "SDIA",
    "CADX",
    "CADY",
    "CATX",
    "CATY",
    "CTIP",
    "TEMP",
    "PRES",
    "STPS",
    "PUCN",
    "SATP",
    "FLTP",
    "RAAM",
    "MOFF",
    "MIND",
    "MABB",
    "MDPG",
    "NPAR",
    "COTN",
    "IGNR",
    "LTTL",
    "XDAT",
    "YDAT",
}
_COLUMNS = {k: k for k in ("XFLN", "YFLN", "VDXN", "VDYN", "VCXN", "VCYN", "VANN")} | {"XFLD": "XFLN", "YFLD": "YFLN"}


@dataclass
class _Surf:
    number: int
    type: str = "STANDARD"
    curv: float = 0.0
    conic: float = 0.0
    parms: dict[int, tuple[float, int]] = field(default_factory=dict)
    disz: float = 0.0
    glas: list[str] | None = None
    glas_line: int = 0
    stop: bool = False
    diam: float = 0.0
    clap: tuple[float, float] | None = None
    obsc: tuple[float, float] | None = None
    obsc_line: int = 0
    flap: bool = False
    comment: str = ""


class _Reader:
    def __init__(self, path: Path):
        self.src = str(path)
        self.notes: list[str] = []
        self.name = ""
        self.aperture: tuple[str, float, int] | None = None  # (keyword, value, line)
        self.catalogs: list[str] | None = None
        self.ftyp: tuple[int, int | None, int | None, int] | None = None  # type, n fields, n waves, line
        self.columns: dict[str, tuple[list[float], int]] = {}
        self.wavm: dict[int, tuple[float, float]] = {}
        self.wavl: list[float] | None = None
        self.wwgt: list[float] | None = None
        self.pwav: tuple[int, int] | None = None
        self.surfs: list[_Surf] = []
        self.mnum: tuple[int, int, int] | None = None  # configurations, the active one, line
        self.thic: dict[int, dict[int, tuple[float, int]]] = {}  # Zemax surface -> {config: (value, line)}
        self.mce_other: set[str] = set()

    # ---- helpers -----------------------------------------------------------------
    def err(self, lineno: int, what: str, msg: str) -> InputError:
        return InputError(self.src, f"line {lineno} ({what})", msg)

    def num(self, lineno: int, what: str, tokens: list[str], i: int) -> float:
        if i >= len(tokens):
            raise self.err(lineno, what, f"expected at least {i} value(s) after {tokens[0]}")
        try:
            x = float(tokens[i])
        except ValueError:
            raise self.err(lineno, what, f"expected a number, got {tokens[i]!r}") from None
        if not math.isfinite(x):
            raise self.err(lineno, what, f"expected a finite number, got {tokens[i]!r}")
        return x

    def integer(self, lineno: int, what: str, tokens: list[str], i: int) -> int:
        x = self.num(lineno, what, tokens, i)
        if x != int(x):
            raise self.err(lineno, what, f"expected a whole number, got {tokens[i]!r}")
        return int(x)

    def values(self, lineno: int, key: str, tokens: list[str]) -> list[float]:
        return [self.num(lineno, key, tokens, i) for i in range(1, len(tokens))]

    # ---- parsing -----------------------------------------------------------------
    def line(self, lineno: int, text: str) -> None:
        """Read one line of the file: a system keyword, or a keyword of the current surface."""
        tokens = text.split()
        if not tokens:
            return
        key = tokens[0].upper()
        if not self.system_line(lineno, key, tokens, text) and self.surfs:
            self.surface_line(self.surfs[-1], lineno, key, tokens, text)

    def system_line(self, lineno: int, key: str, tokens: list[str], text: str) -> bool:
        """Read a system keyword (SURF starts a surface); False when ``key`` is not one."""
        if key == "SURF":
            n = self.integer(lineno, "SURF", tokens, 1)
            if n != len(self.surfs):
                raise self.err(lineno, "SURF", f"expected surface number {len(self.surfs)}, got {n}")
            self.surfs.append(_Surf(n))
        elif key == "MODE":
            if len(tokens) > 1 and tokens[1].upper() != "SEQ":
                raise self.err(lineno, "MODE", f"expected a sequential lens (MODE SEQ), got MODE {tokens[1]}")
        elif key == "UNIT":
            unit = tokens[1].upper() if len(tokens) > 1 else ""
            if unit != "MM":
                raise self.err(
                    lineno,
                    "UNIT",
                    f"expected lens units MM, got {unit or 'nothing'}; "
                    "set the lens units to millimetres in OpticStudio and save again",
                )
        elif key == "NAME":
            self.name = text.strip()[4:].strip()
        elif key in ("ENPD", "FNUM", "OBNA", "FLOA"):
            value = self.num(lineno, key, tokens, 1) if key != "FLOA" else 0.0
            flag = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 and key != "FLOA" else 0
            self.aperture = (key if flag == 0 else f"{key}/{flag}", value, lineno)
        elif key == "GCAT":
            self.glass_catalogues(tokens)
        elif key == "FTYP":
            self.field_type(lineno, tokens)
        elif key in _COLUMNS:
            self.columns[_COLUMNS[key]] = (self.values(lineno, key, tokens), lineno)
        elif key == "WAVM":
            k = self.integer(lineno, key, tokens, 1)
            wl = self.num(lineno, key, tokens, 2)
            weight = self.num(lineno, key, tokens, 3) if len(tokens) > 3 else 1.0
            self.wavm[k] = (wl, weight)
        elif key == "WAVL":
            self.wavl = self.values(lineno, key, tokens)
        elif key == "WWGT":
            self.wwgt = self.values(lineno, key, tokens)
        elif key == "PWAV":
            self.pwav = (self.integer(lineno, key, tokens, 1), lineno)
        elif key == "RAIM":
            mode = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 else 0
            if mode in _RAY_AIMING:
                self.notes.append(
                    f"the file sets {_RAY_AIMING[mode]} ray aiming (RAIM); lensim aims rays as the "
                    "caller asks (aiming='real' aims at the real stop)"
                )
        elif key == "MNUM":
            n = self.integer(lineno, key, tokens, 1)
            active = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 else 1
            if n < 1 or not 1 <= active <= n:
                raise self.err(
                    lineno, key, f"expected a number of configurations >= 1 and the active one 1..n, got {n} {active}"
                )
            self.mnum = (n, active, lineno)
        elif key == "THIC":
            self.thickness_operand(lineno, tokens)
        elif key in _MCE_OPERANDS and self.mnum is not None:
            if key != "MOFF":
                self.mce_other.add(key)
        else:
            return False
        return True

    def thickness_operand(self, lineno: int, tokens: list[str]) -> None:
        """A multi-configuration THIC operand: THIC surface configuration value ..."""
        if self.mnum is None:
            raise self.err(lineno, "THIC", "a multi-configuration operand before MNUM (the number of configurations)")
        surface = self.integer(lineno, "THIC", tokens, 1)
        config = self.integer(lineno, "THIC", tokens, 2)
        value = self.num(lineno, "THIC", tokens, 3)
        if not 1 <= config <= self.mnum[0]:
            raise self.err(lineno, "THIC", f"expected a configuration number 1..{self.mnum[0]} (MNUM), got {config}")
        if surface < 0:
            raise self.err(lineno, "THIC", f"expected a surface number >= 0, got {surface}")
        self.thic.setdefault(surface, {})[config] = (value, lineno)

    def glass_catalogues(self, tokens: list[str]) -> None:
        """GCAT: the catalogues to search, with a note naming those lensim does not have."""
        cats, unknown = [], []
        for name in tokens[1:]:
            (cats if name.upper() in _CATALOG_NAMES else unknown).append(name)
        if unknown:
            self.notes.append(
                f"glass catalogue(s) {', '.join(unknown)} not available in lensim; ignored "
                f"(searching {', '.join(_CATALOG_NAMES[c.upper()] for c in cats) or 'every catalogue'})"
            )
        self.catalogs = [_CATALOG_NAMES[c.upper()] for c in cats] or None

    def field_type(self, lineno: int, tokens: list[str]) -> None:
        """FTYP: field type, number of fields and wavelengths; telecentric or afocal refused."""
        key = "FTYP"
        ftyp = self.integer(lineno, key, tokens, 1)
        if ftyp not in FIELD_TYPES:
            raise self.err(
                lineno,
                key,
                f"unsupported field type {ftyp}; expected 0 (angle), 1 (object height), "
                "2 (paraxial image height) or 3 (real image height)",
            )
        if len(tokens) > 2 and self.integer(lineno, key, tokens, 2) == 1:
            raise self.err(
                lineno,
                key,
                "telecentric object space is not supported; expected the stop to "
                "define the entrance pupil (FTYP second value 0)",
            )
        if len(tokens) > 7 and self.integer(lineno, key, tokens, 7) == 1:
            raise self.err(
                lineno,
                key,
                "afocal image space is not supported; expected a lens that forms an image (FTYP seventh value 0)",
            )
        nf = self.integer(lineno, key, tokens, 3) if len(tokens) > 3 else None
        nw = self.integer(lineno, key, tokens, 4) if len(tokens) > 4 else None
        self.ftyp = (ftyp, nf, nw, lineno)

    def surface_line(self, cur: _Surf, lineno: int, key: str, tokens: list[str], text: str) -> None:
        """Read a keyword of surface ``cur`` (other keywords are ignored)."""
        sw = f"SURF {cur.number} {key}"
        if key == "TYPE":
            cur.type = tokens[1].upper() if len(tokens) > 1 else ""
            cur.type = "ODDASPHE" if cur.type == "ODDASPH" else cur.type
            if cur.type not in SUPPORTED_TYPES:
                raise InputError(
                    self.src,
                    f"SURF {cur.number} TYPE",
                    f"unsupported surface type {cur.type or 'nothing'} (line {lineno}); "
                    f"lensim reads {', '.join(SUPPORTED_TYPES)} surfaces only",
                )
        elif key == "CURV":
            cur.curv = self.num(lineno, sw, tokens, 1)
        elif key == "CONI":
            cur.conic = self.num(lineno, sw, tokens, 1)
        elif key == "PARM":
            k = self.integer(lineno, sw, tokens, 1)
            cur.parms[k] = (self.num(lineno, sw, tokens, 2), lineno)
        elif key == "DISZ":
            if len(tokens) > 1 and tokens[1].upper() == "INFINITY":
                cur.disz = math.inf
            else:
                cur.disz = self.num(lineno, sw, tokens, 1)
        elif key == "GLAS":
            if len(tokens) < 2:
                raise self.err(lineno, sw, "expected a glass name")
            cur.glas, cur.glas_line = tokens[1:], lineno
        elif key == "STOP":
            cur.stop = True
        elif key == "DIAM":
            cur.diam = self.num(lineno, sw, tokens, 1)
        elif key == "CLAP":
            cur.clap = (self.num(lineno, sw, tokens, 1), self.num(lineno, sw, tokens, 2))
        elif key == "OBSC":
            cur.obsc = (self.num(lineno, sw, tokens, 1), self.num(lineno, sw, tokens, 2))
            cur.obsc_line = lineno
        elif key == "FLAP":
            cur.flap = True
        elif key == "OBDC":
            dx, dy = (self.num(lineno, sw, tokens, i) for i in (1, 2))
            if dx or dy:
                raise self.err(
                    lineno, sw, f"a decentred aperture ({dx}, {dy}) is not rotationally symmetric; expected 0 0"
                )
        elif key in _NON_CIRCULAR_APERTURES:
            raise self.err(
                lineno,
                sw,
                f"a {_NON_CIRCULAR_APERTURES[key]} is not rotationally symmetric; "
                "expected a circular aperture (CLAP), obscuration (OBSC) or floating aperture",
            )
        elif key == "COMM":
            cur.comment = text.strip()[4:].strip()

    # ---- building ----------------------------------------------------------------
    def glass(self, s: _Surf, medium: Material) -> tuple[Material, bool]:
        """(material after surface s, is_mirror)."""
        if s.glas is None:
            return Air(), False
        what = f"SURF {s.number} GLAS"
        t = s.glas
        name = t[0]
        if name.upper() == "MIRROR":
            return medium, True

        def opt_num(i: int) -> float | None:
            return self.num(s.glas_line, what, t, i) if len(t) > i else None

        nd, vd, dpgf = opt_num(3), opt_num(4), opt_num(5) or 0.0
        if name.upper() == "___BLANK":
            if nd is None or vd is None:
                raise self.err(s.glas_line, what, "expected a model glass line 'GLAS ___BLANK 1 0 nd Vd dPgF ...'")
            return self.model(s, nd, vd, dpgf), False
        try:
            mat, note = resolve_glass(name, self.catalogs)
        except UnknownGlassError as e:
            if nd is not None and vd is not None and nd > 1.0 and vd >= 0.0 and (nd, vd) != PLACEHOLDER_ND_VD:
                self.notes.append(
                    f"glass {name} is in no catalogue; using a model glass with the file's nd {nd:.5f}, Vd {vd:.2f}"
                )
                return self.model(s, nd, vd, dpgf, name), False
            model = (
                "" if nd is None or vd is None else f" and the line's nd/Vd ({nd:g}, {vd:g}) are Zemax's placeholders"
            )
            raise InputError(self.src, what, f"{e.message}{model}") from None
        if note:
            self.notes.append(note)
        return mat, False

    def asphere(self, s: _Surf) -> dict[int, float]:
        """{power: coefficient} of an EVENASPH (PARM k: r^2k) or ODDASPHE (PARM k: r^k) surface."""
        step = _PARM_POWER.get(s.type)
        if step is None:
            return {}
        asphere: dict[int, float] = {}
        for k, (v, line) in sorted(s.parms.items()):
            if not 1 <= k <= 8:
                if v != 0.0:
                    raise self.err(
                        line, f"SURF {s.number} PARM", f"expected PARM 1..8 (r^{step}..r^{8 * step}), got PARM {k}"
                    )
                continue
            if v != 0.0:
                asphere[step * k] = v
        return asphere

    def model(self, s: _Surf, nd: float, vd: float, dpgf: float, name: str | None = None) -> Material:
        """Zemax's MODEL glass (nd, Vd, dPgF); Vd 0 is a constant index."""
        if not (1.0 < nd < 5.0) or vd < 0 or not abs(dpgf) < 0.2:
            raise self.err(
                s.glas_line,
                f"SURF {s.number} GLAS",
                f"expected model glass 1 < nd < 5, Vd >= 0 and |dPgF| < 0.2, got nd {nd}, Vd {vd}, dPgF {dpgf}",
            )
        if vd == 0:
            return ConstantIndex(nd)
        return ModelGlass(nd, vd, dpgf, name=name or f"model {nd:.5f}/{vd:.2f}")

    def fields(self) -> tuple[str, list[float]]:
        ftyp, nf, _, _ = self.ftyp if self.ftyp else (0, None, None, 0)
        if "YFLN" not in self.columns:
            if nf not in (None, 1):
                raise InputError(self.src, "YFLN", f"missing the field values (FTYP says {nf} fields)")
            return FIELD_TYPES[ftyp], [0.0]
        ys, yline = self.columns["YFLN"]
        n = len(ys) if nf is None else nf
        if not 1 <= n <= len(ys):
            raise self.err(yline, "YFLN", f"expected {n} field values (FTYP), got {len(ys)}")
        if "XFLN" in self.columns:
            xs, xline = self.columns["XFLN"]
            bad = [(i + 1, x) for i, x in enumerate(xs[:n]) if x != 0.0]
            if bad:
                raise self.err(
                    xline,
                    "XFLN",
                    f"field {bad[0][0]} has x = {bad[0][1]:g}; lensim models rotationally "
                    "symmetric lenses with fields along y (give the radial field in YFLN)",
                )
        vig = []
        for key in ("VDXN", "VDYN", "VCXN", "VCYN", "VANN"):
            vals = self.columns.get(key, ([], 0))[0][:n]
            if any(v != 0.0 for v in vals):
                vig.append(f"{key} {' '.join(f'{v:.4g}' for v in vals)}")
        if vig:
            self.notes.append(
                f"vignetting factors ({'; '.join(vig)}) are not applied; lensim vignettes rays "
                "with the real surface apertures"
            )
        return FIELD_TYPES[ftyp], ys[:n]

    def wavelengths(self) -> tuple[list[float], list[float], int]:
        nw = self.ftyp[2] if self.ftyp else None
        if self.wavm:
            n = nw if nw is not None else max(self.wavm)
            missing = [k for k in range(1, n + 1) if k not in self.wavm]
            if missing:
                raise InputError(self.src, "WAVM", f"missing wavelength {missing[0]} of {n}")
            wls = [self.wavm[k][0] for k in range(1, n + 1)]
            weights = [self.wavm[k][1] for k in range(1, n + 1)]
        elif self.wavl:
            n = nw if nw is not None else len(self.wavl)
            if n > len(self.wavl):
                raise InputError(self.src, "WAVL", f"expected {n} wavelengths, got {len(self.wavl)}")
            wls = self.wavl[:n]
            weights = (self.wwgt or [1.0] * n)[:n]
            if len(weights) != n:
                raise InputError(self.src, "WWGT", f"expected {n} weights, got {len(weights)}")
        else:
            raise InputError(self.src, "WAVM", "missing the wavelengths")
        primary = 1
        if self.pwav is not None:
            primary = self.pwav[0]
            if not 1 <= primary <= len(wls):
                raise self.err(self.pwav[1], "PWAV", f"expected a wavelength number 1..{len(wls)}, got {primary}")
        return wls, weights, primary - 1

    def build(self) -> Lens:
        if len(self.surfs) < 3:
            raise InputError(
                self.src,
                "SURF",
                f"expected an object, at least one lens surface and an image surface, "
                f"found {len(self.surfs)} surface(s)",
            )
        obj, img, optical = self.surfs[0], self.surfs[-1], self.surfs[1:-1]
        stops = [s for s in self.surfs if s.stop]
        if not stops:
            raise InputError(self.src, "STOP", "missing the aperture stop: no surface has a STOP line")
        if stops[0] in (obj, img):
            raise InputError(
                self.src, f"SURF {stops[0].number} STOP", "expected the stop on a lens surface, not the object or image"
            )
        # object
        object_distance = obj.disz if obj.disz < 1e10 else math.inf
        if not object_distance > 0:
            raise InputError(
                self.src, "SURF 0 DISZ", f"expected a positive object distance or INFINITY, got {obj.disz}"
            )
        if math.isfinite(object_distance) and obj.curv != 0.0:
            raise InputError(self.src, "SURF 0 CURV", "expected a flat object surface")
        object_material, mirror = self.glass(obj, Air())
        if mirror:
            raise InputError(self.src, "SURF 0 GLAS", "the object surface cannot be a mirror")
        if img.curv != 0.0:
            raise InputError(self.src, f"SURF {img.number} CURV", "expected a flat image surface")
        # surfaces
        surfaces: list[Surface] = []
        medium = object_material
        for s in optical:
            if not math.isfinite(s.disz):
                raise InputError(
                    self.src, f"SURF {s.number} DISZ", "expected a finite thickness (INFINITY is for the object)"
                )
            asphere = self.asphere(s)
            material, mirror = self.glass(s, medium)
            medium = material
            clear, obscuration = self.apertures(s)
            surfaces.append(
                Surface(
                    curvature=s.curv,
                    thickness=s.disz,
                    material=material,
                    conic=s.conic,
                    asphere=asphere,
                    clear_radius=clear,
                    obscuration_radius=obscuration,
                    semi_diameter=s.diam if s.diam > 0 else None,
                    is_stop=s.stop,
                    is_mirror=mirror,
                    comment=s.comment,
                )
            )
        image_clear, _ = self.apertures(img)
        aperture_type, aperture_value = self.system_aperture(stops[0], object_distance)
        field_type, fields = self.fields()
        wls, weights, primary = self.wavelengths()
        configurations = self.configurations(len(optical))
        return Lens(
            surfaces=surfaces,
            aperture_type=aperture_type,
            aperture_value=aperture_value,
            field_type=field_type,
            fields=fields,
            wavelengths_um=wls,
            wavelength_weights=weights,
            primary=primary,
            object_distance=object_distance,
            object_material=object_material,
            image_clear_radius=image_clear,
            name=self.name or Path(self.src).stem,
            source=self.src,
            notes=self.notes,
            configurations=configurations,
        )

    def configurations(self, n_optical: int) -> dict[str, dict[int, float]]:
        """Lens.configurations from the THIC operands: configuration k (named "k") sets
        surfaces[s - 1].thickness for every operand on Zemax surface s = 1..n_optical (the
        last one's thickness is the distance to the image); notes for what is not applied."""
        if self.mnum is None or self.mnum[0] < 2:
            return {}
        n, active, _ = self.mnum
        optical = {s: per for s, per in self.thic.items() if 1 <= s <= n_optical}
        if 0 in self.thic:
            self.notes.append(
                "multi-configuration THIC 0 (the object distance per configuration) is not applied; "
                "the object distance as saved is used"
            )
        if self.mce_other:
            self.notes.append(
                f"multi-configuration operand(s) {', '.join(sorted(self.mce_other))} not applied "
                "(lensim's configurations change thicknesses only)"
            )
        if not optical:
            self.notes.append(
                f"the file has {n} configurations but no thickness operands (THIC) lensim applies; "
                f"the lens data as saved (configuration {active}) are used"
            )
            return {}
        out: dict[str, dict[int, float]] = {}
        for k in range(1, n + 1):
            thicknesses = {}
            for s, per in sorted(optical.items()):
                if k not in per:
                    line = next(iter(per.values()))[1]
                    raise self.err(line, "THIC", f"surface {s} has no value for configuration {k} of {n}")
                thicknesses[s - 1] = per[k][0]
            out[str(k)] = thicknesses
        return out

    def apertures(self, s: _Surf) -> tuple[float | None, float | None]:
        """(clear_radius, obscuration_radius) of a surface from CLAP / FLAP / OBSC."""
        clear = obscuration = None
        if s.clap is not None:
            rmin, rmax = s.clap
            if not 0 <= rmin < rmax:
                raise InputError(
                    self.src, f"SURF {s.number} CLAP", f"expected 0 <= min radius < max radius, got {rmin}, {rmax}"
                )
            clear = rmax
            obscuration = rmin if rmin > 0 else None
        elif s.flap:
            if s.diam <= 0:
                raise InputError(
                    self.src, f"SURF {s.number} FLAP", "a floating aperture needs a positive semi-diameter (DIAM)"
                )
            clear = s.diam
        if s.obsc is not None:
            rmin, rmax = s.obsc
            if rmin != 0 or rmax <= 0:
                raise self.err(
                    s.obsc_line,
                    f"SURF {s.number} OBSC",
                    f"expected a central obscuration '0 radius', got {rmin}, {rmax}",
                )
            obscuration = max(rmax, obscuration or 0.0)
        return clear, obscuration

    def system_aperture(self, stop: _Surf, object_distance: float) -> tuple[str, float]:
        if self.aperture is None:
            raise InputError(self.src, "aperture", "missing the system aperture; expected ENPD, FNUM or FLOA")
        key, value, line = self.aperture
        if key == "ENPD":
            return "epd", value
        if key == "FNUM":
            return "fno", value
        if key == "FNUM/1":
            if math.isinf(object_distance):
                # paraxial working F/# = 1 / (2 n' u') = EFL / EPD exactly for an object at infinity
                return "fno", value
            raise self.err(
                line,
                "FNUM",
                "a paraxial working F/# aperture is supported for an object at infinity "
                "only; expected ENPD, an image-space F/# or float by stop size",
            )
        if key == "FLOA":
            if stop.diam <= 0:
                raise InputError(
                    self.src, f"SURF {stop.number} DIAM", "float by stop size needs the stop's semi-diameter (DIAM > 0)"
                )
            return "stop_semi_diameter", stop.diam
        what = {"OBNA": "object-space NA", "OBNA/1": "object cone angle"}.get(key, key)
        raise self.err(
            line,
            key.split("/")[0],
            f"unsupported system aperture ({what}); expected ENPD, an image-space "
            "F/# (FNUM) or float by stop size (FLOA)",
        )


def read_zmx(path: str | Path) -> Lens:
    """Read a Zemax .zmx file into a Lens (see the module docstring for what is read)."""
    path = Path(path)
    reader = _Reader(path)
    text = decode_text(read_bytes(path, "Zemax lens file"), str(path))
    for lineno, line in enumerate(text.splitlines(), start=1):
        reader.line(lineno, line)
    return reader.build()
