"""The CUDA path, run for real where a GPU is present (marker ``gpu``; every case is skipped
on a machine without CUDA, such as CI's): the networks forward and backward against the
CPU, the deformable convolution's CUDA backend against the pure-PyTorch one, mixed-precision
training and its checkpoint round trip, tiled restoration against the CPU, ONNX export from a
CUDA model (and onnxruntime's CUDA provider where it is installed), and universal
pretraining on the GPU. `benchmarks/gpu_check.py` runs them on the device machine.
``LENSIM_GPU_TESTS_DEVICE=cpu`` runs the same cases on the CPU: a dry run of the test code
on a machine without a GPU (the comparisons then hold trivially)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
import torch

from lensim.restore.models import build_model

DEVICE = os.environ.get("LENSIM_GPU_TESTS_DEVICE", "cuda")
CUDA = torch.device(DEVICE)
pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(CUDA.type == "cuda" and not torch.cuda.is_available(), reason="needs CUDA"),
]
TINY_TRAIN = dict(width=8, depth=2, crop=32, batch_size=2, lr=5e-3, val_fraction=0.25, val_batch_size=4, seed=3)


@pytest.fixture(autouse=True)
def exact_float32():
    """Full float32 matrix products on the GPU while comparing against the CPU (TF32 off)."""
    before = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = before


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from test_train import make_pairs

    return make_pairs(tmp_path_factory.mktemp("pairs"))


def _inputs(model: torch.nn.Module, size: int = 64) -> tuple[torch.Tensor | None, ...]:
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, size, size, generator=gen)
    fov = torch.rand(2, 2, size, size, generator=gen) * 2 - 1
    if getattr(model, "uses_wiener", False):
        return (x, fov, None, torch.rand(2, 3, size, size, generator=gen))
    return (x, fov)


def _perturbed(config: dict) -> torch.nn.Module:
    """The network of ``config`` with every weight perturbed (no zero-initialised layer)."""
    torch.manual_seed(0)
    model = build_model(config)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model.eval()


@pytest.mark.parametrize(
    "config",
    [
        {"arch": "nafnet", "width": 16, "stem": 2, "use_fov": True},
        {"arch": "psfnet", "width": 16, "stem": 2, "use_fov": True},
        {"arch": "unet", "width": 8, "depth": 2, "deformable_scales": 1},
    ],
    ids=["nafnet", "psfnet", "unet-dcn"],
)
def test_networks_forward_and_backward_on_cuda_match_the_cpu(config: dict):
    model = _perturbed(config)
    args = _inputs(model)
    with torch.no_grad():
        cpu_out = model(*args)
    gpu = model.to(CUDA)
    gpu_args = tuple(a.to(CUDA) if a is not None else None for a in args)
    out = gpu(*gpu_args)
    assert out.device.type == CUDA.type and out.shape == cpu_out.shape
    assert (out.detach().cpu() - cpu_out).abs().max() < 1e-3
    out.square().mean().backward()
    grads = [p.grad for p in gpu.parameters() if p.requires_grad]
    assert all(g is not None and bool(torch.isfinite(g).all()) for g in grads)


def test_deformable_convolution_cuda_backend_matches_grid_sample():
    from lensim.restore.deform import deform_conv2d

    gen = torch.Generator().manual_seed(1)
    b, c, h, w, k, g = 2, 8, 20, 24, 3, 2
    x = torch.rand(b, c, h, w, generator=gen)
    offset = 1.5 * torch.randn(b, 2 * g * k * k, h, w, generator=gen)
    mask = torch.rand(b, g * k * k, h, w, generator=gen)
    weight = torch.randn(6, c, k, k, generator=gen)
    bias = torch.randn(6, generator=gen)
    ref = deform_conv2d(x, offset, mask, weight, bias, g, backend="grid_sample")
    out = deform_conv2d(*(t.to(CUDA) for t in (x, offset, mask, weight, bias)), g, backend="auto")
    assert (out.cpu() - ref).abs().max() < 1e-3


def test_mixed_precision_training_and_its_checkpoint_round_trip(pairs: Path, tmp_path: Path):
    from lensim.restore.checkpoint import read_checkpoint
    from lensim.restore.run_log import read_csv
    from lensim.restore.train import train

    run = tmp_path / "amp"
    first = train(pairs, run, epochs=2, device=DEVICE, amp=True, max_steps_per_epoch=3, **TINY_TRAIN)
    resumed = train(pairs, run, epochs=4, resume=True)
    assert resumed.step == 2 * first.step == 12
    losses = [float(r["loss"]) for r in read_csv(run / "steps.csv")]
    assert len(losses) == 12 and all(math.isfinite(v) for v in losses)
    ckpt = read_checkpoint(run / "last.pt")  # written from CUDA, read on the CPU
    model = build_model(ckpt["model_config"])
    model.load_state_dict(ckpt["model_state"])
    assert all(not t.is_cuda for t in ckpt["model_state"].values())


def test_tiled_restoration_on_cuda_matches_the_cpu():
    from lensim.restore.infer import restore_image

    model = _perturbed({"arch": "nafnet", "width": 16, "stem": 2, "use_fov": True})
    image = torch.rand(3, 300, 420, generator=torch.Generator().manual_seed(2))
    kw = dict(sensor_top_left=(40.0, 60.0), sensor_size=(400.0, 600.0), tile=128, overlap=32)
    with torch.inference_mode():
        cpu = restore_image(model, image, **kw)
        gpu = restore_image(model.to(CUDA), image, **kw)
        half = restore_image(model.to(torch.bfloat16), image, **kw)
    assert gpu.device.type == "cpu" and gpu.shape == cpu.shape == image.shape
    assert (gpu - cpu).abs().max() < 1e-3
    mse = float((half - cpu).square().mean())
    assert 10 * math.log10(1.0 / max(mse, 1e-20)) > 35.0  # bfloat16 weights and tiles


def test_onnx_export_from_a_cuda_model_matches_it():
    import io

    import numpy as np
    import onnx
    import onnxruntime as ort

    from lensim.restore.export import export_model_bytes

    model = _perturbed({"arch": "nafnet", "width": 16, "stem": 2, "use_fov": True}).to(CUDA)
    data = export_model_bytes(model, {"sensor": None, "lens": None})
    onnx.checker.check_model(onnx.load(io.BytesIO(data)))
    x, fov = (t.numpy() for t in _inputs(model))  # type: ignore[union-attr]
    providers = ["CPUExecutionProvider"]
    if "CUDAExecutionProvider" in ort.get_available_providers():
        providers.insert(0, "CUDAExecutionProvider")
    session = ort.InferenceSession(data, providers=providers)
    feeds = {i.name: v for i, v in zip(session.get_inputs(), (x, fov), strict=False)}
    (out,) = session.run(None, feeds)
    with torch.no_grad():
        ref = model(torch.from_numpy(x).to(CUDA), torch.from_numpy(fov).to(CUDA)).cpu().numpy()
    assert np.abs(out - ref).max() < 1e-3


def test_universal_pretraining_on_cuda_ships_a_cpu_model(tmp_path: Path):
    from lensim.restore import universal as uni
    from test_universal import _pairs

    cfg = uni.PretrainConfig(
        width=8, stem=2, crop=32, batch_size=2, time_budget_s=None, max_steps=4, arch="nafnet", device=DEVICE
    )
    result = uni.pretrain([_pairs(tmp_path / "pairs", 0)], tmp_path / "run", cfg)
    assert result.step == 4 and result.loss is not None and math.isfinite(result.loss)
    model, _ = uni.load_universal(uni.ship(tmp_path / "run", tmp_path / "model").parent)
    assert next(model.parameters()).device.type == "cpu"


def test_huygens_psf_on_cuda_matches_the_cpu():
    from lensim.optics.lens_file import load_lens
    from lensim.optics.paraxial import paraxial_data
    from lensim.psf.huygens import huygens_psf
    from lensim.psf.pupil_field import pupil_field

    lens = load_lens("cooke_triplet")
    for field in (0.0, 0.7):  # on axis the mirror fold runs, off axis too (a field on the y axis)
        pf = pupil_field(lens, field * lens.max_field, 0.55, 48, "real", paraxial_data(lens))
        gpf = pf.to(CUDA)
        ref = huygens_psf(pf, 96, 0.5)
        got = huygens_psf(gpf, 96, 0.5)
        assert got.device.type == CUDA.type
        assert (got.cpu() - ref).abs().max() <= 1e-4 * ref.max()
    off = huygens_psf(gpf, 96, 0.5, offset_mm=(0.003, 0.0), mirror=False)  # no fold: every column
    assert (off.cpu() - huygens_psf(pf, 96, 0.5, offset_mm=(0.003, 0.0), mirror=False)).abs().max() <= 1e-4 * ref.max()
