"""Shooting settings (issue 16): stopping down, focusing, object distance, against
independent truth: the Airy pattern of the new F-number, Newton's equation, optiland's
paraxial image solve, the geometric defocus blur Delta z / N_w; and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import j1

from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_from_dict, lens_to_dict, load_lens
from lensim.optics.paraxial import paraxial_data, signed_indices, trace_yu
from lensim.optics.shooting import ShootingSettings, describe, lens_at, max_stop_mm, record
from lensim.optics.surfaces import Surface
from lensim.psf.compute import compute_psf

WL = 0.55


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def _airy(n: int, spacing_um: float, fno: float) -> np.ndarray:
    """The Airy pattern [2 J1(v) / v]^2, v = pi r / (lambda N), on an n x n grid (peak 1)."""
    y, x = (np.mgrid[:n, :n] - n // 2) * spacing_um
    v = np.pi * np.hypot(x, y) / (WL * fno)
    v[v == 0] = 1e-12
    return (2 * j1(v) / v) ** 2


def _first_zero_um(psf: np.ndarray, spacing_um: float, expected_um: float) -> float:
    """The first dark ring's radius along +x (parabolic refinement of the minimum found
    between 0.6 and 1.5 times the expected radius)."""
    c = psf.shape[0] // 2
    profile = psf[c, c:]
    lo, hi = int(0.6 * expected_um / spacing_um), int(1.5 * expected_um / spacing_um) + 1
    i = lo + int(np.argmin(profile[lo:hi]))
    y0, y1, y2 = profile[i - 1], profile[i], profile[i + 1]
    return (i + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) * spacing_um


def paraboloid(f: float = 100.0, epd: float = 10.0) -> Lens:
    """A perfect imager on axis: a paraboloidal mirror, its stop plane f in front (F/10)."""
    return Lens(
        [Surface(0.0, f, is_stop=True), Surface(-1 / (2 * f), -f, conic=-1.0, is_mirror=True)],
        aperture_value=epd,
        fields=[0.0, 0.1],
        wavelengths_um=[WL],
    )


# ---------------------------------------------------------------- stopping down


def test_stopped_down_perfect_imager_has_the_airy_ring_of_the_new_f_number() -> None:
    # F/10 paraboloid stopped to F/20: the first dark ring moves to 1.22 lambda 20 (1 %)
    lens = lens_at(paraboloid(), ShootingSettings(fno=20))
    assert lens.aperture_type == "stop_semi_diameter"
    assert paraxial_data(lens).epd_mm == pytest.approx(5.0, rel=1e-12)
    spacing = 0.2
    psf = compute_psf(lens, 0.0, WL, pupil_samples=96, grid=161, spacing_um=spacing).data
    psf = psf.numpy() if isinstance(psf, torch.Tensor) else psf
    assert _first_zero_um(psf, spacing, 1.22 * WL * 20) == pytest.approx(1.22 * WL * 20, rel=0.01)
    assert _ncc(psf, _airy(161, spacing, 20.0)) > 0.999


def test_stopped_down_cooke_triplet_is_nearly_the_airy_pattern_of_f16() -> None:
    # the F/5 Cooke triplet at F/16 is nearly diffraction-limited on axis: its Huygens PSF
    # correlates with the F/16 Airy pattern (measured 0.9995), not with F/5's, and its
    # first dark ring sits at 1.22 lambda 16 within 3 %
    lens = load_lens("cooke_triplet")
    stopped = lens_at(lens, ShootingSettings(fno=16))
    assert describe(lens, ShootingSettings(fno=16))["fno"] == pytest.approx(16.0, rel=1e-12)
    spacing = 0.5
    psf = compute_psf(stopped, 0.0, WL, pupil_samples=64, grid=81, spacing_um=spacing)
    data = psf.data.numpy() if isinstance(psf.data, torch.Tensor) else np.asarray(psf.data)
    assert psf.figures["strehl"] > 0.85
    assert _ncc(data, _airy(81, spacing, 16.0)) > 0.998
    assert _ncc(data, _airy(81, spacing, 5.0)) < 0.9
    assert _first_zero_um(data, spacing, 1.22 * WL * 16) == pytest.approx(1.22 * WL * 16, rel=0.03)


def test_the_iris_keeps_its_size_when_focusing_close() -> None:
    lens = load_lens("cooke_triplet")
    far = lens_at(lens, ShootingSettings(fno=8))
    near = lens_at(lens, ShootingSettings(fno=8, focus_m=0.5))
    assert near.aperture_value == pytest.approx(far.aperture_value, rel=1e-12)
    d = describe(lens, ShootingSettings(fno=8, focus_m=0.5))
    # working F-number N (1 + |m|) for a lens whose pupils are nearly equal
    m = abs(paraxial_data(near).magnification)
    assert d["fno"] == pytest.approx(8.0, rel=1e-12)
    assert d["working_fno"] == pytest.approx(8.0 * (1 + m), rel=0.02)
    assert d["working_fno"] > 8.5


def test_too_fast_an_f_number_is_refused_naming_the_maximum() -> None:
    with pytest.raises(InputError, match=r"^fno: F/4 is faster than the lens's maximum aperture F/5\b"):
        lens_at(load_lens("cooke_triplet"), ShootingSettings(fno=4))
    lens_at(load_lens("cooke_triplet"), ShootingSettings(fno=5.0))  # its own aperture is allowed


def test_a_rounded_marking_of_wide_open_is_wide_open() -> None:
    lens = load_lens("double_gauss")  # EPD 50 mm at EFL 100.0002 mm: wide open is F/2.0001
    wide_open = describe(lens, ShootingSettings())["fno"]
    assert 2.0 < wide_open < 2.001
    with pytest.warns(UserWarning) as caught:
        at_two = lens_at(lens, ShootingSettings(fno=2))
    assert len(caught) == 1 and "F/2 is 0.00 stop faster" in str(caught[0].message)
    with pytest.warns(UserWarning):
        assert describe(lens, ShootingSettings(fno=2))["fno"] == pytest.approx(wide_open, rel=1e-9)
    assert at_two.aperture_value == pytest.approx(max_stop_mm(lens), rel=1e-9)


def test_nominal_f_numbers_within_a_sixth_of_a_stop_mean_wide_open() -> None:
    """Markings and EXIF FNumber are rounded to third stops: F/4.8 (0.12 stop faster) on the
    F/5 triplet is F/5 with one warning line naming both; F/4.7 (0.18 stop) is refused."""
    lens = load_lens("cooke_triplet")
    with pytest.warns(UserWarning) as caught:
        at = lens_at(lens, ShootingSettings(fno=4.8))
    assert len(caught) == 1
    text = str(caught[0].message)
    assert "\n" not in text and "F/4.8" in text and "F/5 " in text and "wide open" in text
    assert at.aperture_value == pytest.approx(max_stop_mm(lens), rel=1e-9)
    assert paraxial_data(at).fno == pytest.approx(5.0, rel=1e-4)
    with pytest.raises(InputError, match=r"^fno: F/4.7 is faster than the lens's maximum aperture F/5 by 0.18 stop"):
        lens_at(lens, ShootingSettings(fno=4.7))
    with pytest.raises(InputError, match=r"^fno: F/1.8 is faster than the lens's maximum aperture F/2\b"):
        lens_at(load_lens("double_gauss"), ShootingSettings(fno=1.8))


def test_the_stop_clear_aperture_limits_the_maximum_aperture() -> None:
    data = lens_to_dict(load_lens("cooke_triplet"))
    stop = paraxial_data(load_lens("cooke_triplet")).stop_semi_diameter_mm
    data["surfaces"][3]["clear_semi_diameter"] = 0.8 * stop
    lens = lens_from_dict(data)
    with pytest.raises(InputError, match="^fno: F/5 is faster than the lens's maximum aperture F/6.2"):
        lens_at(lens, ShootingSettings(fno=5))


# ---------------------------------------------------------------- focusing


def _system_matrix(lens: Lens) -> tuple[float, float, float, float]:
    """(A, B, C, D): [y', nu'] = [[A, B], [C, D]] [y, nu] from the first to the last vertex
    plane, from two paraxial rays (primary wavelength)."""
    wl = lens.primary_wavelength_um
    (ya, nua), (yb, nub) = (trace_yu(lens, 1.0, 0.0, wl), trace_yu(lens, 0.0, 1.0, wl))
    return float(ya[-1]), float(yb[-1]), float(nua), float(nub)


@pytest.mark.parametrize("focus_m", [5.0, 1.0, 0.4])
def test_unit_focusing_obeys_newtons_equation(focus_m: float) -> None:
    lens = load_lens("cooke_triplet")
    at = lens_at(lens, ShootingSettings(focus_m=focus_m, focus_mode="paraxial"))
    # the object is focus_m from the image plane
    assert at.object_distance + at.total_track == pytest.approx(focus_m * 1000.0, abs=1e-9)
    # focal points from the system matrix: front focal point D f before the first vertex,
    # rear focal point -A/C... after the last vertex; x x' = f^2 (air on both sides)
    a, _, c, d = _system_matrix(lens)
    f = -1.0 / c
    ffd, bfd = d * f, -a / c
    z_last = float(lens.vertex_z()[-2])
    x = at.object_distance - ffd  # object beyond the front focal point
    x_image = paraxial_data(at).paraxial_image_z_mm - (z_last + bfd)  # image beyond the rear one
    assert x * x_image == pytest.approx(f * f, rel=1e-9)
    # the image plane keeps the designer's offset from the paraxial image
    offset = lens.total_track - paraxial_data(lens).paraxial_image_z_mm
    assert at.total_track - paraxial_data(at).paraxial_image_z_mm == pytest.approx(offset, abs=1e-8)


@pytest.mark.parametrize("focus_m", [2.0, 0.5])
def test_unit_focusing_matches_optilands_paraxial_image_solve(focus_m: float) -> None:
    pytest.importorskip("optiland")
    from optiland_models import optiland_from_lens

    lens = load_lens("cooke_triplet").with_changes(image_defocus=0.0)
    at = lens_at(lens, ShootingSettings(focus_m=focus_m, focus_mode="paraxial"))
    op = optiland_from_lens(lens)
    op.updater.set_thickness(at.object_distance, 0)
    op.updater.image_solve()
    bfd_optiland = float(op.surfaces[-2].thickness)
    offset = lens.total_track - paraxial_data(lens).paraxial_image_z_mm  # the designer's, kept
    assert at.surfaces[-1].thickness - offset == pytest.approx(bfd_optiland, abs=1e-7)


def test_defocus_blur_diameter_is_delta_z_over_working_f_number() -> None:
    # focused at 0.5 m, object at infinity: the image plane stands dz behind the object's
    # paraxial image and the geometric blur is a disc of diameter dz / N_w
    from lensim.optics.aiming.sampling import hexapolar
    from lensim.optics.spot import spot_diagram

    lens = load_lens("cooke_triplet")
    at = lens_at(lens, ShootingSettings(fno=8, focus_m=0.5, object_m=math.inf))
    assert at.infinite_object
    sharp = lens_at(lens, ShootingSettings(fno=8, focus_m=math.inf))
    dz = at.total_track - sharp.total_track
    n_w = paraxial_data(at).working_fno
    spot = spot_diagram(at, [0.0], [WL], pupil=hexapolar(12), aiming="real")
    xy = spot.xy[spot.valid].numpy()
    radius = float(np.hypot(xy[:, 0], xy[:, 1]).max())
    assert dz > 4.0
    assert 2 * radius == pytest.approx(dz / n_w, rel=0.02)


def test_object_and_focus_default_to_each_other() -> None:
    lens = load_lens("cooke_triplet")
    a = lens_at(lens, ShootingSettings(focus_m=1.5))
    b = lens_at(lens, ShootingSettings(object_m=1.5))
    c = lens_at(lens, ShootingSettings(object_m=1.5, focus_m=1.5))
    assert lens_to_dict(a) == lens_to_dict(b) == lens_to_dict(c)
    d = describe(lens, ShootingSettings(object_m=1.5))
    assert d["focus_m"] == d["object_m"] == 1.5
    assert d["config"] is None and d["focal_mm"] == pytest.approx(50.0, rel=1e-4)


def test_default_settings_leave_the_lens_as_it_is() -> None:
    lens = load_lens("cooke_triplet")
    assert lens_at(lens, ShootingSettings()) is lens
    d = describe(lens, ShootingSettings())
    assert d["object_m"] == d["focus_m"] == math.inf and d["fno"] == pytest.approx(5.0, rel=1e-4)


def test_a_focus_group_moves_between_its_gaps_and_focuses() -> None:
    # the Cooke triplet's middle element focuses, moving between the gaps 1 and 3: the
    # track stays, the paraxial image keeps the designer's offset from the image plane
    data = lens_to_dict(load_lens("cooke_triplet"))
    data["focus"] = {"thickness": 1, "compensator": 3}
    lens = lens_from_dict(data)
    assert lens_from_dict(lens_to_dict(lens)).focus_thickness == 1
    at = lens_at(lens, ShootingSettings(focus_m=3.0, focus_mode="paraxial"))
    t = [s.thickness for s in at.surfaces]
    t0 = [s.thickness for s in lens.surfaces]
    assert t[1] != t0[1] and t[1] + t[3] == pytest.approx(t0[1] + t0[3], abs=1e-12)
    assert at.total_track == pytest.approx(lens.total_track, abs=1e-12)
    assert at.object_distance + at.total_track == pytest.approx(3000.0, abs=1e-9)
    offset = lens.total_track - paraxial_data(lens).paraxial_image_z_mm
    assert at.total_track - paraxial_data(at).paraxial_image_z_mm == pytest.approx(offset, abs=1e-8)


def test_front_cell_focusing_extends_the_lens() -> None:
    data = lens_to_dict(load_lens("cooke_triplet"))
    data["focus"] = {"thickness": 1}  # the front element moves, the rest stays with the image
    at = lens_at(lens_from_dict(data), ShootingSettings(focus_m=2.0))
    assert at.surfaces[-1].thickness == load_lens("cooke_triplet").surfaces[-1].thickness
    assert at.object_distance + at.total_track == pytest.approx(2000.0, abs=1e-9)


# ---------------------------------------------------------------- values and refusals


def test_settings_round_trip_through_a_dict() -> None:
    s = ShootingSettings(fno=5.6, object_m=math.inf, focus_m=2.0, config="tele")
    assert s.to_dict() == {"fno": 5.6, "object_m": "inf", "focus_m": 2.0, "config": "tele"}
    assert ShootingSettings.from_dict(s.to_dict()) == s
    assert ShootingSettings.from_dict(None) == ShootingSettings()
    assert ShootingSettings(config=2).config == "2"  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"fno": 0}, "^fno: expected a positive, finite F-number"),
        ({"fno": -2.8}, "^fno: expected a positive"),
        ({"fno": math.nan}, "^fno: expected a positive"),
        ({"fno": math.inf}, "^fno: expected a positive, finite"),
        ({"fno": "f8"}, "^fno: expected a number"),
        ({"object_m": -1}, "^object_m: expected a positive distance in metres or inf"),
        ({"object_m": math.nan}, "^object_m: expected a positive distance"),
        ({"focus_m": 0}, "^focus_m: expected a positive distance"),
        ({"focus_m": 1e9}, "^focus_m: expected a distance up to"),
        ({"config": "  "}, "^config: expected a configuration name or number"),
    ],
)
def test_bad_values_are_refused_naming_the_option(kwargs: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        ShootingSettings(**kwargs)


def test_unreachable_distances_are_refused() -> None:
    lens = load_lens("cooke_triplet")
    with pytest.raises(InputError, match=r"^focus_m: the lens cannot focus at 0.1 m by moving its image plane"):
        lens_at(lens, ShootingSettings(focus_m=0.1))
    with pytest.raises(InputError, match=r"^object_m: 0.03 m from the image plane is inside the lens"):
        lens_at(lens, ShootingSettings(object_m=0.03, focus_m=1.0))


def test_unknown_configurations_are_refused() -> None:
    with pytest.raises(InputError, match="declares no configurations"):
        lens_at(load_lens("cooke_triplet"), ShootingSettings(config="tele"))


def test_unit_focusing_of_a_mirror_lens() -> None:
    # after a mirror z runs backwards: the object is still focus_m from the image plane
    lens = paraboloid()
    at = lens_at(lens, ShootingSettings(focus_m=2.0, focus_mode="paraxial"))
    assert at.object_distance + at.total_track == pytest.approx(2000.0, abs=1e-9)
    # a mirror of f = 100 mm: 1/s + 1/s' = 1/f from its vertex
    s = at.object_distance + 100.0
    s_image = -(at.total_track - 100.0)
    assert 1 / s + 1 / s_image == pytest.approx(1 / 100.0, rel=1e-9)
    assert signed_indices(at, WL)[-1] < 0


def test_zoom_positions_take_shooting_settings(reference_lenses) -> None:
    # each position: F/2.8 is its widest aperture (FNUM 2.8 at every position), describe()
    # gives its own focal length, and focusing and stopping down apply to that position
    from lensim.optics.configurations import apply_configuration

    lens = load_lens(reference_lenses / "nikon_80-200_zoom.zmx", warn=False)
    for name in ("1", "2", "3"):
        efl = paraxial_data(apply_configuration(lens, name)).efl_mm
        d = describe(lens, ShootingSettings(config=name, fno=4, focus_m=3.0))
        assert d["config"] == name and d["focal_mm"] == pytest.approx(efl, rel=1e-12)
        assert d["fno"] == pytest.approx(4.0, rel=1e-12) and d["focus_m"] == 3.0
        assert describe(lens, ShootingSettings(config=name))["fno"] == pytest.approx(2.8, rel=1e-12)
        with pytest.raises(InputError, match="F/2 is faster than the lens's maximum aperture F/2.8"):
            lens_at(lens, ShootingSettings(config=name, fno=2))
    with pytest.raises(InputError, match=r"unknown configuration 'wide'; expected a name or a number 1..3"):
        lens_at(lens, ShootingSettings(config="wide"))


# ---------------------------------------------------------------- the commands


def test_psf_compute_takes_the_settings_and_records_them(capsys, monkeypatch) -> None:
    import json

    from cli_runner import run_cli

    code, out, _ = run_cli(
        [
            "psf",
            "compute",
            "cooke_triplet",
            "--fno",
            "8",
            "--focus-m",
            "1",
            "--grid",
            "48",
            "--pupil-samples",
            "48",
            "--json",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0
    got = json.loads(out)["settings"]
    want = describe(load_lens("cooke_triplet"), ShootingSettings(fno=8, focus_m=1.0))
    assert got == {k: (pytest.approx(v) if isinstance(v, float) else v) for k, v in want.items()}
    assert got["fno"] == pytest.approx(8.0) and got["working_fno"] > 8.0 and got["object_m"] == 1.0


def test_banks_simulate_and_pairs_record_the_settings(tmp_path, capsys, monkeypatch) -> None:
    # psf bank --fno/--focus-m/--object-m: the manifest holds the lens at those settings and
    # their record; simulate with that bank and --lens at the same settings records them in
    # its photo JSON; dataset make from it gives every record the settings
    import json

    from PIL import Image

    from cli_runner import run_cli

    options = ["--fno", "8", "--focus-m", "2", "--object-m", "inf"]
    code, _, err = run_cli(
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
            "32",
            "-o",
            str(tmp_path / "bank"),
            "--json",
            *options,
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    manifest = json.loads((tmp_path / "bank" / "manifest.json").read_text())
    settings = ShootingSettings(fno=8, focus_m=2.0, object_m=math.inf)
    want = record(describe(load_lens("cooke_triplet"), settings))
    assert manifest["shooting"]["resolved"] == want and want["object_m"] == "inf"
    assert manifest["lens"] == json.loads(json.dumps(lens_to_dict(lens_at(load_lens("cooke_triplet"), settings))))
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(2):
        Image.fromarray((np.random.default_rng(i).random((64, 80, 3)) * 255).astype(np.uint8)).save(photos / f"{i}.png")
    code, _, err = run_cli(
        [
            "simulate",
            str(photos / "0.png"),
            "-o",
            str(tmp_path / "sim"),
            "--bank",
            str(tmp_path / "bank"),
            "--lens",
            "cooke_triplet",
            *options,
            "--no-blur",
            "--quiet",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert json.loads((tmp_path / "sim" / "0.json").read_text())["settings"] == want
    code, _, err = run_cli(
        [
            "simulate",
            str(photos / "1.png"),
            "-o",
            str(tmp_path / "sim2"),
            "--lens",
            "cooke_triplet",
            *options,
            "--no-blur",
            "--quiet",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert json.loads((tmp_path / "sim2" / "1.json").read_text())["settings"] == want
    code, _, err = run_cli(
        [
            "dataset",
            "make",
            str(photos),
            "-o",
            str(tmp_path / "data"),
            "--bank",
            str(tmp_path / "bank"),
            "--crops",
            "1",
            "--size",
            "32",
            "--quiet",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    records = json.loads((tmp_path / "data" / "manifest.json").read_text())["records"]
    assert [r["settings"] for r in records] == [want] * 2


# ---------------------------------------------------------------- the native focus block and fields


@pytest.mark.parametrize(
    "focus, match",
    [
        ({"thickness": 9}, r"focus.thickness: expected a surface index 0..5"),
        ({"thickness": 0}, r"focus.thickness: expected an air gap, but surfaces\[0\] is followed by"),
        ({"thickness": 1, "compensator": 1}, "focus.compensator: expected another gap than focus.thickness"),
        ({"thickness": "1"}, "focus.thickness: expected a 0-based surface index"),
        ({"thickness": True}, "focus.thickness: expected a 0-based surface index"),
        ({"compensator": 3}, "focus.thickness: missing"),
        ({"thickness": 1, "group": 3}, r"focus: unknown key\(s\) group"),
        ([1, 3], "focus: expected a mapping"),
    ],
)
def test_bad_focus_blocks_are_named(focus, match: str) -> None:
    data = lens_to_dict(load_lens("cooke_triplet"))
    data["focus"] = focus
    with pytest.raises(InputError, match=match):
        lens_from_dict(data, source="t.yaml")


def test_object_height_fields_become_the_angles_they_subtend() -> None:
    data = lens_to_dict(load_lens("cooke_triplet"))
    data["object"] = {"distance": 800.0}
    data["fields"] = {"type": "object_height", "values": [0.0, 100.0, 200.0]}
    lens = lens_from_dict(data)
    z_ep = paraxial_data(lens).entrance_pupil_z_mm
    at = lens_at(lens, ShootingSettings(focus_m=math.inf))
    assert at.infinite_object and at.field_type == "angle"
    assert at.fields == pytest.approx([math.degrees(math.atan2(h, 800.0 + z_ep)) for h in (0.0, 100.0, 200.0)])
    # the file's own object distance keeps its fields
    same = lens_at(lens, ShootingSettings(fno=8))
    assert same.field_type == "object_height" and same.fields == lens.fields


def test_lens_info_shows_the_lens_at_a_zoom_position(reference_lenses, capsys, monkeypatch) -> None:
    import json

    from cli_runner import run_cli

    code, out, err = run_cli(
        [
            "lens",
            "info",
            str(reference_lenses / "nikon_80-200_zoom.zmx"),
            "--config",
            "3",
            "--fno",
            "4",
            "--model-glass",  # the EFL of the file's own nd/Vd model glasses (optiland's)
            "--json",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    info = json.loads(out)
    assert info["efl_mm"] == pytest.approx(143.0764, abs=1e-3)
    assert info["settings"]["config"] == "3" and info["settings"]["fno"] == pytest.approx(4.0)
    assert info["epd_mm"] == pytest.approx(info["efl_mm"] / 4.0, rel=1e-9)


def test_a_demo_folder_refuses_other_shooting_settings(tmp_path, capsys, monkeypatch) -> None:
    # a demo folder made at the lens file's settings is not resumed at F/8 (its cached
    # bank and pairs are of another lens): one line naming the marker, nothing computed
    from cli_runner import run_cli
    from lensim.demo import DemoSettings, _claim_folder

    _claim_folder(tmp_path, DemoSettings.make(True), quick=True, seed=0)
    code, _, err = run_cli(["demo", "--quick", "--fno", "8", "-o", str(tmp_path)], capsys, monkeypatch)
    assert code == 2 and "demo.json" in err and "shooting=None" in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.json"]


def test_lens_at_settings_saves_as_yaml(tmp_path) -> None:
    """A lens at shooting settings (numpy numbers in its surfaces) writes as YAML and reads back."""
    from lensim.optics.lens_file import save_lens

    lens = lens_at(load_lens("phone_wide", warn=False), ShootingSettings(object_m=1.0, focus_m=1.0))
    save_lens(lens, tmp_path / "at1m.yaml")
    again = load_lens(tmp_path / "at1m.yaml", warn=False)
    assert lens_to_dict(again) == lens_to_dict(lens)
