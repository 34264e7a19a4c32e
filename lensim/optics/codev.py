"""Import CODE V sequence (.seq) lens files.

The supported subset is what CODE V writes for plain rotationally symmetric lenses:

    RDM [Y|N]       radius mode: surfaces give radii (Y, the default) or curvatures (N)
    LEN ["title"]   start of the lens;  TITLE 'text'
    DIM M           millimetres (the only unit accepted)
    EPD d | FNO f   entrance-pupil diameter (mm) or image-space F/# (EFL / EPD)
    WL nm...        wavelengths (nm);  REF k (1-based primary);  WTW weights
    YAN | YOB | YIM | YRI values   fields: angle (deg), object height, paraxial or real
                    image height (mm); the X counterparts must be zero;  WTF ignored
    VUX VLX VUY VLY vignetting factors: not applied (a note says so)
    SO c t          object surface (t >= 1e10 is infinity)
    S c t [glass]   a surface: radius or curvature, thickness, glass (NAME_CATALOG such as
                    NSSK2_SCHOTT, a bare name searched in every catalogue, or REFL = mirror)
    STO             the current surface is the stop;  SI c t: image surface, t = defocus
    K k; ASP; A..H, J coefficients (r^4..r^20);  CIR r (clear semi-diameter)
    SPS ODD [0|1]   odd polynomial asphere (no normalization radius), with SCO K k and
                    SCO AR1..AR20 (the r^1..r^20 coefficients), or SCO C1 (= K), C2..C21 (= AR1..AR20)
    PIM             paraxial image solve: the last thickness is set to the paraxial focus
    CCY/THC/CCX codes, INI, DER, GO: ignored

Several commands may share a line, separated by ';'; '!' starts a comment. Anything
else raises InputError naming the line and the command. Lengths in mm.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from lensim.errors import InputError, UnknownGlassError
from lensim.io import decode_text, read_bytes
from lensim.optics.lens import Lens
from lensim.optics.materials import CATALOGS, Air, Material, resolve_glass
from lensim.optics.paraxial import paraxial_focus_thickness
from lensim.optics.surfaces import MAX_ASPHERE_POWER, Surface

INFINITE_THICKNESS_MM = 1e10
_TOKEN = re.compile(r"'[^']*'|\"[^\"]*\"|[^\s,]+")
_FIELD_KEYS = {"YAN": "angle", "YOB": "object_height", "YIM": "paraxial_image_height", "YRI": "real_image_height"}
_X_FIELD_KEYS = {"XAN", "XOB", "XIM", "XRI"}
_ASPHERE_LETTERS = {"A": 4, "B": 6, "C": 8, "D": 10, "E": 12, "F": 14, "G": 16, "H": 18, "J": 20}
_IGNORED = {"INI", "DER", "WTF", "CCY", "THC", "CCX"}
_CATALOG_SUFFIX = {c.upper(): c for c in CATALOGS}

# keyword -> handler(reader, line number, keyword, arguments): filled by @_command below
_Handler = Callable[["_Reader", int, str, list[str]], None]
_COMMANDS: dict[str, _Handler] = {}


def _command(*keys: str) -> Callable[[_Handler], _Handler]:
    """Register the decorated _Reader method as the handler of CODE V commands ``keys``."""

    def register(handler: _Handler) -> _Handler:
        for key in keys:
            _COMMANDS[key] = handler
        return handler

    return register


@dataclass
class _SurfaceData:
    number: int
    line: int
    value: float  # radius or curvature as written
    thickness: float
    glass: str | None
    is_stop: bool = False
    conic: float = 0.0
    asphere: dict[int, float] = field(default_factory=dict)
    clear_radius: float | None = None
    pim: bool = False
    odd: bool = False  # SPS ODD: SCO coefficients allowed


def _split_commands(text: str) -> list[tuple[int, list[str]]]:
    """(line number, tokens) for every command; ';' separates commands, '!' starts a
    comment (both only outside quotes)."""
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        parts, buf, quote = [], [], None
        for ch in line:
            if quote:
                buf.append(ch)
                if ch == quote:
                    quote = None
            elif ch in "'\"":
                quote = ch
                buf.append(ch)
            elif ch == ";":
                parts.append("".join(buf))
                buf = []
            elif ch == "!":
                break
            else:
                buf.append(ch)
        parts.append("".join(buf))
        for part in parts:
            tokens = _TOKEN.findall(part)
            if tokens:
                out.append((lineno, tokens))
    return out


class _Reader:
    def __init__(self, path: Path):
        self.src = str(path)
        self.notes: list[str] = []
        self.radius_mode = True
        self.title = ""
        self.aperture: tuple[str, float] | None = None
        self.wavelengths_nm: list[float] = []
        self.weights: list[float] | None = None
        self.ref: int | None = None
        self.field_type: str | None = None
        self.fields: list[float] | None = None
        self.x_fields: list[float] = []
        self.vignetting: dict[str, list[float]] = {}
        self.object: tuple[int, float, float, str | None] | None = None
        self.surfaces: list[_SurfaceData] = []
        self.image: tuple[int, float, float] | None = None
        self.done = False

    # ---- helpers -----------------------------------------------------------------
    def err(self, lineno: int, what: str, msg: str) -> InputError:
        return InputError(self.src, f"line {lineno} ({what})", msg)

    def num(self, lineno: int, what: str, token: str) -> float:
        try:
            x = float(token)
        except ValueError:
            raise self.err(lineno, what, f"expected a number, got {token!r}") from None
        if not math.isfinite(x):
            raise self.err(lineno, what, f"expected a finite number, got {token!r}")
        return x

    def nums(self, lineno: int, cmd: str, args: list[str], min_count: int = 1) -> list[float]:
        if len(args) < min_count:
            raise self.err(lineno, cmd, f"expected at least {min_count} number(s), got {len(args)}")
        return [self.num(lineno, cmd, a) for a in args]

    def current(self, lineno: int, cmd: str) -> _SurfaceData:
        if not self.surfaces:
            raise self.err(lineno, cmd, "expected after an S surface line")
        return self.surfaces[-1]

    # ---- commands ----------------------------------------------------------------
    def command(self, lineno: int, tokens: list[str]) -> None:
        """Read one command: its keyword's handler in ``_COMMANDS`` does the work."""
        cmd, args = tokens[0].upper(), tokens[1:]
        if self.done:
            raise self.err(lineno, cmd, "expected nothing after GO")
        if cmd in _IGNORED:
            return
        handler = _COMMANDS.get(cmd)
        if handler is None:
            raise self.err(lineno, cmd, f"unsupported CODE V command {tokens[0]!r}")
        handler(self, lineno, cmd, args)

    @_command("GO")
    def _go(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.done = True

    @_command("RDM")
    def _radius_mode(self, lineno: int, cmd: str, args: list[str]) -> None:
        flag = args[0].upper() if args else "Y"
        if flag not in ("Y", "N", "YES", "NO"):
            raise self.err(lineno, cmd, f"expected Y or N, got {args[0]!r}")
        self.radius_mode = flag.startswith("Y")

    @_command("LEN")
    def _lens(self, lineno: int, cmd: str, args: list[str]) -> None:
        if self.surfaces or self.object:
            raise self.err(lineno, cmd, "expected one lens per file (LEN after surfaces)")
        if args:
            self.title = self.title or args[0].strip("'\"")

    @_command("TITLE")
    def _title(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.title = " ".join(a.strip("'\"") for a in args).strip()

    @_command("DIM")
    def _dimension(self, lineno: int, cmd: str, args: list[str]) -> None:
        unit = args[0].upper() if args else ""
        if unit != "M":
            raise self.err(
                lineno,
                cmd,
                f"expected DIM M (millimetres), got {' '.join(args) or 'nothing'}; convert the lens to millimetres",
            )

    @_command("EPD", "FNO")
    def _aperture(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.aperture = (cmd.lower(), self.nums(lineno, cmd, args)[0])

    @_command("NAO", "NA")
    def _numerical_aperture(self, lineno: int, cmd: str, args: list[str]) -> None:
        raise self.err(lineno, cmd, "numerical-aperture system apertures are not supported; expected EPD or FNO")

    @_command("WL")
    def _wavelengths(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.wavelengths_nm = self.nums(lineno, cmd, args)

    @_command("REF")
    def _reference(self, lineno: int, cmd: str, args: list[str]) -> None:
        ref = self.nums(lineno, cmd, args)[0]
        if ref != int(ref):
            raise self.err(lineno, cmd, f"expected a whole wavelength number, got {args[0]}")
        self.ref = int(ref)

    @_command("WTW")
    def _weights(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.weights = self.nums(lineno, cmd, args)

    @_command(*_FIELD_KEYS)
    def _fields(self, lineno: int, cmd: str, args: list[str]) -> None:
        if self.field_type is not None and self.field_type != _FIELD_KEYS[cmd]:
            raise self.err(lineno, cmd, f"expected one field type, got both {self.field_type} and {_FIELD_KEYS[cmd]}")
        self.field_type = _FIELD_KEYS[cmd]
        self.fields = self.nums(lineno, cmd, args)

    @_command(*_X_FIELD_KEYS)
    def _x_fields(self, lineno: int, cmd: str, args: list[str]) -> None:
        xs = self.nums(lineno, cmd, args)
        if any(x != 0.0 for x in xs):
            raise self.err(
                lineno,
                cmd,
                "expected zero x fields: lensim models rotationally symmetric lenses "
                "with fields along y (give the radial field as Y values)",
            )
        self.x_fields = xs

    @_command("VUX", "VLX", "VUY", "VLY")
    def _vignetting(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.vignetting[cmd] = self.nums(lineno, cmd, args)

    @_command("SO")
    def _object_surface(self, lineno: int, cmd: str, args: list[str]) -> None:
        if self.object is not None or self.surfaces:
            raise self.err(lineno, cmd, "expected one SO line before the surfaces")
        vals = self.nums(lineno, cmd, args[:2], 2)
        glass = args[2] if len(args) > 2 else None
        self.object = (lineno, vals[0], vals[1], glass)

    @_command("S")
    def _surface(self, lineno: int, cmd: str, args: list[str]) -> None:
        if self.object is None:
            raise self.err(lineno, cmd, "expected the object surface (SO) first")
        if self.image is not None:
            raise self.err(lineno, cmd, "expected no surface after the image surface (SI)")
        n = len(self.surfaces) + 1
        vals = self.nums(lineno, f"S {n}", args[:2], 2)
        if len(args) > 3:
            raise self.err(lineno, f"S {n}", f"expected 'S curvature thickness [glass]', got {' '.join(args)}")
        self.surfaces.append(_SurfaceData(n, lineno, vals[0], vals[1], args[2] if len(args) > 2 else None))

    @_command("SI")
    def _image_surface(self, lineno: int, cmd: str, args: list[str]) -> None:
        if not self.surfaces:
            raise self.err(lineno, cmd, "expected surfaces (S) before the image surface")
        vals = self.nums(lineno, cmd, args[:2], 1)
        self.image = (lineno, vals[0], vals[1] if len(vals) > 1 else 0.0)

    @_command("STO")
    def _stop(self, lineno: int, cmd: str, args: list[str]) -> None:
        s = self.current(lineno, cmd)
        if self.image is not None:
            raise self.err(lineno, cmd, "expected the stop on a lens surface, not the image")
        if any(t.is_stop for t in self.surfaces):
            raise self.err(lineno, cmd, "expected one stop, found a second STO")
        s.is_stop = True

    @_command("PIM")
    def _paraxial_image(self, lineno: int, cmd: str, args: list[str]) -> None:
        if self.image is not None:
            raise self.err(lineno, cmd, "expected PIM on the last lens surface, not after SI")
        self.current(lineno, cmd).pim = True

    @_command("K")
    def _conic(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.current(lineno, cmd).conic = self.nums(lineno, cmd, args)[0]

    @_command("ASP")
    def _asphere(self, lineno: int, cmd: str, args: list[str]) -> None:
        self.current(lineno, cmd)

    @_command(*_ASPHERE_LETTERS)
    def _asphere_coefficient(self, lineno: int, cmd: str, args: list[str]) -> None:
        s = self.current(lineno, cmd)
        s.asphere[_ASPHERE_LETTERS[cmd]] = self.nums(lineno, f"S {s.number} {cmd}", args)[0]

    @_command("CIR")
    def _clear_radius(self, lineno: int, cmd: str, args: list[str]) -> None:
        s = self.current(lineno, cmd)
        r = self.nums(lineno, f"S {s.number} CIR", args)[0]
        if r <= 0:
            raise self.err(lineno, f"S {s.number} CIR", f"expected a positive clear semi-diameter, got {r}")
        s.clear_radius = r

    @_command("SPS")
    def special_surface(self, lineno: int, cmd: str, args: list[str]) -> None:
        """SPS ODD [NRADIUS]: an odd polynomial asphere (CODE V's ODD special surface)."""
        s = self.current(lineno, "SPS")
        kind = args[0].upper() if args else ""
        if kind != "ODD":
            raise self.err(
                lineno,
                f"S {s.number} SPS",
                f"unsupported special surface {kind or 'nothing'}; lensim reads SPS ODD (odd polynomial asphere) only",
            )
        if len(args) > 1 and self.num(lineno, f"S {s.number} SPS ODD", args[1]) not in (0.0, 1.0):
            raise self.err(
                lineno,
                f"S {s.number} SPS ODD",
                f"normalization radius {args[1]} is not supported; expected 0 or 1 (coefficients of r in mm)",
            )
        s.odd = True

    @_command("SCO")
    def special_coefficient(self, lineno: int, cmd: str, args: list[str]) -> None:
        """SCO K k | SCO ARn v | SCO Cn v of an SPS ODD surface (C1 = K, C(n+1) = ARn)."""
        s = self.current(lineno, "SCO")
        what = f"S {s.number} SCO"
        if not s.odd:
            raise self.err(lineno, what, "expected SPS ODD before its SCO coefficients")
        if len(args) != 2:
            raise self.err(lineno, what, f"expected 'SCO name value', got {' '.join(args) or 'nothing'}")
        name, value = args[0].upper(), self.num(lineno, what, args[1])
        m = re.fullmatch(r"(AR|C)(\d+)", name)
        power = None if m is None else int(m.group(2)) - (1 if m.group(1) == "C" else 0)
        if name == "K" or power == 0:
            s.conic = value
        elif power is not None and value == 0.0:
            s.asphere.pop(power, None)  # CODE V writes unused terms as zero
        elif power is not None and 1 <= power <= MAX_ASPHERE_POWER:
            s.asphere[power] = value
        else:
            raise self.err(
                lineno,
                what,
                f"unsupported coefficient {args[0]}; expected K, AR1..AR{MAX_ASPHERE_POWER} "
                f"or C1..C{MAX_ASPHERE_POWER + 1}",
            )

    # ---- building ----------------------------------------------------------------
    def curvature(self, value: float) -> float:
        """Curvature (1/mm) from a number written as a radius (RDM Y) or curvature (RDM N)."""
        if not self.radius_mode:
            return value
        if value == 0.0:
            return 0.0  # CODE V writes a plane as radius 0
        return 1.0 / value

    def material(self, lineno: int, what: str, token: str, notes: list[str]) -> Material:
        name = token.strip("'\"")
        catalogs: list[str] | None = None
        if "_" in name:
            base, suffix = name.rsplit("_", 1)
            if suffix.upper() in _CATALOG_SUFFIX:
                name, catalogs = base, [_CATALOG_SUFFIX[suffix.upper()]]
            elif suffix.upper() != "MOLD":
                notes.append(
                    f"glass catalogue {suffix} of {token} is not available in lensim; searching every catalogue"
                )
                name = base
        try:
            glass, note = resolve_glass(name, catalogs)
        except UnknownGlassError as e:
            raise self.err(lineno, what, e.message) from None
        if note:
            notes.append(note)
        return glass

    def required(self) -> tuple[tuple[int, float, float, str | None], tuple[int, float, float], tuple[str, float]]:
        """(object, image, aperture): what every lens needs, checked present in this order."""
        if self.object is None:
            raise InputError(self.src, "SO", "missing the object surface (SO curvature thickness)")
        if not self.surfaces:
            raise InputError(self.src, "S", "expected at least one lens surface (S)")
        if self.image is None:
            raise InputError(self.src, "SI", "missing the image surface (SI)")
        if self.aperture is None:
            raise InputError(self.src, "EPD", "missing the system aperture; expected EPD (mm) or FNO")
        if not self.wavelengths_nm:
            raise InputError(self.src, "WL", "missing the wavelengths (WL, nm)")
        if not any(s.is_stop for s in self.surfaces):
            raise InputError(self.src, "STO", "missing the aperture stop (STO after one of the S lines)")
        return self.object, self.image, self.aperture

    def wavelength_data(self) -> tuple[list[float], int]:
        """(weights, 1-based reference wavelength): WTW and REF, or their defaults."""
        w = len(self.wavelengths_nm)
        weights = self.weights if self.weights is not None else [1.0] * w
        if len(weights) != w:
            raise InputError(self.src, "WTW", f"expected {w} weights (one per WL), got {len(weights)}")
        ref = self.ref if self.ref is not None else (w + 1) // 2
        if not 1 <= ref <= w:
            raise InputError(self.src, "REF", f"expected a wavelength number 1..{w}, got {ref}")
        return weights, ref

    def note_vignetting(self) -> None:
        """A note naming the non-zero vignetting factors, which are not applied."""
        vig = [
            f"{key} {' '.join(f'{v:g}' for v in vals)}"
            for key, vals in self.vignetting.items()
            if any(v != 0.0 for v in vals)
        ]
        if vig:
            self.notes.append(
                f"vignetting factors ({'; '.join(vig)}) are not applied; "
                "lensim vignettes rays with the real surface apertures"
            )

    def object_space(self, obj: tuple[int, float, float, str | None]) -> tuple[float, Material]:
        """(object distance in mm or math.inf, object-space material) from the SO line."""
        lineno, obj_c, obj_t, obj_glass = obj
        object_distance = math.inf if abs(obj_t) >= INFINITE_THICKNESS_MM else obj_t
        if not (object_distance > 0):
            raise self.err(lineno, "SO thickness", f"expected a positive object distance, got {obj_t}")
        if math.isfinite(object_distance) and self.curvature(obj_c) != 0.0:
            raise self.err(lineno, "SO curvature", "expected a flat object surface")
        if obj_glass is None:
            return object_distance, Air()
        return object_distance, self.material(lineno, "SO glass", obj_glass, self.notes)

    def lens_surfaces(self, object_material: Material) -> list[Surface]:
        """The S lines as Surfaces (a REFL mirror keeps the medium it reflects in)."""
        surfaces: list[Surface] = []
        medium = object_material
        for sd in self.surfaces:
            mirror = sd.glass is not None and sd.glass.upper() == "REFL"
            if mirror:
                material = medium
            elif sd.glass is None:
                material = Air()
            else:
                material = self.material(sd.line, f"S {sd.number} glass", sd.glass, self.notes)
            medium = material
            surfaces.append(
                Surface(
                    curvature=self.curvature(sd.value),
                    thickness=sd.thickness,
                    material=material,
                    conic=sd.conic,
                    asphere=dict(sd.asphere),
                    clear_radius=sd.clear_radius,
                    is_stop=sd.is_stop,
                    is_mirror=mirror,
                )
            )
        return surfaces

    def solve_pim(self, lens: Lens) -> None:
        """PIM: set the last thickness to the paraxial focus (on the last surface only)."""
        pim = [s for s in self.surfaces if s.pim]
        if not pim:
            return
        if pim[-1] is not self.surfaces[-1]:
            raise self.err(pim[-1].line, f"S {pim[-1].number} PIM", "expected PIM on the last surface before SI")
        try:
            lens.surfaces[-1].thickness = paraxial_focus_thickness(lens)
        except InputError as e:
            raise InputError(lens.source, "PIM", f"{e.message}; remove the PIM solve") from None

    def build(self) -> Lens:
        """The Lens the commands describe; InputError naming the command for what is missing or wrong."""
        obj, (img_line, img_c, img_t), aperture = self.required()
        weights, ref = self.wavelength_data()
        self.note_vignetting()
        object_distance, object_material = self.object_space(obj)
        surfaces = self.lens_surfaces(object_material)
        if self.curvature(img_c) != 0.0:
            raise self.err(img_line, "SI curvature", "expected a flat image surface")
        lens = Lens(
            surfaces=surfaces,
            aperture_type=aperture[0],
            aperture_value=aperture[1],
            field_type=self.field_type or "angle",
            fields=self.fields if self.fields is not None else [0.0],
            wavelengths_um=[v / 1000.0 for v in self.wavelengths_nm],
            wavelength_weights=weights,
            primary=ref - 1,
            object_distance=object_distance,
            object_material=object_material,
            image_defocus=img_t,
            name=self.title or Path(self.src).stem,
            source=self.src,
            notes=self.notes,
        )
        self.solve_pim(lens)
        return lens


def read_seq(path: str | Path) -> Lens:
    """Read a CODE V .seq file into a Lens (see the module docstring for the subset)."""
    path = Path(path)
    text = decode_text(read_bytes(path, "CODE V lens file"), str(path))
    reader = _Reader(path)
    for lineno, tokens in _split_commands(text):
        reader.command(lineno, tokens)
    return reader.build()
