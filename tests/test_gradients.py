"""Gradients through the tracer and the Huygens PSF (torch.autograd.gradcheck, float64).

A lens whose curvature, thickness, conic constant, aspheric coefficients, image defocus or
surface decentres (Surface.pose) are tensors that require grad is traced by the reference
tracer (trace() switches to it), and autograd follows every step: the paraxial pupils the
rays are aimed with, real ray aiming's Newton iterations, the decentred surface frames, the
surface intersections (Newton for aspheres), refraction and reflection, the exit-pupil
sphere and the Huygens sum. The sensor's decentre against the chief ray is huygens_psf's
offset_mm.

The PSF is a sum of waves whose phases are ~1e5 rad, so rounding leaves ~1e-10 relative
noise in it: each parameter gets a finite-difference step that suits how strongly it
moves the wavefront (a curvature step of 1e-7 1/mm changes the PSF as much as a thickness
step of 1e-5 mm), and the tolerances are those the noise allows.
"""

from dataclasses import replace

import pytest
import torch

from lensim.optics.aiming.rays import generate_rays
from lensim.optics.aiming.sampling import square_grid
from lensim.optics.lens import Lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.surfaces import Surface
from lensim.optics.trace import Rays, trace, trace_reference
from lensim.psf.huygens import huygens_psf
from lensim.psf.pupil_field import pupil_field

pytestmark = [
    pytest.mark.usefixtures("one_torch_thread"),
    # Lens.validate reads tensor parameters as numbers (math.isfinite), which torch warns about
    pytest.mark.filterwarnings("ignore:Converting a tensor with requires_grad=True to a scalar"),
]

DTYPE = torch.float64


def _param(value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=DTYPE, requires_grad=True)


# ---- the tracer -------------------------------------------------------------------------

TRACER_PARAMS = {
    "curvature": 1 / 12.0,
    "thickness": 3.0,
    "conic": -0.6,
    "even asphere A4": 2e-5,
    "odd asphere b3": -4e-5,
    "air gap": 2.0,
    "image defocus": 0.05,
}


def _tracer_lens(p: dict) -> Lens:
    """Sphere/conic, even asphere, stop, odd asphere and a plane: every kind of surface."""
    return Lens(
        [
            Surface(p["curvature"], p["thickness"], ConstantIndex(1.62), conic=p["conic"]),
            Surface(-1 / 40.0, p["air gap"], asphere={4: p["even asphere A4"], 6: -1e-7}),
            Surface(0.0, 1.0, is_stop=True),
            Surface(1 / 30.0, 3.0, ConstantIndex(1.7), asphere={3: p["odd asphere b3"], 4: 1e-6}),
            Surface(0.0, 30.0),
        ],
        aperture_value=6.0,
        fields=[0.0, 8.0],
        wavelengths_um=[0.55],
        image_defocus=p["image defocus"],
    )


@pytest.fixture(scope="module")
def rays() -> tuple[Rays, torch.Tensor]:
    plain = _tracer_lens(TRACER_PARAMS)
    return generate_rays(plain, [0.0, 8.0], square_grid(3) * 0.9, [0.55, 0.48])


def _traced(names: list[str], rays: tuple[Rays, torch.Tensor]):
    """The traced image-plane positions, directions and optical paths as a function of the
    parameters `names` (the others at their values in TRACER_PARAMS)."""

    def f(*values: torch.Tensor) -> tuple[torch.Tensor, ...]:
        lens = _tracer_lens({**TRACER_PARAMS, **dict(zip(names, values, strict=True))})
        res = trace(lens, rays[0], rays[1])
        assert bool(res.rays.valid.all())
        return res.rays.position[..., :2], res.rays.direction, res.rays.opl

    return f


def test_trace_with_tensor_parameters_runs_the_reference_path(rays):
    c = _param(TRACER_PARAMS["curvature"])
    lens = _tracer_lens({**TRACER_PARAMS, "curvature": c})
    assert lens.requires_grad and not _tracer_lens(TRACER_PARAMS).requires_grad
    res = trace(lens, *rays)
    assert res.rays.position.requires_grad
    ref = trace_reference(_tracer_lens(TRACER_PARAMS), *rays)
    assert torch.equal(res.rays.position.detach(), ref.rays.position)
    (res.rays.position[..., 1].sum()).backward()
    assert c.grad is not None and c.grad != 0


def test_gradcheck_tracer_surface_parameters(rays):
    names = list(TRACER_PARAMS)
    inputs = tuple(_param(TRACER_PARAMS[n]) for n in names)
    assert torch.autograd.gradcheck(_traced(names, rays), inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_gradcheck_tracer_ray_start(rays):
    """Through a mirror and the fast tracer's switch: the start positions and directions."""
    lens = Lens(
        [
            Surface(0.0, 80.0, is_stop=True),
            Surface(-1 / 150.0, -60.0, conic=-1.2, is_mirror=True),
            Surface(-1 / 60.0, 50.0, conic=-3.0, is_mirror=True),
        ],
        aperture_value=30.0,
        wavelengths_um=[0.55],
    )
    start, wl = generate_rays(lens, [0.0, 0.1], square_grid(4), [0.55])

    def f(position: torch.Tensor, direction: torch.Tensor) -> tuple[torch.Tensor, ...]:
        d = direction / torch.linalg.norm(direction, dim=-1, keepdim=True)
        out = trace(lens, Rays(position, d, start.opl, start.valid), wl).rays
        return out.position, out.direction, out.opl

    inputs = (start.position.clone().requires_grad_(), start.direction.clone().requires_grad_())
    # fast mode: one random direction through the 144 inputs instead of each of them
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-7, rtol=1e-5, fast_mode=True)


# ---- decentre ----------------------------------------------------------------------


def test_gradcheck_tracer_element_decentre(rays):
    """The image-plane rays as a function of the decentres (dx, dy) mm of the element
    before the stop (surfaces 0 and 1) and of the one after it (3 and 4), one of them
    starting at zero, as a calibration does (Surface.pose)."""
    base = _tracer_lens(TRACER_PARAMS)

    def f(front: torch.Tensor, rear: torch.Tensor) -> tuple[torch.Tensor, ...]:
        surfaces = list(base.surfaces)
        for i, d in ((0, front), (1, front), (3, rear), (4, rear)):
            surfaces[i] = replace(surfaces[i], pose=(d[0], d[1], 0.0, 0.0))
        out = trace(replace(base, surfaces=surfaces), rays[0], rays[1])
        assert bool(out.rays.valid.all())
        return out.rays.position[..., :2], out.rays.direction, out.rays.opl

    inputs = tuple(torch.tensor(d, dtype=DTYPE, requires_grad=True) for d in ([0.02, -0.01], [0.0, 0.0]))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


# ---- the Huygens PSF --------------------------------------------------------------------

PSF_PARAMS = {
    "front curvature": 1 / 25.0,
    "front conic": -0.3,
    "air gap": 2.0,
    "rear curvature": 1 / 40.0,
    "rear decentre x": 0.0,
    "rear decentre y": 0.01,
}
# finite-difference step per parameter (see the module docstring)
PSF_STEPS = {
    "front curvature": 1e-7,
    "front conic": 1e-5,
    "air gap": 1e-5,
    "rear curvature": 1e-7,
    "rear decentre x": 1e-5,
    "rear decentre y": 1e-5,
}


def _psf_lens(p: dict) -> Lens:
    """A doublet with the stop between its elements: parameters before the stop move the
    entrance pupil (and real aiming's solutions), those after it the exit pupil; the rear
    element is decentred (an x decentre breaks the PSF's mirror symmetry)."""
    rear = (p["rear decentre x"], p["rear decentre y"], 0.0, 0.0)
    return Lens(
        [
            Surface(p["front curvature"], 5.0, ConstantIndex(1.6), conic=p["front conic"]),
            Surface(-1 / 60.0, p["air gap"]),
            Surface(0.0, 1.0, is_stop=True),
            Surface(p["rear curvature"], 4.0, ConstantIndex(1.7), pose=rear),
            Surface(-1 / 30.0, 40.0, pose=rear),
        ],
        aperture_value=3.0,
        fields=[0.0, 5.0],
        wavelengths_um=[0.55],
    )


def _psf(name: str, aiming: str):
    def f(value: torch.Tensor) -> torch.Tensor:
        lens = _psf_lens({**PSF_PARAMS, name: value})
        pf = pupil_field(lens, 5.0, 0.55, samples=8, aiming=aiming)
        return huygens_psf(pf, 5, 2.0, dtype=torch.complex128)  # float64 phasors: what gradcheck needs

    return f


@pytest.mark.parametrize("name", list(PSF_PARAMS))
@pytest.mark.parametrize("aiming", ["paraxial", "real"])
def test_gradcheck_huygens_psf(name, aiming):
    f, h = _psf(name, aiming), PSF_STEPS[name]
    x = _param(PSF_PARAMS[name])
    with torch.no_grad():  # the size of the derivative, by central differences, sets the tolerance
        scale = ((f(x + h) - f(x - h)) / (2 * h)).abs().max().item()
    assert scale > 0
    # real aiming's graph is long: fast mode checks the gradient along one random output direction
    fast = aiming == "real"
    assert torch.autograd.gradcheck(f, (x,), eps=h, atol=1e-4 * scale, rtol=1e-3, fast_mode=fast)


def test_psf_gradient_is_not_zero():
    """The check can fail: the PSF depends on the rear curvature, and autograd sees it."""
    x = _param(PSF_PARAMS["rear curvature"])
    psf = _psf("rear curvature", "paraxial")(x)
    (g,) = torch.autograd.grad(psf[2, 2], x)
    assert abs(g.item()) > 1e-3


def test_gradcheck_huygens_psf_sensor_decentre():
    """The PSF as a function of the sensor's decentre (dx, dy) mm against the chief ray
    (huygens_psf's offset_mm): a 2 um grid moved by a few um, from x = 0 where the PSF is
    mirror-symmetric and its x derivative is not."""
    pf = pupil_field(_psf_lens(PSF_PARAMS), 5.0, 0.55, samples=8, aiming="paraxial")

    def f(offset: torch.Tensor) -> torch.Tensor:
        return huygens_psf(pf, 5, 2.0, offset_mm=(offset[0], offset[1]), dtype=torch.complex128)

    x = torch.tensor([0.0, -0.002], dtype=DTYPE, requires_grad=True)
    (g,) = torch.autograd.grad(f(x)[2, 1], x)
    assert g.abs().min() > 0  # a sample off the centre line moves with the sensor in x and y
    h = 1e-7
    with torch.no_grad():  # the size of the derivative, by central differences, sets the tolerance
        scale = max(((f(x + h * e) - f(x - h * e)) / (2 * h)).abs().max().item() for e in torch.eye(2, dtype=DTYPE))
    assert torch.autograd.gradcheck(f, (x,), eps=h, atol=1e-4 * scale, rtol=1e-3)
