"""The PSF-informed network (issue 23): the Wiener stage against a direct per-tile Wiener,
its training cache, the network end to end at tiny size, tiling, ONNX and bad inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from lensim.assets.images import sample_image_path
from lensim.data.pairs import make_dataset
from lensim.errors import InputError
from lensim.evaluate import baselines as B
from lensim.evaluate import harness
from lensim.images import read_image, write_image
from lensim.render.mapping import SensorMapping
from lensim.restore.infer import restore_image
from lensim.restore.models import build_model
from lensim.restore.psf_stage import (
    STAGE_JSON,
    WienerStage,
    cached_path,
    ensure_wiener_cache,
    photo_wiener,
    wiener_channels,
)
from lensim.restore.psfnet import PSFNet
from lensim.restore.train import train
from tests.test_baselines import PITCH_UM, _bank
from tests.tiny_camera import tiny_camera

pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ----------------------------------------------------------------------------- the stage


def _direct_wiener(window: np.ndarray, kernels: list[np.ndarray], var_n: float, margin: int) -> np.ndarray:
    """Wiener deconvolution of one (n, n) window with (P, P) kernels (one, or several draws'),
    written out with NumPy: mean removed, raised-cosine taper over the outer ``margin``
    pixels, each kernel's OTF H about its centre pixel, the filter conj(E[H]) / (E[|H|^2] +
    NSR) (E: the mean over the kernels; one kernel: conj(H) / (|H|^2 + NSR)), NSR of the
    1/|f|^2 prior scaled by the window's mean squared gradient (wiener_tiles' docstring),
    the mean restored as mean E[H(0)] / E[|H(0)|^2] (one kernel: mean / kernel sum)."""
    n = window.shape[0]
    ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(margin) + 0.5) / margin)
    taper = np.concatenate([ramp, np.ones(n - 2 * margin), ramp[::-1]])
    otfs = []
    for kernel in kernels:
        p = kernel.shape[0]
        big = np.zeros((n, n))
        big[:p, :p] = kernel
        otfs.append(np.fft.fft2(np.roll(big, (-(p // 2), -(p // 2)), axis=(0, 1))))
    mean_h = np.mean(otfs, axis=0)
    power = np.mean([np.abs(h) ** 2 for h in otfs], axis=0)
    f = np.fft.fftfreq(n)
    g2 = 4 * np.sin(np.pi * f)[:, None] ** 2 + 4 * np.sin(np.pi * f)[None, :] ** 2
    grad = np.mean(np.diff(window, axis=1) ** 2) + np.mean(np.diff(window, axis=0) ** 2)
    amp = max(grad - 4 * var_n, 4 * var_n, 1e-8)
    y = np.fft.fft2((window - window.mean()) * taper[:, None] * taper[None, :])
    x = np.conj(mean_h) * y / (power + var_n / amp * g2)
    return np.real(np.fft.ifft2(x)) + window.mean() * mean_h[0, 0].real / power[0, 0]


def _trapezoid(count: int, tile: int, ramp: int, size: int) -> np.ndarray:
    """(count, size) weight of each tile along one axis: 1 inside it, linear cross-fades of
    ``ramp`` pixels centred on the inner borders, 1 out to the image's borders."""
    w = np.zeros((count, size))
    for t in range(count):
        for x in range(size):
            lo, hi = t * tile, (t + 1) * tile  # the tile's borders
            up = 1.0 if t == 0 else np.clip((x + 0.5 - (lo - ramp / 2)) / ramp, 0, 1)
            down = 1.0 if t == count - 1 else np.clip(((hi + ramp / 2) - (x + 0.5)) / ramp, 0, 1)
            w[t, x] = min(up, down)
    return w


def _other_banks() -> list:
    """Two banks unlike _bank(): its kernels turned upside down, and shifted one pixel."""
    flipped, shifted = _bank(), _bank()
    for f in flipped.fields:
        f.rgb = np.ascontiguousarray(np.flip(f.rgb, -2))
    for f in shifted.fields:
        f.rgb = np.ascontiguousarray(np.roll(f.rgb, 1, -1))
    return [flipped, shifted]


@pytest.mark.parametrize("robust", [False, True], ids=["one bank", "three draws"])
def test_stage_equals_a_direct_per_tile_wiener(robust):
    """Every pixel of the stage is the cross-fade of the direct Wiener deconvolutions of its
    tiles' windows, each with the bank's kernel at its tile's centre (``bank.psf_at``) and
    its window's own NSR, per channel, in the energy domain; with several draws' banks (the
    tolerance-robust stage) the filter is conj(E[H]) / (E[|H|^2] + NSR) over their kernels
    at the tile's centre."""
    bank = _bank()
    draws = [bank, *_other_banks()] if robust else [bank]
    img, _ = read_image(sample_image_path("kodim23"))
    image = img[:, 200:296, 300:390]
    mapping = SensorMapping(96, 90, PITCH_UM, 1.3, 1.7)  # off axis: rotated, asymmetric kernels
    capture = {
        "ccm": [[1.8, -0.6, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]],
        "r_gain": 1.9,
        "b_gain": 1.6,
        "shot": 1e-3,
        "read": 2e-3,
    }
    stage = WienerStage(tile=32, noise_floor=1e-5, ramp=8, margin=6)
    out = wiener_channels(image, mapping, draws if robust else bank, capture, stage)
    assert out.shape == (3, 96, 90) and out.dtype == torch.float32
    cam = B.to_energy(image, capture).numpy()
    t, m, half = stage.tile, stage.margin, stage.ramp // 2 + stage.margin
    n = t + 2 * half
    padded = np.pad(cam, ((0, 0), (half, half + t), (half, half + t)), mode="symmetric")
    wy, wx = _trapezoid(3, t, stage.ramp, 96), _trapezoid(3, t, stage.ramp, 90)
    direct = np.zeros((3, 96 + 2 * half + t, 90 + 2 * half + t))
    for a in range(3):
        for b in range(3):
            x_mm, y_mm = mapping.pixel_to_mm(torch.tensor((a + 0.5) * t - 0.5), torch.tensor((b + 0.5) * t - 0.5))
            ks = [d.psf_at(float(x_mm), float(y_mm)) for d in draws]
            for ch in range(3):
                win = padded[ch, a * t : a * t + n, b * t : b * t + n]
                var_n = capture["shot"] * max(win.mean(), 0) + capture["read"] ** 2 + stage.noise_floor
                res = _direct_wiener(win.astype(np.float64), [k[ch].astype(np.float64) for k in ks], var_n, m)
                direct[ch, a * t : a * t + n, b * t : b * t + n] += (
                    np.pad(wy[a], (half, half + t))[a * t : a * t + n, None]
                    * np.pad(wx[b], (half, half + t))[None, b * t : b * t + n]
                    * res
                )
    direct = direct[:, half : half + 96, half : half + 90]
    got = B.to_energy(out, capture).numpy()
    ref = B.to_energy(B.from_energy(torch.from_numpy(direct), capture), capture).numpy()  # the same clipping
    err = np.abs(got - ref)
    assert err.max() < 3e-4 and err.mean() < 2e-5, (err.max(), err.mean())
    # and it can fail: the kernels of the neighbouring tile, or no cross-fade, are far off
    assert np.abs(direct - np.roll(direct, 1, axis=-1)).mean() > 20 * err.mean()
    # and the oracle baseline is the same computation (one home)
    oracle = B.wiener(
        image, mapping, tuple(draws) if robust else bank, capture, tile=32, noise_floor=1e-5, ramp=8, margin=6
    )
    assert torch.equal(oracle, out)
    if robust:  # and the draws' spread matters: the robust stage is not the first draw's
        plain = B.to_energy(wiener_channels(image, mapping, bank, capture, stage), capture).numpy()
        assert np.abs(plain - ref).mean() > 20 * err.mean()


def test_robust_stage_of_equal_draws_is_the_stage():
    """The tolerance-robust stage over draws that are all the same lens is that lens's
    stage, for banks and for lenses with poses (banks by source; a symmetric draw's one
    bank in every source); draws that differ give another image."""
    from lensim.render.posed import MIRROR, QUADRANTS
    from lensim.restore.psf_stage import draws_by_source

    bank = _bank()
    other = _other_banks()[0]
    img, _ = read_image(sample_image_path("kodim23"))
    image = img[:, 200:296, 300:390]
    mapping = SensorMapping(96, 90, PITCH_UM, -40 * PITCH_UM * 1e-3, -30 * PITCH_UM * 1e-3)  # across the axis
    stage = WienerStage(tile=32, noise_floor=1e-5, ramp=8, margin=6)
    plain = wiener_channels(image, mapping, bank, None, stage)
    same = wiener_channels(image, mapping, [bank, bank, bank], None, stage)
    assert torch.allclose(same, plain, rtol=0, atol=2e-6), (same - plain).abs().max()
    keys = [k + m for k in QUADRANTS for m in ("", MIRROR)]
    posed = dict.fromkeys(keys, bank)
    assert torch.allclose(wiener_channels(image, mapping, [posed, bank, posed], None, stage), plain, atol=2e-6)
    assert draws_by_source([posed, bank])["ur"] == (bank, bank)
    with pytest.raises(ValueError, match="same sources"):
        draws_by_source([posed, {"ur": bank}])
    mixed = wiener_channels(image, mapping, [bank, other], None, stage)
    assert (mixed - plain).abs().mean() > 1e-4  # 50 times the tolerance above
    # posed draws: each source's pixels get the robust stage over the draws' banks of that source
    flip = {k: other if k.startswith("u") else bank for k in keys}
    out = wiener_channels(image, mapping, [posed, flip], None, stage)
    from lensim.render.posed import pixel_sources

    for key, mask in pixel_sources((96, 90), mapping, mirrored=True).items():
        want = mixed if key.startswith("u") else plain
        m = torch.from_numpy(mask)
        assert torch.allclose(out[:, m], want[:, m], rtol=0, atol=2e-6), key


def test_stage_settings_are_checked():
    assert WienerStage.from_dict(None) == WienerStage()
    # the stage's defaults are the oracle's (one computation, lensim.evaluate.wiener_tiles)
    from lensim.evaluate import wiener_tiles as WT

    st = WienerStage()
    assert (st.tile, st.ramp, st.margin) == (WT.DEFAULT_TILE, WT.DEFAULT_RAMP, WT.DEFAULT_MARGIN)
    assert st.noise_floor == B.DEFAULT_NOISE_FLOOR
    assert WienerStage.from_dict({"tile": 16, "ramp": 8}).tile == 16
    # a config of the old stage (32 px mirrored windows) reads as today's stage, its noise floor kept
    assert WienerStage.from_dict({"tile": 32, "noise_floor": 1e-4}) == WienerStage(noise_floor=1e-4)
    with pytest.raises(InputError, match="stage"):
        WienerStage.from_dict({"tile": 64, "ramp": 15})
    with pytest.raises(InputError, match="stage"):
        WienerStage.from_dict({"tile": 0, "ramp": 0})
    with pytest.raises(InputError, match="stage"):
        WienerStage.from_dict({"tile": 16, "nsr": 1})


# ----------------------------------------------------------------------------- pairs


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Two photos on a 128 x 96 pixel sensor (the APS-C profile's pitch), two 64 px crops
    each, and the bank they were made with."""
    base = tmp_path_factory.mktemp("psfnet")
    sharp, sensor_file, sensor, bank = tiny_camera(base)
    make_dataset(sharp, base / "pairs", bank, str(sensor_file), sensor, crops=2, size=64, seed=1)
    return {"pairs": base / "pairs", "bank": bank, "sensor": sensor, "base": base}


def test_cache_is_the_stage_of_each_crop_and_resumes(world):
    pairs = world["pairs"]
    folder = ensure_wiener_cache(pairs)
    manifest = json.loads((pairs / "manifest.json").read_text())
    crop = manifest["records"][0]["crops"][0]
    stored, bits = read_image(cached_path(folder, pairs / crop["input"]))
    assert bits == 16
    # equal to the stage computed the way the evaluation computes it, up to 16-bit rounding
    x, _ = read_image(pairs / crop["input"])
    rows = []
    harness.evaluate(pairs, {"wiener": harness.builtin_method("wiener")}, rows=rows, max_crops=1)
    from lensim.data.pairs import crop_capture
    from lensim.render.mapping import native_mapping

    mapping = native_mapping(64, 64, world["sensor"], crop["sensor_top"], crop["sensor_left"])
    live = wiener_channels(x, mapping, world["bank"], crop_capture(manifest["records"][0], crop))
    assert (stored - live).abs().max() < 1.0 / 65535 + 1e-6
    info = json.loads((folder / STAGE_JSON).read_text())
    assert info["crops"] == 4 and info["stage"] == WienerStage().to_dict()
    # a killed computation: a missing file is computed again, the others are kept
    victim = cached_path(folder, pairs / crop["input"])
    other = cached_path(folder, pairs / manifest["records"][1]["crops"][0]["input"])
    mtime = other.stat().st_mtime_ns
    victim.unlink()
    assert ensure_wiener_cache(pairs) == folder
    assert victim.exists() and other.stat().st_mtime_ns == mtime


def test_cache_without_the_bank_is_one_line(world, tmp_path):
    import shutil

    copy = tmp_path / "pairs"
    shutil.copytree(world["pairs"], copy, ignore=shutil.ignore_patterns("wiener"))
    m = json.loads((copy / "manifest.json").read_text())
    m["bank"] = str(tmp_path / "gone")
    (copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(InputError, match="bank") as e:
        ensure_wiener_cache(copy)
    assert "\n" not in str(e.value)


# ----------------------------------------------------------------------------- network


def test_untrained_network_is_the_wiener_stage_and_tiles_equal_the_whole():
    torch.manual_seed(0)
    net = PSFNet(width=8, use_fov=True, stem=2).eval()
    rgb, wien = torch.rand(1, 3, 50, 70), torch.rand(1, 3, 50, 70)
    fov = torch.rand(1, 2, 50, 70)
    assert torch.equal(net(rgb, fov, None, wien), wien)  # zero-initialised tail
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    assert build_model(net.config).config == net.config
    image, wiener = torch.rand(3, 200, 180), torch.rand(3, 200, 180)
    whole = restore_image(net, image, (10.0, 20.0), (400.0, 600.0), tile=4096, wiener=wiener)
    tiled = restore_image(net, image, (10.0, 20.0), (400.0, 600.0), tile=96, overlap=80, margin=36, wiener=wiener)
    assert (whole - tiled).abs().max() < 1e-4
    with pytest.raises(ValueError, match="Wiener"):
        restore_image(net, image, (10.0, 20.0), (400.0, 600.0))


TINY = dict(width=8, depth=2, crop=32, batch_size=2, lr=3e-3, val_fraction=0.5, val_batch_size=4, seed=0)


@pytest.fixture(scope="module")
def run(world, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "psfnet"
    res = train(world["pairs"], out, arch="psfnet", epochs=2, **TINY)
    return out, res


def test_trains_and_restores_end_to_end(world, run):
    out, res = run
    assert res.step > 0 and math.isfinite(res.last_loss)
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["arch"] == "psfnet"
    rows = []
    methods = {"model": harness.checkpoint_method(out / "last.pt"), "wiener": harness.builtin_method("wiener")}
    summary = harness.evaluate(world["pairs"], methods, rows=rows)
    assert math.isfinite(summary["methods"]["model"]["psnr_db"])
    # a whole photo at the sensor's native scale: the stage, then the network's tiles
    from lensim.restore.checkpoint import load_checkpoint

    model, _ = load_checkpoint(out / "last.pt")
    photo = torch.rand(3, 96, 128)
    wien = photo_wiener(photo, world["bank"], world["sensor"], (0.0, 0.0), (96.0, 128.0), stage=model.stage)
    restored = restore_image(model, photo, (0.0, 0.0), (96.0, 128.0), tile=64, overlap=32, wiener=wien)
    assert restored.shape == photo.shape and torch.isfinite(restored).all()
    with pytest.raises(InputError, match="native"):
        photo_wiener(photo[:, :48, :64], world["bank"], world["sensor"], (0.0, 0.0), (48.0, 64.0))


def test_onnx_export_takes_the_wiener_image_as_a_named_input(run):
    from lensim.restore.checkpoint import load_checkpoint
    from lensim.restore.engines import OnnxEngine
    from lensim.restore.export import export_model_bytes

    out, _ = run
    model, info = load_checkpoint(out / "last.pt")
    engine = OnnxEngine(export_model_bytes(model, info), threads=1)
    assert engine.uses_wiener and engine.stage == model.stage
    assert engine.input_names == ["rgb", "fov", "wiener"]
    assert engine.metadata["inputs"]["wiener"].startswith("(N, 3, H, W)")
    gen = torch.Generator().manual_seed(1)
    image, wiener = torch.rand(3, 70, 90, generator=gen), torch.rand(3, 70, 90, generator=gen)
    ref = restore_image(model, image, (5.0, 7.0), (96.0, 128.0), tile=64, overlap=32, wiener=wiener)
    got = restore_image(engine, image, (5.0, 7.0), (96.0, 128.0), tile=64, overlap=32, wiener=wiener)
    assert (ref - got).abs().max() < 1e-4


def test_cli_restores_a_photo_and_refuses_a_missing_bank(world, run, tmp_path, capsys, monkeypatch):
    from tests.cli_runner import run_cli

    out, _ = run
    photo = tmp_path / "photo.png"
    write_image(photo, torch.rand(3, 96, 128), 8)
    code, _, err = run_cli(
        ["restore", str(out), str(photo), "-o", str(tmp_path / "restored"), "--quiet"], capsys, monkeypatch
    )
    assert code == 0, err
    assert (tmp_path / "restored" / "photo.png").exists()
    args = ["restore", str(out), str(photo), "-o", str(tmp_path / "r2"), "--bank", str(tmp_path / "nothing")]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "nothing" in err, err
    assert not (tmp_path / "r2" / "photo.png").exists()


def test_stage_of_a_lens_with_poses_takes_each_pixels_own_sources_bank():
    """Banks by source (lensim.render.posed.posed_banks): each pixel's stage is the one
    computed with the bank of its source (its quadrant, split at the optical axis, and the
    mirrored lens's where the kernel is taken mirrored); one bank under every key gives
    the plain stage."""
    from lensim.render.posed import MIRROR, QUADRANTS, pixel_sources

    bank = _bank()
    other = _bank()
    for f in other.fields:
        f.rgb = np.ascontiguousarray(np.flip(f.rgb, -2))  # the kernels turned upside down
    img, _ = read_image(sample_image_path("kodim23"))
    image = img[:, 200:296, 300:390]
    mapping = SensorMapping(96, 90, PITCH_UM, -40 * PITCH_UM * 1e-3, -30 * PITCH_UM * 1e-3)  # across the axis
    stage = WienerStage(tile=32, noise_floor=1e-5, ramp=8, margin=6)
    keys = [k + m for k in QUADRANTS for m in ("", MIRROR)]
    plain = wiener_channels(image, mapping, bank, None, stage)
    assert torch.equal(wiener_channels(image, mapping, dict.fromkeys(keys, bank), None, stage), plain)
    banks = {k: other if k in ("ur", "ll" + MIRROR, "lr" + MIRROR) else bank for k in keys}
    out = wiener_channels(image, mapping, banks, None, stage)
    flipped = wiener_channels(image, mapping, other, None, stage)
    sources = pixel_sources((96, 90), mapping, mirrored=True)
    assert all(sources[k].any() for k in keys)  # every source has pixels in this frame
    for key, mask in sources.items():
        want = flipped if banks[key] is other else plain
        assert torch.equal(out[:, torch.from_numpy(mask)], want[:, torch.from_numpy(mask)])
    assert not torch.equal(out, plain)
    # a frame whose sources' boxes (grown by whole tiles) are smaller than it: each source is
    # computed on its box only, and its pixels are still what the whole-frame stage gives
    big = img[:, 100:420, 120:420]
    wide = SensorMapping(320, 300, PITCH_UM, -170 * PITCH_UM * 1e-3, -150 * PITCH_UM * 1e-3)
    whole = {id(b): wiener_channels(big, wide, b, None, stage) for b in (bank, other)}
    out = wiener_channels(big, wide, banks, None, stage)
    for key, mask in pixel_sources((320, 300), wide, mirrored=True).items():
        m = torch.from_numpy(mask)
        assert torch.allclose(out[:, m], whole[id(banks[key])][:, m], rtol=0, atol=1e-6), key
