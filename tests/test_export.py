"""ONNX export (`lensim export`, lensim.restore.export) and the onnxruntime engine
(`lensim restore --engine onnxruntime`, lensim.restore.engines): the exported graph equals
the PyTorch network within 1e-3 on a 512 x 512 tile, on sizes other than the traced one,
batched; metadata round trip; one-line refusals; restore with either engine agrees."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_runner import run_cli
from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
from lensim.restore.engines import OnnxEngine
from lensim.restore.export import (
    FOV_CONVENTION,
    ONNX_FORMAT,
    export_model_bytes,
    export_onnx,
    read_metadata,
)
from lensim.restore.fov import fov_channels
from lensim.restore.infer import restore_image
from lensim.restore.network import FieldAwareUNet
from lensim.sensor.profile import load_sensor

TOL = 1e-3


@pytest.fixture(autouse=True)
def two_threads():
    n = torch.get_num_threads()
    torch.set_num_threads(min(n, 2))
    yield
    torch.set_num_threads(n)


def perturbed(seed: int = 0, **kw) -> FieldAwareUNet:
    """A network with deformable blocks whose weights are all perturbed: the zero-initialised
    tail and offset convs become non-zero, so the output is not the identity and the DCN
    samples at non-integer offsets."""
    torch.manual_seed(seed)
    model = FieldAwareUNet(**kw)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model.eval()


def save_run(
    folder: Path, model: torch.nn.Module, sensor: dict | None = None, conditioning: dict | None = None
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    sensor = sensor or load_sensor("apsc_mirrorless").to_dict()
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": sensor,
            "sensor_name": sensor["name"],
            "lens": {"name": "test lens"},
            "train_config": {"crop": 96, "lr": 5e-4},
            "epoch": 3,
            "step": 42,
            "conditioning": conditioning,
        },
        folder / "best.pt",
    )
    return folder


NARROW = dict(width=8, depth=3, deformable_scales=None, field_modulation=True)


@pytest.fixture(scope="module")
def narrow(tmp_path_factory: pytest.TempPathFactory) -> tuple[FieldAwareUNet, Path, Path]:
    """(model, run folder, exported .onnx): a width-8 network, DCN at every decoder scale."""
    model = perturbed(0, **NARROW)
    root = tmp_path_factory.mktemp("narrow")
    run = save_run(root / "run", model)
    return model, run, export_onnx(run, root / "model.onnx")


def tile_inputs(h: int, w: int, n: int = 1, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """n random RGB tiles and the FOV channels of places on an APS-C-sized sensor."""
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(n, 3, h, w, generator=g)
    fov = torch.stack([fov_channels(h, w, 100 + 37 * i, 900 - 53 * i, 4000, 6000) for i in range(n)])
    return rgb, fov


def max_diff(model: FieldAwareUNet, engine: OnnxEngine, rgb: torch.Tensor, fov: torch.Tensor) -> float:
    with torch.no_grad():
        ref = model(rgb, fov)
    assert (ref - rgb).abs().max().item() > 0.05  # not the identity
    out = engine(rgb, fov)
    assert out.shape == ref.shape and out.dtype == torch.float32
    return (out - ref).abs().max().item()


def test_onnx_equals_torch_on_a_512_tile(narrow):
    model, _, path = narrow
    rgb, fov = tile_inputs(512, 512)
    assert max_diff(model, OnnxEngine(path), rgb, fov) < TOL


@pytest.mark.slow
def test_default_network_onnx_equals_torch_on_a_512_tile(tmp_path: Path):
    """The default network (widths 32/64/128), DCN at every decoder scale (~20 s)."""
    model = perturbed(3, deformable_scales=None)
    rgb, fov = tile_inputs(512, 512, seed=4)
    assert max_diff(model, OnnxEngine(export_model_bytes(model, {})), rgb, fov) < TOL


def test_one_file_runs_any_size_and_batch(narrow):
    """Sizes other than the traced one, not multiples of the size multiple, a 1-pixel side
    and a batch of 3 with different FOV each: the graph's padding and the DCN's grids are
    dynamic."""
    model, _, path = narrow
    engine = OnnxEngine(path)
    for n, h, w in [(1, 96, 160), (1, 53, 37), (3, 30, 18), (1, 1, 9)]:
        rgb, fov = tile_inputs(h, w, n, seed=h)
        assert max_diff(model, engine, rgb, fov) < TOL, (n, h, w)


ARCHS = {
    "unet-conditioned": dict(arch="unet", width=8, settings_dim=2, field_modulation=True),
    "nafnet-fov-dcn-stem": dict(arch="nafnet", width=8, use_fov=True, use_deformable=True, stem=2, settings_dim=1),
    "nafnet-plain": dict(arch="nafnet", width=8),
}


@pytest.mark.parametrize("name", list(ARCHS))
def test_every_architecture_exports(name: str):
    """Both architectures of lensim.restore.models, conditioned or not: the graph's inputs
    follow the network's (fov iff use_fov, settings iff settings_dim) and its output equals
    PyTorch's, batched, at a size that is not a multiple of the size multiple."""
    from lensim.restore.models import build_model

    torch.manual_seed(7)
    model = build_model(ARCHS[name])
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    model.eval()
    engine = OnnxEngine(export_model_bytes(model, {}))
    k = model.settings_dim
    assert engine.input_names == ["rgb"] + (["fov"] if model.use_fov else []) + (["settings"] if k else [])
    rgb, fov = tile_inputs(45, 70, n=2, seed=9)
    fov = fov if model.use_fov else None
    settings = torch.rand(2, k) * 2 - 1 if k else None
    with torch.no_grad():
        ref = model(rgb, fov, settings)
    assert (ref - rgb).abs().max().item() > 0.05
    assert (engine(rgb, fov, settings) - ref).abs().max().item() < TOL


def test_plain_network_has_no_fov_input(tmp_path: Path):
    model = perturbed(1, width=6, depth=2, use_fov=False, use_deformable=False, use_context=False)
    engine = OnnxEngine(export_model_bytes(model, {}))
    assert engine.input_names == ["rgb"] and not engine.use_fov
    rgb, _ = tile_inputs(40, 28)
    with torch.no_grad():
        assert (engine(rgb, None) - model(rgb)).abs().max().item() < TOL


def test_metadata_round_trip(narrow):
    model, run, path = narrow
    meta = read_metadata(path)
    ckpt = torch.load(run / "best.pt", weights_only=True)
    assert meta["format"] == ONNX_FORMAT and meta["opset"] == 17
    assert meta["model_config"] == json.loads(json.dumps(model.config))
    assert meta["size_multiple"] == model.size_multiple == 4 and meta["use_fov"] is True
    assert meta["settings_dim"] == 0 and meta["arch"] == "unet"
    assert meta["sensor"] == json.loads(json.dumps(ckpt["sensor"])) and meta["lens"] == {"name": "test lens"}
    assert meta["train_config"] == {"crop": 96, "lr": 5e-4}
    assert meta["checkpoint"]["path"] == str(run / "best.pt") and meta["checkpoint"]["step"] == 42
    assert meta["fov_convention"]["definition"] == FOV_CONVENTION
    assert meta["fov_convention"]["sensor_resolution"] == list(ckpt["sensor"]["resolution"])
    assert meta["tiling"] == {"tile": 512, "overlap": 192, "margin": 72, "tile_origin_multiple": 4}
    assert set(meta["inputs"]) == {"rgb", "fov"}
    import onnx

    proto = onnx.load(str(path))
    assert [i.name for i in proto.graph.input] == ["rgb", "fov"]
    assert [o.name for o in proto.graph.output] == ["restored"]
    dims = [d.dim_param or d.dim_value for d in proto.graph.input[0].type.tensor_type.shape.dim]
    assert dims == ["batch", 3, "height", "width"]
    assert max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")) == 17


def test_tiled_restore_with_either_engine_agrees(narrow):
    model, _, path = narrow
    img = torch.rand(3, 150, 230, generator=torch.Generator().manual_seed(5))
    args = ((10.0, 20.0), (400.0, 600.0))
    a = restore_image(model, img, *args, tile=96, overlap=40)
    b = restore_image(OnnxEngine(path), img, *args, tile=96, overlap=40)
    assert (a - b).abs().max().item() < TOL and (a - img).abs().max().item() > 0.05


def write_tif16(path: Path, h: int, w: int, seed: int) -> Path:
    import tifffile

    rgb = (np.random.default_rng(seed).random((h, w, 3)) * 65535).astype(np.uint16)
    tifffile.imwrite(path, rgb, photometric="rgb")
    return path


def read_tif16(path: Path) -> np.ndarray:
    import tifffile

    return tifffile.imread(path).astype(np.float64) / 65535.0


def test_restore_command_onnxruntime_equals_torch(narrow, tmp_path: Path, capsys, monkeypatch):
    """`lensim restore` with --engine onnxruntime (the .onnx file, and the run exported on
    the fly) writes what --engine torch writes, within 1e-3."""
    _, run, path = narrow
    photo = write_tif16(tmp_path / "a.tif", 72, 100, 0)
    common = [str(photo), "--sensor-offset", "1000,2000", "--tile", "48", "--overlap", "24", "--quiet"]
    outs = {}
    for name, source, engine in [("torch", run, "torch"), ("file", path, "onnxruntime"), ("fly", run, "onnxruntime")]:
        code, _, err = run_cli(
            ["restore", str(source), *common, "-o", str(tmp_path / name), "--engine", engine, "--precision", "float32"],
            capsys,
            monkeypatch,
        )
        assert code == 0, err
        outs[name] = read_tif16(tmp_path / name / "a.tif")
    assert np.abs(outs["torch"] - read_tif16(photo)).max() > 0.05
    assert np.abs(outs["file"] - outs["torch"]).max() < TOL
    assert np.abs(outs["fly"] - outs["torch"]).max() < TOL


def test_conditioned_restore_reads_the_conditioning_from_the_file(tmp_path: Path, capsys, monkeypatch):
    """A network conditioned on the F-number and focus: the .onnx file carries the trained
    ranges (a focus range reaching infinity included, as strict JSON), restore takes the
    settings from --fno/--focus-m and writes what the torch engine writes; a photo without
    them is refused in one line, as with the checkpoint."""
    from lensim.restore.models import build_model

    torch.manual_seed(11)
    model = build_model(dict(arch="unet", width=8, depth=2, settings_dim=2))
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    cond = {"keys": ["fno", "focus_m"], "ranges": {"fno": [2.0, 8.0], "focus_m": [1.0, float("inf")]}}
    run = save_run(tmp_path / "run", model.eval(), conditioning=cond)
    path = export_onnx(run, tmp_path / "c.onnx")
    meta = read_metadata(path)
    assert meta["settings_dim"] == 2 and meta["conditioning"]["ranges"]["focus_m"] == [1.0, "inf"]
    photo = write_tif16(tmp_path / "a.tif", 40, 56, 3)
    outs = {}
    for name, source, engine in [("torch", run, "torch"), ("ort", path, "onnxruntime")]:
        code, _, err = run_cli(
            [
                "restore",
                str(source),
                str(photo),
                "-o",
                str(tmp_path / name),
                "--quiet",
                "--engine",
                engine,
                "--precision",
                "float32",
                "--fno",
                "4",
                "--focus-m",
                "3",
                "--sensor-offset",
                "100,200",
            ],
            capsys,
            monkeypatch,
        )
        assert code == 0, err
        outs[name] = read_tif16(tmp_path / name / "a.tif")
    assert np.abs(outs["ort"] - outs["torch"]).max() < TOL
    assert np.abs(outs["torch"] - read_tif16(photo)).max() > 0.05
    code, _, err = run_cli(
        [
            "restore",
            str(path),
            str(photo),
            "-o",
            str(tmp_path / "x"),
            "--engine",
            "onnxruntime",
            "--sensor-offset",
            "100,200",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--fno" in err, err


def test_export_command(narrow, tmp_path: Path, capsys, monkeypatch):
    _, run, _ = narrow
    code, out, err = run_cli(
        ["export", str(run), "-o", str(tmp_path / "sub" / "m.onnx"), "--opset", "18", "--json"], capsys, monkeypatch
    )
    assert code == 0, err
    doc = json.loads(out)
    assert doc["metadata"]["opset"] == 18 and (tmp_path / "sub" / "m.onnx").is_file()
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["m.onnx"]  # no temporary left


@pytest.mark.parametrize(
    "make, expect",
    [
        (lambda t: torch.save({"weights": torch.zeros(3)}, t / "other.pt"), "format"),
        (lambda t: (t / "other.pt").write_bytes(b"not a checkpoint at all"), "corrupt"),
        (lambda t: (t / "other.pt").mkdir(), "no best.pt or last.pt"),
    ],
)
def test_export_refuses_what_is_not_a_restoration_run(make, expect, tmp_path: Path, capsys, monkeypatch):
    make(tmp_path)
    code, out, err = run_cli(
        ["export", str(tmp_path / "other.pt"), "-o", str(tmp_path / "m.onnx")], capsys, monkeypatch
    )
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and expect in err and "other.pt" in err, err
    assert not (tmp_path / "m.onnx").exists()


def test_onnx_files_not_from_lensim_are_refused(narrow, tmp_path: Path):
    import onnx

    from lensim.errors import InputError

    _, _, path = narrow
    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    onnx.save(proto, str(tmp_path / "bare.onnx"))
    (tmp_path / "junk.onnx").write_bytes(b"\x00garbage")
    with pytest.raises(InputError, match="bare.onnx: metadata: has no 'lensim' entry"):
        OnnxEngine(tmp_path / "bare.onnx")
    with pytest.raises(InputError, match="junk.onnx: is not an ONNX model onnxruntime loads"):
        OnnxEngine(tmp_path / "junk.onnx")
    with pytest.raises(InputError, match="junk.onnx: is not an ONNX model"):
        read_metadata(tmp_path / "junk.onnx")


def raw_run(tmp_path: Path) -> tuple[Path, Path, list[Path]]:
    """(run, its .onnx, three DNGs) on the small sensor of tests/test_raw_restore.py."""
    from lensim.raw.dng import write_capture_dng
    from test_raw_restore import capture, small_sensor

    model = perturbed(2, width=8, depth=2)
    run = save_run(tmp_path / "run", model, small_sensor().to_dict())
    dngs = []
    for k in range(3):
        raw, params = capture(k)
        dngs.append(write_capture_dng(tmp_path / "raws" / f"s{k}.dng", raw, small_sensor(), params))
    return run, export_onnx(run, tmp_path / "m.onnx"), dngs


def test_raw_restore_onnxruntime_equals_torch(tmp_path: Path, capsys, monkeypatch):
    run, onnx_file, dngs = raw_run(tmp_path)
    outs = {}
    for name, source, engine in [("torch", run, "torch"), ("ort", onnx_file, "onnxruntime")]:
        code, _, err = run_cli(
            [
                "restore",
                str(source),
                str(dngs[0]),
                "-o",
                str(tmp_path / name),
                "--quiet",
                "--tile",
                "32",
                "--overlap",
                "8",
                "--engine",
                engine,
                "--precision",
                "float32",
            ],
            capsys,
            monkeypatch,
        )
        assert code == 0, err
        outs[name] = read_tif16(tmp_path / name / "s0.tif")
    assert np.abs(outs["ort"] - outs["torch"]).max() < TOL


@pytest.mark.slow
def test_raw_worker_processes_run_onnxruntime(tmp_path: Path, capsys, monkeypatch):
    """--workers 2 with --engine onnxruntime: each worker builds its session from the
    exported bytes (the run exported on the fly) and writes what the torch engine writes."""
    run, _, dngs = raw_run(tmp_path)
    for name, engine, workers in [("torch", "torch", "1"), ("ort", "onnxruntime", "2")]:
        code, _, err = run_cli(
            [
                "restore",
                str(run),
                str(tmp_path / "raws"),
                "-o",
                str(tmp_path / name),
                "--quiet",
                "--engine",
                engine,
                "--precision",
                "float32",
                "--workers",
                workers,
            ],
            capsys,
            monkeypatch,
        )
        assert code == 0, err
    for d in dngs:
        a, b = read_tif16(tmp_path / "torch" / f"{d.stem}.tif"), read_tif16(tmp_path / "ort" / f"{d.stem}.tif")
        assert np.abs(a - b).max() < TOL


def test_execution_providers(monkeypatch):
    """cpu runs on the CPU provider; cuda:N asks for the CUDA provider on device N (with the
    CPU one behind it) where onnxruntime has it, else a one-line refusal naming --device."""
    import onnxruntime as ort

    from lensim.errors import InputError
    from lensim.restore.engines import providers_for

    assert providers_for("cpu") == ["CPUExecutionProvider"]
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    assert providers_for("cuda:1") == [("CUDAExecutionProvider", {"device_id": 1}), "CPUExecutionProvider"]
    assert providers_for("cuda")[0] == ("CUDAExecutionProvider", {"device_id": 0})
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    with pytest.raises(InputError, match="^device: 'cuda' requested but this onnxruntime has no CUDA"):
        providers_for("cuda")
    with pytest.raises(InputError, match="^device: expected cpu, cuda or cuda:N"):
        providers_for("gpu")


def test_onnx_file_warns_about_another_camera_like_a_checkpoint(narrow):
    from lensim.restore.engines import load_engine

    _, _, path = narrow
    engine, info = load_engine(path, "onnxruntime", lens={"name": "test lens"})
    assert info["sensor"]["resolution"] == [6000, 4000] and info["lens"] == {"name": "test lens"}
    other = load_sensor("phone").to_dict()
    with pytest.warns(UserWarning, match=r"model\.onnx: trained for sensor .*used for sensor"):
        load_engine(path, "onnxruntime", sensor=other)
    with pytest.warns(UserWarning, match=r"trained for lens 'test lens', used for lens 'other'"):
        load_engine(path, "onnxruntime", lens={"name": "other"})


def test_library_refusals(narrow, tmp_path: Path):
    """export_onnx itself (not only the CLI) refuses a destination under a file, a folder
    as destination, an opset outside 17..max_opset() and leaves nothing behind."""
    from lensim.errors import InputError
    from lensim.restore.export import max_opset

    _, run, _ = narrow
    (tmp_path / "afile").write_text("x")
    (tmp_path / "folder.onnx").mkdir()
    with pytest.raises(InputError, match="afile is a file, not a folder"):
        export_onnx(run, tmp_path / "afile" / "m.onnx")
    with pytest.raises(InputError, match="folder.onnx: is a folder"):
        export_onnx(run, tmp_path / "folder.onnx")
    for opset in (16, max_opset() + 1):
        with pytest.raises(InputError, match=f"^opset: expected an ONNX opset from 17 to {max_opset()}"):
            export_onnx(run, tmp_path / "m.onnx", opset=opset)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "folder.onnx"]


def test_the_export_uses_the_grid_sample_dcn_whatever_the_backend_named():
    """A network configured for torchvision's deformable op (CUDA) exports through the
    pure-PyTorch grid_sample DCN; the network itself is left as it was."""
    from lensim.restore.deform import ModulatedDeformConv2d
    from lensim.restore.export import _cpu_float_copy

    model = perturbed(5, width=8, depth=2)
    for m in model.modules():
        if isinstance(m, ModulatedDeformConv2d):
            m.backend = "torchvision"
    twin = _cpu_float_copy(model)
    backends = {m.backend for m in twin.modules() if isinstance(m, ModulatedDeformConv2d)}
    assert backends == {"grid_sample"}
    assert {m.backend for m in model.modules() if isinstance(m, ModulatedDeformConv2d)} == {"torchvision"}
