"""From what the keywords of a Zemax file say to a Lens (lensim.optics.zemax reads the
file with one handler per keyword, into a ZemaxData).

ZemaxData.build checks and converts: the object, image and stop surfaces, each surface's
glass (MIRROR makes a mirror; ___BLANK a model glass from the GLAS line's nd, Vd and dPgF,
Vd 0: constant index; other names are looked up in the file's GCAT catalogues, then in
every catalogue, then by glass family, notes recording substitutions; a name found nowhere
falls back to the line's nd/Vd as a model glass, with a note, when the line carries real
values, otherwise it is an error listing close names), the aspheric coefficients, the
apertures (CLAP, FLAP, OBSC), the system aperture, fields, wavelengths and the
multi-configuration thicknesses. Lengths in mm, wavelengths in um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from lensim.errors import InputError, UnknownGlassError
from lensim.optics.lens import Lens
from lensim.optics.materials import Air, ConstantIndex, Material, ModelGlass, resolve_glass
from lensim.optics.surfaces import Surface

# PARM k's power: EVENASPH r^(2k), ODDASPHE (Zemax's "Odd Asphere") r^k
_PARM_POWER = {"EVENASPH": 2, "ODDASPHE": 1}
FIELD_TYPES = {0: "angle", 1: "object_height", 2: "paraxial_image_height", 3: "real_image_height"}
# Zemax's default nd/Vd on a catalogue glass's GLAS line: no real model data.
PLACEHOLDER_ND_VD = (1.5, 40.0)


@dataclass
class ZemaxSurface:
    """What the keywords of one SURF block say (Zemax surface ``number``; 0: the object)."""

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


class ZemaxData:
    """What the keywords of a Zemax file say, and the Lens they describe (build)."""

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
        self.surfs: list[ZemaxSurface] = []
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

    # ---- building ----------------------------------------------------------------
    def glass(self, s: ZemaxSurface, medium: Material) -> tuple[Material, bool]:
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

    def asphere(self, s: ZemaxSurface) -> dict[int, float]:
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

    def model(self, s: ZemaxSurface, nd: float, vd: float, dpgf: float, name: str | None = None) -> Material:
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

    def required_surfaces(self) -> ZemaxSurface:
        """The stop, after checking there are an object, a lens surface and an image, and
        that the first STOP is on a lens surface."""
        if len(self.surfs) < 3:
            raise InputError(
                self.src,
                "SURF",
                f"expected an object, at least one lens surface and an image surface, "
                f"found {len(self.surfs)} surface(s)",
            )
        stops = [s for s in self.surfs if s.stop]
        if not stops:
            raise InputError(self.src, "STOP", "missing the aperture stop: no surface has a STOP line")
        if stops[0] in (self.surfs[0], self.surfs[-1]):
            raise InputError(
                self.src, f"SURF {stops[0].number} STOP", "expected the stop on a lens surface, not the object or image"
            )
        return stops[0]

    def object_space(self) -> tuple[float, Material]:
        """(object distance in mm or math.inf, object-space material) from SURF 0; the image
        surface is checked flat too."""
        obj, img = self.surfs[0], self.surfs[-1]
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
        return object_distance, object_material

    def lens_surfaces(self, object_material: Material) -> list[Surface]:
        """The surfaces between the object and the image as Surfaces."""
        surfaces: list[Surface] = []
        medium = object_material
        for s in self.surfs[1:-1]:
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
        return surfaces

    def build(self) -> Lens:
        """The Lens the file describes; InputError naming the keyword for what is missing or wrong."""
        stop = self.required_surfaces()
        object_distance, object_material = self.object_space()
        surfaces = self.lens_surfaces(object_material)
        image_clear, _ = self.apertures(self.surfs[-1])
        aperture_type, aperture_value = self.system_aperture(stop, object_distance)
        field_type, fields = self.fields()
        wls, weights, primary = self.wavelengths()
        configurations = self.configurations(len(surfaces))
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

    def apertures(self, s: ZemaxSurface) -> tuple[float | None, float | None]:
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

    def system_aperture(self, stop: ZemaxSurface, object_distance: float) -> tuple[str, float]:
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
