"""The fast tracer's fused kernel: one chunk of rays through every step, ray by ray, in
one compiled loop (numba), without a vector temporary.

lensim.optics.trace.trace runs it for each chunk where it can (CPU tensors, no gradients,
every surface a Plane, Sphere, Conic, EvenAsphere or OddAsphere, no recorded surface
positions); elsewhere it runs the torch chunk loop (lensim.optics.trace_chunk), whose
semantics this kernel keeps ray for ray: the same steps (``trace_chunk.steps``), the same
status codes (MISSED, TIR, VIGNETTED) written on the same surfaces, failed rays left as
they stand (a ray that misses keeps its state from before the surface; a vignetted or
totally internally reflected one stops on it with its incoming direction), the same
backwards test and virtual steps. The per-ray formulas mirror the chunk forms of
lensim.optics.geometry (named in each function's docstring); tests/test_trace_fused.py
checks the two against each other on every kind of surface, failing rays included. The
results agree to rounding (~1e-13 mm): the kernel's square roots are ``sqrt``, not
``u * rsqrt(u)``, a conic's normal is scaled to unit length
with a sphere's formula (1/sqrt), and each ray runs Newton's method until it converges
itself rather than until its whole chunk has.

Layout: rays go through in blocks of BLOCK, a block through one step at a time, its state
(x, y, z, L, M, N, OPL, status, failure surface) in the flat rows of one of two work
blocks (WORK_SHAPE); planes, spheres and conics run a loop without branches (selects)
over all BLOCK rays (those past the batch's end are not traced), reading one work block
and writing the other, which the compiler vectorizes (SIMD across rays) without runtime
overlap checks or masked stores (an in-place store of "new if cond else old" compiles to
a masked store, microcoded on AMD CPUs: the kernel ran about 20 % slower that way);
aspheres run Newton's method ray by ray, in place.

The kernel releases the GIL (trace() runs chunks on its thread pool) and is compiled for
its one signature when this module is first imported (lensim.optics.trace imports it on
the first trace), then cached on disk (numba's ``cache=True``, next to this file or in
NUMBA_CACHE_DIR). Lengths in mm.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from numba import njit

from lensim.optics.geometry import (
    _FLAT_DZ,
    _MIN_RADIUS_MM,
    NEWTON_MAX_ITER,
    NEWTON_TOL_MM,
    Conic,
    EvenAsphere,
    OddAsphere,
    Plane,
    Sphere,
)
from lensim.optics.trace_chunk import _BACKWARDS_MM, MISSED, OK, TIR, VIGNETTED, Step

# kinds of surface (a step's KIND)
PLANE, SPHERE, CONIC, ASPHERE = 0, 1, 2, 3
_KIND_OF = {Plane: PLANE, Sphere: SPHERE, Conic: CONIC, EvenAsphere: ASPHERE, OddAsphere: ASPHERE}
# a step's integers (plan.ints[s, ...])
KIND, INDEX, INTERACT, MIRROR, BACKWARDS_OK, CHECK_DOMAIN = range(6)
# a step's floats (plan.floats[s, ...])
CURV, CONIC_K, SHIFT, Z_VERTEX, R2_MAX, R2_MIN, B1 = range(7)
# aspheric series (plan.coef[s, series, m]: the coefficient of r2^m; plan.high[s, series]:
# the highest m, -1 for none): the sag's even and odd parts, the slope over r's even and odd
SAG_EVEN, SAG_ODD, SLOPE_EVEN, SLOPE_ODD = range(4)
_MAX_M = 11  # r2^0 .. r2^10 (powers up to 20)
Arr = np.ndarray
#: numba's options for every function of the kernel: compiled once and cached on disk;
#: the GIL released; division as in C (no ZeroDivisionError checks); no reference counts
#: (the kernel allocates nothing, and counting the arrays passed between its functions cost
#: more than the arithmetic). Multiply-adds are NOT fused (no fastmath "contract"): fused,
#: a ray's rounding differed between the vectorized loop body and its scalar remainder, so
#: a ray's result depended on where the thread-count-dependent chunks split the batch, and
#: a killed-and-resumed bank differed from an uninterrupted one by 1 ulp
#: (tests/test_kill_resume.py)
_JIT: dict = dict(cache=True, nogil=True, error_model="numpy", _nrt=False)


class Plan:
    """A trace's steps as the kernel's arrays: ints (S, 6), floats (S, 7), the aspheric
    series coef (S, 4, 11) and their highest power high (S, 4)."""

    def __init__(self, chunk_steps: list[Step]) -> None:
        S = len(chunk_steps)
        self.ints = np.zeros((S, 6), dtype=np.int64)
        self.floats = np.zeros((S, 7), dtype=np.float64)
        self.coef = np.zeros((S, 4, _MAX_M), dtype=np.float64)
        self.high = np.full((S, 4), -1, dtype=np.int64)
        for s, st in enumerate(chunk_steps):
            self._fill(s, st)

    def _fill(self, s: int, st: Step) -> None:
        g = st.geometry
        kind = _KIND_OF[type(g)]
        domain = isinstance(g, Conic) and g._leaves_domain()  # every kind the kernel knows is a Conic
        self.ints[s] = (kind, st.index, st.interact, st.surface.is_mirror, st.backwards_ok, domain)
        r2_max = math.inf if st.r2_max is None else st.r2_max
        r2_min = -math.inf if st.r2_min is None else st.r2_min
        b1 = float(g._b1) if isinstance(g, EvenAsphere) else 0.0
        self.floats[s] = (float(g.curvature), float(g.conic), st.shift, st.z_vertex, r2_max, r2_min, b1)
        if isinstance(g, EvenAsphere):
            for j, terms in enumerate((g._sag_even, g._sag_odd, g._slope_even, g._slope_odd)):
                for m, a in terms.items():
                    self.coef[s, j, m] = float(a)
                self.high[s, j] = max(terms) if terms else -1


#: whether the kernel traces aspheres. Its Newton's method runs ray by ray, a chain of
#: dependent square roots and divisions that the CPU cannot overlap, and is slower than the
#: torch loop's, which is vectorized across the chunk (measured: 0.69x in CPU time on the
#: phone wide-angle lens, 100k rays): aspheric lenses take the torch loop until the
#: kernel's Newton iterations run across a block. Tests turn it on to check the code.
ASPHERES = False


def plan_for(chunk_steps: list[Step]) -> Plan | None:
    """The kernel's plan for these steps, or None where a surface is of a kind the kernel
    does not know (a Geometry subclass of its own, an asphere unless ASPHERES) or has a
    parameter that is a tensor."""
    for st in chunk_steps:
        g = st.geometry
        if type(g) not in _KIND_OF or (_KIND_OF[type(g)] == ASPHERE and not ASPHERES):
            return None
        values = [g.curvature, g.conic] + (list(g.terms.values()) if isinstance(g, EvenAsphere) else [])
        if any(isinstance(v, torch.Tensor) and v.requires_grad for v in values):
            return None
    return Plan(chunk_steps)


# ---- per-ray formulas (each mirrors a chunk method of lensim.optics.geometry) -----------
@njit(**_JIT)
def _series(coef: np.ndarray, high: np.ndarray, s: int, j: int, r2: float) -> float:
    """sum coef[s, j, m] r2^m for m = 0..high[s, j] by Horner's rule (geometry._power_series)."""
    h = high[s, j]
    acc = coef[s, j, h]
    for m in range(h - 1, -1, -1):
        acc = acc * r2 + coef[s, j, m]
    return acc


@njit(**_JIT)
def _sag(f: np.ndarray, coef: np.ndarray, high: np.ndarray, s: int, r2: float) -> float:
    """An asphere's sag (mm) at squared radius r2 (EvenAsphere.sag, OddAsphere.sag)."""
    c, k = f[s, CURV], f[s, CONIC_K]
    u = 1.0 - (1.0 + k) * c * c * r2
    z = c * r2 / (1.0 + math.sqrt(max(u, 0.0)))
    if high[s, SAG_EVEN] >= 0:
        z += _series(coef, high, s, SAG_EVEN, r2)
    if high[s, SAG_ODD] >= 0:
        z += math.sqrt(max(r2, 0.0)) * _series(coef, high, s, SAG_ODD, r2)
    return z


@njit(**_JIT)
def _slope_over_r(f: np.ndarray, coef: np.ndarray, high: np.ndarray, s: int, r2: float) -> float:
    """An asphere's (dz/dr) / r (1/mm) at r2 (EvenAsphere / OddAsphere.sag_slope_over_r)."""
    c, k = f[s, CURV], f[s, CONIC_K]
    g = c / math.sqrt(max(1.0 - (1.0 + k) * c * c * r2, 1e-30))
    if high[s, SLOPE_EVEN] >= 0:
        g += _series(coef, high, s, SLOPE_EVEN, r2)
    if high[s, SLOPE_ODD] >= 0 or f[s, B1] != 0.0:
        r = max(math.sqrt(max(r2, 0.0)), _MIN_RADIUS_MM)
        if high[s, SLOPE_ODD] >= 0:
            g += r * _series(coef, high, s, SLOPE_ODD, r2)
        g += f[s, B1] / r
    return g


@njit(**_JIT)
def _newton(
    f: np.ndarray,
    coef: np.ndarray,
    high: np.ndarray,
    s: int,
    x1: float,
    y1: float,
    L: float,
    M: float,
    N: float,
    t1: float,
) -> tuple[float, bool]:
    """EvenAsphere.refine_chunk for one ray: (t1, converged) from the conic root t1 of the
    vertex-plane point (x1, y1, 0); a ray that does not converge, or ends where the sag
    has no slope along it, misses."""
    if not math.isfinite(t1):
        t1 = 0.0
    for _ in range(NEWTON_MAX_ITER):
        xx = x1 + t1 * L
        yy = y1 + t1 * M
        rr = xx * xx + yy * yy
        fv = t1 * N - _sag(f, coef, high, s, rr)
        fp = N - (xx * L + yy * M) * _slope_over_r(f, coef, high, s, rr)
        ok = abs(fp) > 1e-12
        step = fv / fp if ok else fv
        t1 = t1 - step
        if abs(step) < NEWTON_TOL_MM:
            return t1, ok
    return t1, False


@njit(**_JIT)
def _conic_root(
    c: float, k: float, x: float, y: float, z: float, L: float, M: float, N: float
) -> tuple[float, float, float, float, bool]:
    """Conic.hit_chunk's closed form for one ray (a plane is c = 0): (t1, back, x1, y1,
    ok), the root t1 from the vertex-plane point (x1, y1, 0), back = z / N (minus the
    path to that plane), ok: the ray is not parallel to the plane and meets the quadric."""
    back = z / N
    x1 = x - back * L
    y1 = y - back * M
    r2 = x1 * x1 + y1 * y1
    b = (x1 * L + y1 * M) * c - N
    disc = b * b - c * (N * N * (c * k) + c) * r2
    t1 = r2 * -c / (b + math.copysign(math.sqrt(max(disc, 0.0)), b))
    return t1, back, x1, y1, (abs(N) > _FLAT_DZ) & (disc >= 0.0)


@njit(**_JIT)
def _advance(
    s: int, i: int, ints: np.ndarray, f: np.ndarray, coef: np.ndarray, high: np.ndarray, w: np.ndarray
) -> None:
    """Step s for ray i of the block w on an asphere (Newton's method, ray by ray): the
    same as _closed_loop, with EvenAsphere's intersection and normal."""
    live = w[CODE * BLOCK + i] == OK
    x, y, z = w[X * BLOCK + i], w[Y * BLOCK + i], w[Z * BLOCK + i] - (f[s, SHIFT] if live else 0.0)
    L, M, N = w[L_ * BLOCK + i], w[M_ * BLOCK + i], w[N_ * BLOCK + i]
    t1, back, x1, y1, hit = _conic_root(f[s, CURV], f[s, CONIC_K], x, y, z, L, M, N)
    if live and hit:
        t1, hit = _newton(f, coef, high, s, x1, y1, L, M, N, t1)
    t = t1 - back
    hit = hit and math.isfinite(t) and (ints[s, BACKWARDS_OK] != 0 or t > _BACKWARDS_MM)
    if live and hit:
        xn, yn, zn = x + t * L, y + t * M, z + t * N
        rr = xn * xn + yn * yn
        hit = 1.0 - (1.0 + f[s, CONIC_K]) * f[s, CURV] ** 2 * rr >= 0.0  # Conic.in_domain
    code = OK if not live else (MISSED if not hit else OK)
    if live and hit:
        x, y, z = xn, yn, zn
        w[OPL * BLOCK + i] += t * w[N1 * BLOCK + i]
        if rr > f[s, R2_MAX] or rr < f[s, R2_MIN]:
            code = VIGNETTED
        elif ints[s, MIRROR] != 0 or w[MU * BLOCK + i] != 1.0:
            g = _slope_over_r(f, coef, high, s, rr)
            inv = 1.0 / math.sqrt(x * x * g * g + y * y * g * g + 1.0)
            L, M, N, tir = _bend(ints[s, MIRROR] != 0, w[MU * BLOCK + i], -(x * g) * inv, -(y * g) * inv, inv, L, M, N)
            code = TIR if tir else OK
            if not tir:
                w[L_ * BLOCK + i], w[M_ * BLOCK + i], w[N_ * BLOCK + i] = L, M, N
    w[X * BLOCK + i], w[Y * BLOCK + i], w[Z * BLOCK + i] = x, y, z + (f[s, Z_VERTEX] if code != OK else 0.0)
    if code != OK:
        w[CODE * BLOCK + i], w[WHERE * BLOCK + i] = code, ints[s, INDEX]


@njit(**_JIT)
def _bend(
    mirror: bool, mu: float, nx: float, ny: float, nz: float, L: float, M: float, N: float
) -> tuple[float, float, float, bool]:
    """trace_chunk._reflect / _refract for one ray at a surface of unit normal (nx, ny, nz),
    mu = n1 / n2: (L, M, N, tir), the direction after it (tir: totally internally reflected)."""
    cos_i = L * nx + M * ny + N * nz
    if mirror:
        dn = cos_i * -2.0
        return L + dn * nx, M + dn * ny, N + dn * nz, False
    ct = cos_i * cos_i * (mu * mu) + (1.0 - mu * mu)
    kk = math.copysign(math.sqrt(max(ct, 0.0)), cos_i) - cos_i * mu
    return L * mu + kk * nx, M * mu + kk * ny, N * mu + kk * nz, ct < 0.0


@njit(**_JIT)
def _step_asphere(
    s: int, ints: np.ndarray, f: np.ndarray, coef: np.ndarray, high: np.ndarray, w: np.ndarray, m: int
) -> None:
    """Step s (an even or odd asphere) for the first m rays of the block w."""
    for i in range(m):
        _advance(s, i, ints, f, coef, high, w)


@njit(**_JIT, inline="always")
def _closed_loop(
    s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1s: float, mus: float, uni: bool, bend: bool, unit: bool
) -> None:
    """trace_chunk's _move_to_surface, _reflect and _refract at step s (a plane, sphere or
    conic: Conic.hit_chunk's closed form) for the BLOCK rays of the block a (flat rows of
    BLOCK: X, Y, Z (z local to the previous vertex), L, M, N, OPL, CODE (status), WHERE
    (failure surface), N1 (the medium's index before the surface), MU (n1 / n2)), written
    to the rows X..WHERE of b: a ray still traced (CODE OK) moves to the surface and is
    bent there; one that fails gets its code and the step's surface, its z made global,
    and stops. Every branch is a select and every store unconditional (into the other
    block: an in-place store of a select with the old value compiles to a masked store,
    microcoded and slow on AMD CPUs), over a constant trip count, so the compiler
    vectorizes the loop without runtime checks. bend: the step refracts or reflects;
    unit: its normal needs scaling (a conic; a plane's and a sphere's are unit already);
    both constants."""
    plane, mirror, c, k = ints[s, KIND] == PLANE, ints[s, MIRROR] != 0, f[s, CURV], f[s, CONIC_K]
    shift, z_vertex, r2_max, r2_min = f[s, SHIFT], f[s, Z_VERTEX], f[s, R2_MAX], f[s, R2_MIN]
    back_ok, domain = ints[s, BACKWARDS_OK] != 0, ints[s, CHECK_DOMAIN] != 0
    idx = float(ints[s, INDEX])
    for i in range(BLOCK):
        cw, wh = a[CODE * BLOCK + i], a[WHERE * BLOCK + i]
        n1, mu = (n1s, mus) if uni else (a[N1 * BLOCK + i], a[MU * BLOCK + i])
        live = cw == OK
        x, y, z = a[X * BLOCK + i], a[Y * BLOCK + i], a[Z * BLOCK + i] - (shift if live else 0.0)
        dx, dy, dz, o = a[L_ * BLOCK + i], a[M_ * BLOCK + i], a[N_ * BLOCK + i], a[OPL * BLOCK + i]
        t1, back, x1, y1, hit = _conic_root(c, k, x, y, z, dx, dy, dz)
        t = -(z / dz) if plane else t1 - back
        hit = hit & (plane | (abs(t) < math.inf)) & (back_ok | (t > _BACKWARDS_MM))
        xn, yn, zn = x + t * dx, y + t * dy, z + t * dz
        rr = xn * xn + yn * yn
        hit = hit & (~domain | (1.0 - (1.0 + k) * c * c * rr >= 0.0))  # Conic.in_domain
        go = live & hit
        vig = go & ((rr > r2_max) | (rr < r2_min))
        tir, bent = False, False
        Lo, Mo, No = dx, dy, dz
        if bend:
            nx, ny, nz = xn * -c, yn * -c, zn * (-c * (1.0 + k)) + 1.0
            if unit:
                inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
                nx, ny, nz = nx * inv, ny * inv, nz * inv
            cos_i = dx * nx + dy * ny + dz * nz
            ct = cos_i * cos_i * (mu * mu) + (1.0 - mu * mu)
            kk = math.copysign(math.sqrt(max(ct, 0.0)), cos_i) - cos_i * mu
            dn = cos_i * -2.0
            bent = go & ~vig & (mirror | (mu != 1.0))
            tir = bent & ~mirror & (ct < 0.0)
            bent = bent & ~tir
            Lo = (dx + dn * nx if mirror else dx * mu + kk * nx) if bent else dx
            Mo = (dy + dn * ny if mirror else dy * mu + kk * ny) if bent else dy
            No = (dz + dn * nz if mirror else dz * mu + kk * nz) if bent else dz
        code = MISSED if not hit else (VIGNETTED if vig else (TIR if tir else OK))
        fails = live & (code != OK)
        b[L_ * BLOCK + i], b[M_ * BLOCK + i], b[N_ * BLOCK + i] = Lo, Mo, No
        b[X * BLOCK + i] = xn if go else x
        b[Y * BLOCK + i] = yn if go else y
        b[Z * BLOCK + i] = (zn if go else z) + (z_vertex if fails else 0.0)
        b[OPL * BLOCK + i] = o + t * n1 if go else o
        b[CODE * BLOCK + i] = code if fails else cw
        b[WHERE * BLOCK + i] = idx if fails else wh


@njit(**_JIT)
def _move(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_closed_loop for a step that does not bend the rays (the image plane, a surface
    between equal media), per-ray media (rows N1, MU)."""
    _closed_loop(s, ints, f, a, b, n1, mu, False, False, False)


@njit(**_JIT)
def _move_bend(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_closed_loop for a plane or sphere that bends the rays, per-ray media."""
    _closed_loop(s, ints, f, a, b, n1, mu, False, True, False)


@njit(**_JIT)
def _move_bend_unit(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_closed_loop for a conic that bends the rays, per-ray media."""
    _closed_loop(s, ints, f, a, b, n1, mu, False, True, True)


@njit(**_JIT)
def _move_u(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_move with one index n1 and ratio mu for every ray."""
    _closed_loop(s, ints, f, a, b, n1, mu, True, False, False)


@njit(**_JIT)
def _move_bend_u(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_move_bend with one index n1 and ratio mu for every ray."""
    _closed_loop(s, ints, f, a, b, n1, mu, True, True, False)


@njit(**_JIT)
def _move_bend_unit_u(s: int, ints: Arr, f: Arr, a: Arr, b: Arr, n1: float, mu: float) -> None:
    """_move_bend_unit with one index n1 and ratio mu for every ray."""
    _closed_loop(s, ints, f, a, b, n1, mu, True, True, True)


# rows of a block's work array w
X, Y, Z, L_, M_, N_, OPL, CODE, WHERE, N1, MU = range(11)
#: rays per block: the kernel carries a block through one step at a time, its state in
#: cache, in loops the compiler vectorizes (SIMD across rays; aspheres excepted)
BLOCK = 2048
#: the rows of a block's work array
ROWS = 11
#: the shape of the work array trace_rays takes: two blocks of flat rows (the closed loops
#: read one and write the other)
WORK_SHAPE = (2, ROWS * BLOCK)


@njit(**_JIT)
def _media(n: np.ndarray, uniform: bool, s: int, a: int, m: int, w: np.ndarray) -> bool:
    """Rows N1 (index before surface s) and MU (n1 / n2) of the block w for rays a..a+m
    (the asphere's loop and the closed loops with per-ray media read them); uniform: every
    ray has the same indices (n: (S+1, B), a column broadcast). Returns whether the surface
    has the same medium on both sides for every ray."""
    s2 = min(s + 1, n.shape[0] - 1)
    if uniform:
        v1, mu = n[s, a], n[s, a] / n[s2, a]
        for i in range(m):
            w[N1 * BLOCK + i], w[MU * BLOCK + i] = v1, mu
        return mu == 1.0
    for i in range(m):
        w[N1 * BLOCK + i], w[MU * BLOCK + i] = n[s, a + i], n[s, a + i] / n[s2, a + i]
    return False


@njit(**_JIT)
def _run_step(
    s: int, ints: Arr, floats: Arr, coef: Arr, high: Arr, n: Arr, uniform: bool, a: int, m: int, w: Arr, v: Arr
) -> bool:
    """Step s on the first m rays (from row a of the batch) of the block w, by the loop its
    surface needs, with the media indices n (S+1, B) (uniform: a column broadcast, passed
    to the loop as two numbers, else rows N1 and MU of w): an asphere in place, else into
    the block v. Returns whether the rays are now in v."""
    kind, j = ints[s, KIND], ints[s, INDEX]
    if kind == ASPHERE:
        _media(n, uniform, j, a, m, w)
        _step_asphere(s, ints, floats, coef, high, w, m)
        return False
    uni = uniform
    if uniform:
        n1, mu = n[j, a], n[j, a] / n[min(j + 1, n.shape[0] - 1), a]
    else:
        n1, mu = 0.0, 0.0
        _media(n, uniform, j, a, m, w)
    if ints[s, INTERACT] == 0 or (uni and mu == 1.0 and ints[s, MIRROR] == 0):
        if uni:
            _move_u(s, ints, floats, w, v, n1, mu)
        else:
            _move(s, ints, floats, w, v, n1, mu)
    elif kind == CONIC:
        if uni:
            _move_bend_unit_u(s, ints, floats, w, v, n1, mu)
        else:
            _move_bend_unit(s, ints, floats, w, v, n1, mu)
    elif uni:
        _move_bend_u(s, ints, floats, w, v, n1, mu)
    else:
        _move_bend(s, ints, floats, w, v, n1, mu)
    return True


def _array(dtype: Any, ndim: int, layout: Any) -> Any:
    """numba's array type of dtype, ndim and layout ("C" or "A")."""
    from numba import types

    return types.Array(dtype, ndim, layout)


def _trace_signature() -> Any:
    """trace_rays' one signature: the media indices of any layout ("A": a broadcast column,
    or rows of a larger array), every other array C-contiguous (lensim.optics.trace passes
    them so). Without it numba compiled a specialisation per layout met (four in one demo
    bank, each nearly as long to compile as the kernel's other functions together)."""
    from numba import types

    f64, i64, c2, c1 = types.float64, types.int64, _array(types.float64, 2, "C"), _array(types.float64, 1, "C")
    flags = _array(types.boolean, 1, "C")
    plan = (_array(i64, 2, "C"), c2, _array(f64, 3, "C"), _array(i64, 2, "C"))
    outs = (c2, c2, c1, flags, _array(types.int8, 1, "C"), _array(types.int16, 1, "C"))
    return types.void(c2, c2, c1, flags, _array(f64, 2, "A"), types.boolean, f64, *plan, *outs, c2)


@njit(_trace_signature(), **_JIT)
def trace_rays(
    p: Arr,
    d: Arr,
    o: Arr,
    v: Arr,
    n: Arr,
    uniform: bool,
    z0: float,
    ints: Arr,
    floats: Arr,
    coef: Arr,
    high: Arr,
    out_p: Arr,
    out_d: Arr,
    out_o: Arr,
    out_v: Arr,
    status: Arr,
    failed: Arr,
    work: Arr,
) -> None:
    """Trace rays p (B, 3) mm, d (B, 3), OPL o (B,) mm, validity v (B,) through the plan's
    steps (ints, floats, coef, high), media indices n (S+1, B) (uniform: a column
    broadcast), z0 the first step's vertex z (mm); write positions, directions, paths,
    validity, status codes and failure surfaces (-1: none) to the outputs; work: a work
    array of WORK_SHAPE (zeros: finite values past a ragged block's end). Rays invalid on
    input are written as given."""
    S, B = ints.shape[0], p.shape[0]
    z_last = floats[S - 1, Z_VERTEX]
    for a in range(0, B, BLOCK):
        m = min(BLOCK, B - a)
        w = work[0]
        for i in range(BLOCK):  # rays past m: copies of the first, not traced (CODE -1)
            j = a + i if i < m else a
            w[X * BLOCK + i], w[Y * BLOCK + i] = p[j, 0], p[j, 1]
            w[Z * BLOCK + i] = p[j, 2] - (z0 if v[j] else 0.0)
            w[L_ * BLOCK + i], w[M_ * BLOCK + i], w[N_ * BLOCK + i] = d[j, 0], d[j, 1], d[j, 2]
            w[OPL * BLOCK + i] = o[j]
            w[CODE * BLOCK + i] = OK if v[j] and i < m else -1.0  # -1: not traced
            w[WHERE * BLOCK + i] = -1.0
        cur = 0
        for s in range(S):
            if _run_step(s, ints, floats, coef, high, n, uniform, a, m, work[cur], work[1 - cur]):
                cur = 1 - cur
        w = work[cur]
        for i in range(m):
            live = w[CODE * BLOCK + i] == OK
            out_p[a + i, 0], out_p[a + i, 1] = w[X * BLOCK + i], w[Y * BLOCK + i]
            out_p[a + i, 2] = w[Z * BLOCK + i] + (z_last if live else 0.0)
            out_d[a + i, 0], out_d[a + i, 1], out_d[a + i, 2] = w[L_ * BLOCK + i], w[M_ * BLOCK + i], w[N_ * BLOCK + i]
            out_o[a + i], out_v[a + i] = w[OPL * BLOCK + i], live
            status[a + i], failed[a + i] = max(w[CODE * BLOCK + i], 0.0), w[WHERE * BLOCK + i]
