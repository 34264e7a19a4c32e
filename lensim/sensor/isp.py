"""The camera ISP stages of the imaging simulation (paper, "Imaging Simulation Pipeline").

Forward direction of a camera, from the scene's energy on the sensor to a photo::

    unprocess (sRGB -> energy domain) -> [blur, lensim.render] -> mosaic -> add_noise
        -> (quantize_raw) -> white_balance_mosaic -> demosaic -> process -> sRGB

Conventions (every function):
- torch float32 tensors; colour images are (3, H, W) or batches (..., 3, H, W), channel
  order R, G, B; a raw mosaic is (H, W) or (..., H, W). Any H, W >= 3 (odd sizes
  too: the Bayer pattern starts at the top-left pixel).
- sRGB images are in [0, 1] (8-bit code / 255). Linear and camera RGB images are
  relative scene radiance with the sensor's white level at 1 (after white balance a
  white diffuse surface that just saturates is (1, 1, 1)).
- Raw values are normalized: 0 at the black level, 1 at the white level. Noise
  parameters are in these units (see lensim.sensor.profile).
- Bayer patterns name the colours of the pixels (0,0) (0,1) (1,0) (1,1) of every 2x2
  quad, row-major, (0,0) the top-left pixel: 'RGGB', 'BGGR', 'GRBG', 'GBRG'.
- Random draws take a ``torch.Generator`` (seeded by the caller) and return what they drew.
- Library functions never print.

Example (the whole sensor side, no blur)::

    from lensim.sensor import load_sensor, isp
    prof = load_sensor("fullframe_dslr")
    g = torch.Generator().manual_seed(0)
    cam, params = isp.unprocess(srgb, prof, g)          # energy domain, random colour temperature
    cam = blur(cam)                                      # lensim.render (not here)
    raw = isp.mosaic(cam, prof.bayer_pattern)
    params.shot, params.read = prof.sample_noise(g)
    raw = isp.quantize_raw(isp.add_noise(raw, params.shot, params.read, g), prof)
    out = isp.raw_to_srgb(raw, params, method="ahd", bits=8)   # or lensim.render.pipeline.simulate_capture

The unprocessing follows Brooks et al. 2019 ("Unprocessing images for learned raw
denoising") without their tone-curve inversion, as the paper describes: the exact sRGB
transfer curve (IEC 61966-2-1) with the input clamped at eps = 1e-8, the inverse CCM,
and inverse white balance at a random colour temperature. The demosaicers: AHD
(Hirakawa & Parks 2005, "Adaptive homogeneity-directed demosaicing algorithm", IEEE TIP
14(3)) written here in vectorized torch, the default; bilinear (here); Malvar, He &
Cutler 2004 and Menon, Andriani & Calvagno 2007 from the colour-demosaicing package.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from lensim.errors import InputError
from lensim.sensor.calibration import SRGB_TO_XYZ
from lensim.sensor.cfa import CfaPattern, cfa_pattern
from lensim.sensor.profile import SensorProfile

EPS = 1e-8
DEMOSAIC_METHODS = ("ahd", "malvar", "menon", "bilinear")
_CHANNEL = {"R": 0, "G": 1, "B": 2}

# The D65 white in XYZ (Y = 1); linear sRGB -> XYZ is calibration.SRGB_TO_XYZ.
D65_XYZ = (0.95047, 1.0, 1.08883)


# ---------------------------------------------------------------- transfer curve, colour


def srgb_to_linear(x: torch.Tensor, eps: float = EPS) -> torch.Tensor:
    """Exact inverse sRGB transfer curve (IEC 61966-2-1): sRGB values in [0, 1] -> linear
    values in [0, 1]. The input is clamped to [eps, 1] first (eps = 1e-8 as in the paper,
    keeping the power's gradient finite)."""
    x = x.clamp(eps, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: torch.Tensor, eps: float = EPS) -> torch.Tensor:
    """Exact sRGB transfer curve (IEC 61966-2-1): linear values -> sRGB values in [0, 1].
    The input is clipped to [0, 1] (values outside cannot be displayed) and the power's
    argument clamped at eps."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(eps) ** (1.0 / 2.4) - 0.055)


def expose(img: torch.Tensor, ev: float) -> torch.Tensor:
    """An sRGB image (..., 3, H, W) in [0, 1] at ``ev`` stops more exposure: linear light
    times 2**ev (negative ev: a darker scene), back to sRGB; what brightens past 1 clips
    as a photo's highlights do. ev = 0 returns the image itself."""
    if ev == 0.0:
        return img
    return linear_to_srgb(srgb_to_linear(img) * 2.0**ev)


def apply_ccm(img: torch.Tensor, ccm: torch.Tensor | Any) -> torch.Tensor:
    """Multiply every pixel's RGB vector by a 3x3 matrix: out[..., i, :, :] = sum_j
    ccm[i, j] * img[..., j, :, :]. img is (..., 3, H, W)."""
    _check_rgb(img)
    m = torch.as_tensor(ccm, dtype=img.dtype, device=img.device)
    return torch.einsum("ij,...jhw->...ihw", m, img)


def _gain_vector(r_gain: float, b_gain: float, like: torch.Tensor) -> torch.Tensor:
    return torch.tensor([r_gain, 1.0, b_gain], dtype=like.dtype, device=like.device).view(3, 1, 1)


def white_balance(img: torch.Tensor, r_gain: float, b_gain: float, inverse: bool = False) -> torch.Tensor:
    """Multiply camera R by r_gain and B by b_gain (G gain is 1); divide when inverse.
    img is (..., 3, H, W) camera RGB."""
    _check_rgb(img)
    g = _gain_vector(r_gain, b_gain, img)
    return img / g if inverse else img * g


# ---------------------------------------------------------------- 1. unprocess


@dataclass
class CaptureParams:
    """What one simulated capture drew and used: colour temperature (K), the white-balance
    gains at it, the CCM (camera RGB -> linear sRGB), the Bayer pattern, the noise draw
    (shot, read; normalized raw units, None when no noise was added)."""

    kelvin: float
    r_gain: float
    b_gain: float
    ccm: list[list[float]]
    bayer_pattern: CfaPattern = "RGGB"
    shot: float | None = None
    read: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready mapping (for manifests and raw sidecars)."""
        return asdict(self)


def unprocess(
    img: torch.Tensor, profile: SensorProfile, generator: torch.Generator | None = None, kelvin: float | None = None
) -> tuple[torch.Tensor, CaptureParams]:
    """sRGB image -> energy domain (linear camera RGB before white balance), after Brooks
    et al. 2019 and the paper's energy-domain transformation.

    img: (..., 3, H, W) sRGB in [0, 1]. Steps: exact inverse sRGB curve (input clamped at
    1e-8), inverse CCM (linear sRGB -> white-balanced camera RGB), inverse white balance at
    a colour temperature: ``kelvin`` if given, else drawn uniformly in mired over
    profile.kelvin_range with ``generator`` (one draw for the whole batch).
    Returns (camera RGB (..., 3, H, W) float32, CaptureParams with kelvin and gains).
    Values stay in about [0, 1]; saturated colours may leave it slightly (no clipping here,
    so :func:`process` inverts this exactly)."""
    _check_rgb(img)
    img = img.to(torch.float32)
    if kelvin is None:
        kelvin = profile.sample_kelvin(generator)
    r_gain, b_gain = profile.wb_gains(float(kelvin))
    cam = srgb_to_camera(img, profile.ccm, r_gain, b_gain)
    return cam, CaptureParams(
        kelvin=float(kelvin),
        r_gain=r_gain,
        b_gain=b_gain,
        ccm=[list(r) for r in profile.ccm],
        bayer_pattern=profile.bayer_pattern,
    )


def srgb_to_camera(img: torch.Tensor, ccm: Any, r_gain: float, b_gain: float) -> torch.Tensor:
    """sRGB (..., 3, H, W) in [0, 1] -> camera RGB before white balance, float32: exact
    inverse sRGB curve (input clamped at 1e-8), inverse CCM (3x3, camera RGB -> linear
    sRGB), inverse white balance with the gains. The inverse of :func:`process`."""
    lin = srgb_to_linear(img.to(torch.float32))
    cam = apply_ccm(lin, torch.linalg.inv(torch.as_tensor(ccm, dtype=torch.float64)).to(torch.float32))
    return white_balance(cam, r_gain, b_gain, inverse=True)


# ---------------------------------------------------------------- 3. mosaic and noise


def _check_rgb(img: torch.Tensor) -> None:
    if not isinstance(img, torch.Tensor) or img.dim() < 3 or img.shape[-3] != 3:
        raise InputError(
            None, "image", f"expected a tensor of shape (..., 3, H, W), got {tuple(getattr(img, 'shape', ()))}"
        )


def _check_size(h: int, w: int) -> None:
    if h < 3 or w < 3:
        raise InputError(None, "image", f"expected an image of at least 3x3 pixels for the Bayer stages, got {h}x{w}")


def bayer_masks(
    pattern: CfaPattern,
    height: int,
    width: int,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """(3, H, W) masks, 1 where the pixel has the R, G or B filter, 0 elsewhere."""
    p = cfa_pattern(pattern)
    masks = torch.zeros(3, height, width, dtype=dtype, device=device)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        masks[_CHANNEL[p[k]], dy::2, dx::2] = 1
    return masks


def mosaic(rgb: torch.Tensor, pattern: CfaPattern = "RGGB") -> torch.Tensor:
    """Bayer mosaic: (..., 3, H, W) -> (..., H, W), keeping at each pixel the colour of its
    filter (pattern as in the module docstring)."""
    _check_rgb(rgb)
    p = cfa_pattern(pattern)
    h, w = rgb.shape[-2:]
    _check_size(h, w)
    out = torch.empty(rgb.shape[:-3] + (h, w), dtype=rgb.dtype, device=rgb.device)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        out[..., dy::2, dx::2] = rgb[..., _CHANNEL[p[k]], dy::2, dx::2]
    return out


def add_noise(raw: torch.Tensor, shot: float, read: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Heteroscedastic Gaussian shot + read noise (Brooks et al. 2019) in normalized raw
    units: out = raw + sqrt(shot * max(raw, 0) + read**2) * N(0, 1), independently per pixel.

    shot: dimensionless (variance per unit normalized signal); read: standard deviation
    of the signal-independent noise (normalized units). No clipping: the result may leave
    [0, 1] (clip with :func:`quantize_raw` or in :func:`process`)."""
    if shot < 0 or read < 0:
        raise InputError(None, "noise", f"expected non-negative shot and read noise, got shot={shot}, read={read}")
    var = shot * raw.clamp_min(0.0) + read * read
    noise = torch.randn(raw.shape, generator=generator, dtype=raw.dtype, device=raw.device)
    return raw + var.sqrt() * noise


def quantize_raw(raw: torch.Tensor, profile: SensorProfile) -> torch.Tensor:
    """Simulate the ADC: normalized raw -> digital numbers DN = round(black + raw * (white -
    black)) clipped to [0, white_level] -> back to normalized units. The result is clipped
    at 1 (saturation) and at -black/(white-black) below."""
    dn = digital_numbers(raw, profile)
    return (dn - profile.black_level) / (profile.white_level - profile.black_level)


def digital_numbers(raw: torch.Tensor, profile: SensorProfile) -> torch.Tensor:
    """The ADC's output for a normalized raw mosaic: DN = round(black + raw * (white -
    black)) clipped to [0, white_level], a float tensor of whole numbers (raw files store
    these)."""
    scale = profile.white_level - profile.black_level
    return torch.round(profile.black_level + raw * scale).clamp(0.0, profile.white_level)


def white_balance_mosaic(raw: torch.Tensor, pattern: CfaPattern, r_gain: float, b_gain: float) -> torch.Tensor:
    """White balance a raw mosaic (..., H, W): R pixels times r_gain, B pixels times
    b_gain (what a camera does before demosaicing)."""
    h, w = raw.shape[-2:]
    m = bayer_masks(pattern, h, w, raw.device, raw.dtype)
    gains = m[0] * r_gain + m[1] + m[2] * b_gain
    return raw * gains


# ---------------------------------------------------------------- 4. demosaic


def _pad(x: torch.Tensor, p: int) -> torch.Tensor:
    """Mirror-pad the last two dims of (N, C, H, W) by p without repeating the edge
    (keeps the Bayer phase: index -k maps to k)."""
    return F.pad(x, (p, p, p, p), mode="reflect")


def _win(xp: torch.Tensor, p: int, dy: int, dx: int, h: int, w: int) -> torch.Tensor:
    """View of the (H, W) window of a tensor padded by p, shifted by (dy, dx)."""
    return xp[..., p + dy : p + dy + h, p + dx : p + dx + w]


def _interp_rb(sparse: torch.Tensor) -> torch.Tensor:
    """Bilinear fill of a sparse R or B plane (zeros elsewhere) of (N, C, H, W): the value
    itself at its sites, the mean of the 2 nearest at the greens, of the 4 diagonal ones
    at the other colour (the 3x3 kernel [[1, 2, 1], [2, 4, 2], [1, 2, 1]] / 4)."""
    h, w = sparse.shape[-2:]
    sp = _pad(sparse, 1)
    edges = _win(sp, 1, -1, 0, h, w) + _win(sp, 1, 1, 0, h, w) + _win(sp, 1, 0, -1, h, w) + _win(sp, 1, 0, 1, h, w)
    corners = _win(sp, 1, -1, -1, h, w) + _win(sp, 1, -1, 1, h, w) + _win(sp, 1, 1, -1, h, w) + _win(sp, 1, 1, 1, h, w)
    return sparse + 0.5 * edges + 0.25 * corners


def _interp_g(sparse: torch.Tensor) -> torch.Tensor:
    """Bilinear fill of the sparse green plane of (N, C, H, W): the mean of the 4
    neighbours at R and B pixels."""
    h, w = sparse.shape[-2:]
    sp = _pad(sparse, 1)
    return sparse + 0.25 * (
        _win(sp, 1, -1, 0, h, w) + _win(sp, 1, 1, 0, h, w) + _win(sp, 1, 0, -1, h, w) + _win(sp, 1, 0, 1, h, w)
    )


def demosaic_bilinear(raw: torch.Tensor, pattern: CfaPattern) -> torch.Tensor:
    """Bilinear demosaicing: (H, W) -> (3, H, W). Each missing value is the mean of the
    nearest 2 or 4 samples of its colour."""
    h, w = raw.shape
    m = bayer_masks(pattern, h, w, raw.device, raw.dtype)
    x = raw.reshape(1, 1, h, w)
    return torch.cat([_interp_rb(x * m[0]), _interp_g(x * m[1]), _interp_rb(x * m[2])], dim=1)[0]


def _lab(rgb: torch.Tensor, to_xyz: list[list[float]]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """CIE L*, a*, b* (D65 white) of linear RGB (N, 3, H, W) through a 3x3 RGB -> XYZ
    matrix (negative RGB clipped to 0). Returns three (N, H, W) tensors."""
    r, g, b = rgb[:, 0].clamp_min(0.0), rgb[:, 1].clamp_min(0.0), rgb[:, 2].clamp_min(0.0)
    fs = []
    for row, white in zip(to_xyz, D65_XYZ):
        t = (row[0] / white) * r + (row[1] / white) * g + (row[2] / white) * b
        fs.append(torch.where(t > 0.008856, t.clamp_min(1e-12).pow(1.0 / 3.0), 7.787 * t + 16.0 / 116.0))
    fx, fy, fz = fs
    return 116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)


def _median3x3(x: torch.Tensor) -> torch.Tensor:
    """3x3 median of the last two dims of (N, C, H, W), mirror padded: the 19
    compare-exchange median-of-9 network (Paeth 1990; Devillard's opt_med9)."""
    h, w = x.shape[-2:]
    xp = _pad(x, 1)
    p = [_win(xp, 1, dy, dx, h, w) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]

    def srt(i: int, j: int) -> None:
        lo, hi = torch.minimum(p[i], p[j]), torch.maximum(p[i], p[j])
        p[i], p[j] = lo, hi

    for i, j in (
        (1, 2),
        (4, 5),
        (7, 8),
        (0, 1),
        (3, 4),
        (6, 7),
        (1, 2),
        (4, 5),
        (7, 8),
        (0, 3),
        (5, 8),
        (4, 7),
        (3, 6),
        (1, 4),
        (2, 5),
        (4, 7),
        (4, 2),
        (6, 4),
        (4, 2),
    ):
        srt(i, j)
    return p[4]


def _ahd_block(x: torch.Tensor, m: torch.Tensor, to_xyz: list[list[float]], median_passes: int) -> torch.Tensor:
    """AHD on one block: x (1, 1, h, w) mosaic, m (1, 3, h, w) Bayer masks -> (1, 3, h, w)."""
    h, w = x.shape[-2:]
    mr, mg, mb = m[:, 0:1], m[:, 1:2], m[:, 2:3]
    green_site = mg > 0

    # 1. green along rows (gh) and along columns (gv), clamped to the two neighbouring greens
    xp = _pad(x, 2)
    c = _win(xp, 2, 0, 0, h, w)
    l1, r1, l2, r2 = (
        _win(xp, 2, 0, -1, h, w),
        _win(xp, 2, 0, 1, h, w),
        _win(xp, 2, 0, -2, h, w),
        _win(xp, 2, 0, 2, h, w),
    )
    u1, d1, u2, d2 = (
        _win(xp, 2, -1, 0, h, w),
        _win(xp, 2, 1, 0, h, w),
        _win(xp, 2, -2, 0, h, w),
        _win(xp, 2, 2, 0, h, w),
    )
    gh = 0.5 * (l1 + r1) + 0.25 * (2.0 * c - l2 - r2)
    gh = torch.minimum(torch.maximum(gh, torch.minimum(l1, r1)), torch.maximum(l1, r1))
    gv = 0.5 * (u1 + d1) + 0.25 * (2.0 * c - u2 - d2)
    gv = torch.minimum(torch.maximum(gv, torch.minimum(u1, d1)), torch.maximum(u1, d1))
    g2 = torch.where(green_site, x, torch.cat([gh, gv], dim=0))  # (2, 1, h, w): row and column candidates

    # 2. red and blue of each candidate from bilinear colour differences
    diff = x - g2
    cand = torch.cat([g2 + _interp_rb(diff * mr), g2, g2 + _interp_rb(diff * mb)], dim=1)  # (2, 3, h, w)

    # 3. homogeneity in CIELab: neighbours within the adaptive tolerances
    L, A, B = _lab(cand, to_xyz)
    lab = torch.stack([L, A, B], dim=1)  # (2, 3, h, w)
    lp = F.pad(lab, (1, 1, 1, 1), mode="replicate")
    ctr = lab
    nb = [_win(lp, 1, 0, -1, h, w), _win(lp, 1, 0, 1, h, w), _win(lp, 1, -1, 0, h, w), _win(lp, 1, 1, 0, h, w)]
    ld = [(ctr[:, 0] - n[:, 0]).abs() for n in nb]  # each (2, h, w)
    cd = [(ctr[:, 1] - n[:, 1]) ** 2 + (ctr[:, 2] - n[:, 2]) ** 2 for n in nb]
    leps = torch.minimum(torch.maximum(ld[0][0], ld[1][0]), torch.maximum(ld[2][1], ld[3][1]))
    ceps = torch.minimum(torch.maximum(cd[0][0], cd[1][0]), torch.maximum(cd[2][1], cd[3][1]))
    homo = torch.zeros_like(ld[0])
    for li, ci in zip(ld, cd):
        homo += ((li <= leps) & (ci <= ceps)).to(homo.dtype)

    # 4. 3x3 sums of homogeneity; the more homogeneous candidate wins (mean on a tie)
    hp = F.pad(homo.unsqueeze(1), (1, 1, 1, 1), mode="replicate")
    rows = _win(hp, 1, 0, -1, h, w) + _win(hp, 1, 0, 0, h, w) + _win(hp, 1, 0, 1, h, w)
    rp = F.pad(rows, (0, 0, 1, 1), mode="replicate")
    hm = rp[..., 0:h, :] + rp[..., 1 : h + 1, :] + rp[..., 2 : h + 2, :]  # (2, 1, h, w)
    wh = (hm[0:1] > hm[1:2]).to(x.dtype) + 0.5 * (hm[0:1] == hm[1:2]).to(x.dtype)
    out = cand[1:2] + wh * (cand[0:1] - cand[1:2])

    # 5. artefact reduction: median-filtered colour differences
    for _ in range(median_passes):
        r, g, b = out[:, 0:1], out[:, 1:2], out[:, 2:3]
        drg = _median3x3(r - g)
        dbg = _median3x3(b - g)
        r_new = torch.where(mr > 0, x, g + drg)
        b_new = torch.where(mb > 0, x, g + dbg)
        g_new = torch.where(mr > 0, x - drg, torch.where(mb > 0, x - dbg, x))
        out = torch.cat([r_new, g_new, b_new], dim=1)
    return out


def demosaic_ahd(
    raw: torch.Tensor,
    pattern: CfaPattern,
    rgb_to_xyz: torch.Tensor | Any | None = None,
    median_passes: int = 1,
    block_rows: int = 256,
    workers: int | None = None,
) -> torch.Tensor:
    """Adaptive homogeneity-directed demosaicing (Hirakawa & Parks 2005): (H, W) -> (3, H, W).

    1. Green is interpolated twice, along rows and along columns, with the 5-tap filter
       (G[-1] + G[+1]) / 2 + (2 C[0] - C[-2] - C[+2]) / 4, clamped to the two neighbouring
       greens (as dcraw's ahd_interpolate does).
    2. Red and blue are filled in each candidate by bilinear interpolation of the colour
       differences R - G and B - G (using that candidate's green).
    3. Both candidates go to CIE L*a*b* (``rgb_to_xyz``: camera RGB -> XYZ, default the
       sRGB matrix, i.e. the input is taken as white-balanced, roughly sRGB-like linear
       data). A pixel's homogeneity in a candidate is the number of its 4 neighbours
       within the adaptive luminance and chrominance tolerances eps_L = min(max |dL| to the
       left/right neighbours in the row candidate, max |dL| to the up/down neighbours in
       the column candidate), eps_C likewise with (da^2 + db^2) (dcraw's form).
    4. Homogeneity is summed over 3x3 windows; each pixel takes the more homogeneous
       candidate (the mean of both on a tie).
    5. ``median_passes`` passes of Hirakawa & Parks' artefact reduction: R - G and B - G are
       3x3-median filtered and the missing values rebuilt from them (R, B at other pixels
       as G plus the filtered difference, G at R/B pixels as the measured value minus it);
       measured values are kept.

    Input and output are linear, normalized raw values (no clipping, so noise keeps zero
    mean). Borders: mirror padding that keeps the Bayer phase. The image is processed in
    blocks of ``block_rows`` rows with a halo wider than the algorithm's reach (identical
    result, far fewer large allocations). ``workers`` (default: torch.get_num_threads())
    threads process blocks side by side, each running its tensor operations on one
    thread: on a busy machine this is several times faster than torch's intra-op
    threading, whose barriers stall when a core is taken (measured 8x on 2 shared cores).
    With workers > 1, torch's process-wide default thread count is set back to its value
    on return (the workers set it to 1 for themselves)."""
    h, w = raw.shape
    _check_size(h, w)
    p = cfa_pattern(pattern)
    passes = max(0, int(median_passes))
    to_xyz = SRGB_TO_XYZ.tolist() if rgb_to_xyz is None else torch.as_tensor(rgb_to_xyz, dtype=torch.float64).tolist()
    halo = 2 * ((6 + 2 * passes + 1) // 2)  # even, more than the reach: 2 + 1 + 1 + 1 + 2 per pass
    step = max(2, 2 * (int(block_rows) // 2))
    out = torch.empty(3, h, w, dtype=raw.dtype, device=raw.device)
    starts = list(range(0, h, step))

    def run(y0: int) -> None:
        y1 = min(h, y0 + step)
        a, b = max(0, y0 - halo), min(h, y1 + halo)  # a is even: the block keeps the Bayer phase
        m = bayer_masks(p, b - a, w, raw.device, raw.dtype).unsqueeze(0)
        blk = _ahd_block(raw[a:b].reshape(1, 1, b - a, w), m, to_xyz, passes)
        out[:, y0:y1] = blk[0, :, y0 - a : y1 - a]

    n_workers = min(len(starts), torch.get_num_threads() if workers is None else max(1, int(workers)))
    if n_workers <= 1 or raw.device.type != "cpu":
        for y0 in starts:
            run(y0)
        return out
    default_threads = torch.get_num_threads()

    def run_single_threaded(y0: int) -> None:
        torch.set_num_threads(1)  # this worker thread only (OpenMP's per-thread setting)
        run(y0)

    try:
        with ThreadPoolExecutor(max_workers=n_workers) as pool:
            list(pool.map(run_single_threaded, starts))
    finally:
        torch.set_num_threads(default_threads)
    return out


_LIB_PAD = 8  # even: keeps the Bayer phase


def _demosaic_colour(raw: torch.Tensor, pattern: CfaPattern, method: str) -> torch.Tensor:
    try:
        import colour_demosaicing as cd
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError(
            None,
            "method",
            f"demosaicing method {method!r} needs the colour-demosaicing package (pip install colour-demosaicing)",
        ) from None
    fn = cd.demosaicing_CFA_Bayer_Malvar2004 if method == "malvar" else cd.demosaicing_CFA_Bayer_Menon2007
    # colour-demosaicing convolves with scipy's 'reflect' mode, which repeats the edge
    # pixel and so breaks the Bayer phase at the borders (2 px of wrong colours): pad
    # first with a phase-keeping mirror (numpy's 'reflect'), crop after.
    pad = _LIB_PAD
    arr = np.pad(raw.detach().cpu().to(torch.float64).numpy(), pad, mode="reflect")
    out = fn(arr, pattern)[pad:-pad, pad:-pad]
    return torch.from_numpy(np.ascontiguousarray(np.moveaxis(out, -1, 0))).to(raw.dtype).to(raw.device)


def demosaic(raw: torch.Tensor, pattern: CfaPattern = "RGGB", method: str = "ahd", **kwargs: Any) -> torch.Tensor:
    """Demosaic a Bayer mosaic (..., H, W) -> (..., 3, H, W), float32 linear values.

    method: 'ahd' (Hirakawa & Parks 2005, :func:`demosaic_ahd`, the default; kwargs go
    to it), 'malvar' (Malvar, He & Cutler 2004) or 'menon' (Menon et al. 2007, with its
    refining step) from colour-demosaicing, or 'bilinear'. Run it on white-balanced raw
    data (:func:`white_balance_mosaic`): AHD's homogeneity test and the cross-channel
    filters of Malvar and Menon assume a neutral grey has equal R, G and B."""
    p = cfa_pattern(pattern)
    meth = str(method).lower()
    if meth not in DEMOSAIC_METHODS:
        raise InputError(
            None, "method", f"expected a demosaicing method among {', '.join(DEMOSAIC_METHODS)}, got {method!r}"
        )
    if raw.dim() < 2:
        raise InputError(None, "raw", f"expected a mosaic of shape (..., H, W), got {tuple(raw.shape)}")
    h, w = raw.shape[-2:]
    _check_size(h, w)
    if kwargs and meth != "ahd":
        raise InputError(None, "method", f"options {', '.join(sorted(kwargs))} apply to 'ahd' only, not {meth!r}")
    flat = raw.to(torch.float32).reshape(-1, h, w)
    outs = []
    for r in flat:
        if meth == "ahd":
            outs.append(demosaic_ahd(r, p, **kwargs))
        elif meth == "bilinear":
            outs.append(demosaic_bilinear(r, p))
        else:
            outs.append(_demosaic_colour(r, p, meth))
    return torch.stack(outs).reshape(raw.shape[:-2] + (3, h, w))


# ---------------------------------------------------------------- 5. process


def quantize(img: torch.Tensor, bits: int) -> torch.Tensor:
    """Round values in [0, 1] to the grid of an unsigned ``bits``-bit image (8 or 16):
    round(clip(x, 0, 1) * (2**bits - 1)) / (2**bits - 1), still float32."""
    if bits not in (8, 16):
        raise InputError(None, "bits", f"expected 8 or 16, got {bits!r}")
    q = float(2**bits - 1)
    return torch.round(img.clamp(0.0, 1.0) * q) / q


def to_uint(img: torch.Tensor, bits: int = 8) -> np.ndarray:
    """(3, H, W) values in [0, 1] -> (H, W, 3) numpy uint8 (bits=8) or uint16 (bits=16),
    ready for an image writer."""
    if bits not in (8, 16):
        raise InputError(None, "bits", f"expected 8 or 16, got {bits!r}")
    q = torch.round(img.detach().clamp(0.0, 1.0) * float(2**bits - 1)).to(torch.int32)
    arr = q.movedim(-3, -1).cpu().numpy()
    return arr.astype(np.uint8 if bits == 8 else np.uint16)


def process(
    cam: torch.Tensor, params: CaptureParams, bits: int | None = 8, white_balanced: bool = False
) -> torch.Tensor:
    """Camera RGB (..., 3, H, W) -> sRGB (..., 3, H, W) float32 in [0, 1]: white balance
    with params' gains (skipped when ``white_balanced``, e.g. after
    :func:`white_balance_mosaic`), CCM (camera RGB -> linear sRGB), clip to [0, 1], sRGB
    transfer curve, and rounding to the ``bits``-bit grid (8 or 16; None: no rounding).
    The exact inverse of :func:`unprocess` up to the rounding."""
    _check_rgb(cam)
    x = cam.to(torch.float32)
    if not white_balanced:
        x = white_balance(x, params.r_gain, params.b_gain)
    x = apply_ccm(x, torch.tensor(params.ccm, dtype=torch.float32))
    x = linear_to_srgb(x)
    return x if bits is None else quantize(x, bits)


def raw_to_srgb(
    raw: torch.Tensor, params: CaptureParams, method: str = "ahd", bits: int | None = 8, **demosaic_options: Any
) -> torch.Tensor:
    """The camera's side of the pipeline on a normalized raw mosaic (..., H, W): white
    balance on the mosaic, demosaic (``method``; AHD measures homogeneity in CIELab through
    sRGB->XYZ @ params.ccm), CCM, sRGB curve, rounding to ``bits``. White balance comes
    before demosaicing, as in a camera (for the linear bilinear method the order does not
    matter; AHD, Malvar and Menon assume balanced channels). ``demosaic_options`` go to
    :func:`demosaic` (AHD's block_rows and workers: memory and speed, not the result)."""
    wb = white_balance_mosaic(raw, params.bayer_pattern, params.r_gain, params.b_gain)
    kwargs: dict[str, Any] = dict(demosaic_options)
    if str(method).lower() == "ahd":  # AHD's CIELab through the camera's own colour matrix
        kwargs["rgb_to_xyz"] = torch.from_numpy(SRGB_TO_XYZ) @ torch.tensor(params.ccm, dtype=torch.float64)
    rgb = demosaic(wb, params.bayer_pattern, method, **kwargs)
    return process(rgb, params, bits=bits, white_balanced=True)
