"""Surface geometry (lensim.optics.geometry): each kind's chunk forms (the fast tracer's)
against its batched forms (the reference tracer's), and both against closed forms."""

import math

import pytest
import torch

from lensim.optics.geometry import (
    Conic,
    EvenAsphere,
    OddAsphere,
    Plane,
    Sphere,
    make_geometry,
)
from lensim.optics.surfaces import Surface

DTYPE = torch.float64

KINDS = {
    "plane": Plane(),
    "sphere": Sphere(1 / 20.0),
    "concave sphere": Sphere(-1 / 35.0),
    "ellipsoid": Conic(1 / 15.0, -0.7),
    "oblate": Conic(-1 / 30.0, 2.0),
    "paraboloid": Conic(-1 / 200.0, -1.0),
    "hyperboloid": Conic(1 / 40.0, -2.5),
    "even asphere": EvenAsphere(1 / 15.0, -0.7, {4: 2e-5, 6: -3e-8, 8: 1e-10}),
    "flat even asphere": EvenAsphere(0.0, 0.0, {2: 4e-3, 4: -1e-5}),
    "odd asphere": OddAsphere(1 / 30.0, -0.5, {1: 1e-3, 3: -2e-5, 4: 1e-6, 5: 3e-8}),
}


def _rays(n: int = 400, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays from z = -3 mm over a 12 mm disc, up to about 25 deg off the axis."""
    g = torch.Generator().manual_seed(seed)
    xy = (torch.rand(n, 2, generator=g, dtype=DTYPE) - 0.5) * 12.0
    pos = torch.cat([xy, torch.full((n, 1), -3.0, dtype=DTYPE)], -1)
    d = torch.cat([(torch.rand(n, 2, generator=g, dtype=DTYPE) - 0.5) * 0.9, torch.ones(n, 1, dtype=DTYPE)], -1)
    return pos, d / torch.linalg.norm(d, dim=-1, keepdim=True)


def test_make_geometry_picks_the_kind():
    assert isinstance(make_geometry(0.0), Plane)
    assert isinstance(make_geometry(0.0, -1.0), Plane)  # no curvature: the conic does not matter
    assert type(make_geometry(0.1)) is Sphere
    assert type(make_geometry(0.1, -1.0)) is Conic
    assert type(make_geometry(0.1, 0.0, {4: 1e-5, 6: 0.0})) is EvenAsphere
    assert type(make_geometry(0.1, 0.0, {4: 0.0})) is Sphere  # zero terms are no asphere
    assert type(make_geometry(0.0, 0.0, {3: 1e-5})) is OddAsphere
    assert Surface(0.1, asphere={1: 1e-3, 4: 1e-5}).kind == "odd asphere"
    with pytest.raises(ValueError, match="even powers"):
        EvenAsphere(0.1, 0.0, {3: 1e-5})


@pytest.mark.parametrize("name", list(KINDS))
def test_chunk_forms_match_batched_forms(name):
    geo = KINDS[name]
    pos, d = _rays()
    t, hit = geo.intersect(pos, d)
    x, y, z = (pos[:, i].clone() for i in range(3))
    L, M, N = (d[:, i].clone() for i in range(3))
    tc, hc = geo.hit_chunk(x, y, z, L, M, N)
    assert torch.equal(x, pos[:, 0]) and torch.equal(N, d[:, 2])  # the inputs are left as they were
    assert hit.sum() > 100 and torch.equal(hit, torch.ones_like(hit) if hc is None else hc)
    assert (t - tc)[hit].abs().max() < 1e-11
    p = pos + t.unsqueeze(-1) * d
    on = p[hit]
    r2 = on[:, 0] ** 2 + on[:, 1] ** 2
    assert (on[:, 2] - geo.sag(r2)).abs().max() < 1e-11  # on the surface
    n_batched = geo.normal(on[:, 0], on[:, 1])
    n_chunk = geo.normal_chunk(on[:, 0].clone(), on[:, 1].clone(), on[:, 2].clone())
    if n_chunk is None:
        assert torch.equal(n_batched, torch.tensor([0.0, 0.0, 1.0], dtype=DTYPE).expand_as(n_batched))
    else:
        assert (torch.stack(n_chunk, -1) - n_batched).abs().max() < 1e-12
    dirs = d[hit]
    cos_i, nrm = geo.cos_incidence_chunk(on[:, 0], on[:, 1], on[:, 2], dirs[:, 0], dirs[:, 1], dirs[:, 2])
    assert ((dirs * n_batched).sum(-1) - cos_i).abs().max() < 1e-12
    kk = torch.full_like(cos_i, 0.25)
    L, M, N = (dirs[:, i].clone() for i in range(3))
    geo.bend_chunk(kk, nrm, on[:, 0], on[:, 1], on[:, 2], L, M, N)
    assert (torch.stack([L, M, N], -1) - (dirs + 0.25 * n_batched)).abs().max() < 1e-12


def test_sphere_intersection_against_the_closed_form():
    R = 20.0
    geo = Sphere(1 / R)
    pos, d = _rays(50)
    t, hit = geo.intersect(pos, d)
    # |p + t d - (0, 0, R)| = R, nearest root
    w = pos - torch.tensor([0.0, 0.0, R], dtype=DTYPE)
    b = (w * d).sum(-1)
    c = (w * w).sum(-1) - R * R
    t_ref = -b - torch.sqrt(b * b - c)
    assert hit.all() and (t - t_ref).abs().max() < 1e-12


@pytest.mark.parametrize("name", list(KINDS))
def test_scalar_sag_and_domain(name):
    geo = KINDS[name]
    assert geo.sag_at(2.5) == geo.sag(torch.tensor([6.25], dtype=DTYPE)).item()
    c, k = geo.curvature, geo.conic
    q = (1 + k) * c * c
    assert geo.max_radius == pytest.approx(1 / math.sqrt(q) if q > 0 else math.inf, rel=1e-15)
    if math.isfinite(geo.max_radius):
        r2 = torch.tensor([0.99, 1.01], dtype=DTYPE) * geo.max_radius**2
        assert geo.in_domain(r2).tolist() == [True, False]


def test_odd_asphere_sag_against_the_formula():
    geo = KINDS["odd asphere"]
    r = torch.linspace(0.0, 6.0, 25, dtype=DTYPE)
    c, k = geo.curvature, geo.conic
    z = c * r**2 / (1 + torch.sqrt(1 - (1 + k) * c**2 * r**2)) + sum(a * r**p for p, a in geo.terms.items())
    assert (geo.sag(r * r) - z).abs().max() < 1e-14


def test_a_subclass_that_says_nothing_of_what_it_fits_changes_no_lens():
    """A subclass that does not define `fits` (a test double, a user's variant of a kind) is
    not a new kind: make_geometry keeps making the built-in kinds. Before, any subclass was
    asked first with its parent's `fits`, so defining one anywhere in a process turned every
    sphere loaded afterwards into it (a bank resumed in that process then differed by 1 ulp
    from the one a fresh process had started)."""
    from lensim.optics import geometry

    kinds = list(geometry._KINDS)

    class Other(Conic):
        kind = "other"

    assert geometry._KINDS == kinds
    assert type(make_geometry(0.02)) is Sphere and type(make_geometry(0.02, -0.5)) is Conic
    assert Surface(0.02).kind == "sphere"


def test_a_new_kind_is_one_subclass():
    """Defining a subclass registers it: make_geometry (and so Surface.geometry, the tracers
    and the drawings) picks it for the parameters its `fits` accepts, before the older kinds."""
    from lensim.optics import geometry

    class Paraboloid(Conic):
        kind = "paraboloid"

        @classmethod
        def fits(cls, curvature, conic, terms):
            return not terms and curvature != 0.0 and conic == -1.0

        @classmethod
        def create(cls, curvature, conic, terms):
            return cls(curvature, conic)

    try:
        assert type(make_geometry(0.02, -1.0)) is Paraboloid
        assert Surface(0.02, conic=-1.0).kind == "paraboloid"
        assert type(make_geometry(0.02, -0.5)) is Conic and type(make_geometry(0.02, -1.0, {4: 1e-6})) is EvenAsphere
    finally:
        geometry._KINDS.remove(Paraboloid)
    assert type(make_geometry(0.02, -1.0)) is Conic
