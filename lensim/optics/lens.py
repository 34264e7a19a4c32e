"""The lens prescription: a sequential, rotationally symmetric optical system.

Global frame: z along the optical axis, light leaves the object towards +z, the first
surface vertex is at z = 0. Lengths in mm, wavelengths in um, field angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from lensim.errors import InputError
from lensim.optics.materials import Air, Material
from lensim.optics.surfaces import MAX_ASPHERE_POWER, Surface

ApertureType = Literal["epd", "fno", "stop_semi_diameter"]
FieldType = Literal["angle", "object_height", "paraxial_image_height", "real_image_height"]
APERTURE_TYPES = ("epd", "fno", "stop_semi_diameter")
FIELD_TYPES = ("angle", "object_height", "paraxial_image_height", "real_image_height")
#: the largest gap between two surfaces (mm): 1 km, far beyond any lens or telescope; a
#: larger thickness is a typo (1e9 for 1e1) that would otherwise show as a failed ray
MAX_THICKNESS_MM = 1e6


@dataclass
class Lens:
    """A lens prescription.

    surfaces: every surface from the first optical surface to the last one before the
    image plane; the last surface's thickness is its distance to the image plane.
    object_distance: mm from the object to the first surface vertex (math.inf for an
    object at infinity). image_defocus: mm added to the last thickness (a focus shift).
    aperture_value: entrance-pupil diameter (mm), image-space F-number (EFL / EPD), or
    stop semi-diameter (mm), as aperture_type says. fields: field points along +y in the
    unit of field_type (degrees or mm). wavelengths_um with weights; primary indexes them.
    configurations: zoom or focus positions, an ordered mapping of name -> {0-based surface
    index: thickness (mm)} (lensim.optics.configurations; apply_configuration picks one).
    focus_thickness: the 0-based index of the surface whose thickness (an air gap) focusing
    changes (a focus group), or None for unit focusing (the image plane moves);
    focus_compensator: another air gap that changes by the opposite amount, so the group
    moves between the two (None: only focus_thickness changes). lensim.optics.shooting.
    image_tilt: the sensor's tilt (deg) about x and y at the image point on the axis
    (lensim.optics.pose; surfaces carry their own decentre and tilt in Surface.pose).
    as_built: the record of a toleranced draw or a calibration (parameters, values and
    uncertainties; lensim.calibrate), kept with the lens file.
    """

    surfaces: list[Surface]
    aperture_type: str = "epd"
    aperture_value: float = 10.0
    field_type: str = "angle"
    fields: list[float] = field(default_factory=lambda: [0.0])
    wavelengths_um: list[float] = field(default_factory=lambda: [0.5875618])
    wavelength_weights: list[float] | None = None
    primary: int = 0
    object_distance: float = math.inf
    object_material: Material = field(default_factory=Air)
    image_defocus: float = 0.0
    image_clear_radius: float | None = None
    name: str = ""
    source: str = "<lens>"
    notes: list[str] = field(default_factory=list)
    configurations: dict[str, dict[int, float]] = field(default_factory=dict)
    focus_thickness: int | None = None
    focus_compensator: int | None = None
    image_tilt: tuple[float, float] = (0.0, 0.0)
    as_built: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.wavelength_weights is None:
            self.wavelength_weights = [1.0] * len(self.wavelengths_um)
        self.validate()

    # ---- validation -------------------------------------------------------------
    def _err(self, fld: str, msg: str) -> InputError:
        return InputError(self.source, fld, msg)

    def validate(self) -> None:
        """Check the prescription; raise InputError naming the offending field."""
        if not self.surfaces:
            raise self._err("surfaces", "expected at least one surface")
        self._check_aperture_and_fields()
        self._check_wavelengths()
        if not (self.object_distance > 0):
            raise self._err(
                "object.distance", f"expected a positive distance (mm) or infinity, got {self.object_distance}"
            )
        stops = [i for i, s in enumerate(self.surfaces) if s.is_stop]
        if len(stops) != 1:
            found = f"{len(stops)} (surfaces {', '.join(f'[{i}]' for i in stops)})" if stops else "0"
            raise self._err("surfaces", f"expected exactly one stop surface, found {found}")
        media, dirs = self.media(), self.directions()
        for i, s in enumerate(self.surfaces):
            self._check_surface(i, s, media[i + 1], dirs[i + 1])
        self._check_air_gaps(media, dirs)
        self._check_focus(media)
        if self.configurations:
            from lensim.optics.configurations import check_configurations

            check_configurations(self)

    def _check_aperture_and_fields(self) -> None:
        """aperture.type/value and fields.type/values."""
        if self.aperture_type not in APERTURE_TYPES:
            raise self._err("aperture.type", f"expected one of {', '.join(APERTURE_TYPES)}, got {self.aperture_type!r}")
        if not (self.aperture_value > 0 and math.isfinite(self.aperture_value)):
            raise self._err("aperture.value", f"expected a positive number, got {self.aperture_value}")
        if self.field_type not in FIELD_TYPES:
            raise self._err("fields.type", f"expected one of {', '.join(FIELD_TYPES)}, got {self.field_type!r}")
        if self.field_type == "object_height" and self.infinite_object:
            raise self._err(
                "fields.type", "object_height fields need a finite object distance; use angle for an object at infinity"
            )
        if not self.fields:
            raise self._err("fields.values", "expected at least one field")
        if any(not math.isfinite(f) for f in self.fields):
            raise self._err("fields.values", "expected finite numbers")
        if self.field_type == "angle" and any(abs(f) >= 90 for f in self.fields):
            raise self._err("fields.values", "field angles must be below 90 degrees")

    def _check_wavelengths(self) -> None:
        """wavelengths: 200..15000 nm, one non-negative weight each, the primary's index."""
        if not self.wavelengths_um:
            raise self._err("wavelengths", "expected at least one wavelength")
        for i, w in enumerate(self.wavelengths_um):
            if not (0.2 <= w <= 15.0):
                raise self._err(
                    f"wavelengths.nm[{i}]", f"expected a wavelength between 200 and 15000 nm, got {w * 1000:g} nm"
                )
        weights = self.wavelength_weights
        if weights is None or len(weights) != len(self.wavelengths_um) or any(w < 0 for w in weights):
            raise self._err("wavelengths.weights", "expected one non-negative weight per wavelength")
        if not (0 <= self.primary < len(self.wavelengths_um)):
            raise self._err(
                "wavelengths.primary", f"expected an index 0..{len(self.wavelengths_um) - 1}, got {self.primary}"
            )

    def _check_surface(self, i: int, s: Surface, medium: Material, direction: float) -> None:
        """surfaces[i]: finite numbers, a thickness that light can travel inside glass,
        apertures and aspheric powers in range. medium, direction: after the surface."""
        if not math.isfinite(s.thickness):
            raise self._err(f"surfaces[{i}].thickness", f"expected a finite number, got {s.thickness}")
        if abs(s.thickness) > MAX_THICKNESS_MM:
            raise self._err(
                f"surfaces[{i}].thickness",
                f"expected at most {MAX_THICKNESS_MM:g} mm (1 km) between two surfaces, got {s.thickness:g} mm",
            )
        if not math.isfinite(s.curvature) or not math.isfinite(s.conic):
            raise self._err(f"surfaces[{i}]", "expected finite curvature and conic")
        if not isinstance(medium, Air) and s.thickness * direction < 0:
            expected = "positive" if direction > 0 else "negative (light travels towards -z after a mirror)"
            raise self._err(
                f"surfaces[{i}].thickness",
                f"expected a {expected} thickness inside {medium.name}, got {s.thickness:g}: a ray "
                f"cannot travel backwards inside glass (negative thicknesses are allowed in air only)",
            )
        if s.thickness == 0 and not s.is_mirror and not isinstance(s.material, Air) and i < len(self.surfaces) - 1:
            raise self._err(
                f"surfaces[{i}].thickness", f"expected a non-zero thickness inside {s.material.name}, got 0"
            )
        if s.clear_radius is not None and s.clear_radius <= 0:
            raise self._err(f"surfaces[{i}].clear_semi_diameter", f"expected a positive number, got {s.clear_radius}")
        limit = s.clear_radius if s.clear_radius is not None else math.inf
        if s.obscuration_radius is not None and not (0 <= s.obscuration_radius < limit):
            within = "" if s.clear_radius is None else f" below the clear semi-diameter {s.clear_radius:g}"
            raise self._err(
                f"surfaces[{i}].obscuration",
                f"expected a central obscuration radius >= 0 mm{within}, got {s.obscuration_radius:g}",
            )
        for p in s.asphere:
            if not (1 <= p <= MAX_ASPHERE_POWER):
                raise self._err(f"surfaces[{i}].asphere", f"expected powers r1..r{MAX_ASPHERE_POWER}, got r{p}")

    def _check_focus(self, media: list[Material]) -> None:
        """The focus group's gaps: surface indices in range, in air, distinct; a compensator
        only with a focus thickness."""
        n = len(self.surfaces)
        if self.focus_thickness is None:
            if self.focus_compensator is not None:
                raise self._err("focus.compensator", "expected focus.thickness too (the gap the focus group moves in)")
            return
        for key, index in (("thickness", self.focus_thickness), ("compensator", self.focus_compensator)):
            if index is None:
                continue
            if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < n:
                raise self._err(
                    f"focus.{key}", f"expected a surface index 0..{n - 1} (0-based, as in surfaces[i]), got {index!r}"
                )
            if not isinstance(media[index + 1], Air):
                raise self._err(
                    f"focus.{key}", f"expected an air gap, but surfaces[{index}] is followed by {media[index + 1].name}"
                )
        if self.focus_compensator == self.focus_thickness:
            raise self._err("focus.compensator", f"expected another gap than focus.thickness ({self.focus_thickness})")

    def is_dummy(self, i: int, media: list[Material] | None = None) -> bool:
        """Surface i bends no ray: air on both sides and not a mirror (a stop in air, a
        dummy surface); propagation to or from it may be virtual. media: self.media()."""
        media = self.media() if media is None else media
        return not self.surfaces[i].is_mirror and isinstance(media[i], Air) and isinstance(media[i + 1], Air)

    def _check_air_gaps(self, media: list[Material], dirs: np.ndarray) -> None:
        """A negative thickness in air may place a stop or dummy surface (the rays reach it
        virtually, as in Zemax), but the air between two surfaces that bend rays, or between
        one and the object or the image plane, must not add up to less than zero along the
        axis: those would overlap, and a real ray would have to travel backwards."""

        def name(k: int | None) -> str:
            return "the object" if k is None else ("the image plane" if k > last else f"surfaces[{k}]")

        last = len(self.surfaces) - 1
        # the open run of air: where it started (None: the object), the axial air
        # thickness since then (None: not checked) and its gaps
        start: int | None = None
        net = self.object_distance if (not self.infinite_object and isinstance(self.object_material, Air)) else None
        gaps: list[int] = []
        for i in range(len(self.surfaces) + 1):
            if i > last or not self.is_dummy(i, media):
                if net is not None and net < 0:
                    neg = next(k for k in gaps if self.surfaces[k].thickness * dirs[k + 1] < 0)  # the first one back
                    t = self.surfaces[neg].thickness
                    why = "only a stop or dummy surface may (placed by a negative thickness in air, as in Zemax)"
                    if len(gaps) == 1 and start == neg:
                        expected = (
                            "a positive thickness"
                            if dirs[neg + 1] > 0
                            else "a negative thickness (light travels towards -z after a mirror)"
                        )
                        raise self._err(
                            f"surfaces[{neg}].thickness",
                            f"expected {expected}, got {t:g}: {name(i)} would lie behind {name(start)} "
                            f"along the light's path, which {why}",
                        )
                    raise self._err(
                        f"surfaces[{neg}].thickness",
                        f"expected the air from {name(start)} to {name(i)} to add up to >= 0 mm along "
                        f"the light's path, got {net:g} mm with this thickness {t:g}: {name(i)} would lie "
                        f"behind {name(start)}, which {why}",
                    )
                if i > last:
                    break
                start, gaps = i, []
                net = 0.0 if isinstance(media[i + 1], Air) else None
            if net is not None:
                net += self.surfaces[i].thickness * dirs[i + 1]
                gaps.append(i)

    def virtual_steps(self) -> np.ndarray:
        """Where propagation may run backwards along the ray (length N+1: the step onto
        surface k, then onto the image plane, index N).

        Sequential tracing, as in Zemax: across a zero or negative thickness in air next to
        a surface that bends no ray (a stop or dummy surface placed behind the next vertex,
        say) the next surface is intersected whatever the sign of the distance. Everywhere
        else (inside glass, across a positive air gap, between two lens surfaces) a ray that
        would have to travel backwards misses the surface. Step 0 is False here: where rays
        start is the tracer's business (it always lets the first step run backwards).
        """
        media, dirs, zv = self.media(), self.directions(), self.vertex_z()
        n = len(self.surfaces)
        out = np.zeros(n + 1, dtype=bool)
        for k in range(1, n + 1):
            if not isinstance(media[k], Air) or (zv[k] - zv[k - 1]) * dirs[k] > 0:
                continue
            out[k] = self.is_dummy(k - 1, media) or (k < n and self.is_dummy(k, media))
        return out

    # ---- geometry ---------------------------------------------------------------
    @property
    def infinite_object(self) -> bool:
        return math.isinf(self.object_distance)

    @property
    def has_poses(self) -> bool:
        """True when a surface or the image plane is decentred or tilted: the lens is no
        longer rotationally symmetric (fields still lie along +y)."""
        return any(s.has_pose for s in self.surfaces) or any(v != 0.0 for v in self.image_tilt)

    @property
    def stop_index(self) -> int:
        return next(i for i, s in enumerate(self.surfaces) if s.is_stop)

    @property
    def num_surfaces(self) -> int:
        return len(self.surfaces)

    def vertex_z(self) -> np.ndarray:
        """z (mm) of every surface vertex, then of the image plane (length N+1)."""
        return np.asarray([float(z) for z in self.vertex_positions()])

    def vertex_positions(self) -> list:
        """vertex_z() as a list of numbers, each a tensor where a thickness (or the image
        defocus) before it is one: what the tracer differentiates."""
        z = [0.0]
        for s in self.surfaces[:-1]:
            z.append(z[-1] + s.thickness)
        z.append(z[-1] + self.surfaces[-1].thickness + self.image_defocus)
        return z

    @property
    def requires_grad(self) -> bool:
        """Whether a surface parameter or the image defocus is a tensor that requires grad."""
        return any(s.requires_grad for s in self.surfaces) or bool(getattr(self.image_defocus, "requires_grad", False))

    @property
    def meridional_mirror(self) -> bool:
        """Whether the rays of a field on the y axis are mirror images about the meridional
        plane x = 0, so that pupil grids may be traced at px >= 0 only and mirrored: no
        surface or sensor pose, and no gradient to follow (a pose at zero that requires grad
        need not keep the symmetry)."""
        return not (self.has_poses or self.requires_grad)

    def media(self) -> list[Material]:
        """Medium before surface 0, then after every surface (length N+1).
        A mirror keeps the medium it reflects in."""
        out = [self.object_material]
        for s in self.surfaces:
            out.append(out[-1] if s.is_mirror else s.material)
        return out

    def directions(self) -> np.ndarray:
        """+1 / -1: the z direction light travels in each medium (length N+1)."""
        d = [1.0]
        for s in self.surfaces:
            d.append(-d[-1] if s.is_mirror else d[-1])
        return np.asarray(d)

    def indices(self, wavelengths_um) -> np.ndarray:
        """Refractive index of every medium (N+1, W) at the given wavelengths (um)."""
        wl = np.atleast_1d(np.asarray(wavelengths_um, dtype=np.float64))
        return np.stack([m.index(wl) for m in self.media()])

    @property
    def primary_wavelength_um(self) -> float:
        return float(self.wavelengths_um[self.primary])

    @property
    def max_field(self) -> float:
        return float(max(abs(f) for f in self.fields))

    @property
    def total_track(self) -> float:
        """First vertex to image plane (mm)."""
        return float(self.vertex_z()[-1])

    @property
    def launch_field_type(self) -> str:
        """What rays are launched with: "angle" (deg) for an object at infinity or for angle
        fields, "object_height" (mm) for a finite object otherwise. Image-height fields are
        solved for a launch value of this type (lensim.optics.aiming.rays.object_field)."""
        return "angle" if self.infinite_object or self.field_type == "angle" else "object_height"

    def launch_lens(self) -> Lens:
        """This lens with field_type set to :attr:`launch_field_type`, so that launch values
        (from object_field) are read the right way by functions that take a field in the
        lens's unit (paraxial_image_height, chief_ray_image_height). The lens itself when
        its field type already is the launch type; otherwise a copy (surfaces shared) whose
        fields are [0] (the lens's fields are image heights in mm, not launch values, and
        an image height of 90 mm or more would fail as an angle)."""
        launch_type = self.launch_field_type
        if self.field_type == launch_type:
            return self
        return self.with_changes(field_type=launch_type, fields=[0.0])

    def with_changes(self, **changes) -> Lens:
        """A copy with some top-level attributes replaced (surfaces are shared)."""
        from dataclasses import replace

        return replace(self, **changes)
