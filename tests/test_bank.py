"""PSF bank: energy (kernels sum to the relative illumination), symmetry, resume,
rotation and interpolation in psf_at, spectral weights, CLI. Tolerances per test."""

import json
import math
import shutil
import time
import warnings
from dataclasses import replace

import numpy as np
import pytest

from lensim.errors import InputError
from lensim.optics.field_analysis import relative_illumination
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import paraxial_image_height
from lensim.psf.bank import MANIFEST, BankSettings, PSFBank, default_fields, field_file, get_bank
from lensim.psf.compute import compute_psf
from lensim.psf.pupil_field import pupil_field
from lensim.render.rotation import rotate_kernel
from lensim.sensor.spectral import read_response_csv, spectral_response

FIELDS = [0.0, 0.5, 0.8, 1.0]
WAVELENGTHS = [450.0, 550.0, 650.0]  # 550 nm is the Cooke triplet's primary
PITCH, KERNEL = 4.0, 15
SETTINGS = BankSettings(fields=tuple(FIELDS), wavelengths_nm=WAVELENGTHS, pupil_samples=48, kernel_pixels=KERNEL)


@pytest.fixture(scope="module")
def lens():
    return load_lens("cooke_triplet")


@pytest.fixture(scope="module")
def bank_dir(lens, tmp_path_factory):
    d = tmp_path_factory.mktemp("bank") / "cooke"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sampling notes about the small 60 um window at full field
        get_bank(lens, PITCH, SETTINGS, out_dir=d)
    return d


@pytest.fixture(scope="module")
def bank(bank_dir):
    return PSFBank.load(bank_dir)


def test_bank_layout_and_sampling(bank, bank_dir):
    m = json.loads((bank_dir / MANIFEST).read_text())
    assert m["kernel_pixels"] == KERNEL and m["pixel_pitch_um"] == PITCH
    # default spacing: half the Airy radius at 450 nm for F/5.07 is 1.39 um -> k = 3 (1.33 um)
    assert m["oversampling"] == 3 and m["fine_spacing_um"] == pytest.approx(4.0 / 3)
    assert m["response"]["name"] == "Nikon 5100 (NPL)" and "colour-science" in m["response"]["source"]
    assert m["lens"]["name"].startswith("Cooke triplet")
    assert [f.field for f in bank.fields] == FIELDS
    for f in bank.fields:
        assert f.rgb.shape == (3, KERNEL, KERNEL) and f.rgb.dtype == np.float32
        assert f.primary_fine.shape == (3 * KERNEL, 3 * KERNEL)
        assert np.all(np.isfinite(f.rgb))
    # the reference point is the primary chief ray: its own offset is zero; image heights grow
    assert np.all(np.diff(bank.radii_mm) > 0)
    assert bank.fields[-1].reference_xy_mm[1] == pytest.approx(18.1385, abs=1e-3)
    for f in bank.fields:
        assert np.abs(f.chief_offsets_mm[1]).max() < 1e-12
        # no clear apertures in this prescription: nothing vignettes; the 60 um window
        # holds most of the energy (88 % at full field, 650 nm)
        assert f.transmission == pytest.approx(np.ones(3), abs=1e-12)
        assert np.all((f.window_energy > 0.85) & (f.window_energy <= 1.0 + 1e-9))


def test_strehl_is_that_of_the_single_primary_psf(bank, lens):
    # same pupil sampling and fine grid as the bank: the same number to 1e-9
    for i, fld in ((0, 0.0), (2, 0.8)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the 60 um window note at 0.8 field
            one = compute_psf(lens, fld, 0.55, "huygens", 48, 3 * KERNEL, PITCH / 3)
        assert bank.fields[i].strehl == pytest.approx(one.figures["strehl"], abs=1e-9)
        np.testing.assert_allclose(bank.fields[i].primary_fine, one.data, rtol=0, atol=1e-7 * one.data.max())
    assert 0.25 < bank.fields[0].strehl < 0.35  # the Cooke triplet on axis at 550 nm: 0.30


def test_kernels_sum_to_the_channel_weighted_relative_illumination(bank, lens):
    w = np.asarray(bank.manifest["response"]["weights"])
    for f in bank.fields:
        expected = w @ f.relative_illumination
        assert f.rgb.astype(np.float64).sum(axis=(1, 2)) == pytest.approx(expected, abs=2e-6)  # float32 storage
    on_axis = bank.fields[0].rgb.astype(np.float64).sum(axis=(1, 2))
    assert on_axis == pytest.approx([1.0, 1.0, 1.0], abs=2e-6)
    sums = bank.kernels.astype(np.float64).sum(axis=(2, 3))[:, 1]
    assert np.all(np.diff(sums) < 0) and 0.85 < sums[-1] < 0.9  # Cooke triplet RI at 20 deg: 0.876
    # the stored relative illumination is field_analysis.relative_illumination's
    ri = relative_illumination(lens, [20.0], 0.55, 32)["relative_illumination"][0]
    assert bank.fields[-1].relative_illumination[1] == pytest.approx(ri, abs=1e-12)


def test_on_axis_kernel_is_rotationally_symmetric(bank):
    k = bank.fields[0].rgb.astype(np.float64)
    peak = k.max()
    for c in range(3):
        assert np.abs(np.rot90(k[c]) - k[c]).max() < 1e-5 * peak
        assert np.abs(k[c].T - k[c]).max() < 1e-5 * peak
    # and it is compact: the centre pixel is the brightest
    assert np.unravel_index(np.argmax(k[1]), k[1].shape) == (KERNEL // 2, KERNEL // 2)


def test_reference_point_and_lateral_colour_offsets_match_single_traces(bank, lens):
    # the kernel centre is the 550 nm chief ray; each wavelength's offset is its own chief
    # ray minus that point (independent pupil traces; to 1e-9 mm)
    f = bank.fields[-1]
    chief = {wl: pupil_field(lens, 20.0, wl / 1000.0, 48).chief[:2].numpy() for wl in WAVELENGTHS}
    assert f.reference_xy_mm == pytest.approx(chief[550.0], abs=1e-9)
    for w, wl in enumerate(WAVELENGTHS):
        assert f.chief_offsets_mm[w] == pytest.approx(chief[wl] - chief[550.0], abs=1e-9)
    # lateral colour of the Cooke triplet at 20 deg: 450 nm and 650 nm land > 0.5 um apart
    assert abs(f.chief_offsets_mm[0, 1] - f.chief_offsets_mm[2, 1]) * 1e3 > 0.5
    # the paraxial point: the paraxial chief ray on the image plane (primary wavelength)
    assert f.paraxial_xy_mm == pytest.approx([0.0, paraxial_image_height(lens, 20.0)], abs=1e-9)


def test_resume_recomputes_only_missing_fields_and_refuses_other_settings(lens, bank_dir, tmp_path):
    d = tmp_path / "copy"
    shutil.copytree(bank_dir, d)
    before = PSFBank.load(d)
    (d / field_file(2)).unlink()
    calls = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = get_bank(lens, PITCH, SETTINGS, out_dir=d, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(3, 4), (4, 4)]  # the start (3 on disk), then the one recomputed field
    assert (d / field_file(2)).exists()
    np.testing.assert_allclose(again.fields[2].rgb, before.fields[2].rgb, rtol=0, atol=1e-7)
    # a complete bank: nothing to compute
    calls.clear()
    get_bank(lens, PITCH, SETTINGS, out_dir=d, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(4, 4)]
    with pytest.raises(InputError, match="kernel_pixels.*different settings"):
        get_bank(lens, PITCH, replace(SETTINGS, kernel_pixels=13), out_dir=d)
    with pytest.raises(InputError, match="pupil_samples"):
        get_bank(lens, PITCH, replace(SETTINGS, pupil_samples=64), out_dir=d)
    with pytest.raises(InputError, match="lens"):
        get_bank(lens.with_changes(image_defocus=0.01), PITCH, SETTINGS, out_dir=d)


def test_truncated_or_foreign_field_files_are_named_by_readers_and_recomputed_on_resume(lens, bank_dir, tmp_path):
    d = tmp_path / "copy"
    shutil.copytree(bank_dir, d)
    before = PSFBank.load(d)
    good = (d / field_file(1)).read_bytes()
    (d / field_file(1)).write_bytes(good[: len(good) // 2])  # a write cut short (not by lensim.io)
    with pytest.raises(InputError) as err:
        PSFBank.load(d)
    assert str(err.value).startswith(str(d / field_file(1))) and "BadZipFile" in str(err.value)
    # a field of another bank's settings (same field, same kernel size) in this bank
    other = tmp_path / "other"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        get_bank(lens, PITCH, replace(SETTINGS, pupil_samples=40), out_dir=other)
    shutil.copy(other / field_file(3), d / field_file(3))
    (d / field_file(1)).write_bytes(good)
    with pytest.raises(InputError, match=f"{field_file(3)}: settings_key: computed with other settings"):
        PSFBank.load(d)
    (d / field_file(1)).write_bytes(good[:100])
    calls = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = get_bank(lens, PITCH, SETTINGS, out_dir=d, progress=lambda done, total: calls.append(done))
    assert calls == [2, 3, 4]  # fields 1 and 3 recomputed
    for a, b in zip(PSFBank.load(d).fields, before.fields):
        np.testing.assert_array_equal(a.rgb, b.rgb)
    assert [f.settings_key for f in again.fields] == [before.fields[0].settings_key] * 4 != [""] * 4


def test_too_small_kernel_is_refused_and_the_empty_bank_can_be_redone(lens, tmp_path):
    one = BankSettings(fields=(1.0,), wavelengths_nm=(550.0,), pupil_samples=32, kernel_pixels=3)
    # 3 px of 4 um hold 20 % of the full-field spot (RMS radius 12.9 um)
    with pytest.raises(InputError, match=r"field 1 at 550 nm: the 12.0 um window holds only .*kernel 3 px"):
        get_bank(lens, PITCH, one, out_dir=tmp_path / "b")
    # no field was written under the refused settings, so other settings may take the directory
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = get_bank(lens, PITCH, replace(one, kernel_pixels=KERNEL), out_dir=tmp_path / "b")
    assert b.kernel_pixels == KERNEL and PSFBank.load(tmp_path / "b").kernel_pixels == KERNEL


def test_psf_at_rotates_by_the_azimuth(bank):
    r = bank.radii_mm[2]
    k = bank.fields[2].rgb.astype(np.float64)
    peak = k.max()
    # along +y (the stored direction): the stored kernel itself
    assert np.abs(bank.psf_at(0.0, r) - k).max() < 1e-6 * peak
    # +x is a rotation by -90 degrees: np.rot90 (rows are +y); -y is a half turn
    assert np.abs(bank.psf_at(r, 0.0) - np.rot90(k, axes=(1, 2))).max() < 1e-6 * peak
    assert np.abs(bank.psf_at(0.0, -r) - np.rot90(k, 2, axes=(1, 2))).max() < 1e-6 * peak
    assert np.abs(bank.psf_at(-r, 0.0) - np.rot90(k, 3, axes=(1, 2))).max() < 1e-6 * peak


def test_rotation_keeps_sum_and_centre(bank):
    k = bank.fields[3].rgb[1].astype(np.float64)
    rot = rotate_kernel(k, 30.0)
    assert rot.sum() == pytest.approx(k.sum(), rel=1e-12)
    # centroid rotates about the centre pixel: (x, y) -> R(30 deg) (x, y), within 0.05 px
    y, x = np.mgrid[0:KERNEL, 0:KERNEL] - KERNEL // 2
    cx, cy = (k * x).sum() / k.sum(), (k * y).sum() / k.sum()
    rx, ry = (rot * x).sum() / rot.sum(), (rot * y).sum() / rot.sum()
    a = math.radians(30.0)
    assert math.hypot(cx, cy) > 0.2  # the full-field kernel is asymmetric (coma)
    assert rx == pytest.approx(cx * math.cos(a) - cy * math.sin(a), abs=0.05)
    assert ry == pytest.approx(cx * math.sin(a) + cy * math.cos(a), abs=0.05)


def test_rotation_by_45_degrees_keeps_the_on_axis_kernel_sharp(bank):
    # the on-axis kernel is rotationally symmetric: a 45 degree turn should leave it as it
    # is. Cubic-spline rotation keeps its MTF area within 1 % (measured 0.6 %) and the
    # round trip within 2 % of the peak (measured 1.0 %); bilinear would lose 4 % and 11 %.
    k = bank.fields[0].rgb[1].astype(np.float64)

    def area(x):
        o = np.abs(np.fft.fft2(x))
        return (o / o[0, 0]).mean()

    turned = rotate_kernel(k, 45.0)
    assert area(turned) / area(k) == pytest.approx(1.0, abs=0.01)
    assert np.abs(rotate_kernel(turned, -45.0) - k).max() < 0.02 * k.max()
    assert np.all(turned >= 0)


def test_psf_at_interpolates_linearly_between_radial_fields(bank):
    r1, r2 = bank.radii_mm[1], bank.radii_mm[2]
    k1, k2 = (bank.fields[i].rgb.astype(np.float64) for i in (1, 2))
    for t in (0.25, 0.5):
        got = bank.psf_at(0.0, (1 - t) * r1 + t * r2)
        assert np.abs(got - ((1 - t) * k1 + t * k2)).max() < 1e-6 * k1.max()
    assert np.abs(bank.psf_at(0.0, r1) - k1).max() < 1e-6 * k1.max()
    # beyond the outermost field: the outermost kernel (clamped)
    assert np.abs(bank.psf_at(0.0, bank.radii_mm[-1] * 1.1) - bank.fields[-1].rgb).max() < 1e-9


def test_parallel_workers_match_serial(lens, tmp_path):
    settings = BankSettings(fields=(0.6, 1.0), wavelengths_nm=(550.0, 650.0), pupil_samples=32, kernel_pixels=KERNEL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        serial = get_bank(lens, PITCH, settings, memory_only=True)
        calls = []
        par = get_bank(
            lens, PITCH, settings, workers=2, out_dir=tmp_path / "par", progress=lambda d, t: calls.append((d, t))
        )
    assert calls[0] == (0, 2) and calls[-1] == (2, 2) and len(calls) == 3
    for a, b in zip(serial.fields, par.fields):
        np.testing.assert_allclose(b.rgb, a.rgb, rtol=0, atol=1e-7)
    assert len(PSFBank.load(tmp_path / "par").fields) == 2


def test_default_fields_are_denser_towards_the_edge():
    f = default_fields(64)
    assert len(f) == 64 and f[0] == 0.0 and f[-1] == 1.0
    steps = np.diff(f)
    assert np.all(steps > 0) and steps[-1] < steps[1] / 5


def test_bad_bank_arguments_are_refused(lens):
    with pytest.raises(InputError, match="odd"):
        replace(SETTINGS, kernel_pixels=14)
    with pytest.raises(InputError, match="between 0 and 1"):
        BankSettings(fields=(0.0, 1.5), wavelengths_nm=WAVELENGTHS)
    with pytest.raises(InputError, match="strictly increasing normalized fields"):
        BankSettings(fields=(0.5, 0.5, 1.0))
    with pytest.raises(InputError, match="pixel_pitch_um"):
        get_bank(lens, -1.0, SETTINGS, memory_only=True)
    with pytest.raises(InputError, match="workers"):
        get_bank(lens, PITCH, SETTINGS, memory_only=True, workers=0)


# ---- spectral response --------------------------------------------------------------


def test_camera_weights_sum_to_one_per_channel():
    for illum in ("E", "D65"):
        r = spectral_response(None, None, illum)
        assert r.weights.shape == (3, 31)
        assert r.weights.sum(axis=1) == pytest.approx([1.0, 1.0, 1.0], abs=1e-12)
        assert np.all(r.weights >= 0)
    # the measured Nikon D5100 filters: red peaks past 580 nm, green 500-580 nm, blue below 490 nm
    wl = r.wavelengths_nm
    red, green, blue = (wl[np.argmax(row)] for row in r.weights)
    assert red > 580 and 500 <= green <= 580 and blue < 490


def test_unknown_camera_and_out_of_range_wavelengths_are_refused():
    with pytest.raises(InputError, match="unknown camera"):
        spectral_response(None, "No Such Camera")
    with pytest.raises(InputError, match="400-680 nm"):
        spectral_response(None, "Sigma SDMerill (NPL)")  # tabulated to 680 nm only


def test_user_csv_is_interpolated(tmp_path):
    p = tmp_path / "cam.csv"
    p.write_text("wavelength_nm,r,g,b\n400,0,1,2\n500,1,1,1\n600,2,1,0\n")
    r = spectral_response([450, 550], p)
    # linear table: r = 0.5, 1.5; g = 1, 1; b = 1.5, 0.5 -> normalized per channel
    np.testing.assert_allclose(r.weights, [[0.25, 0.75], [0.5, 0.5], [0.75, 0.25]], atol=1e-12)
    assert r.name == str(p)


@pytest.mark.parametrize(
    "text, where",
    [
        ("wavelength_nm,r,g\n400,1,1\n500,1,1\n", "header: missing column(s) b"),
        ("wavelength_nm,r,g,b\n400,1,1,1\n500,1,x,1\n", "line 3, column g: expected a number, got 'x'"),
        ("wavelength_nm,r,g,b\n400,1,1,1\n500,1,-1,1\n", "line 3, column g"),
        ("wavelength_nm,r,g,b\n500,1,1,1\n400,1,1,1\n", "line 3, column wavelength_nm: expected strictly increasing"),
    ],
)
def test_malformed_csv_gives_a_one_line_error(tmp_path, text, where):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_response_csv(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)) and where in msg


# ---- CLI ------------------------------------------------------------------------------


def test_cli_bank_and_show_write_the_files(tmp_path):
    from typer.testing import CliRunner

    from lensim.cli import app

    runner = CliRunner()
    out = tmp_path / "bank"
    res = runner.invoke(
        app,
        [
            "psf",
            "bank",
            "cooke_triplet",
            "--pixel-um",
            "4",
            "--kernel",
            "15",
            "--fields",
            "3",
            "--wavelengths-nm",
            "500:600:50",
            "--pupil-samples",
            "48",
            "--illuminant",
            "D65",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "wrote" in res.output
    assert sorted(p.name for p in out.iterdir()) == sorted([MANIFEST, field_file(0), field_file(1), field_file(2)])
    m = json.loads((out / MANIFEST).read_text())
    assert m["wavelengths_nm"] == [500.0, 550.0, 600.0] and m["response"]["illuminant"] == "D65"
    figs = tmp_path / "figs"
    res = runner.invoke(app, ["psf", "show", str(out), "-o", str(figs)])
    assert res.exit_code == 0, res.output
    for name in ("psf_map.png", "strehl.png", "mtf.png", "relative_illumination.png"):
        data = (figs / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_cli_bank_takes_the_sensor_profile_and_prints_json(tmp_path):
    """--lens/--sensor spelled as everywhere else: the pitch and spectral response come from
    the profile, the kernel is sized from the lens; --json prints the summary only."""
    from typer.testing import CliRunner

    from lensim.cli import app
    from lensim.sensor.profile import load_sensor

    out = tmp_path / "bank"
    res = CliRunner().invoke(
        app,
        [
            "psf",
            "bank",
            "--lens",
            "cooke_triplet",
            "--sensor",
            "apsc_mirrorless",
            "--fields",
            "2",
            "--wavelengths-nm",
            "550",
            "--pupil-samples",
            "48",
            "-o",
            str(out),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    sensor = load_sensor("apsc_mirrorless")
    assert info["pixel_pitch_um"] == sensor.pixel_pitch_um and info["response"] == sensor.spectral_response
    assert info["fields"] == 2 and info["kernel_pixels"] % 2 == 1 and (out / MANIFEST).exists()


@pytest.mark.parametrize(
    "args, field",
    [
        ([], "--sensor/--pixel-um"),
        (["--sensor", "phone", "--pixel-um", "4"], "--sensor/--pixel-um"),
        (["--lens", "double_gauss", "--pixel-um", "4"], "lens"),
    ],
)
def test_cli_bank_refuses_ambiguous_options(tmp_path, args, field):
    from typer.testing import CliRunner

    from lensim.cli import app

    res = CliRunner().invoke(app, ["psf", "bank", "cooke_triplet", *args, "-o", str(tmp_path / "b")])
    assert res.exit_code != 0 and isinstance(res.exception, InputError)
    assert field in str(res.exception) and "\n" not in str(res.exception)
    assert not (tmp_path / "b").exists()


def test_cli_bad_csv_is_a_one_line_error(tmp_path):
    from typer.testing import CliRunner

    from lensim.cli import app

    p = tmp_path / "bad.csv"
    p.write_text("wavelength_nm,r,g,b\n400,1,1,1\n500,1,oops,1\n")
    res = CliRunner().invoke(
        app,
        [
            "psf",
            "bank",
            "cooke_triplet",
            "--pixel-um",
            "4",
            "--fields",
            "2",
            "--response",
            str(p),
            "-o",
            str(tmp_path / "b"),
        ],
    )
    # run_guarded (the console entry point) prints str(error) on one line and exits 2
    assert res.exit_code != 0 and isinstance(res.exception, InputError)
    msg = str(res.exception)
    assert "\n" not in msg and msg.startswith(str(p)) and "line 3, column g" in msg
    assert not (tmp_path / "b").exists()


# ---- default size (slow) --------------------------------------------------------------------


@pytest.mark.slow
def test_default_size_bank_on_two_workers(lens, tmp_path):
    """BankSettings' defaults (32 fields x 16 wavelengths 400-700 nm, pupil 128), 4 um
    pixels, 21 px kernels, 2 worker processes: target under 10 minutes."""
    t0 = time.time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = get_bank(lens, 4.0, BankSettings(kernel_pixels=21), workers=2, out_dir=tmp_path / "bank")
    elapsed = time.time() - t0
    print(f"default bank: {elapsed:.0f} s")
    assert len(b.fields) == 32 and len(b.wavelengths_nm) == 16
    assert elapsed < 600


def test_coarse_pitch_uses_the_alias_free_window():
    # 30 um pixels, 9-pixel kernel (270 um) with 48 pupil samples: the diffraction PSF would
    # wrap every ~110 um, so only the central alias-free pixels are computed and the rest
    # stay zero; the on-axis kernel still holds all the energy (sum 1 within 1e-6)
    settings = BankSettings(fields=(0.0, 1.0), wavelengths_nm=(450, 550), pupil_samples=48, kernel_pixels=9)
    bank = get_bank(load_lens("cooke_triplet"), 30.0, settings, memory_only=True)
    k0 = bank.fields[0].rgb
    assert abs(float(k0.sum(axis=(-2, -1)).max()) - 1.0) < 1e-5
    assert float(np.abs(k0[:, 0, :]).max()) == 0.0  # outer ring untouched


def test_a_spot_wider_than_the_alias_free_window_asks_for_more_pupil_samples():
    # Smith's Tessar at F/3.5, full field, 5.82 um pixels: a 62 um RMS spot that the 31 px
    # kernel (180 um) holds, but 16 pupil samples resolve only 5 px (29 um) without
    # wrap-around. That is the pupil sampling's shortfall, not the kernel's: a
    # PupilSamplingError naming the samples, which with_enough_pupil_samples raises to
    # (was an InputError asking for a larger kernel, so nothing raised them)
    from lensim.assets.library import load_library_lens
    from lensim.errors import PupilSamplingError
    from lensim.psf.bank.settings import with_enough_pupil_samples

    lens = load_library_lens("smith_tessar_f3.5")
    one = BankSettings(fields=(1.0,), wavelengths_nm=(550.0,), pupil_samples=16, kernel_pixels=31, ri_samples=2)
    with pytest.raises(PupilSamplingError, match=r"16 pupil samples resolve 5 of the kernel's 31 px") as caught:
        get_bank(lens, 5.82, one, memory_only=True)
    assert caught.value.needed > 16
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bank = with_enough_pupil_samples(lambda s: get_bank(lens, 5.82, s, memory_only=True), one)
    assert bank.manifest["method"] == "huygens" and bank.manifest["pupil_samples"] >= caught.value.needed
    # the whole kernel is alias-free now: what the spot's tail needs is a larger kernel, not samples
    assert bank.fields[0].warnings and not any("pupil samples" in w for w in bank.fields[0].warnings)
