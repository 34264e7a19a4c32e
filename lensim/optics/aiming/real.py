"""Real ray aiming: the rays that cross the real stop at given points.

The unknown of each ray is the point (x, y) where it crosses the paraxial entrance-pupil
plane (lensim.optics.aiming.launch); the target is the point (px, py) * paraxial stop
semi-diameter on the stop surface (as Zemax's ray aiming does). Rays are traced to the
stop without apertures (a clear aperture or an obscuration vignettes a ray, it does not
move the ray's aim).

1. Chief rays, one per field and wavelength, by damped Newton iteration from the centre
   of the paraxial entrance pupil. A step that lands on a ray that misses a surface or
   is totally internally reflected is halved until it does not (backtracking).
2. A chief ray whose start or iteration fails (wide angles: the real entrance pupil moves
   far from the paraxial one and the paraxial guess misses the front lens) is searched
   for along the meridian: rays across the whole first surface are traced to the stop,
   and the sign changes of their stop height bracket the chief ray (the bracket nearest
   the paraxial pupil centre is taken); Newton finishes from there.
3. Every other pupil point starts from the chief ray's linear model of the pupil (the
   chief ray plus the inverse of its Jacobian times the target): near-exact for a real
   pupil that is shifted, scaled or stretched, as wide-angle pupils are.
4. A pupil ray that fails from there is tried from the paraxial pupil point, and one that
   still fails is continued from the chief ray: its target is walked out in
   CONTINUATION_STEPS steps, each solved from the previous solution. Rays that do not
   exist (they miss a surface before the stop whatever their aim) end unconverged.

Shapes: fields F, wavelengths W (tensor (W, 1, 1)), pupil points P; lengths in mm.
"""

from __future__ import annotations

import math

import torch

from lensim.optics.aiming.launch import launch_at, object_rays
from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData
from lensim.optics.trace import DTYPE, trace

AIM_TOL_MM = 1e-10
AIM_MAX_ITER = 25
BACKTRACK_HALVINGS = 8
SEARCH_SAMPLES = 4097  # rays across the first surface in the meridian search (a steep beam is narrow)
CONTINUATION_STEPS = 4
STALL_ITERATIONS = 5  # Newton gives a ray up after this many full steps without a 10 % gain


class _Problem:
    """One batch of aiming: launch fields, wavelengths and media indices that broadcast
    against the rays' batch shape, and the paraxial data."""

    def __init__(self, lens: Lens, field: torch.Tensor, wl: torch.Tensor, n: torch.Tensor, para: ParaxialData) -> None:
        self.lens, self.field, self.wl, self.n, self.para = lens, field, wl, n, para
        self.scale = max(para.epd_mm, 1e-3)
        self.tol = AIM_TOL_MM * max(1.0, para.stop_semi_diameter_mm)

    def stop_xy(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where the rays through entrance-plane points x (..., 2) cross the stop (..., 2),
        and whether they reach it."""
        pos, dirs = launch_at(self.lens, self.field, x, self.para.entrance_pupil_z_mm)
        rays = object_rays(self.lens, pos, dirs, self.n[0])
        res = trace(
            self.lens, rays, self.wl, end=self.lens.stop_index + 1, to_image=False, apertures=False, indices=self.n
        )
        return res.rays.position[..., :2], res.rays.valid

    def probe(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """stop_xy at x (..., 2) and its Jacobian d(stop xy)/d(x) (..., 2, 2) by forward
        differences, from one trace of x and its two probes (a small batch costs about as
        much as a single ray): (stop xy, reached, Jacobian, both probes reached)."""
        h = 1e-7 * self.scale
        pts = torch.stack([x, x, x])
        pts[1, ..., 0] += h
        pts[2, ..., 1] += h
        s, v = self.stop_xy(pts)
        return s[0], v[0], torch.stack([(s[1] - s[0]) / h, (s[2] - s[0]) / h], -1), v[1] & v[2]


def _solve2(jac: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """jac^-1 r for (..., 2, 2) and (..., 2), and where jac is invertible."""
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    ok = det.abs() > 1e-300
    det = torch.where(ok, det, torch.ones_like(det))
    sx = (jac[..., 1, 1] * r[..., 0] - jac[..., 0, 1] * r[..., 1]) / det
    sy = (-jac[..., 1, 0] * r[..., 0] + jac[..., 0, 0] * r[..., 1]) / det
    return torch.stack([sx, sy], -1), ok


def _newton(pb: _Problem, x: torch.Tensor, target: torch.Tensor, max_iter: int = AIM_MAX_ITER):
    """Damped Newton iteration with backtracking on entrance-plane points x (..., 2) so
    each ray meets the stop at target (broadcast to x). A ray within the tolerance is
    polished while its miss still shrinks (so the same ray aimed from two starts agrees
    to rounding); one whose full steps gain nothing STALL_ITERATIONS times is given up (a
    target out of its reach). Once fewer than a quarter of the rays still move, only those
    are traced. Returns (x, converged)."""
    s0, v0, jac, probes_ok = pb.probe(x)  # each trace probes the Jacobian at its points too
    miss = (s0 - target).abs().amax(-1)
    final = torch.zeros_like(v0)  # polished to rounding, or no step keeps the ray
    stall = torch.zeros(v0.shape, dtype=torch.int16, device=v0.device)  # iterations without progress
    for it in range(max_iter):
        final = final | (v0 & (miss < pb.tol * 1e-4))
        todo = v0 & ~final
        if not bool(todo.any()):
            break
        if todo.numel() >= 256 and int(todo.sum()) * 4 < todo.numel():  # a few stragglers: trace only them
            sub, idx = _subset(pb, todo)
            xs, ok = _newton(sub, x[idx], target.expand(todo.shape + (2,))[idx], max_iter - it)
            x, conv = x.clone(), v0 & (miss < pb.tol)
            x[idx], conv[idx] = xs, ok
            return x, conv
        step, inv_ok = _solve2(jac, s0 - target)
        norm = torch.linalg.norm(step, dim=-1, keepdim=True)
        limit = 0.5 * pb.scale  # far from the solution the map can be strongly non-linear
        clipped = (norm > limit).squeeze(-1)
        step = torch.where(norm > limit, step * limit / norm, step)
        active = v0 & probes_ok & inv_ok & ~final
        if not bool(active.any()):
            break
        cand = torch.where(active.unsqueeze(-1), x - step, x)
        sc, vc, jac_c, ok_c = pb.probe(cand)
        lost = active & ~vc
        if bool(lost.any()):
            cand, sc, vc, jac_c, ok_c = _backtrack(pb, x, step, lost, (cand, sc, vc, jac_c, ok_c))
        miss_c = (sc - target).abs().amax(-1)
        accept = active & vc & ((miss_c < miss) | (miss >= pb.tol))  # within tolerance: only improvements
        progress = accept & (clipped | (miss_c < 0.9 * miss))  # a damped step is progress
        stall = torch.where(progress, torch.zeros_like(stall), stall + 1)
        final = final | (active & ~accept) | (stall >= STALL_ITERATIONS)  # a target out of reach: give up
        x = torch.where(accept.unsqueeze(-1), cand, x)
        s0 = torch.where(accept.unsqueeze(-1), sc, s0)
        jac = torch.where(accept.unsqueeze(-1).unsqueeze(-1), jac_c, jac)
        probes_ok = torch.where(accept, ok_c, probes_ok)
        miss = torch.where(accept, miss_c, miss)
    return x, v0 & (miss < pb.tol)


def _backtrack(
    pb: _Problem,
    x: torch.Tensor,
    step: torch.Tensor,
    lost: torch.Tensor,
    probed: tuple[torch.Tensor, ...],
) -> tuple[torch.Tensor, ...]:
    """Halve the steps of the rays that a full step lost (lost: a mask over x's batch) until
    their rays trace again, at most BACKTRACK_HALVINGS times, tracing only those rays.
    probed: the full steps' (candidates, stop xy, reached, Jacobian, probes reached);
    returns updated copies, the lost rays' taken at their shortened steps."""
    sub, idx = _subset(pb, lost)
    xs, ss = x[idx], step[idx]
    found = torch.zeros(xs.shape[:-1], dtype=torch.bool, device=x.device)
    for _ in range(BACKTRACK_HALVINGS):
        ss = torch.where(found.unsqueeze(-1), ss, 0.5 * ss)
        _, v_try = sub.stop_xy(xs - ss)
        found = found | v_try
        if bool(found.all()):
            break
    cand, sc, vc, jac, ok = (t.clone() for t in probed)
    cand[idx] = torch.where(found.unsqueeze(-1), xs - ss, cand[idx])
    s_new, v_new, jac_new, ok_new = sub.probe(cand[idx])  # the Jacobian at the shortened steps
    sc[idx] = torch.where(found.unsqueeze(-1), s_new, sc[idx])
    vc[idx] = found & v_new
    jac[idx] = jac_new
    ok[idx] = ok_new
    return cand, sc, vc, jac, ok


def _first_surface_reach(lens: Lens, para: ParaxialData) -> float:
    """Distance (mm) from the first vertex to the rim of the part of the first surface
    searched for chief rays: its size when the file gives one, else a generous multiple
    of the pupil and track, never beyond where the conic is defined."""
    s = lens.surfaces[0]
    domain = s.geometry.max_radius
    generous = max(4.0 * para.epd_mm, 4.0 * para.stop_semi_diameter_mm, abs(lens.total_track))
    rim = min(max(s.clear_radius or 0.0, s.semi_diameter or 0.0, generous), domain * (1.0 - 1e-9))
    sag = s.geometry.sag_at(rim)
    return math.hypot(rim, sag)


def _meridian_points(lens: Lens, field: torch.Tensor, offsets: torch.Tensor, z_ep: float) -> torch.Tensor:
    """Entrance-plane y (mm), (K, S), of the meridional rays of launch fields `field` (K, 1)
    that pass the first vertex at perpendicular distances `offsets` (S,) mm. Every ray that
    meets the first surface within a distance D of its vertex has an offset in [-D, D],
    however steep it is."""
    if lens.infinite_object:
        a = torch.deg2rad(field)
        return offsets / torch.cos(a) + z_ep * torch.tan(a)
    d = lens.object_distance
    h = -(d + z_ep) * torch.tan(torch.deg2rad(field)) if lens.launch_field_type == "angle" else field
    norm = torch.sqrt(h * h + d * d)
    py, pz = offsets * d / norm, offsets * h / norm  # the point offset across the line object -> vertex
    return h + (py - h) * (z_ep + d) / (pz + d)


def _search_meridian(pb: _Problem) -> tuple[torch.Tensor, torch.Tensor]:
    """Chief rays (K, 2) of the K (field, wavelength) pairs of pb (field, wl: (K,)) found
    by scanning the meridian across the first surface and finishing with Newton."""
    K = pb.field.shape[0]
    reach = _first_surface_reach(pb.lens, pb.para)
    offsets = torch.linspace(-reach, reach, SEARCH_SAMPLES, dtype=DTYPE, device=pb.field.device)
    ys = _meridian_points(pb.lens, pb.field.reshape(K, 1), offsets, pb.para.entrance_pupil_z_mm)  # (K, S)
    scan = _Problem(pb.lens, pb.field.reshape(K, 1), pb.wl.reshape(K, 1), pb.n.reshape(-1, K, 1), pb.para)
    pts = torch.stack([torch.zeros_like(ys), ys], -1)
    stop_y, ok = scan.stop_xy(pts)
    sy = stop_y[..., 1]
    bracket = ok[:, :-1] & ok[:, 1:] & (sy[:, :-1] * sy[:, 1:] <= 0)
    dy = sy[:, 1:] - sy[:, :-1]
    frac = torch.where(dy != 0, -sy[:, :-1] / torch.where(dy != 0, dy, torch.ones_like(dy)), torch.zeros_like(dy))
    roots = ys[:, :-1] + frac.clamp(0.0, 1.0) * (ys[:, 1:] - ys[:, :-1])
    far = torch.full_like(roots, math.inf)
    pick = torch.where(bracket, roots.abs(), far).argmin(-1, keepdim=True)  # nearest the paraxial pupil centre
    start_y = roots.gather(1, pick)[:, 0]
    # no bracket: the traced ray that comes nearest the stop centre
    nearest = ys.gather(1, torch.where(ok, sy.abs(), torch.full_like(sy, math.inf)).argmin(-1, keepdim=True))[:, 0]
    start_y = torch.where(bracket.any(-1), start_y, nearest)
    start = torch.stack([torch.zeros_like(start_y), start_y], -1)
    x, conv = _newton(pb, start, torch.zeros(2, dtype=DTYPE, device=start.device))
    return x, conv & ok.any(-1)


def _aim_chief(
    lens: Lens, field: torch.Tensor, wl: torch.Tensor, n: torch.Tensor, para: ParaxialData
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entrance-plane points (W, F, 1, 2) of the real chief rays and where they converged."""
    W, F = wl.shape[0], field.shape[0]
    pb = _Problem(lens, field.reshape(1, F, 1), wl, n, para)
    x = torch.zeros(W, F, 1, 2, dtype=DTYPE, device=field.device)
    x, ok = _newton(pb, x, torch.zeros(2, dtype=DTYPE, device=field.device))
    if bool(ok.all()):
        return x, ok
    wi, fi, _ = torch.nonzero(~ok, as_tuple=True)
    lost = _Problem(lens, field[fi], wl.reshape(-1)[wi], n.reshape(n.shape[0], -1)[:, wi], para)
    found, found_ok = _search_meridian(lost)
    x[wi, fi, 0] = found
    ok[wi, fi, 0] = found_ok
    return x, ok


def _subset(pb: _Problem, todo: torch.Tensor) -> tuple[_Problem, tuple[torch.Tensor, ...]]:
    """The rays where todo (W, F, P) is True as a flat problem (K rays), and their indices."""
    idx = torch.nonzero(todo, as_tuple=True)
    n = pb.n.expand((pb.n.shape[0],) + todo.shape)[(slice(None),) + idx]
    return _Problem(pb.lens, pb.field.expand(todo.shape)[idx], pb.wl.expand(todo.shape)[idx], n, pb.para), idx


def _retry_from(
    pb: _Problem, x: torch.Tensor, conv: torch.Tensor, todo: torch.Tensor, start: torch.Tensor, target: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Newton again for the rays where todo (W, F, P) holds, from start (W, F, P, 2); the
    ones that converge replace x. Returns updated copies of (x, conv)."""
    if not bool(todo.any()):
        return x, conv
    sub, idx = _subset(pb, todo)
    xs, ok = _newton(sub, start[idx], target.expand(todo.shape + (2,))[idx])
    return _write_back(x, conv, idx, xs, ok)


def _write_back(
    x: torch.Tensor, conv: torch.Tensor, idx: tuple[torch.Tensor, ...], xs: torch.Tensor, ok: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Copies of (x, conv) with the rays at idx that converged again (ok) replaced by xs, and
    their convergence flags set to ok."""
    x, conv = x.clone(), conv.clone()
    x[idx] = torch.where(ok.unsqueeze(-1), xs, x[idx])
    conv[idx] = ok
    return x, conv


def _continue_from_chief(
    pb: _Problem,
    x: torch.Tensor,
    conv: torch.Tensor,
    chief: torch.Tensor,
    chief_ok: torch.Tensor,
    jac: torch.Tensor,
    target: torch.Tensor,
):
    """Walk the targets of the unconverged rays (whose chief ray converged) out from the
    chief ray in CONTINUATION_STEPS steps, dropping a ray at the first step it fails.
    x, conv: (W, F, P, ...); returns updated copies."""
    todo = ~conv & chief_ok
    if not bool(todo.any()):
        return x, conv
    sub, idx = _subset(pb, todo)
    wi, fi = idx[0], idx[1]
    goal = target.expand(todo.shape + (2,))[idx]
    d, _ = _solve2(jac[wi, fi, 0], goal / CONTINUATION_STEPS)  # the linear model's step per stage
    xk, alive = chief[wi, fi, 0], torch.ones(wi.shape, dtype=torch.bool, device=x.device)
    for k in range(1, CONTINUATION_STEPS + 1):
        live = torch.nonzero(alive)[:, 0]
        part = _Problem(pb.lens, sub.field[live], sub.wl[live], sub.n[:, live], pb.para)
        xs, ok = _newton(part, xk[live] + d[live], goal[live] * (k / CONTINUATION_STEPS))
        xk = xk.index_copy(0, live, xs)
        alive = alive.index_copy(0, live, ok)
        if not bool(alive.any()):
            break
    return _write_back(x, conv, idx, xk, alive)


def aim_real(
    lens: Lens,
    field: torch.Tensor,
    pupil: torch.Tensor,
    wl: torch.Tensor,
    n: torch.Tensor,
    para: ParaxialData,
    start: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entrance-plane points (W, F, P, 2) of the rays of launch fields field (F,) and
    wavelengths wl (W, 1, 1) (media indices n, (N+1, W, 1, 1)) that cross the real stop at
    pupil (P, 2) x the paraxial stop semi-diameter, and where the aim converged.

    start: a nearby solution (broadcasting to (W, F, P, 2)), such as the same rays' aim at a
    neighbouring wavelength: Newton starts there, and only when a ray does not converge
    from it are all the rays aimed from scratch (steps 1-4 above). Newton polishes every
    ray to rounding, so the result does not depend on the start."""
    W, F, P = wl.shape[0], field.shape[0], pupil.shape[0]
    target = pupil.to(DTYPE) * para.stop_semi_diameter_mm  # (P, 2)
    pb = _Problem(lens, field.reshape(1, F, 1), wl, n, para)
    if start is not None:
        x, conv = _newton(pb, start.to(DTYPE).expand(W, F, P, 2), target)
        if bool(conv.all()):
            return x, conv
    chief, chief_ok = _aim_chief(lens, field, wl, n, para)
    _, _, jac, jac_ok = pb.probe(chief)
    model, inv_ok = _solve2(jac, target.reshape(1, 1, P, 2))  # the chief ray's linear pupil model
    use_model = (chief_ok & jac_ok & inv_ok).expand(W, F, P)
    paraxial = (pupil.to(DTYPE) * (para.epd_mm / 2.0)).expand(W, F, P, 2)
    x, conv = _newton(pb, torch.where(use_model.unsqueeze(-1), chief + model, paraxial), target)
    x, conv = _retry_from(pb, x, conv, ~conv & use_model, paraxial, target)  # the paraxial start, as before
    return _continue_from_chief(pb, x, conv, chief, chief_ok & jac_ok, jac, target)
