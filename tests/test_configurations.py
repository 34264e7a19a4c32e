"""Lens configurations (zoom and focus positions): the data model, apply_configuration, the
native file's configurations block (round trip) and the Zemax multi-configuration import."""

from __future__ import annotations

import copy

import pytest
import yaml

from lensim.assets import lens_path
from lensim.errors import InputError
from lensim.optics.analysis import first_order_summary
from lensim.optics.configurations import apply_configuration, configuration_names
from lensim.optics.lens_file import lens_from_dict, lens_to_dict, load_lens, save_lens

COOKE = yaml.safe_load(lens_path("cooke_triplet").read_text())
# two air gaps of the Cooke triplet moved: the front gap and the back focal distance
CONFIGS = {"near": {"thicknesses": {1: 5.0, 5: 43.5}}, "far": {"thicknesses": {1: 7.0}}}


def cooke(configurations: dict | None = CONFIGS, **thicknesses: float) -> dict:
    """The Cooke triplet's mapping with configurations and surfaces[i].thickness = value
    for keys like s1=5.0."""
    d = copy.deepcopy(COOKE)
    for key, value in thicknesses.items():
        d["surfaces"][int(key[1:])]["thickness"] = value
    if configurations is not None:
        d["configurations"] = copy.deepcopy(configurations)
    return d


def test_configuration_equals_the_lens_written_with_its_thicknesses() -> None:
    lens = lens_from_dict(cooke())
    assert configuration_names(lens) == ["near", "far"]
    cases = {"near": cooke(None, s1=5.0, s5=43.5), "far": cooke(None, s1=7.0)}
    for key, name in (("near", "near"), ("2", "far"), ("FAR", "far"), ("1", "near")):
        got = apply_configuration(lens, key)
        want = lens_from_dict(cases[name])
        assert [s.thickness for s in got.surfaces] == [s.thickness for s in want.surfaces]
        assert got.configurations == {}
        assert first_order_summary(got)["efl_mm"] == first_order_summary(want)["efl_mm"]
    # the lens itself is unchanged and the two positions differ
    assert [s.thickness for s in lens.surfaces] == [s["thickness"] for s in COOKE["surfaces"]]
    efl = {k: first_order_summary(apply_configuration(lens, k))["efl_mm"] for k in ("near", "far")}
    assert abs(efl["near"] - efl["far"]) > 0.1


def test_unknown_key_lists_the_configurations() -> None:
    lens = lens_from_dict(cooke(), source="c.yaml")
    for key in ("3", "0", "mid", ""):
        with pytest.raises(InputError) as e:
            apply_configuration(lens, key)
        assert str(e.value) == (
            f"c.yaml: configuration: unknown configuration {key!r}; expected a name or a number 1..2: 1 (near), 2 (far)"
        )
    plain = lens_from_dict(cooke(None), source="p.yaml")
    with pytest.raises(InputError, match="p.yaml: configuration: the lens declares no configurations"):
        apply_configuration(plain, "1")


def test_numbered_names_must_be_their_position() -> None:
    lens_from_dict(cooke({"1": {"thicknesses": {1: 5.0}}, "2": {"thicknesses": {}}}))
    with pytest.raises(
        InputError,
        match=r"configurations\.2: a configuration named by a number must be that number in the list \(it is number 1\)",
    ):
        lens_from_dict(cooke({"2": {"thicknesses": {1: 5.0}}, "1": {"thicknesses": {}}}))


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_round_trip(tmp_path, suffix) -> None:
    lens = lens_from_dict(cooke())
    path = tmp_path / f"zoom{suffix}"
    save_lens(lens, path)
    again = load_lens(path)
    assert again.configurations == lens.configurations == {"near": {1: 5.0, 5: 43.5}, "far": {1: 7.0}}
    assert list(again.configurations) == ["near", "far"]
    assert lens_to_dict(again) == lens_to_dict(lens)


# ---------------------------------------------------------------- Zemax multi-configuration

ZOOM = "nikon_80-200_zoom.zmx"  # tests/data/lenses/README.md: three zoom positions in the MCE
ZOOM_GAPS = {
    "1": {4: 1.86, 9: 36.928, 12: 16.55},
    "2": {4: 25.27, 9: 26.8207, 12: 3.2473},
    "3": {4: 48.678, 9: 1.536, 12: 5.133},
}


def test_zemax_thic_operands_are_read_into_configurations(reference_lenses) -> None:
    lens = load_lens(reference_lenses / ZOOM, warn=False, model_glasses=True)
    assert lens.configurations == ZOOM_GAPS
    assert lens.notes == []  # configurations are read, not a caveat (model glasses: no catalogue twins either)
    # the lens data as saved are configuration 1 (MNUM 3 1)
    assert [s.thickness for s in apply_configuration(lens, "1").surfaces] == [s.thickness for s in lens.surfaces]
    # and they survive a native round trip
    assert lens_from_dict(lens_to_dict(lens)).configurations == ZOOM_GAPS


def test_each_zoom_position_has_optilands_efl(reference_lenses) -> None:
    # optiland reads the same .zmx (configuration 1) and gets each position's thicknesses
    # set surface by surface; EFL agrees to 1e-9 (measured: identical)
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file

    from lensim.optics.paraxial import paraxial_data

    lens = load_lens(reference_lenses / ZOOM, warn=False, model_glasses=True)  # optiland's glasses: the models
    op = load_zemax_file(str(reference_lenses / ZOOM))
    efl = {}
    for name, thicknesses in lens.configurations.items():
        for index, t in thicknesses.items():
            op.updater.set_thickness(t, index + 1)  # optiland's surface 0 is the object
        efl[name] = paraxial_data(apply_configuration(lens, name)).efl_mm
        assert efl[name] == pytest.approx(float(op.paraxial.f2()), rel=1e-9)
    # the published zoom: ratio 2.5, the image plane fixed (paraxial BFL within 0.02 mm)
    assert efl["3"] / efl["1"] == pytest.approx(2.5, abs=0.01)
    assert efl["1"] < efl["2"] < efl["3"]
    bfl = [paraxial_data(apply_configuration(lens, k)).bfl_mm for k in lens.configurations]
    assert max(bfl) - min(bfl) < 0.02


def _zmx_with(text: str, tmp_path, extra: str):
    path = tmp_path / "zoom.zmx"
    path.write_text(text.replace("MNUM 3 1\r\n", extra), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    "extra, match",
    [
        ('THIC 5 1 2.0 0 0 0 1 1 1 0 0 "" 0\r\n', r"line \d+ \(THIC\): a multi-configuration operand before MNUM"),
        ('MNUM 3 1\r\nTHIC 5 4 2.0 0 0 0 1 1 1 0 0 "" 0\r\n', r"expected a configuration number 1..3 \(MNUM\), got 4"),
        ("MNUM 3 1\r\nTHIC 5 1 x\r\n", "expected a number, got 'x'"),
        ("MNUM 0 1\r\n", "expected a number of configurations >= 1"),
        ("MNUM 3 5\r\n", "the active one 1..n, got 3 5"),
        ("MNUM 3 1\r\nTHIC 8 1 2.0\r\n", "surface 8 has no value for configuration 2 of 3"),
        ("MNUM 3 1\r\nTHIC 8 1 -6\r\nTHIC 8 2 5\r\nTHIC 8 3 5\r\n", r"configurations.1: surfaces\[7\].thickness"),
    ],
)
def test_bad_multi_configuration_operands_are_named(reference_lenses, tmp_path, extra: str, match: str) -> None:
    text = (reference_lenses / ZOOM).read_text(encoding="utf-8")
    text = text[: text.index("MNUM")] + "MNUM 3 1\r\n"  # the file without its THIC operands
    with pytest.raises(InputError, match=match):
        load_lens(_zmx_with(text, tmp_path, extra), warn=False)


def test_operands_lensim_does_not_apply_are_noted(reference_lenses, tmp_path) -> None:
    text = (reference_lenses / ZOOM).read_text(encoding="utf-8")
    text = text.replace(
        "MNUM 3 1\n",
        'MNUM 3 1\r\nAPER 0 1 2.8 0 0 0 1 1 1 0 0 "" 0\r\nTHIC 0 1 5000 0\r\nTHIC 0 2 5000 0\r\nTHIC 0 3 5000 0\r\n',
    )
    path = tmp_path / "zoom.zmx"
    path.write_text(text, encoding="utf-8")
    lens = load_lens(path, warn=False)
    assert lens.configurations == ZOOM_GAPS and lens.infinite_object
    assert any("APER not applied" in n for n in lens.notes)
    assert any("THIC 0 (the object distance per configuration) is not applied" in n for n in lens.notes)
