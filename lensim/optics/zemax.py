"""Import Zemax OpticStudio sequential lens files (.zmx, ASCII/UTF-8 or UTF-16 LE/BE).

Read: surfaces (TYPE STANDARD, EVENASPH or ODDASPHE only; CURV, CONI, PARM 1..8 = the
r^2..r^16 coefficients of EVENASPH and the r^1..r^8 coefficients of ODDASPHE, DISZ, GLAS,
STOP, DIAM, CLAP, OBSC, FLAP, COMM), the system aperture (ENPD, FNUM image-space or
paraxial working F/# for an object at infinity, FLOA), UNIT (MM only), NAME, GCAT, FTYP
(field type, numbers of fields and wavelengths; telecentric object space and afocal image
space are refused), XFLN/YFLN (older XFLD/YFLD), WAVM (older WAVL/WWGT), PWAV, and the
multi-configuration editor: MNUM (number of configurations, the active one) and its THIC
operands (``THIC surface configuration value ...``, one line per operand and
configuration), read into ``Lens.configurations`` named 1..n (a zoom's positions; the
lens data as saved are the active configuration's). Vignetting factors, ray aiming (RAIM)
and other multi-configuration operands (curvatures, glasses, apertures, fields, the object
distance's THIC 0, ...) are not applied; the lens's notes say so. Every other keyword
(drawing, tolerancing, merit function, solves whose results the file already holds) is
ignored. Surface 0 is the object (DISZ = object distance), the last surface the image;
DIAM is the drawn semi-diameter, and clips rays only with FLAP (floating aperture) or FLOA
(the stop's size).

Each keyword has one handler (the tables ``_SYSTEM`` and ``_SURFACE``); what they read is
turned into a Lens by lensim.optics.zemax_build, which also describes the glass lookup.
Lengths in mm, wavelengths in um.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from lensim.errors import InputError
from lensim.io import decode_text, read_bytes
from lensim.optics.lens import Lens
from lensim.optics.materials import CATALOGS
from lensim.optics.zemax_build import FIELD_TYPES, ZemaxData, ZemaxSurface

SUPPORTED_TYPES = ("STANDARD", "EVENASPH", "ODDASPHE")
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
# multi-configuration operands other than THIC (noted as not applied when they are in the file)
_MCE_OPERANDS = frozenset(
    (
        "CRVT CONN GLSS PRAM PAR1 PAR2 PAR3 PAR4 PAR5 PAR6 PAR7 PAR8 APER WAVE WLWT PWAV XFIE "
        "YFIE FLWT FVDX FVDY FVCX FVCY FVAN SDIA CADX CADY CATX CATY CTIP TEMP PRES STPS PUCN "
        "SATP FLTP RAAM MOFF MIND MABB MDPG NPAR COTN IGNR LTTL XDAT YDAT"
    ).split()
)
# per-field columns (older files: XFLD/YFLD)
_COLUMNS = {k: k for k in ("XFLN", "YFLN", "VDXN", "VDYN", "VCXN", "VCYN", "VANN")} | {"XFLD": "XFLN", "YFLD": "YFLN"}
# surface keywords that set one number or flag of the surface (ZemaxSurface attribute)
_SURFACE_NUMBERS = {"CURV": "curv", "CONI": "conic", "DIAM": "diam"}
_SURFACE_FLAGS = {"STOP": "stop", "FLAP": "flap"}

# keyword -> handler: system keywords (reader, line number, keyword, tokens, line) and
# keywords of the current surface (the same after the surface); filled by @_system and @_surface
_H = TypeVar("_H")
_SystemHandler = Callable[["_Reader", int, str, list[str], str], None]
_SurfaceHandler = Callable[["_Reader", ZemaxSurface, int, str, list[str], str], None]
_SYSTEM: dict[str, _SystemHandler] = {}
_SURFACE: dict[str, _SurfaceHandler] = {}


def _registrar(table: dict[str, _H], keys: tuple[str, ...]) -> Callable[[_H], _H]:
    """A decorator that makes the decorated method the handler of ``keys`` in ``table``."""

    def register(handler: _H) -> _H:
        for key in keys:
            if key in _SYSTEM or key in _SURFACE:
                raise ValueError(f"Zemax keyword {key} has two handlers")
            table[key] = handler
        return handler

    return register


def _system(*keys: str) -> Callable[[_SystemHandler], _SystemHandler]:
    return _registrar(_SYSTEM, keys)


def _surface(*keys: str) -> Callable[[_SurfaceHandler], _SurfaceHandler]:
    return _registrar(_SURFACE, keys)


class _Reader(ZemaxData):
    """Reads a Zemax file line by line: one handler per keyword (``_SYSTEM``, ``_SURFACE``)."""

    # ---- parsing -----------------------------------------------------------------
    def line(self, lineno: int, text: str) -> None:
        """Read one line of the file: a system keyword (``_SYSTEM``; SURF starts a surface),
        else a keyword of the current surface (``_SURFACE``; other keywords are ignored)."""
        tokens = text.split()
        if not tokens:
            return
        key = tokens[0].upper()
        handler = _SYSTEM.get(key)
        if handler is not None:
            handler(self, lineno, key, tokens, text)
        elif self.surfs and key in _SURFACE:
            _SURFACE[key](self, self.surfs[-1], lineno, key, tokens, text)

    @_system("SURF")
    def _surf(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        n = self.integer(lineno, "SURF", tokens, 1)
        if n != len(self.surfs):
            raise self.err(lineno, "SURF", f"expected surface number {len(self.surfs)}, got {n}")
        self.surfs.append(ZemaxSurface(n))

    @_system("MODE")
    def _mode(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        if len(tokens) > 1 and tokens[1].upper() != "SEQ":
            raise self.err(lineno, "MODE", f"expected a sequential lens (MODE SEQ), got MODE {tokens[1]}")

    @_system("UNIT")
    def _unit(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        unit = tokens[1].upper() if len(tokens) > 1 else ""
        if unit != "MM":
            raise self.err(
                lineno,
                "UNIT",
                f"expected lens units MM, got {unit or 'nothing'}; "
                "set the lens units to millimetres in OpticStudio and save again",
            )

    @_system("NAME")
    def _name(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.name = text.strip()[4:].strip()

    @_system("ENPD", "FNUM", "OBNA")
    def _aperture(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        value = self.num(lineno, key, tokens, 1)
        flag = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 else 0
        self.aperture = (key if flag == 0 else f"{key}/{flag}", value, lineno)

    @_system("FLOA")
    def _float_by_stop(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.aperture = (key, 0.0, lineno)

    @_system("GCAT")
    def glass_catalogues(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        """GCAT: the catalogues to search, with a note naming those lensim does not have."""
        cats: list[str] = []
        unknown: list[str] = []
        for name in tokens[1:]:
            (cats if name.upper() in _CATALOG_NAMES else unknown).append(name)
        if unknown:
            self.notes.append(
                f"glass catalogue(s) {', '.join(unknown)} not available in lensim; ignored "
                f"(searching {', '.join(_CATALOG_NAMES[c.upper()] for c in cats) or 'every catalogue'})"
            )
        self.catalogs = [_CATALOG_NAMES[c.upper()] for c in cats] or None

    @_system(*_COLUMNS)
    def _column(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.columns[_COLUMNS[key]] = (self.values(lineno, key, tokens), lineno)

    @_system("WAVM")
    def _wavelength(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        k = self.integer(lineno, key, tokens, 1)
        wl = self.num(lineno, key, tokens, 2)
        weight = self.num(lineno, key, tokens, 3) if len(tokens) > 3 else 1.0
        self.wavm[k] = (wl, weight)

    @_system("WAVL")
    def _wavelength_list(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.wavl = self.values(lineno, key, tokens)

    @_system("WWGT")
    def _weight_list(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.wwgt = self.values(lineno, key, tokens)

    @_system("PWAV")
    def _primary(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        self.pwav = (self.integer(lineno, key, tokens, 1), lineno)

    @_system("RAIM")
    def _ray_aiming(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        mode = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 else 0
        if mode in _RAY_AIMING:
            self.notes.append(
                f"the file sets {_RAY_AIMING[mode]} ray aiming (RAIM); lensim aims rays as the "
                "caller asks (aiming='real' aims at the real stop)"
            )

    @_system("MNUM")
    def _configuration_count(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        n = self.integer(lineno, key, tokens, 1)
        active = self.integer(lineno, key, tokens, 2) if len(tokens) > 2 else 1
        if n < 1 or not 1 <= active <= n:
            raise self.err(
                lineno, key, f"expected a number of configurations >= 1 and the active one 1..n, got {n} {active}"
            )
        self.mnum = (n, active, lineno)

    @_system(*sorted(_MCE_OPERANDS - {"PWAV"}))  # PWAV is also the primary wavelength's keyword
    def _other_operand(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        if self.mnum is not None and key != "MOFF":
            self.mce_other.add(key)

    @_system("THIC")
    def thickness_operand(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
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

    @_system("FTYP")
    def field_type(self, lineno: int, key: str, tokens: list[str], text: str) -> None:
        """FTYP: field type, number of fields and wavelengths; telecentric or afocal refused."""
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

    @_surface("TYPE")
    def _type(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        cur.type = tokens[1].upper() if len(tokens) > 1 else ""
        cur.type = "ODDASPHE" if cur.type == "ODDASPH" else cur.type
        if cur.type not in SUPPORTED_TYPES:
            raise InputError(
                self.src,
                f"SURF {cur.number} TYPE",
                f"unsupported surface type {cur.type or 'nothing'} (line {lineno}); "
                f"lensim reads {', '.join(SUPPORTED_TYPES)} surfaces only",
            )

    @_surface(*_SURFACE_NUMBERS)
    def _number(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        setattr(cur, _SURFACE_NUMBERS[key], self.num(lineno, f"SURF {cur.number} {key}", tokens, 1))

    @_surface(*_SURFACE_FLAGS)
    def _flag(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        setattr(cur, _SURFACE_FLAGS[key], True)

    @_surface("PARM")
    def _parameter(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        sw = f"SURF {cur.number} {key}"
        k = self.integer(lineno, sw, tokens, 1)
        cur.parms[k] = (self.num(lineno, sw, tokens, 2), lineno)

    @_surface("DISZ")
    def _thickness(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        if len(tokens) > 1 and tokens[1].upper() == "INFINITY":
            cur.disz = math.inf
        else:
            cur.disz = self.num(lineno, f"SURF {cur.number} {key}", tokens, 1)

    @_surface("GLAS")
    def _glass(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        if len(tokens) < 2:
            raise self.err(lineno, f"SURF {cur.number} {key}", "expected a glass name")
        cur.glas, cur.glas_line = tokens[1:], lineno

    @_surface("CLAP", "OBSC")
    def _annulus(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        sw = f"SURF {cur.number} {key}"
        radii = (self.num(lineno, sw, tokens, 1), self.num(lineno, sw, tokens, 2))
        if key == "CLAP":
            cur.clap = radii
        else:
            cur.obsc, cur.obsc_line = radii, lineno

    @_surface("OBDC")
    def _aperture_decentre(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        sw = f"SURF {cur.number} {key}"
        dx, dy = (self.num(lineno, sw, tokens, i) for i in (1, 2))
        if dx or dy:
            raise self.err(lineno, sw, f"a decentred aperture ({dx}, {dy}) is not rotationally symmetric; expected 0 0")

    @_surface(*_NON_CIRCULAR_APERTURES)
    def _non_circular(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        raise self.err(
            lineno,
            f"SURF {cur.number} {key}",
            f"a {_NON_CIRCULAR_APERTURES[key]} is not rotationally symmetric; "
            "expected a circular aperture (CLAP), obscuration (OBSC) or floating aperture",
        )

    @_surface("COMM")
    def _comment(self, cur: ZemaxSurface, lineno: int, key: str, tokens: list[str], text: str) -> None:
        cur.comment = text.strip()[4:].strip()


def read_zmx(path: str | Path) -> Lens:
    """Read a Zemax .zmx file into a Lens (see the module docstring for what is read)."""
    path = Path(path)
    reader = _Reader(path)
    text = decode_text(read_bytes(path, "Zemax lens file"), str(path))
    for lineno, line in enumerate(text.splitlines(), start=1):
        reader.line(lineno, line)
    return reader.build()
