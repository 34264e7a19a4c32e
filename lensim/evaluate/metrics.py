"""Full-reference image metrics (PSNR, SSIM) and their split by field zone.

Images are (3, H, W) (or (C, H, W)) arrays or tensors of display-referred values (sRGB
code / 255) with data range 1. Computation is in float64 numpy; :func:`psnr_batch` and
:func:`ssim_batch` are the torch entry points (batches (B, C, H, W) on any device, float64,
one value per image: what training validation uses), with the same definitions.

* PSNR (dB) = 10 log10(1 / MSE), the MSE over every pixel and channel (data range 1);
  identical images give +inf.
* SSIM after Wang, Bovik, Sheikh & Simoncelli 2004 ("Image quality assessment: from error
  visibility to structural similarity", IEEE TIP 13(4)): Gaussian window sigma 1.5 px
  truncated at 3.5 sigma (11 x 11, normalized), K1 = 0.01, K2 = 0.03, population
  (co)variances, per channel, averaged over channels. The SSIM map is defined on the
  "valid" pixels only, those at least 5 px from the border (the window fits inside the
  image), as in ``skimage.metrics.structural_similarity(..., gaussian_weights=True,
  sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=0)``, which the tests
  match to 1e-6 (PSNR) and 1e-4 (SSIM).

Field zones come from each pixel's absolute sensor position: its normalized radius
rho = |(x, y)| / R, with (x, y) the pixel centre relative to the sensor centre and R the
sensor half-diagonal, both in pixels (the network's FOV channels,
``lensim.restore.fov.fov_channels``). Zones: centre rho < 1/3, middle 1/3 <= rho < 2/3,
edge rho >= 2/3; every pixel lies in exactly one.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import correlate1d

ArrayLike = np.ndarray | torch.Tensor

ZONES: tuple[str, ...] = ("centre", "middle", "edge")
#: Zone limits on the normalized radius rho (fractions of the sensor half-diagonal).
ZONE_EDGES: tuple[float, float] = (1.0 / 3.0, 2.0 / 3.0)

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _np(x: ArrayLike) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"expected a (C, H, W) or (H, W) image, got shape {a.shape}")
    return a


def _pair(a: ArrayLike, b: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    x, y = _np(a), _np(b)
    if x.shape != y.shape:
        raise ValueError(f"images differ in shape: {x.shape} vs {y.shape}")
    return x, y


def mse(a: ArrayLike, b: ArrayLike) -> float:
    """Mean squared error over every pixel and channel (units of the values squared)."""
    x, y = _pair(a, b)
    return float(np.mean((x - y) ** 2))


def psnr_from_mse(m: float, data_range: float = 1.0) -> float:
    """PSNR (dB) of a mean squared error; +inf for 0."""
    if m <= 0:
        return math.inf
    return float(10.0 * math.log10(data_range * data_range / m))


def psnr(test: ArrayLike, reference: ArrayLike, data_range: float = 1.0) -> float:
    """PSNR (dB) of an image against its reference, data range 1 by default."""
    return psnr_from_mse(mse(test, reference), data_range)


def gaussian_window_1d(sigma: float = SSIM_SIGMA, truncate: float = SSIM_TRUNCATE) -> np.ndarray:
    """The normalized 1-D Gaussian of SSIM: radius int(truncate * sigma + 0.5) (5 px for
    sigma 1.5), as scipy.ndimage.gaussian_filter builds it."""
    r = int(truncate * sigma + 0.5)
    t = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (t / sigma) ** 2)
    return w / w.sum()


def ssim_pad(sigma: float = SSIM_SIGMA, truncate: float = SSIM_TRUNCATE) -> int:
    """Border width (px) excluded from the SSIM map: the window radius (5 px by default)."""
    return int(truncate * sigma + 0.5)


def _valid_filter(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Separable filtering of (C, H, W) with w on rows and columns, keeping only the output
    pixels whose window lies inside the image."""
    r = len(w) // 2
    y = correlate1d(x, w, axis=-1, mode="reflect")[..., :, r : x.shape[-1] - r]
    y = correlate1d(y, w, axis=-2, mode="reflect")[..., r : x.shape[-2] - r, :]
    return y


def ssim_map(test: ArrayLike, reference: ArrayLike, data_range: float = 1.0, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """Per-channel SSIM map (C, H - 2p, W - 2p), p = ssim_pad(sigma) (5 px): the map's pixel
    (i, j) belongs to image pixel (i + p, j + p). Dimensionless, <= 1."""
    x, y = _pair(test, reference)
    p = ssim_pad(sigma)
    if x.shape[-1] <= 2 * p or x.shape[-2] <= 2 * p:
        raise ValueError(f"SSIM needs images larger than {2 * p + 1} px on each side, got {x.shape[-2:]}")
    w = gaussian_window_1d(sigma)
    ux, uy = _valid_filter(x, w), _valid_filter(y, w)
    vx = _valid_filter(x * x, w) - ux * ux
    vy = _valid_filter(y * y, w) - uy * uy
    vxy = _valid_filter(x * y, w) - ux * uy
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    return ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))


def ssim(test: ArrayLike, reference: ArrayLike, data_range: float = 1.0, sigma: float = SSIM_SIGMA) -> float:
    """Mean SSIM (dimensionless) over the valid pixels of every channel (Wang et al. 2004)."""
    return float(ssim_map(test, reference, data_range, sigma).mean())


# ---------------------------------------------------------------------------------------
# torch entry points (batched, for training validation)


def _as_batch(x: torch.Tensor, name: str) -> torch.Tensor:
    if x.dim() == 3:
        x = x.unsqueeze(0)
    if x.dim() != 4:
        raise ValueError(f"{name} must be (B, C, H, W) or (C, H, W), got {tuple(x.shape)}")
    return x.to(torch.float64)


def _batch_pair(pred: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    p, t = _as_batch(pred, "pred"), _as_batch(target, "target")
    if p.shape != t.shape:
        raise ValueError(f"shapes differ: {tuple(p.shape)} vs {tuple(t.shape)}")
    return p, t


def psnr_batch(pred: torch.Tensor, target: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """PSNR (B,) in dB of images (B, C, H, W) or (C, H, W), each over all its channels and
    pixels, in float64 on the images' device (:func:`psnr` per image); +inf for identical
    images."""
    p, t = _batch_pair(pred, target)
    mse_per_image = (p - t).pow(2).flatten(1).mean(1)
    return 10.0 * torch.log10(data_range**2 / mse_per_image)


def ssim_batch(
    pred: torch.Tensor, target: torch.Tensor, data_range: float = 1.0, sigma: float = SSIM_SIGMA
) -> torch.Tensor:
    """Mean SSIM (B,) of images (B, C, H, W) or (C, H, W) in float64 on the images' device:
    :func:`ssim` per image (the same window, constants and valid pixels). Images must be
    larger than 2 * ssim_pad(sigma) pixels on each side."""
    p, t = _batch_pair(pred, target)
    _, c, h, w = p.shape
    window = 2 * ssim_pad(sigma) + 1
    if h < window or w < window:
        raise ValueError(f"SSIM needs images of at least {window}x{window} pixels, got {h}x{w}")
    r = torch.arange(window, dtype=p.dtype, device=p.device) - (window - 1) / 2.0
    g = torch.exp(-(r**2) / (2.0 * sigma**2))
    g = g / g.sum()
    kx = g.view(1, 1, 1, window).expand(c, 1, 1, window)
    ky = g.view(1, 1, window, 1).expand(c, 1, window, 1)

    def blur(x: torch.Tensor) -> torch.Tensor:  # separable, valid positions only
        return F.conv2d(F.conv2d(x, kx, groups=c), ky, groups=c)

    mu_p, mu_t = blur(p), blur(t)
    s_pp = blur(p * p) - mu_p**2
    s_tt = blur(t * t) - mu_t**2
    s_pt = blur(p * t) - mu_p * mu_t
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    num = (2 * mu_p * mu_t + c1) * (2 * s_pt + c2)
    den = (mu_p**2 + mu_t**2 + c1) * (s_pp + s_tt + c2)
    return (num / den).flatten(1).mean(1)


# ---------------------------------------------------------------------------------------
# field zones


def normalized_radius(
    height: int, width: int, top: float, left: float, sensor_height: float, sensor_width: float
) -> np.ndarray:
    """(height, width) normalized radius rho of the pixels of a crop whose top-left pixel is
    sensor pixel (top, left), on a sensor of sensor_height x sensor_width pixels (rho = 1 at
    the sensor corners; see the module docstring)."""
    from lensim.restore.fov import fov_channels

    f = fov_channels(height, width, top, left, sensor_height, sensor_width, dtype=torch.float64)
    return torch.sqrt(f[0] ** 2 + f[1] ** 2).numpy()


def zone_index(rho: np.ndarray) -> np.ndarray:
    """Zone of each normalized radius: 0 centre (< 1/3), 1 middle (1/3..2/3), 2 edge (>= 2/3)."""
    return np.digitize(np.asarray(rho, dtype=np.float64), ZONE_EDGES).astype(np.int64)


def zone_masks(rho: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks {zone: mask} with the shape of rho; they partition the pixels."""
    z = zone_index(rho)
    return {name: z == i for i, name in enumerate(ZONES)}


def image_scores(test: ArrayLike, reference: ArrayLike, rho: np.ndarray) -> dict:
    """PSNR and SSIM of one image, overall and per zone.

    rho: (H, W) normalized radius of each pixel. Returns {"psnr_db", "ssim", "mse",
    "zones": {zone: {"psnr_db", "ssim", "mse", "pixels", "ssim_pixels"}}}: per zone the
    MSE and PSNR over that zone's pixels (all channels), the mean SSIM-map value over that
    zone's valid SSIM pixels (channel mean), and the pixel counts behind them (0 pixels:
    NaN scores)."""
    x, y = _pair(test, reference)
    rho = np.asarray(rho, dtype=np.float64)
    if rho.shape != x.shape[-2:]:
        raise ValueError(f"rho has shape {rho.shape}; expected the image's {x.shape[-2:]}")
    se = ((x - y) ** 2).mean(axis=0)  # (H, W) channel-mean squared error
    smap = ssim_map(x, y).mean(axis=0)  # (H-2p, W-2p)
    p = ssim_pad()
    rho_valid = rho[p : rho.shape[0] - p, p : rho.shape[1] - p]
    m = float(se.mean())
    out: dict = {"psnr_db": psnr_from_mse(m), "ssim": float(smap.mean()), "mse": m, "zones": {}}
    masks, masks_v = zone_masks(rho), zone_masks(rho_valid)
    for name in ZONES:
        n, nv = int(masks[name].sum()), int(masks_v[name].sum())
        zm = float(se[masks[name]].mean()) if n else math.nan
        out["zones"][name] = {
            "psnr_db": psnr_from_mse(zm) if n else math.nan,
            "ssim": float(smap[masks_v[name]].mean()) if nv else math.nan,
            "mse": zm,
            "pixels": n,
            "ssim_pixels": nv,
        }
    return out
