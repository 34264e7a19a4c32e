"""Surface geometry: one class per kind of rotationally symmetric surface.

Every surface is z = sag(r) about its local z axis, vertex at the origin, r^2 = x^2 + y^2
(lengths in mm, curvature c = 1/R in 1/mm, conic constant k):

    Plane        z = 0
    Sphere       z = c r^2 / (1 + sqrt(1 - c^2 r^2))
    Conic        z = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2))
    EvenAsphere  conic + A2 r^2 + A4 r^4 + ... + A20 r^20   (the paper's Eq. 2; Zemax EVENASPH)
    OddAsphere   conic + b1 r + b2 r^2 + b3 r^3 + ... + b20 r^20   (Zemax ODDASPHE; CODE V SPS ODD)

Each class owns its sag, slope, domain, ray intersection and normal, in three forms:

* scalar: ``sag_at(r)`` (a float: drawings, search limits);
* batched: ``sag``, ``sag_slope_over_r``, ``in_domain``, ``normal`` and ``intersect`` on
  tensors of any batch shape, without in-place operations, so autograd runs through them
  (the reference tracer, lensim.optics.trace.trace_reference, and every gradient);
* chunk: ``hit_chunk``, ``normal_chunk``, ``cos_incidence_chunk`` and ``bend_chunk``, in
  place on the flat x, y, z, L, M, N vectors of the fast tracer (lensim.optics.trace), each
  kind with its shortest exact formulas: a plane is a transfer, spheres and conics have a
  closed-form root and an analytic normal (a sphere's is never stored), aspheres run
  Newton's method from the conic root.

``make_geometry(curvature, conic, asphere)`` picks the class (each kind says which
parameters it ``fits``); ``Surface.geometry`` calls it. A new kind of surface is one
subclass of Geometry (its formulas, ``fits`` and ``create``; defining it registers it) and
the file readers that read its parameters.
"""

from __future__ import annotations

import math
from typing import ClassVar

import torch

NEWTON_MAX_ITER = 30
NEWTON_TOL_MM = 1e-12
MAX_ASPHERE_POWER = 20
# below this radius (mm) an r^1 term's slope over r is evaluated at this radius: the tip of
# the cone it makes has no normal, and x * slope_over_r stays finite (0 on the axis)
_MIN_RADIUS_MM = 1e-150
_FLAT_DZ = 1e-12  # |N| below this: the ray runs parallel to the vertex plane and misses

T = torch.Tensor
Normal = tuple[T, T, T]
_KINDS: list[type[Geometry]] = []  # the subclasses of Geometry that define fits(), in the order defined


def sqrt_nonneg(u: torch.Tensor, positive: bool = False) -> torch.Tensor:
    """Square root of u >= 0, computed as u * rsqrt(u): torch's CPU sqrt kernel splits any
    tensor above 2048 elements across threads (its rsqrt does not), and on a busy 2-core
    machine every such parallel region waits milliseconds for a descheduled thread.
    positive: every u is known to exceed 1e-300 (rsqrt needs no clamp)."""
    if positive:
        return torch.rsqrt(u).mul_(u)
    return u * torch.rsqrt(torch.clamp(u, min=1e-300))


def narrow(hit: torch.Tensor | None, mask: torch.Tensor) -> torch.Tensor:
    """hit & mask (in place on hit), where hit None stands for every ray."""
    return mask if hit is None else hit.logical_and_(mask)


def with_sign_of(v: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """v >= 0 with the sign of s, in place (copysign); where s has one sign throughout (one
    reduction) a negation or nothing, cheaper than torch's copysign."""
    lo, hi = (float(m) for m in torch.aminmax(s))
    if lo > 0.0:
        return v
    if hi < 0.0:
        return v.neg_()
    return v.copysign_(s)


def plus_with_sign_of(b: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """b + copysign(v, b) for v >= 0 (a quadratic's root away from cancellation): a
    difference or a sum where b has one sign throughout (one reduction)."""
    lo, hi = (float(m) for m in torch.aminmax(b))
    if hi < 0.0:
        return torch.sub(b, v)
    if lo > 0.0:
        return torch.add(b, v)
    return v.copysign_(b).add_(b)


def _steep(N: torch.Tensor) -> bool:
    """Whether every direction cosine N is farther than _FLAT_DZ from 0 (one or two
    reductions); False also where some N is NaN."""
    return float(N.amin()) > _FLAT_DZ or float(N.amax()) < -_FLAT_DZ


def _finite(t: torch.Tensor) -> bool:
    """Whether every value of t is finite (a finite sum says so; one reduction)."""
    return math.isfinite(float(t.sum()))


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
    """sum(a_m * r2**m) for {m: a_m} with m >= 0, by Horner's rule (in place, unless r2 or
    a coefficient takes part in autograd: the same operations out of place)."""
    low, high = min(terms), max(terms)
    if r2.requires_grad or any(isinstance(a, torch.Tensor) for a in terms.values()):
        acc = terms[high] * torch.ones_like(r2)
        for m in range(high - 1, low - 1, -1):
            acc = acc * r2
            if terms.get(m):
                acc = acc + terms[m]
        for _ in range(low):
            acc = acc * r2
        return acc
    acc = torch.full_like(r2, terms[high])
    for m in range(high - 1, low - 1, -1):
        acc.mul_(r2)
        if terms.get(m):
            acc.add_(terms[m])
    for _ in range(low):
        acc.mul_(r2)
    return acc


def _unit(nx: torch.Tensor, ny: torch.Tensor, nz: torch.Tensor) -> Normal:
    """(nx, ny, nz) scaled to unit length, in place."""
    inv = nx * nx
    inv.addcmul_(ny, ny).addcmul_(nz, nz).rsqrt_()
    return nx.mul_(inv), ny.mul_(inv), nz.mul_(inv)


class Geometry:
    """A rotationally symmetric surface z = sag(r): the interface every kind implements.

    Subclasses give the batched ``sag``, ``sag_slope_over_r``, ``in_domain`` and
    ``intersect`` and the chunk forms ``hit_chunk`` and ``normal_chunk``; the scalar sag,
    the batched normal and the refraction helpers of the fast tracer follow from those.
    """

    kind: ClassVar[str] = ""
    curvature: float = 0.0
    conic: float = 0.0

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if "fits" in cls.__dict__:  # a kind that says which surfaces it is: make_geometry asks it
            _KINDS.append(cls)

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        """Whether this kind is the shape of a surface with these parameters (terms: the
        nonzero aspheric coefficients); make_geometry asks the more specific kinds first."""
        return False

    @classmethod
    def create(cls, curvature: float, conic: float, terms: dict[int, float]) -> Geometry:
        """This kind's geometry for parameters it fits."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}(curvature={self.curvature!r}, conic={self.conic!r})"

    # ---- batched (any shape, autograd-safe) -------------------------------------
    def sag(self, r2: torch.Tensor) -> torch.Tensor:
        """Sag z (mm) at squared radius r2 (mm^2), NaN-free (callers mask out-of-domain rays)."""
        raise NotImplementedError

    def sag_slope_over_r(self, r2: torch.Tensor) -> torch.Tensor:
        """(dz/dr) / r (1/mm), so that dz/dx = x * this and dz/dy = y * this."""
        raise NotImplementedError

    def in_domain(self, r2: torch.Tensor) -> torch.Tensor:
        """True where the sag is defined."""
        raise NotImplementedError

    def intersect(self, pos: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Path parameter t (mm) from pos (..., 3) along unit dirs (..., 3) to the surface
        (local coordinates, pos on or near the vertex plane z = 0) and the hit mask;
        t is 0 where the ray misses."""
        raise NotImplementedError

    def normal(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Unit surface normal (..., 3) at (x, y) mm, pointing along +z at the vertex."""
        g = self.sag_slope_over_r(x * x + y * y)
        n = torch.stack([-x * g, -y * g, torch.ones_like(x)], dim=-1)
        return n / torch.linalg.norm(n, dim=-1, keepdim=True)

    # ---- scalar ------------------------------------------------------------------
    @property
    def max_radius(self) -> float:
        """Largest radius (mm) where the sag is defined (math.inf: everywhere)."""
        return math.inf

    def sag_at(self, r: float) -> float:
        """Sag z (mm) at radius r (mm)."""
        return float(self.sag(torch.tensor([r * r], dtype=torch.float64))[0])

    # ---- chunk (in place on flat float64 vectors; the fast tracer) ----------------
    def hit_chunk(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        z: torch.Tensor,
        L: torch.Tensor,
        M: torch.Tensor,
        N: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Path length t (mm) from the points (x, y, z), z local to the vertex, along the
        directions (L, M, N) to the surface, and the hit mask, None where every ray hits
        (the inputs are not changed)."""
        raise NotImplementedError

    def normal_chunk(self, x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> Normal | None:
        """Unit normal (nx, ny, nz) at the surface points (x, y, z), along +z at the vertex;
        None for a plane (the normal is +z)."""
        raise NotImplementedError

    def cos_incidence_chunk(
        self, x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, L: torch.Tensor, M: torch.Tensor, N: torch.Tensor
    ) -> tuple[torch.Tensor, Normal | None]:
        """The direction's component along the normal, and the normal for bend_chunk."""
        nrm = self.normal_chunk(x, y, z)
        if nrm is None:
            return N.clone(), None
        return torch.mul(L, nrm[0]).addcmul_(M, nrm[1]).addcmul_(N, nrm[2]), nrm

    def bend_chunk(
        self,
        kk: torch.Tensor,
        nrm: Normal | None,
        x: torch.Tensor,
        y: torch.Tensor,
        z: torch.Tensor,
        L: torch.Tensor,
        M: torch.Tensor,
        N: torch.Tensor,
    ) -> None:
        """(L, M, N) += kk * normal, in place (nrm: from cos_incidence_chunk)."""
        if nrm is None:
            N.add_(kk)
            return
        L.addcmul_(kk, nrm[0])
        M.addcmul_(kk, nrm[1])
        N.addcmul_(kk, nrm[2])


class Conic(Geometry):
    """The conic z = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)); the base of every other kind.

    Its intersection is the closed-form root of the quadric on the sheet nearest the
    vertex plane (the quadric's equation divided through, so that c = 0 is the plane);
    refine() is where aspheres correct it."""

    kind: ClassVar[str] = "conic"

    def __init__(self, curvature: float, conic: float = 0.0) -> None:
        self.curvature = curvature
        self.conic = conic

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        return not terms

    @classmethod
    def create(cls, curvature: float, conic: float, terms: dict[int, float]) -> Geometry:
        return Conic(curvature, conic)

    def sag(self, r2: torch.Tensor) -> torch.Tensor:
        c, k = self.curvature, self.conic
        root = sqrt_nonneg(torch.clamp(1.0 - (1.0 + k) * c * c * r2, min=0.0))
        return c * r2 / (1.0 + root)

    def sag_slope_over_r(self, r2: torch.Tensor) -> torch.Tensor:
        c, k = self.curvature, self.conic
        return c * torch.rsqrt(torch.clamp(1.0 - (1.0 + k) * c * c * r2, min=1e-30))

    def in_domain(self, r2: torch.Tensor) -> torch.Tensor:
        c, k = self.curvature, self.conic
        return 1.0 - (1.0 + k) * c * c * r2 >= 0.0

    @property
    def max_radius(self) -> float:
        q = (1.0 + self.conic) * self.curvature**2
        return math.inf if q <= 0 else 1.0 / math.sqrt(q)

    def intersect(self, pos: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
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
        t, valid = self.refine(pos, dirs, t, valid)
        r2 = (px + t * dx) ** 2 + (py + t * dy) ** 2
        valid = valid & self.in_domain(r2) & torch.isfinite(t)
        t = torch.where(valid, t, torch.zeros_like(t))
        return t, valid

    def refine(
        self, pos: torch.Tensor, dirs: torch.Tensor, t: torch.Tensor, valid: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The intersection (t, valid) from the conic root: the root itself for a conic."""
        return t, valid

    # ---- chunk -------------------------------------------------------------------
    def _leaves_domain(self) -> bool:
        """Whether hit_chunk checks the sag's domain at the hit: always after Newton (an
        asphere), at an ellipsoid's rim (k > -1); never for a sphere, where it holds on
        every hit, nor for 1 + k <= 0, whose domain is the whole plane."""
        return self.conic > -1.0

    def hit_chunk(self, x: T, y: T, z: T, L: T, M: T, N: T) -> tuple[T, T | None]:
        c, k = self.curvature, self.conic
        back = torch.div(z, N)  # minus the path to the vertex plane
        hit = None if _steep(N) else N.abs() > _FLAT_DZ
        x1 = torch.addcmul(x, back, L, value=-1.0)
        y1 = torch.addcmul(y, back, M, value=-1.0)
        r2 = x1 * x1
        r2.addcmul_(y1, y1)
        b = x1 * L
        b.addcmul_(y1, M).mul_(c).sub_(N)
        disc = b * b
        if k == 0.0:
            disc.add_(r2, alpha=-c * c)
        else:
            a = N * N
            a.mul_(c * k).add_(c)
            disc.addcmul_(a, r2, value=-c)
        low = float(disc.amin())
        if not low >= 0.0:
            hit = narrow(hit, disc >= 0.0)
            disc.clamp_(min=0.0)
        denom = plus_with_sign_of(b, sqrt_nonneg(disc, positive=low > 1e-300))
        t1 = r2.mul_(-c).div_(denom)  # conic root measured from the vertex plane
        t1, hit = self.refine_chunk(x1, y1, L, M, N, t1, hit)
        t = t1.sub_(back)
        if not _finite(t):
            hit = narrow(hit, torch.isfinite(t))
        if self._leaves_domain():
            xn = torch.addcmul(x, t, L)
            yn = torch.addcmul(y, t, M)
            rn = xn * xn
            rn.addcmul_(yn, yn)
            if not bool(self.in_domain(rn.amax())):  # the domain is a disc about the axis
                hit = narrow(hit, self.in_domain(rn))
        return t, hit

    def refine_chunk(
        self,
        x1: torch.Tensor,
        y1: torch.Tensor,
        L: torch.Tensor,
        M: torch.Tensor,
        N: torch.Tensor,
        t1: torch.Tensor,
        hit: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """hit_chunk's root t1 from the vertex-plane points (x1, y1, 0) (hit: None where every
        ray hits): as is for a conic."""
        return t1, hit

    def normal_chunk(self, x: T, y: T, z: T) -> Normal | None:
        c, k = self.curvature, self.conic
        return _unit(x * -c, y * -c, torch.mul(z, -c * (1.0 + k)).add_(1.0))


class Plane(Conic):
    """The plane z = 0 (a flat surface, the image plane)."""

    kind: ClassVar[str] = "plane"

    def __init__(self) -> None:
        super().__init__(0.0, 0.0)

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        return not terms and curvature == 0.0  # without curvature the conic does not matter

    @classmethod
    def create(cls, curvature: float, conic: float, terms: dict[int, float]) -> Geometry:
        return Plane()

    def __repr__(self) -> str:
        return "Plane()"

    def hit_chunk(self, x: T, y: T, z: T, L: T, M: T, N: T) -> tuple[T, T | None]:
        return torch.div(z, N).neg_(), None if _steep(N) else N.abs() > _FLAT_DZ

    def normal_chunk(self, x: T, y: T, z: T) -> Normal | None:
        return None


class Sphere(Conic):
    """The sphere of curvature c: on it, (-c x, -c y, 1 - c z) is already the unit normal,
    so the fast tracer neither normalizes nor stores it, and no root leaves the domain."""

    kind: ClassVar[str] = "sphere"

    def __init__(self, curvature: float) -> None:
        super().__init__(curvature, 0.0)

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        return not terms and curvature != 0.0 and conic == 0.0

    @classmethod
    def create(cls, curvature: float, conic: float, terms: dict[int, float]) -> Geometry:
        return Sphere(curvature)

    def _leaves_domain(self) -> bool:
        return False

    def normal_chunk(self, x: T, y: T, z: T) -> Normal | None:
        c = self.curvature
        return x * -c, y * -c, torch.mul(z, -c).add_(1.0)

    def cos_incidence_chunk(self, x: T, y: T, z: T, L: T, M: T, N: T) -> tuple[T, Normal | None]:
        cos_i = x * L
        cos_i.addcmul_(y, M).addcmul_(z, N).mul_(-self.curvature).add_(N)
        return cos_i, None

    def bend_chunk(self, kk: T, nrm: Normal | None, x: T, y: T, z: T, L: T, M: T, N: T) -> None:
        c = self.curvature
        L.addcmul_(kk, x, value=-c)
        M.addcmul_(kk, y, value=-c)
        N.add_(kk).addcmul_(kk, z, value=-c)


class EvenAsphere(Conic):
    """The conic plus sum A_p r^p over even powers p = 2..20 (coefficients in mm^(1-p)).

    Intersection: Newton's method from the conic root, with a convergence test; rays that
    do not converge, or where the sag has no slope along the ray, miss."""

    kind: ClassVar[str] = "even asphere"

    def __init__(self, curvature: float, conic: float, terms: dict[int, float]) -> None:
        super().__init__(curvature, conic)
        self.terms = {p: a for p, a in terms.items() if a}
        if type(self) is EvenAsphere and any(p % 2 for p in self.terms):
            raise ValueError(f"an even asphere has even powers only, got {sorted(self.terms)}")
        slope = {p: a * p for p, a in self.terms.items()}
        self._b1 = slope.pop(1, 0.0)  # the slope over r of b1 r is b1 / r
        self._sag_even, self._sag_odd = _split_powers(self.terms, 0)
        self._slope_even, self._slope_odd = _split_powers(slope, 2)  # p a_p r^(p-2)

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        return bool(terms) and not any(p % 2 for p in terms)

    @classmethod
    def create(cls, curvature: float, conic: float, terms: dict[int, float]) -> Geometry:
        return cls(curvature, conic, terms)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(curvature={self.curvature!r}, conic={self.conic!r}, terms={self.terms!r})"

    def sag(self, r2: torch.Tensor) -> torch.Tensor:
        z = super().sag(r2)
        if self._sag_even:
            z = z + _power_series(r2, self._sag_even)
        return z

    def sag_slope_over_r(self, r2: torch.Tensor) -> torch.Tensor:
        g = super().sag_slope_over_r(r2)
        if self._slope_even:
            g = g + _power_series(r2, self._slope_even)
        return g

    def _leaves_domain(self) -> bool:
        return True

    def refine(
        self, pos: torch.Tensor, dirs: torch.Tensor, t: torch.Tensor, valid: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        px, py, pz = pos.unbind(-1)
        dx, dy, dz = dirs.unbind(-1)
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
        return t, valid & converged & (fp.abs() > 1e-12)

    def refine_chunk(self, x1: T, y1: T, L: T, M: T, N: T, t1: T, hit: T | None) -> tuple[T, T | None]:
        if not _finite(t1):
            t1 = torch.where(torch.isfinite(t1), t1, torch.zeros_like(t1))
        converged: T | None = None
        fp_ok: T | None = None
        for _ in range(NEWTON_MAX_ITER):
            xx = torch.addcmul(x1, t1, L)
            yy = torch.addcmul(y1, t1, M)
            rr = xx * xx
            rr.addcmul_(yy, yy)
            f = t1 * N
            f.sub_(self.sag(rr))
            fp = xx.mul_(L).addcmul_(yy, M).mul_(self.sag_slope_over_r(rr)).neg_().add_(N)
            fp_ok = None if float(fp.abs().amin()) > 1e-12 else fp.abs() > 1e-12
            step = f.div_(fp if fp_ok is None else torch.where(fp_ok, fp, torch.ones_like(fp)))
            t1 = t1 - step
            size = step.abs()
            if float(size.amax()) < NEWTON_TOL_MM:
                converged = None
                break
            converged = size < NEWTON_TOL_MM
            if bool(converged.all() if hit is None else converged[hit].all()):
                break
        if converged is not None:
            hit = narrow(hit, converged)
        return t1, hit if fp_ok is None else narrow(hit, fp_ok)

    def normal_chunk(self, x: T, y: T, z: T) -> Normal | None:
        r2 = x * x
        r2.addcmul_(y, y)
        g = self.sag_slope_over_r(r2)
        return _unit((x * g).neg_(), (y * g).neg_(), torch.ones_like(x))


class OddAsphere(EvenAsphere):
    """The conic plus sum b_p r^p over powers p = 1..20, odd ones among them (an r^1 term
    makes a cone's tip on the axis, where the normal is taken as +z)."""

    kind: ClassVar[str] = "odd asphere"

    @classmethod
    def fits(cls, curvature: float, conic: float, terms: dict[int, float]) -> bool:
        return any(p % 2 for p in terms)

    def sag(self, r2: torch.Tensor) -> torch.Tensor:
        z = super().sag(r2)
        if self._sag_odd:  # sum b_p r^p over odd p = r * sum b_p r2^((p-1)/2)
            z = z + sqrt_nonneg(r2) * _power_series(r2, self._sag_odd)
        return z

    def sag_slope_over_r(self, r2: torch.Tensor) -> torch.Tensor:
        g = super().sag_slope_over_r(r2)
        if self._slope_odd or self._b1:
            r = torch.clamp(sqrt_nonneg(r2), min=_MIN_RADIUS_MM)
            if self._slope_odd:
                g = g + r * _power_series(r2, self._slope_odd)
            if self._b1:
                g = g + self._b1 / r
        return g


def make_geometry(curvature: float, conic: float = 0.0, asphere: dict[int, float] | None = None) -> Geometry:
    """The geometry of a surface with this vertex curvature (1/mm), conic constant and
    aspheric terms {power: coefficient} (zero terms dropped): the first kind, the most
    recently defined first, whose ``fits`` accepts them (a plane, sphere, conic, even or
    odd asphere)."""
    terms = {p: a for p, a in (asphere or {}).items() if a != 0.0}
    for kind in reversed(_KINDS):
        if kind.fits(curvature, conic, terms):
            return kind.create(curvature, conic, terms)
    raise ValueError(f"no surface geometry for curvature {curvature}, conic {conic}, terms {terms}")
