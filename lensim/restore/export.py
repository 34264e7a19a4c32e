"""Export a trained restoration network to ONNX (`lensim export`), and read the export back.

The ONNX model (:func:`export_onnx`) has named inputs

* ``rgb``: (N, 3, H, W) float32, the photo's sRGB values in [0, 1] as `lensim restore`
  feeds them (8/16-bit images divided by 255/65535; developed raws);
* ``fov``: (N, 2, H, W) float32, present when the network takes field-of-view input
  (metadata ``use_fov``): the FOV channels of :func:`lensim.restore.fov.fov_channels`
  at the pixels' absolute place on the sensor (see :data:`FOV_CONVENTION`);
* ``settings``: (N, settings_dim) float32, present when the network is conditioned on
  shooting settings (metadata ``settings_dim`` > 0);
* ``wiener``: (N, 3, H, W) float32, present for the PSF-informed network (metadata
  ``uses_wiener``, ``stage``): the Wiener stage's image of the same pixels (sRGB in
  [0, 1]), computed by lensim before onnxruntime runs (lensim.restore.psf_stage.photo_wiener
  over the whole photo, with the lens's PSF bank and the stage settings of ``stage``);

and one output ``restored`` (N, 3, H, W) float32 (not clamped). N, H and W are dynamic,
H, W >= 2. The network works on multiples of its ``size_multiple``; the graph pads the
inputs itself, the same way the PyTorch network does (RGB by edge replication, FOV
channels by linear continuation), with index arithmetic on the input's shape rather than
Python branches, so one file serves every size, and crops the output back.

Exporter: the TorchScript-based ``torch.onnx.export(..., dynamo=False)``, tracing with
dynamic axes. The grid_sample DCN (lensim.restore.deform) and the padding export as
ordinary ops (GridSample, opset >= 16), their shape arithmetic recorded from the input's
shape, so the file runs any size (tests/test_export.py checks sizes other than the traced
one against PyTorch). It exports the paper's UNet in about 1 s; the torch.export
(dynamo) exporter gave the same results at the same onnxruntime speed but took 15-35 s on
a 2-core CPU and needs onnxscript, which matters for `lensim restore --engine onnxruntime
RUN`, which exports on the fly.

Metadata: ``metadata_props["lensim"]`` holds one JSON document (:func:`onnx_metadata`):
the format and lensim version, the checkpoint it came from, the model configuration,
size_multiple, the FOV convention with the sensor it refers to, the sensor and lens
trained for, the training settings (TrainConfig), the shooting-settings conditioning
(lensim.restore.conditioning.Conditioning.to_dict(): what the ``settings`` vector holds)
and the tiling `lensim restore` uses. Non-finite numbers (a focus range reaching
infinity) are written as the strings "inf", "-inf", "nan", so the document is strict JSON.
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn

import lensim
from lensim.errors import InputError, ParameterError
from lensim.io import atomic_write_bytes
from lensim.jsonable import strict_json

ONNX_FORMAT = "lensim-restore-onnx"
ONNX_FORMAT_VERSION = 1
#: the metadata_props key holding the JSON metadata
METADATA_KEY = "lensim"
MIN_OPSET = 17
DEFAULT_OPSET = 17


def max_opset() -> int:
    """The newest opset the TorchScript exporter of this PyTorch writes."""
    from torch.onnx import _constants

    return int(getattr(_constants, "ONNX_TORCHSCRIPT_EXPORTER_MAX_OPSET", 17))


#: how the ``fov`` input is computed (also in the metadata)
FOV_CONVENTION = (
    "fov[:, 0] = x = (c + 0.5 - Ws / 2) / R, fov[:, 1] = y = (r + 0.5 - Hs / 2) / R, where (r, c) is the pixel's "
    "absolute row and column on the sensor (in the image's pixel units), Hs x Ws the sensor size in those units and "
    "R = sqrt(Hs^2 + Ws^2) / 2 its half-diagonal (optical axis at the sensor centre; lensim.restore.fov.fov_channels). "
    "A photo taken as a full frame is fitted inside the sensor, centred, its limiting side spanning it "
    "(lensim.restore.infer.image_sensor_geometry); a tile gets the coordinates of its own pixels."
)


class OnnxGraph(nn.Module):
    """What is exported: pad to the network's size multiple, run it, crop.

    forward(rgb (N, 3, H, W), fov (N, 2, H, W) or None, settings (N, D) or None) ->
    (N, 3, H, W). The padding is the network's own (edge replication for RGB, linear
    continuation for the FOV channels; replication along a side of 1 pixel), written as
    gathers with indices computed from the input's shape so that the traced graph pads
    any size. Wrapping the padded input, the network's own padding is a no-op."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model
        self.multiple = int(getattr(model, "size_multiple", 1))
        self.use_fov = bool(getattr(model, "use_fov", True))
        self.settings_dim = int(getattr(model, "settings_dim", 0) or 0)
        self.uses_wiener = bool(getattr(model, "uses_wiener", False))

    @staticmethod
    def _indices(n: Any, multiple: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(source index of each padded position, how far past the last one it lies)."""
        padded = (n + multiple - 1) // multiple * multiple
        pos = torch.arange(padded)
        src = pos.clamp(max=n - 1)
        return src, (pos - src).to(torch.float32)

    @staticmethod
    def _pad_linear(x: torch.Tensor, dim: int, src: torch.Tensor, past: torch.Tensor) -> torch.Tensor:
        """Gather along ``dim`` and continue linearly from the last two entries."""
        last = src[-1:]
        step = x.index_select(dim, last) - x.index_select(dim, (last - 1).clamp(min=0))
        shape = [1, 1, 1, 1]
        shape[dim] = -1
        return x.index_select(dim, src) + past.view(shape) * step

    @property
    def input_names(self) -> list[str]:
        """The graph's inputs, in order: rgb, then fov when the network takes it, settings
        when it is conditioned and wiener for the PSF-informed network."""
        return (
            ["rgb"]
            + (["fov"] if self.use_fov else [])
            + (["settings"] if self.settings_dim else [])
            + (["wiener"] if self.uses_wiener else [])
        )

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """inputs: rgb (N, 3, H, W)[, fov (N, 2, H, W)][, settings (N, D)] as input_names
        lists them -> (N, 3, H, W)."""
        named = dict(zip(self.input_names, inputs, strict=True))
        rgb, fov, settings = named["rgb"], named.get("fov"), named.get("settings")
        h, w = rgb.shape[2], rgb.shape[3]
        rows, past_r = self._indices(h, self.multiple)
        cols, past_c = self._indices(w, self.multiple)
        x = rgb.index_select(2, rows).index_select(3, cols)
        f = None
        if fov is not None:
            f = self._pad_linear(self._pad_linear(fov, 2, rows, past_r), 3, cols, past_c)
        if self.uses_wiener:
            wien = named["wiener"].index_select(2, rows).index_select(3, cols)
            out = self.model(x, f, settings, wien)
        else:
            out = self.model(x, f, settings) if self.settings_dim > 0 else self.model(x, f)
        return out[:, :, :h, :w]


# ----------------------------------------------------------------------------- metadata


def _fov_metadata(sensor: Any) -> dict[str, Any]:
    res = sensor.get("resolution") if isinstance(sensor, dict) else None
    return {
        "definition": FOV_CONVENTION,
        "sensor_resolution": list(res) if isinstance(res, (list, tuple)) else None,
        "pixel_pitch_um": sensor.get("pixel_pitch_um") if isinstance(sensor, dict) else None,
        "channels": ["x", "y"],
    }


def onnx_metadata(model: nn.Module, info: dict[str, Any], opset: int) -> dict[str, Any]:
    """The JSON metadata of an export: ``model`` the network, ``info`` what
    lensim.restore.checkpoint.load_checkpoint returned with it."""
    from lensim.restore.infer import default_margin, default_overlap, default_tile

    config = dict(getattr(model, "config", {}))
    graph = OnnxGraph(model)
    overlap = default_overlap(model)
    sensor = info.get("sensor")
    inputs = {"rgb": "(N, 3, H, W) float32 sRGB in [0, 1]"}
    if graph.use_fov:
        inputs["fov"] = "(N, 2, H, W) float32 field-of-view channels (fov_convention)"
    if graph.settings_dim:
        inputs["settings"] = f"(N, {graph.settings_dim}) float32 shooting-settings vector (lensim.restore.conditioning)"
    if graph.uses_wiener:
        inputs["wiener"] = (
            "(N, 3, H, W) float32 the Wiener stage's image of the same pixels, sRGB in [0, 1] "
            "(lensim.restore.psf_stage.photo_wiener with the lens's PSF bank and the settings in 'stage')"
        )
    return {
        "format": ONNX_FORMAT,
        "format_version": ONNX_FORMAT_VERSION,
        "lensim_version": lensim.__version__,
        "exporter": f"torch.onnx TorchScript exporter, torch {torch.__version__}",
        "opset": opset,
        "checkpoint": {
            k: info.get(k)
            for k in (
                "path",
                "format",
                "version",
                "epoch",
                "step",
                "best_val_psnr",
                "val_psnr",
                "val_ssim",
                "train_seconds",
            )
        },
        "arch": config.get("arch", "unet"),
        "model_config": config,
        "size_multiple": graph.multiple,
        "use_fov": graph.use_fov,
        "settings_dim": graph.settings_dim,
        "uses_wiener": graph.uses_wiener,
        "stage": config.get("stage"),
        "inputs": inputs,
        "outputs": {"restored": "(N, 3, H, W) float32, not clamped"},
        "fov_convention": _fov_metadata(sensor),
        "sensor": sensor,
        "sensor_name": info.get("sensor_name"),
        "lens": info.get("lens"),
        "dataset": info.get("dataset"),
        "train_config": info.get("train_config"),
        "conditioning": info.get("conditioning"),
        "tiling": {
            "tile": default_tile(model),
            "overlap": overlap,
            "margin": default_margin(overlap),
            "tile_origin_multiple": graph.multiple,
        },
    }


# ----------------------------------------------------------------------------- export


def check_opset(opset: int) -> int:
    """The ONNX opset, from MIN_OPSET to the newest this exporter writes (else a ParameterError)."""
    top = max_opset()
    if not isinstance(opset, int) or not MIN_OPSET <= opset <= top:
        raise ParameterError(
            None,
            "opset",
            f"expected an ONNX opset from {MIN_OPSET} to {top} (the newest this "
            f"PyTorch's exporter writes), got {opset}",
        )
    return opset


def _example_inputs(graph: OnnxGraph) -> tuple[torch.Tensor, ...]:
    """Inputs to trace with, in input_names order: batch 2, a size that is not a multiple
    of the network's (so the padding is in the traced graph)."""
    h, w = 3 * graph.multiple + 1, 2 * graph.multiple + 3
    gen = torch.Generator().manual_seed(0)
    make = {
        "rgb": lambda: torch.rand(2, 3, h, w, generator=gen),
        "fov": lambda: torch.rand(2, 2, h, w, generator=gen) * 2 - 1,
        "settings": lambda: torch.rand(2, graph.settings_dim, generator=gen),
        "wiener": lambda: torch.rand(2, 3, h, w, generator=gen),
    }
    return tuple(make[n]() for n in graph.input_names)


def export_model_bytes(model: nn.Module, info: dict[str, Any], opset: int = DEFAULT_OPSET) -> bytes:
    """The serialized ONNX model of a loaded network (see the module docstring) with its
    metadata; ``info`` as :func:`onnx_metadata` takes it. The model is exported from a
    float32 CPU copy, in eval mode."""
    import onnx

    opset = check_opset(opset)
    model = _cpu_float_copy(model)
    graph = OnnxGraph(model).eval()
    example = _example_inputs(graph)
    names = graph.input_names
    dims = {0: "batch", 2: "height", 3: "width"}
    axes: dict[str, dict[int, str]] = {n: (dims if n != "settings" else {0: "batch"}) for n in names}
    axes["restored"] = dims
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        # the legacy exporter's deprecation notice and the tracer's notes on the network's shape checks
        warnings.simplefilter("ignore")
        # the TorchScript exporter writes to file objects too (its stub types only paths)
        torch.onnx.export(
            graph,
            example,
            buf,  # type: ignore[arg-type]
            dynamo=False,
            opset_version=opset,
            input_names=names,
            output_names=["restored"],
            dynamic_axes=axes,
            do_constant_folding=True,
        )
    proto = onnx.load_from_string(buf.getvalue())
    entry = proto.metadata_props.add()
    entry.key = METADATA_KEY
    entry.value = json.dumps(strict_json(onnx_metadata(model, info, opset)), default=str, allow_nan=False)
    proto.producer_name = "lensim"
    proto.producer_version = lensim.__version__
    return proto.SerializeToString()


def _cpu_float_copy(model: nn.Module) -> nn.Module:
    """A float32 CPU copy in eval mode whose deformable convolutions use the pure-PyTorch
    grid_sample backend (what exports; torchvision's op would not)."""
    import copy

    from lensim.restore.deform import ModulatedDeformConv2d

    twin = copy.deepcopy(model).to(device="cpu", dtype=torch.float32).eval()
    for module in twin.modules():
        if isinstance(module, ModulatedDeformConv2d):
            module.backend = "grid_sample"
    return twin


def _check_destination(path: Path) -> None:
    """Every existing ancestor of ``path`` is a folder and ``path`` is not one."""
    if path.is_dir():
        raise InputError(str(path), None, "is a folder; expected an .onnx file name to write")
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(str(path), None, f"cannot be created: {parent} is a file, not a folder")


def export_onnx(run_or_checkpoint: str | Path, path: str | Path, opset: int = DEFAULT_OPSET) -> Path:
    """Export the network of a `lensim train` run folder (best.pt, else last.pt) or
    checkpoint file to ONNX at ``path`` (written atomically); returns ``path``.

    Raises a one-line InputError for a file that is not a restoration checkpoint, an opset
    outside [17, max_opset()] or a destination that cannot be written."""
    from lensim.restore.checkpoint import load_checkpoint

    path = Path(path)
    check_opset(opset)
    _check_destination(path)
    model, info = load_checkpoint(run_or_checkpoint)
    atomic_write_bytes(path, export_model_bytes(model, info, opset))
    return path


# ----------------------------------------------------------------------------- reading back


def parse_metadata(props: dict[str, str], source: str) -> dict[str, Any]:
    """The lensim metadata of an ONNX model from its metadata_props (a dict); one-line
    InputError naming ``source`` when it is missing, not JSON or of another format."""
    text = props.get(METADATA_KEY)
    if text is None:
        raise InputError(
            source, "metadata", f"has no {METADATA_KEY!r} entry; expected an ONNX file written by `lensim export`"
        )
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(source, "metadata", f"the {METADATA_KEY!r} entry is not JSON ({e.msg})") from None
    if not isinstance(meta, dict) or meta.get("format") != ONNX_FORMAT:
        raise InputError(
            source, "metadata.format", f"expected {ONNX_FORMAT!r} (an ONNX file written by `lensim export`)"
        )
    if meta.get("format_version") != ONNX_FORMAT_VERSION:
        raise InputError(
            source,
            "metadata.format_version",
            f"expected {ONNX_FORMAT_VERSION}, got {meta.get('format_version')!r} (written by another lensim version)",
        )
    for key, kind in (("size_multiple", int), ("use_fov", bool), ("settings_dim", int)):
        if not isinstance(meta.get(key), kind):
            raise InputError(source, f"metadata.{key}", f"expected {kind.__name__}, got {meta.get(key)!r}")
    if not isinstance(meta.setdefault("uses_wiener", False), bool):  # absent before issue 23: no Wiener input
        raise InputError(source, "metadata.uses_wiener", f"expected bool, got {meta.get('uses_wiener')!r}")
    return meta


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The lensim metadata of an ONNX file (:func:`onnx_metadata`); one-line InputError for
    a missing file, a file that is not ONNX, or an ONNX file not written by lensim."""
    import onnx

    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), None, "no such file; expected an ONNX model from `lensim export`")
    try:
        proto = onnx.load(str(path), load_external_data=False)
    except Exception as e:  # noqa: BLE001 - protobuf's errors vary; any of them means "not ONNX"
        raise InputError(str(path), None, f"is not an ONNX model ({type(e).__name__})") from None
    return parse_metadata({p.key: p.value for p in proto.metadata_props}, str(path))


__all__ = [
    "DEFAULT_OPSET",
    "FOV_CONVENTION",
    "METADATA_KEY",
    "MIN_OPSET",
    "ONNX_FORMAT",
    "ONNX_FORMAT_VERSION",
    "OnnxGraph",
    "check_opset",
    "export_model_bytes",
    "export_onnx",
    "max_opset",
    "onnx_metadata",
    "parse_metadata",
    "read_metadata",
]
