"""PSNR / SSIM against scikit-image, and the field zones."""

import math

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from lensim.evaluate.metrics import (
    ZONES,
    image_scores,
    normalized_radius,
    psnr,
    psnr_batch,
    ssim,
    ssim_batch,
    ssim_map,
    zone_masks,
)


def _pair(seed: int, h: int = 40, w: int = 52):
    rng = np.random.default_rng(seed)
    ref = rng.random((3, h, w))
    # a smooth image plus noise, so SSIM is neither ~0 nor ~1
    ref = 0.5 * ref + 0.5 * np.linspace(0, 1, w)[None, None, :]
    test = np.clip(ref + 0.08 * rng.standard_normal(ref.shape), 0, 1)
    return test, ref


@pytest.mark.parametrize("seed", [0, 1])
def test_psnr_matches_skimage(seed):
    test, ref = _pair(seed)
    want = peak_signal_noise_ratio(ref, test, data_range=1.0)
    assert abs(psnr(test, ref) - want) < 1e-6
    assert abs(psnr(torch.from_numpy(test).float(), torch.from_numpy(ref).float()) - want) < 1e-4  # float32 input


@pytest.mark.parametrize("seed", [0, 1])
def test_ssim_matches_skimage(seed):
    test, ref = _pair(seed)
    want = structural_similarity(
        ref, test, channel_axis=0, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
    )
    got = ssim(test, ref)
    assert 0.1 < want < 0.95
    assert abs(got - want) < 1e-4
    # the map is the valid part of skimage's full map
    _, full = structural_similarity(
        ref[0], test[0], data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True
    )
    assert np.max(np.abs(ssim_map(test, ref)[0] - full[5:-5, 5:-5])) < 1e-6


def test_identical_images():
    _, ref = _pair(3)
    assert psnr(ref, ref) == math.inf
    assert abs(ssim(ref, ref) - 1.0) < 1e-12


def test_zones_partition_and_follow_radius():
    # a 6000 x 4000 sensor; crops at the centre and in a corner
    rho_c = normalized_radius(64, 64, 2000 - 32, 3000 - 32, 4000, 6000)
    assert rho_c.max() < 0.02
    rho_e = normalized_radius(64, 64, 0, 0, 4000, 6000)
    assert rho_e.max() < 1.0 and rho_e.min() > 0.95
    # a strip across the whole width crosses every zone
    rho = normalized_radius(16, 6000, 1992, 0, 4000, 6000)
    masks = zone_masks(rho)
    total = sum(m.astype(int) for m in masks.values())
    assert np.all(total == 1)
    assert all(masks[z].any() for z in ZONES)
    assert np.all(rho[masks["centre"]] < 1 / 3) and np.all(rho[masks["edge"]] >= 2 / 3)
    mid = rho[masks["middle"]]
    assert mid.min() >= 1 / 3 and mid.max() < 2 / 3
    # the half-diagonal is 3605.55 px: the centre zone spans |x| < 1201.85 px on the middle row
    row = rho[8]
    assert int((row < 1 / 3).sum()) == pytest.approx(2 * 1201.85, abs=2)


def test_image_scores_zone_counts_and_values():
    test, ref = _pair(5, 64, 6000 // 50)
    rho = normalized_radius(64, 120, 1968, 2940, 4000, 6000)
    # stretch rho artificially so the crop spans several zones
    rho = rho * 40
    s = image_scores(test, ref, rho)
    assert sum(s["zones"][z]["pixels"] for z in ZONES) == 64 * 120
    assert sum(s["zones"][z]["ssim_pixels"] for z in ZONES) == 54 * 110
    assert abs(s["psnr_db"] - psnr(test, ref)) < 1e-9
    assert abs(s["ssim"] - ssim(test, ref)) < 1e-9
    # the pixel-weighted mean of the zone MSEs is the overall MSE
    m = sum(s["zones"][z]["mse"] * s["zones"][z]["pixels"] for z in ZONES if s["zones"][z]["pixels"]) / (64 * 120)
    assert abs(m - s["mse"]) < 1e-12


def test_torch_batch_entry_points_match_references_and_the_numpy_ones():
    """psnr_batch / ssim_batch (what training validates with): the MSE formula, scikit-image,
    and the numpy entry points image by image."""
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 40, 48, generator=gen, dtype=torch.float64)
    b = (a + 0.05 * torch.randn(a.shape, generator=gen, dtype=torch.float64)).clamp(0, 1)
    mse = ((a - b) ** 2).flatten(1).mean(1)
    assert torch.allclose(psnr_batch(b, a), -10 * torch.log10(mse), atol=1e-12)
    s = ssim_batch(b, a)
    assert torch.allclose(ssim_batch(a, a), torch.ones(2, dtype=torch.float64), atol=1e-12)
    metrics = pytest.importorskip("skimage.metrics")
    for i in range(2):
        ref = metrics.structural_similarity(
            b[i].numpy(),
            a[i].numpy(),
            channel_axis=0,
            data_range=1.0,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
        )
        assert abs(float(s[i]) - ref) < 1e-6, (float(s[i]), ref)
    p = psnr_batch(b, a)
    for i in range(2):
        assert abs(float(p[i]) - psnr(b[i], a[i])) < 1e-12 and abs(float(s[i]) - ssim(b[i], a[i])) < 1e-12
