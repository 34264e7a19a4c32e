"""Which architecture takes which switches (lensim.restore.arch_rules): the rules at the
library level, and the same rules where the constructors, TrainConfig and `lensim train`
apply them (one home: the parameter named by the library, the option by the CLI)."""

from __future__ import annotations

import pytest

from cli_runner import run_cli
from lensim.errors import InputError
from lensim.restore.arch_rules import ARCH_DEFAULTS, ARCHS, check_switches
from lensim.restore.config import TrainConfig

#: (arch, switches, the parameter named): one case per rule
BROKEN = [
    ("banana", {}, "arch"),
    ("nafnet", {"field_modulation": True}, "field_modulation"),
    ("unet", {"field_modulation": True, "use_fov": False}, "field_modulation"),
    ("unet", {"stem": 2}, "stem"),
    ("nafnet", {"stem": 3}, "stem"),
    ("nafnet", {"deformable_groups": 0}, "deformable_groups"),
    ("nafnet", {"use_deformable": True, "deformable_groups": 3, "widths": (8, 16, 32)}, "deformable_groups"),
    ("unet", {"use_deformable": True, "deformable_groups": 4, "widths": (6, 12)}, "deformable_groups"),
    ("nafnet", {"use_deformable": True, "deformable_scales": 0}, "deformable_scales"),
    ("nafnet", {"use_deformable": True, "deformable_scales": 3, "widths": (8, 16, 32)}, "deformable_scales"),
    ("unet", {"deformable_scales": 3, "widths": (8, 16, 32)}, "deformable_scales"),
]


@pytest.mark.parametrize(("arch", "switches", "field"), BROKEN, ids=[f"{a}-{f}" for a, _, f in BROKEN])
def test_each_rule_names_its_parameter(arch, switches, field):
    with pytest.raises(InputError) as e:
        check_switches(arch, **switches)
    assert e.value.field == field and e.value.source is None and "--" not in str(e.value)


def test_what_each_architecture_takes():
    assert ARCHS == ("unet", "nafnet", "psfnet") and set(ARCH_DEFAULTS) == set(ARCHS)
    check_switches("unet", use_deformable=True, field_modulation=True, deformable_scales=0, widths=(8, 16, 32))
    check_switches("nafnet", stem=2, use_deformable=True, deformable_scales=2, widths=(8, 16, 32))
    check_switches("nafnet", deformable_scales=0)  # no deformable blocks: the count is unused
    check_switches(None, field_modulation=True, stem=2)  # architecture not known: its rules wait
    for arch, d in ARCH_DEFAULTS.items():  # each architecture's defaults keep its rules
        check_switches(arch, use_deformable=d["use_deformable"], stem=d["stem"], widths=(16, 32, 64))


def test_the_constructors_apply_the_same_rules():
    from lensim.restore.nafnet import NAFNet
    from lensim.restore.network import FieldAwareUNet

    with pytest.raises(InputError) as e:
        NAFNet(width=8, use_deformable=True, deformable_groups=3)
    assert e.value.field == "deformable_groups"
    with pytest.raises(InputError) as e:
        NAFNet(width=8, use_deformable=True, deformable_scales=0)
    assert e.value.field == "deformable_scales"
    with pytest.raises(InputError) as e:
        FieldAwareUNet(width=8, depth=3, deformable_scales=3)
    assert e.value.field == "deformable_scales"
    with pytest.raises(InputError) as e:
        FieldAwareUNet(width=8, use_fov=False, field_modulation=True)
    assert e.value.field == "field_modulation"


def test_train_config_applies_the_same_rules():
    for kw, field in (
        ({"arch": "nafnet", "field_modulation": True}, "field_modulation"),
        ({"arch": "unet", "stem": 2}, "stem"),
        ({"arch": "nafnet", "use_deformable": True, "width": 9, "deformable_groups": 2}, "deformable_groups"),
    ):
        with pytest.raises(InputError) as e:
            TrainConfig(**kw).model_kwargs()
        assert e.value.field == field


def test_lensim_train_names_the_option(tmp_path, capsys, monkeypatch):
    from test_train import make_pairs

    pairs = make_pairs(tmp_path / "pairs", photos=2, crops=1, size=32)
    base = ["train", str(pairs), "-o", str(tmp_path / "run"), "--epochs", "1", "--crop", "32"]
    for extra, option, needle in (
        (["--arch", "unet", "--stem", "2"], "--stem", "arch 'nafnet'"),
        (["--field-modulation"], "--field-modulation", "arch 'unet'"),
        (["--deformable", "--width", "9"], "--deformable-groups", "decoder widths (9, 18)"),
    ):
        code, _, err = run_cli([*base, *extra], capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1 and f"{option}: " in err and needle in err, err
    assert not (tmp_path / "run").exists()
