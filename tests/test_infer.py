"""Inference: tiled == whole-image restoration, absolute FOV per tile, sensor geometry,
checkpoint loading errors and warnings, and the train/restore commands end to end."""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import pytest
import torch
import typer
from typer.testing import CliRunner

from lensim.errors import InputError
from lensim.images import read_image, write_image
from lensim.restore.checkpoint import load_checkpoint
from lensim.restore.fov import fov_channels
from lensim.restore.infer import image_sensor_geometry, restore_image, tile_starts
from lensim.restore.network import FieldAwareUNet
from lensim.restore.train import train
from test_train import LENS, SENSOR, TINY, make_pairs

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def random_model(depth: int = 2, use_fov: bool = True, field_modulation: bool = False) -> FieldAwareUNet:
    """A tiny network that is far from the identity and has non-zero deformable offsets
    (and, with field_modulation, non-zero position-dependent modulations)."""
    torch.manual_seed(0)
    m = FieldAwareUNet(8, depth, use_fov=use_fov, zero_init_tail=False, field_modulation=field_modulation)
    with torch.no_grad():
        for blk in m.dec:
            torch.nn.init.normal_(blk.offset_conv.weight, std=0.05)
        for mod in m.modulate or []:
            torch.nn.init.normal_(mod.out.weight, std=0.3)
    return m.eval()


def test_tile_grid_starts_on_the_multiple_and_covers_the_image():
    for length, tile, overlap, mult in [(230, 96, 80, 2), (1000, 512, 192, 4), (97, 64, 16, 8), (50, 64, 16, 4)]:
        s = tile_starts(length, tile, overlap, mult)
        assert s[0] == 0 and all(v % mult == 0 for v in s) and s == sorted(set(s))
        assert s[-1] + tile >= length and s[-1] < length
        assert all(b - a <= tile - overlap for a, b in zip(s, s[1:]))  # neighbours overlap by >= overlap


def test_even_tiles_need_no_more_tiles_and_spread_the_overlap():
    from lensim.restore.infer import even_tile

    for length in list(range(40, 700, 7)) + [4000, 6000]:
        for tile, overlap, mult in [(512, 96, 4), (1024, 96, 4), (96, 80, 2), (64, 16, 8), (512, 192, 16)]:
            side = even_tile(length, tile, overlap, mult)
            s, before = tile_starts(length, side, overlap, mult), tile_starts(length, tile, overlap, mult)
            assert side % mult == 0 and side <= tile and len(s) <= len(before)
            assert s[0] == 0 and all(v % mult == 0 for v in s) and s[-1] + side >= length
            assert all(b - a <= side - overlap for a, b in zip(s, s[1:]))
    # a 24 MP frame at the NAFNet defaults: 1.21 instead of 1.53 times its pixels computed
    assert (even_tile(6000, 1024, 96, 4), even_tile(4000, 1024, 96, 4)) == (940, 880)
    assert len(tile_starts(6000, 940, 96, 4)) * 940 * len(tile_starts(4000, 880, 96, 4)) * 880 < 1.22 * 24e6


def test_default_tile_is_the_networks():
    from lensim.restore.infer import DEFAULT_TILE, default_tile
    from lensim.restore.nafnet import NAFNet

    assert default_tile(NAFNet(8, use_fov=True, stem=2)) == 1024
    assert default_tile(NAFNet(8, use_fov=True, use_context=True)) == DEFAULT_TILE == 512
    assert default_tile(random_model(depth=2)) == DEFAULT_TILE


@pytest.mark.parametrize("field_modulation", [False, True], ids=["fov-input", "field-modulation"])
def test_tiled_equals_whole_image_inference(field_modulation: bool):
    model = random_model(depth=2, field_modulation=field_modulation)  # receptive-field radius about 28 px
    gen = torch.Generator().manual_seed(1)
    img = torch.rand(3, 150, 230, generator=gen)
    top_left, size = (37.0, 211.0), (480.0, 640.0)
    with torch.no_grad():
        whole = model(img[None], fov_channels(150, 230, *top_left, *size)[None])[0]
    assert (whole - img).abs().max() > 0.05  # the model really changes the image
    tiled = restore_image(model, img, top_left, size, tile=96, overlap=80, margin=32)
    err = (tiled - whole).abs().max().item()
    assert err < 1e-4, err
    # tiles whose outputs are used right up to their edges do differ: the margin matters
    naive = restore_image(model, img, top_left, size, tile=96, overlap=2, margin=0)
    assert (naive - whole).abs().max().item() > 1e-3
    # one tile covering everything is the whole-image pass
    one = restore_image(model, img, top_left, size, tile=256, overlap=16)
    assert (one - whole).abs().max().item() < 1e-6


class Recorder(torch.nn.Module):
    """Wraps a model and records every (rgb, fov) it is fed."""

    def __init__(self, model: FieldAwareUNet) -> None:
        super().__init__()
        self.model = model
        self.calls: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.size_multiple = model.size_multiple
        self.use_fov = model.use_fov

    def forward(self, rgb: torch.Tensor, fov: torch.Tensor) -> torch.Tensor:
        self.calls.append((rgb.clone(), fov.clone()))
        return self.model(rgb, fov)


def test_each_tile_gets_its_absolute_fov_channels():
    rec = Recorder(random_model(depth=3))
    img = torch.rand(3, 90, 130, generator=torch.Generator().manual_seed(2))
    top_left, size = (12.0, 300.0), (400.0, 600.0)
    restore_image(rec, img, top_left, size, tile=48, overlap=24, margin=8)
    ys, xs = tile_starts(90, 48, 24, 4), tile_starts(130, 48, 24, 4)
    assert len(rec.calls) == len(ys) * len(xs) > 4
    whole_fov = fov_channels(90, 130, *top_left, *size)
    k = 0
    for y0 in ys:
        for x0 in xs:
            rgb, fov = rec.calls[k]
            h, w = rgb.shape[-2:]
            assert y0 % 4 == 0 and x0 % 4 == 0
            assert torch.equal(rgb[0], img[:, y0 : y0 + h, x0 : x0 + w])
            assert torch.allclose(fov[0], whole_fov[:, y0 : y0 + h, x0 : x0 + w], atol=1e-7), (y0, x0)
            k += 1


def test_full_frame_geometry_matches_map_to_sensor():
    from lensim.render.mapping import map_to_sensor
    from lensim.sensor.profile import load_sensor

    sensor = load_sensor("apsc_mirrorless")
    for h, w in [(400, 600), (300, 600), (500, 500)]:
        top_left, size = image_sensor_geometry(h, w, sensor.resolution)
        fov = fov_channels(h, w, *top_left, *size, dtype=torch.float64)
        mp = map_to_sensor(h, w, sensor)
        rows = torch.tensor([0.0, h - 1.0, h / 2]).view(3, 1)
        cols = torch.tensor([0.0, w - 1.0, 7.0]).view(1, 3)
        x_mm, y_mm = mp.pixel_to_mm(rows.expand(3, 3), cols.expand(3, 3))
        half_diag_mm = 0.5 * math.hypot(*sensor.sensor_size_mm)
        r_idx, c_idx = rows.long().expand(3, 3), cols.long().expand(3, 3)
        assert torch.allclose(fov[0][r_idx, c_idx], x_mm.double() / half_diag_mm, atol=1e-9)
        assert torch.allclose(fov[1][r_idx, c_idx], y_mm.double() / half_diag_mm, atol=1e-9)
    # native-scale offset: the sensor's own pixel grid
    assert image_sensor_geometry(64, 64, (6000, 4000), offset=(100, 200)) == ((100.0, 200.0), (4000.0, 6000.0))


# ----------------------------------------------------------------------------- checkpoints


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    with torch.random.fork_rng():
        torch.set_num_threads(1)
        pairs = make_pairs(tmp_path_factory.mktemp("pairs"), photos=3, crops=2, size=32)
        run = tmp_path_factory.mktemp("run") / "run"
        train(pairs, run, epochs=1, max_steps_per_epoch=2, **{**TINY, "crop": 32})
    return run


def test_load_checkpoint_rebuilds_the_trained_model(run_dir: Path):
    model, info = load_checkpoint(run_dir)
    assert info["path"].endswith("best.pt")
    assert info["model_config"]["arch"] == "nafnet" and info["model_config"]["width"] == 8  # the default network
    ck = torch.load(run_dir / "best.pt", weights_only=True)
    assert all(torch.equal(v, ck["model_state"][k]) for k, v in model.state_dict().items())
    assert not model.training
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_checkpoint(run_dir / "last.pt", lens=json.loads(json.dumps(LENS)), sensor=dict(SENSOR))


def test_other_lens_or_sensor_warns(run_dir: Path):
    with pytest.warns(UserWarning, match="trained for lens 'test lens', used for lens 'other'"):
        load_checkpoint(run_dir, lens={"name": "other"})
    with pytest.warns(UserWarning, match="trained for sensor 'test sensor 640x480'"):
        load_checkpoint(run_dir, sensor={"name": "test sensor", "resolution": [320, 240]})


def test_another_unit_of_the_same_lens_warns_what_differs(run_dir: Path):
    """Same name (a nominal lens and an as-built unit of it): the line names the fields that
    differ and a digest of each lens, not the one name twice."""
    unit = json.loads(json.dumps(LENS))
    unit["surfaces"][0]["decentre"] = [0.004, 0.0]
    unit["as_built"] = {"kind": "calibration"}
    with pytest.warns(UserWarning) as caught:
        load_checkpoint(run_dir, lens=unit)
    (line,) = [str(w.message) for w in caught if "trained for lens" in str(w.message)]
    assert "\n" not in line
    assert "differ in surfaces[0].decentre, as_built; lens digests " in line
    digests = re.search(r"lens digests (\w{8}) \(trained\) and (\w{8}) \(used\)", line)
    assert digests and digests[1] != digests[2]


def test_corrupt_and_mismatched_checkpoints_are_one_line_errors(run_dir: Path, tmp_path: Path):
    good = (run_dir / "last.pt").read_bytes()
    cases = {}
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint at all\n" * 10)
    cases["garbage.pt"] = "corrupt or not a lensim checkpoint"
    (tmp_path / "truncated.pt").write_bytes(good[: len(good) // 2])
    cases["truncated.pt"] = "corrupt or not a lensim checkpoint"
    torch.save({"state_dict": {}}, tmp_path / "foreign.pt")
    cases["foreign.pt"] = "format: expected a 'lensim-restore-checkpoint'"
    ck = torch.load(run_dir / "last.pt", weights_only=True)
    torch.save({**ck, "model_config": {**ck["model_config"], "width": 16}}, tmp_path / "mismatch.pt")
    cases["mismatch.pt"] = "model_state: does not match the model config"
    torch.save({**ck, "model_config": {**ck["model_config"], "bogus": 1}}, tmp_path / "badconfig.pt")
    cases["badconfig.pt"] = "model_config: cannot build the network"
    cases["missing.pt"] = "no such file"
    for name, msg in cases.items():
        with pytest.raises(InputError) as err:
            load_checkpoint(tmp_path / name)
        text = str(err.value)
        assert text.startswith(str(tmp_path / name)) and msg in text and "\n" not in text, text


# ----------------------------------------------------------------------------- commands


def test_train_and_restore_commands(tmp_path: Path):
    from lensim.cli.restore_cmd import restore_command
    from lensim.cli.train_cmd import train_command

    app = typer.Typer()
    app.command("train")(train_command)
    app.command("restore")(restore_command)
    pairs = make_pairs(tmp_path / "pairs", photos=2, crops=2, size=32)
    runner = CliRunner()
    res = runner.invoke(
        app,
        [
            "train",
            str(pairs),
            "-o",
            str(tmp_path / "run"),
            "--epochs",
            "1",
            "--crop",
            "32",
            "--width",
            "8",
            "--depth",
            "2",
            "--steps-per-epoch",
            "1",
            "--batch-size",
            "2",
            "--val-fraction",
            "0.5",
            "--json",
            "--threads",
            "1",
        ],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["steps"] == 1 and summary["epochs_done"] == 1
    img = torch.rand(3, 40, 56, generator=torch.Generator().manual_seed(0))
    write_image(tmp_path / "a.png", img, 16)
    res = runner.invoke(
        app,
        [
            "restore",
            str(tmp_path / "run"),
            str(tmp_path / "a.png"),
            "-o",
            str(tmp_path / "out"),
            "--sensor-offset",
            "100,200",
            "--tile",
            "32",
            "--overlap",
            "16",
            "--json",
            "--precision",
            "float32",
        ],
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["precision"] == "float32"
    out, bits = read_image(tmp_path / "out" / "a.png")
    assert bits == 16 and out.shape == (3, 40, 56)
    model, _ = load_checkpoint(tmp_path / "run")
    expected = restore_image(
        model, read_image(tmp_path / "a.png")[0], (100.0, 200.0), (480.0, 640.0), tile=32, overlap=16
    ).clamp(0, 1)
    assert (out - expected).abs().max() <= 0.5 / 65535 + 1e-6  # 16-bit quantisation only
    res = runner.invoke(
        app,
        [
            "restore",
            str(tmp_path / "run"),
            str(tmp_path / "a.png"),
            "-o",
            str(tmp_path / "o8"),
            "--bits",
            "8",
            "--sensor-offset",
            "100,200",
        ],
    )
    assert res.exit_code == 0, res.output
    assert read_image(tmp_path / "o8" / "a.png")[1] == 8


def test_bfloat16_tiles_stay_close_to_float32_and_float32_is_the_library_default():
    """precision bfloat16 runs the tiles under autocast (the output differs from float32's,
    so it did run, and is float32) within 35 dB PSNR of float32 even for this random
    network; the default is float32 (bit for bit)."""
    model = random_model()
    img = torch.rand(3, 48, 64, generator=torch.Generator().manual_seed(3))
    geometry = ((100.0, 200.0), (480.0, 640.0))
    ref = restore_image(model, img, *geometry, tile=32, overlap=16)
    assert torch.equal(restore_image(model, img, *geometry, tile=32, overlap=16, precision="float32"), ref)
    low = restore_image(model, img, *geometry, tile=32, overlap=16, precision="bfloat16")
    assert low.dtype == torch.float32 and not torch.equal(low, ref)
    mse = float((low - ref).square().mean())
    assert 10 * math.log10(float(ref.square().mean()) / mse) > 35.0


def test_auto_precision_is_bfloat16_only_for_a_torch_network_on_a_cpu_that_has_it(monkeypatch):
    import lensim.restore.infer as infer

    model = random_model()
    engine = infer.as_engine(model)
    monkeypatch.setattr(infer, "native_bfloat16", lambda device="cpu": True)
    assert infer.tile_dtype("auto", engine) == torch.bfloat16
    assert infer.tile_dtype("auto", model) == torch.bfloat16  # a bare network: its parameters' device
    assert infer.tile_dtype("float32", engine) is None

    class Exported:  # an engine that is not a PyTorch network (an ONNX session)
        device, dtype = torch.device("cpu"), torch.float32

    assert infer.tile_dtype("auto", Exported()) is None
    with pytest.raises(ValueError, match="bfloat16 applies to a PyTorch network"):
        infer.tile_dtype("bfloat16", Exported())
    with pytest.raises(ValueError, match="precision must be one of"):
        infer.tile_dtype("half", engine)
    monkeypatch.setattr(infer, "native_bfloat16", lambda device="cpu": False)
    assert infer.tile_dtype("auto", engine) is None
    assert infer.tile_dtype("bfloat16", engine) == torch.bfloat16  # asked for: emulated, slower


def test_restore_precision_option_is_checked_in_one_line(tmp_path: Path, capsys, monkeypatch):
    from cli_runner import run_cli

    photo = tmp_path / "a.png"
    write_image(photo, torch.rand(3, 16, 16), 8)
    for extra, expected in (
        (["--precision", "half"], "--precision: expected one of auto, float32, bfloat16, got 'half'"),
        (["--precision", "bfloat16", "--engine", "onnxruntime"], "--precision: bfloat16 applies to --engine torch"),
    ):
        args = ["restore", str(tmp_path), str(photo), "-o", str(tmp_path / "o"), *extra]
        code, _, err = run_cli(args, capsys, monkeypatch)
        assert code == 2 and len(err.strip().splitlines()) == 1 and expected in err, err
        assert not (tmp_path / "o").exists()
