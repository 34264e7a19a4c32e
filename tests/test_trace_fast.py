"""The chunked tracer (trace) against the surface-by-surface reference (trace_reference)."""

import pytest
import torch

import lensim.optics.trace as T
from lensim.optics.aiming.rays import generate_rays, object_field
from lensim.optics.aiming.sampling import random_uniform, square_grid
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.surfaces import Surface
from reference_lenses import REFERENCE_LENSES


def _systems():
    return {
        "cooke": load_lens("cooke_triplet", warn=False),
        "asphere_apertures": load_lens(REFERENCE_LENSES / "US08427765-1.zmx", warn=False),
        "tir": Lens(
            [Surface(0.0, 5.0, ConstantIndex(1.9), is_stop=True), Surface(-1 / 6.0, 20.0)],
            aperture_value=10.0,
            fields=[0.0, 40.0],
            wavelengths_um=[0.55],
        ),
        "miss": Lens(
            [Surface(1 / 5.0, 2.0, ConstantIndex(1.5), is_stop=True), Surface(0.0, 20.0)],
            aperture_value=20.0,
            wavelengths_um=[0.55],
        ),
        "obscured_paraboloid": Lens(
            [
                Surface(0.0, 100.0, is_stop=True),
                Surface(-1 / 200.0, -100.0, conic=-1.0, is_mirror=True, obscuration_radius=3.0),
            ],
            aperture_value=40.0,
            fields=[0.0, 1.0],
            wavelengths_um=[0.55],
        ),
        "conics": Lens(
            [
                Surface(1 / 15.0, 4.0, ConstantIndex(1.6), conic=-0.7, is_stop=True, clear_radius=5.5),
                Surface(-1 / 30.0, 30.0, conic=2.0),
            ],
            aperture_value=12.0,
            fields=[0.0, 10.0],
            wavelengths_um=[0.55],
        ),
    }


@pytest.mark.parametrize("name", list(_systems()))
@pytest.mark.parametrize("aiming", ["paraxial", "real"])
def test_chunked_tracer_matches_reference(name, aiming, monkeypatch):
    monkeypatch.setattr(T, "CHUNK_RAYS", 200)  # several chunks, a ragged last one, the thread pool
    monkeypatch.setattr(T, "FUSED_MIN_BATCH", 0)  # the fused kernel (test_trace_fused: against the torch loop)
    lens = _systems()[name]
    fields = [object_field(lens, f * lens.max_field, "paraxial") for f in (0.0, 0.7, 1.0)]
    pupil = torch.cat([square_grid(15) * 1.3, random_uniform(100)])
    rays, wl = generate_rays(lens, fields, pupil, lens.wavelengths_um, aiming)
    for kw in ({}, {"record": True}, {"apertures": False}, {"end": lens.stop_index + 1, "to_image": False}):
        a, b = T.trace(lens, rays, wl, **kw), T.trace_reference(lens, rays, wl, **kw)
        assert torch.equal(a.rays.valid, b.rays.valid)
        assert torch.equal(a.status, b.status) and torch.equal(a.failed_at, b.failed_at)
        v = b.rays.valid
        for x, y in ((a.rays.position, b.rays.position), (a.rays.direction, b.rays.direction)):
            assert (x - y)[v].abs().max().item() < 1e-11  # measured <= 2e-12 (steep TIR-lens rays)
        assert (a.rays.opl - b.rays.opl)[v].abs().max().item() < 1e-11
        assert torch.isfinite(a.rays.position).all() and torch.isfinite(a.rays.direction).all()
        if kw.get("record"):
            assert (a.surface_positions - b.surface_positions)[:, v].abs().max().item() < 1e-11
    # per-ray wavelengths take the tensor path
    a = T.trace(lens, rays, wl.expand(rays.shape).clone())
    b = T.trace_reference(lens, rays, wl)
    assert torch.equal(a.rays.valid, b.rays.valid)
    assert (a.rays.position - b.rays.position)[b.rays.valid].abs().max().item() < 1e-11
