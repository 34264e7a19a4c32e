"""Inference engines for `lensim restore --engine`: PyTorch (the network itself,
lensim.restore.infer.TorchEngine) and onnxruntime (:class:`OnnxEngine`, an ONNX model
written by `lensim export` or exported on the fly from a run).

Both run under the same tiling (lensim.restore.infer.restore_image): the engine only
restores one tile. :func:`load_engine` is the one place that turns what `lensim restore`
is given (a run folder, a checkpoint or an .onnx file) into an engine and the record of
what it was trained for (sensor, lens), warning when the photos' lens or sensor differs.

onnxruntime execution providers (:func:`providers_for`): ``cpu`` runs on the
CPUExecutionProvider; ``cuda`` / ``cuda:N`` on the CUDAExecutionProvider (device N) when
the installed onnxruntime has it (the onnxruntime-gpu build), with the CPU provider as
fallback for any op it lacks; otherwise a one-line error. Tiles are passed as NumPy
arrays on the host (float32).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from lensim.errors import InputError, ParameterError
from lensim.restore.export import DEFAULT_OPSET, export_model_bytes, parse_metadata

ENGINES = ("torch", "onnxruntime")


def providers_for(device: str) -> list[Any]:
    """onnxruntime execution providers for a device name (cpu, cuda, cuda:N), best first; a
    ParameterError naming ``device`` for another name or a CUDA this onnxruntime lacks."""
    import onnxruntime as ort

    name = device.strip()
    if name == "cpu":
        return ["CPUExecutionProvider"]
    kind, _, index = name.partition(":")
    if kind != "cuda" or (index and not index.isdigit()):
        raise ParameterError(None, "device", f"expected cpu, cuda or cuda:N for `engine` onnxruntime, got {device!r}")
    available = ort.get_available_providers()
    if "CUDAExecutionProvider" not in available:
        raise ParameterError(
            None,
            "device",
            f"{device!r} requested but this onnxruntime has no CUDAExecutionProvider "
            f"(it has {', '.join(available)}); expected cpu, or install onnxruntime-gpu",
        )
    return [("CUDAExecutionProvider", {"device_id": int(index or 0)}), "CPUExecutionProvider"]


class OnnxEngine:
    """An exported restoration network run by onnxruntime, as a lensim.restore.infer.Engine.

    Args:
        model: an .onnx file from `lensim export`, or its serialized bytes.
        device: cpu, cuda or cuda:N (:func:`providers_for`).
        threads: onnxruntime's intra-op threads (0: its default, all cores).
        source: the name used in error messages (default: the file name).

    Attributes: ``metadata`` (lensim.restore.export.onnx_metadata), size_multiple,
    use_fov, settings_dim, uses_wiener, tile_overlap and tile_size (the overlap and tile the
    metadata records: the defaults of lensim.restore.infer.default_overlap and default_tile) and stage (the PSF-informed network's
    WienerStage, else None); device/dtype are CPU float32 (the tiles' host arrays).
    """

    def __init__(
        self, model: str | Path | bytes, device: str = "cpu", threads: int = 0, source: str | None = None
    ) -> None:
        import onnxruntime as ort

        self.source = source or (str(model) if not isinstance(model, bytes) else "exported model")
        opts = ort.SessionOptions()
        if threads > 0:
            opts.intra_op_num_threads = threads
            opts.inter_op_num_threads = 1
        opts.log_severity_level = 3  # errors only: onnxruntime's notes would reach stderr unasked
        # idle threads sleep instead of spinning, as lensim sets OMP_WAIT_POLICY=PASSIVE for torch
        # (lensim/__init__.py): on a shared machine spinning threads steal the cores others wait for
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        providers = providers_for(device)
        if not isinstance(model, bytes) and not Path(model).is_file():
            raise InputError(self.source, None, "no such file; expected an ONNX model from `lensim export`")
        try:
            self.session = ort.InferenceSession(
                model if isinstance(model, bytes) else str(model), opts, providers=providers
            )
        except Exception as e:  # noqa: BLE001 - onnxruntime raises its own exception types
            first = (str(e).strip().splitlines() or [""])[0][:200]
            raise InputError(
                self.source, None, f"is not an ONNX model onnxruntime loads ({type(e).__name__}: {first})"
            ) from None
        self.metadata = parse_metadata(self.session.get_modelmeta().custom_metadata_map, self.source)
        self.size_multiple = int(self.metadata["size_multiple"])
        self.use_fov = bool(self.metadata["use_fov"])
        self.settings_dim = int(self.metadata["settings_dim"])
        self.uses_wiener = bool(self.metadata["uses_wiener"])
        self.tile_overlap = (self.metadata.get("tiling") or {}).get("overlap")
        self.tile_size = (self.metadata.get("tiling") or {}).get("tile")
        self.stage = None
        if self.uses_wiener:
            from lensim.restore.psf_stage import WienerStage

            self.stage = WienerStage.from_dict(self.metadata.get("stage"), self.source)
        self.input_names = [i.name for i in self.session.get_inputs()]
        expected = (
            ["rgb"]
            + (["fov"] if self.use_fov else [])
            + (["settings"] if self.settings_dim else [])
            + (["wiener"] if self.uses_wiener else [])
        )
        if self.input_names != expected:
            raise InputError(self.source, "inputs", f"expected {expected} as its metadata says, got {self.input_names}")
        self.device = torch.device("cpu")
        self.dtype = torch.float32

    def __call__(
        self,
        rgb: torch.Tensor,
        fov: torch.Tensor | None,
        settings: torch.Tensor | None = None,
        wiener: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """rgb (N, 3, h, w), fov (N, 2, h, w) or None, settings (N, D) or None, wiener
        (N, 3, h, w) or None (the PSF-informed network's Wiener image) -> restored
        (N, 3, h, w) float32 on the CPU."""
        feed = {"rgb": _host(rgb)}
        if self.use_fov:
            if fov is None:
                raise ValueError("this model takes the FOV channels (fov_channels)")
            feed["fov"] = _host(fov.expand(rgb.shape[0], -1, -1, -1) if fov.dim() == 4 else fov)
        if self.settings_dim:
            if settings is None:
                raise ValueError(f"this model takes a settings vector of {self.settings_dim} values")
            feed["settings"] = _host(settings.reshape(rgb.shape[0], self.settings_dim))
        if self.uses_wiener:
            if wiener is None:
                raise ValueError("this model takes the Wiener stage's image (lensim.restore.psf_stage)")
            feed["wiener"] = _host(wiener)
        return torch.from_numpy(self.session.run(["restored"], feed)[0])


def _host(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(device="cpu", dtype=torch.float32).numpy())


def is_onnx_path(path: str | Path) -> bool:
    """Whether `lensim restore` was given an ONNX file (by its suffix)."""
    return Path(path).suffix.lower() == ".onnx"


def load_engine(
    model_path: str | Path,
    engine: str,
    device: str = "cpu",
    threads: int = 0,
    lens: dict[str, Any] | None = None,
    sensor: dict[str, Any] | None = None,
) -> tuple[Any, dict[str, Any]]:
    """(engine, info) for `lensim restore`: info holds "path", "sensor", "lens" (what the
    network was trained for), "conditioning" (Conditioning.to_dict()), "engine" and, for onnxruntime, "onnx" (the model's bytes, for
    worker processes). ``model_path``: a run folder or checkpoint (torch: loaded;
    onnxruntime: exported on the fly, in memory), or with engine "onnxruntime" an .onnx
    file from `lensim export`. ``lens``/``sensor``: the photos' (dicts), warned about when
    they differ from the trained ones."""
    from lensim.restore.checkpoint import load_checkpoint, warn_other_camera
    from lensim.restore.conditioning import checkpoint_conditioning

    if engine not in ENGINES:
        raise ParameterError(None, "engine", f"expected one of {', '.join(ENGINES)}, got {engine!r}")
    if is_onnx_path(model_path):
        if engine != "onnxruntime":
            raise InputError(
                str(model_path),
                None,
                "is an ONNX model; expected `engine` onnxruntime to run it (or a "
                "run folder or checkpoint for `engine` torch)",
            )
        data = Path(model_path).read_bytes() if Path(model_path).is_file() else b""
        if not data:
            raise InputError(
                str(model_path), None, "no such file (or empty); expected an ONNX model from `lensim export`"
            )
        onnx_engine = OnnxEngine(data, device, threads, source=str(model_path))
        meta = onnx_engine.metadata
        cond = checkpoint_conditioning(meta, onnx_engine.settings_dim, f"{model_path}: metadata")
        info = {
            "path": str(model_path),
            "sensor": meta.get("sensor"),
            "lens": meta.get("lens"),
            "engine": engine,
            "conditioning": cond.to_dict(),
            "onnx": data,
        }
        warn_other_camera(str(model_path), info, lens, sensor)
        return onnx_engine, info
    model, info = load_checkpoint(model_path, lens=lens, sensor=sensor, device="cpu" if engine != "torch" else device)
    info = dict(info, engine=engine)
    if engine == "torch":
        return model, info
    data = export_model_bytes(model, info, DEFAULT_OPSET)
    info["onnx"] = data
    return OnnxEngine(data, device, threads, source=f"{str(info['path'])} (exported)"), info


__all__ = ["ENGINES", "OnnxEngine", "is_onnx_path", "load_engine", "providers_for"]
