"""The fast paths of training-pair simulation against the direct computations they replace
(issue 29): batched kernel turns and lookups, the blur's overlap-add, and the bank loaded
once per process. Small sizes, random kernels (a mix-up of kernels or of turns shows as a
difference of the order of the kernels themselves)."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from lensim.psf.bank import BankField, PSFBank
from lensim.psf.bank.azimuth import AZIMUTHS_DEG
from lensim.psf.bank.store import load_bank_cached
from lensim.render.blur import _fast_len, _hat, spatially_variant_blur, tile_centres
from lensim.render.rotation import rotate_kernel, rotate_kernels


def test_rotate_kernels_equals_rotate_kernel_one_by_one() -> None:
    rng = np.random.default_rng(0)
    k = rng.random((7, 3, 15, 15)) ** 3
    angles = np.array([0.3, -1.8, 1.875, 45.0, 90.0, -30.0, 180.0])
    direct = np.stack([rotate_kernel(k[i], float(a)) for i, a in enumerate(angles)])
    batched = rotate_kernels(k, angles)
    assert np.abs(batched - direct).max() < 1e-12 * direct.max()
    # a 45 degree turn of a 61 px kernel samples beyond scipy's padding: turned one by one
    big = rng.random((2, 1, 61, 61))
    ref = np.stack([rotate_kernel(big[0], 45.0), rotate_kernel(big[1], 1.0)])
    assert np.abs(rotate_kernels(big, np.array([45.0, 1.0])) - ref).max() < 1e-12


def _bank(p: int = 11) -> PSFBank:
    """A bank of random kernels at three fields along +y, with azimuth kernels."""
    rng = np.random.default_rng(3)
    fields = []
    for i, r in enumerate((0.0, 1.0, 2.5)):
        fields.append(
            BankField(
                index=i,
                field=r / 2.5,
                field_value=r,
                rgb=rng.random((3, p, p)).astype(np.float32),
                reference_xy_mm=np.array([0.0, r]),
                paraxial_xy_mm=np.array([0.0, r]),
                chief_offsets_mm=np.zeros((1, 2)),
                relative_illumination=np.ones(1),
                transmission=np.ones(1),
                window_energy=np.ones(1),
                strehl=1.0,
                working_fno=4.0,
                primary_fine=np.zeros((p, p), np.float32),
                rgb_azimuths=rng.random((len(AZIMUTHS_DEG), 3, p, p)).astype(np.float32),
            )
        )
    return PSFBank({"pixel_pitch_um": 4.0, "kernel_pixels": p}, fields)


def test_psfs_at_equals_psf_at_point_by_point() -> None:
    bank = _bank()
    rng = np.random.default_rng(4)
    x, y = rng.uniform(-2.2, 2.2, 40), rng.uniform(-2.2, 2.2, 40)
    # the axis, the bank's direction and its mirror, stored azimuths, beyond the last field
    x = np.concatenate([x, [0.0, 0.0, 0.0, 1.0, -1.0, 2.0 * math.sin(math.radians(7.5)), 3.0]])
    y = np.concatenate([y, [0.0, 1.5, -1.5, 0.0, 0.0, 2.0 * math.cos(math.radians(7.5)), 3.0]])
    direct = np.stack([bank.psf_at(float(a), float(b)) for a, b in zip(x, y, strict=True)])
    batched = bank.psfs_at(x, y)
    assert batched.dtype == np.float32 and batched.shape == direct.shape
    # float64 arithmetic in another order, then float32: at most one float32 step apart
    assert np.abs(batched - direct).max() <= 2e-7 * direct.max()
    assert bank.psfs_at(np.zeros(0), np.zeros(0)).shape == (0, 3, 11, 11)


def test_psfs_at_without_azimuth_kernels_takes_psf_at() -> None:
    bank = _bank()
    for f in bank.fields:
        f.rgb_azimuths = None
    x, y = np.array([0.3, -1.2]), np.array([1.1, 0.4])
    direct = np.stack([bank.psf_at(float(a), float(b)) for a, b in zip(x, y, strict=True)])
    assert np.array_equal(bank.psfs_at(x, y), direct)


def _fold_blur(image: torch.Tensor, kernels: torch.Tensor, tile: int) -> torch.Tensor:
    """The blur as it was computed before issue 29: one FFT convolution per centre over its
    hat's whole support, every block at once, overlap-added with F.fold."""
    c, h, w = image.shape
    hy, hx = _hat(h, tile).float(), _hat(w, tile).float()
    ny, nx = len(tile_centres(h, tile)), len(tile_centres(w, tile))
    p = kernels.shape[-1]
    support, block = 2 * tile + 1, 2 * tile + p
    n_fft = _fast_len(block)
    pad_y, pad_x = ny * tile + 1 - h, nx * tile + 1 - w
    img_p = F.pad(image.float(), (tile, pad_x, tile, pad_y))
    hy_p, hx_p = F.pad(hy, (tile, pad_y)), F.pad(hx, (tile, pad_x))
    idx = torch.arange(ny * nx)
    ty, tx = idx // nx, idx % nx
    ar = torch.arange(support)
    ys, xs = (ty * tile).unsqueeze(1) + ar, (tx * tile).unsqueeze(1) + ar
    patch = img_p[:, ys.unsqueeze(2), xs.unsqueeze(1)]
    wgt = hy_p[ty.unsqueeze(1), ys].unsqueeze(2) * hx_p[tx.unsqueeze(1), xs].unsqueeze(1)
    patch = (patch * wgt.unsqueeze(0)).permute(1, 0, 2, 3)
    pf, kf = torch.fft.rfft2(patch, s=(n_fft, n_fft)), torch.fft.rfft2(kernels.float(), s=(n_fft, n_fft))
    blocks = torch.fft.irfft2(pf * kf, s=(n_fft, n_fft))[..., :block, :block]
    cols = blocks.reshape(ny * nx, c * block * block).T.unsqueeze(0)
    out = F.fold(cols, output_size=((ny - 1) * tile + block, (nx - 1) * tile + block), kernel_size=block, stride=tile)
    r = p // 2
    return out[0, :, tile + r : tile + r + h, tile + r : tile + r + w]


@pytest.mark.parametrize(("h", "w", "tile", "p"), [(45, 70, 16, 9), (65, 97, 32, 7), (64, 33, 32, 5)])
def test_cell_blur_equals_the_per_support_computation(h: int, w: int, tile: int, p: int) -> None:
    # (65, 97): the last row and column lie on the last centres' line, a cell of their own
    g = torch.Generator().manual_seed(0)
    img = torch.rand(3, h, w, generator=g)
    n = len(tile_centres(h, tile)) * len(tile_centres(w, tile))
    kernels = torch.rand(n, 3, p, p, generator=g, dtype=torch.float64)
    ref = _fold_blur(img, kernels, tile)
    got = {chunk: spatially_variant_blur(img, lambda r, c: kernels, tile=tile, chunk=chunk) for chunk in (1, 2, 16)}
    # float32 transforms of other lengths, summed in another order: rounding apart
    assert (got[16] - ref).abs().max().item() < 2e-6 * ref.abs().max().item()
    assert torch.allclose(got[1], got[16], rtol=0, atol=1e-6 * ref.abs().max().item())
    assert torch.allclose(got[2], got[16], rtol=0, atol=1e-6 * ref.abs().max().item())


def test_bank_is_loaded_once_until_its_files_change(tmp_path) -> None:
    from lensim.psf.bank.store import FORMAT, FORMAT_VERSION, MANIFEST, field_file

    bank = _bank()
    d = tmp_path / "bank"
    d.mkdir()
    for f in bank.fields:
        (d / field_file(f.index)).write_bytes(f.to_npz_bytes())
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "pixel_pitch_um": 4.0, "kernel_pixels": 11}
    (d / MANIFEST).write_text(json.dumps({**manifest, "fields": [0, 0.4, 1]}))
    first = load_bank_cached(d)
    assert load_bank_cached(d) is first
    assert np.array_equal(first.fields[1].rgb, bank.fields[1].rgb)
    changed = bank.fields[1]
    changed.rgb = changed.rgb * 2
    (d / field_file(1)).write_bytes(changed.to_npz_bytes())
    os.utime(d / field_file(1), ns=(1, 1))  # rewritten: same size, another time
    again = load_bank_cached(d)
    assert again is not first and np.array_equal(again.fields[1].rgb, changed.rgb)
