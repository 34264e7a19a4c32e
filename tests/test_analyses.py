"""The lens analyses (MTF, wavefront and Zernike terms, ray fans and field curves,
encircled and ensquared energy) against analytic truth and against lensim's own
independent paths; the peers are in test_analyses_peers.py.

Analytic cases (tolerances per test):
* a paraboloidal mirror, perfect on axis: its MTF is the incoherent MTF of a circular
  pupil, (2/pi)(acos v - v sqrt(1 - v^2)), v = f lambda N; its encircled energy the Airy
  curve 1 - J0(v)^2 - J1(v)^2, v = pi r / (lambda N);
* the same mirror with its image plane moved by dz: defocus W020 = dz / (8 N^2) (paraxial
  limit), so Noll Z4 = W020 / (2 sqrt 3) and Fringe Z4 = W020 / 2, Strehl sinc^2(W020);
* Zernike polynomials: Noll's are orthonormal over the disc, a fit returns the
  coefficients a wavefront was made from;
* enclosed energy of a Gaussian spot: 1 - exp(-r^2 / 2 s^2) (circle), erf(a / s sqrt 2)^2 (square).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import erf, j0, j1

from lensim.errors import InputError
from lensim.optics.fans import field_curves, ray_fans
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.surfaces import Surface
from lensim.psf import zernike
from lensim.psf.energy import energy_curves
from lensim.psf.fourier import fft_psf
from lensim.psf.metrics import enclosed_energy
from lensim.psf.mtf import FieldOTF, OTFCuts, diffraction_limited_mtf, field_otf, otf_cuts, refocused, through_focus
from lensim.psf.pupil_field import pupil_field, pupil_fields_through_focus
from lensim.psf.wavefront import remove_piston_tilt, wavefront, wavefront_figures, zernike_fit

WL = 0.55


def paraboloid(f: float = 100.0, epd: float = 10.0) -> Lens:
    """A paraboloidal mirror (F/10 by default): a perfect imager on axis."""
    return Lens(
        [Surface(0.0, f, is_stop=True), Surface(-1 / (2 * f), -f, conic=-1.0, is_mirror=True)],
        aperture_value=epd,
        fields=[0.0, 0.1],
        wavelengths_um=[WL],
    )


# ---------------------------------------------------------------- Zernike polynomials


def test_noll_and_fringe_indices() -> None:
    """Noll's (n, m) table (Noll 1976, Table 1) and the Fringe set's (Zemax's 37 terms)."""
    noll = {1: (0, 0), 2: (1, 1), 3: (1, -1), 4: (2, 0), 5: (2, -2), 6: (2, 2), 7: (3, -1), 8: (3, 1)}
    noll |= {9: (3, -3), 10: (3, 3), 11: (4, 0), 12: (4, 2), 13: (4, -2), 22: (6, 0), 37: (8, 0)}
    for j, nm in noll.items():
        assert zernike.noll_nm(j) == nm, j
    fringe = {1: (0, 0), 4: (2, 0), 5: (2, 2), 6: (2, -2), 7: (3, 1), 8: (3, -1), 9: (4, 0), 10: (3, 3)}
    fringe |= {16: (6, 0), 25: (8, 0), 36: (10, 0), 37: (12, 0)}
    for j, nm in fringe.items():
        assert zernike.fringe_nm(j) == nm, j
    assert len(set(zernike.FRINGE_NM)) == 37


def test_noll_terms_are_orthonormal_on_the_disc() -> None:
    """Over a fine grid on the unit disc, <Z_i Z_j> = delta_ij within 2e-3 (grid error)."""
    g = (np.arange(400) + 0.5) / 200 - 1
    x, y = np.meshgrid(g, g)
    inside = x * x + y * y <= 1
    a = zernike.design_matrix("noll", 22, x[inside], y[inside])
    gram = a.T @ a / inside.sum()
    assert np.abs(gram - np.eye(22)).max() < 2e-3


def test_fit_recovers_known_coefficients() -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, (4000, 2))
    p = p[(p**2).sum(1) <= 1]
    for conv in zernike.CONVENTIONS:
        c = rng.normal(size=20)
        w = zernike.design_matrix(conv, 20, p[:, 0], p[:, 1]) @ c
        np.testing.assert_allclose(zernike.fit(conv, 20, p[:, 0], p[:, 1], w), c, atol=1e-10)


def test_unsupported_terms_are_refused() -> None:
    with pytest.raises(InputError, match="1 to 37 fringe terms"):
        zernike.check_terms("fringe", 38)
    with pytest.raises(InputError, match="1 to 231 noll terms"):
        zernike.check_terms("noll", 232)
    with pytest.raises(InputError, match="zernike_convention"):
        zernike.check_terms("zemax", 4)


# ---------------------------------------------------------------- wavefront


@pytest.mark.parametrize("dz_mm", [0.1, -0.1, 0.3])
def test_defocus_zernike_of_a_known_image_plane_shift(dz_mm: float) -> None:
    """Paraboloid F/10: the image plane moved dz away from the mirror gives W020 = dz / (8
    N^2) waves (paraxial limit): Noll Z4 = W020 / (2 sqrt 3), Fringe Z4 = W020 / 2 within
    1 %, the other terms below 1e-3 of it; Strehl [sin(pi W020) / (pi W020)]^2 within 5e-3
    (measured 2e-3 at 0.68 waves: 64 pupil samples)."""
    n = 10.0
    w020 = dz_mm / (8 * n * n) / (WL * 1e-3)
    wf = wavefront(refocused(paraboloid(), dz_mm), 0.0, WL, 64, "paraxial")
    noll = np.asarray(zernike_fit(wf, "noll", 15)["coefficients_waves"])
    assert noll[3] == pytest.approx(w020 / (2 * math.sqrt(3)), rel=0.01)
    others = np.delete(noll, [0, 3])
    assert np.abs(others).max() < 1e-3 * abs(w020)
    fringe = zernike_fit(wf, "fringe", 9)["coefficients_waves"]
    assert fringe[3] == pytest.approx(w020 / 2, rel=0.01)
    x = math.pi * w020
    assert wavefront_figures(wf)["strehl"] == pytest.approx((math.sin(x) / x) ** 2, abs=5e-3)


def test_perfect_lens_has_a_flat_wavefront() -> None:
    figures = wavefront_figures(wavefront(paraboloid(), 0.0, WL, 48, "paraxial"))
    assert figures["rms_waves"] < 1e-6 and figures["strehl"] == pytest.approx(1.0, abs=1e-9)


def test_piston_and_tilt_are_removed() -> None:
    """A pure tilt plus piston leaves nothing; RMS, PV and Strehl ignore them."""
    wf = wavefront(load_lens("cooke_triplet"), 14.0, WL, 48, "real")
    base = wavefront_figures(wf)
    wf.opd_waves = wf.opd_waves + 3.0 + 2.0 * wf.pupil_xy[:, 0] - 1.5 * wf.pupil_xy[:, 1]
    moved = wavefront_figures(wf)
    for key in ("rms_waves", "pv_waves", "strehl"):
        assert moved[key] == pytest.approx(base[key], rel=1e-9)
    assert np.abs(remove_piston_tilt(wf.pupil_xy, 1.0 + wf.pupil_xy[:, 1])).max() < 1e-12


# ---------------------------------------------------------------- MTF


@pytest.mark.parametrize("epd", [10.0, 20.0])
def test_perfect_lens_mtf_is_the_circular_pupil_mtf(epd: float) -> None:
    """Paraboloid at F/10 and F/5: MTF within 0.005 of (2/pi)(acos v - v sqrt(1 - v^2)),
    sagittal and tangential, 0 to the cutoff (measured 0.0016 / 0.0009 at 64 samples)."""
    lens = paraboloid(epd=epd)
    n = 100.0 / epd
    f = np.linspace(0.0, 1.0 / (WL * 1e-3 * n), 41)
    sag, tan = field_otf(lens, 0.0, [WL], [1.0], 64, "paraxial").mtf(f)
    truth = diffraction_limited_mtf(f, WL, n)
    assert np.abs(sag - truth).max() < 0.005
    assert np.abs(tan - truth).max() < 0.005


def test_mtf_is_the_fourier_transform_of_the_fft_psf() -> None:
    """Same pupil field, off axis: the pupil autocorrelation equals the transform of the
    FFT PSF's line spread functions within 5e-3 (measured 3.9e-3 at 10 lp/mm, where the
    PSF's 256 um window truncates the tails: there the autocorrelation gives 0.8438, 0.8451
    converged with 384 pupil samples, the PSF's transform 0.8477)."""
    lens = load_lens("cooke_triplet")
    pf = pupil_field(lens, 14.0, WL, 128, "real")
    spacing = 1.0
    psf = fft_psf(pf, 256, spacing).numpy()
    x = (np.arange(256) - 128) * spacing * 1e-3
    f = np.linspace(0.0, 300.0, 31)
    kernel = np.exp(-2j * np.pi * np.outer(f, x))
    sag_psf = np.abs(kernel @ psf.sum(0)) / psf.sum()
    tan_psf = np.abs(kernel @ psf.sum(1)) / psf.sum()
    sag, tan = FieldOTF(14.0, [otf_cuts(pf)]).mtf(f)
    assert np.abs(sag - sag_psf).max() < 5e-3
    assert np.abs(tan - tan_psf).max() < 5e-3


def test_lateral_colour_enters_the_polychromatic_mtf() -> None:
    """Two equal wavelengths whose images lie d apart along y: tangential MTF |cos(pi f d)|,
    sagittal unchanged."""
    n = 8
    ones = np.ones(n + 1, dtype=complex)
    d = 0.004  # mm
    cuts = [
        OTFCuts(10.0, 10.0, ones, ones, np.array([0.0, 0.0]), 1.0),
        OTFCuts(10.0, 10.0, ones, ones, np.array([0.0, d]), 1.0),
    ]
    f = np.linspace(0.0, 70.0, 8)
    sag, tan = FieldOTF(0.0, cuts).mtf(f)
    np.testing.assert_allclose(sag, 1.0, atol=1e-12)
    np.testing.assert_allclose(tan, np.abs(np.cos(np.pi * f * d)), atol=1e-12)


def test_through_focus_moves_the_traced_rays_exactly() -> None:
    """One trace carried to other image planes equals a trace of the refocused lens."""
    lens = load_lens("cooke_triplet")
    shifts = [-0.04, 0.0, 0.025]
    moved = pupil_fields_through_focus(lens, 20.0, 0.48, shifts, 32, "real")
    for dz, pf in zip(shifts, moved, strict=True):
        ref = pupil_field(refocused(lens, dz), 20.0, 0.48, 32, "real")
        assert torch.allclose(pf.opl, ref.opl, atol=1e-11)
        assert torch.allclose(pf.points, ref.points, atol=1e-11)
        assert torch.allclose(pf.chief, ref.chief, atol=1e-11)


def test_perfect_lens_peaks_at_focus() -> None:
    """Through focus, the perfect lens's MTF is symmetric about its focus and largest there."""
    shifts = np.linspace(-0.4, 0.4, 9)
    sag, tan = through_focus(paraboloid(), 0.0, shifts, [40.0], [WL], [1.0], 48, "paraxial")
    assert int(np.argmax(tan[0])) == 4 and int(np.argmax(sag[0])) == 4
    np.testing.assert_allclose(tan[0], tan[0][::-1], atol=1e-5)


# ---------------------------------------------------------------- encircled energy


def test_enclosed_energy_of_a_gaussian_spot() -> None:
    s = 3.0
    spacing = 0.5
    g = (np.arange(96) - 48) * spacing
    x, y = np.meshgrid(g, g)
    psf = np.exp(-(x * x + y * y) / (2 * s * s))
    psf /= psf.sum()
    r = np.linspace(0.5, 12.0, 24)
    ee = enclosed_energy(psf, spacing, r, "circle", (0.0, 0.0))
    np.testing.assert_allclose(ee, 1 - np.exp(-r * r / (2 * s * s)), atol=2e-3)
    sq = enclosed_energy(psf, spacing, r, "square", (0.0, 0.0))
    np.testing.assert_allclose(sq, erf(r / (s * math.sqrt(2))) ** 2, atol=2e-3)


def test_airy_encircled_energy() -> None:
    """Huygens PSF of the paraboloid (F/10): EE within 0.005 of 1 - J0^2 - J1^2 out to 0.8
    of the window's half-width (measured 0.0015); 83.8 % inside the first dark ring."""
    c = energy_curves(paraboloid(), 0.0, [WL], [1.0], grid=128, aiming="paraxial")
    v = np.pi * c.sizes_um / (WL * 10.0)
    truth = 1 - j0(v) ** 2 - j1(v) ** 2
    inner = c.sizes_um < 0.8 * c.sizes_um[-1]
    assert np.abs(c.encircled - truth)[inner].max() < 0.005
    assert np.interp(1.22 * WL * 10.0, c.sizes_um, c.encircled) == pytest.approx(0.838, abs=0.005)
    assert np.all(c.ensquared >= c.encircled - 1e-12)


# ---------------------------------------------------------------- fans and field curves


def test_on_axis_fans_are_odd_and_alike() -> None:
    fans = ray_fans(load_lens("cooke_triplet"), [0.0], 21, "real")
    t, s = fans.tangential_um[:, 0], fans.sagittal_um[:, 0]
    np.testing.assert_allclose(t, -t[:, ::-1], atol=1e-9)
    np.testing.assert_allclose(t, s, atol=1e-9)
    assert np.abs(t[fans.primary, 10]) < 1e-9  # the chief ray itself


def test_field_curves_meet_on_axis_and_follow_refocusing() -> None:
    """T = S on axis; moving the image plane by dz moves every focus by -dz."""
    lens = load_lens("cooke_triplet")
    fc = field_curves(lens, [0.0, 10.0, 20.0], "real")
    assert fc.tangential_mm[:, 0] == pytest.approx(fc.sagittal_mm[:, 0], abs=1e-9)
    moved = field_curves(refocused(lens, 0.05), [0.0, 10.0, 20.0], "real")
    np.testing.assert_allclose(moved.tangential_mm, fc.tangential_mm - 0.05, atol=1e-9)
    np.testing.assert_allclose(moved.sagittal_mm, fc.sagittal_mm - 0.05, atol=1e-9)
