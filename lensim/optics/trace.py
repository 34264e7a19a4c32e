"""Batched real-ray tracing in float64 PyTorch.

Rays are tensors of any batch shape (typically wavelengths x fields x pupil samples).
Each surface: transfer to the vertex plane, exact conic intersection (Newton for
aspheres), clear-aperture / obscuration test, vector Snell refraction or reflection.
Tracing is sequential, as in Zemax: the root taken is always the one on the sheet of the
surface nearest its vertex plane, and across a zero or negative thickness in air next to
a stop or dummy surface (Lens.virtual_steps) the surface is met whatever the sign of the
distance along the ray; elsewhere a ray that would travel backwards misses the surface.
Failures (miss, total internal reflection, vignetting) become per-ray validity masks
with a status code and the surface where they happened; no NaN reaches the caller.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from lensim.optics.lens import Lens
from lensim.optics.pose import to_global, to_local
from lensim.optics.surfaces import Surface
from lensim.optics.trace_chunk import MISSED, OK, TIR, VIGNETTED, Live, Sink, chunk_indices, steps, trace_chunk

DTYPE = torch.float64

# status codes (per ray): OK, MISSED (the ray does not meet the surface, or travels backwards
# to it where that is not allowed), TIR (total internal reflection), VIGNETTED (blocked by a
# clear aperture or obscuration); defined with the fast tracer's loop
STATUS_TEXT = {
    OK: "ok",
    MISSED: "misses the surface",
    TIR: "is totally internally reflected",
    VIGNETTED: "is vignetted by the aperture",
}


@dataclass
class Rays:
    """A batch of rays: position (...,3) mm, unit direction (...,3), optical path length
    (...) mm accumulated from the reference (wavefront plane or object point), validity."""

    position: torch.Tensor
    direction: torch.Tensor
    opl: torch.Tensor
    valid: torch.Tensor
    entrance_xy: torch.Tensor | None = None  # (..., 2) mm: where real aiming launched them (lensim.optics.aiming)

    @property
    def shape(self) -> torch.Size:
        return self.opl.shape

    def select(self, index: slice | int) -> Rays:
        """The rays at `index` along the last batch axis (the pupil axis of (W, F, P) rays)."""
        idx = index if isinstance(index, slice) else slice(index, index + 1)
        return Rays(self.position[..., idx, :], self.direction[..., idx, :], self.opl[..., idx], self.valid[..., idx])


@dataclass
class TraceResult:
    """Rays after the last traced surface, why rays failed, and (optionally) every
    surface intersection (S, ..., 3) for plots and surface-by-surface checks."""

    rays: Rays
    status: torch.Tensor
    failed_at: torch.Tensor
    surface_positions: torch.Tensor | None = None

    def first_failure(self, mask: torch.Tensor | None = None) -> tuple[int, int] | None:
        """(status, surface index) of the first failed ray (within mask), or None."""
        bad = self.status != OK
        if mask is not None:
            bad = bad & mask
        if not bool(bad.any()):
            return None
        idx = torch.nonzero(bad.reshape(-1))[0, 0]
        return int(self.status.reshape(-1)[idx]), int(self.failed_at.reshape(-1)[idx])


def media_indices(lens: Lens, wavelength_um: torch.Tensor) -> torch.Tensor:
    """Index of each medium (N+1, *wavelength_um.shape) as a float64 tensor."""
    wl = wavelength_um.detach().cpu().numpy().astype(np.float64)
    n = lens.indices(wl.reshape(-1)).reshape((lens.num_surfaces + 1,) + wl.shape)
    return torch.as_tensor(n, dtype=DTYPE, device=wavelength_um.device)


#: numpy's dtype of each torch dtype host_empty() allocates
_NUMPY_DTYPES = {torch.float64: np.float64, torch.bool: np.bool_, torch.int8: np.int8, torch.int16: np.int16}


def host_empty(shape: tuple[int, ...], dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """torch.empty(shape), allocated on the CPU by numpy: numpy asks the kernel for
    transparent huge pages for large arrays (madvise), so that first writing a multi-MB
    output costs a page fault per 2 MB rather than per 4 kB (24 MB written in 3 ms against
    16-26 ms from torch.empty on the 2-core VM the benchmarks ran on). Elsewhere torch.empty."""
    if device.type != "cpu" or dtype not in _NUMPY_DTYPES:
        return torch.empty(shape, dtype=dtype, device=device)
    return torch.from_numpy(np.empty(shape, dtype=_NUMPY_DTYPES[dtype]))


def _refract(d: torch.Tensor, normal: torch.Tensor, n1: torch.Tensor, n2: torch.Tensor):
    """Vector Snell's law. Returns (new direction, TIR mask)."""
    cos_i = (d * normal).sum(-1)
    sign = torch.where(cos_i < 0, -1.0, 1.0).to(d.dtype)
    nrm = normal * sign.unsqueeze(-1)
    cos_i = cos_i * sign
    mu = n1 / n2
    sin2_t = mu * mu * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = torch.sqrt(torch.clamp(1.0 - sin2_t, min=0.0))
    new = mu.unsqueeze(-1) * d + (cos_t - mu * cos_i).unsqueeze(-1) * nrm
    new = new / torch.linalg.norm(new, dim=-1, keepdim=True)
    return new, tir


def _reflect(d: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    return d - 2.0 * (d * normal).sum(-1, keepdim=True) * normal


def trace_surface(
    surf: Surface,
    z_vertex: float | torch.Tensor,
    rays: Rays,
    n_before: torch.Tensor,
    n_after: torch.Tensor,
    allow_backwards: bool = False,
    apertures: bool = True,
    interact: bool = True,
):
    """Propagate rays to one surface and refract/reflect there.

    Returns (new rays, status code for rays that failed here (OK otherwise)).
    """
    pos, d = rays.position, rays.direction
    if surf.has_pose:
        local, d = to_local(surf.pose, z_vertex, pos, d)
    else:
        local = pos.clone()
        local[..., 2] = local[..., 2] - z_vertex
    dz = d[..., 2]
    ok_dir = dz.abs() > 1e-12
    safe_dz = torch.where(ok_dir, dz, torch.ones_like(dz))
    t0 = -local[..., 2] / safe_dz
    p1 = local + t0.unsqueeze(-1) * d
    geometry = surf.geometry
    t1, hit = geometry.intersect(p1, d)
    t = torch.where(ok_dir & hit, t0 + t1, torch.zeros_like(t0))
    hit = hit & ok_dir
    if not allow_backwards:
        hit = hit & (t > -1e-9)
    new_local = local + t.unsqueeze(-1) * d
    x, y = new_local[..., 0], new_local[..., 1]
    status = torch.where(rays.valid & ~hit, MISSED, OK)
    valid = rays.valid & hit
    if apertures:
        inside = surf.passes_aperture(x, y)
        status = torch.where(valid & ~inside, VIGNETTED, status)
        valid = valid & inside
    opl = rays.opl + n_before * t
    if interact:
        normal = geometry.normal(x, y)
        if surf.is_mirror:
            new_d = _reflect(d, normal)
        else:
            new_d, tir = _refract(d, normal, n_before, n_after)
            status = torch.where(valid & tir, TIR, status)
            valid = valid & ~tir
    else:
        new_d = d
    if surf.has_pose:
        new_pos, new_d = to_global(surf.pose, z_vertex, new_local, new_d)
    else:
        new_pos = new_local.clone()
        new_pos[..., 2] = new_pos[..., 2] + z_vertex
    # keep invalid rays finite and inert
    new_pos = torch.where(valid.unsqueeze(-1), new_pos, pos)
    new_d = torch.where(valid.unsqueeze(-1), new_d, rays.direction)
    opl = torch.where(valid, opl, rays.opl)
    return Rays(new_pos, new_d, opl, valid), status


def trace_reference(
    lens: Lens,
    rays: Rays,
    wavelength_um: torch.Tensor,
    start: int = 0,
    end: int | None = None,
    to_image: bool = True,
    record: bool = False,
    apertures: bool = True,
    indices: torch.Tensor | None = None,
) -> TraceResult:
    """trace(), one surface at a time over the whole batch with trace_surface(): the
    plain reference implementation (also used when gradients are needed)."""
    end = lens.num_surfaces if end is None else end
    n = media_indices(lens, wavelength_um) if indices is None else indices
    zv = [z if isinstance(z, torch.Tensor) else float(z) for z in lens.vertex_positions()]
    backwards = lens.virtual_steps()  # where a ray may travel backwards to the surface
    backwards[min(start, lens.num_surfaces)] = True  # rays start anywhere
    status = torch.zeros(rays.shape, dtype=torch.int8, device=rays.opl.device)
    failed_at = torch.full(rays.shape, -1, dtype=torch.int16, device=rays.opl.device)
    positions = []
    for i in range(start, end):
        rays, st = trace_surface(
            lens.surfaces[i],
            zv[i],
            rays,
            n[i],
            n[i + 1],
            allow_backwards=bool(backwards[i]),
            apertures=apertures,
        )
        newly = (st != OK) & (status == OK)
        status = torch.where(newly, st.to(status.dtype), status)
        failed_at = torch.where(newly, torch.as_tensor(i, dtype=failed_at.dtype), failed_at)
        if record:
            positions.append(rays.position)
    if to_image and end == lens.num_surfaces:
        image = Surface(clear_radius=lens.image_clear_radius, pose=(0.0, 0.0, *lens.image_tilt))
        rays, st = trace_surface(
            image,
            zv[-1],
            rays,
            n[-1],
            n[-1],
            allow_backwards=bool(backwards[end]),
            apertures=apertures,
            interact=False,
        )
        newly = (st != OK) & (status == OK)
        status = torch.where(newly, st.to(status.dtype), status)
        failed_at = torch.where(newly, torch.as_tensor(end, dtype=failed_at.dtype), failed_at)
        if record:
            positions.append(rays.position)
    surface_positions = torch.stack(positions) if record and positions else None
    return TraceResult(rays, status, failed_at, surface_positions)


# ---------------------------------------------------------------------------------------
# The fast path. Rays are flattened and cut into chunks of CHUNK_RAYS; each chunk runs
# through every surface as separate contiguous x, y, z, L, M, N, OPL vectors with in-place
# operations, so its working set stays in cache and no large temporaries are allocated
# (lensim.optics.trace_chunk: rays that fail leave the vectors). Chunks are smaller than
# torch's intra-op grain size, so each operation runs on one core, and the chunks run in
# parallel threads (torch releases the GIL inside its kernels), one per torch thread.
# Where it covers the steps (CPU tensors, the five kinds of surface, no recorded
# positions), a chunk runs lensim.optics.trace_fused's compiled kernel instead, one chunk
# per torch thread (the kernel releases the GIL), with the same results to rounding.

CHUNK_RAYS = 32767  # just below torch's GRAIN_SIZE (32768): each operation stays on one core
_EXECUTORS: dict[int, ThreadPoolExecutor] = {}


def _index_groups(
    n: torch.Tensor, wavelength_um: torch.Tensor, batch: torch.Size
) -> list[tuple[int, int, list | torch.Tensor]]:
    """Split the flattened batch into (start, stop, media indices) with one wavelength per
    block where the layout allows it and the blocks are long (indices as Python floats),
    else per-ray tensors: many short blocks (a pupil of a few thousand rays at each of 13
    wavelengths) would each be a chunk of its own, and a chunk's fixed cost per operation
    outweighs the per-ray index products."""
    S1 = n.shape[0]
    B = int(np.prod(batch)) if len(batch) else 1
    wl_shape = tuple(wavelength_um.shape)
    if wavelength_um.numel() == 1:
        return [(0, B, [float(v) for v in n.reshape(S1, -1)[:, 0]])]
    if len(wl_shape) <= len(batch):
        ws = (1,) * (len(batch) - len(wl_shape)) + wl_shape
        a = max(i for i, v in enumerate(ws) if v > 1)
        block = int(np.prod(batch[a + 1 :])) if a + 1 < len(batch) else 1
        if block >= CHUNK_RAYS // 4:  # each block's wavelength, also where leading axes broadcast
            cols = n.reshape(S1, -1).detach().cpu().numpy()
            which = np.broadcast_to(np.arange(cols.shape[1]).reshape(ws[: a + 1]), batch[: a + 1]).reshape(-1)
            return [(b * block, (b + 1) * block, [float(v) for v in cols[:, w]]) for b, w in enumerate(which)]
    full = n.reshape((S1,) + (1,) * (len(batch) - len(wl_shape)) + wl_shape).expand((S1,) + tuple(batch))
    return [(0, B, full.reshape(S1, B))]


class _ChunkSource:
    """Read [a, b) of a tensor's flattened batch without copying the whole batch: a flat
    view when the (expanded) tensor allows one, else one row of its last batch dimension at
    a time (rays expanded over wavelengths or fields), or, for short rows, one copy."""

    def __init__(self, t: torch.Tensor, batch: tuple, tail: tuple):
        e = t.expand(batch + tail)
        B = int(np.prod(batch)) if batch else 1
        self.rows = None
        try:
            self.flat = e.view((B,) + tail)
        except RuntimeError:
            if len(batch) > 1 and batch[-1] >= 1024:
                self.rows, self.e, self.lead = batch[-1], e, batch[:-1]
            else:
                self.flat = e.reshape((B,) + tail)

    def get(self, a: int, b: int) -> torch.Tensor:
        if self.rows is None:
            return self.flat[a:b]
        r, off = divmod(a, self.rows)
        return self.e[tuple(int(i) for i in np.unravel_index(r, self.lead))][off : off + (b - a)]


#: whether trace() runs the fused kernel where it covers the steps (tests compare it with
#: the torch chunk loop by turning it off)
USE_FUSED_KERNEL = True
#: the fused kernel's smallest task (rays): below it, handing a task to the thread pool
#: costs more than tracing it
FUSED_MIN_RAYS = 16384
#: tasks per torch thread for the fused kernel: several, so that where another process
#: holds a core, the thread on the free core takes more of them (one task per thread would
#: make the whole trace wait for the slowed one)
FUSED_TASKS_PER_THREAD = 8
#: the smallest trace (rays) that runs the fused kernel: the first in a process costs about
#: 1.5 s (numba's import and start, the kernel loaded from its cache), which a chief ray or
#: a ray fan (lens info, fans, the chief-ray checks) need not pay
FUSED_MIN_BATCH = 4096


#: set by without_fused_kernel (per thread and task: a context variable)
_FUSED_OFF: contextvars.ContextVar[bool] = contextvars.ContextVar("lensim_fused_off", default=False)


@contextlib.contextmanager
def without_fused_kernel() -> Iterator[None]:
    """Within this context (in this thread), no compiled kernel runs (trace()'s chunk loop and
    the aiming's torch launch instead; fused_kernels_allowed): for a
    one-off trace of a few thousand rays in a process that may trace nothing else (a bank's
    kernel size, looked up before its cache: the Cooke triplet's 0.06 s instead of 0.8 s,
    most of that numba's import and start). Same results to rounding."""
    token = _FUSED_OFF.set(True)
    try:
        yield
    finally:
        _FUSED_OFF.reset(token)


def fused_kernels_allowed() -> bool:
    """Whether compiled kernels may run here (the tracer's and the fused launch's,
    lensim.optics.aiming): USE_FUSED_KERNEL, and not within without_fused_kernel."""
    return USE_FUSED_KERNEL and not _FUSED_OFF.get()


def _fused_kernel(chunk_steps: list):
    """The fused kernel (lensim.optics.trace_fused) as fn(p, d, o, v, z0, n, *outputs) on
    torch tensors, or None where it does not cover the steps (or there are none). numba is
    imported here, on the first trace, not with lensim."""
    if not chunk_steps or not fused_kernels_allowed():
        return None
    from lensim.optics import trace_fused

    plan = trace_fused.plan_for(chunk_steps)
    if plan is None:
        return None
    arrays = (plan.ints, plan.floats, plan.coef, plan.high)

    def fn(p, d, o, v, z0, n, *outs) -> None:
        t = [np.ascontiguousarray(x.numpy()) for x in (p, d, o, v)]  # the kernel's one signature
        work = np.zeros(trace_fused.WORK_SHAPE)  # zeros: finite media rows past a ragged block's end
        uniform = n.strides[1] == 0
        trace_fused.trace_rays(*t, n, uniform, z0, *arrays, *(x.numpy() for x in outs), work)

    return fn


def _chunk_media(nv: list | torch.Tensor, a: int, b: int) -> np.ndarray:
    """The media indices of rows [a, b) as an (S+1, b - a) array for the fused kernel (a
    column broadcast over the rows where each medium has one index)."""
    if isinstance(nv, list):  # writable (not np.broadcast_to's read-only view): the kernel's one signature
        column = np.asarray(nv, dtype=np.float64)[:, None]
        return np.lib.stride_tricks.as_strided(column, (len(nv), b - a), (column.strides[0], 0), writeable=True)
    return nv[:, a:b].numpy()


def _executor(workers: int):
    if workers not in _EXECUTORS:
        _EXECUTORS[workers] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lensim-trace")
    return _EXECUTORS[workers]


def trace(
    lens: Lens,
    rays: Rays,
    wavelength_um: torch.Tensor,
    start: int = 0,
    end: int | None = None,
    to_image: bool = True,
    record: bool = False,
    apertures: bool = True,
    indices: torch.Tensor | None = None,
) -> TraceResult:
    """Trace rays (in the medium before surface `start`) through surfaces start..end-1 and,
    if to_image and end is the last surface, on to the image plane.

    Within :func:`without_fused_kernel` it never runs the compiled kernel.

    wavelength_um must broadcast against the rays' batch shape. Rays that fail stay finite
    and stop: one that misses a surface keeps its state from before that surface, one that
    is vignetted or totally internally reflected stops on the surface (direction unchanged).
    Runs the chunked fast path below (its fused kernel where it can); trace_reference() is
    the plain one (same results for valid rays to rounding) and is used when the rays or the
    lens's parameters (curvature, thickness, conic, aspheric terms, image defocus, surface
    poses given as tensors) require gradients, or a surface or the image plane is decentred
    or tilted (lensim.optics.pose).
    """
    end = lens.num_surfaces if end is None else end
    reference = lens.has_poses or lens.requires_grad
    if reference or any(t.requires_grad for t in (rays.position, rays.direction, rays.opl)):
        return trace_reference(lens, rays, wavelength_um, start, end, to_image, record, apertures, indices)
    n = media_indices(lens, wavelength_um) if indices is None else indices
    zv = lens.vertex_z()
    chunk_steps = steps(lens, start, end, to_image, apertures)
    batch = tuple(rays.shape)
    device = rays.opl.device
    B = int(np.prod(batch)) if len(batch) else 1
    P = batch[-1] if batch else 1
    sources = [
        _ChunkSource(t, batch, tail)
        for t, tail in ((rays.position, (3,)), (rays.direction, (3,)), (rays.opl, ()), (rays.valid, ()))
    ]
    by_rows = any(src.rows is not None for src in sources)
    out_pos, out_dir = host_empty((B, 3), DTYPE, device), host_empty((B, 3), DTYPE, device)
    out_opl, out_valid = host_empty((B,), DTYPE, device), host_empty((B,), torch.bool, device)
    status, failed_at = host_empty((B,), torch.int8, device), host_empty((B,), torch.int16, device)
    rec = host_empty((len(chunk_steps), B, 3), DTYPE, device) if record and chunk_steps else None
    z0 = float(zv[start]) if start < len(zv) else 0.0
    use_fused = device.type == "cpu" and rec is None and B >= FUSED_MIN_BATCH
    fused_fn = _fused_kernel(chunk_steps) if use_fused else None

    def run(task) -> None:
        a, b, nv = task
        p, d, o, v = (src.get(a, b) for src in sources)
        if fused_fn is not None:
            outs = (out_pos, out_dir, out_opl, out_valid, status, failed_at)
            return fused_fn(p, d, o, v, z0, _chunk_media(nv, a, b), *(t[a:b] for t in outs))
        rows = [rec[j, a:b] for j in range(len(chunk_steps))] if rec is not None else None
        sink = Sink(out_pos[a:b], out_dir[a:b], out_opl[a:b], out_valid[a:b], status[a:b], failed_at[a:b], rows)
        if not chunk_steps:
            sink.pos.copy_(p), sink.dirs.copy_(d), sink.opl.copy_(o), sink.valid.copy_(v)
            sink.status.zero_(), sink.failed_at.fill_(-1)
            return
        trace_chunk(chunk_steps, Live.start(p, d, o, v, z0, chunk_indices(nv, a, b), sink), sink)

    chunk = CHUNK_RAYS if device.type == "cpu" else max(B, 1)
    workers = torch.get_num_threads() if device.type == "cpu" else 1
    if fused_fn is not None:  # as many tasks for each thread, a few each where the batch allows
        per = min(FUSED_TASKS_PER_THREAD, B // (workers * FUSED_MIN_RAYS)) if workers > 1 else 0
        chunk = -(-B // (workers * per)) if per >= 1 else max(FUSED_MIN_RAYS, -(-B // workers))
    tasks = []
    for g0, g1, nv in _index_groups(n, wavelength_um, batch):
        a = g0
        while a < g1:  # chunks never cross a row of the last batch dimension when read by rows
            b = min(a + chunk, g1, (a // P + 1) * P if by_rows else g1)
            tasks.append((a, b, nv))  # a tensor nv spans the whole batch (g0 = 0)
            a = b
    pooled = len(tasks) >= 2 if fused_fn is not None else len(tasks) >= 4 * workers
    if workers > 1 and pooled:  # fewer chunks: the pool costs more than it gains
        for f in [_executor(workers).submit(run, t) for t in tasks]:
            f.result()
    else:
        for t in tasks:
            run(t)
    status = status.reshape(batch)
    failed_at = failed_at.reshape(batch)
    out = Rays(
        out_pos.reshape(tuple(batch) + (3,)),
        out_dir.reshape(tuple(batch) + (3,)),
        out_opl.reshape(batch),
        out_valid.reshape(batch),
    )
    surface_positions = rec.reshape((len(chunk_steps),) + tuple(batch) + (3,)) if rec is not None else None
    return TraceResult(out, status, failed_at, surface_positions)
