"""`lensim lens info|plot|spot` end to end, and the layout / spot plots they draw."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import torch
import yaml

from cli_runner import run_cli
from lensim.errors import RayTraceError
from lensim.optics.aiming.rays import object_field
from lensim.optics.aiming.sampling import hexapolar
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_from_dict, load_lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.paraxial import paraxial_data
from lensim.optics.spot import spot_diagram
from lensim.optics.surfaces import Surface
from lensim.optics.trace import VIGNETTED
from lensim.plots.lens import plot_layout, plot_spots, trace_ray_paths

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path, min_bytes: int = 10_000) -> np.ndarray:
    """A real, non-blank PNG; returns its pixels."""
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    assert len(data) > min_bytes
    img = matplotlib.image.imread(path)
    assert img.shape[0] > 200 and img.shape[1] > 200
    assert float(img[..., :3].std()) > 0.02  # something is drawn on the white background
    assert not [p.name for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.")]  # no temp file left
    return img


def mirror_dict(conic: float = -1.0, thickness: float = -100.0, fields=(0.0, 1.0)) -> dict:
    """A concave mirror, R = -200 mm (f = 100 mm), stop on the mirror, image 100 mm in front
    of it (negative thickness after the mirror). conic -1: a paraboloid."""
    return {
        "name": "concave mirror f=100",
        "aperture": {"type": "epd", "value": 20.0},
        "fields": {"type": "angle", "values": list(fields)},
        "wavelengths": {"nm": [550.0]},
        "surfaces": [{"radius": -200.0, "conic": conic, "thickness": thickness, "mirror": True, "stop": True}],
    }


# ---- lens info ------------------------------------------------------------------------
def test_info_json_first_order_data(capsys, monkeypatch):
    code, out, err = run_cli(["lens", "info", "cooke_triplet", "--json"], capsys, monkeypatch)
    assert code == 0, err
    d = json.loads(out)
    for key in (
        "efl_mm",
        "bfl_mm",
        "fno",
        "epd_mm",
        "entrance_pupil_z_mm",
        "exit_pupil_z_mm",
        "exit_pupil_diameter_mm",
        "max_field",
        "field_type",
        "wavelengths_um",
        "primary_wavelength_um",
        "image_height_mm",
    ):
        assert key in d, key
    assert d["efl_mm"] == pytest.approx(50.0, abs=0.01)
    assert d["epd_mm"] == pytest.approx(10.0)
    assert d["fno"] == pytest.approx(d["efl_mm"] / d["epd_mm"], rel=1e-9)
    # BFL: last vertex (z = 17.969) to the paraxial focus, a little beyond the image plane at 42.208
    assert 42.0 < d["bfl_mm"] < 43.0
    # the stop sits between the elements (z = 10.27 mm), so both pupils lie inside the lens
    assert 0.0 < d["entrance_pupil_z_mm"] < 17.97 and 0.0 < d["exit_pupil_z_mm"] < 17.97
    assert 9.0 < d["exit_pupil_diameter_mm"] < 12.0
    assert d["max_field"] == 20.0 and d["field_type"] == "angle"
    assert d["wavelengths_um"] == pytest.approx([0.48, 0.55, 0.65])
    assert d["primary_wavelength_um"] == pytest.approx(0.55)
    # f tan(20 deg) = 18.20 mm, less the triplet's small barrel distortion
    assert d["image_height_mm"] == pytest.approx(50.0 * math.tan(math.radians(20.0)), rel=0.01)


def test_python_dash_m_lensim_runs_the_cli(tmp_path):
    lens_file = tmp_path / "mirror.json"  # no catalogue glass: a quick start
    lens_file.write_text(json.dumps(mirror_dict()))
    r = subprocess.run(
        [sys.executable, "-m", "lensim", "lens", "info", str(lens_file), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["efl_mm"] == pytest.approx(100.0) and d["fno"] == pytest.approx(5.0)


@pytest.mark.parametrize("command", ["plot", "spot"])
def test_help_has_an_example(command, capsys, monkeypatch):
    code, out, _ = run_cli(["lens", command, "--help"], capsys, monkeypatch)
    assert code == 0
    assert f"Example: lensim lens {command} " in out


# ---- lens plot ------------------------------------------------------------------------
def test_plot_writes_a_png(tmp_path, capsys, monkeypatch):
    out_png = tmp_path / "figs" / "layout.png"
    code, out, err = run_cli(["lens", "plot", "cooke_triplet", "-o", str(out_png), "--rays", "5"], capsys, monkeypatch)
    assert code == 0, err
    assert "layout.png" in out
    assert_png(out_png)


def test_plot_rejects_an_unknown_image_type_and_writes_nothing(tmp_path, capsys, monkeypatch):
    target = tmp_path / "layout.txt"
    code, _, err = run_cli(["lens", "plot", "cooke_triplet", "-o", str(target)], capsys, monkeypatch)
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert str(target) in err and ".png" in err
    assert list(tmp_path.iterdir()) == []


def test_layout_rays_follow_the_trace_and_end_at_the_image():
    lens = load_lens("cooke_triplet")
    para = paraxial_data(lens)
    paths, rays, status, _ = trace_ray_paths(lens, [0.0, 20.0], np.linspace(-1, 1, 5), "real", para, -10.0)
    assert (status == 0).all()
    assert paths.reached.all()
    assert np.allclose(paths.points[..., 0, 0], -10.0)  # drawn from z = -10 mm
    zv = lens.vertex_z()
    assert np.allclose(paths.points[..., -1, 0], zv[-1])  # the last point lies on the image plane
    assert np.allclose(paths.points[..., -1, 1], rays.position[0, ..., 1].numpy())
    # every intermediate point lies on its surface: z = vertex + sag(y^2)
    for i, s in enumerate(lens.surfaces):
        y = paths.points[..., i + 1, 1]
        sag = s.geometry.sag(torch.as_tensor(y * y)).numpy()
        assert np.allclose(paths.points[..., i + 1, 0], zv[i] + sag, atol=1e-9)


def test_layout_vignetted_rays_end_on_the_blocking_surface():
    data = yaml.safe_load((Path(load_lens("cooke_triplet").source)).read_text())
    for sd in data["surfaces"]:
        sd["clear_semi_diameter"] = 0.8 * sd.pop("semi_diameter")
    lens = lens_from_dict(data, "clipped")
    para = paraxial_data(lens)
    paths, _, status, failed_at = trace_ray_paths(lens, [20.0], np.linspace(-1, 1, 11), "real", para, None)
    blocked = (status[0] == VIGNETTED).numpy()
    assert blocked.any() and not blocked.all()
    for f, p in zip(*np.nonzero(blocked)):
        k = int(failed_at[0, f, p])
        reached = paths.reached[f, p]
        assert reached[: k + 2].all() and not reached[k + 2 :].any()  # start point + surfaces 0..k
        y = paths.points[f, p, k + 1, 1]
        assert abs(y) > lens.surfaces[k].clear_radius  # stopped outside the clear aperture
    fig = plot_layout(lens, rays_per_field=9)
    ax = fig.axes[0]
    assert "EFL 50 mm" in ax.get_title() and "F/5" in ax.get_title()


def test_mirror_layout_and_image_position(tmp_path):
    lens = lens_from_dict(mirror_dict(conic=0.0, fields=(0.0, 1.0, 2.0)), "mirror")
    para = paraxial_data(lens)
    assert para.efl_mm == pytest.approx(100.0)
    paths, _, status, _ = trace_ray_paths(lens, [2.0], np.array([0.0, -1.0, 1.0]), "real", para, -120.0)
    assert (status == 0).all()
    # reflected back towards -z onto the image plane at z = -100
    assert np.allclose(paths.points[0, :, -1, 0], -100.0)
    # the chief ray reflects at the vertex: image height f tan(field)
    assert paths.points[0, 0, -1, 1] == pytest.approx(100.0 * math.tan(math.radians(2.0)), abs=1e-9)
    out_png = tmp_path / "mirror.png"
    fig = plot_layout(lens, path=out_png)
    assert_png(out_png)
    assert "EFL 100 mm" in fig.axes[0].get_title()


def test_cassegrain_layout_with_central_obscuration(tmp_path):
    # primary f = 200 with the secondary's shadow as an obscuration, convex secondary,
    # image 50 mm behind the primary: EFL 800 mm. Its chief rays are obscured, not an error.
    lens = Lens(
        [
            Surface(-1 / 400, -150.0, is_mirror=True, is_stop=True, obscuration_radius=12.0, semi_diameter=32.0),
            Surface(-3 / 400, 200.0, is_mirror=True, semi_diameter=10.0),
        ],
        aperture_value=60.0,
        fields=[0.0, 0.3],
        wavelengths_um=[0.55],
        name="Cassegrain",
    )
    assert paraxial_data(lens).efl_mm == pytest.approx(800.0, rel=1e-6)
    out_png = tmp_path / "cass.png"
    plot_layout(lens, rays_per_field=7, path=out_png)
    assert_png(out_png)


# ---- lens spot ------------------------------------------------------------------------
def test_spot_writes_png_and_json(tmp_path, capsys, monkeypatch):
    out_png = tmp_path / "spot.png"
    code, out, err = run_cli(["lens", "spot", "cooke_triplet", "-o", str(out_png), "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert_png(out_png)
    d = json.loads(out)  # nothing but JSON on stdout
    assert d["output"] == str(out_png) and d["aiming"] == "paraxial" and d["reference"] == "chief"
    assert d["airy_radius_um"] == pytest.approx(1.22 * 0.55 * 5.0, rel=1e-3)
    assert [f["field"] for f in d["fields"]] == [0.0, 14.0, 20.0]
    lens = load_lens("cooke_triplet")
    sd = spot_diagram(lens, None, None, hexapolar(8), "paraxial")
    poly = sd.rms_radius("chief", polychromatic=True) * 1000
    mono = sd.rms_radius("chief", polychromatic=False) * 1000
    for fi, f in enumerate(d["fields"]):
        assert f["field_unit"] == "deg"
        assert f["rms_radius_um"] == pytest.approx(float(poly[fi]), rel=1e-9)
        assert [w["wavelength_nm"] for w in f["wavelengths"]] == [480.0, 550.0, 650.0]
        for wi, w in enumerate(f["wavelengths"]):
            assert 1.0 < w["rms_radius_um"] < 60.0
            assert w["rms_radius_um"] == pytest.approx(float(mono[wi, fi]), rel=1e-9)
            assert w["rays"] == w["rays_reaching_image"] == 217
            assert w["chief_x_mm"] == pytest.approx(0.0, abs=1e-12)
    assert d["fields"][0]["wavelengths"][1]["chief_y_mm"] == pytest.approx(0.0, abs=1e-12)
    full = d["fields"][2]["wavelengths"][1]["chief_y_mm"]
    assert full == pytest.approx(50.0 * math.tan(math.radians(20.0)), rel=0.01)
    # lateral colour: the blue and red chief rays land apart at full field
    blue, red = (d["fields"][2]["wavelengths"][i]["chief_y_mm"] for i in (0, 2))
    assert blue != pytest.approx(red, abs=1e-4)


def test_spot_json_of_a_paraboloid_is_perfect_on_axis(tmp_path, capsys, monkeypatch):
    lens_file = tmp_path / "parabola.yaml"
    lens_file.write_text(yaml.safe_dump(mirror_dict(conic=-1.0)))
    code, out, err = run_cli(
        ["lens", "spot", str(lens_file), "--json", "--field", "0", "--field", "1"], capsys, monkeypatch
    )
    assert code == 0, err
    d = json.loads(out)
    on_axis, off_axis = d["fields"]
    assert on_axis["rms_radius_um"] < 1e-6  # a paraboloid images a point at infinity perfectly
    assert off_axis["rms_radius_um"] > 1.0  # off axis: coma
    assert off_axis["wavelengths"][0]["chief_y_mm"] == pytest.approx(100.0 * math.tan(math.radians(1.0)), abs=1e-9)
    assert d["output"] is None


def test_spot_fields_normalized_in_degrees_or_as_image_height(capsys, monkeypatch):
    def chief_y(*field_args: str) -> tuple[float, dict]:
        code, out, err = run_cli(
            ["lens", "spot", "cooke_triplet", "--json", "--aiming", "real", *field_args], capsys, monkeypatch
        )
        assert code == 0, err
        f = json.loads(out)["fields"][0]
        return f["wavelengths"][load_lens("cooke_triplet").primary]["chief_y_mm"], f

    # --field is normalized (1 = the triplet's 20 deg), --field-deg an angle
    full, f = chief_y("--field", "1")
    assert f["field"] == 20.0 and f["field_unit"] == "deg"
    assert chief_y("--field-deg", "20")[0] == pytest.approx(full, abs=1e-12)
    # --image-height-mm: the real chief ray lands at the asked height
    height, f = chief_y("--image-height-mm", "12.5")
    assert height == pytest.approx(12.5, abs=1e-8) and f["field_unit"] == "mm"
    code, _, err = run_cli(
        ["lens", "spot", "cooke_triplet", "--json", "--field", "1", "--field-deg", "20"], capsys, monkeypatch
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--field-deg" in err
    code, _, err = run_cli(["lens", "plot", "cooke_triplet", "-o", "x.png", "--field", "1.5"], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "between 0 and 1" in err


def test_spot_needs_an_output_or_json(capsys, monkeypatch):
    code, out, err = run_cli(["lens", "spot", "cooke_triplet"], capsys, monkeypatch)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "--json" in err and "-o" in err


def test_plot_spots_centroid_reference_and_image_height_fields(tmp_path):
    data = yaml.safe_load(Path(load_lens("cooke_triplet").source).read_text())
    data["fields"] = {"type": "real_image_height", "values": [0.0, 12.0]}
    lens = lens_from_dict(data, "ih")
    path = tmp_path / "spots.pdf"
    fig = plot_spots(lens, reference="centroid", path=path)
    assert path.read_bytes()[:4] == b"%PDF"
    assert "centroid" in fig.get_suptitle()
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == 2
    assert "12 mm" in panels[1].get_title()
    # the chief ray of a real-image-height field lands at that height
    launch = object_field(lens, 12.0, "paraxial")
    sd = spot_diagram(lens, [12.0], None, hexapolar(2), "paraxial")
    assert float(sd.chief[lens.primary, 0, 1]) == pytest.approx(12.0, abs=1e-8)
    assert launch > 0


def test_layout_refuses_a_chief_ray_that_cannot_be_aimed():
    # a 60 degree chief ray cannot be aimed through a steep clipped front lens onto the stop
    lens = Lens(
        [
            Surface(1 / 5, 3.0, ConstantIndex(1.5), clear_radius=3.0),
            Surface(0.0, 20.0, is_stop=True),
            Surface(0.0, 10.0),
        ],
        aperture_value=2.0,
        fields=[0.0, 60.0],
        wavelengths_um=[0.55],
        source="clip.yaml",
    )
    with pytest.raises(RayTraceError, match=r"clip.yaml: fields: the chief ray at field 60 deg could not be aimed"):
        plot_layout(lens, aiming="real")
    with pytest.raises(RayTraceError, match=r"clip.yaml: fields: the chief ray at field 60 deg is totally internally"):
        plot_layout(lens, aiming="paraxial")
    plot_layout(lens, fields=[0.0, 10.0], aiming="real")  # fields it covers draw
