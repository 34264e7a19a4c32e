"""ISP stages: sRGB curve, unprocess/process round trip on natural images, Bayer
mosaics, noise statistics, demosaicing (AHD vs Malvar on natural images), raw output."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.render.pipeline import simulate_capture
from lensim.sensor import isp, load_sensor

# ----------------------------------------------------------------- natural test images


def _natural_images() -> dict[str, np.ndarray]:
    """Three or more natural 8-bit RGB photos available offline: scikit-image's bundled
    astronaut and coffee (public domain) and sporco's Kodak kodim23 (unrestricted)."""
    out: dict[str, np.ndarray] = {}
    try:
        import skimage.data as sd

        out["astronaut"] = sd.astronaut()
        out["coffee"] = sd.coffee()
    except Exception:
        pass
    try:
        import sporco
        from PIL import Image

        p = os.path.join(os.path.dirname(sporco.__file__), "data", "kodim23.png")
        out["kodim23"] = np.asarray(Image.open(p).convert("RGB"))
    except Exception:
        pass
    if len(out) < 3:
        pytest.skip("needs scikit-image and sporco (pip install scikit-image; pip install --no-deps sporco)")
    return {k: np.ascontiguousarray(v[: v.shape[0] // 2 * 2, : v.shape[1] // 2 * 2, :3]) for k, v in out.items()}


@pytest.fixture(scope="module")
def natural() -> dict[str, np.ndarray]:
    return _natural_images()


def _t(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(a.copy()).permute(2, 0, 1).to(torch.float32) / 255.0


def _psnr(a: torch.Tensor, b: torch.Tensor, crop: int = 8) -> float:
    d = (a - b)[..., crop:-crop, crop:-crop]
    return float(10.0 * torch.log10(1.0 / (d**2).mean()))


# ----------------------------------------------------------------- 1. transfer curve, unprocess


def test_srgb_curve_exact_values_inverse_and_eps_clamp():
    x = torch.tensor([0.0, 0.04045, 0.5, 1.0])
    lin = isp.srgb_to_linear(x)
    assert lin[0].item() == pytest.approx(1e-8 / 12.92, rel=1e-6)  # input clamped at eps = 1e-8
    assert lin[1].item() == pytest.approx(0.04045 / 12.92, rel=1e-6)
    assert lin[2].item() == pytest.approx(((0.5 + 0.055) / 1.055) ** 2.4, rel=1e-6)  # 0.214041
    assert lin[3].item() == pytest.approx(1.0, abs=1e-7)
    assert isp.srgb_to_linear(torch.tensor([-0.3])).item() == lin[0].item()
    s = torch.linspace(0, 1, 10001, dtype=torch.float64)
    assert (isp.linear_to_srgb(isp.srgb_to_linear(s)) - s).abs().max() < 1e-7  # exact inverse pair
    # continuity at the breakpoints of both branches
    assert abs(((0.04045 + 0.055) / 1.055) ** 2.4 - 0.04045 / 12.92) < 1e-6
    assert abs(1.055 * 0.0031308 ** (1 / 2.4) - 0.055 - 12.92 * 0.0031308) < 1e-6


def test_unprocess_is_seeded_records_its_draw_and_inverts_wb_and_ccm():
    prof = load_sensor("fullframe_dslr")
    grey = torch.full((3, 4, 6), 0.5)
    a, pa = isp.unprocess(grey, prof, torch.Generator().manual_seed(11))
    b, pb = isp.unprocess(grey, prof, torch.Generator().manual_seed(11))
    c, pc = isp.unprocess(grey, prof, torch.Generator().manual_seed(12))
    assert torch.equal(a, b) and pa == pb and pc.kelvin != pa.kelvin
    lo, hi = prof.kelvin_range
    assert lo <= pa.kelvin <= hi
    assert (pa.r_gain, pa.b_gain) == prof.wb_gains(pa.kelvin)
    # grey stays grey through the inverse CCM (rows sum to 1); the inverse WB divides by the gains
    lin = ((0.5 + 0.055) / 1.055) ** 2.4
    want = torch.tensor([lin / pa.r_gain, lin, lin / pa.b_gain]).view(3, 1, 1).expand(3, 4, 6)
    assert torch.allclose(a, want, atol=1e-6)
    d, pd = isp.unprocess(grey, prof, kelvin=3200.0)
    assert pd.kelvin == 3200.0 and (pd.r_gain, pd.b_gain) == prof.wb_gains(3200.0)


@pytest.mark.parametrize("sensor", ["fullframe_dslr", "phone"])
def test_round_trip_unprocess_process_within_one_code(natural, sensor):
    """process(unprocess(x)) with no blur and no noise returns the 8-bit input within 1/255
    (measured: exactly, 0 codes off, on every image and colour temperature tried)."""
    prof = load_sensor(sensor)
    g = torch.Generator().manual_seed(5)
    worst = 0
    for a in natural.values():
        x = _t(a)
        for _ in range(2):
            cam, params = isp.unprocess(x, prof, g)
            out = isp.to_uint(isp.process(cam, params, bits=8), 8)
            worst = max(worst, int(np.abs(out.astype(int) - a.astype(int)).max()))
    assert worst <= 1, worst
    # batches go through in one call
    xb = torch.stack([_t(natural["astronaut"])[:, :64, :64], _t(natural["coffee"])[:, :64, :64]])
    cam, params = isp.unprocess(xb, prof, g)
    assert cam.shape == xb.shape
    assert (isp.process(cam, params, bits=None) - xb).abs().max() < 0.5 / 255


# ----------------------------------------------------------------- 3. mosaic, noise


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_mosaic_places_colours_by_pattern(pattern):
    h, w = 6, 8
    rgb = torch.stack([torch.full((h, w), 1.0), torch.full((h, w), 2.0), torch.full((h, w), 3.0)])
    raw = isp.mosaic(rgb, pattern)
    code = {"R": 1.0, "G": 2.0, "B": 3.0}
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        assert torch.all(raw[dy::2, dx::2] == code[pattern[k]])
    m = isp.bayer_masks(pattern, h, w)
    assert torch.all(m.sum(0) == 1) and m[1].sum() == h * w / 2 and m[0].sum() == h * w / 4
    assert torch.equal(raw, (rgb * m).sum(0))
    assert isp.mosaic(rgb.expand(2, 3, h, w), pattern).shape == (2, h, w)
    odd = isp.mosaic(rgb[:, :5, :7], pattern)  # odd sizes: the pattern starts at the top-left pixel
    assert torch.equal(odd, raw[:5, :7])
    with pytest.raises(InputError, match="bayer_pattern"):
        isp.mosaic(rgb, "RGBG")


def test_noise_variance_matches_shot_x_plus_read_squared():
    """Flat fields at several levels: sample variance within 5% of shot * x + read^2
    (262144 samples: the variance's standard error is 0.3%), mean unbiased."""
    shot, read = 0.01, 0.004
    n = 512
    for level in (0.02, 0.1, 0.4, 0.9):
        flat = torch.full((n, n), level)
        noisy = isp.add_noise(flat, shot, read, torch.Generator().manual_seed(int(level * 1000)))
        var = float(noisy.var())
        want = shot * level + read**2
        assert abs(var / want - 1.0) < 0.05, (level, var, want)
        assert abs(float(noisy.mean()) - level) < 4 * (want / n**2) ** 0.5
    g1, g2 = torch.Generator().manual_seed(1), torch.Generator().manual_seed(1)
    assert torch.equal(isp.add_noise(flat, shot, read, g1), isp.add_noise(flat, shot, read, g2))
    assert torch.equal(isp.add_noise(flat, 0.0, 0.0), flat)
    with pytest.raises(InputError):
        isp.add_noise(flat, -1.0, 0.0)


def test_quantize_raw_snaps_to_digital_numbers_and_saturates():
    prof = load_sensor("phone")  # black 64, white 1023 (10 bit)
    scale = prof.white_level - prof.black_level
    raw = torch.tensor([[-1.0, 0.0, 0.5, 1.3], [0.25, 0.999, 1.0, 1e-4]])
    q = isp.quantize_raw(raw, prof)
    dn = q * scale + prof.black_level
    assert torch.allclose(dn, torch.round(dn), atol=1e-3)
    assert q[0, 3] == 1.0 and q[0, 0] == pytest.approx(-prof.black_level / scale)
    assert (q - raw.clamp(-prof.black_level / scale, 1.0)).abs().max() <= 0.5 / scale + 1e-6


# ----------------------------------------------------------------- 4. demosaic


@pytest.mark.parametrize("method", ["ahd", "bilinear", "malvar", "menon"])
@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_demosaic_reproduces_flat_colour_fields(method, pattern):
    if method in ("malvar", "menon"):
        pytest.importorskip("colour_demosaicing")
    rgb = torch.tensor([0.3, 0.5, 0.7]).view(3, 1, 1).expand(3, 32, 48).contiguous()
    out = isp.demosaic(isp.mosaic(rgb, pattern), pattern, method)
    assert out.shape == (3, 32, 48) and out.dtype == torch.float32
    assert (out - rgb).abs().max() < 1e-5


def test_ahd_blocks_and_median_network_are_exact():
    g = torch.Generator().manual_seed(0)
    raw = torch.rand(70, 52, generator=g)
    whole = isp.demosaic_ahd(raw, "GRBG", block_rows=10_000)
    for rows in (4, 16):
        assert torch.equal(isp.demosaic_ahd(raw, "GRBG", block_rows=rows), whole)
    x = torch.rand(2, 3, 9, 11, generator=g)
    ref = torch.nn.functional.pad(x, (1, 1, 1, 1), mode="reflect").unfold(2, 3, 1).unfold(3, 3, 1)
    assert torch.equal(isp._median3x3(x), ref.reshape(2, 3, 9, 11, 9).median(-1).values)
    with pytest.raises(InputError, match="method"):
        isp.demosaic(raw, "RGGB", "vng")
    with pytest.raises(InputError, match="apply to 'ahd' only"):
        isp.demosaic(raw, "RGGB", "malvar", median_passes=2)
    odd = raw[:69, :51]  # odd sizes keep the Bayer phase at every border
    for method in ("ahd", "bilinear", "malvar"):
        flat = torch.tensor([0.3, 0.5, 0.7]).view(3, 1, 1).expand(3, 69, 51)
        assert (isp.demosaic(isp.mosaic(flat, "GRBG"), "GRBG", method) - flat).abs().max() < 1e-5
    assert torch.equal(isp.demosaic_ahd(odd, "GRBG", block_rows=16), isp.demosaic_ahd(odd, "GRBG", block_rows=1000))
    assert isp.demosaic(raw.expand(2, 70, 52), "RGGB", "bilinear").shape == (2, 3, 70, 52)


def test_ahd_psnr_on_natural_images_at_least_malvars(natural):
    """Through the simulation's own path (unprocess at 5000 K, mosaic, white balance on the
    mosaic, demosaic, process; PSNR in sRGB against the input, 8-pixel border cropped)
    AHD must score at least Malvar's PSNR on every image. Measured (dB, AHD / Malvar /
    bilinear): astronaut 33.6 / 29.5 / 26.1, coffee 30.1 / 27.8 / 25.4,
    kodim23 36.4 / 34.0 / 30.8."""
    pytest.importorskip("colour_demosaicing")
    prof = load_sensor("fullframe_dslr")
    for name, a in natural.items():
        x = _t(a)
        cam, params = isp.unprocess(x, prof, kelvin=5000.0)
        raw = isp.white_balance_mosaic(
            isp.mosaic(cam, prof.bayer_pattern), prof.bayer_pattern, params.r_gain, params.b_gain
        )
        scores = {}
        for method in ("ahd", "malvar", "bilinear"):
            rgb = isp.demosaic(raw, prof.bayer_pattern, method)
            scores[method] = _psnr(isp.process(rgb, params, bits=None, white_balanced=True), x)
        assert scores["ahd"] >= scores["malvar"], (name, scores)
        assert scores["ahd"] > scores["bilinear"] + 2.0, (name, scores)


# ----------------------------------------------------------------- 5. process, full chain, raw files


def test_process_quantizes_and_white_balanced_flag_skips_gains():
    prof = load_sensor("fullframe_dslr")
    x = torch.rand(3, 8, 8, generator=torch.Generator().manual_seed(2))
    cam, params = isp.unprocess(x, prof, kelvin=4000.0)
    out8 = isp.process(cam, params, bits=8)
    assert torch.allclose(out8 * 255, torch.round(out8 * 255), atol=1e-4)
    out16 = isp.process(cam, params, bits=16)
    assert (out16 - x).abs().max() < 1.0 / 65535  # the float path is exact to 16-bit precision
    pre = isp.white_balance(cam, params.r_gain, params.b_gain)
    assert torch.equal(isp.process(pre, params, bits=None, white_balanced=True), isp.process(cam, params, bits=None))
    u = isp.to_uint(out16, 16)
    assert u.dtype == np.uint16 and u.shape == (8, 8, 3)
    with pytest.raises(InputError):
        isp.quantize(x, 12)


def test_simulate_capture_is_deterministic_and_close_without_noise(natural):
    prof = load_sensor("phone")
    x = _t(natural["kodim23"])[:, :128, :192]
    a, pa = simulate_capture(x, prof, torch.Generator().manual_seed(9))
    b, pb = simulate_capture(x, prof, torch.Generator().manual_seed(9))
    assert torch.equal(a, b) and pa == pb and pa.shot is not None and pa.read is not None
    clean, pc = simulate_capture(x, prof, torch.Generator().manual_seed(9), noise=False, adc=False)
    assert pc.shot is None and _psnr(clean, x) > 30.0
    assert _psnr(a, x) < _psnr(clean, x)  # noise costs something
    seen = []
    simulate_capture(x, prof, torch.Generator().manual_seed(9), blur=lambda c: seen.append(c.shape) or c)
    assert seen == [(3, 128, 192)]
