"""Centrally obscured systems against analytic truth and a published telescope.

* A perfect imager (an F/10 paraboloid, f = 100 mm, EPD 10 mm) with a central
  obscuration of ratio eps on its stop: the Huygens PSF against the annular-aperture
  pattern I(v) = I0 [2 J1(v)/v - eps^2 2 J1(eps v)/(eps v)]^2 / (1 - eps^2)^2 with
  v = pi r / (lambda N) (Born & Wolf 8.6; Mahajan, Optical Imaging and Aberrations II):
  first dark ring, encircled energy, the peak against the unobscured Airy peak, the
  transmitted fraction 1 - eps^2 and the Strehl ratio, whose ideal is the obscured one.
* The chief ray is a reference ray that the obscuration does not block; every real ray
  through the obscuration is blocked (spot diagram, relative illumination).
* The Hubble Space Telescope's Ritchey-Chretien design (tests/data/lenses/hubble_rc.yaml):
  EFL against its published 57.6 m and against optiland, a near-perfect on-axis PSF whose
  dark ring is that of its annulus.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.special import j1

from lensim.errors import InputError
from lensim.optics.field_analysis import chief_ray_heights, relative_illumination
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.spot import spot_diagram
from lensim.optics.surfaces import Surface
from lensim.psf.compute import compute_psf
from reference_lenses import REFERENCE_LENSES

WL = 0.55
F_MM, EPD_MM = 100.0, 10.0
N = F_MM / EPD_MM


def obscured_paraboloid(eps: float) -> Lens:
    """A paraboloidal mirror (perfect on axis), its stop plane f in front with a central
    obscuration of eps times the pupil radius."""
    stop = Surface(0.0, F_MM, is_stop=True, obscuration_radius=eps * EPD_MM / 2 if eps else None)
    return Lens(
        [stop, Surface(-1 / (2 * F_MM), -F_MM, conic=-1.0, is_mirror=True)],
        aperture_value=EPD_MM,
        fields=[0.0, 0.1],
        wavelengths_um=[WL],
    )


def annulus_amplitude(v, eps: float):
    """2 J1(v)/v - eps^2 2 J1(eps v)/(eps v): 1 - eps^2 at v = 0."""
    v = np.maximum(np.asarray(v, dtype=np.float64), 1e-12)
    return 2 * j1(v) / v - eps**2 * 2 * j1(eps * v) / (eps * v)


def annulus_first_zero(eps: float) -> float:
    return brentq(lambda v: annulus_amplitude(v, eps), 2.0, 4.5)


def annulus_encircled_energy(v: float, eps: float) -> float:
    """Fraction of the transmitted energy within v (the integral of I v dv is 2 (1 - eps^2))."""
    return quad(lambda t: annulus_amplitude(t, eps) ** 2 * t, 0.0, v, limit=200)[0] / (2 * (1 - eps**2))


@pytest.fixture(scope="module", params=[0.3, 0.5])
def annular(request):
    eps = request.param
    spacing = 0.125  # um; the Airy radius 1.22 lambda N is 6.7 um, the window +-10 um
    psf = compute_psf(obscured_paraboloid(eps), 0.0, WL, pupil_samples=128, grid=161, spacing_um=spacing)
    return eps, psf, spacing


def _radii(psf) -> np.ndarray:
    c = psf.data.shape[0] // 2
    y, x = np.mgrid[0 : psf.data.shape[0], 0 : psf.data.shape[1]]
    return np.hypot(x - c, y - c) * psf.spacing_um


def test_annular_first_dark_ring(annular):
    eps, psf, spacing = annular
    c = psf.data.shape[0] // 2
    profile = psf.data[c, c:]
    expected = annulus_first_zero(eps) * WL * N / math.pi
    i = int(np.argmin(profile[: int(1.3 * expected / spacing)]))
    y0, y1, y2 = profile[i - 1], profile[i], profile[i + 1]
    r = (i + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) * spacing
    assert r == pytest.approx(expected, rel=0.01)
    assert expected < 1.22 * WL * N * 0.99  # the annulus's dark ring lies inside Airy's: the test can tell


def test_annular_encircled_energy(annular):
    eps, psf, _ = annular
    r = _radii(psf)
    for v in (1.0, 2.0, 3.0, annulus_first_zero(eps), 4.5, 5.5):  # 5.5: r = 9.6 um, inside the window
        radius = v * WL * N / math.pi
        measured = psf.data[r <= radius].sum() / psf.transmission
        assert measured == pytest.approx(annulus_encircled_energy(v, eps), rel=0.01), v


def test_annular_peak_transmission_and_strehl(annular):
    eps, psf, spacing = annular
    # the energy per sample at the peak: the unobscured Airy peak P pi D^2 / (4 lambda^2 f^2)
    # times (1 - eps^2)^2 (power and amplitude both scale with the annulus's area)
    airy_peak = math.pi * EPD_MM**2 / (4 * (WL * 1e-3) ** 2 * F_MM**2) * (spacing * 1e-3) ** 2
    assert psf.data.max() == pytest.approx(airy_peak * (1 - eps**2) ** 2, rel=0.01)
    assert psf.transmission == pytest.approx(1 - eps**2, rel=0.01)
    assert psf.figures["strehl"] == pytest.approx(1.0, abs=0.01)  # normalized by the obscured ideal


def test_obscuration_blocks_rays_but_not_the_chief_ray():
    lens = obscured_paraboloid(0.4)
    sd = spot_diagram(lens, aiming="real")  # the chief rays cross the obscuration's centre: no error
    assert torch.equal(sd.chief[0, 0], torch.zeros(2, dtype=torch.float64))
    assert float(sd.chief[0, 1, 1]) == pytest.approx(F_MM * math.tan(math.radians(0.1)), rel=1e-5)  # distortion < 1e-5
    # hexapolar(6): rings of 6k points at rho = k/6; rings 1-2 (rho < 0.4) are blocked
    assert sd.valid[0].sum(-1).tolist() == [6 * (3 + 4 + 5 + 6)] * 2
    ri = relative_illumination(lens, [0.0], samples=32)
    assert ri["unvignetted_fraction"][0] == pytest.approx(1 - 0.4**2, abs=0.01)


def test_obscuration_must_be_smaller_than_the_clear_aperture():
    with pytest.raises(
        InputError,
        match=r"surfaces\[0\]\.obscuration: expected a central obscuration radius >= 0 mm "
        r"below the clear semi-diameter 4, got 5",
    ):
        Lens([Surface(0.0, 10.0, is_stop=True, clear_radius=4.0, obscuration_radius=5.0), Surface(0.0, 5.0)])


# ---- a published Ritchey-Chretien telescope --------------------------------------------
HUBBLE_EFL_MM = 57600.0  # published: 57.6 m, f/24


def test_hubble_first_order_against_published_value():
    lens = load_lens(REFERENCE_LENSES / "hubble_rc.yaml")
    para = paraxial_data(lens)
    assert para.efl_mm == pytest.approx(HUBBLE_EFL_MM, rel=1e-4)
    assert para.fno == pytest.approx(24.0, rel=1e-4)


def test_hubble_psf_is_its_annulus():
    # on axis: near-perfect (the image plane as printed is 0.3 mm inside the paraxial
    # focus: Strehl about 0.94); the transmitted fraction is the annulus's 1 - 0.33^2, the
    # dark ring that of an annulus of ratio 0.33 at f/24 (1 %)
    lens = load_lens(REFERENCE_LENSES / "hubble_rc.yaml")
    eps = 396.0 / 1200.0
    psf = compute_psf(lens, 0.0, 0.6328, pupil_samples=128, grid=64, spacing_um=1.0)
    assert psf.transmission == pytest.approx(1 - eps**2, rel=0.01)
    assert psf.figures["strehl"] > 0.9
    c = psf.data.shape[0] // 2
    profile = psf.data[c, c:]
    i = int(np.argmin(profile[:30]))
    y0, y1, y2 = profile[i - 1], profile[i], profile[i + 1]
    r = i + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    fno = paraxial_data(lens).fno
    assert r == pytest.approx(annulus_first_zero(eps) * 0.6328 * fno / math.pi, rel=0.01)


def test_hubble_chief_rays_cross_the_obscuration_in_lens_level_outputs():
    # lens field's chief-ray heights: the axial chief ray meets the obscuration's centre;
    # at 0.04 deg the height is EFL tan(field) up to the design's 8e-6 distortion
    lens = load_lens(REFERENCE_LENSES / "hubble_rc.yaml")
    heights = chief_ray_heights(lens, [0.0, 0.04], [0.6328])
    efl = paraxial_data(lens).efl_mm
    assert heights[0, 0] == 0.0
    assert heights[0, 1] == pytest.approx(efl * math.tan(math.radians(0.04)), rel=1e-4)


@pytest.mark.slow
def test_hubble_efl_against_optiland():
    import optiland.backend as be
    from optiland.optic import Optic
    from optiland.physical_apertures import RadialAperture

    lens = load_lens(REFERENCE_LENSES / "hubble_rc.yaml")
    op = Optic()
    op.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    s0, s1, s2 = lens.surfaces
    op.surfaces.add(index=1, thickness=s0.thickness, aperture=RadialAperture(r_max=be.inf, r_min=s0.obscuration_radius))
    op.surfaces.add(index=2, radius=s1.radius, thickness=s1.thickness, material="mirror", conic=s1.conic, is_stop=True)
    op.surfaces.add(index=3, radius=s2.radius, thickness=s2.thickness, material="mirror", conic=s2.conic)
    op.surfaces.add(index=4)
    op.set_aperture(aperture_type="EPD", value=lens.aperture_value)
    op.fields.set_type(field_type="angle")
    op.fields.add(y=0.0)
    op.wavelengths.add(value=0.6328, is_primary=True)
    assert paraxial_data(lens).efl_mm == pytest.approx(float(op.paraxial.f2()), rel=1e-9)
