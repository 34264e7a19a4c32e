"""Rotationally symmetric surfaces: sag, normals and ray intersection (float64 torch).

Even asphere (the paper's Eq. 2; Zemax EVENASPH):
    z(r) = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)) + A2 r^2 + A4 r^4 + ... + A20 r^20
Odd asphere (Zemax ODDASPHE, PARM 1..8 = b1..b8; CODE V SPS ODD, SCO AR1..):
    z(r) = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)) + b1 r + b2 r^2 + b3 r^3 + ... + b20 r^20
Both are one Surface whose `asphere` maps each power to its coefficient; any odd power
makes it an odd asphere (Surface.kind). Lengths in mm, all coordinates local to the
surface vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from lensim.optics.materials import Air, Material
from lensim.optics.pose import NO_POSE, Pose

NEWTON_MAX_ITER = 30
NEWTON_TOL_MM = 1e-12
MAX_ASPHERE_POWER = 20
# below this radius (mm) an r^1 term's slope over r is evaluated at this radius: the tip of
# the cone it makes has no normal, and x * slope_over_r stays finite (0 on the axis)
_MIN_RADIUS_MM = 1e-150


def sqrt_nonneg(u: torch.Tensor) -> torch.Tensor:
    """Square root of u >= 0, computed as u * rsqrt(u): torch's CPU sqrt kernel splits any
    tensor above 2048 elements across threads (its rsqrt does not), and on a busy 2-core
    machine every such parallel region waits milliseconds for a descheduled thread."""
    return u * torch.rsqrt(torch.clamp(u, min=1e-300))


def _split_powers(asphere: dict[int, float], shift: int) -> tuple[dict[int, float], dict[int, float]]:
    """{power: a} -> (even, odd) Horner terms of sum a * r^(power - shift) in r2 = r^2:
    even {m: a} for power - shift = 2m, odd {m: a} for power - shift = 2m + 1 (times r).
    shift 0 gives the sag's terms; the slope over r uses shift 2 with a * power."""
    even: dict[int, float] = {}
    odd: dict[int, float] = {}
    for p, a in asphere.items():
        if not a:
            continue
        q = p - shift
        (odd if q % 2 else even)[q // 2] = (odd if q % 2 else even).get(q // 2, 0.0) + a
    return even, odd


def _power_series(r2: torch.Tensor, terms: dict[int, float]) -> torch.Tensor:
    """sum(a_m * r2**m) for {m: a_m} with m >= 0, by Horner's rule."""
    low, high = min(terms), max(terms)
    acc = torch.full_like(r2, terms[high])
    for m in range(high - 1, low - 1, -1):
        acc.mul_(r2)
        if terms.get(m):
            acc.add_(terms[m])
    for _ in range(low):
        acc.mul_(r2)
    return acc


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
        """True when the surface is decentred or tilted (lensim.optics.pose)."""
        return any(v != 0.0 for v in self.pose)

    @property
    def radius(self) -> float:
        return math.inf if self.curvature == 0 else 1.0 / self.curvature

    @property
    def is_aspheric(self) -> bool:
        return any(v != 0.0 for v in self.asphere.values())

    @property
    def kind(self) -> str:
        """'plane', 'sphere', 'conic', 'even asphere' or 'odd asphere' (any odd power)."""
        if any(v != 0.0 and p % 2 for p, v in self.asphere.items()):
            return "odd asphere"
        if self.is_aspheric:
            return "even asphere"
        if self.curvature == 0.0:
            return "plane"
        return "sphere" if self.conic == 0.0 else "conic"

    def sag(self, r2: torch.Tensor) -> torch.Tensor:
        """Sag z (mm) at squared radius r2 (mm^2). NaN-free: outside the conic's domain
        the square root is clamped (callers mask such rays)."""
        c, k = self.curvature, self.conic
        root = sqrt_nonneg(torch.clamp(1.0 - (1.0 + k) * c * c * r2, min=0.0))
        z = c * r2 / (1.0 + root)
        even, odd = _split_powers(self.asphere, 0)
        if even:
            z = z + _power_series(r2, even)
        if odd:  # sum b_p r^p over odd p = r * sum b_p r2^((p-1)/2)
            z = z + sqrt_nonneg(r2) * _power_series(r2, odd)
        return z

    def sag_slope_over_r(self, r2: torch.Tensor) -> torch.Tensor:
        """(dz/dr) / r, so that dz/dx = x * this and dz/dy = y * this."""
        c, k = self.curvature, self.conic
        g = c * torch.rsqrt(torch.clamp(1.0 - (1.0 + k) * c * c * r2, min=1e-30))
        slope = {p: coef * p for p, coef in self.asphere.items() if coef}
        b1 = slope.pop(1, 0.0)
        even, odd = _split_powers(slope, 2)  # p a_p r^(p-2): even p in r2, odd p >= 3 as r * (...)
        if even:
            g = g + _power_series(r2, even)
        if odd or b1:
            r = torch.clamp(sqrt_nonneg(r2), min=_MIN_RADIUS_MM)
            if odd:
                g = g + r * _power_series(r2, odd)
            if b1:
                g = g + b1 / r
        return g

    def in_domain(self, r2: torch.Tensor) -> torch.Tensor:
        """True where the conic sag is defined (the square root's argument is >= 0)."""
        c, k = self.curvature, self.conic
        return 1.0 - (1.0 + k) * c * c * r2 >= 0.0

    def normal(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Unit surface normal (..., 3) pointing along +z at the vertex."""
        g = self.sag_slope_over_r(x * x + y * y)
        n = torch.stack([-x * g, -y * g, torch.ones_like(x)], dim=-1)
        return n / torch.linalg.norm(n, dim=-1, keepdim=True)

    def intersect(self, pos: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Path parameter t (mm) from pos along unit dirs to this surface (local coordinates,
        pos already on the vertex plane z=0 or near it) and a validity mask.

        Conic part in closed form, aspheric terms by Newton iteration from the conic root,
        with a convergence test; rays that miss or do not converge are marked invalid.
        """
        px, py, pz = pos.unbind(-1)
        dx, dy, dz = dirs.unbind(-1)
        c, k = self.curvature, self.conic
        a = c * (dx * dx + dy * dy + (1.0 + k) * dz * dz)
        b = c * (px * dx + py * dy + (1.0 + k) * pz * dz) - dz
        cc = c * (px * px + py * py + (1.0 + k) * pz * pz) - 2.0 * pz
        disc = b * b - a * cc
        valid = disc >= 0.0
        sq = torch.sqrt(torch.clamp(disc, min=0.0))
        denom = b + torch.where(b >= 0, sq, -sq)
        valid = valid & (denom.abs() > 1e-300)
        t = -cc / torch.where(valid, denom, torch.ones_like(denom))
        if self.is_aspheric:
            converged = torch.zeros_like(valid)
            for _ in range(NEWTON_MAX_ITER):
                x, y, z = px + t * dx, py + t * dy, pz + t * dz
                r2 = x * x + y * y
                f = z - self.sag(r2)
                g = self.sag_slope_over_r(r2)
                fp = dz - g * (x * dx + y * dy)
                step = f / torch.where(fp.abs() > 1e-12, fp, torch.ones_like(fp))
                t = t - step
                converged = step.abs() < NEWTON_TOL_MM
                if bool(converged[valid].all()):
                    break
            valid = valid & converged & (fp.abs() > 1e-12)
        r2 = (px + t * dx) ** 2 + (py + t * dy) ** 2
        valid = valid & self.in_domain(r2) & torch.isfinite(t)
        t = torch.where(valid, t, torch.zeros_like(t))
        return t, valid

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
