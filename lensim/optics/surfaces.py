"""One surface of a prescription: its shape parameters, the medium after it, its apertures.

The shape is curvature, conic and `asphere` ({power: coefficient}, powers 1..20; any odd
power makes an odd asphere, as Zemax ODDASPHE PARM 1..8 = b1..b8 and CODE V SPS ODD do).
What the shape is (sag, normal, ray intersection, and their formulas) lives in
lensim.optics.geometry: ``Surface.geometry`` is the Plane, Sphere, Conic, EvenAsphere or
OddAsphere those parameters make. Lengths in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from lensim.optics.geometry import MAX_ASPHERE_POWER, Geometry, make_geometry
from lensim.optics.materials import Air, Material
from lensim.optics.pose import NO_POSE, Pose

__all__ = ["MAX_ASPHERE_POWER", "Surface"]


@dataclass
class Surface:
    """One surface and the medium after it.

    curvature: 1/R (1/mm), 0 for a plane. thickness: signed distance (mm) to the next
    surface vertex (negative after a mirror, as in Zemax; in air also to place a stop or
    dummy surface behind the next vertex, see Lens.virtual_steps). asphere: {power: coefficient}
    with powers 1..20 (coefficients in mm^(1-power)); even powers only: an even asphere,
    any odd power: an odd asphere. clear_radius: semi-diameter of
    the clear aperture that vignettes rays (None: unlimited). obscuration_radius: central
    obscuration (rays with r below it are blocked). semi_diameter: drawn size only.
    pose: (decentre x, decentre y mm, tilt x, tilt y deg) of an as-built or toleranced
    surface (lensim.optics.pose); the nominal (0, 0, 0, 0) keeps the lens symmetric.
    """

    curvature: float = 0.0
    thickness: float = 0.0
    material: Material = field(default_factory=Air)
    conic: float = 0.0
    asphere: dict[int, float] = field(default_factory=dict)
    clear_radius: float | None = None
    obscuration_radius: float | None = None
    semi_diameter: float | None = None
    is_stop: bool = False
    is_mirror: bool = False
    comment: str = ""
    pose: Pose = NO_POSE

    @property
    def has_pose(self) -> bool:
        """True when the surface is decentred or tilted (lensim.optics.pose), or its pose is
        a tensor that requires grad (a calibration's start at zero)."""
        return any(v != 0.0 or getattr(v, "requires_grad", False) for v in self.pose)

    @property
    def radius(self) -> float:
        return math.inf if self.curvature == 0 else 1.0 / self.curvature

    @property
    def is_aspheric(self) -> bool:
        return any(v != 0.0 for v in self.asphere.values())

    @property
    def kind(self) -> str:
        """'plane', 'sphere', 'conic', 'even asphere' or 'odd asphere' (any odd power)."""
        return self.geometry.kind

    @property
    def requires_grad(self) -> bool:
        """Whether curvature, thickness, conic, an aspheric coefficient or a decentre is a
        tensor that requires grad (the tracer then runs its reference path, which autograd
        follows; tilts enter through math and take no gradient)."""
        values = (self.curvature, self.thickness, self.conic, *self.asphere.values(), *self.pose[:2])
        return any(getattr(v, "requires_grad", False) for v in values)

    @property
    def geometry(self) -> Geometry:
        """The surface's shape (a Plane, Sphere, Conic, EvenAsphere or OddAsphere, from
        curvature, conic and asphere): its sag, normal and ray intersection."""
        return make_geometry(self.curvature, self.conic, self.asphere)

    def passes_aperture(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """True where a ray at (x, y) on this surface is inside the clear aperture and
        outside the central obscuration."""
        r2 = x * x + y * y
        ok = torch.ones_like(r2, dtype=torch.bool)
        if self.clear_radius is not None:
            ok = ok & (r2 <= self.clear_radius**2 * (1 + 1e-12))
        if self.obscuration_radius is not None:
            ok = ok & (r2 >= self.obscuration_radius**2)
        return ok
