"""Tracer checks against analytic truth (tolerances stated per test)."""

import math

import pytest
import torch

from lensim.optics.aiming.rays import generate_rays
from lensim.optics.aiming.sampling import square_grid
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.paraxial import paraxial_data
from lensim.optics.surfaces import Surface
from lensim.optics.trace import MISSED, TIR, VIGNETTED, trace


def _singlet(n=1.5, r1=50.0, thickness=5.0, **kw):
    return Lens(
        [Surface(1 / r1, thickness, ConstantIndex(n), is_stop=True), Surface(0.0, 90.0)],
        aperture_value=10.0,
        fields=[0.0, 5.0],
        wavelengths_um=[0.55],
        **kw,
    )


def test_plano_convex_efl_matches_lensmaker():
    # thin-lens-exact for a plano-convex: f = R / (n - 1), independent of thickness
    lens = _singlet()
    p = paraxial_data(lens)
    assert p.efl_mm == pytest.approx(100.0, rel=1e-12)
    # BFL = f - t/n for a plano-convex with the curved side first
    assert p.bfl_mm == pytest.approx(100.0 - 5.0 / 1.5, rel=1e-12)


def test_paraxial_limit_of_real_trace():
    # a ray at 1e-4 of the aperture behaves paraxially: crosses the axis at the BFL
    lens = _singlet()
    p = paraxial_data(lens)
    lens.surfaces[-1].thickness = p.bfl_mm
    rays, wl = generate_rays(lens, [0.0], torch.tensor([[0.0, 1e-4]], dtype=torch.float64), [0.55])
    res = trace(lens, rays, wl)
    assert abs(res.rays.position[0, 0, 0, 1].item()) < 1e-12


def test_sphere_intersection_exact():
    # a ray parallel to the axis at height h hits a sphere of radius R at sag R - sqrt(R^2 - h^2)
    R, h = 20.0, 7.0
    lens = Lens(
        [Surface(1 / R, 5.0, ConstantIndex(1.5), is_stop=True), Surface(0.0, 50.0)],
        aperture_value=15.0,
        wavelengths_um=[0.55],
    )
    rays, wl = generate_rays(lens, [0.0], torch.tensor([[0.0, h / 7.5]], dtype=torch.float64), [0.55])
    res = trace(lens, rays, wl, end=1, to_image=False)
    assert res.rays.position[0, 0, 0, 2].item() == pytest.approx(R - math.sqrt(R * R - h * h), abs=1e-12)


def test_asphere_newton_intersection_on_surface():
    s = Surface(1 / 15.0, 4.0, ConstantIndex(1.6), conic=-0.7, asphere={4: 2e-5, 6: -3e-8, 8: 1e-10}, is_stop=True)
    lens = Lens([s, Surface(0.0, 30.0)], aperture_value=12.0, fields=[0.0, 10.0], wavelengths_um=[0.55])
    rays, wl = generate_rays(lens, [0.0, 10.0], square_grid(15), [0.55])
    res = trace(lens, rays, wl, end=1, to_image=False)
    p = res.rays.position[res.rays.valid]
    z_surface = s.geometry.sag(p[:, 0] ** 2 + p[:, 1] ** 2)
    assert (p[:, 2] - z_surface).abs().max().item() < 1e-11


def test_snell_law_holds_at_each_refraction():
    lens = _singlet(n=1.7)
    rays, wl = generate_rays(lens, [5.0], square_grid(9), [0.55])
    d_in = rays.direction.clone()
    res = trace(lens, rays, wl, end=1, to_image=False)
    s = lens.surfaces[0]
    p = res.rays.position
    nrm = s.geometry.normal(p[..., 0], p[..., 1])
    sin_i = torch.linalg.norm(torch.cross(d_in, nrm, dim=-1), dim=-1)
    sin_t = torch.linalg.norm(torch.cross(res.rays.direction, nrm, dim=-1), dim=-1)
    assert torch.allclose(1.0 * sin_i, 1.7 * sin_t, atol=1e-13)


def test_total_internal_reflection_is_flagged_not_nan():
    # a steep ray leaving glass through a strongly curved surface
    lens = Lens(
        [Surface(0.0, 5.0, ConstantIndex(1.9), is_stop=True), Surface(-1 / 6.0, 20.0)],
        aperture_value=10.0,
        fields=[0.0, 40.0],
        wavelengths_um=[0.55],
    )
    rays, wl = generate_rays(lens, [40.0], square_grid(21), [0.55])
    res = trace(lens, rays, wl)
    assert (res.status == TIR).any()
    assert torch.isfinite(res.rays.position).all() and torch.isfinite(res.rays.opl).all()
    assert not res.rays.valid[res.status == TIR].any()


def test_ray_missing_a_surface_is_flagged():
    lens = Lens(
        [Surface(1 / 5.0, 2.0, ConstantIndex(1.5), is_stop=True), Surface(0.0, 20.0)],
        aperture_value=20.0,
        wavelengths_um=[0.55],
    )
    rays, wl = generate_rays(lens, [0.0], square_grid(11), [0.55])
    res = trace(lens, rays, wl)
    assert (res.status == MISSED).any()
    assert torch.isfinite(res.rays.position).all()


def test_clear_aperture_and_obscuration_vignette():
    lens = Lens(
        [
            Surface(0.0, 5.0, ConstantIndex(1.5), is_stop=True, clear_radius=4.0, obscuration_radius=1.0),
            Surface(0.0, 20.0),
        ],
        aperture_value=10.0,
        wavelengths_um=[0.55],
    )
    pupil = square_grid(41)
    rays, wl = generate_rays(lens, [0.0], pupil, [0.55])
    res = trace(lens, rays, wl)
    r = torch.linalg.norm(pupil, dim=-1) * 5.0
    expect = (r <= 4.0) & (r >= 1.0)
    assert torch.equal(res.rays.valid[0, 0], expect)
    assert (res.status[0, 0][~expect] == VIGNETTED).all()


def test_plane_mirror_folds_path():
    # object at infinity, flat mirror 50 mm away, image plane 20 mm back towards the object
    lens = Lens(
        [Surface(0.0, 50.0, is_stop=True), Surface(0.0, -20.0, is_mirror=True)],
        aperture_value=10.0,
        wavelengths_um=[0.55],
    )
    rays, wl = generate_rays(lens, [0.0], square_grid(5), [0.55])
    res = trace(lens, rays, wl)
    assert res.rays.valid.all()
    assert torch.allclose(res.rays.direction[..., 2], torch.tensor(-1.0, dtype=torch.float64))
    assert torch.allclose(res.rays.position[..., 2], torch.tensor(30.0, dtype=torch.float64))


def test_concave_mirror_focal_length():
    lens = Lens(
        [Surface(0.0, 100.0, is_stop=True), Surface(-1 / 200.0, -100.0, is_mirror=True)],
        aperture_value=10.0,
        wavelengths_um=[0.55],
    )
    p = paraxial_data(lens)
    assert p.efl_mm == pytest.approx(100.0, rel=1e-12)
    assert p.bfl_mm == pytest.approx(-100.0, rel=1e-12)  # focus 100 mm in front of the mirror (towards -z)


def test_cooke_triplet_paraxial_values():
    lens = load_lens("cooke_triplet")
    p = paraxial_data(lens)
    # textbook design value f = 50 mm, F/5 with a 10 mm entrance pupil
    assert p.efl_mm == pytest.approx(50.0, rel=1e-4)
    assert p.fno == pytest.approx(5.0, rel=1e-4)


def test_opl_is_constant_for_perfect_focus_of_a_paraboloid():
    # a paraboloid mirror focuses an axial plane wave perfectly: all OPLs to the focus equal
    f = 100.0
    lens = Lens(
        [Surface(0.0, 100.0, is_stop=True), Surface(-1 / (2 * f), -f, conic=-1.0, is_mirror=True)],
        aperture_value=40.0,
        wavelengths_um=[0.55],
    )
    rays, wl = generate_rays(lens, [0.0], square_grid(21), [0.55])
    res = trace(lens, rays, wl)
    xy = res.rays.position[..., :2]
    assert xy.abs().max().item() < 1e-11
    opl = res.rays.opl
    assert (opl - opl.mean()).abs().max().item() < 1e-11


def test_top_level_api_names_resolve():
    import lensim

    for name in lensim.__all__:
        assert callable(getattr(lensim, name)), name


def test_top_level_api_names_do_not_shadow_submodules():
    import pkgutil

    import lensim

    assert not set(lensim.__all__) & {m.name for m in pkgutil.iter_modules(lensim.__path__)}
