"""The chart check (issue 24, items 1-2): chart layout and sidecar, marker detection and
pose on rendered photos with perspective and noise, the MTF area against a Gaussian
blur's analytic MTF, and the photo-vs-simulation comparison on a photo lensim simulated
itself (ratios ~1 in every field zone)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from cli_runner import run_cli
from lensim.calibrate.chart import ChartLayout, chart_from_dict, chart_to_dict, design_chart
from lensim.calibrate.chart_detect import check_coverage, detect_chart, estimate_pose
from lensim.calibrate.chart_draw import project, render_view
from lensim.calibrate.chart_measure import ZONES, linear_rgb, measure_chart
from lensim.calibrate.compare import PixelDistortion, compare_chart, ideal_homography
from lensim.errors import InputError
from lensim.evaluate.slanted_edge import mtf_area, pixel_aperture_mtf

LENS, SENSOR, DISTANCE_M = "phone_wide", "phone", 1.0
ROWS, COLS = 720, 960  # the photo: the phone sensor (3.674 x 2.760 mm) at 3.83 um per pixel


def _srgb(linear: np.ndarray) -> np.ndarray:
    a = np.clip(linear, 0.0, 1.0)
    return np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.maximum(a, 0.0031308) ** (1 / 2.4) - 0.055)


def _layout(rows: int = ROWS, cols: int = COLS) -> ChartLayout:
    """A chart whose frame footprint has the photo's aspect (1 mm per pixel)."""
    return design_chart((float(cols), float(rows)), float(cols))


def _frontal(layout: ChartLayout, fill: float = 0.97, tilt: tuple[float, float] = (0.06, -0.04)) -> np.ndarray:
    """A homography that puts the footprint's width at ``fill`` of the photo's, with
    perspective (w = 1 + a x / width + b y / width) and a little shear."""
    s = COLS / layout.frame_mm[0] * fill
    persp = np.array(
        [[1.0, 0.02, 0.0], [-0.015, 1.0, 0.0], [tilt[0] / layout.frame_mm[0], tilt[1] / layout.frame_mm[0], 1]]
    )
    return np.array([[s, 0, (COLS - 1) / 2], [0, s, (ROWS - 1) / 2], [0, 0, 1.0]]) @ persp


def _photo(layout: ChartLayout, h: np.ndarray, sigma_px: float, noise: float, seed: int = 0) -> np.ndarray:
    """The chart seen through h, blurred by a Gaussian of sigma_px pixels in linear light,
    Gaussian noise of std ``noise`` added, sRGB-encoded: (3, ROWS, COLS)."""
    lin = render_view(layout, h, (0, 0, ROWS, COLS), levels=(np.full(3, 0.05), np.full(3, 0.8)))
    if sigma_px > 0:
        lin = np.stack([gaussian_filter(c, sigma_px, mode="nearest") for c in lin])
    lin = lin + np.random.default_rng(seed).normal(0.0, noise, lin.shape)
    return _srgb(lin)


# ----------------------------------------------------------------------------- layout


def test_layout_covers_five_zones_both_azimuths_and_round_trips():
    layout = design_chart((900.0, 600.0), 1000.0, {"lens": "x"})
    assert layout.width_mm == 1000.0 and layout.height_mm == pytest.approx(1000.0 * 600 / 900)
    fields = sorted({round(e.field, 6) for e in layout.edges})
    assert fields == pytest.approx(list(ZONES))
    # all four diagonals beyond the centre (a sensor tilt defocuses one side, sharpens the other)
    a = round(math.degrees(math.atan2(600, 900)))
    assert {round(e.azimuth_deg) for e in layout.edges if e.field > 0} == {a, 180 - a, 180 + a, 360 - a}
    assert len(layout.edges) == 17
    assert all(abs(e.angle_deg - 5.0) < 1e-12 for e in layout.edges)
    assert len(layout.markers) == 8 and len(layout.checkers) >= 5
    back = chart_from_dict(chart_to_dict(layout))
    assert back == layout


def test_layout_refuses_a_print_narrower_than_the_frame():
    with pytest.raises(InputError, match="print_width_mm: the frame spans 900 x 600 mm"):
        design_chart((900.0, 600.0), 500.0)


def test_sidecar_errors_name_the_key():
    data = chart_to_dict(design_chart((900.0, 600.0), 900.0))
    data["edges"][2]["side_mm"] = -1
    with pytest.raises(InputError, match=r"chart.json: edges\[2\]\.side_mm: expected a positive number"):
        chart_from_dict(data, "chart.json")
    with pytest.raises(InputError, match="lensim_chart"):
        chart_from_dict({"edges": []}, "chart.json")


# ----------------------------------------------------------------------------- detection and pose


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.08, -0.05), (-0.06, 0.09)])
def test_detection_recovers_the_homography_under_perspective_blur_and_noise(tilt):
    # tolerance stated: every square and patch centre within 0.3 px of where the true
    # homography puts it (marker corners are found to about 0.5 px RMS; 32 of them)
    layout = _layout()
    h = _frontal(layout, tilt=tilt)
    photo = _photo(layout, h, sigma_px=1.0, noise=0.01)
    det = detect_chart(photo, layout)
    assert det.marker_ids == tuple(range(8))
    pts = np.array([e.centre_mm for e in layout.edges] + [c.centre_mm for c in layout.checkers])
    err = np.linalg.norm(project(det.homography, pts) - project(h, pts), axis=1)
    assert err.max() < 0.3, err.max()
    assert det.reprojection_rms_px < 1.0


def test_pose_recovers_distance_and_tilt():
    # a pinhole camera at the lens's entrance pupil, the chart 1.2 m away turned 10 deg
    # about the vertical axis and 3 deg about the optical axis: the distance within 1 %,
    # the tilt within 0.5 deg
    from lensim.calibrate.chart_detect import _paraxial_scale
    from lensim.optics.lens_file import load_lens
    from lensim.render.mapping import map_to_sensor
    from lensim.sensor.profile import load_sensor

    lens, sensor = load_lens(LENS), load_sensor(SENSOR)
    pitch = map_to_sensor(ROWS, COLS, sensor).pitch_um
    distance_m = 1.2
    mag, ep_z, img_z = _paraxial_scale(lens, distance_m)
    u = distance_m * 1e3 - (img_z - ep_z)
    f = mag * u / (pitch * 1e-3)
    layout = design_chart((sensor.sensor_size_mm[0] / mag, sensor.sensor_size_mm[1] / mag), 2000.0)
    a, b = math.radians(10.0), math.radians(3.0)
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rz = np.array([[math.cos(b), -math.sin(b), 0], [math.sin(b), math.cos(b), 0], [0, 0, 1]])
    r = rz @ ry
    k = np.array([[f, 0, (COLS - 1) / 2], [0, f, (ROWS - 1) / 2], [0, 0, 1.0]])
    h = k @ np.c_[r[:, 0], r[:, 1], [0.0, 0.0, u]]
    h = h / h[2, 2]
    photo = _photo(layout, h, sigma_px=0.8, noise=0.005)
    pose = estimate_pose(detect_chart(photo, layout), lens, pitch)
    assert pose.distance_m == pytest.approx(distance_m, rel=0.01)
    assert pose.tilt_deg == pytest.approx(10.0, abs=0.5)
    assert pose.roll_deg == pytest.approx(3.0, abs=0.5)


def test_photo_without_a_chart_is_refused_in_one_line():
    rng = np.random.default_rng(1)
    photo = np.clip(gaussian_filter(rng.random((3, 240, 320)), (0, 3, 3)), 0, 1)
    with pytest.raises(InputError, match=r"^shot.png: chart: no chart markers found; expected a photo of the chart"):
        detect_chart(photo, _layout(), "shot.png")


def test_chart_too_small_in_the_frame_is_refused_in_one_line():
    layout = _layout()
    photo = _photo(layout, _frontal(layout, fill=0.42), sigma_px=0.7, noise=0.003)
    det = detect_chart(photo, layout, "far.png")  # the markers are still found
    with pytest.raises(InputError, match=r"^far.png: chart: too small in the frame: the chart spans 4\d %"):
        check_coverage(layout, det, "far.png")


# ----------------------------------------------------------------------------- MTF area


def test_mtf_area_of_a_gaussian_blur_matches_the_analytic_mtf():
    # MTF area (0 .. Nyquist) per zone of a chart blurred by a Gaussian of sigma px, noise
    # free: the analytic exp(-2 pi^2 sigma^2 f^2) times the pixel aperture along a 5 deg
    # edge. The ISO Hamming window on these 38 px wide regions leaves the measured area up
    # to 2.5 % high at sigma = 1.2 px (1.5 % at 0.8; the bias shrinks with larger regions).
    layout = _layout()
    f = np.linspace(0.0, 0.5, 2001)
    for sigma in (0.8, 1.2):
        photo = _photo(layout, _frontal(layout), sigma_px=sigma, noise=0.0)
        m = measure_chart(photo, layout, _frontal(layout))
        truth = mtf_area(f, np.exp(-2 * math.pi**2 * sigma**2 * f**2) * pixel_aperture_mtf(f, 5.0))
        assert [z.zone for z in m.zones] == list(ZONES)
        for z in m.zones:
            assert z.edges >= 4
            assert z.mtf_area / truth == pytest.approx(1.0, abs=0.03), (sigma, z.zone, z.mtf_area / truth)
            # a Gaussian's MTF50: sqrt(ln 2 / 2) / (pi sigma) (the pixel lowers it further)
            assert z.mtf50_cy_px < math.sqrt(math.log(2) / 2) / (math.pi * sigma) * 1.02


# ----------------------------------------------------------------------------- comparison


@pytest.fixture(scope="module")
def camera(tmp_path_factory):
    """The phone camera at 1 m: its bank (cached in a folder the CLI test reuses), the
    chart for it, and a photo of the chart simulated by lensim itself (perspective, noise,
    relative illumination, AHD, the lens's distortion), written as a 16-bit PNG and as the CFA DNG of its raw
    mosaic, with the chart's sidecar."""
    from lensim.images import write_image
    from lensim.io import atomic_write_json
    from lensim.optics.lens_file import load_lens
    from lensim.optics.paraxial import paraxial_data
    from lensim.optics.shooting import ShootingSettings, lens_at
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.render.mapping import map_to_sensor
    from lensim.render.pipeline import simulate
    from lensim.sensor.profile import load_sensor

    folder = tmp_path_factory.mktemp("chart-camera")
    sensor = load_sensor(SENSOR)
    lens = lens_at(load_lens(LENS), ShootingSettings(object_m=DISTANCE_M, focus_m=DISTANCE_M))
    mag = abs(paraxial_data(lens).magnification)
    layout = design_chart((sensor.sensor_size_mm[0] / mag, sensor.sensor_size_mm[1] / mag), 1200.0)
    mapping = map_to_sensor(ROWS, COLS, sensor)
    settings = BankSettings(
        fields=5, wavelengths_nm=(450.0, 550.0, 650.0), pupil_samples=64, cache_dir=folder / "cache"
    )
    bank = get_bank(lens, mapping.pitch_um, settings, response=sensor.spectral_response)
    h = _frontal(layout)  # chart -> undistorted pixels; the lens's distortion (2 %, 12 px at the corners) on top
    warp = PixelDistortion.from_bank(bank, mapping)
    lin = render_view(layout, h, (0, 0, ROWS, COLS), levels=(np.full(3, 0.04), np.full(3, 0.8)), warp=warp)
    photo, _ = simulate(torch.from_numpy(_srgb(lin)).float(), bank, sensor, torch.Generator().manual_seed(3),
                        mapping=mapping, bits=16, kelvin=5000.0, raw_path=folder / "photo.dng")  # fmt: skip
    write_image(folder / "photo.png", photo, 16)
    atomic_write_json(folder / "chart.json", chart_to_dict(layout))
    return {"folder": folder, "layout": layout, "bank": bank, "sensor": sensor, "mapping": mapping,
            "photo": photo.double().numpy(), "h": h}  # fmt: skip


def test_compare_on_a_photo_lensim_simulated_gives_ratios_near_one(camera):
    # measured (this size, seed 5): ratios 0.998 1.000 0.997 1.002 0.995, PSNR 29-33 dB
    # (0.998 0.989 0.978 1.012 0.991 before the simulation took the ink's level, the lens's
    # fall of illumination across each crop and the frame's kernel grid)
    photo, layout = camera["photo"], camera["layout"]
    det = detect_chart(photo, layout)
    check_coverage(layout, det)
    # the undistorted marker corners give back the chart's homography
    warp = PixelDistortion.from_bank(camera["bank"], camera["mapping"])
    pts = np.array([e.centre_mm for e in layout.edges] + [c.centre_mm for c in layout.checkers])
    err = np.linalg.norm(project(ideal_homography(det, warp), pts) - project(camera["h"], pts), axis=1)
    assert err.max() < 0.3, err.max()
    cmp = compare_chart(photo, layout, det, camera["bank"], camera["sensor"], camera["mapping"], seed=5)
    assert [z.zone for z in cmp.zones] == list(ZONES)
    for z in cmp.zones:
        assert 0.96 <= z.mtf_area_ratio <= 1.04, (z.zone, z.mtf_area_ratio)
        assert z.psnr_db > 21.0 or z.checkers == 0
        assert abs(z.sim_lateral_colour_px[0] - z.photo_lateral_colour_px[0]) < 0.1
    assert cmp.noise is not None and cmp.noise[0] > 0  # matched to the photo's noise
    # without the lens's distortion (2 %: 12 px at the corners) the checkers land off the
    # photo's: measured 4-10 dB lower PSNR in every zone (35/28/32/23/27 dB against 27/22/22/19/22)
    flat = compare_chart(photo, layout, det, camera["bank"], camera["sensor"], camera["mapping"], seed=5,
                         distortion=False)  # fmt: skip
    for z, f in zip(cmp.zones, flat.zones, strict=True):
        assert z.psnr_db > f.psnr_db + 2.0, (z.zone, z.psnr_db, f.psnr_db)


def test_simulation_of_a_lensim_photo_gives_its_edges_back(camera):
    # the photo's own lens and no noise: the chart's simulation (crops on the frame's kernel
    # grid, the photo's ink and paper levels, the lens's fall of illumination across each
    # crop) reads the photo's SFRs; measured 0.005 RMS, 0.011 at the worst edge (0.037 and
    # 0.096 with the black from the crop's mean, no fall across a crop, each crop on its own
    # kernel grid)
    from lensim.calibrate.compare import simulate_chart
    from lensim.render.pipeline import simulate

    layout, bank, sensor, mapping = camera["layout"], camera["bank"], camera["sensor"], camera["mapping"]
    warp = PixelDistortion.from_bank(bank, mapping)
    lin = render_view(layout, camera["h"], (0, 0, ROWS, COLS), levels=(np.full(3, 0.04), np.full(3, 0.8)), warp=warp)
    photo, _ = simulate(torch.from_numpy(_srgb(lin)).float(), bank, sensor, torch.Generator().manual_seed(3),
                        mapping=mapping, bits=16, kelvin=5000.0, noise=False)  # fmt: skip
    photo = photo.double().numpy()
    det = detect_chart(photo, layout)
    sim, _ = simulate_chart(photo, layout, det, bank, sensor, mapping, noise=False)
    freq = np.linspace(0.04, 0.4, 10)
    a = measure_chart(photo, layout, det.homography, mapping.pitch_um)
    b = measure_chart(sim, layout, det.homography, mapping.pitch_um, regions=[e.region for e in a.edges])
    d = np.array([
        np.interp(freq, p.sfr.freq_cy_px, p.sfr.mtf) - np.interp(freq, s.sfr.freq_cy_px, s.sfr.mtf)
        for p, s in zip(a.edges, b.edges, strict=True) if p.sfr is not None and s.sfr is not None
    ])  # fmt: skip
    assert len(d) >= 60
    assert np.sqrt(np.mean(d**2)) < 0.012, np.sqrt(np.mean(d**2))
    assert np.abs(d.mean(axis=1)).max() < 0.04, np.abs(d.mean(axis=1)).max()


def test_compare_sees_a_camera_blurrier_than_its_simulation(camera):
    # the same photo blurred once more (a Gaussian of 1 px, as a lens worse than its
    # prescription would): the simulation's MTF area exceeds the photo's by > 10 % everywhere
    photo = _srgb(np.stack([gaussian_filter(c, 1.0) for c in linear_rgb(camera["photo"])]))
    layout = camera["layout"]
    det = detect_chart(photo, layout)
    cmp = compare_chart(photo, layout, det, camera["bank"], camera["sensor"], camera["mapping"], seed=5)
    assert len(cmp.zones) == len(ZONES)
    assert all(z.mtf_area_ratio > 1.1 for z in cmp.zones), [z.mtf_area_ratio for z in cmp.zones]


# ----------------------------------------------------------------------------- command line


def test_cli_chart_make_writes_the_page_at_print_size_and_its_sidecar(tmp_path, capsys, monkeypatch):
    from lensim.calibrate.chart import load_chart

    args = ["chart", "make", "--lens", LENS, "--sensor", SENSOR, "--distance-m", "1", "--print-width-mm", "1200"]
    code, out, _ = run_cli([*args, "--dpi", "60", "-o", str(tmp_path / "chart.pdf"), "--json"], capsys, monkeypatch)
    assert code == 0, out
    layout = load_chart(tmp_path / "chart.json")
    assert layout.width_mm == 1200.0 and layout.design["distance_m"] == 1.0
    pdf = (tmp_path / "chart.pdf").read_bytes()
    assert pdf.startswith(b"%PDF")
    points = f"{1200 / 25.4 * 72:.0f}".encode()  # the page is 1200 mm wide: 3402 points
    assert points in pdf
    code, _, _ = run_cli([*args, "--dpi", "60", "-o", str(tmp_path / "chart.png"), "--quiet"], capsys, monkeypatch)
    from PIL import Image

    with Image.open(tmp_path / "chart.png") as im:
        assert im.size[0] == round(1200 / 25.4 * 60) and round(im.info["dpi"][0]) == 60


@pytest.mark.parametrize(
    "args, message",
    [
        (["--print-width-mm", "500"], "--print-width-mm: the frame spans 1086 x 816 mm at this distance"),
        (["--print-width-mm", "-3"], "--print-width-mm: expected a width above 0 mm"),
        (
            ["--print-width-mm", "1200", "-o", "chart.svg"],
            "chart.svg: --output: expected a file name ending in .pdf or .png",
        ),
    ],
)
def test_cli_chart_make_errors_are_one_line(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    base = ["chart", "make", "--lens", LENS, "--sensor", SENSOR, "--distance-m", "1"]
    out = ["-o", "chart.pdf"] if "-o" not in args else []
    code, _, err = run_cli([*base, *args, *out], capsys, monkeypatch)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("name", ["photo.png", "photo.dng"])
def test_cli_chart_compare_on_a_simulated_photo(camera, capsys, monkeypatch, name):
    # the developed photo and its raw file (developed by lensim's own chain, as-shot white
    # balance): ratios within 4 % of 1 at every zone (the DNG case runs by default, below)
    _compare_cli(camera, capsys, monkeypatch, name)


def test_cli_chart_compare_on_a_simulated_raw_photo(camera, capsys, monkeypatch):
    record = _compare_cli(camera, capsys, monkeypatch, "photo.dng")
    assert record["path"] == "raw"


def _compare_cli(camera, capsys, monkeypatch, name: str) -> dict:
    folder = camera["folder"]
    bank_args = [
        "--fields",
        "5",
        "--wavelengths-nm",
        "450,550,650",
        "--pupil-samples",
        "64",
        "--cache",
        str(folder / "cache"),
    ]
    args = ["chart", "compare", str(folder / name), "--chart", str(folder / "chart.json"), "--lens", LENS,
            "--sensor", SENSOR, "--object-m", "1", "--focus-m", "1", *bank_args]  # fmt: skip
    args += ["-o", str(folder / "out"), "--json"]
    code, out, err = run_cli(args, capsys, monkeypatch)
    assert code == 0, err
    import json

    record = json.loads(out)
    assert record["pose"]["distance_m"] == pytest.approx(1.0 / 0.97, rel=0.02)
    assert [z["zone"] for z in record["zones"]] == list(ZONES)
    assert all(0.96 <= z["mtf_area_ratio"] <= 1.04 for z in record["zones"]), [
        z["mtf_area_ratio"] for z in record["zones"]
    ]
    for written in ("photo_chart.json", "photo_chart.png", "photo_sim.png"):
        assert (folder / "out" / written).is_file()
    return record


def _png(path, image: np.ndarray) -> None:
    from lensim.images import write_image

    write_image(path, torch.from_numpy(np.clip(image, 0, 1)).float(), 8)


@pytest.mark.parametrize("case", ["no chart", "too small", "bad raw"])
def test_cli_chart_compare_errors_are_one_line(camera, tmp_path, capsys, monkeypatch, case):
    layout = camera["layout"]
    if case == "no chart":
        photo, message = tmp_path / "wall.png", "wall.png: chart: no chart markers found"
        _png(photo, gaussian_filter(np.random.default_rng(2).random((3, ROWS, COLS)), (0, 2, 2)))
    elif case == "too small":
        photo, message = tmp_path / "far.png", "far.png: chart: too small in the frame"
        s = COLS / layout.frame_mm[0] * 0.42
        h = np.array([[s, 0, (COLS - 1) / 2], [0, s, (ROWS - 1) / 2], [0, 0, 1.0]])
        _png(photo, _srgb(render_view(layout, h, (0, 0, ROWS, COLS), levels=(np.full(3, 0.05), np.full(3, 0.8)))))
    else:
        photo, message = tmp_path / "broken.dng", "broken.dng"
        photo.write_bytes(b"II*\x00" + bytes(range(256)) * 8)
    out = tmp_path / "out"
    args = ["chart", "compare", str(photo), "--chart", str(camera["folder"] / "chart.json"), "--lens", LENS,
            "--sensor", SENSOR, "-o", str(out)]  # fmt: skip
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert not out.exists() or list(out.iterdir()) == []
