"""Training losses (lensim.restore.losses, TrainConfig.loss, `lensim train --loss`): the
Laplacian against its formula, each loss's value at a perfect output, the edge term
ranking an over-smoothed output below one with an equally large smooth error (MSE ranks
them equal), training with each loss, and the loss frozen on resume."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from lensim.errors import InputError
from lensim.restore.losses import CHARBONNIER_EPS, EDGE_WEIGHT, LOSSES, laplacian, restoration_loss
from lensim.restore.run_log import read_csv
from lensim.restore.train import train
from test_train import TINY, make_pairs


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_pairs(tmp_path_factory.mktemp("pairs"))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_laplacian_matches_its_formula() -> None:
    """Interior: up + down + left + right - 4 * centre; zero on a plane a + b y + c x;
    reflect padding at the border (a corner sees its neighbours twice)."""
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 9, 11, generator=g, dtype=torch.float64)
    lap = laplacian(x)
    want = x[..., :-2, 1:-1] + x[..., 2:, 1:-1] + x[..., 1:-1, :-2] + x[..., 1:-1, 2:] - 4 * x[..., 1:-1, 1:-1]
    torch.testing.assert_close(lap[..., 1:-1, 1:-1], want)
    torch.testing.assert_close(lap[..., 0, 0], 2 * x[..., 1, 0] + 2 * x[..., 0, 1] - 4 * x[..., 0, 0])
    yy, xx = torch.meshgrid(
        torch.arange(9.0, dtype=torch.float64), torch.arange(11.0, dtype=torch.float64), indexing="ij"
    )
    plane = (0.3 + 0.02 * yy - 0.01 * xx).expand(1, 3, 9, 11)
    assert float(laplacian(plane)[..., 1:-1, 1:-1].abs().max()) < 1e-12


def test_a_perfect_output_scores_the_floor_of_each_loss() -> None:
    x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(1))
    floors = {"mse": 0.0, "charbonnier": CHARBONNIER_EPS, "charbonnier-edge": CHARBONNIER_EPS * (1 + EDGE_WEIGHT)}
    assert set(floors) == set(LOSSES)
    for name, floor in floors.items():
        assert math.isclose(float(restoration_loss(name, x, x)), floor, rel_tol=1e-5, abs_tol=1e-12), name


def _textured_target() -> torch.Tensor:
    t = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    return F.avg_pool2d(F.pad(t, (1, 1, 1, 1), mode="reflect"), 3, 1) * 0.6 + 0.2


def test_the_edge_term_does_not_reward_over_smoothing() -> None:
    """Two outputs with the same MSE: the target blurred (fine detail lost) and the target
    plus a smooth shading ramp. MSE cannot tell them apart; charbonnier-edge ranks the
    blurred one worse by more than 15 %."""
    t = _textured_target()
    k = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0])
    k = (k[:, None] * k[None, :]) / 256.0
    smooth = F.conv2d(F.pad(t, (2, 2, 2, 2), mode="reflect"), k.expand(3, 1, 5, 5), groups=3)
    mse = F.mse_loss(smooth, t)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, 64), torch.linspace(-1, 1, 64), indexing="ij")
    ramp = (0.5 * xx + 0.3 * yy).expand_as(t)
    shaded = t + ramp * torch.sqrt(mse / (ramp**2).mean())
    assert math.isclose(float(restoration_loss("mse", shaded, t)), float(mse), rel_tol=1e-4)
    edge_smooth, edge_shaded = (float(restoration_loss("charbonnier-edge", o, t)) for o in (smooth, shaded))
    assert edge_smooth > 1.15 * edge_shaded


@pytest.mark.parametrize("loss", ["charbonnier", "charbonnier-edge"])
def test_training_with_each_loss_lowers_it_and_records_it(pairs: Path, tmp_path: Path, loss: str) -> None:
    """(At lr 1e-3: an L1-like loss's steps do not shrink near the optimum, and 5e-3
    overshoots in 4 steps of this tiny problem.)"""
    res = train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=4, loss=loss, **{**TINY, "lr": 1e-3})
    losses = [r["loss"] for r in read_csv(tmp_path / "run" / "steps.csv")]
    assert len(losses) == 4 and losses == sorted(losses, reverse=True) and losses[-1] < 0.7 * losses[0], losses
    assert res.val_psnr > res.val_input_psnr
    ck = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    assert ck["train_config"]["loss"] == loss


def test_the_loss_is_frozen_on_resume_and_checked(pairs: Path, tmp_path: Path) -> None:
    train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, loss="charbonnier-edge", **TINY)
    with pytest.raises(InputError, match="loss"):
        train(pairs, tmp_path / "run", epochs=2, resume=True, loss="mse")
    res = train(pairs, tmp_path / "run", epochs=2, resume=True, loss="charbonnier-edge")
    assert res.epochs_done == 2
    with pytest.raises(InputError, match="loss.*expected one of mse, charbonnier, charbonnier-edge"):
        train(pairs, tmp_path / "other", epochs=1, loss="ssim", **TINY)


def test_a_checkpoint_without_a_loss_resumes_as_mse(pairs: Path, tmp_path: Path) -> None:
    """Runs made before the option had MSE: their checkpoints lack the key and resume with
    loss="mse", also when it is given explicitly."""
    from lensim.restore.checkpoint import atomic_torch_save

    train(pairs, tmp_path / "run", epochs=1, max_steps_per_epoch=1, **TINY)
    ck = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    del ck["train_config"]["loss"]
    atomic_torch_save(ck, tmp_path / "run" / "last.pt")
    res = train(pairs, tmp_path / "run", epochs=2, resume=True, loss="mse")
    assert res.epochs_done == 2
    assert torch.load(tmp_path / "run" / "last.pt", weights_only=True)["train_config"]["loss"] == "mse"
