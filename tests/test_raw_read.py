"""Reading raw files: DNG fixtures written by pidng (an independent writer) with known
mosaics and tags; lensim.raw.read_raw and `lensim raw info` must report what was written,
and refuse what is not a Bayer raw in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cli_runner import run_cli
from lensim.errors import InputError
from lensim.raw import read_raw
from raw_fixtures import SONY_ILCE7_MATRIX, random_mosaic, write_dng

INFO_KEYS = {
    "make",
    "model",
    "lens",
    "width",
    "height",
    "cfa_pattern",
    "black_level",
    "white_level",
    "as_shot_wb_gains",
    "color_matrix",
    "focal_length_mm",
    "fno",
    "focus_distance_m",
    "iso",
    "exposure_s",
    "orientation",
}

# every Bayer pattern, 12/14/16-bit white levels, orientations 1/3/6/8, per-position black levels
CASES = [
    ("RGGB", 4095, 1, (64, 65, 66, 67)),
    ("BGGR", 16383, 3, (500, 510, 520, 530)),
    ("GRBG", 65535, 6, (2048, 2040, 2056, 2064)),
    ("GBRG", 16383, 8, (0, 1, 2, 3)),
]
EXIF = {
    "exposure_s": 1 / 125,
    "fno": 4.0,
    "iso": 800,
    "focal_length_mm": 35.0,
    "focus_distance_m": 2.5,
    "lens": "Acme 35mm F2",
    "pixel_um": 3.92,
}


@pytest.mark.parametrize("pattern, white, orientation, black", CASES)
def test_read_raw_reports_what_was_written(tmp_path, capsys, monkeypatch, pattern, white, orientation, black):
    mosaic = random_mosaic(hi=white, seed=white + orientation)
    path = write_dng(
        tmp_path / "a.dng",
        mosaic,
        pattern=pattern,
        black=black,
        white=white,
        wb_gains=(2.25, 1.6),
        orientation=orientation,
        make="Acme",
        model="Z 9",
        exif=EXIF,
    )
    raw = read_raw(path)
    assert np.array_equal(raw.mosaic, mosaic) and raw.mosaic.dtype == np.uint16
    code, out, err = run_cli(["raw", "info", str(path), "--json"], capsys, monkeypatch)
    assert code == 0, err
    info = json.loads(out)
    assert set(info) == INFO_KEYS
    want = {
        "make": "Acme",
        "model": "Z 9",
        "lens": "Acme 35mm F2",
        "width": 96,
        "height": 64,
        "cfa_pattern": pattern,
        "black_level": list(black),
        "white_level": white,
        "orientation": orientation,
        "iso": 800,
        "focal_length_mm": 35.0,
        "fno": 4.0,
        "focus_distance_m": 2.5,
    }
    assert {k: info[k] for k in want} == want
    assert info["exposure_s"] == pytest.approx(1 / 125, rel=1e-12)
    assert info["as_shot_wb_gains"] == pytest.approx([2.25, 1.0, 1.6], rel=1e-12)
    assert np.allclose(info["color_matrix"], np.reshape(SONY_ILCE7_MATRIX, (3, 3)), atol=1e-12)
    assert raw.pixel_pitch_um == pytest.approx(3.92, rel=1e-9)


def test_dng_matrix_nearest_d65_is_the_colour_matrix(tmp_path):
    stdA = [0.6, -0.1, -0.05, -0.5, 1.3, 0.2, -0.1, 0.2, 0.8]
    path = write_dng(
        tmp_path / "two.dng",
        random_mosaic(),
        color_matrix=stdA,
        illuminant=17,
        color_matrix2=SONY_ILCE7_MATRIX,
        illuminant2=21,
    )
    raw = read_raw(path)
    assert raw.color_matrix_illuminant == 21
    assert np.allclose(raw.color_matrix, np.reshape(SONY_ILCE7_MATRIX, (3, 3)), atol=1e-12)
    assert [i for i, _ in raw.color_matrices] == [17, 21]
    assert np.allclose(raw.color_matrices[0][1], np.reshape(stdA, (3, 3)), atol=1e-12)


def test_active_area_excludes_margins_and_shifts_the_pattern(tmp_path):
    """DNG: CFAPattern is given at the ActiveArea's top-left corner. Whatever offset LibRaw
    crops to, the mosaic must be that part of the stored frame and the pattern must be
    the written one shifted by the offset from the ActiveArea's corner."""
    full = random_mosaic(64, 96, hi=60000, seed=3)  # distinct values: the crop's position is found by matching
    top, left, bottom, right = 3, 5, 61, 93
    raw = read_raw(
        write_dng(tmp_path / "m.dng", full, pattern="RGGB", white=65535, active_area=[top, left, bottom, right])
    )
    h, w = raw.mosaic.shape
    hits = [
        (y, x)
        for y in range(top, bottom - h + 1)
        for x in range(left, right - w + 1)
        if np.array_equal(full[y : y + h, x : x + w], raw.mosaic)
    ]
    assert len(hits) == 1 and (h, w) != full.shape
    y, x = hits[0]
    rggb = np.array([["R", "G"], ["G", "B"]])
    want = "".join(rggb[(y - top + dy) % 2, (x - left + dx) % 2] for dy in (0, 1) for dx in (0, 1))
    assert raw.cfa_pattern == want


def _one_error(code: int, err: str, path: Path, *words: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert str(path) in lines[0]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize(
    "kind, words", [("linear", ("LinearRaw",)), ("mono", ("monochrome",)), ("xtrans", ("6x6", "X-Trans"))]
)
def test_non_bayer_refused_in_one_line(tmp_path, capsys, monkeypatch, kind, words):
    path = tmp_path / f"{kind}.dng"
    if kind == "linear":
        write_dng(path, np.stack([random_mosaic(seed=k) for k in range(3)], axis=-1), photometric=34892)
    elif kind == "mono":
        write_dng(path, random_mosaic(), photometric=1)
    else:
        xtrans = [
            1,
            1,
            0,
            1,
            1,
            2,
            1,
            1,
            2,
            1,
            1,
            0,
            2,
            0,
            1,
            0,
            2,
            1,
            1,
            1,
            2,
            1,
            1,
            0,
            1,
            1,
            0,
            1,
            1,
            2,
            0,
            2,
            1,
            2,
            0,
            1,
        ]
        write_dng(path, random_mosaic(72, 96), cfa_dims=(6, 6), cfa_codes=xtrans)
    code, _, err = run_cli(["raw", "info", str(path)], capsys, monkeypatch)
    _one_error(code, err, path, *words)
    with pytest.raises(InputError):
        read_raw(path)


def test_bad_files_one_line_each(tmp_path, capsys, monkeypatch):
    from PIL import Image

    jpeg = tmp_path / "photo.dng"
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(jpeg, format="JPEG")
    good = write_dng(tmp_path / "good.dng", random_mosaic())
    truncated = tmp_path / "cut.dng"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    folder = tmp_path / "folder.dng"
    folder.mkdir()
    cases = [
        (jpeg, "JPEG"),
        (truncated, "truncated"),
        (folder, "no raw files"),
        (tmp_path / "none.dng", "no such file"),
    ]
    for path, word in cases:
        code, out, err = run_cli(["raw", "info", str(path), "--json"], capsys, monkeypatch)
        _one_error(code, err, path, word)
        assert out == ""
    with pytest.raises(InputError, match="is a directory"):
        read_raw(folder)
