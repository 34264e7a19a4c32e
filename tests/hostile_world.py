"""The hostile-input suite's shared pieces: a small world of valid inputs made once per
session (lens and sensor files, tiny photos, a 2-field bank, a pairs folder, a trained
run, a DNG), the case table's row type, and a runner that checks one bad command: exit
status 2, one line on stderr, no traceback, the message naming what is wrong, and nothing
new (or changed) on disk afterwards."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ASSETS = Path(__file__).resolve().parents[1] / "lensim" / "assets"
#: seconds one bad command may run: bad input must be refused before any real work
CASE_TIME_LIMIT_S = 20.0


@dataclass(frozen=True)
class World:
    """Valid inputs every case may point at (read-only for the cases)."""

    root: Path
    lens: Path  # cooke_triplet.yaml copy
    sensor: Path  # apsc_mirrorless.yaml copy
    photo: Path  # 48 x 64 8-bit PNG
    photos: Path  # folder of three 64 x 80 PNGs
    bank: Path  # 2 fields, 550 nm, 32 pupil samples, at the APS-C pitch
    data: Path  # pairs folder made from photos/ with bank/
    run: Path  # one epoch of a 4-channel, 2-scale network on data/
    dng: Path  # a 32 x 48 CFA DNG (pidng)
    cache: Path  # the bank cache the commands see (LENSIM_CACHE)


def _png(path: Path, h: int, w: int, seed: int) -> Path:
    from PIL import Image

    rgb = (np.random.default_rng(seed).random((h, w, 3)) * 255).astype(np.uint8)
    Image.fromarray(rgb).save(path)
    return path


def build_world(root: Path) -> World:
    """Make the valid inputs (about 3 s): library calls, no CLI."""
    import lensim
    from lensim.psf.bank import BankSettings, get_bank
    from raw_fixtures import random_mosaic, write_dng

    root.mkdir(parents=True, exist_ok=True)
    lens = shutil.copy(ASSETS / "lenses" / "cooke_triplet.yaml", root / "cooke.yaml")
    sensor = shutil.copy(ASSETS / "sensors" / "apsc_mirrorless.yaml", root / "sensor.yaml")
    photo = _png(root / "photo.png", 48, 64, 0)
    photos = root / "photos"
    photos.mkdir()
    for i in range(3):
        _png(photos / f"p{i}.png", 64, 80, i + 1)
    profile = lensim.load_sensor("apsc_mirrorless")
    settings = BankSettings(fields=2, wavelengths_nm=[550.0], pupil_samples=32)
    bank = get_bank(
        lensim.load_lens("cooke_triplet"),
        profile.pixel_pitch_um,
        settings,
        response=profile.spectral_response,
        out_dir=root / "bank",
    )
    lensim.make_dataset(photos, root / "data", bank, "apsc_mirrorless", profile, crops=1, size=32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lensim.train(root / "data", root / "run", epochs=1, width=4, depth=2, crop=32, batch_size=1)
    dng = write_dng(root / "shot.dng", random_mosaic(32, 48, 600, 4000))
    cache = root / "cache"
    cache.mkdir()
    return World(root, Path(lens), Path(sensor), photo, photos, root / "bank", root / "data", root / "run", dng, cache)


Make = Callable[[Path, World], object]


@dataclass(frozen=True)
class Case:
    """One bad command. ``command`` is formatted with t (the case's empty folder, also
    the working directory) and w (the World) and split like a shell line; ``make``
    writes the case's bad files into t first; every string of ``expect`` must appear in
    the one error line (file names and values literally)."""

    id: str
    command: str
    expect: tuple[str, ...]
    make: tuple[Make, ...] = field(default=())


def case(id: str, command: str, *expect: str, make: Make | tuple[Make, ...] = ()) -> Case:
    return Case(id, command, tuple(expect), make if isinstance(make, tuple) else (make,))


# --- makers of bad files ---------------------------------------------------------------


def text(name: str, content: str, encoding: str = "utf-8") -> Make:
    def make(t: Path, w: World) -> None:
        (t / name).parent.mkdir(parents=True, exist_ok=True)
        (t / name).write_bytes(content.encode(encoding))

    return make


def binary(name: str, data: bytes) -> Make:
    def make(t: Path, w: World) -> None:
        (t / name).parent.mkdir(parents=True, exist_ok=True)
        (t / name).write_bytes(data)

    return make


def folder(name: str) -> Make:
    def make(t: Path, w: World) -> None:
        (t / name).mkdir(parents=True, exist_ok=True)

    return make


def copy_of(source: Callable[[World], Path], name: str) -> Make:
    """A copy of a World file or folder under t/name."""

    def make(t: Path, w: World) -> None:
        src = source(w)
        if src.is_dir():
            shutil.copytree(src, t / name)
        else:
            shutil.copy(src, t / name)

    return make


def edited(name: str, source: Callable[[World], Path], edit: Callable[[Path], None]) -> Make:
    """A copy of a World file or folder under t/name, then changed by ``edit(path)``."""
    base = copy_of(source, name)

    def make(t: Path, w: World) -> None:
        base(t, w)
        edit(t / name)

    return make


def image(name: str, array: np.ndarray, **tiff: object) -> Make:
    """An image file from an array: .tif through tifffile (with its keywords), else Pillow."""

    def make(t: Path, w: World) -> None:
        path = t / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix in (".tif", ".tiff"):
            import tifffile

            tifffile.imwrite(path, array, **tiff)
        else:
            from PIL import Image

            Image.fromarray(array).save(path)

    return make


# --- running and checking ----------------------------------------------------------------


def snapshot(*roots: Path) -> dict[str, tuple[int, int]]:
    """Every path under the roots with its (size, mtime_ns): files, folders, links."""
    seen: dict[str, tuple[int, int]] = {}
    for root in roots:
        for dirpath, dirnames, filenames in os.walk(root):
            for name in dirnames + filenames:
                p = os.path.join(dirpath, name)
                st = os.lstat(p)
                seen[p] = (0 if name in dirnames else st.st_size, 0 if name in dirnames else st.st_mtime_ns)
    return seen


class _TimeLimit(Exception):
    pass


def _alarm(signum, frame):
    raise _TimeLimit()


@dataclass
class Outcome:
    code: int | None
    stderr: str
    traceback: str | None
    changed: list[str]
    seconds: float

    @property
    def lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


def run_case(c: Case, t: Path, w: World, capsys, monkeypatch) -> Outcome:
    """Make the case's files, run the command in-process (cwd t, the World's bank cache)
    and report what happened."""
    from lensim.cli import main

    for make in c.make:
        make(t, w)
    args = shlex.split(c.command.format(t=t, w=w))
    monkeypatch.chdir(t)
    monkeypatch.setenv("LENSIM_CACHE", str(w.cache))
    monkeypatch.setattr(sys, "argv", ["lensim", *args])
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # run_guarded replaces it
    before = snapshot(t, w.root)
    capsys.readouterr()
    code, trace = None, None
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, CASE_TIME_LIMIT_S)
    start = time.perf_counter()
    try:
        main()
        code = 0
    except SystemExit as e:
        code = 0 if e.code is None else int(e.code) if isinstance(e.code, int) else 1
    except _TimeLimit:
        trace = f"still working after {CASE_TIME_LIMIT_S:g} s"
    except BaseException as e:  # a traceback the user would have seen
        trace = f"{type(e).__name__}: {e}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    seconds = time.perf_counter() - start
    _, err = capsys.readouterr()
    after = snapshot(t, w.root)
    changed = sorted(p for p in set(before) | set(after) if before.get(p) != after.get(p))
    return Outcome(code, err, trace, [os.path.relpath(p, t) for p in changed], seconds)


def check_case(c: Case, t: Path, w: World, capsys, monkeypatch) -> None:
    """Run a case and assert the project's promise for bad input."""
    out = run_case(c, t, w, capsys, monkeypatch)
    tally = os.environ.get("LENSIM_HOSTILE_TALLY")
    if tally:  # counts for the closing note
        with open(tally, "a") as fh:
            fh.write(
                json.dumps(
                    {
                        "id": c.id,
                        "traceback": out.traceback,
                        "code": out.code,
                        "lines": len(out.lines),
                        "changed": out.changed,
                        "seconds": round(out.seconds, 2),
                        "named": all(s in out.stderr for s in c.expect),
                    }
                )
                + "\n"
            )
    assert out.traceback is None, f"{c.id}: {out.traceback}\n{out.stderr}"
    assert out.code == 2, f"{c.id}: exit status {out.code}\n{out.stderr}"
    assert len(out.lines) == 1, f"{c.id}: expected one line on stderr, got:\n{out.stderr}"
    line = out.lines[0]
    assert line.startswith("error: "), line
    assert line.isprintable(), f"{c.id}: control characters in {line!r}"
    assert "weights_only=False" not in line and "weights_only` set to `False" not in line, line  # unsafe advice
    assert "Traceback" not in out.stderr
    missing = [s for s in c.expect if s not in line]
    assert not missing, f"{c.id}: {missing} not in: {line}"
    assert not out.changed, f"{c.id}: left on disk {out.changed}"
