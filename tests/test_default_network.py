"""The default network of `lensim train` (TrainConfig's defaults, resolved per architecture
by lensim.restore.arch_rules.ARCH_DEFAULTS): NAFNet with FOV channels and a 2x pixel-unshuffle
stem, no deformable convolution, no context block, at the paper's UNet's size; `--arch
unet` alone is the paper's UNet exactly as the old default; the tri-state switches
override either; the resolved values are what a run records; a checkpoint from before
"arch" and "stem" resumes as the UNet."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import pytest
import torch

from cli_runner import run_cli
from lensim.restore.arch_rules import ARCH_DEFAULTS
from lensim.restore.checkpoint import atomic_torch_save, load_checkpoint
from lensim.restore.config import TrainConfig
from lensim.restore.models import build_model, default_width, reference_parameters
from lensim.restore.nafnet import NAFNet
from lensim.restore.network import ContextBlock, DeformResBlock, FieldAwareUNet, count_parameters
from test_train import make_pairs

# the model config TrainConfig() gave before NAFNet became the default (written out, not computed)
OLD_DEFAULT = {
    "arch": "unet",
    "width": 32,
    "depth": 3,
    "use_fov": True,
    "use_deformable": True,
    "use_context": True,
    "deformable_groups": 2,
    "settings_dim": 0,
    "deformable_scales": None,
    "field_modulation": False,
}
NETWORK_KEYS = ("arch", "width", "use_fov", "use_deformable", "use_context", "stem")


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_pairs(tmp_path_factory.mktemp("pairs"), photos=2, crops=2, size=32)


def test_the_default_is_nafnet_with_fov_and_stem_2_at_the_papers_size() -> None:
    cfg = TrainConfig().resolved()
    assert (cfg.arch, cfg.use_fov, cfg.stem, cfg.use_deformable, cfg.use_context) == ("nafnet", True, 2, False, False)
    assert TrainConfig().model_kwargs() == cfg.model_kwargs()  # model_kwargs resolves an unresolved config
    with torch.device("meta"):
        net = build_model(cfg.model_kwargs())
    assert isinstance(net, NAFNet) and net.stem == 2 and net.use_fov
    assert not net.use_deformable and not net.use_context
    ref = reference_parameters()
    assert abs(count_parameters(net) - ref) <= 0.1 * ref
    assert TrainConfig().width == 0 and TrainConfig().stem == 0  # unresolved: "the architecture's default"
    assert TrainConfig().use_deformable is None and TrainConfig().use_context is None


def test_arch_unet_is_the_papers_unet_as_before() -> None:
    assert TrainConfig(arch="unet").model_kwargs() == OLD_DEFAULT
    cfg = TrainConfig(arch="unet").resolved()
    assert (cfg.width, cfg.stem, cfg.use_deformable, cfg.use_context) == (32, 1, True, True)
    with torch.device("meta"):
        net = build_model(OLD_DEFAULT)
    assert isinstance(net, FieldAwareUNet) and net.head.in_channels == 5  # RGB + the 2 FOV channels
    assert all(isinstance(block, DeformResBlock) for block in net.dec)  # DCN at every decoder scale
    assert isinstance(net.context, ContextBlock)


def test_given_switches_beat_the_architecture_defaults() -> None:
    assert set(ARCH_DEFAULTS) == {"unet", "nafnet", "psfnet"}
    cfg = TrainConfig(use_deformable=True, use_context=True, stem=1).resolved()
    assert (cfg.arch, cfg.use_deformable, cfg.use_context, cfg.stem) == ("nafnet", True, True, 1)
    cfg = TrainConfig(arch="unet", use_deformable=False, use_context=False).resolved()
    assert (cfg.use_deformable, cfg.use_context, cfg.stem) == (False, False, 1)
    assert TrainConfig(width=8).resolved().width == 8
    # the size-matched width of what the switches describe
    deform = TrainConfig(use_deformable=True, use_context=True).resolved()
    assert deform.width == default_width(
        "nafnet", **{k: v for k, v in deform.model_kwargs().items() if k not in ("arch", "width", "depth")}
    )


def _captured_config(args: list[str], pairs: Path, tmp_path: Path, capsys, monkeypatch) -> tuple[int, str, Any]:
    """Run `lensim train PAIRS -o RUN ARGS` with train() replaced by one that only resolves
    the settings as train() does; (exit status, stderr, the resolved TrainConfig or None)."""
    import lensim.restore.train as train_module

    seen: list[TrainConfig] = []

    def fake_train(dataset, run, config=None, resume=False, progress=None, **overrides):
        seen.append(train_module.resolve_config(config, overrides, None, str(run)))
        return train_module.TrainResult(str(run), 0, 0, False, 0.0, math.nan, None, None, None, None)

    monkeypatch.setattr(train_module, "train", fake_train)
    code, _, err = run_cli(
        ["train", str(pairs), "-o", str(tmp_path / "run"), "--crop", "32", "--json", *args], capsys, monkeypatch
    )
    return code, err, seen[0] if seen else None


@pytest.mark.parametrize(
    "args, expected",
    [
        ([], ("nafnet", True, False, False, 2)),
        (["--arch", "unet"], ("unet", True, True, True, 1)),
        (["--arch", "unet", "--stem", "0"], ("unet", True, True, True, 1)),
        (["--deformable"], ("nafnet", True, True, False, 2)),
        (["--context", "--stem", "1"], ("nafnet", True, False, True, 1)),
        (["--no-fov", "--no-deformable", "--no-context"], ("nafnet", False, False, False, 2)),
        (["--arch", "unet", "--no-deformable"], ("unet", True, False, True, 1)),
        (["--arch", "unet", "--no-context"], ("unet", True, True, False, 1)),
        (["--arch", "unet", "--deformable", "--context"], ("unet", True, True, True, 1)),
    ],
)
def test_cli_switches(args: list[str], expected: tuple, pairs: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    code, err, cfg = _captured_config(args, pairs, tmp_path, capsys, monkeypatch)
    assert code == 0, err
    assert (cfg.arch, cfg.use_fov, cfg.use_deformable, cfg.use_context, cfg.stem) == expected
    if args == ["--arch", "unet"]:
        assert cfg.model_kwargs() == OLD_DEFAULT
    if not args:
        assert cfg.model_kwargs() == TrainConfig().model_kwargs()


def test_cli_refuses_the_stem_on_the_unet_in_one_line(pairs: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    code, err, cfg = _captured_config(["--arch", "unet", "--stem", "2"], pairs, tmp_path, capsys, monkeypatch)
    assert code == 2 and cfg is None and err.count("\n") == 1
    assert "--stem" in err and "nafnet" in err


def test_a_run_records_the_resolved_network(pairs: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    run = tmp_path / "run"
    code, _, err = run_cli(
        [
            "train",
            str(pairs),
            "-o",
            str(run),
            "--epochs",
            "1",
            "--steps-per-epoch",
            "1",
            "--crop",
            "32",
            "--batch-size",
            "2",
            "--val-fraction",
            "0.5",
            "--quiet",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    want = TrainConfig().resolved()
    recorded = json.loads((run / "config.json").read_text())
    model, info = load_checkpoint(run / "last.pt")
    for key in NETWORK_KEYS:
        assert recorded[key] == info["train_config"][key] == getattr(want, key), key
    assert isinstance(model, NAFNet) and model.stem == 2 and model.width == want.width > 0


def test_a_checkpoint_from_before_arch_resumes_as_the_unet(pairs: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    """A run written before "arch" and "stem" existed (they are removed from its
    checkpoint; model_config without "arch" too) continues as the UNet, through train()
    and through the command line, whose --arch now defaults to nafnet."""
    from lensim.restore.train import train

    run = tmp_path / "run"
    train(
        pairs,
        run,
        epochs=1,
        max_steps_per_epoch=1,
        arch="unet",
        width=8,
        depth=2,
        crop=32,
        batch_size=2,
        val_fraction=0.5,
    )
    ckpt = torch.load(run / "last.pt", weights_only=True)
    for key in ("arch", "stem"):
        del ckpt["train_config"][key]
    del ckpt["model_config"]["arch"]
    assert ckpt["train_config"]["use_deformable"] is True  # old checkpoints name their switches
    atomic_torch_save(ckpt, run / "last.pt")
    res = train(pairs, run, resume=True, epochs=2)
    assert res.epochs_done == 2
    saved = torch.load(run / "last.pt", weights_only=True)["train_config"]
    assert (saved["arch"], saved["stem"], saved["width"], saved["use_deformable"], saved["use_context"]) == (
        "unet",
        1,
        8,
        True,
        True,
    )
    assert {k: saved[k] for k in asdict(TrainConfig()) if k in saved}.keys() == asdict(TrainConfig()).keys()
    code, out, err = run_cli(
        ["train", str(pairs), "-o", str(run), "--resume", "--epochs", "3", "--json"], capsys, monkeypatch
    )
    assert code == 0 and json.loads(out)["epochs_done"] == 3, err
    assert isinstance(load_checkpoint(run / "last.pt")[0], FieldAwareUNet)
    code, _, err = run_cli(["train", str(pairs), "-o", str(run), "--resume", "--arch", "nafnet"], capsys, monkeypatch)
    assert code == 2 and "arch" in err and err.count("\n") == 1
    # asking for the architecture's default of a frozen switch is no change
    code, _, err = run_cli(
        ["train", str(pairs), "-o", str(run), "--resume", "--epochs", "4", "--stem", "0", "--deformable", "--quiet"],
        capsys,
        monkeypatch,
    )
    assert code == 0, err


def _demo_configs(tmp_path: Path, monkeypatch, settings: list) -> list[TrainConfig]:
    """The resolved TrainConfig the demo's _train asks train() for, per (settings, plain)."""
    import lensim.restore.train as train_module
    from lensim.demo import _train

    seen: list[TrainConfig] = []

    def fake_train(dataset, run, config=None, resume=False, progress=None, **overrides):
        seen.append(train_module.resolve_config(config, overrides, None, str(run)))
        Path(run).mkdir(parents=True)
        return train_module.TrainResult(str(run), 0, 0, False, 0.0, math.nan, None, None, None, None)

    monkeypatch.setattr(train_module, "train", fake_train)
    for i, (demo, plain) in enumerate(settings):
        _train(tmp_path, tmp_path / f"run{i}", demo, plain=plain, seed=0)
    return seen


def test_demo_trains_the_networks_it_named_before(tmp_path: Path, monkeypatch) -> None:
    """lensim demo names every architecture and switch: its UNet variant and that
    variant's plain UNet resolve as with the old defaults, its field-aware network is the
    PSF-informed network (issue 23) with the default network's switches."""
    import dataclasses

    from lensim.demo import DemoSettings
    from lensim.restore.network import plain_unet_width

    quick = DemoSettings.make(quick=True)
    as_unet = dataclasses.replace(quick, arch="unet")
    plain, model, unet = _demo_configs(tmp_path, monkeypatch, [(as_unet, True), (quick, False), (as_unet, False)])
    target = count_parameters(FieldAwareUNet(width=quick.width, deformable_scales=quick.deformable_scales))
    assert plain.model_kwargs() == {
        **OLD_DEFAULT,
        "width": plain_unet_width(target, 3),
        "use_fov": False,
        "use_deformable": False,
        "use_context": False,
    }
    assert (model.arch, model.use_fov, model.use_deformable, model.use_context, model.stem) == (
        "psfnet",  # the demo's field-aware network since issue 23: the PSF-informed one
        True,
        False,
        False,
        quick.stem,
    )
    assert unet.model_kwargs() == {**OLD_DEFAULT, "width": quick.width, "deformable_scales": quick.deformable_scales}


@pytest.mark.parametrize("quick", [True, False])
def test_demo_baseline_is_its_network_without_the_field_aware_parts(tmp_path: Path, monkeypatch, quick: bool) -> None:
    """The demo's baseline (lensim.demo.plain_network) is NAFNet with the demo's stem and no
    FOV channels, deformable blocks or context block, within 10% of the parameters of the
    demo's network; train() is asked for exactly that."""
    from lensim.demo import DemoSettings, plain_network

    settings = DemoSettings.make(quick=quick)
    plain, model = _demo_configs(tmp_path, monkeypatch, [(settings, True), (settings, False)])
    assert (
        (plain.arch, plain.use_fov, plain.use_deformable, plain.use_context, plain.stem)
        == ("nafnet", False, False, False, settings.stem)
        == tuple(plain_network(settings)[k] for k in ("arch", "use_fov", "use_deformable", "use_context", "stem"))
    )
    assert plain.width == plain_network(settings)["width"]
    with torch.device("meta"):
        plain_net, net = build_model(plain.model_kwargs()), build_model(model.model_kwargs())
    assert isinstance(plain_net, NAFNet) and not plain_net.use_fov and plain_net.stem == settings.stem
    assert not any(isinstance(m, (DeformResBlock, ContextBlock)) for m in plain_net.modules())
    assert isinstance(net, NAFNet) and net.use_fov and net.stem == settings.stem
    assert abs(count_parameters(plain_net) - count_parameters(net)) <= 0.1 * count_parameters(net)


def test_networks_described_as_their_configs_say() -> None:
    """describe_network: "plain ARCH" with every field-aware part off, else the parts on;
    the stem where it is not 1; a config without arch or switches is the old UNet."""
    from lensim.restore.models import describe_network

    with torch.device("meta"):
        plain = NAFNet(23, use_fov=False, stem=2).config
        fov = NAFNet(23, use_fov=True, stem=2).config
        unet = FieldAwareUNet(width=37, use_fov=False, use_deformable=False, use_context=False).config
    assert describe_network(plain) == "plain NAFNet (stem 2, width 23)"
    assert describe_network(fov) == "NAFNet with FOV (stem 2, width 23)"
    assert describe_network(unet) == "plain UNet (width 37)"
    assert describe_network({"width": 32}) == "UNet with FOV, deformable, context (width 32)"


def test_demo_names_the_network_its_run_holds(tmp_path: Path) -> None:
    """The demo's report names each run's network from its last.pt, not from the settings:
    a run-plain left by an older lensim (a plain UNet, reused by its done.json) is named
    as the UNet it holds."""
    from lensim.demo import _network
    from lensim.restore.checkpoint import CHECKPOINT_FORMAT

    for name, net, words in (
        ("new", NAFNet(8, stem=2), "plain NAFNet (stem 2, width 8)"),
        (
            "old",
            FieldAwareUNet(width=8, use_fov=False, use_deformable=False, use_context=False),
            "plain UNet (width 8)",
        ),
    ):
        (tmp_path / name).mkdir()
        atomic_torch_save(
            {"format": CHECKPOINT_FORMAT, "model_config": net.config, "model_state": net.state_dict()},
            tmp_path / name / "last.pt",
        )
        assert _network(tmp_path / name) == words
