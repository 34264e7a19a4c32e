"""Coherent (Huygens) superposition of the exit-pupil wavelets on the image plane.

The paper's Eqs. 5-9: every ray on the exit-pupil reference sphere is a secondary
spherical wavelet; the complex amplitude at an image-plane point x is

    E(x) = (n'/lambda) * sum_j sqrt(P_j dS_j) * K_j * exp(i k (l_j + n' r_j)) / r_j,

with l_j the ray's optical path to the sphere, r_j = |x - Q_j|, dS_j the sphere area the
ray stands for, P_j its power, k = 2 pi / lambda and K_j = (cos(nu, r) + cos(nu, D_j)) / 2
the obliquity factor (nu: sphere normal towards its centre, D_j: ray direction). I = |E|^2
times the sample area is the energy per sample, so the PSF sums to the transmitted
fraction (up to what falls outside the window).

Fast evaluation: the image window is cut into tiles; in each tile the distance is
expanded about the tile centre, r = r_t + u.e + (|e|^2 - (u.e)^2) / (2 r_t), and the
cross term u_x u_y e_x e_y / r_t is the only one dropped, which makes the sum separable
in x and y: one complex matrix product per tile, done as one real matrix product of
[cos, sin] blocks (:func:`_real_blocks`). The tile size is chosen so that the dropped
phase stays below `max_phase_error` radians, and the window is cut into the fewest tiles
of that size with the least padding; tile size 1 is the exact direct sum. The rays are
summed in chunks whose phase blocks stay near 8 MB (in cache).

Symmetry: for a field on the y axis of a rotationally symmetric lens (every bank field) the
wavelets are mirror images about the meridional plane x = 0, and so is the PSF;
:func:`mirror_symmetric` checks that on the traced pupil, and then only the columns at
x >= 0 are summed and mirrored (about half the work). Where tiles spanning all those
columns, centred on x = 0, keep the dropped phase as small (:func:`_fold_rows`), each ray
at px > 0 is summed together with its mirror image, whose wavelet is the same with u_x
negated: w (exp(i(L e + Q e^2)) + exp(i(-L e + Q e^2))) = 2 w cos(L e) exp(i Q e^2) along
x, so half the rays enter the matrix products (another 1.3-1.8x on a bank's PSFs).

Precision: each wavelet's amplitude and its large phase k (l_j + n' r_j) (1e5-1e6 rad) are
computed in float64 and the phase reduced modulo 2 pi; the per-tile phases (a few hundred
radians at most), their sines and cosines and the matrix products run in float32 by
default, 1.9-3.4x faster than all-float64 on a CPU. Against the complex128
evaluation, pixel kernels (5 x 5 samples binned) differ by at most 3e-7 of their peak and
single samples by 1e-6 (the demo's sampling: Cooke triplet, 128 pupil samples, 175 x 175
samples; benchmarks/README.md). ``dtype=torch.complex128`` gives the all-float64 sum, and
:func:`huygens_psf_direct` the exact reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lensim.psf.pupil_field import PupilField

CHUNK_RAYS = 4096
FOLD_MIN_ROWS = 8  # the fewest rows of a folded tile (_fold_rows)


def sample_offsets(grid: int, spacing_mm: float) -> torch.Tensor:
    """Sample offsets (mm) from the window centre along one axis: (m - grid//2) * spacing."""
    return (torch.arange(grid, dtype=torch.float64) - grid // 2) * spacing_mm


def _amplitudes(pf: PupilField) -> torch.Tensor:
    lam = pf.wavelength_mm
    return torch.sqrt(pf.power * pf.area) * pf.n_image / lam


def _tile_size(pf: PupilField, spacing_mm: float, max_phase_error: float) -> int:
    k = 2.0 * math.pi / pf.wavelength_mm * pf.n_image
    u = (pf.chief.unsqueeze(0) - pf.points) / pf.radius
    cross = (u[:, 0] * u[:, 1]).abs().max().item() + 1e-9
    half = math.sqrt(max_phase_error * pf.radius / (k * cross))
    return max(1, int(2.0 * half / spacing_mm))


def _terms(e: torch.Tensor, linear: torch.Tensor, quadratic: torch.Tensor, real: torch.dtype) -> torch.Tensor:
    """(2, T, m, N) phase terms e linear and e^2 quadratic (rad) in ``real``: e (T, m)
    sample offsets within each tile (mm), linear and quadratic (T, N) per-ray phase
    coefficients (rad/mm, rad/mm^2)."""
    e = e.to(real).unsqueeze(2)
    return torch.stack([e * linear.to(real).unsqueeze(1), (e * e) * quadratic.to(real).unsqueeze(1)])


def _x_parts(x: torch.Tensor, weight: torch.Tensor, fold: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The weighted x factors (real, imaginary), each (T, mx, N), of the phase terms x
    (2, T, mx, N) (:func:`_terms`): w exp(i (lin + quad)), or folded (a ray and its mirror
    image at once, about a tile centre on x = 0) w (exp(i (lin + quad)) + exp(i (-lin + quad)))
    = 2 w cos(lin) exp(i quad)."""
    if fold:
        amp = 2.0 * weight * torch.cos(x[0])
        return amp * torch.cos(x[1]), amp * torch.sin(x[1])
    arg = x[0] + x[1]
    return weight * torch.cos(arg), weight * torch.sin(arg)


def _real_blocks(
    arg_y: torch.Tensor, x: torch.Tensor, weight: torch.Tensor, fold: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """The tiles' complex products as one real matrix product: with phases arg_y (T, m, N),
    the x phase terms x (2, T, mx, N) and ray weights (T, 1, N), A = [cos y, sin y]
    (T, m, 2N) and B = [[X_re, -X_im], [X_im, X_re]] (T, 2 mx, 2N) with X the weighted x
    factors (:func:`_x_parts`), so that A B^T (T, m, 2 mx) holds the real parts of
    sum_j exp(i y_j) X_j in its first mx columns and the imaginary parts in the others (one
    real GEMM instead of building complex tensors)."""
    T, m, n = arg_y.shape
    mx = x.shape[2]
    if arg_y.requires_grad or x.requires_grad or weight.requires_grad:  # no out= under autograd
        cx, sx = _x_parts(x, weight, fold)
        b = torch.cat([torch.cat([cx, -sx], -1), torch.cat([sx, cx], -1)], 1)
        return torch.cat([torch.cos(arg_y), torch.sin(arg_y)], -1), b
    a = torch.empty(T, m, 2 * n, dtype=arg_y.dtype, device=arg_y.device)
    torch.cos(arg_y, out=a[:, :, :n])
    torch.sin(arg_y, out=a[:, :, n:])
    b = torch.empty(T, 2 * mx, 2 * n, dtype=arg_y.dtype, device=arg_y.device)
    cos, sin = b[:, :mx, :n], b[:, mx:, :n]
    if fold:
        amp = torch.cos(x[0]).mul_(2.0 * weight)
        torch.cos(x[1], out=cos).mul_(amp)
        torch.sin(x[1], out=sin).mul_(amp)
    else:
        arg = x[0].add_(x[1])
        torch.cos(arg, out=cos).mul_(weight)
        torch.sin(arg, out=sin).mul_(weight)
    torch.neg(sin, out=b[:, :mx, n:])
    b[:, mx:, n:].copy_(cos)
    return a, b


def _axis_tiles(offsets: torch.Tensor, m: int, one_sided: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample offsets (g,) (mm, evenly spaced) cut into tiles of m samples, the last one
    padded: the tiles' expansion centres (n,) and the offsets within each tile (n, m). A
    tile's centre is its middle sample, except the first one's with one_sided: its first
    sample (so a tile of m samples reaches as far from its centre as one of 2m - 1)."""
    n = math.ceil(offsets.shape[0] / m)
    step = float(offsets[1] - offsets[0]) if offsets.shape[0] > 1 else 0.0
    padded = (offsets[0] + torch.arange(n * m, dtype=torch.float64, device=offsets.device) * step).reshape(n, m)
    centres = padded.mean(1)
    if one_sided:
        centres[0] = padded[0, 0]
    return centres, padded - centres.unsqueeze(1)


def mirror_symmetric(pf: PupilField, x0_mm: float, rtol: float = 1e-9) -> bool:
    """Whether the wavelets of pf are mirror images about the plane x = x0_mm, so that the
    PSF is too: pf's rays come from a square pupil grid (pupil_xy), every ray's mirror
    (-px, py) is there too, and their positions, directions, optical paths, powers and
    areas agree to rtol (a rotationally symmetric lens and a field on the y axis)."""
    n = pf.samples
    if pf.pupil_xy.shape[0] < 2 or abs(x0_mm) > rtol * pf.radius:
        return False
    ij = torch.round((pf.pupil_xy + 1.0) * (n / 2.0) - 0.5).long()
    if bool((ij < 0).any() or (ij >= n).any()):
        return False
    index = torch.full((n, n), -1, dtype=torch.long, device=ij.device)
    index[ij[:, 1], ij[:, 0]] = torch.arange(ij.shape[0], device=ij.device)
    partner = index[ij[:, 1], n - 1 - ij[:, 0]]
    if bool((partner < 0).any()):
        return False
    flip = pf.points.new_tensor([-1.0, 1.0, 1.0])
    mirrored = (pf.points - pf.points.new_tensor([2.0 * x0_mm, 0.0, 0.0])) * flip
    differences = (  # each relative to its scale
        (mirrored - pf.points[partner]).abs().max() / pf.radius,
        (pf.directions * flip - pf.directions[partner]).abs().max(),
        (pf.opl - pf.opl[partner]).abs().max() / pf.wavelength_mm,  # in waves
        (pf.power - pf.power[partner]).abs().max() / pf.power.abs().max(),
        (pf.area - pf.area[partner]).abs().max() / pf.area.abs().max(),
    )
    return all(float(d) <= rtol for d in differences)


def _balanced(count: int, most: int) -> int:
    """The tile size (<= most) that cuts count samples into the fewest tiles with the
    least padding."""
    return math.ceil(count / math.ceil(count / most))


@dataclass
class _Tiles:
    """The image window cut into T = rows x cols tiles: the tiles' expansion centres
    (T, 3) mm, each tile's sample offsets from its centre along y (T, m) and x (T, mx) mm,
    the number of columns computed (all, or those at x >= the window centre when
    mirrored) and the sample index of each window column among them (grid,)."""

    centres: torch.Tensor
    ey: torch.Tensor
    ex: torch.Tensor
    rows: int
    cols: int
    columns: int
    column_index: torch.Tensor


def _tiles(grid: int, s: float, centre: tuple[torch.Tensor, ...], most: int, mirror: bool, fold: int = 0) -> _Tiles:
    """The tiling of a grid x grid window of spacing s (mm) centred on centre (3 0-dim
    tensors, mm): tiles of at most `most` samples across (balanced, so the padding is
    least); mirrored: only the columns at x >= the centre, the first tile centred on x = 0
    (so it reaches as far with most // 2 + 1 columns); fold > 0 (mirrored): one tile across
    all those columns, centred on x = 0, and tiles of at most `fold` rows. The tensors are
    on the centre's device."""
    device = centre[0].device
    k = torch.arange(grid, device=device) - grid // 2  # sample index from the window centre
    ty_c, ey_t = _axis_tiles(k.to(torch.float64) * s, _balanced(grid, fold or most))
    if mirror:
        columns = torch.arange(int(k.abs().max()) + 1, device=device)
        mx = columns.shape[0] if fold else _balanced(columns.shape[0], min(most // 2 + 1, columns.shape[0]))
        tx_c, ex_t = _axis_tiles(columns.to(torch.float64) * s, mx, one_sided=True)
        index = k.abs()
    else:
        columns, tx_c, ex_t, index = k, ty_c, ey_t, torch.arange(grid, device=device)
    rows, cols = ty_c.shape[0], tx_c.shape[0]
    ty, tx = torch.meshgrid(ty_c, tx_c, indexing="ij")
    cx, cy, cz = centre
    T = rows * cols
    centres = torch.stack([cx + tx.reshape(-1), cy + ty.reshape(-1), cz.expand(T)], -1)
    ex = ex_t[torch.arange(cols, device=device).repeat(rows)]
    ey = ey_t[torch.arange(rows, device=device).repeat_interleave(cols)]
    return _Tiles(centres, ey, ex, rows, cols, columns.shape[0], index)


def _fold_rows(grid: int, most: int) -> int:
    """The most rows of a tile that spans the x >= 0 half of the window (grid // 2 + 1
    columns, centred on x = 0) with the dropped cross term's phase as small as in a square
    tile of `most` samples (|e_x| |e_y| <= (most / 2)^2 samples^2); 0 when under
    FOLD_MIN_ROWS (many thin tiles cost more than the fold saves)."""
    rows = most * most // (2 * max(grid // 2, 1))
    return rows if rows >= min(FOLD_MIN_ROWS, grid) else 0


def _chunk_rays(tiles: _Tiles) -> int:
    """Rays per chunk: the chunk's phase blocks (2 x (m + 2 mx) x T x rays values) stay
    near 2^21 values (8 MB of float32), in cache, and at most CHUNK_RAYS."""
    per_ray = 2 * tiles.centres.shape[0] * (tiles.ey.shape[1] + 2 * tiles.ex.shape[1])
    return max(64, min(CHUNK_RAYS, (1 << 21) // per_ray // 64 * 64))


def _rays(pf: PupilField, fold: bool) -> tuple[torch.Tensor, ...]:
    """Each ray's point (N, 3), optical path (N,), amplitude (N,), sphere normal nu (N, 3)
    and cos(nu, D) (N,); folded: only the rays at px >= 0 (the others are their mirror
    images), those at px = 0 (their own) at half amplitude."""
    amp = _amplitudes(pf)
    nu = (pf.chief.unsqueeze(0) - pf.points) / pf.radius
    cos_d = (nu * pf.directions).sum(-1)
    if not fold:
        return pf.points, pf.opl, amp, nu, cos_d
    px = pf.pupil_xy[:, 0]
    keep = px >= 0
    amp = torch.where(px == 0, 0.5 * amp, amp)
    return pf.points[keep], pf.opl[keep], amp[keep], nu[keep], cos_d[keep]


def _tile_fields(pf: PupilField, tiles: _Tiles, real: torch.dtype, fold: bool) -> torch.Tensor:
    """The complex field of every tile's samples as (T, m, 2 mx) reals in ``real``: the
    real parts in the first mx columns, the imaginary parts in the others (up to the
    constant factors applied by huygens_psf), summed over the rays chunk by chunk; fold:
    each ray at px > 0 with its mirror image (every tile centred on x = 0)."""
    k_vac = 2.0 * math.pi / pf.wavelength_mm
    kn = k_vac * pf.n_image
    points, opl, amp, nu, cos_d = _rays(pf, fold)
    T, m, mx = tiles.centres.shape[0], tiles.ey.shape[1], tiles.ex.shape[1]
    out = torch.zeros(T, m, 2 * mx, dtype=real, device=pf.points.device)
    chunk = _chunk_rays(tiles)
    for a in range(0, points.shape[0], chunk):
        b = a + chunk
        v = tiles.centres.unsqueeze(1) - points[a:b].unsqueeze(0)  # (T, N, 3)
        r = torch.linalg.norm(v, dim=-1)
        u = v / r.unsqueeze(-1)
        kfac = 0.5 * ((u * nu[a:b].unsqueeze(0)).sum(-1) + cos_d[a:b].unsqueeze(0))
        phase = torch.remainder(k_vac * opl[a:b].unsqueeze(0) + kn * r, 2.0 * math.pi)
        weight = (amp[a:b].unsqueeze(0) * kfac / r).to(real).unsqueeze(1)
        ux, uy, inv2r = u[..., 0], u[..., 1], 0.5 / r
        x = _terms(tiles.ex, kn * ux, kn * (1 - ux * ux) * inv2r, real)
        y = _terms(tiles.ey, kn * uy, kn * (1 - uy * uy) * inv2r, real)
        blocks_y, blocks_x = _real_blocks(y[0] + y[1] + phase.to(real).unsqueeze(1), x, weight, fold)
        out = torch.baddbmm(out, blocks_y, blocks_x.transpose(1, 2))
    return out


def huygens_psf(
    pf: PupilField,
    grid: int,
    spacing_um: float,
    offset_mm: tuple[float, float] | tuple[torch.Tensor, torch.Tensor] = (0.0, 0.0),
    max_phase_error: float = 0.01,
    tile: int | None = None,
    dtype: torch.dtype = torch.complex64,
    mirror: bool | None = None,
) -> torch.Tensor:
    """Huygens PSF (grid x grid, energy per sample, float64) on the image plane, sampled
    every spacing_um, centred (sample grid//2) on the chief-ray point plus offset_mm (mm;
    0-dim tensors where gradients with respect to the sensor's decentre are wanted).
    Rows are y, columns x. dtype: complex64 (float32 phase factors and products) or
    complex128 (float64; see the module's note on precision). tile: the largest tile
    (samples across; default from max_phase_error, rad).
    mirror: compute the columns at x >= the window centre only and mirror them, for a PSF
    symmetric about the meridional plane (about half the work); None: when
    :func:`mirror_symmetric` finds the wavelets symmetric about the window's centre line
    and no gradient flows through pf (the derivative of a symmetric PSF, say with respect
    to an x decentre, need not be symmetric)."""
    s = spacing_um * 1e-3
    cx = pf.chief[0] + offset_mm[0]  # 0-dim tensors, so that gradients reach the chief ray
    cy = pf.chief[1] + offset_mm[1]
    if mirror is None:  # a symmetric PSF's gradient need not be (a decentre across the plane)
        mirror = not (cx.requires_grad or _requires_grad(pf)) and mirror_symmetric(pf, cx.item())
    most = tile or min(grid, _tile_size(pf, s, max_phase_error))
    fold = _fold_rows(grid, most) if mirror else 0
    tiles = _tiles(grid, s, (cx, cy, pf.chief[2]), most, mirror, fold)
    real = torch.float32 if dtype == torch.complex64 else torch.float64
    out = _tile_fields(pf, tiles, real, fold > 0).to(torch.float64)
    m, mx = tiles.ey.shape[1], tiles.ex.shape[1]
    power = out[..., :mx] ** 2 + out[..., mx:] ** 2  # (T, m, mx)
    power = power.reshape(tiles.rows, tiles.cols, m, mx).permute(0, 2, 1, 3).reshape(tiles.rows * m, tiles.cols * mx)
    return power[:grid, tiles.column_index] * s * s * _obliquity(pf)


def _requires_grad(pf: PupilField) -> bool:
    """Whether autograd follows any of pf's tensors (a lens parameter requires grad)."""
    values = (pf.points, pf.directions, pf.opl, pf.power, pf.area, pf.chief, pf.radius)
    return any(isinstance(v, torch.Tensor) and v.requires_grad for v in values)


def _obliquity(pf: PupilField) -> torch.Tensor:
    d = (pf.chief.unsqueeze(0) - pf.points) / pf.radius
    return ((d[:, 2] * pf.power).sum() / pf.power.sum()).abs()


def plane_obliquity(pf: PupilField) -> float:
    """cos of the chief ray's angle to the image-plane normal: the beam's intensity
    |E|^2 becomes irradiance on the tilted-incidence plane with this factor."""
    return float(_obliquity(pf))


def ideal_peak(pf: PupilField, spacing_um: float) -> float:
    """Peak energy per sample of the aberration-free PSF of the same pupil (all wavelets
    in phase at the centre): the Strehl ratio's denominator."""
    s = spacing_um * 1e-3
    e0 = (_amplitudes(pf) / pf.radius).sum().item()
    return e0 * e0 * s * s * plane_obliquity(pf)


def huygens_psf_direct(
    pf: PupilField, grid: int, spacing_um: float, offset_mm: tuple[float, float] = (0.0, 0.0)
) -> torch.Tensor:
    """Exact direct float64 summation of every wavelet at every sample (slow reference)."""
    return huygens_psf(pf, grid, spacing_um, offset_mm, tile=1, dtype=torch.complex128, mirror=False)
