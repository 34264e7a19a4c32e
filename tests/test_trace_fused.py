"""The fused kernel (lensim.optics.trace_fused) against the torch chunk loop
(lensim.optics.trace_chunk) it replaces where it can: the same statuses and failure
surfaces ray for ray, the same rays to rounding, failing rays included."""

import pytest
import torch

import lensim.optics.trace as T
from lensim.optics import trace_fused
from lensim.optics.aiming.rays import generate_rays, object_field
from lensim.optics.aiming.sampling import random_uniform, square_grid
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.trace_chunk import MISSED, TIR, VIGNETTED, steps
from reference_lenses import REFERENCE_LENSES
from test_trace_fast import _systems

DATA = REFERENCE_LENSES


def _lens(name: str) -> Lens:
    made = _systems()  # the torch loop's test lenses (tir, conics, ...)
    if name in made:
        return made[name]
    files = {"hubble": "hubble_rc.yaml", "odd_asphere": "odd_asphere_singlet.zmx", "vignetting": "US08427765-1.zmx"}
    return load_lens(DATA / files[name] if name in files else name, warn=False)


@pytest.fixture(autouse=True)
def _kernel_for_every_size(monkeypatch):
    monkeypatch.setattr(T, "FUSED_MIN_BATCH", 0)  # small test batches run the kernel too
    monkeypatch.setattr(trace_fused, "ASPHERES", True)  # and so do aspheres (off by default: slower)


LENSES = ["double_gauss", "cooke_triplet", "phone_wide", "hubble", "odd_asphere", "vignetting", "tir", "conics"]


def _compare(lens: Lens, rays, wl, **kw) -> torch.Tensor:
    """Trace with the fused kernel and with the torch chunk loop; assert that they agree;
    return the statuses."""
    a = T.trace(lens, rays, wl, **kw)
    T.USE_FUSED_KERNEL = False
    try:
        b = T.trace(lens, rays, wl, **kw)
    finally:
        T.USE_FUSED_KERNEL = True
    assert torch.equal(a.status, b.status) and torch.equal(a.failed_at, b.failed_at)
    assert torch.equal(a.rays.valid, b.rays.valid)
    for x, y in ((a.rays.position, b.rays.position), (a.rays.direction, b.rays.direction), (a.rays.opl, b.rays.opl)):
        scale = max(1.0, float(y.abs().max()))  # the telescope's paths are metres long
        assert float((x - y).abs().max()) <= 2e-12 * scale  # failed rays too: where they stopped
    return a.status


@pytest.mark.parametrize("name", LENSES)
def test_fused_kernel_matches_chunk_loop(name):
    lens = _lens(name)
    assert T._fused_kernel(steps(lens, 0, lens.num_surfaces, True, True)) is not None  # the kernel runs
    fields = [object_field(lens, f * lens.max_field, "paraxial") for f in (0.0, 0.7, 1.0)]
    pupil = torch.cat([square_grid(21) * 1.3, random_uniform(200)])  # beyond the pupil: rays that fail
    rays, wl = generate_rays(lens, fields, pupil, lens.wavelengths_um, "paraxial")
    status = _compare(lens, rays, wl)
    for kw in ({"apertures": False}, {"end": lens.stop_index + 1, "to_image": False}):
        _compare(lens, rays, wl, **kw)
    # per-ray wavelengths: the media indices ray by ray
    _compare(lens, rays, wl.expand(rays.shape).clone())
    # rays invalid on input come back as given
    rays.valid = rays.valid.clone()
    rays.valid[..., ::3] = False
    _compare(lens, rays, wl)
    if name in ("tir", "vignetting", "hubble"):  # each fails some rays its own way
        want = {"tir": TIR, "vignetting": VIGNETTED, "hubble": VIGNETTED}[name]
        assert bool((status == want).any())
    if name == "double_gauss":
        assert bool((status == MISSED).any())


def test_fused_kernel_from_a_middle_surface():
    """A trace that starts on surface 3 (rays start anywhere: the first step may run
    backwards)."""
    lens = _lens("double_gauss")
    rays, wl = generate_rays(lens, [0.0, 10.0], square_grid(15), lens.wavelengths_um, "paraxial")
    mid = T.trace(lens, rays, wl, end=3, to_image=False)
    _compare(lens, mid.rays, wl, start=3)


def test_fused_kernel_declines_what_it_does_not_know(monkeypatch):
    """A geometry of a kind of its own, and aspheres unless ASPHERES, take the torch loop."""
    from lensim.optics.geometry import Conic

    class Other(Conic):
        kind = "other"

    lens = _lens("cooke_triplet")
    st = steps(lens, 0, lens.num_surfaces, True, True)
    assert trace_fused.plan_for(st) is not None
    st[1] = st[1].__class__(**{**st[1].__dict__, "geometry": Other(0.01)})
    assert trace_fused.plan_for(st) is None
    phone = _lens("phone_wide")
    phone_steps = steps(phone, 0, phone.num_surfaces, True, True)
    assert trace_fused.plan_for(phone_steps) is not None
    monkeypatch.setattr(trace_fused, "ASPHERES", False)
    assert trace_fused.plan_for(phone_steps) is None


@pytest.mark.parametrize("name", ["double_gauss", "tir", "phone_wide"])
def test_fused_kernel_rays_do_not_depend_on_the_split(name, monkeypatch):
    """A ray's result does not depend on where the batch is cut into tasks or where its
    block ends (the closed loops run over whole blocks, the rays past the end untraced):
    traced whole, in tasks of odd sizes and with two threads, bit for bit the same."""
    lens = _lens(name)
    pupil = torch.cat([square_grid(61) * 1.2, random_uniform(777)])  # 3665 rays: a ragged last block
    rays, wl = generate_rays(lens, [0.0, 0.8 * lens.max_field], pupil, [lens.primary_wavelength_um], "paraxial")
    runs = []
    for tasks, threads, block_rays in ((1, 1, 16384), (8, 2, 1000), (3, 2, 333)):
        monkeypatch.setattr(T, "FUSED_TASKS_PER_THREAD", tasks)
        monkeypatch.setattr(T, "FUSED_MIN_RAYS", block_rays)
        old = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            runs.append(T.trace(lens, rays, wl))
        finally:
            torch.set_num_threads(old)
    for other in runs[1:]:
        for a, b in zip(
            (runs[0].rays.position, runs[0].rays.direction, runs[0].rays.opl, runs[0].status, runs[0].failed_at),
            (other.rays.position, other.rays.direction, other.rays.opl, other.status, other.failed_at),
            strict=True,
        ):
            assert torch.equal(a, b)
    assert bool(runs[0].rays.valid.any()) and not bool(runs[0].rays.valid.all())


def test_a_banks_kernel_size_is_looked_up_without_numba_and_equals_the_fused_one(monkeypatch):
    """suggest_kernel_pixels traces a few thousand rays before every bank's cache lookup;
    it runs the torch loop (without_fused_kernel), so a command whose bank is cached never
    starts numba, and it finds the size the fused kernel finds."""
    import contextlib
    import subprocess
    import sys

    from lensim.psf.bank.settings import suggest_kernel_pixels

    code = (
        "import sys; from lensim.optics.lens_file import load_lens; "
        "from lensim.psf.bank.settings import suggest_kernel_pixels; "
        "print(suggest_kernel_pixels(load_lens('cooke_triplet', warn=False), 3.9), 'numba' in sys.modules)"
    )
    size, numba_loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    monkeypatch.setattr(T, "without_fused_kernel", contextlib.nullcontext)
    assert numba_loaded == "False"
    assert int(size) == suggest_kernel_pixels(load_lens("cooke_triplet", warn=False), 3.9)


def test_one_switch_turns_off_both_compiled_kernels():
    """without_fused_kernel (and USE_FUSED_KERNEL) rule the tracer's kernel and the aiming's
    compiled launch alike (fused_kernels_allowed)."""
    from lensim.optics.aiming.rays import _fused_launch_applies
    from lensim.optics.paraxial import paraxial_data

    lens = load_lens("double_gauss", warn=False)
    para = paraxial_data(lens)
    fld, pupil, n0 = torch.zeros(4, 2, dtype=torch.float64), torch.zeros(2048, 2, dtype=torch.float64), torch.ones(1)
    assert T.fused_kernels_allowed() and _fused_launch_applies(lens, fld, pupil, para, n0, 1)
    with T.without_fused_kernel():
        assert not T.fused_kernels_allowed() and not _fused_launch_applies(lens, fld, pupil, para, n0, 1)
        assert T._fused_kernel(steps(lens, 0, lens.num_surfaces, True, True)) is None
    assert T.fused_kernels_allowed()
