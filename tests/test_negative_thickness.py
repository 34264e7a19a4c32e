"""Negative thicknesses in air, traced sequentially as in Zemax.

A thickness in air may run against the light to place a surface that bends no ray (a stop
or a dummy plane) behind the next vertex, as phone-lens patents do with their stop. Every
surface is then intersected in turn whatever the sign of the distance along the ray. The
checks: (a) a +d / -d pair of dummy surfaces, or a stop placed by a negative thickness,
changes no ray (to 1e-12 mm); (b) nor any paraxial figure; (c) optiland traces a lens
whose stop lies behind the first vertex the same way; (d) what no real lens can do (a
negative thickness inside glass, lens surfaces overlapping) is a one-line error, and a ray
still cannot travel backwards inside glass; (e) a Zemax file with a negative DISZ in air
loads.
"""

from __future__ import annotations

import copy
import json

import pytest
import torch

from lensim.errors import InputError
from lensim.optics.aiming.rays import generate_rays
from lensim.optics.aiming.sampling import hexapolar, square_grid
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_from_dict, lens_to_dict, load_lens
from lensim.optics.materials import Air, ConstantIndex
from lensim.optics.paraxial import paraxial_data
from lensim.optics.surfaces import Surface
from lensim.optics.trace import MISSED, OK, VIGNETTED, trace, trace_reference
from lensim.optics.zemax import read_zmx
from optiland_models import assert_agrees_with_optiland

TOL_MM = 1e-12
FIELDS = [0.0, 14.0, 20.0, 23.0]  # 23 deg: beyond the file's 20, so the clear apertures vignette


def cooke(clear: bool = True) -> Lens:
    """The built-in Cooke triplet; with clear apertures (its drawn semi-diameters) that
    vignette the outer fields."""
    lens = load_lens("cooke_triplet", warn=False)
    surfaces = [copy.copy(s) for s in lens.surfaces]
    if clear:
        for s in surfaces:
            s.clear_radius = s.semi_diameter
    return lens.with_changes(surfaces=surfaces)


def insert(lens: Lens, after: int, new: list[Surface]) -> Lens:
    """The lens with surfaces `new` inserted after surface `after` (-1: before the first)."""
    surfaces = [copy.copy(s) for s in lens.surfaces]
    return lens.with_changes(surfaces=surfaces[: after + 1] + new + surfaces[after + 1 :])


def dummy_pair(lens: Lens, after: int, d: float) -> Lens:
    """A dummy air plane with thickness +d, then one with -d, after surface `after`: the
    second dummy lies d beyond the first, the next surface where it was."""
    return insert(lens, after, [Surface(thickness=d), Surface(thickness=-d)])


def traced(lens: Lens, aiming: str, fields=FIELDS, pupil=None):
    pupil = square_grid(25) if pupil is None else pupil
    rays, wl = generate_rays(lens, fields, pupil, lens.wavelengths_um, aiming)
    return trace(lens, rays, wl), rays, wl


def assert_same_rays(a, b, index_map) -> None:
    """Same status for every ray, the same surface of failure (b's index mapped to a's),
    and the same image-plane position, direction and optical path (1e-12 mm)."""
    assert torch.equal(a.status, b.status)
    fa = a.failed_at[a.status != OK]
    fb = b.failed_at[b.status != OK].apply_(index_map) if fa.numel() else fa
    assert torch.equal(fa, fb)
    ok = a.rays.valid
    assert torch.equal(ok, b.rays.valid)
    for x, y in ((a.rays.position, b.rays.position), (a.rays.direction, b.rays.direction)):
        assert float((x - y)[ok].abs().max()) < TOL_MM
    assert float((a.rays.opl - b.rays.opl)[ok].abs().max()) < TOL_MM


# ---------------------------------------------------------------- (a) every ray


@pytest.mark.parametrize("aiming", ["paraxial", "real"])
@pytest.mark.parametrize("after", [1, 3, 5])  # the three air gaps (after 5: before the image)
@pytest.mark.parametrize("d", [0.5, 20.0])  # 20 mm: the dummies lie beyond the next lens
def test_dummy_pair_changes_no_ray(after, d, aiming):
    base = cooke()
    ref, _, _ = traced(base, aiming)
    assert bool((ref.status == VIGNETTED).any()) and bool((ref.status == OK).any())  # the check means something
    lens = dummy_pair(base, after, d)
    assert lens.virtual_steps().tolist() == [i == after + 3 for i in range(lens.num_surfaces + 1)]
    res, rays, wl = traced(lens, aiming)
    assert_same_rays(ref, res, lambda k: k - 2 if k > after + 2 else k)
    # the plain surface-by-surface tracer agrees
    slow = trace_reference(lens, rays, wl)
    assert torch.equal(slow.status, res.status) and torch.equal(slow.failed_at, res.failed_at)
    assert float((slow.rays.position - res.rays.position)[res.rays.valid].abs().max()) < TOL_MM


@pytest.mark.parametrize("after", [3, 9])  # behind lens 1 (0.030 mm of air) and lens 4 (0.205 mm)
def test_dummy_pair_changes_no_ray_through_aspheres(after):
    # the phone lens: the next even asphere is met 0.5 mm back along the ray (Newton from
    # the conic root nearest the vertex plane, as for a positive distance); its clear
    # aperture and conic domain stop the same rays
    base = load_lens("phone_wide", warn=False)
    ref, _, _ = traced(base, "paraxial", [0.0, 25.2, 36.0], hexapolar(8))
    assert bool((ref.status != OK).any())
    res, _, _ = traced(dummy_pair(base, after, 0.5), "paraxial", [0.0, 25.2, 36.0], hexapolar(8))
    assert_same_rays(ref, res, lambda k: k - 2 if k > after + 2 else k)


def _stop_in_gap(negative: bool) -> Lens:
    """The Cooke triplet with its stop moved off lens 2's rear surface onto a plane 1.5 mm
    behind it, written with positive thicknesses only, or with the stop reached by a
    negative thickness from a dummy plane at lens 3's vertex."""
    base = cooke()
    surfaces = [copy.copy(s) for s in base.surfaces]
    surfaces[3].is_stop = False
    g, a = surfaces[3].thickness, 1.5
    if negative:
        new = [Surface(thickness=a - g), Surface(thickness=g - a, is_stop=True)]  # dummy at lens 3, stop back at +a
    else:
        surfaces[3].thickness = a
        new = [Surface(thickness=g - a, is_stop=True)]
    return base.with_changes(
        surfaces=surfaces[:4] + new + surfaces[4:], aperture_type="stop_semi_diameter", aperture_value=3.5
    )


@pytest.mark.parametrize("aiming", ["paraxial", "real"])
def test_stop_placed_by_a_negative_thickness_changes_no_ray(aiming):
    positive, negative = _stop_in_gap(False), _stop_in_gap(True)
    assert negative.surfaces[negative.stop_index - 1].thickness < 0
    assert negative.vertex_z()[negative.stop_index] == pytest.approx(
        positive.vertex_z()[positive.stop_index], abs=1e-12
    )
    ref, _, _ = traced(positive, aiming)
    res, _, _ = traced(negative, aiming)
    assert_same_rays(ref, res, lambda k: k - 1 if k > 4 else k)


def test_zero_thickness_stop_before_a_concave_surface():
    # a stop on the vertex plane of a surface that curves towards the object: the rays
    # meet the surface behind the stop plane (negative distance), and all reach the image
    lens = Lens(
        [Surface(0.0, 0.0, is_stop=True), Surface(-1 / 30.0, 4.0, ConstantIndex(1.6)), Surface(-1 / 12.0, 40.0)],
        aperture_value=10.0,
        fields=[0.0, 10.0],
        wavelengths_um=[0.55],
    )
    assert lens.virtual_steps().tolist() == [False, True, False, False]
    res, _, _ = traced(lens, "paraxial", [0.0, 10.0])
    assert bool((res.status == OK).all())


# ---------------------------------------------------------------- (b) paraxial data


@pytest.mark.parametrize("after", [-1, 1, 3, 5])
def test_dummy_pair_changes_no_paraxial_figure(after):
    base = cooke()
    lens = dummy_pair(base, after, 7.0)
    assert lens.vertex_z()[after + 3] == base.vertex_z()[after + 1]  # z is global: lens 1 stays at z = 0
    a, b = paraxial_data(base).as_dict(), paraxial_data(lens).as_dict()
    # the BFL is measured from the last surface (as in Zemax), a dummy after the last lens
    # surface included: where it puts the focus is what must not change
    a["bfl_mm"] += base.vertex_z()[-2]
    b["bfl_mm"] += lens.vertex_z()[-2]
    for key, value in a.items():
        assert b[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key


def test_stop_placed_by_a_negative_thickness_changes_no_paraxial_figure():
    a, b = paraxial_data(_stop_in_gap(False)).as_dict(), paraxial_data(_stop_in_gap(True)).as_dict()
    for key, value in a.items():
        assert b[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key


# ---------------------------------------------------------------- (c) optiland


def stop_behind_first_vertex(h: float = 0.3) -> Lens:
    """The Cooke triplet with its stop in object space, h mm behind the front vertex of
    lens 1, written as the patents do: a dummy plane at lens 1's vertex (thickness h),
    then the stop (thickness -h). EPD 10 mm, so the stop's semi-diameter is 5 mm. With
    the clear apertures of cooke(): the full-field beam, far off axis behind a front stop,
    would otherwise cross lens 3's rim beyond r = 9.2 mm, where its edge thickness is
    negative (lensim stops such rays, optiland traces them on)."""
    base = cooke()
    surfaces = [copy.copy(s) for s in base.surfaces]
    surfaces[3].is_stop = False
    return base.with_changes(surfaces=[Surface(thickness=h), Surface(thickness=-h, is_stop=True)] + surfaces)


def test_stop_behind_the_first_vertex_traces_both_ways():
    # lens 1's front surface (R = 22 mm) lies behind the stop plane (z = 0.3 mm) beyond
    # r = 3.6 mm: rays near the axis go back to it, rim rays forward
    lens = stop_behind_first_vertex()
    para = paraxial_data(lens)
    assert para.entrance_pupil_z_mm == pytest.approx(0.3, abs=1e-12)
    assert para.stop_semi_diameter_mm == pytest.approx(5.0, abs=1e-12)
    rays, wl = generate_rays(lens, [0.0, 20.0], hexapolar(8), lens.wavelengths_um, "paraxial", para)
    res = trace(lens, rays, wl, record=True)
    assert bool((res.status[:, 0] == OK).all())  # on axis nothing is lost (off axis: lens 2's rim)
    assert set(res.status.unique().tolist()) == {OK, VIGNETTED}
    z_lens1 = res.surface_positions[2, ..., 2]
    assert bool((z_lens1 < 0.3).any()) and bool((z_lens1 > 0.3).any())
    # the stop is in object space: real aiming gives the same rays
    real, wl = generate_rays(lens, [0.0, 20.0], hexapolar(8), lens.wavelengths_um, "real", para)
    assert float((real.position - rays.position).abs().max()) < 1e-9


@pytest.mark.filterwarnings("ignore")
def test_stop_behind_the_first_vertex_agrees_with_optiland():
    """optiland 0.6.3, built surface for surface (negative thickness included) with
    lensim's glass data: EFL and F-number to 1e-9, RMS spot radius at 0 / 0.7 / 1.0 field
    (optiland's definition: per wavelength, about the primary-wavelength chief ray, 6
    hexapolar rings) within 1e-4 relative (measured 7e-13), the same rays vignetted."""
    pytest.importorskip("optiland")
    assert_agrees_with_optiland(stop_behind_first_vertex(), rms_rtol=1e-4)


# ---------------------------------------------------------------- (d) impossible geometry


def _cooke_dict() -> dict:
    return lens_to_dict(load_lens("cooke_triplet", warn=False))


def one_line_error(data: dict, source: str = "neg.yaml") -> str:
    with pytest.raises(InputError) as e:
        lens_from_dict(data, source)
    line = str(e.value)
    assert "\n" not in line and line.startswith(f"{source}: ")
    return line


def test_negative_thickness_inside_glass_is_an_error():
    d = _cooke_dict()
    d["surfaces"][0]["thickness"] = -3.25896
    line = one_line_error(d)
    assert line.startswith("neg.yaml: surfaces[0].thickness: expected a positive thickness inside J-SK16, got -3.25896")
    assert "cannot travel backwards inside glass" in line


def test_overlapping_lens_surfaces_are_an_error():
    # a negative air gap straight between two lens surfaces
    d = _cooke_dict()
    d["surfaces"][1]["thickness"] = -6.0
    line = one_line_error(d)
    assert line.startswith(
        "neg.yaml: surfaces[1].thickness: expected a positive thickness, got -6: surfaces[2] "
        "would lie behind surfaces[1]"
    )
    # ... or through a dummy plane, adding up to less than zero
    d = _cooke_dict()
    d["surfaces"].insert(2, {"thickness": -7.0})
    line = one_line_error(d)
    assert line.startswith(
        "neg.yaml: surfaces[2].thickness: expected the air from surfaces[1] to surfaces[3] to add "
        "up to >= 0 mm along the light's path, got -0.99245 mm"
    )
    # ... or putting the image plane before the last lens surface
    d = _cooke_dict()
    d["surfaces"].append({"thickness": -50.0})
    assert "expected the air from surfaces[5] to the image plane" in one_line_error(d)


def test_object_behind_the_first_lens_surface_is_an_error():
    d = _cooke_dict()
    d["object"] = {"distance": 10.0}
    d["surfaces"].insert(0, {"thickness": -12.0})
    line = one_line_error(d)
    assert "surfaces[0].thickness: expected the air from the object to surfaces[1] to add up to >= 0 mm" in line
    d["object"] = {"distance": 12.5}
    lens_from_dict(d, "ok.yaml")  # 0.5 mm of air left: fine


def test_a_ray_cannot_travel_backwards_inside_glass():
    # a biconvex lens (R = 10 mm, 1 mm thick) whose edge thickness is negative beyond
    # r = 3.12 mm, behind a stop placed by a negative thickness: rim rays would have to
    # travel backwards inside the glass to its rear surface, so they miss it there
    lens = Lens(
        [
            Surface(0.0, 0.5),
            Surface(0.0, -0.5, is_stop=True),
            Surface(0.1, 1.0, ConstantIndex(1.5)),
            Surface(-0.1, 20.0),
        ],
        aperture_value=8.0,
        wavelengths_um=[0.55],
    )
    res, rays, _ = traced(lens, "paraxial", [0.0], square_grid(41))
    r = torch.linalg.norm(rays.position[..., :2], dim=-1)
    assert bool((res.status[r < 3.0] == OK).all())
    missed = res.status == MISSED
    assert bool(missed[r > 3.3].all()) and set(res.failed_at[missed].tolist()) == {3}


# ---------------------------------------------------------------- (e) Zemax


def _zmx(disz_dummy: float, disz_stop: float) -> str:
    return f"""VERS 140730 73 26155
MODE SEQ
NAME stop behind lens 1
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 3 1 0 0 0
YFLN 0 14 20
WAVM 1 0.55 1
PWAV 1
SURF 0
  TYPE STANDARD
  DISZ INFINITY
SURF 1
  TYPE STANDARD
  DISZ {disz_dummy}
SURF 2
  STOP
  TYPE STANDARD
  DISZ {disz_stop}
SURF 3
  TYPE STANDARD
  CURV 4.542684386E-2
  GLAS ___BLANK 1 0 1.62 60
  DISZ 3.25896
SURF 4
  TYPE STANDARD
  CURV -2.29483E-3
  DISZ 50
SURF 5
  TYPE STANDARD
  DISZ 0
"""


def test_zemax_file_with_a_negative_air_thickness_loads(tmp_path):
    path = tmp_path / "stop_behind.zmx"
    path.write_text(_zmx(0.3, -0.3))
    lens = read_zmx(path)
    assert [s.thickness for s in lens.surfaces] == [0.3, -0.3, 3.25896, 50.0]
    assert lens.stop_index == 1 and isinstance(lens.surfaces[1].material, Air)
    para = paraxial_data(lens)
    assert para.entrance_pupil_z_mm == pytest.approx(0.3, abs=1e-12)
    res, _, _ = traced(lens, "real", [0.0, 14.0, 20.0])
    assert bool((res.status == OK).all())
    # a negative DISZ that makes lens surfaces overlap names the file and the surface
    path.write_text(_zmx(0.3, -0.3).replace("  DISZ 3.25896", "  DISZ -3.25896"))
    with pytest.raises(
        InputError,
        match=r"stop_behind\.zmx: surfaces\[2\]\.thickness: expected a positive thickness "
        r"inside model 1\.62000/60\.00, got -3\.25896: a ray cannot travel backwards",
    ):
        read_zmx(path)


# ---------------------------------------------------------------- command line


def test_command_line_reads_and_draws_a_stop_behind_the_first_vertex(tmp_path, capsys, monkeypatch):
    from cli_runner import run_cli
    from lensim.optics.lens_file import save_lens

    path = tmp_path / "stop_behind.yaml"
    save_lens(stop_behind_first_vertex(), path)
    code, out, err = run_cli(["lens", "info", str(path), "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert json.loads(out)["entrance_pupil_z_mm"] == pytest.approx(0.3, abs=1e-12)
    code, _, err = run_cli(["lens", "plot", str(path), "-o", str(tmp_path / "layout.png")], capsys, monkeypatch)
    assert code == 0, err
    assert (tmp_path / "layout.png").stat().st_size > 10_000
