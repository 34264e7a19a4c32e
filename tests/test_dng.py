"""DNG writing (lensim.raw.dng): LibRaw (rawpy) reads back what was written; pidng, an
independent DNG writer, gives LibRaw the same file contents; the colour matrix is the
exact inverse of the CCM derivation and matches the camera's published Adobe matrix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.raw.dng import (
    DngCamera,
    DngColour,
    DngExif,
    profile_colour,
    read_simulation_record,
    write_capture_dng,
    write_cfa_dng,
    write_linear_dng,
    write_srgb_as_linear_dng,
)
from lensim.sensor import isp
from lensim.sensor.calibration import ccm_from_dng_color_matrix, dng_color_matrix_from_ccm
from lensim.sensor.profile import load_sensor

rawpy = pytest.importorskip("rawpy")

# Sony ILCE-7 Adobe DNG ColorMatrix (D65), dcraw's adobe_coeff / 10000: the source of the
# built-in profiles' CCM (lensim/assets/sensors/fullframe_dslr.yaml)
ILCE7_XYZ_TO_CAM = (
    np.array([5271, -712, -347, -6153, 13653, 2763, -1601, 2366, 7242], dtype=np.float64).reshape(3, 3) / 1e4
)
LIBRAW_FLIP = {1: 0, 3: 3, 6: 6, 8: 5}  # TIFF orientation -> LibRaw's sizes.flip
CAMERA = DngCamera("Lensim", "Test Camera")


def _pattern_from_libraw(raw) -> str:
    desc = raw.color_desc.decode()
    return "".join(desc[c] for c in raw.raw_pattern.ravel())


def _mosaic(h: int, w: int, white: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, white + 1, (h, w)).astype(np.uint16)


def test_color_matrix_inverts_the_ccm_derivation_and_matches_adobe():
    prof = load_sensor("fullframe_dslr")
    r65, b65 = prof.wb_gains(6504.0)
    cm = dng_color_matrix_from_ccm(prof.ccm, r65, b65)
    ccm, r, b = ccm_from_dng_color_matrix(cm)
    np.testing.assert_allclose(ccm, np.array(prof.ccm), atol=1e-12)
    assert (r, b) == pytest.approx((r65, b65), rel=1e-12)
    # the published matrix up to its overall scale (the profile stores 6-decimal CCMs, 4-decimal gains)
    ratio = ILCE7_XYZ_TO_CAM / cm
    np.testing.assert_allclose(ratio, np.median(ratio), rtol=2e-3)
    # DNG convention: the D65 white (Y = 1) maps to a camera neutral whose green is 1
    d65 = np.array([0.95047, 1.0, 1.08883])
    np.testing.assert_allclose(cm @ d65, [1 / r65, 1.0, 1 / b65], rtol=1e-4)


@pytest.mark.parametrize(
    "pattern,bits,orientation", [("RGGB", 12, 1), ("BGGR", 14, 3), ("GRBG", 16, 6), ("GBRG", 14, 8)]
)
def test_cfa_dng_reads_back_in_libraw(tmp_path: Path, pattern: str, bits: int, orientation: int):
    white = 2**bits - 1
    black = [64 * (bits - 10) + k for k in range(4)]  # a different level per CFA position
    mosaic = _mosaic(24, 36, white)
    colour = DngColour.from_gains(ILCE7_XYZ_TO_CAM, 2.1, 1.6)
    exif = DngExif(exposure_s=1 / 250, fno=4.0, iso=800, focal_length_mm=35.0, focus_distance_m=3.5, lens="Cooke 50mm")
    path = write_cfa_dng(tmp_path / "a.dng", mosaic, pattern, black, white, colour, CAMERA, orientation, exif)
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_type == rawpy.RawType.Flat
        np.testing.assert_array_equal(raw.raw_image_visible, mosaic)
        assert _pattern_from_libraw(raw) == pattern
        assert raw.white_level == white
        # LibRaw lists black per colour index (R, G, B, G2); map back to CFA positions
        per_colour = raw.black_level_per_channel
        assert [per_colour[c] for c in raw.raw_pattern.ravel()] == black
        ccm = ccm_from_dng_color_matrix(ILCE7_XYZ_TO_CAM)[0]
        np.testing.assert_allclose(raw.color_matrix[:, :3], ccm, atol=1e-5)  # LibRaw's own derivation
        np.testing.assert_allclose(raw.camera_whitebalance[:3], [2.1, 1.0, 1.6], rtol=1e-6)
        assert raw.sizes.flip == LIBRAW_FLIP[orientation]
        assert (raw.sizes.width, raw.sizes.height) == (36, 24)
        other = raw.other
        assert other.shutter_speed == pytest.approx(1 / 250, rel=1e-6)
        assert (other.aperture, other.iso_speed, other.focal_length) == pytest.approx((4.0, 800, 35.0), rel=1e-6)
        assert raw.lens.model == "Cooke 50mm"
    import tifffile

    with tifffile.TiffFile(path) as tf:
        tags = tf.pages[0].tags
        assert (tags["Make"].value, tags["Model"].value) == ("Lensim", "Test Camera")
        assert tags["UniqueCameraModel"].value == "Lensim Test Camera"
        assert tuple(tags["DNGVersion"].value) == (1, 4, 0, 0)
        num, den = tags["ExifTag"].value["SubjectDistance"]
        assert num / den == pytest.approx(3.5)


def test_pidng_writes_what_libraw_reads_the_same(tmp_path: Path):
    """The same mosaic and metadata written by pidng (an independent writer) and by
    lensim give LibRaw identical data, pattern, levels, matrix and white balance."""
    from pidng.core import RAW2DNG
    from pidng.dng import DNGTags, Tag

    mosaic = _mosaic(32, 48, 16383, seed=1)
    cm, neutral = ILCE7_XYZ_TO_CAM, (1 / 2.4, 1.0, 1 / 1.3)
    ours = write_cfa_dng(tmp_path / "ours.dng", mosaic, "GBRG", 512, 16383, DngColour.from_gains(cm, 2.4, 1.3), CAMERA)

    def rational(v: float) -> list[int]:
        return [round(v * 10000), 10000]

    t = DNGTags()
    for tag, value in [
        (Tag.ImageWidth, 48),
        (Tag.ImageLength, 32),
        (Tag.TileWidth, 48),
        (Tag.TileLength, 32),
        (Tag.BitsPerSample, 16),
        (Tag.SamplesPerPixel, 1),
        (Tag.PhotometricInterpretation, 32803),
        (Tag.CFARepeatPatternDim, [2, 2]),
        (Tag.CFAPattern, [1, 2, 0, 1]),
        (Tag.BlackLevel, 512),
        (Tag.WhiteLevel, 16383),
        (Tag.ColorMatrix1, [rational(v) for v in cm.ravel()]),
        (Tag.CalibrationIlluminant1, 21),
        (Tag.AsShotNeutral, [rational(v) for v in neutral]),
        (Tag.Make, "Lensim"),
        (Tag.Model, "Test Camera"),
        (Tag.Orientation, 1),
        (Tag.DNGVersion, [1, 4, 0, 0]),
    ]:
        t.set(tag, value)
    writer = RAW2DNG()
    writer.options(t, path=str(tmp_path), compress=False)
    peer = writer.convert(mosaic, filename="peer")
    with rawpy.imread(str(ours)) as a, rawpy.imread(peer) as b:
        np.testing.assert_array_equal(a.raw_image_visible, b.raw_image_visible)
        np.testing.assert_array_equal(a.raw_pattern, b.raw_pattern)
        assert a.black_level_per_channel == b.black_level_per_channel and a.white_level == b.white_level
        np.testing.assert_allclose(a.color_matrix, b.color_matrix, atol=2e-4)
        np.testing.assert_allclose(a.camera_whitebalance, b.camera_whitebalance, rtol=1e-3)


def test_linear_dng_reads_back_in_libraw(tmp_path: Path):
    rng = np.random.default_rng(2)
    cam = rng.uniform(-0.05, 1.05, (3, 24, 30)).astype(np.float32)
    colour = DngColour.from_gains(ILCE7_XYZ_TO_CAM, 2.0, 1.5, 21).with_second_matrix(ILCE7_XYZ_TO_CAM * 1.1, 17)
    path = write_linear_dng(
        tmp_path / "lin.dng", torch.from_numpy(cam), colour, CAMERA, orientation=6, exif=DngExif(iso=100), block_rows=7
    )
    expected = np.rint(np.clip(cam, 0, 1) * 65535).astype(np.uint16).transpose(1, 2, 0)
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_type == rawpy.RawType.Stack
        np.testing.assert_array_equal(raw.raw_image[..., :3], expected)
        np.testing.assert_allclose(raw.color_matrix[:, :3], ccm_from_dng_color_matrix(ILCE7_XYZ_TO_CAM)[0], atol=1e-5)
        np.testing.assert_allclose(raw.camera_whitebalance[:3], [2.0, 1.0, 1.5], rtol=1e-6)
        assert raw.sizes.flip == 6 and raw.other.iso_speed == 100
    import tifffile

    with tifffile.TiffFile(path) as tf:
        tags = tf.pages.first.tags
        assert (tags["CalibrationIlluminant1"].value, tags["CalibrationIlluminant2"].value) == (21, 17)
        m2 = np.array(tags["ColorMatrix2"].value, dtype=np.float64).reshape(9, 2)
        np.testing.assert_allclose(m2[:, 0] / m2[:, 1], (ILCE7_XYZ_TO_CAM * 1.1).ravel(), atol=1e-6)


def test_developed_photo_round_trips_through_linear_dng(tmp_path: Path):
    """sRGB developed by lensim's chain -> LinearRaw camera RGB -> developed again by the
    same chain (process) gives the photo back to the 16-bit grid."""
    prof = load_sensor("apsc_mirrorless")
    srgb = torch.rand(3, 24, 32, generator=torch.Generator().manual_seed(3)) * 0.6 + 0.2
    colour = profile_colour(prof, 2.2, 1.4)
    path = write_srgb_as_linear_dng(tmp_path / "r.dng", srgb, prof.ccm, colour, CAMERA, block_rows=5)
    with rawpy.imread(str(path)) as raw:
        cam = torch.from_numpy(raw.raw_image[..., :3].astype(np.float32).transpose(2, 0, 1) / 65535.0)
    params = isp.CaptureParams(kelvin=0.0, r_gain=2.2, b_gain=1.4, ccm=[list(r) for r in prof.ccm])
    back = isp.process(cam, params, bits=None)
    assert float((back - srgb).abs().max()) < 2e-3


def test_capture_dng_holds_the_simulated_adc_output(tmp_path: Path):
    prof = load_sensor("apsc_mirrorless")
    g = torch.Generator().manual_seed(4)
    cam, params = isp.unprocess(torch.rand(3, 24, 32, generator=g), prof, g)
    raw = isp.quantize_raw(isp.add_noise(isp.mosaic(cam, prof.bayer_pattern), 1e-3, 2e-3, g), prof)
    path = write_capture_dng(tmp_path / "c.dng", raw, prof, params)
    record = read_simulation_record(path)
    assert record is not None and record["sensor"] == prof.name and record["capture"]["r_gain"] == params.r_gain
    assert (record["x0_mm"], record["pitch_um"]) == (-prof.sensor_size_mm[0] / 2, prof.pixel_pitch_um)
    assert (
        read_simulation_record(
            write_cfa_dng(
                tmp_path / "other.dng",
                _mosaic(24, 24, 4095),
                "RGGB",
                0,
                4095,
                DngColour.from_gains(np.eye(3), 1, 1),
                CAMERA,
            )
        )
        is None
    )
    with rawpy.imread(str(path)) as r:
        back = (r.raw_image_visible.astype(np.float64) - prof.black_level) / (prof.white_level - prof.black_level)
        np.testing.assert_allclose(back, raw.numpy(), atol=1e-6)
        assert _pattern_from_libraw(r) == prof.bayer_pattern
        np.testing.assert_allclose(r.color_matrix[:, :3], np.array(prof.ccm), atol=1e-5)
        np.testing.assert_allclose(r.camera_whitebalance[:3], [params.r_gain, 1.0, params.b_gain], rtol=1e-5)


@pytest.mark.parametrize(
    "kwargs,field",
    [
        ({"cfa_pattern": "RGBX"}, "cfa_pattern"),
        ({"orientation": 9}, "orientation"),
        ({"white_level": 1000}, "mosaic"),
        ({"black_level": [1, 2, 3]}, "black_level"),
        ({"mosaic": np.zeros((20, 40), np.uint16)}, "mosaic"),
    ],
)
def test_bad_arguments_write_nothing(tmp_path: Path, kwargs: dict, field: str):
    args = {
        "mosaic": _mosaic(24, 24, 4095),
        "cfa_pattern": "RGGB",
        "black_level": 0,
        "white_level": 4095,
        "orientation": 1,
        **kwargs,
    }
    with pytest.raises(InputError) as err:
        write_cfa_dng(tmp_path / "bad.dng", colour=DngColour.from_gains(np.eye(3), 1, 1), camera=CAMERA, **args)
    assert err.value.field == field
    assert list(tmp_path.iterdir()) == []


def test_simulate_writes_the_mosaic_it_develops(tmp_path: Path):
    """simulate(raw_path=...) writes the mosaic its own develop chain ran on: LibRaw's
    digital numbers, normalized, developed by raw_to_srgb give simulate's output."""
    from lensim.render.mapping import native_mapping
    from lensim.render.pipeline import simulate

    prof = load_sensor("apsc_mirrorless")
    photo = torch.rand(3, 32, 48, generator=torch.Generator().manual_seed(5))
    mapping = native_mapping(32, 48, prof, 1000, 2000)
    out, params = simulate(
        photo,
        None,
        prof,
        torch.Generator().manual_seed(6),
        blur=False,
        bits=None,
        mapping=mapping,
        raw_path=tmp_path / "s.dng",
    )
    with rawpy.imread(str(tmp_path / "s.dng")) as r:
        dn = torch.from_numpy(r.raw_image_visible.astype(np.float32))
    raw = (dn - prof.black_level) / (prof.white_level - prof.black_level)
    assert float((isp.raw_to_srgb(raw, params, bits=None) - out).abs().max()) < 1e-6
    record = read_simulation_record(tmp_path / "s.dng")
    assert record is not None
    assert (record["pitch_um"], record["x0_mm"], record["y0_mm"]) == (mapping.pitch_um, mapping.x0_mm, mapping.y0_mm)


def test_simulate_command_writes_a_dng(tmp_path: Path, capsys, monkeypatch):
    from cli_runner import run_cli
    from lensim.images import write_image

    write_image(tmp_path / "photo.png", torch.rand(3, 24, 36, generator=torch.Generator().manual_seed(7)))
    code, _, err = run_cli(
        ["simulate", str(tmp_path / "photo.png"), "-o", str(tmp_path / "out"), "--no-blur", "--raw", "--quiet"],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    with rawpy.imread(str(tmp_path / "out" / "photo.dng")) as r:
        assert r.raw_image_visible.shape == (24, 36) and _pattern_from_libraw(r) == "RGGB"
    assert not list((tmp_path / "out").glob("*_raw*"))
