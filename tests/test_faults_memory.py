"""Memory pressure in `lensim restore`: a tile the memory cannot hold makes restore try
smaller tiles (a warning line names the tile it settled on) and end with the photo a run
at that tile writes; when even the smallest tile fails, one line names --tile. Injected
here (a network that fails on tiles above a size, as PyTorch does when an allocation
fails); under -m slow a 24-megapixel frame under a real address-space cap (ulimit -v)."""

from __future__ import annotations

import resource
from pathlib import Path

import numpy as np
import pytest

from cli_runner import run_cli
from faults import half_files, lensim_process, one_line_error

ALLOC_FAILURE = (
    "[enforce fail at alloc_cpu.cpp:118] data. DefaultCPUAllocator: not enough memory: you tried to allocate "
    "1073741824 bytes."
)


def _photo(path: Path, h: int, w: int) -> Path:
    from PIL import Image

    y, x = np.mgrid[0:h, 0:w]
    rgb = np.stack([(x * 255 // max(w - 1, 1)), (y * 255 // max(h - 1, 1)), ((x + y) % 256)], -1).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path)
    return path


def _cap_tiles(monkeypatch, largest: int) -> None:
    """Tiles of more than ``largest`` x ``largest`` pixels fail as an allocation does."""
    from lensim.restore.infer import TorchEngine

    real = TorchEngine.__call__

    def call(self, rgb, fov, settings=None):
        if rgb.shape[-1] * rgb.shape[-2] > largest * largest:
            raise RuntimeError(ALLOC_FAILURE)
        return real(self, rgb, fov, settings)

    monkeypatch.setattr(TorchEngine, "__call__", call)


def test_restore_adapts_its_tile_to_the_memory(fault_world, tmp_path, capsys, monkeypatch):
    photo = _photo(tmp_path / "in" / "photo.png", 96, 128)
    base = ["restore", str(fault_world.model), str(photo), "--overlap", "16", "--quiet"]
    code, _, err = run_cli([*base, "-o", str(tmp_path / "small"), "--tile", "32"], capsys, monkeypatch)
    assert code == 0, err
    _cap_tiles(monkeypatch, 48)
    code, _, err = run_cli([*base, "-o", str(tmp_path / "out"), "--tile", "128"], capsys, monkeypatch)
    assert code == 0, err
    assert "Traceback" not in err and "tile" in err and "32" in err, err
    assert (tmp_path / "out" / "photo.png").read_bytes() == (tmp_path / "small" / "photo.png").read_bytes()


def test_restore_that_no_tile_fits_fails_in_one_line_naming_the_tile(fault_world, tmp_path, capsys, monkeypatch):
    photo = _photo(tmp_path / "in" / "photo.png", 96, 128)
    _cap_tiles(monkeypatch, 8)
    out = tmp_path / "out"
    code, _, err = run_cli(
        ["restore", str(fault_world.model), str(photo), "-o", str(out), "--tile", "64", "--overlap", "16", "--quiet"],
        capsys,
        monkeypatch,
    )
    line = one_line_error(err)
    assert code == 2 and "--tile" in line and "memory" in line, err
    assert not out.exists() or not [p for p in out.iterdir() if p.name != ".lensim.lock"]


def test_raws_on_workers_adapt_their_tile_too(fault_world, tmp_path, capsys, monkeypatch):
    """In this process (one worker) the raws' tiles adapt like a photo's."""
    _cap_tiles(monkeypatch, 24)
    out = tmp_path / "out"
    code, _, err = run_cli(fault_world.args("restore", out, "--tile", "48", "--overlap", "8"), capsys, monkeypatch)
    assert code == 0, err
    assert sorted(p.name for p in out.glob("*.tif")) == ["s0.tif", "s1.tif", "s2.tif"]


def _limit_address_space(limit: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return apply


@pytest.mark.slow
def test_a_24_megapixel_frame_under_a_memory_cap(fault_world, tmp_path):
    """`restore` of a 6000 x 4000 photo with the address space capped (ulimit -v): it
    adapts its tile or fails in one line naming --tile; no traceback, no half file."""
    photo = _photo(tmp_path / "in" / "frame.png", 4000, 6000)
    out = tmp_path / "out"
    args = ["restore", str(fault_world.model), str(photo), "-o", str(out), "--tile", "2048", "--overlap", "64"]
    proc = lensim_process([*args, "--quiet", "--threads", "1"], preexec_fn=_limit_address_space(6 << 30))
    _, err = proc.communicate(timeout=1800)
    assert "Traceback" not in err, err
    if proc.returncode != 0:
        line = one_line_error(err)
        assert proc.returncode == 2 and "--tile" in line, err
    else:
        assert "tile" in err and (out / "frame.png").is_file(), err
    assert not half_files(out) if out.exists() else True
