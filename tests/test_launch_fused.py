"""The compiled paraxial launch (lensim.optics.aiming.launch_fused) against the torch
launch it replaces for large batches: bit-identical rays, the same layout (strides), at
one and two torch threads; and host_empty's tensors."""

import pytest
import torch

from lensim.optics import trace as T
from lensim.optics.aiming import launch_fused
from lensim.optics.aiming import rays as R
from lensim.optics.aiming.sampling import random_uniform
from lensim.optics.lens_file import load_lens


def _both(lens, fields, pupil, wavelengths, monkeypatch):
    """generate_rays by the compiled launch (asserting that it ran) and by the torch one."""
    calls = []
    kernel = launch_fused.launch_infinite

    def counted(*args):
        calls.append(1)
        return kernel(*args)

    monkeypatch.setattr(launch_fused, "launch_infinite", counted)
    monkeypatch.setattr(R, "FUSED_LAUNCH_MIN", 0)
    fused, wl_a = R.generate_rays(lens, fields, pupil, wavelengths)
    assert calls, "the compiled launch did not run"
    monkeypatch.setattr(R, "FUSED_LAUNCH_MIN", 10**12)
    plain, wl_b = R.generate_rays(lens, fields, pupil, wavelengths)
    assert len(calls) == 1 and torch.equal(wl_a, wl_b)
    return fused, plain


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("counts", [(1, 1), (3, 2), (1, 4)])
def test_fused_launch_is_bit_identical(threads, counts, monkeypatch):
    W, F = counts
    lens = load_lens("double_gauss", warn=False)
    pupil = random_uniform(30000) * 1.1  # past the rim too
    fields, wls = [0.0, 10.0, -7.5, 14.0][:F], [0.5, 0.5876, 0.65][:W]
    old = torch.get_num_threads()
    torch.set_num_threads(threads)  # with 2 threads the torch launch runs in pieces
    try:
        fused, plain = _both(lens, fields, pupil, wls, monkeypatch)
    finally:
        torch.set_num_threads(old)
    got = (fused.position, fused.direction, fused.opl, fused.valid)
    for a, b in zip(got, (plain.position, plain.direction, plain.opl, plain.valid), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype and a.stride() == b.stride()
        assert torch.equal(a, b)
    assert bool(fused.valid.all()) and float(fused.opl.abs().max()) > 0.0


def test_fused_launch_takes_any_pupil_layout(monkeypatch):
    """A float32 pupil and a strided one: converted as the torch launch converts them."""
    lens = load_lens("cooke_triplet", warn=False)
    wide = random_uniform(20000).repeat(1, 2)[:, ::2]  # (P, 2), not contiguous
    for pupil in (wide, wide.float()):
        fused, plain = _both(lens, [5.0], pupil, [0.55], monkeypatch)
        assert torch.equal(fused.position, plain.position) and torch.equal(fused.opl, plain.opl)


def test_finite_object_keeps_the_torch_launch(monkeypatch):
    lens = load_lens("double_gauss", warn=False).with_changes(object_distance=500.0)
    assert not lens.infinite_object
    monkeypatch.setattr(R, "FUSED_LAUNCH_MIN", 0)
    monkeypatch.setattr(launch_fused, "launch_infinite", None)  # would fail if called
    rays, _ = R.generate_rays(lens, [1.0], random_uniform(5000), [0.55])
    assert bool(rays.valid.all())


@pytest.mark.parametrize("dtype", [torch.float64, torch.bool, torch.int8, torch.int16, torch.float32])
def test_host_empty(dtype):
    t = T.host_empty((5, 3), dtype, torch.device("cpu"))
    assert t.shape == (5, 3) and t.dtype == dtype and t.is_contiguous()
    t.fill_(1)
    assert bool((t == 1).all())
