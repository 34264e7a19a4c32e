"""The fast tracer's inner loop (lensim.optics.trace.trace): one chunk of rays through
every surface, in place on separate contiguous x, y, z, L, M, N, OPL vectors.

Only rays still traced stay in the chunk (``Live``): a ray that misses a surface, is
vignetted or totally internally reflected is written to the chunk's outputs (``Sink``)
as it stands, with its status and surface, and dropped from the vectors. So every
vector op works on valid rays only, and the tests for a failure are reductions (the
smallest discriminant, the largest radius on an aperture, ...), a few microseconds for a
32k-ray chunk; a mask is made only where such a test says some ray fails. Each surface's
geometry (lensim.optics.geometry) meets and bends the rays with its kind's shortest exact
formulas (its chunk methods). Lengths in mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from lensim.optics.geometry import Geometry, narrow, sqrt_nonneg, with_sign_of
from lensim.optics.lens import Lens
from lensim.optics.surfaces import Surface

# status codes (per ray), re-exported by lensim.optics.trace
OK = 0
MISSED = 1  # the ray does not meet the surface (or travels backwards to it where that is not allowed)
TIR = 2  # total internal reflection
VIGNETTED = 3  # blocked by a clear aperture or obscuration
_BACKWARDS_MM = -1e-9  # a path shorter than this runs backwards


@dataclass(frozen=True)
class Step:
    """One surface (or the image plane) as the fast tracer sees it."""

    index: int  # surface index; lens.num_surfaces for the image plane
    shift: float  # mm from the previous vertex (subtracted from the local z)
    z_vertex: float  # mm, the vertex's global z
    geometry: Geometry
    surface: Surface
    r2_max: float | None
    r2_min: float | None
    interact: bool
    backwards_ok: bool  # the first step (rays start anywhere) and virtual steps (Lens.virtual_steps)


def steps(lens: Lens, start: int, end: int, to_image: bool, apertures: bool) -> list[Step]:
    """The steps of a trace through surfaces start..end-1 (and the image plane)."""
    zv = lens.vertex_z()
    virtual = lens.virtual_steps()
    out = []
    surfaces = [(i, lens.surfaces[i], True) for i in range(start, end)]
    if to_image and end == lens.num_surfaces:
        surfaces.append((end, Surface(clear_radius=lens.image_clear_radius), False))
    for j, (i, s, interact) in enumerate(surfaces):
        r2_max = s.clear_radius**2 * (1 + 1e-12) if (apertures and s.clear_radius is not None) else None
        r2_min = s.obscuration_radius**2 if (apertures and s.obscuration_radius is not None) else None
        shift = 0.0 if j == 0 else float(zv[i] - zv[surfaces[j - 1][0]])
        out.append(Step(i, shift, float(zv[i]), s.geometry, s, r2_max, r2_min, interact, j == 0 or bool(virtual[i])))
    return out


@dataclass
class Sink:
    """Where the rays of one chunk end (views of rows [a, b) of trace()'s outputs):
    positions and directions (n, 3), optical paths (n,), validity, status codes, failure
    surfaces, and the recorded surface positions (one (n, 3) view per step) or None."""

    pos: torch.Tensor
    dirs: torch.Tensor
    opl: torch.Tensor
    valid: torch.Tensor
    status: torch.Tensor
    failed_at: torch.Tensor
    rec: list[torch.Tensor] | None


class Live:
    """The rays of a chunk still traced: x, y, z (z local to the current step's vertex),
    L, M, N and opl as contiguous vectors; n, the index of every medium (floats, or
    per-ray tensors); ids, each ray's row in the sink (None: rows 0..n-1).

    A ray that fails is written to the sink and leaves: while few have, it stays in the
    vectors as a copy of a live ray (dead: a mask of those, rows: their rows in the sink),
    traced along for nothing, which costs less than compacting 32k-ray vectors; once more
    than COMPACT_SHARE of the rays are dead (or surface positions are recorded), the
    vectors are compacted."""

    COMPACT_SHARE = 0.25

    def __init__(self, comps: list[torch.Tensor], n: list, ids: torch.Tensor | None) -> None:
        self.x, self.y, self.z, self.L, self.M, self.N, self.opl = comps
        self.n, self.ids = n, ids
        self.dead: torch.Tensor | None = None
        self.dead_count = 0
        self.dead_rows: list[torch.Tensor] = []

    @classmethod
    def start(
        cls, p: torch.Tensor, d: torch.Tensor, o: torch.Tensor, v: torch.Tensor, z0: float, n: list, sink: Sink
    ) -> Live:
        """The valid rays of positions p, directions d (n, 3), paths o and validity v, z made
        local to z0; rays invalid on input go to the sink unchanged (status OK)."""
        sink.status.zero_()
        sink.failed_at.fill_(-1)
        sink.valid.zero_()
        if bool(v.all()):
            comps = [p[:, 0].clone(), p[:, 1].clone(), p[:, 2] - z0, d[:, 0].clone(), d[:, 1].clone()]
            return cls(comps + [d[:, 2].clone(), o.clone()], n, None)
        bad, keep = torch.nonzero(~v)[:, 0], torch.nonzero(v)[:, 0]
        sink.pos.index_copy_(0, bad, p[bad])
        sink.dirs.index_copy_(0, bad, d[bad])
        sink.opl.index_copy_(0, bad, o[bad])
        for row in sink.rec or []:
            row.index_copy_(0, bad, p[bad])
        pk, dk = p[keep], d[keep]
        comps = [pk[:, 0].clone(), pk[:, 1].clone(), pk[:, 2] - z0, dk[:, 0].clone(), dk[:, 1].clone()]
        nk = [v_ if isinstance(v_, float) else v_[keep] for v_ in n]
        return cls(comps + [dk[:, 2].clone(), o[keep]], nk, keep)

    def __len__(self) -> int:
        return self.x.shape[0] - self.dead_count

    def _vectors(self) -> list[torch.Tensor]:
        return [self.x, self.y, self.z, self.L, self.M, self.N, self.opl]

    def xyz(self, z_vertex: float) -> torch.Tensor:
        """Global positions (n, 3) of the rays."""
        return torch.stack([self.x, self.y, self.z + z_vertex], -1)

    def drop(self, lost: torch.Tensor, code: int, st: Step, sink: Sink, first_row: int, extra: Sequence = ()) -> list:
        """Write the rays where `lost` holds to the sink as they stand, failed with `code` on
        step st (recorded positions from step first_row on), and remove them from the live
        rays, with their entries of every vector in `extra` (returned updated)."""
        new = lost if self.dead is None else lost & ~self.dead
        idx = torch.nonzero(new)[:, 0]
        rows = idx if self.ids is None else self.ids[idx]
        pos = torch.stack([self.x[idx], self.y[idx], self.z[idx] + st.z_vertex], -1)
        sink.pos.index_copy_(0, rows, pos)
        sink.dirs.index_copy_(0, rows, torch.stack([self.L[idx], self.M[idx], self.N[idx]], -1))
        sink.opl.index_copy_(0, rows, self.opl[idx])
        sink.status.index_fill_(0, rows, code)
        sink.failed_at.index_fill_(0, rows, st.index)
        for row in (sink.rec or [])[first_row:]:
            row.index_copy_(0, rows, pos)
        gone = lost if self.dead is None else lost | self.dead
        count = self.dead_count + idx.shape[0]
        if sink.rec is not None or count > self.COMPACT_SHARE * self.x.shape[0]:
            return self._compact(gone, extra)
        every = torch.nonzero(lost)[:, 0] if self.dead is not None else idx
        donor = int(torch.argmin(lost.to(torch.uint8)))  # a ray that stays
        for v in [*self._vectors(), *self.n, *extra]:
            if isinstance(v, torch.Tensor):
                v.index_fill_(0, every, float(v[donor]))
        self.dead, self.dead_count = gone, count
        self.dead_rows.append(rows)
        return list(extra)

    def _compact(self, gone: torch.Tensor, extra: Sequence) -> list:
        """Remove the rays where `gone` holds from the vectors, the media indices and extra."""
        keep = torch.nonzero(~gone)[:, 0]
        self.ids = keep if self.ids is None else self.ids[keep]
        self.x, self.y, self.z, self.L, self.M, self.N, self.opl = (c[keep] for c in self._vectors())
        self.n = [v if isinstance(v, float) else v[keep] for v in self.n]
        self.dead, self.dead_count = None, 0
        self.dead_rows = []  # written to the sink already; their copies are gone
        return [e if isinstance(e, float) else e[keep] for e in extra]

    def finish(self, sink: Sink, z_vertex: float) -> None:
        """Write the rays that came through to the sink (z_vertex: the last step's vertex z)."""
        rows = torch.cat(self.dead_rows) if self.dead_rows else None
        if rows is not None:  # the copies of live rays in their place are written over them below
            saved = sink.pos[rows], sink.dirs[rows], sink.opl[rows]
        if self.ids is None:
            for k, c in enumerate((self.x, self.y)):
                sink.pos[:, k].copy_(c)
            torch.add(self.z, z_vertex, out=sink.pos[:, 2])
            for k, c in enumerate((self.L, self.M, self.N)):
                sink.dirs[:, k].copy_(c)
            sink.opl.copy_(self.opl)
            sink.valid.fill_(True)
        else:
            sink.pos.index_copy_(0, self.ids, self.xyz(z_vertex))
            sink.dirs.index_copy_(0, self.ids, torch.stack([self.L, self.M, self.N], -1))
            sink.opl.index_copy_(0, self.ids, self.opl)
            sink.valid.index_fill_(0, self.ids, True)
        if rows is not None:
            for out, v in zip((sink.pos, sink.dirs, sink.opl), saved, strict=True):
                out.index_copy_(0, rows, v)
            sink.valid.index_fill_(0, rows, False)

    def record(self, row: torch.Tensor, z_vertex: float) -> None:
        """Store the rays' global positions in a recorded row (n, 3) of the sink (no dead
        copies: recording compacts)."""
        if self.ids is None:
            row[:, 0].copy_(self.x)
            row[:, 1].copy_(self.y)
            torch.add(self.z, z_vertex, out=row[:, 2])
        else:
            row.index_copy_(0, self.ids, self.xyz(z_vertex))


def trace_chunk(chunk_steps: list[Step], live: Live, sink: Sink) -> None:
    """Trace the live rays of one chunk through every step and write them to the sink."""
    for j, st in enumerate(chunk_steps):
        if not len(live):
            return
        _move_to_surface(st, live, sink, j)
        if not len(live):
            return
        if sink.rec is not None:
            live.record(sink.rec[j], st.z_vertex)
        if not st.interact:
            continue
        if st.surface.is_mirror:
            _reflect(st, live)
        else:
            _refract(st, live, sink, j)
    live.finish(sink, chunk_steps[-1].z_vertex)


def _move_to_surface(st: Step, live: Live, sink: Sink, j: int) -> None:
    """Carry the live rays to surface st (in place): intersection, optical path in the
    medium before it, clear aperture and obscuration; rays that fail are dropped."""
    if st.shift:
        live.z.sub_(st.shift)
    t, hit = st.geometry.hit_chunk(live.x, live.y, live.z, live.L, live.M, live.N)
    if not st.backwards_ok and not float(t.amin()) > _BACKWARDS_MM:
        hit = narrow(hit, t > _BACKWARDS_MM)
    if hit is not None and not bool(hit.all()):
        (t,) = live.drop(~hit, MISSED, st, sink, j, [t])
        if not len(live):
            return
    x, y, z, n1 = live.x, live.y, live.z, live.n[st.index]
    x.addcmul_(t, live.L)
    y.addcmul_(t, live.M)
    z.addcmul_(t, live.N)
    if isinstance(n1, torch.Tensor):
        live.opl.addcmul_(t, n1)
    else:
        live.opl.add_(t, alpha=n1)
    if st.r2_max is None and st.r2_min is None:
        return
    rr = x * x
    rr.addcmul_(y, y)
    out = None
    if st.r2_max is not None and not float(rr.amax()) <= st.r2_max:
        out = rr > st.r2_max
    if st.r2_min is not None and not float(rr.amin()) >= st.r2_min:
        out = rr < st.r2_min if out is None else out.logical_or_(rr < st.r2_min)
    if out is not None and bool(out.any()):
        live.drop(out, VIGNETTED, st, sink, j)


def _reflect(st: Step, live: Live) -> None:
    """Mirror reflection of the live rays' directions at surface st (in place)."""
    L, M, N = live.L, live.M, live.N
    nrm = st.geometry.normal_chunk(live.x, live.y, live.z)
    if nrm is None:
        N.neg_()
        return
    nx, ny, nz = nrm
    dn = L * nx
    dn.addcmul_(M, ny).addcmul_(N, nz).mul_(-2.0)
    L.addcmul_(dn, nx)
    M.addcmul_(dn, ny)
    N.addcmul_(dn, nz)


def _refract(st: Step, live: Live, sink: Sink, j: int) -> None:
    """Snell refraction of the live rays' directions at surface st (in place); totally
    internally reflected rays are dropped, on the surface with their incoming direction."""
    n1, n2 = live.n[st.index], live.n[st.index + 1]
    scalar = not isinstance(n1, torch.Tensor) and not isinstance(n2, torch.Tensor)
    if scalar and n1 == n2:
        return  # no refraction (air to air, a dummy or stop surface)
    mu = n1 / n2
    cos_i, nrm = st.geometry.cos_incidence_chunk(live.x, live.y, live.z, live.L, live.M, live.N)
    ct = cos_i * cos_i
    if scalar:
        ct.mul_(mu * mu).add_(1.0 - mu * mu)  # >= 0 where n1 <= n2
    else:
        mu2 = mu * mu
        ct.mul_(mu2).sub_(mu2).add_(1.0)
    low = 1.0 - mu * mu if scalar and mu <= 1.0 else float(ct.amin())  # TIR needs n1 > n2
    if not low >= 0.0:
        tir = ct < 0.0
        if bool(tir.any()):
            kept = live.drop(tir, TIR, st, sink, j + 1, [ct, cos_i, mu, *(nrm or ())])
            ct, cos_i, mu = kept[:3]
            nrm = (kept[3], kept[4], kept[5]) if nrm is not None else None
            if not len(live):
                return
        ct.clamp_(min=0.0)
    kk = with_sign_of(sqrt_nonneg(ct, positive=low > 1e-300), cos_i).sub_(cos_i.mul_(mu))
    live.L.mul_(mu)
    live.M.mul_(mu)
    live.N.mul_(mu)
    st.geometry.bend_chunk(kk, nrm, live.x, live.y, live.z, live.L, live.M, live.N)


def chunk_indices(n: list | torch.Tensor, a: int, b: int) -> list:
    """The media indices of rows [a, b) of the batch: floats as they are, or each medium's
    per-ray tensor (n: (S+1, B)) sliced."""
    return n if isinstance(n, list) else [n[i, a:b] for i in range(n.shape[0])]
