"""lensim: optical aberration simulation and correction from a lens prescription."""

import os as _os

# torch's OpenMP threads spin-wait for partners; on shared machines another process holding
# a core makes that 10-30x slower (benchmarks/README.md). Passive waiting costs little on a
# dedicated machine; set OMP_WAIT_POLICY yourself to override. Must precede torch's import.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"  # the one place: pyproject.toml reads it (dynamic version)

# The Python API mirrors the CLI; names load lazily so `import lensim` stays light.
_API = {
    "load_lens": "lensim.optics.lens_file",
    "save_lens": "lensim.optics.lens_file",
    "first_order_summary": "lensim.optics.analysis",
    "spot_diagram": "lensim.optics.spot",
    "compute_psf": "lensim.psf.compute",
    "get_bank": "lensim.psf.bank",
    "get_banks": "lensim.psf.bank",
    "BankRequest": "lensim.psf.bank",
    "PSFBank": "lensim.psf.bank",
    "BankSettings": "lensim.psf.bank",
    "load_sensor": "lensim.sensor.profile",
    "read_image": "lensim.images",
    "write_image": "lensim.images",
    "read_raw": "lensim.raw.read",
    "develop_raw": "lensim.raw.develop",
    "sensor_from_raw": "lensim.raw.profile",
    "simulate_photo": "lensim.render.pipeline:simulate",
    "map_to_sensor": "lensim.render.mapping",
    "make_dataset": "lensim.data.pairs",
    "train": "lensim.restore.train",
    "load_checkpoint": "lensim.restore.checkpoint",
    "restore_image": "lensim.restore.infer",
    "export_onnx": "lensim.restore.export",
    "evaluate_methods": "lensim.evaluate.harness:evaluate",  # `lensim.evaluate` is the package
    "run_ablation": "lensim.ablation",
    "run_demo": "lensim.demo",
}


def __getattr__(name: str):
    if name in _API:
        import importlib

        module, _, attr = _API[name].partition(":")
        return getattr(importlib.import_module(module), attr or name)
    raise AttributeError(f"module 'lensim' has no attribute {name!r}")


__all__ = sorted(_API)
