"""Shooting-settings conditioning (issue 16): the settings vector and its trained ranges,
the range check, settings planes, and FieldAwareUNet with settings_dim."""

from __future__ import annotations

import math

import pytest
import torch

from lensim.errors import InputError, ParameterError
from lensim.restore.conditioning import (
    Conditioning,
    feature,
    given_settings,
    photo_vector,
    record_settings,
    settings_planes,
)
from lensim.restore.fov import fov_channels
from lensim.restore.network import FieldAwareUNet

GRID = [
    {"fno": n, "focus_m": d, "focal_mm": 50.0, "object_m": d, "config": None}
    for n in (2.0, 4.0, 8.0)
    for d in (1.0, math.inf)
]


def test_features_are_stops_dioptres_and_log_focal():
    assert feature("fno", 4.0) == 2.0 and feature("fno", 5.6) == pytest.approx(2.485, abs=1e-3)
    assert feature("focus_m", math.inf) == 0.0 and feature("focus_m", 0.5) == 2.0
    assert feature("focal_mm", 50.0) - feature("focal_mm", 25.0) == pytest.approx(1.0)


def test_ranges_and_inputs_from_records():
    cond = Conditioning.from_records(record_settings(s) for s in GRID)
    assert cond.keys == ("fno", "focus_m") and cond.dim == 2  # focal length is the same in every record
    assert cond.ranges == {"fno": (2.0, 8.0), "focus_m": (1.0, math.inf), "focal_mm": (50.0, 50.0)}
    # ends of the range map to -1 and +1, linearly in the features (stops, dioptres)
    assert cond.vector({"fno": 2.0, "focus_m": 1.0}).tolist() == [-1.0, -1.0]
    assert cond.vector({"fno": 8.0, "focus_m": math.inf}).tolist() == [1.0, 1.0]
    assert cond.vector({"fno": 4.0, "focus_m": 2.0}).tolist() == pytest.approx([0.0, 0.0])
    again = Conditioning.from_dict(cond.to_dict())
    assert again == cond
    assert "f/2 to f/8" in cond.describe() and "1 m to inf" in cond.describe()
    unused = Conditioning.from_records((record_settings(s) for s in GRID), use=False)
    assert unused.dim == 0 and unused.ranges == cond.ranges
    assert Conditioning.from_records([None, None]) == Conditioning()


def test_a_missing_input_names_the_settings():
    cond = Conditioning.from_records(record_settings(s) for s in GRID)
    with pytest.raises(InputError) as e:
        cond.vector({"focal_mm": 50.0}, "photo.png")
    msg = str(e.value)
    assert "photo.png" in msg and "`fno`" in msg and "`focus_m`" in msg and "\n" not in msg
    assert "--" not in msg  # the library names no command-line option


def test_a_photo_vector_takes_the_exif_settings_each_replaced_by_a_given_one():
    """photo_vector: the one home of a photo's settings vector (developed photos and raws)."""
    cond = Conditioning.from_records(record_settings(s) for s in GRID)
    exif = {"fno": 2.0, "focus_m": 1.0, "focal_mm": 50.0}
    assert photo_vector(cond, exif, {}, "a.png").tolist() == [-1.0, -1.0]
    assert photo_vector(cond, exif, given_settings(fno=8.0), "a.png").tolist() == [1.0, -1.0]
    assert photo_vector(cond, {"fno": None, "focus_m": None}, {"fno": 8.0, "focus_m": math.inf}, "a.png").tolist() == [
        1.0,
        1.0,
    ]
    with pytest.raises(ParameterError) as e:  # neither the EXIF nor the caller gives the F-number
        photo_vector(cond, {"fno": None, "focus_m": 1.0}, {}, "a.png")
    assert e.value.source == "a.png" and e.value.parameter == "fno"
    assert "FNumber" in e.value.message and "`fno`" in e.value.message and "SubjectDistance" not in e.value.message
    with pytest.warns(UserWarning, match="f/11"):  # 0.46 stop beyond the trained f/8: warned, restored
        assert photo_vector(cond, {**exif, "fno": 11.0}, {}, "a.png") is not None
    with pytest.raises(ParameterError) as e:  # 1.46 stops beyond: refused
        photo_vector(cond, exif, {"fno": 22.0}, "a.png")
    assert e.value.parameter == "fno"
    unconditioned = Conditioning.from_records((record_settings(s) for s in GRID), use=False)
    assert photo_vector(unconditioned, {}, {}, "a.png") is None  # nothing needed


@pytest.mark.parametrize("bad", [{"fno": 0.0}, {"focus_m": -1.0}, {"focal_mm": math.nan}])
def test_given_settings_are_checked_naming_the_setting(bad):
    assert given_settings(fno=4, focus_m=math.inf) == {"fno": 4.0, "focus_m": math.inf}
    with pytest.raises(ParameterError) as e:
        given_settings(**bad)
    assert e.value.parameter == next(iter(bad)) and "--" not in str(e.value)


def test_range_check_tolerates_rounding_warns_then_refuses():
    cond = Conditioning.from_records(record_settings(s) for s in GRID)
    assert cond.check({"fno": 5.6, "focus_m": 3.0, "focal_mm": 50.0}) == []
    assert cond.check({"fno": 8.9, "focal_mm": 50.4}) == []  # 1/7 stop, 0.8 %: rounding of recorded values
    warned = cond.check({"fno": 11.0}, "a.dng")  # 0.46 stop beyond f/8
    assert len(warned) == 1 and "a.dng" in warned[0] and "f/11" in warned[0] and "f/2 to f/8" in warned[0]
    assert len(cond.check({"focus_m": 0.8})) == 1  # 1.25 D: 0.25 D beyond 1 m
    with pytest.raises(InputError) as e:
        cond.check({"fno": 22.0}, "a.dng")  # 1.46 stops beyond f/8
    assert e.value.field == "fno" and "a.dng" in str(e.value)
    with pytest.raises(InputError):
        cond.check({"focus_m": 0.3})  # 3.3 D against a 0..1 D range
    with pytest.raises(InputError):
        cond.check({"focal_mm": 85.0})  # the one focal length trained, by far
    assert len(cond.check({"fno": 22.0, "focal_mm": 85.0}, refuse=False)) == 2  # an unconditioned network warns
    wide = Conditioning({"fno": (1.0, 32.0)}, ("fno",))  # 5 stops: refuses beyond 5/4 stops
    assert wide.refuse_margin("fno") == pytest.approx(1.25)
    assert len(wide.check({"fno": 64.0})) == 1  # 1 stop beyond
    with pytest.raises(InputError):
        wide.check({"fno": 90.0})  # 1.49 stops beyond


@pytest.mark.parametrize("bad", [0.0, -2.0, math.nan, math.inf, "f/4", True])
def test_bad_settings_values_are_refused(bad):
    with pytest.raises(InputError) as e:
        record_settings({"fno": bad}, "manifest.json", "records[3].settings")
    assert "records[3].settings.fno" in str(e.value)


def test_focus_at_infinity_is_a_value_and_malformed_conditioning_is_refused():
    assert record_settings({"focus_m": math.inf, "config": "wide"}) == {"focus_m": math.inf}
    with pytest.raises(InputError):
        record_settings([2.0])
    with pytest.raises(InputError):
        Conditioning.from_dict({"keys": ["fno"], "ranges": {}}, "last.pt")
    with pytest.raises(InputError):
        Conditioning.from_dict({"keys": [], "ranges": {"fno": [0, 2]}}, "last.pt")


def test_settings_planes_are_constant_channels():
    s = torch.tensor([[0.5, -1.0], [0.25, 1.0]])
    planes = settings_planes(s, 3, 4)
    assert planes.shape == (2, 2, 3, 4)
    assert torch.equal(planes[1, 0], torch.full((3, 4), 0.25)) and torch.equal(planes[0, 1], -torch.ones(3, 4))
    with pytest.raises(ValueError):
        settings_planes(torch.zeros(2), 3, 4)


def _fov(b: int, h: int, w: int) -> torch.Tensor:
    return fov_channels(h, w, 5, 7, 64, 80).unsqueeze(0).expand(b, -1, -1, -1)


@pytest.mark.parametrize("field_modulation", [False, True])
@torch.no_grad()
def test_conditioned_network_is_the_identity_at_init_and_depends_on_settings(field_modulation):
    torch.manual_seed(0)
    model = FieldAwareUNet(8, 3, settings_dim=2, field_modulation=field_modulation)
    assert model.config["settings_dim"] == 2
    rgb = torch.rand(2, 3, 20, 27)
    s = torch.tensor([[-1.0, 0.5], [1.0, -0.5]])
    assert torch.equal(model(rgb, _fov(2, 20, 27), s), rgb)
    assert torch.equal(model(rgb, _fov(2, 20, 27), torch.tensor([0.0, 1.0])), rgb)  # (k,): one vector for the batch
    for p in model.parameters():  # a trained network: its output depends on the settings
        p.data += 0.05 * torch.randn_like(p)
    a = model(rgb[:1], _fov(1, 20, 27), s[:1])
    b = model(rgb[:1], _fov(1, 20, 27), s[1:])
    assert a.shape == (1, 3, 20, 27) and float((a - b).abs().max()) > 1e-4
    rebuilt = FieldAwareUNet(**model.config)
    rebuilt.load_state_dict(model.state_dict())
    assert torch.equal(rebuilt(rgb[:1], _fov(1, 20, 27), s[:1]), a)


def test_network_settings_arguments_are_checked():
    model = FieldAwareUNet(8, 2, settings_dim=3)
    rgb = torch.rand(1, 3, 16, 16)
    with pytest.raises(ValueError, match="settings_dim=3"):
        model(rgb, _fov(1, 16, 16))
    with pytest.raises(ValueError, match=r"\(1, 3\)"):
        model(rgb, _fov(1, 16, 16), torch.zeros(1, 2))
    plain = FieldAwareUNet(8, 2)
    assert plain.settings_dim == 0 and plain.config["settings_dim"] == 0
    with pytest.raises(ValueError, match="settings_dim=0"):
        plain(rgb, _fov(1, 16, 16), torch.zeros(1, 2))
    with pytest.raises(ValueError):
        FieldAwareUNet(8, 2, settings_dim=-1)


def test_an_old_config_without_settings_dim_builds_the_same_network():
    torch.manual_seed(3)
    model = FieldAwareUNet(8, 2)
    old = {k: v for k, v in model.config.items() if k != "settings_dim"}
    rebuilt = FieldAwareUNet(**old)
    rebuilt.load_state_dict(model.state_dict())  # no new parameters when settings_dim is 0
    assert sum(p.numel() for p in rebuilt.parameters()) == sum(p.numel() for p in model.parameters())
