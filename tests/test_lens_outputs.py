"""Lens-level outputs: `lensim lens field`, `lensim lens plot --kind ...` and the lensfun
profile of `lensim lens lensfun`, checked with the lensfun library itself (lensfunpy 1.18,
lensfun 0.3.4): it loads the file, and its Modifier, applied to a 24-megapixel frame,
moves every pixel where lensim's own chief rays say (distortion, and red and blue for
lateral colour) and darkens it as lensim's relative illumination says."""

import json
import math
import warnings

import numpy as np
import pytest

from cli_runner import run_cli
from lensim.optics.aiming.rays import chief_ray_image_height
from lensim.optics.field_analysis import distortion, relative_illumination
from lensim.optics.lens_file import load_lens
from lensim.optics.lensfun import CORNER_IN_SHORT_HALF_SIDES
from lensim.optics.paraxial import paraxial_image_height
from lensim.optics.shooting import ShootingSettings, lens_at

ASPHERIC = "US08427765-1.zmx"  # EFL 30.8 mm F/2.1, 13.6 mm image height: an APS-C lens
CROP, FOCAL, APERTURE = 1.6, 30.8, 2.8
WIDTH, HEIGHT = 6000, 4000  # a 24-megapixel 3:2 frame


def test_lens_field_json(capsys, monkeypatch):
    code, out, err = run_cli(
        ["lens", "field", "cooke_triplet", "--json", "--field", "0", "--field", "1"], capsys, monkeypatch
    )
    assert code == 0, err
    report = json.loads(out)
    axis, edge = report["fields"]
    assert (axis["field"], edge["field"]) == (0.0, 20.0) and report["field_unit"] == "deg"
    assert axis["relative_illumination"] == 1.0 and axis["lateral_colour_um"] == {"r": 0.0, "g": 0.0, "b": 0.0}
    lens = load_lens("cooke_triplet")
    dist = distortion(lens, [20.0])
    assert edge["paraxial_height_mm"] == pytest.approx(dist["paraxial_height_mm"][0], abs=1e-12)
    assert edge["distortion_percent"] == pytest.approx(dist["distortion_percent"][0], abs=1e-12)
    at_550 = chief_ray_image_height(lens, 20.0, wavelength_um=0.55)
    assert edge["real_height_mm"]["550"] == pytest.approx(at_550, abs=1e-12)
    # each channel's height is a weighted mean of the wavelengths' heights (weights >= 0)
    heights = list(edge["real_height_mm"].values())
    assert all(min(heights) <= h <= max(heights) for h in edge["channel_height_mm"].values())
    # the sign of the triplet's lateral colour at full field: blue lands outside green and
    # red inside (450 nm +0.99 um and 650 nm -0.86 um from 550 nm, tests/test_model_glass.py)
    assert edge["lateral_colour_um"]["b"] > 0.3 and edge["lateral_colour_um"]["r"] < -0.3
    assert edge["relative_illumination"] == pytest.approx(
        relative_illumination(lens, [20.0], samples=32)["relative_illumination"][0], abs=1e-12
    )


@pytest.mark.parametrize("kind", ["distortion", "lateral-colour", "illumination"])
def test_lens_plot_kinds(kind, tmp_path, capsys, monkeypatch):
    target = tmp_path / f"{kind}.png"
    code, _, err = run_cli(
        ["lens", "plot", "cooke_triplet", "--kind", kind, "--field", "0", "--field", "1", "-o", str(target)],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def profile_file(tmp_path_factory, reference_lenses):
    """The lensfun file `lensim lens lensfun` writes for the patent lens, and what it printed."""
    import contextlib
    import io
    import sys
    from unittest import mock

    from lensim.cli import main

    path = tmp_path_factory.mktemp("lensfun") / "profile.xml"
    args = [
        "lensim",
        "lens",
        "lensfun",
        str(reference_lenses / ASPHERIC),
        "--maker",
        "Patent",
        "--model",
        "US 8,427,765 Ex. 1",
        "--mount",
        "Generic",
        "--crop-factor",
        str(CROP),
        "--focal",
        str(FOCAL),
        "--aperture",
        str(APERTURE),
        "-o",
        str(path),
    ]
    out = io.StringIO()
    with mock.patch.object(sys, "argv", args), contextlib.redirect_stdout(out), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SystemExit) as exc:
            main()
    assert exc.value.code in (0, None), out.getvalue()
    return path, out.getvalue()


def lensfun_lens(path):
    import lensfunpy

    db = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
    (lens,) = db.lenses
    return lens


def test_lensfun_loads_the_profile(profile_file):
    pytest.importorskip("lensfunpy")
    path, printed = profile_file
    text = " ".join(printed.split())  # the console wraps long lines
    assert f"wrote {path}" in text and "largest fit residuals: distortion" in text
    lens = lensfun_lens(path)
    assert (lens.maker, lens.model, lens.crop_factor) == ("Patent", "US 8,427,765 Ex. 1", pytest.approx(CROP))
    (d,), (t,), (v,) = lens.calib_distortion, lens.calib_tca, lens.calib_vignetting
    assert (d.focal, t.focal, v.focal) == (pytest.approx(FOCAL),) * 3
    assert (v.aperture, v.distance) == (pytest.approx(APERTURE), 1000.0)
    # barrel distortion, a red image slightly larger than green's: what the patent lens does
    assert len(d.terms) == 3 and len(t.terms) == 6 and len(v.terms) == 3


def _probe_pixels() -> tuple[np.ndarray, np.ndarray]:
    """Output pixels along the top edge, the diagonal and the horizontal midline."""
    xs = np.linspace(0, WIDTH - 1, 41)
    top = np.stack([xs, np.zeros_like(xs)], 1)
    diag = np.stack([xs, xs * (HEIGHT - 1) / (WIDTH - 1)], 1)
    mid = np.stack([xs, np.full_like(xs, (HEIGHT - 1) / 2)], 1)
    pts = np.concatenate([top, diag, mid]).round().astype(int)
    return pts[:, 0], pts[:, 1]


def _channel_heights(lens, launch: list[float]) -> np.ndarray:
    """(F, 3) chief-ray heights (mm) of the default sensor's R, G, B channels."""
    from lensim.optics.field_analysis import lateral_colour
    from lensim.sensor.profile import load_sensor
    from lensim.sensor.spectral import spectral_response

    resp = spectral_response(None, load_sensor(None).spectral_response)
    return np.array(lateral_colour(lens, launch, resp.wavelengths_nm, resp.weights)["channel_height_mm"])


def _lensim_source_radii(lens, ru: np.ndarray) -> np.ndarray:
    """(len(ru), 3): where lensim's chief rays put the R, G, B images of the point whose
    ideal image radius is ru, in lensfun's unit (half the short side: 12 mm / crop factor).
    The ideal image is the paraxial one scaled by k, and lensfun's normalization fixes k:
    the point of ideal radius 1 is the one green images at radius 1."""
    unit = 12.0 / CROP
    probe = lens.launch_lens()
    per_tan = paraxial_image_height(probe, 1.0) / math.tan(math.radians(1.0))  # mm per unit tan(angle)
    t = unit / per_tan
    for _ in range(3):  # tan(angle) whose green chief ray lands at r = 1
        t *= unit / _channel_heights(probe, [math.degrees(math.atan(t))])[0, 1]
    k = unit / (per_tan * t)
    launch = np.degrees(np.arctan(ru / k * unit / per_tan))
    return _channel_heights(probe, list(launch)) / unit


def test_lensfun_reproduces_lensims_distortion_and_lateral_colour(profile_file, reference_lenses):
    """lensfun's Modifier on a 6000 x 4000 frame (crop 1.6) sends each probe pixel (top edge,
    diagonal, midline; 123 pixels) to where lensim's own chief rays, traced for exactly that
    pixel, say: within 0.5 px for green (the distortion; pixels move up to 36 px) and for
    red and blue (lateral colour on top). Measured: pixels move up to 34.8 px; lensfun puts
    them within 0.05 px of lensim for green, red and blue."""
    pytest.importorskip("lensfunpy")
    import lensfunpy

    path, _ = profile_file
    mod = lensfunpy.Modifier(lensfun_lens(path), CROP, WIDTH, HEIGHT)
    mod.initialize(
        FOCAL, APERTURE, 1000.0, scale=1.0, flags=lensfunpy.ModifyFlags.DISTORTION | lensfunpy.ModifyFlags.TCA
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = lens_at(load_lens(reference_lenses / ASPHERIC), ShootingSettings(fno=APERTURE))
    px, py = _probe_pixels()
    cx, cy, unit_px = (WIDTH - 1) / 2, (HEIGHT - 1) / 2, HEIGHT / 2
    dx, dy = px - cx, py - cy
    ru = np.hypot(dx, dy) / unit_px
    assert ru.max() == pytest.approx(CORNER_IN_SHORT_HALF_SIDES, abs=1e-3)
    moved, errors = 0.0, []
    ours = _lensim_source_radii(lens, ru)
    for channel in (1, 0, 2):  # green (distortion), red, blue
        scale = np.where(ru > 0, ours[:, channel] / np.maximum(ru, 1e-12), 1.0)
        theirs = np.array(
            [mod.apply_subpixel_geometry_distortion(float(x), float(y), 1, 1)[0, 0, channel] for x, y in zip(px, py)]
        )
        err = np.hypot(theirs[:, 0] - (cx + dx * scale), theirs[:, 1] - (cy + dy * scale))
        errors.append(err.max())
        moved = max(moved, np.hypot(dx * (scale - 1), dy * (scale - 1)).max())
    assert moved > 20.0  # the test can see a wrong radius unit: distortion moves pixels by tens of px
    assert max(errors) < 0.5, errors


def test_lensfun_vignetting_matches_relative_illumination(profile_file, reference_lenses):
    """lensfun's vignetting correction of a uniform frame, inverted, is lensim's relative
    illumination at each pixel's real image height (r = 1 at the frame's corner) within
    0.01 (measured 0.006, the pa fit's own residual being 0.005; relative illumination
    0.91 to 0.57 along the top edge)."""
    pytest.importorskip("lensfunpy")
    import lensfunpy

    path, _ = profile_file
    w, h = 300, 200
    mod = lensfunpy.Modifier(lensfun_lens(path), CROP, w, h)
    mod.initialize(FOCAL, APERTURE, 1000.0, scale=1.0, pixel_format=np.float32, flags=lensfunpy.ModifyFlags.VIGNETTING)
    img = np.full((h, w, 3), 0.25, dtype=np.float32)
    assert mod.apply_color_modification(img)
    cols = np.array([150, 200, 250, 299])  # top row, from the middle to the corner
    ri_lensfun = 0.25 / img[0, cols, 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = lens_at(load_lens(reference_lenses / ASPHERIC), ShootingSettings(fno=APERTURE))
    height_mm = np.hypot(cols - (w - 1) / 2, (h - 1) / 2) / (h / 2) * (12.0 / CROP)
    by_height = lens.with_changes(field_type="real_image_height", fields=[float(height_mm.max())])
    ri = relative_illumination(by_height, list(height_mm), samples=32)["relative_illumination"]
    assert np.abs(ri_lensfun - np.array(ri)).max() < 0.01
    assert min(ri) < 0.8  # the corner is visibly darker: the check can fail


@pytest.mark.parametrize(
    "args, message",
    [
        (["--crop-factor", "0"], "--crop-factor: expected a positive number"),
        (["--crop-factor", "0.5"], "does not reach the corner of a 3:2 frame at crop factor 0.5"),
        (["--aperture", "-2"], "--aperture: expected a positive number"),
        (["--distance", "0"], "--distance: expected a positive focus distance"),
        (["--maker", " "], "--maker: expected a non-empty name"),
        (["-o", "profile.txt"], "--output: expected a .xml file name"),
    ],
)
def test_lensfun_bad_settings_are_one_line_errors(args, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = {
        "--maker": "M",
        "--model": "L",
        "--mount": "Generic",
        "--crop-factor": "1.5",
        "--focal": "50",
        "--aperture": "5.6",
        "-o": "profile.xml",
    }
    base.update(dict(zip(args[::2], args[1::2])))
    code, _, err = run_cli(
        ["lens", "lensfun", "cooke_triplet", *[x for kv in base.items() for x in kv]], capsys, monkeypatch
    )
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir())


def test_field_plot_bad_inputs_are_one_line_errors(tmp_path, capsys, monkeypatch):
    code, _, err = run_cli(
        ["lens", "plot", "cooke_triplet", "--kind", "distortion", "-o", str(tmp_path / "d.txt")], capsys, monkeypatch
    )
    assert code == 2 and "expected an image name ending in .png, .pdf or .svg" in err
    code, _, err = run_cli(["lens", "field", "cooke_triplet", "--sensor", "no-such-sensor"], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "no-such-sensor" in err


def test_lensfun_takes_a_nominal_aperture_with_one_warning_line(tmp_path, capsys, monkeypatch) -> None:
    """`--aperture 4.8` on the F/5 triplet (0.12 stop: a rounded marking) writes the wide-open
    profile and says so in one warning line; 4.5 (0.30 stop) is refused in one line."""
    args = "lens lensfun cooke_triplet --maker m --model x --mount Generic --crop-factor 1.5 --focal 50 --aperture"
    code, _, err = run_cli([*args.split(), "4.8", "-o", str(tmp_path / "p.xml")], capsys, monkeypatch)
    assert code == 0, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: F/4.8 is 0.12 stop faster"), err
    assert "F/5 " in lines[0] and (tmp_path / "p.xml").is_file()
    code, _, err = run_cli([*args.split(), "4.5", "-o", str(tmp_path / "q.xml")], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1 and "--aperture: F/4.5 is faster" in err, err
    assert not (tmp_path / "q.xml").exists()
