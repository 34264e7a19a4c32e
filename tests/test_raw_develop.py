"""Developing raw files: the simulator's own chain on a real mosaic.

Truths: (1) a mosaic made by the simulator (unprocess + mosaic + ADC, no noise) and
written as a DNG develops to exactly the simulator's own developed output; (2) a DNG made
from a known sRGB photo develops back to the photo, as closely as LibRaw's own AHD
(rawpy.postprocess) develops the same file; (3) orientation as Pillow's EXIF transpose."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import tifffile
import torch

from cli_runner import run_cli
from lensim.assets.images import read_sample_image
from lensim.raw import apply_orientation, develop_raw, read_raw
from lensim.sensor import isp, load_sensor, sensor_from_dict
from raw_fixtures import random_mosaic, write_dng

SENSOR = "apsc_mirrorless"  # Sony ILCE-7 colour: raw_fixtures.SONY_ILCE7_MATRIX is its DNG matrix


def _photo(name: str = "kodim23", h: int = 64, w: int = 96) -> torch.Tensor:
    img = read_sample_image(name)
    y, x = img.shape[1] // 2 - h // 2, img.shape[2] // 2 - w // 2
    return img[:, y : y + h, x : x + w].contiguous()


def _simulated_dng(
    path: Path, photo: torch.Tensor, pattern: str = "RGGB", kelvin: float = 4500.0, orientation: int = 1
) -> tuple[torch.Tensor, isp.CaptureParams]:
    """The simulator's noiseless capture of ``photo`` (normalized mosaic after the ADC)
    written as a DNG with the profile's levels and the capture's white balance."""
    d = load_sensor(SENSOR).to_dict()
    d["bayer_pattern"] = pattern
    prof = sensor_from_dict(d, "test")
    cam, params = isp.unprocess(photo, prof, kelvin=kelvin)
    mosaic = isp.mosaic(cam, pattern)
    raw, dn = isp.quantize_raw(mosaic, prof), isp.digital_numbers(mosaic, prof).numpy().astype(np.uint16)
    write_dng(
        path,
        dn,
        pattern=pattern,
        black=(prof.black_level,) * 4,
        white=int(prof.white_level),
        wb_gains=(params.r_gain, params.b_gain),
        orientation=orientation,
    )
    return raw, params


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1.0 / ((a - b) ** 2).mean()))


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_develop_equals_the_simulators_own_output(tmp_path, pattern):
    photo = _photo()
    raw, params = _simulated_dng(tmp_path / "sim.dng", photo, pattern)
    want = isp.raw_to_srgb(raw, params, bits=None)
    got, used = develop_raw(read_raw(tmp_path / "sim.dng"), load_sensor(SENSOR), "as-shot", bits=None)
    assert used.bayer_pattern == pattern
    assert (got - want).abs().max().item() <= 1e-6


def test_develop_cli_writes_16_bit_tagged_srgb_equal_to_the_simulator(tmp_path, capsys, monkeypatch):
    from PIL import ImageCms

    (tmp_path / "in").mkdir()
    raw, params = _simulated_dng(tmp_path / "in" / "sim.dng", _photo(), orientation=6)
    code, out, err = run_cli(
        ["develop", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--sensor", SENSOR, "--json"],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert json.loads(out)[0]["skipped"] is False
    with tifffile.TiffFile(tmp_path / "out" / "sim.tif") as tf:
        arr = tf.asarray()
        icc = tf.pages[0].tags["InterColorProfile"].value
    assert arr.dtype == np.uint16 and arr.shape == (96, 64, 3)  # orientation 6: rotated a quarter turn
    assert "sRGB" in ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(bytes(icc))))
    want = apply_orientation(isp.quantize(isp.raw_to_srgb(raw, params, bits=None), 16), 6)
    assert np.abs(arr.astype(np.int64) - isp.to_uint(want, 16).astype(np.int64)).max() <= 1
    # a rerun skips the finished output
    code, out, err = run_cli(
        ["develop", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--sensor", SENSOR, "--json", "--quiet"],
        capsys,
        monkeypatch,
    )
    assert code == 0 and json.loads(out)[0]["skipped"] is True


def test_known_photo_comes_back_as_well_as_with_libraws_ahd(tmp_path):
    """The photo -> simulated DNG (ILCE-7 colour matrix, as-shot WB at 4500 K) -> develop
    without a sensor profile (CCM from the DNG's ColorMatrix1). Measured on kodim23's
    centre 64x96: lensim 38.6 dB PSNR against the photo, LibRaw's AHD 36.4 dB."""
    rawpy = pytest.importorskip("rawpy")
    photo = _photo()
    path = tmp_path / "photo.dng"
    _simulated_dng(path, photo)
    ours, _ = develop_raw(read_raw(path), bits=None)
    with rawpy.imread(str(path)) as rp:
        linear = rp.postprocess(
            demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
            use_camera_wb=True,
            no_auto_bright=True,
            adjust_maximum_thr=0.0,
            output_bps=16,
            gamma=(1, 1),
            output_color=rawpy.ColorSpace.sRGB,
            user_flip=0,
        )
    peer = isp.linear_to_srgb(torch.from_numpy(linear.astype(np.float32) / 65535.0).permute(2, 0, 1))
    ours_db, peer_db = _psnr(ours, photo), _psnr(peer, photo)
    assert ours_db > 37.0 and peer_db > 34.0, (ours_db, peer_db)
    assert ours_db > peer_db - 0.5, (ours_db, peer_db)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_as_pillows_exif_transpose(orientation):
    from PIL import Image, ImageOps

    arr = np.random.default_rng(orientation).integers(0, 256, (5, 7, 3)).astype(np.uint8)
    im = Image.fromarray(arr)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.info["exif"] = exif.tobytes()
    want = np.asarray(ImageOps.exif_transpose(im))
    got = apply_orientation(torch.from_numpy(arr).permute(2, 0, 1), orientation).permute(1, 2, 0).numpy()
    assert np.array_equal(got, want)


def _one_error(code: int, err: str, *words: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    for word in words:
        assert word in lines[0], lines[0]


@pytest.mark.parametrize("bad", ["jpeg", "truncated", "linear", "no_pitch_profile"])
def test_bad_inputs_write_nothing(tmp_path, capsys, monkeypatch, bad):
    """A batch with one bad input: one line, exit 2, no output at all (not even for the
    good file that sorts first)."""
    from PIL import Image

    src = tmp_path / "in"
    src.mkdir()
    write_dng(src / "a_good.dng", random_mosaic(hi=16383))
    bad_path = src / "b_bad.dng"
    args = []
    if bad == "jpeg":
        Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(bad_path, format="JPEG")
    elif bad == "truncated":
        data = (src / "a_good.dng").read_bytes()
        bad_path.write_bytes(data[: len(data) // 2])
    elif bad == "linear":
        write_dng(bad_path, np.stack([random_mosaic(seed=k) for k in range(3)], axis=-1), photometric=34892)
    else:
        d = load_sensor(SENSOR).to_dict()
        del d["pixel_pitch_um"]
        bad_path = tmp_path / "cam.json"
        bad_path.write_text(json.dumps(d))
        args = ["--sensor", str(bad_path)]
    code, _, err = run_cli(["develop", str(src), "-o", str(tmp_path / "out"), *args], capsys, monkeypatch)
    _one_error(code, err, str(bad_path))
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
