"""Classical baselines: Wiener and Richardson-Lucy with the true kernels, unsharp mask."""

import numpy as np
import pytest
import torch

from lensim.assets.images import sample_image_path
from lensim.evaluate import baselines as B
from lensim.evaluate.metrics import psnr
from lensim.images import read_image
from lensim.psf.bank import BankField, PSFBank
from lensim.render.blur import spatially_variant_blur
from lensim.render.kernels import kernel_function
from lensim.render.mapping import SensorMapping

P = 15
PITCH_UM = 4.0


def _kernel(radius_mm: float) -> np.ndarray:
    """(3, P, P) kernels: a Gaussian core that stretches and grows a tail along +y (the
    radial direction of the stored fields) with the field, different per channel."""
    r = np.arange(P) - P // 2
    y, x = np.meshgrid(r, r, indexing="ij")
    out = []
    for c, s in enumerate((1.0, 1.2, 1.4)):
        sy = s * (1.0 + 0.4 * radius_mm)
        k = np.exp(-0.5 * (x / s) ** 2 - 0.5 * ((y - 0.3 * radius_mm) / sy) ** 2)
        k += 0.3 * radius_mm * np.exp(-0.5 * (x / 1.0) ** 2 - 0.5 * ((y - 2.0 - c) / 1.0) ** 2) * (y > 0)
        out.append(k / k.sum() * (1.0 - 0.02 * radius_mm))
    return np.stack(out).astype(np.float32)


def _bank() -> PSFBank:
    radii = [0.0, 1.5, 3.0, 4.5]
    fields = []
    for i, r in enumerate(radii):
        fields.append(
            BankField(
                index=i,
                field=r / 4.5,
                field_value=r,
                rgb=_kernel(r),
                reference_xy_mm=np.array([0.0, r]),
                paraxial_xy_mm=np.array([0.0, r]),
                chief_offsets_mm=np.zeros((2, 2)),
                relative_illumination=np.ones(2),
                transmission=np.ones(2),
                window_energy=np.ones(2),
                strehl=float("nan"),
                working_fno=5.0,
                primary_fine=np.zeros((1, 1)),
                warnings=[],
            )
        )
    manifest = {"pixel_pitch_um": PITCH_UM, "kernel_pixels": P, "fields": [f.field for f in fields]}
    return PSFBank(manifest, fields, None)


@pytest.fixture(scope="module")
def blurred():
    """A sharp 96 x 96 crop (interior of a 160 x 160 blur, so its borders saw real scene
    content), the noise-free energy-domain blur of it, and the crop's sensor mapping
    (off axis: radius 2.2 .. 3.0 mm, so the kernels are asymmetric and rotated)."""
    img, _ = read_image(sample_image_path("kodim23"))
    big = img[:, 150:310, 300:460]
    bank = _bank()
    x0, y0 = 1.2, 1.6  # mm, corner of the 160 px frame
    m_big = SensorMapping(160, 160, PITCH_UM, x0, y0)
    cam = B.to_energy(big)
    blur = spatially_variant_blur(cam.float(), kernel_function(bank, m_big), tile=32).double()
    s = slice(32, 128)
    mapping = SensorMapping(96, 96, PITCH_UM, x0 + 32 * PITCH_UM * 1e-3, y0 + 32 * PITCH_UM * 1e-3)
    sharp = big[:, s, s]
    observed = B.from_energy(blur[:, s, s])
    return sharp, observed, mapping, bank


def test_energy_round_trip_with_a_capture():
    cap = {"ccm": [[1.8, -0.6, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]], "r_gain": 1.9, "b_gain": 1.6}
    img, _ = read_image(sample_image_path("kodim23"))
    x = img[:, :40, :40]
    cam = B.to_energy(x, cap)
    back = B.from_energy(cam, cap)
    # pixels whose linear sRGB stayed in [0, 1] come back exactly (float32 rounding)
    assert (back - x).abs().max() < 1e-5
    # white balance really is undone: the energy-domain image differs from linear sRGB
    assert (cam - B.to_energy(x)).abs().max() > 0.05


def test_tiles_blend_to_a_partition_of_unity(blurred):
    _, observed, mapping, bank = blurred
    cam = B.to_energy(observed)
    same = B.tiled_deconvolve(cam, mapping, bank, lambda win, k: win, tile=24)
    assert (same - cam).abs().max() < 1e-12


# Scores are taken 16 px inside the crop: beyond its border the scene is unknown (the
# deconvolutions mirror the crop there), which costs any method near the border.
INNER = (slice(None), slice(16, -16), slice(16, -16))


def test_wiener_with_the_true_kernel_gains_over_5_db(blurred):
    sharp, observed, mapping, bank = blurred
    before = psnr(observed[INNER], sharp[INNER])
    out = B.wiener(observed, mapping, bank, noise_floor=1e-7)
    after = psnr(out[INNER], sharp[INNER])
    assert after - before > 5.0, (before, after)
    # over the whole crop, border included, it still gains
    assert psnr(out, sharp) > psnr(observed, sharp) + 1.0
    # the oracle needs the right kernels: the axis's kernels do clearly worse
    on_axis = SensorMapping(96, 96, PITCH_UM, -0.192, -0.192)
    wrong = psnr(B.wiener(observed, on_axis, bank, noise_floor=1e-7)[INNER], sharp[INNER])
    assert wrong < after - 2.0, (wrong, after)


def test_richardson_lucy_improves(blurred):
    sharp, observed, mapping, bank = blurred
    before = psnr(observed[INNER], sharp[INNER])
    after = psnr(B.richardson_lucy(observed, mapping, bank, iterations=20)[INNER], sharp[INNER])
    assert after - before > 1.0, (before, after)


def test_unsharp_mask_adds_high_frequencies(blurred):
    _, observed, _, _ = blurred
    out = B.unsharp_mask(observed, sigma_px=1.0, amount=0.6)

    def high(x):  # power above 0.25 cycles/pixel (radially), Hann-windowed mean-free crop
        a = x.numpy().astype(np.float64)
        a = a - a.mean(axis=(-2, -1), keepdims=True)
        win = np.hanning(a.shape[-2])[:, None] * np.hanning(a.shape[-1])[None, :]
        f = np.abs(np.fft.fft2(a * win)) ** 2
        fy = np.fft.fftfreq(a.shape[-2])[:, None]
        fx = np.fft.fftfreq(a.shape[-1])[None, :]
        return float(f[:, np.hypot(fy, fx) > 0.25].sum())

    # the mask's gain is 1 + 0.6 (1 - exp(-2 pi^2 sigma^2 f^2)) >= 1.42 above 0.25 cycles/px,
    # i.e. >= 2.0 in power; clipping to [0, 1] takes a little of it
    assert high(out) > 1.8 * high(observed)
    # and leaves flat regions alone
    flat = torch.full((3, 32, 32), 0.4)
    assert (B.unsharp_mask(flat) - flat).abs().max() < 1e-6


def test_a_bank_at_another_pitch_is_refused(blurred):
    from lensim.errors import InputError

    _, observed, mapping, bank = blurred
    other = SensorMapping(96, 96, 2 * PITCH_UM, mapping.x0_mm, mapping.y0_mm)
    with pytest.raises(InputError, match="pitch"):
        B.wiener(observed, other, bank)


def test_polar_kernels_are_the_banks_at_their_nodes_and_close_between():
    from lensim.render.kernels import PolarKernels

    bank = _bank()
    polar = PolarKernels(bank, step_deg=3.0)
    r = bank.radii_mm[2]
    a = np.radians(33.0)  # a node: 11 steps of 3 degrees
    node = polar.at(np.array([r * np.cos(a)]), np.array([r * np.sin(a)]))[0]
    assert np.abs(node - bank.psf_at(r * np.cos(a), r * np.sin(a))).max() < 1e-6
    # between nodes (radius and azimuth): within 1 % of the kernel's peak
    x, y = 2.2 * np.cos(np.radians(34.4)), 2.2 * np.sin(np.radians(34.4))
    mid, truth = polar.at(np.array([x]), np.array([y]))[0], bank.psf_at(x, y)
    assert np.abs(mid - truth).max() < 0.01 * truth.max()
    # and it can tell azimuths apart: 20 degrees on, the kernel is clearly another
    x2, y2 = 2.2 * np.cos(np.radians(54.4)), 2.2 * np.sin(np.radians(54.4))
    assert np.abs(bank.psf_at(x2, y2) - truth).max() > 0.05 * truth.max()


def test_wiener_tiles_cross_fade_to_a_partition_of_unity():
    from lensim.evaluate.wiener_tiles import tile_weights

    for size, tile, ramp in ((200, 64, 16), (64, 64, 16), (130, 32, 32), (50, 16, 0)):
        w = tile_weights(size, tile, ramp)
        total = torch.zeros(len(w) * tile + ramp)
        for t, row in enumerate(w):
            total[t * tile : t * tile + tile + ramp] += row
        assert (total[ramp // 2 : ramp // 2 + size] - 1).abs().max() < 1e-6, (size, tile, ramp)


def test_mirrored_index_is_numpys_symmetric_padding_however_far_it_reaches():
    import numpy as np

    from lensim.evaluate.wiener_tiles import mirrored_index

    for size, before, after in ((7, 3, 4), (5, 12, 17), (1, 2, 3), (64, 40, 40)):
        line = np.arange(size)
        expected = np.pad(line, (before, after), mode="symmetric")
        assert mirrored_index(-before, size + after, size).tolist() == expected.tolist()
