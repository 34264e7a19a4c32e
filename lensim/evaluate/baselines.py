"""Classical restoration baselines for the evaluation harness (issue 5, "Baselines").

Every method has the form ``method(image, mapping, bank, capture=None, **options) ->
image``: image is a camera (aberrated) sRGB image (3, H, W) in [0, 1]; mapping
(lensim.render.mapping.SensorMapping) places its pixels on the sensor (mm); bank is the PSF
bank the image was simulated with; capture is the capture's record (the ``capture``
mapping of a dataset record: colour-matrix ``ccm``, white-balance gains ``r_gain``,
``b_gain`` and the noise draw ``shot``, ``read``), or None. The result is an sRGB image
(3, H, W) float32 in [0, 1].

Non-blind Wiener and Richardson-Lucy are ORACLES: they get the true PSF bank (and the
capture's colour pipeline and noise levels), which a restoration network does not get.

Energy domain. The simulation blurs in the camera's energy domain (linear camera RGB
before white balance), so both deconvolutions undo the camera processing first: inverse
sRGB curve (lensim.sensor.isp.srgb_to_linear), inverse CCM, inverse white balance (with
the capture's ``ccm`` / ``r_gain`` / ``b_gain``; without a capture only the sRGB curve is
undone), deconvolve each channel with its own kernel, and redo the processing (white
balance, CCM, clip to [0, 1], sRGB curve). The kernels are used as stored, their sum
being the relative illumination, so the deconvolution also undoes lens shading, as the
simulated pairs (made with relative illumination) require; a capture whose ``extra``
says ``relative_illumination: false`` gets unit-sum kernels.

Wiener (:func:`wiener`). Per tile of 64 pixels, with the bank's kernel at the tile's
centre and the tile's own noise-to-signal ratio, cross-faded over 16 pixels into its
neighbours (seamless); the computation, its prior and its speed are documented in its one
home, lensim.evaluate.wiener_tiles (the PSF-informed network's stage runs the same). The
NSR is that of a natural-image prior whose power spectrum falls as 1/|f|^2:
NSR(f) = sigma_n^2 |G(f)|^2 / A, with sigma_n^2 = shot * mean(y) + read^2 + ``noise_floor``
(the capture's noise variance at the window's mean energy, 0 without a noise draw, plus a
floor: ``DEFAULT_NOISE_FLOOR`` = 1e-5, about ten times the variance of 8-bit sRGB
quantization at mid-grey, 1.1e-6 in linear units, leaving room for demosaicing error; on
noisy crops floors of 1e-6..1e-4 changed PSNR by < 0.01 dB, the capture's draw
dominating). ``nsr`` replaces all this with one constant (frequency-flat) ratio. A flat NSR
measured far worse on noisy dataset crops (8 crops of 64 px, Cooke triplet on the APS-C
profile: a flat NSR of 1e-3, 1e-2, 3e-2 lost 13.6, 5.1, 1.5 dB to the input; the 1/|f|^2
prior gained 1.8 dB).

Tiles and blending (Richardson-Lucy, :func:`tiled_deconvolve`). Kernels are taken at tile
centres on a regular grid of spacing ``tile`` pixels (0, tile, 2 tile, ... in both axes,
as lensim.render.blur places them), at each centre's sensor position
(lensim.render.kernels: ``bank.psf_at``, radially interpolated and rotated to the
azimuth). Each centre's kernel deconvolves a window of 2 tile + 1 pixels plus a margin of
``margin`` pixels (default: the kernel size) on every side, the image being mirrored
(symmetric padding) beyond its borders; the window's centre part is weighted by the
bilinear hat of that centre (1 at the centre, 0 at the neighbouring centres) and the
weighted results are summed. The hats sum to 1 at every pixel, so there are no seams and
the effective inverse varies continuously across the image. The solver works on the
even-symmetric (mirrored) extension of each window, 2n x 2n, so the FFT's periodic wrap
meets no intensity jump at the window's border. Beyond the image's own border the scene
is unknown; mirroring it is an approximation whose error spreads some pixels inwards (on
64 px dataset crops with 35 px kernels this limits what any deconvolution can gain).

Richardson-Lucy. ``iterations`` (default ``DEFAULT_RL_ITERATIONS`` = 3) multiplicative
updates per window and channel, x <- x * (K^T (y / (K x))) / sum(K), from x0 = y / sum(K),
with y clamped to >= 1e-6 (RL assumes non-negative data); FFT convolutions on the window.
No regularization: the small, fixed iteration count is the regularizer. It was chosen on
noisy dataset crops (8 crops of 64 px from 2 photos, Cooke triplet): 3 iterations +0.1 dB
over the input, 6: -0.3 dB, 10: -0.8 dB, 20: -1.9 dB (noise amplification); on 32 crops
from the 8 sample photos 3 iterations gained 1.2 dB. Without noise more iterations keep
gaining (the tests use 20).

Unsharp mask (a stand-in for in-camera sharpening, done on the sRGB values as an ISP
does): out = x + amount * (x - G_sigma * x), clipped to [0, 1], G_sigma a Gaussian blur
of ``sigma_px`` pixels (defaults 1.0 px and 0.6). It uses neither the mapping nor the bank.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from lensim.evaluate import wiener_tiles as WT
from lensim.psf.bank import PSFBank
from lensim.render.kernels import check_bank_fits, kernels_at, tile_centres
from lensim.render.mapping import SensorMapping
from lensim.sensor.isp import apply_ccm, linear_to_srgb, srgb_to_linear, white_balance

DEFAULT_TILE = 32
DEFAULT_NOISE_FLOOR = 1e-5
DEFAULT_RL_ITERATIONS = 3
DEFAULT_UNSHARP_SIGMA_PX = 1.0
DEFAULT_UNSHARP_AMOUNT = 0.6

#: A per-window deconvolution: (windows (N, C, n, n), kernels (N, C, P, P), both float64)
#: -> restored windows (N, C, n, n), float64.
WindowSolver = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


# ---------------------------------------------------------------------------------------
# colour: sRGB <-> energy domain


def _check_image(image: torch.Tensor) -> None:
    if not isinstance(image, torch.Tensor) or image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(f"expected a (3, H, W) image tensor, got {getattr(image, 'shape', type(image))}")


def to_energy(
    image: torch.Tensor, capture: Mapping[str, Any] | None = None, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """sRGB (3, H, W) in [0, 1] -> energy-domain camera RGB in ``dtype``: inverse sRGB curve,
    then (with a capture) inverse CCM (inverted in float64) and inverse white balance."""
    _check_image(image)
    lin = srgb_to_linear(image.to(dtype))
    if capture is None:
        return lin
    ccm = torch.linalg.inv(torch.as_tensor(capture["ccm"], dtype=torch.float64)).to(dtype)
    cam = apply_ccm(lin, ccm)
    return white_balance(cam, float(capture["r_gain"]), float(capture["b_gain"]), inverse=True)


def from_energy(
    cam: torch.Tensor, capture: Mapping[str, Any] | None = None, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """Energy-domain camera RGB -> sRGB (3, H, W) float32 in [0, 1] (the inverse of
    :func:`to_energy`, computed in ``dtype``; values are clipped to [0, 1] in linear sRGB)."""
    x = cam.to(dtype)
    if capture is not None:
        x = white_balance(x, float(capture["r_gain"]), float(capture["b_gain"]))
        x = apply_ccm(x, torch.as_tensor(capture["ccm"], dtype=dtype))
    return linear_to_srgb(x).to(torch.float32)


def _unit_sum_kernels(capture: Mapping[str, Any] | None) -> bool:
    extra = (capture or {}).get("extra") or {}
    return extra.get("relative_illumination") is False


# ---------------------------------------------------------------------------------------
# tiles


def tiled_deconvolve(
    cam: torch.Tensor,
    mapping: SensorMapping,
    bank: PSFBank,
    solver: WindowSolver,
    tile: int = DEFAULT_TILE,
    margin: int | None = None,
    unit_sum: bool = False,
    chunk: int = 32,
) -> torch.Tensor:
    """Apply a per-window deconvolution over an energy-domain image (3, H, W) with the bank's
    kernel at each tile centre, blended with bilinear hats (see the module docstring).

    tile: spacing of the tile centres (pixels); margin: extra context on each side of a
    window (pixels; default the kernel size); chunk: windows processed at once (memory is
    about chunk * 3 * (4 tile + 2 + 4 margin)^2 * 40 bytes). Returns float64 (3, H, W).
    InputError when the bank is not at the mapping's pitch or does not reach its corners."""
    if tile < 1:
        raise ValueError(f"tile must be a positive number of pixels, got {tile}")
    if (mapping.height, mapping.width) != tuple(cam.shape[-2:]):
        raise ValueError(f"the mapping is for a {mapping.width}x{mapping.height} image; got {tuple(cam.shape[-2:])}")
    check_bank_fits(bank, mapping, str(bank.directory or "<bank>"))
    c, h, w = cam.shape
    p = bank.kernel_pixels
    m = p if margin is None else int(margin)
    n = 2 * tile + 1 + 2 * m
    cy, cx = tile_centres(h, tile), tile_centres(w, tile)
    ny, nx = len(cy), len(cx)
    off = tile + m
    pad_y = (off, (ny - 1) * tile + n - off - h)
    pad_x = (off, (nx - 1) * tile + n - off - w)
    padded = torch.from_numpy(
        np.pad(cam.detach().cpu().numpy().astype(np.float64), ((0, 0), pad_y, pad_x), mode="symmetric")
    )
    hat = 1.0 - torch.abs(torch.arange(-tile, tile + 1, dtype=torch.float64)) / tile
    hat2 = hat[:, None] * hat[None, :]
    out = torch.zeros(c, (ny - 1) * tile + 2 * tile + 1, (nx - 1) * tile + 2 * tile + 1, dtype=torch.float64)
    centres = [(i, j) for i in range(ny) for j in range(nx)]
    for s in range(0, len(centres), chunk):
        part = centres[s : s + chunk]
        rows = torch.stack([cy[i] for i, _ in part])
        cols = torch.stack([cx[j] for _, j in part])
        ks = kernels_at(bank, mapping, rows, cols, unit_sum)
        if ks.shape[1] != c:
            raise ValueError(f"the bank has {ks.shape[1]} channels; the image {c}")
        win = torch.stack([padded[:, i * tile : i * tile + n, j * tile : j * tile + n] for i, j in part])
        res = solver(win, ks)
        core = res[..., m : m + 2 * tile + 1, m : m + 2 * tile + 1] * hat2
        for (i, j), r in zip(part, core):
            out[:, i * tile : i * tile + 2 * tile + 1, j * tile : j * tile + 2 * tile + 1] += r
    return out[:, tile : tile + h, tile : tile + w]


# ---------------------------------------------------------------------------------------
# Wiener


def wiener(
    image: torch.Tensor,
    mapping: SensorMapping,
    bank: PSFBank | Sequence[PSFBank],
    capture: Mapping[str, Any] | None = None,
    tile: int = WT.DEFAULT_TILE,
    nsr: float | None = None,
    noise_floor: float = DEFAULT_NOISE_FLOOR,
    ramp: int = WT.DEFAULT_RAMP,
    margin: int = WT.DEFAULT_MARGIN,
) -> torch.Tensor:
    """Non-blind Wiener deconvolution with the true PSF bank (an oracle), per tile in the
    energy domain; sRGB (3, H, W) in [0, 1] in and out. bank: the lens's bank, or several
    (a tolerance distribution's draws, the unit's unknown): the minimum-mean-square-error
    filter over them per tile. tile, ramp, margin (pixels): the tiles' layout
    (lensim.evaluate.wiener_tiles, the computation's one home)."""
    _check_image(image)
    # float32 colour conversions: the deconvolution is float32 anyway (a 24 MP frame's
    # conversions took 1.6 of the stage's 4.9 s in float64)
    cam = _by_rows(lambda x: to_energy(x, capture, torch.float32), image)
    out = WT.wiener_deconvolve(
        cam,
        mapping,
        bank,
        capture,
        nsr=nsr,
        noise_floor=noise_floor,
        unit_sum=_unit_sum_kernels(capture),
        layout=(tile, ramp, margin),
    )
    return _by_rows(lambda x: from_energy(x, capture, torch.float32), out)


def _by_rows(fn: Callable[[torch.Tensor], torch.Tensor], image: torch.Tensor, rows: int = 256) -> torch.Tensor:
    """A per-pixel colour conversion ``fn`` of a (3, H, W) image, ``rows`` rows at a time
    (its temporaries stay small on large frames); float32 (3, H, W)."""
    out = torch.empty(image.shape, dtype=torch.float32)
    for i in range(0, image.shape[-2], rows):
        out[:, i : i + rows] = fn(image[:, i : i + rows])
    return out


# ---------------------------------------------------------------------------------------
# Richardson-Lucy


def _mirror(win: torch.Tensor) -> torch.Tensor:
    """(..., n, n) -> (..., 2n, 2n) even-symmetric extension (periodic without jumps)."""
    a = torch.cat([win, win.flip(-1)], dim=-1)
    return torch.cat([a, a.flip(-2)], dim=-2)


def richardson_lucy_solver(iterations: int = DEFAULT_RL_ITERATIONS) -> WindowSolver:
    """The per-window Richardson-Lucy iteration (see the module docstring)."""
    if iterations < 1:
        raise ValueError(f"expected at least one Richardson-Lucy iteration, got {iterations}")

    def solve(win: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
        n = win.shape[-1]
        y = _mirror(win).clamp_min(1e-6)
        s = y.shape[-2:]
        otf = WT.otf(kernels, s[-1])
        ksum = kernels.sum(dim=(-2, -1), keepdim=True).clamp_min(1e-12)
        x = y / ksum
        for _ in range(iterations):
            est = torch.fft.irfft2(torch.fft.rfft2(x) * otf, s=s).clamp_min(1e-12)
            corr = torch.fft.irfft2(torch.fft.rfft2(y / est) * otf.conj(), s=s)
            x = (x * corr / ksum).clamp_min(0.0)
        return x[..., :n, :n]

    return solve


def richardson_lucy(
    image: torch.Tensor,
    mapping: SensorMapping,
    bank: PSFBank,
    capture: Mapping[str, Any] | None = None,
    tile: int = DEFAULT_TILE,
    iterations: int = DEFAULT_RL_ITERATIONS,
) -> torch.Tensor:
    """Richardson-Lucy deconvolution with the true PSF bank (an oracle), per tile in the
    energy domain, a fixed number of iterations; sRGB (3, H, W) in [0, 1] in and out."""
    cam = to_energy(image, capture)
    out = tiled_deconvolve(
        cam, mapping, bank, richardson_lucy_solver(iterations), tile=tile, unit_sum=_unit_sum_kernels(capture)
    )
    return from_energy(out, capture)


# ---------------------------------------------------------------------------------------
# unsharp mask


def unsharp_mask(
    image: torch.Tensor,
    mapping: SensorMapping | None = None,
    bank: PSFBank | None = None,
    capture: Mapping[str, Any] | None = None,
    sigma_px: float = DEFAULT_UNSHARP_SIGMA_PX,
    amount: float = DEFAULT_UNSHARP_AMOUNT,
) -> torch.Tensor:
    """Unsharp-mask sharpening on the sRGB values: x + amount * (x - G_sigma x), clipped to
    [0, 1]; sigma_px in pixels (mirrored borders). mapping, bank and capture are unused
    (same signature as the other baselines)."""
    from scipy.ndimage import gaussian_filter

    _check_image(image)
    if sigma_px <= 0:
        raise ValueError(f"sigma_px must be positive, got {sigma_px}")
    x = image.detach().cpu().numpy().astype(np.float64)
    blurred = gaussian_filter(x, sigma=(0.0, sigma_px, sigma_px), mode="mirror")
    out = np.clip(x + amount * (x - blurred), 0.0, 1.0)
    return torch.from_numpy(out.astype(np.float32))


BASELINES: dict[str, Callable[..., torch.Tensor]] = {
    "wiener": wiener,
    "rl": richardson_lucy,
    "unsharp": unsharp_mask,
}
