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
        assert str(e.value) == (f"c.yaml: configuration: unknown configuration {key!r}; expected a name or a number "
                                "1..2: 1 (near), 2 (far)")
    plain = lens_from_dict(cooke(None), source="p.yaml")
    with pytest.raises(InputError, match="p.yaml: configuration: the lens declares no configurations"):
        apply_configuration(plain, "1")


def test_numbered_names_must_be_their_position() -> None:
    lens_from_dict(cooke({"1": {"thicknesses": {1: 5.0}}, "2": {"thicknesses": {}}}))
    with pytest.raises(InputError, match=r"configurations\.2: a configuration named by a number must be that number in the list \(it is number 1\)"):
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
