"""FOV channels (lensim.restore.fov): values, crops, and dihedral augmentation that keeps
the channels equal to the coordinates of the transformed sensor (the authors' release only
moved the values with the pixels; that is shown to fail here)."""

from __future__ import annotations

import math

import pytest
import torch

from lensim.restore.fov import DIHEDRAL_OPS, augment, fov_channels, invert_augment

SENSOR_H, SENSOR_W = 10, 14  # non-square sensor: transposes change its shape
CROP_TOP, CROP_LEFT, CROP_H, CROP_W = 2, 7, 5, 4  # off-centre, non-square crop


def test_values_isotropic_and_centred() -> None:
    """x = (c + 0.5 - Ws/2) / R, y = (r + 0.5 - Hs/2) / R with R the half-diagonal (float64,
    1e-15): one pixel step is 1/R on both axes, the map is antisymmetric about the centre,
    and the corner pixel centres lie just inside the unit circle."""
    f = fov_channels(SENSOR_H, SENSOR_W, 0, 0, SENSOR_H, SENSOR_W, dtype=torch.float64)
    assert f.shape == (2, SENSOR_H, SENSOR_W)
    r = 0.5 * math.hypot(SENSOR_H, SENSOR_W)
    assert f[0, 3, 0].item() == pytest.approx((0.5 - SENSOR_W / 2) / r, abs=1e-15)
    assert f[1, 0, 3].item() == pytest.approx((0.5 - SENSOR_H / 2) / r, abs=1e-15)
    step = torch.tensor(1 / r, dtype=torch.float64)
    torch.testing.assert_close(f[0, :, 1:] - f[0, :, :-1], step.expand(SENSOR_H, SENSOR_W - 1), atol=1e-15, rtol=0)
    torch.testing.assert_close(f[1, 1:, :] - f[1, :-1, :], step.expand(SENSOR_H - 1, SENSOR_W), atol=1e-15, rtol=0)
    torch.testing.assert_close(f[0].flip(-1), -f[0], atol=1e-15, rtol=0)
    torch.testing.assert_close(f[1].flip(-2), -f[1], atol=1e-15, rtol=0)
    radius = f.pow(2).sum(0).sqrt()
    assert radius.max().item() < 1.0
    assert radius.max().item() == pytest.approx(math.hypot(SENSOR_H - 1, SENSOR_W - 1) / (2 * r), abs=1e-15)
    # y varies only along rows, x only along columns
    assert torch.all(f[0] == f[0, :1, :]) and torch.all(f[1] == f[1, :, :1])


def test_crop_is_slice_of_full_map() -> None:
    full = fov_channels(SENSOR_H, SENSOR_W, 0, 0, SENSOR_H, SENSOR_W, dtype=torch.float64)
    crop = fov_channels(CROP_H, CROP_W, CROP_TOP, CROP_LEFT, SENSOR_H, SENSOR_W, dtype=torch.float64)
    torch.testing.assert_close(
        crop, full[:, CROP_TOP : CROP_TOP + CROP_H, CROP_LEFT : CROP_LEFT + CROP_W], atol=1e-15, rtol=0
    )
    assert fov_channels(3, 3, 0, 0, 5, 5).dtype == torch.float32
    with pytest.raises(ValueError):
        fov_channels(0, 3, 0, 0, 5, 5)


def _spatial(a: torch.Tensor, op: int) -> torch.Tensor:
    """The op on pixel positions only (what the authors' release does to every channel)."""
    if op & 1:
        a = a.flip(-1)
    if op & 2:
        a = a.flip(-2)
    if op & 4:
        a = a.transpose(-1, -2)
    return a


def _expected_fov(op: int) -> torch.Tensor:
    """FOV channels of the transformed crop read off the *transformed sensor*, found
    without any sign/swap logic: transform a map of sensor pixel indices, locate the
    transformed crop inside the transformed sensor, and call fov_channels there."""
    index = torch.arange(SENSOR_H * SENSOR_W).view(1, SENSOR_H, SENSOR_W)
    crop_index = index[:, CROP_TOP : CROP_TOP + CROP_H, CROP_LEFT : CROP_LEFT + CROP_W]
    t_sensor = _spatial(index, op)[0]
    t_crop = _spatial(crop_index, op)[0]
    (top,), (left,) = torch.nonzero(t_sensor == t_crop[0, 0], as_tuple=True)
    h, w = t_crop.shape
    assert torch.equal(t_sensor[top : top + h, left : left + w], t_crop)
    return fov_channels(h, w, int(top), int(left), t_sensor.shape[0], t_sensor.shape[1], dtype=torch.float64)


@pytest.mark.parametrize("op", DIHEDRAL_OPS)
def test_augmented_fov_equals_transformed_sensor_coordinates(op: int) -> None:
    """For each of the 8 ops the augmented crop's FOV channels equal the coordinates of
    the transformed full-sensor map at the transformed crop's place (float64, 1e-15), and
    the image moves with the pixels."""
    gen = torch.Generator().manual_seed(op)
    rgb = torch.rand(3, CROP_H, CROP_W, generator=gen, dtype=torch.float64)
    fov = fov_channels(CROP_H, CROP_W, CROP_TOP, CROP_LEFT, SENSOR_H, SENSOR_W, dtype=torch.float64)
    rgb_t, fov_t = augment(rgb, fov, op)
    expected = _expected_fov(op)
    assert fov_t.shape == expected.shape
    torch.testing.assert_close(fov_t, expected, atol=1e-15, rtol=0)
    assert torch.equal(rgb_t, _spatial(rgb, op))


@pytest.mark.parametrize("op", [op for op in DIHEDRAL_OPS if op])
def test_moving_values_only_is_wrong(op: int) -> None:
    """The authors' augmentation (move the channel values, do not negate/swap them) fails
    the check above for every op except the identity, so that check has teeth."""
    fov = fov_channels(CROP_H, CROP_W, CROP_TOP, CROP_LEFT, SENSOR_H, SENSOR_W, dtype=torch.float64)
    assert (_spatial(fov, op) - _expected_fov(op)).abs().max().item() > 0.05


@pytest.mark.parametrize("op", DIHEDRAL_OPS)
def test_batched_and_inverse(op: int) -> None:
    """Leading batch dims are carried; invert_augment undoes augment exactly; a batched
    call equals per-sample calls."""
    gen = torch.Generator().manual_seed(10 + op)
    rgb = torch.rand(2, 3, CROP_H, CROP_W, generator=gen)
    fov = torch.stack(
        [fov_channels(CROP_H, CROP_W, t, l, SENSOR_H, SENSOR_W) for t, l in ((0, 0), (CROP_TOP, CROP_LEFT))]
    )
    rgb_t, fov_t = augment(rgb, fov, op)
    for i in range(2):
        r_i, f_i = augment(rgb[i], fov[i], op)
        assert torch.equal(rgb_t[i], r_i) and torch.equal(fov_t[i], f_i)
    rgb_b, fov_b = invert_augment(rgb_t, fov_t, op)
    assert torch.equal(rgb_b, rgb) and torch.equal(fov_b, fov)


def test_full_sensor_map_is_invariant() -> None:
    """The whole sensor's map, augmented, is the map of the transformed sensor: unchanged
    by flips, and by transposes up to the swapped sensor shape (float64, exact)."""
    full = fov_channels(SENSOR_H, SENSOR_W, 0, 0, SENSOR_H, SENSOR_W, dtype=torch.float64)
    img = torch.zeros(1, SENSOR_H, SENSOR_W, dtype=torch.float64)
    full_t = fov_channels(SENSOR_W, SENSOR_H, 0, 0, SENSOR_W, SENSOR_H, dtype=torch.float64)
    for op in DIHEDRAL_OPS:
        torch.testing.assert_close(augment(img, full, op)[1], full_t if op & 4 else full, atol=0, rtol=0)


def test_group_closure_and_errors() -> None:
    """Augmenting twice equals one op of the dihedral group (checked on the off-centre
    crop, where the 8 ops give 8 distinct FOV maps), and bad input is refused."""
    fov = fov_channels(CROP_H, CROP_W, CROP_TOP, CROP_LEFT, SENSOR_H, SENSOR_W, dtype=torch.float64)
    img = torch.zeros(1, CROP_H, CROP_W, dtype=torch.float64)
    maps = {op: augment(img, fov, op)[1] for op in DIHEDRAL_OPS}
    distinct = {tuple(m.shape) + tuple(m.flatten().tolist()) for m in maps.values()}
    assert len(distinct) == 8
    for a in DIHEDRAL_OPS:
        for b in DIHEDRAL_OPS:
            twice = augment(*augment(img, fov, a), b)[1]
            assert sum(m.shape == twice.shape and torch.equal(m, twice) for m in maps.values()) == 1
    with pytest.raises(ValueError, match="op"):
        augment(img, fov, 8)
    with pytest.raises(ValueError, match="2 channels"):
        augment(img, fov[:1], 0)
