"""Vocabularies with one home: the Bayer pattern (lensim.sensor.cfa.CfaPattern), checked
where a user's value enters, with one line naming the file or field."""

from __future__ import annotations

import typing

import numpy as np
import pytest
import torch

from lensim.errors import InputError
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
