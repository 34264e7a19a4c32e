"""Vocabularies with one home: the Bayer pattern (lensim.sensor.cfa.CfaPattern), the PSF
methods (lensim.psf.defaults.PsfMethod) and the EXIF shooting data (lensim.raw.exif.Exif,
the fields RawImage carries and DngExif writes). Each vocabulary is checked where a
user's value enters, with one line naming the file or field."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.raw.dng import DngExif
from lensim.raw.exif import EXIF_FIELDS, Exif
from lensim.raw.read import RawImage
from lensim.sensor import isp
from lensim.sensor.cfa import BAYER_PATTERNS, CfaPattern, cfa_pattern


def test_cfa_vocabulary_is_the_literal():
    assert BAYER_PATTERNS == typing.get_args(CfaPattern) == ("RGGB", "BGGR", "GRBG", "GBRG")
    assert cfa_pattern(" gbrg ") == "GBRG"


@pytest.mark.parametrize("bad", ["RGBG", "RGB", "", None, 4, ["RGGB"]])
def test_cfa_pattern_refused_naming_the_source_and_field(bad):
    with pytest.raises(InputError) as e:
        cfa_pattern(bad, "cam.yaml", "bayer_pattern")
    assert str(e.value) == f"cam.yaml: bayer_pattern: expected one of RGGB, BGGR, GRBG, GBRG, got {bad!r}"


def test_isp_refuses_a_pattern_outside_the_vocabulary():
    with pytest.raises(InputError, match="bayer_pattern: expected one of RGGB, BGGR, GRBG, GBRG, got 'RGBG'"):
        isp.bayer_masks("RGBG", 4, 4)
    assert torch.equal(isp.bayer_masks("rggb", 4, 4), isp.bayer_masks("RGGB", 4, 4))


def test_dng_writer_refuses_a_pattern_outside_the_vocabulary(tmp_path):
    from lensim.raw.dng import DngCamera, DngColour, write_cfa_dng

    colour = DngColour.from_gains(np.eye(3), 2.0, 1.5)
    mosaic = np.zeros((32, 32), dtype=np.uint16)
    with pytest.raises(InputError, match="cfa_pattern: expected one of RGGB, BGGR, GRBG, GBRG, got 'RGBG'"):
        write_cfa_dng(tmp_path / "x.dng", mosaic, "RGBG", 0, 4095, colour, DngCamera("a", "b"))
    assert not (tmp_path / "x.dng").exists()


def test_exif_fields_declared_once():
    names = tuple(f.name for f in dataclasses.fields(Exif))
    assert names == EXIF_FIELDS
    assert DngExif is Exif and issubclass(RawImage, Exif)
    # RawImage declares none of them again, and info() (what DngExif.from_mapping reads
    # when a restored raw is written as a DNG) carries every one
    own = set(RawImage.__annotations__)
    assert not own & set(EXIF_FIELDS)
    raw = RawImage(
        path="x.dng",
        mosaic=np.zeros((4, 4), np.uint16),
        cfa_pattern="RGGB",
        black_level=(0.0, 0.0, 0.0, 0.0),
        white_level=4095.0,
        as_shot_wb_gains=None,
        color_matrix=None,
        exposure_s=0.01,
        fno=2.8,
        iso=400.0,
        focal_length_mm=35.0,
        focus_distance_m=float("inf"),
        lens="Cooke",
    )
    assert DngExif.from_mapping(raw.info()) == Exif(0.01, 2.8, 400.0, 35.0, float("inf"), "Cooke")


def test_psf_method_vocabulary_is_the_literal_and_each_has_one_function():
    from lensim.psf.compute import PSF_FUNCTIONS
    from lensim.psf.defaults import METHODS, PsfMethod

    assert METHODS == typing.get_args(PsfMethod) == ("huygens", "fft", "geometric")
    assert tuple(PSF_FUNCTIONS) == METHODS


def test_psf_method_refused_at_each_boundary():
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings
    from lensim.psf.compute import compute_psf
    from lensim.psf.defaults import psf_method

    assert psf_method("fft") == "fft"
    expected = "method: expected one of huygens, fft, geometric, got 'zemax'"
    lens = load_lens("cooke_triplet")
    with pytest.raises(InputError, match=expected) as e:
        compute_psf(lens, 0.0, 0.55, method="zemax")  # type: ignore[arg-type]
    assert e.value.source == lens.source
    with pytest.raises(InputError, match=expected):
        BankSettings(method="zemax")  # type: ignore[arg-type]
