"""PSF physics against analytic truth and between methods (tolerances per test)."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.optics.aiming.sampling import square_grid_full
from lensim.optics.lens import Lens
from lensim.optics.lens_file import load_lens
from lensim.optics.surfaces import Surface
from lensim.psf.compute import PSFSamplingWarning, compute_psf
from lensim.psf.fourier import fft_psf
from lensim.psf.huygens import huygens_psf, huygens_psf_direct
from lensim.psf.pupil_field import pupil_field

WL = 0.55


def _paraboloid(f=100.0, epd=10.0) -> Lens:
    """A perfect imager on axis: a paraboloidal mirror (F/10 by default)."""
    return Lens(
        [Surface(0.0, f, is_stop=True), Surface(-1 / (2 * f), -f, conic=-1.0, is_mirror=True)],
        aperture_value=epd,
        fields=[0.0, 0.1],
        wavelengths_um=[WL],
    )


def _ncc(a, b) -> float:
    a = np.asarray(a) - np.mean(a)
    b = np.asarray(b) - np.mean(b)
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


@pytest.fixture(scope="module")
def airy():
    lens = _paraboloid()
    pf = pupil_field(lens, 0.0, WL, 128, "paraxial")
    spacing = 0.1
    psf = huygens_psf(pf, 161, spacing).numpy()
    return lens, pf, psf, spacing


def test_airy_first_dark_ring(airy):
    # first zero of the Airy pattern at 1.22 lambda N; tolerance 1 %
    _, pf, psf, spacing = airy
    n = 10.0
    c = psf.shape[0] // 2
    profile = psf[c, c:]
    i = int(np.argmin(profile[:100]))
    # parabolic refinement of the minimum
    y0, y1, y2 = profile[i - 1], profile[i], profile[i + 1]
    r = (i + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) * spacing
    assert r == pytest.approx(1.22 * WL * n, rel=0.01)


def test_airy_strehl_is_one(airy):
    _, pf, psf, spacing = airy
    from lensim.psf.metrics import strehl_ratio

    assert strehl_ratio(torch.from_numpy(psf), pf, spacing) == pytest.approx(1.0, abs=0.01)


def test_airy_energy_inside_first_ring(airy):
    # 83.8 % of the energy lies inside the first dark ring (tolerance 1 % absolute)
    _, pf, psf, spacing = airy
    c = psf.shape[0] // 2
    y, x = np.mgrid[0 : psf.shape[0], 0 : psf.shape[1]]
    r = np.hypot(x - c, y - c) * spacing
    inside = psf[r <= 1.22 * WL * 10.0].sum()
    assert inside == pytest.approx(0.838, abs=0.01)


def test_energy_is_conserved_in_a_large_window():
    # a slow lens (F/20, Airy radius 13 um) in a +-46 lambda*N window: the Airy tail
    # outside holds ~0.4 %; the PSF sums to the transmitted fraction (1 here) within 1 %
    lens = load_lens("cooke_triplet").with_changes(aperture_value=2.5)
    psf = compute_psf(lens, 0.5, WL, pupil_samples=128, grid=512, spacing_um=1.0)
    assert psf.transmission == pytest.approx(1.0, abs=1e-12)
    assert psf.data.sum() == pytest.approx(1.0, abs=0.01)


def test_vignetted_field_carries_less_energy():
    lens = load_lens("cooke_triplet")
    lens.surfaces[0].clear_radius = 5.5  # clips the off-axis beam on the front lens
    psf = compute_psf(lens, 1.0, WL, pupil_samples=96, grid=128, spacing_um=0.5)
    assert 0.2 < psf.transmission < 0.98
    assert psf.data.sum() == pytest.approx(psf.transmission, rel=0.06)


def test_on_axis_psf_is_rotationally_symmetric():
    lens = load_lens("cooke_triplet")
    psf = compute_psf(lens, 0.0, WL, pupil_samples=128, grid=96, spacing_um=0.5).data
    psf = psf[1:, 1:]  # odd-sized, centred on the chief ray (sample 48 of 96)
    peak = psf.max()
    # 90 degree rotation and transpose: equal within 1e-3 of the peak (grid symmetry)
    assert np.abs(psf - np.rot90(psf)).max() < 1e-3 * peak
    assert np.abs(psf - psf.T).max() < 1e-3 * peak


def test_huygens_matches_fft_for_slow_lens():
    # F/20 Cooke triplet: aberrations small, Fraunhofer conditions hold: NCC >= 0.995
    lens = load_lens("cooke_triplet").with_changes(aperture_value=2.5)
    for field in (0.0, 0.7):
        pf = pupil_field(lens, field * lens.max_field, WL, 96, "real")
        h = huygens_psf(pf, 96, 1.0).numpy()
        f = fft_psf(pf, 96, 1.0).numpy()
        assert _ncc(h, f) >= 0.995


def test_fast_huygens_equals_direct_summation():
    # the tiled separable expansion against the exact direct float64 sum: NCC >= 0.999,
    # max difference below 1 % of the peak
    lens = load_lens("cooke_triplet")
    pf = pupil_field(lens, 20.0, WL, 48, "paraxial")
    fast = huygens_psf(pf, 48, 0.75).numpy()
    direct = huygens_psf_direct(pf, 48, 0.75).numpy()
    assert _ncc(fast, direct) >= 0.999
    assert np.abs(fast - direct).max() < 0.01 * direct.max()


def test_complex64_huygens_matches_complex128():
    # the default float32 phases and complex64 products against the all-float64 sum, off
    # axis (several tiles) and at two wavelengths: each sample within 5e-6 of the peak (1e-6
    # measured), and 5 x 5 samples binned as pixels within 1e-6 (2e-7 measured)
    lens = load_lens("cooke_triplet")
    for wl in (0.45, 0.65):
        pf = pupil_field(lens, 0.8 * lens.max_field, wl, 96, "real")
        fast = huygens_psf(pf, 100, 0.8)
        exact = huygens_psf(pf, 100, 0.8, dtype=torch.complex128)
        assert fast.dtype == torch.float64
        assert float((fast - exact).abs().max()) < 5e-6 * float(exact.max())
        fast_px, exact_px = (x.reshape(20, 5, 20, 5).sum((1, 3)) for x in (fast, exact))
        assert float((fast_px - exact_px).abs().max()) < 1e-6 * float(exact_px.max())


def test_mirror_fold_equals_the_full_sum_for_a_meridional_field():
    # a field on the y axis of a rotationally symmetric lens: the wavelets are mirror
    # images about x = 0, and the x >= 0 half mirrored equals the whole exact sum (tile 1)
    from dataclasses import replace

    from lensim.psf.huygens import mirror_symmetric

    lens = load_lens("cooke_triplet")
    pf = pupil_field(lens, 14.0, WL, 48, "real")
    assert mirror_symmetric(pf, 0.0)
    folded = huygens_psf(pf, 41, 0.75, tile=1, dtype=torch.complex128, mirror=True)
    direct = huygens_psf_direct(pf, 41, 0.75)
    assert float((folded - direct).abs().max()) < 1e-9 * float(direct.max())
    # not symmetric about a window centre off the meridional plane, nor with one path changed
    assert not mirror_symmetric(pf, 0.002)
    opl = pf.opl.clone()
    opl[7] += 0.01 * pf.wavelength_mm
    assert not mirror_symmetric(replace(pf, opl=opl), 0.0)
    # the default finds the symmetry, and the tiled fold stays within the tiling's error
    fast = huygens_psf(pf, 41, 0.75)
    assert float((fast - direct).abs().max()) < 1e-3 * float(direct.max())


def test_folded_rays_equal_the_unfolded_sum(monkeypatch):
    # a mirror-symmetric pupil: each ray at px > 0 summed with its mirror image in tiles
    # centred on x = 0; on axis the tiling is the same as unfolded, so the sums agree to
    # rounding; off axis (thinner tiles) both stay within the tiling's error of the direct sum
    import lensim.psf.huygens as H

    lens = load_lens("cooke_triplet")
    on_axis = pupil_field(lens, 0.0, 0.45, 49, "real")  # odd: a column at px = 0, its own mirror
    off_axis = pupil_field(lens, 0.9 * lens.max_field, 0.45, 48, "real")
    assert H._fold_rows(61, 61) > 0 and H._fold_rows(61, 20) == 0
    folded = [huygens_psf(pf, 61, 0.75, dtype=torch.complex128) for pf in (on_axis, off_axis)]
    with monkeypatch.context() as m:
        m.setattr(H, "_fold_rows", lambda grid, most: 0)
        unfolded = [huygens_psf(pf, 61, 0.75, dtype=torch.complex128) for pf in (on_axis, off_axis)]
    assert float((folded[0] - unfolded[0]).abs().max()) < 1e-12 * float(unfolded[0].max())
    direct = huygens_psf_direct(off_axis, 61, 0.75)
    for psf in (folded[1], unfolded[1]):
        assert float((psf - direct).abs().max()) < 1e-3 * float(direct.max())
        assert _ncc(psf.numpy(), direct.numpy()) >= 0.9999
    assert float((folded[1] - unfolded[1]).abs().max()) > 0  # a different tiling


def test_geometric_psf_approaches_huygens_envelope_for_large_aberrations():
    # strongly defocused: diffraction matters little, NCC between blurred versions >= 0.9
    from scipy.ndimage import gaussian_filter

    lens = load_lens("cooke_triplet").with_changes(image_defocus=0.6)
    h = compute_psf(lens, 0.0, WL, method="huygens", pupil_samples=192, grid=128, spacing_um=1.0).data
    g = compute_psf(lens, 0.0, WL, method="geometric", pupil_samples=192, grid=128, spacing_um=1.0).data
    assert _ncc(gaussian_filter(h, 2), gaussian_filter(g, 2)) >= 0.9


def test_psf_is_centred_on_the_chief_ray_and_keeps_its_position():
    lens = load_lens("cooke_triplet")
    psf = compute_psf(lens, 1.0, WL, pupil_samples=64, grid=128, spacing_um=0.5)
    assert psf.chief_xy_mm[1] == pytest.approx(18.1385, abs=1e-3)
    assert psf.paraxial_xy_mm[1] == pytest.approx(18.1248, abs=1e-3)


def test_window_smaller_than_the_spot_is_refused():
    lens = load_lens("cooke_triplet")
    with pytest.raises(InputError, match="window"):
        compute_psf(lens, 1.0, WL, pupil_samples=64, grid=16, spacing_um=0.5)


def test_pupil_aliasing_is_refused():
    lens = load_lens("cooke_triplet")
    # 16 pupil samples repeat the PSF every ~ lambda N * 16 / 2 ~ 22 um: a 128 um window aliases
    with pytest.raises(InputError, match="pupil samples"):
        compute_psf(lens, 0.0, WL, pupil_samples=16, grid=128, spacing_um=1.0)


def test_coarse_spacing_warns_with_the_figure():
    lens = load_lens("cooke_triplet").with_changes(aperture_value=5.0)
    with pytest.warns(PSFSamplingWarning, match="Airy radius"):
        compute_psf(lens, 0.0, WL, pupil_samples=64, grid=32, spacing_um=8.0)


def test_field_beyond_coverage_is_refused():
    lens = load_lens("cooke_triplet")
    with pytest.raises(InputError, match="normalized field"):
        compute_psf(lens, 1.5, WL)


@pytest.mark.parametrize("name", ["cooke_triplet", "phone_wide"])
def test_pupil_field_aimed_from_another_wavelength_is_the_same(name):
    # the bank starts each wavelength's real aiming from the last one's: Newton polishes
    # every ray to rounding, so the pupil field is the one aimed from scratch
    lens = load_lens(name)
    near = pupil_field(lens, 0.8 * lens.max_field, 0.45, 48, "real")
    traced = int(((square_grid_full(48)[0] ** 2).sum(-1) <= 1).sum()) // 2  # px >= 0 only
    assert near.aim is not None and near.aim.shape == (1, 1, 1 + traced, 2)
    warm = pupil_field(lens, 0.8 * lens.max_field, 0.65, 48, "real", start=near.aim)
    cold = pupil_field(lens, 0.8 * lens.max_field, 0.65, 48, "real")
    assert warm.points.shape == cold.points.shape
    assert float((warm.points - cold.points).abs().max()) < 1e-9
    assert float((warm.opl - cold.opl).abs().max()) < 1e-9 * 0.65e-3
    assert float((warm.power - cold.power).abs().max()) < 1e-12


def test_mirrored_pupil_field_equals_the_whole_trace(monkeypatch):
    # a meridional field of a symmetric lens: the px >= 0 half traced and mirrored is the
    # whole grid traced, to rounding (the bank's pupils); a decentred lens traces it all
    for name in ("cooke_triplet", "phone_wide"):
        lens = load_lens(name)
        assert lens.meridional_mirror
        half = pupil_field(lens, 0.8 * lens.max_field, 0.5, 48, "real")
        with monkeypatch.context() as m:
            m.setattr(Lens, "meridional_mirror", property(lambda self: False))
            whole = pupil_field(lens, 0.8 * lens.max_field, 0.5, 48, "real")
        assert half.aim.shape[2] < whole.aim.shape[2]
        assert torch.equal(half.pupil_xy, whole.pupil_xy)
        assert float((half.points - whole.points).abs().max()) < 1e-12
        assert float((half.directions - whole.directions).abs().max()) < 1e-12
        assert float((half.opl - whole.opl).abs().max()) < 1e-9 * 0.5e-3
        assert float((half.power - whole.power).abs().max()) < 1e-15
        assert float((half.area - whole.area).abs().max()) < 1e-12 * float(whole.area.max())
    lens = load_lens("cooke_triplet")
    surfaces = list(lens.surfaces)
    surfaces[2] = replace(surfaces[2], pose=(0.01, 0.0, 0.0, 0.0))
    assert not lens.with_changes(surfaces=surfaces).meridional_mirror
