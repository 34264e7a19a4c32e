"""Training pairs from the lens library's banks (lensim.data.library_banks): a few crops
per bank from the built-in training photos (lensim.assets.images.available_sample_images;
never an unseen test photo), one pairs folder per bank, resumable.

Each complete bank of the library folder gets ``photos_per_bank`` photos, picked by a seeded
draw from the bank's id (so every bank sees other photos and the choice never depends on
which banks are done), simulated through the bank on the bank's library sensor at
``placements`` positions (centre, middle and edge zones when 3) and cut into ``crops``
crops per placement (lensim.data.pairs.make_dataset: one folder per bank, resumable per
photo).

On disk (``out_dir``)::

    photos/all/<name>.png     the training photos, centre-cropped to photo_size (sharp sRGB)
    photos/<id>/<name>.png    the photos of bank <id> (links into photos/all)
    pairs/<id>/               the bank's pairs folder (lensim.data.pairs' format)

A rerun skips the banks whose pairs folder has its manifest and finishes the others;
banks computed since the last run are added. Held-out lenses are never used unless asked
for (holdout=True makes the evaluation pairs of the held-out lenses instead).
"""

from __future__ import annotations

import os
import random
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lensim.data.library_banks import library_banks
from lensim.data.manifest import MANIFEST
from lensim.errors import InputError


@dataclass(frozen=True)
class LibraryPairsSettings:
    """photos_per_bank: photos simulated per bank; placements: sensor positions per photo;
    crops: crops per placement; size: crop size (pixels, even); photo_size: the photos'
    centre crop (pixels); seed: the photo draw's and the pairs' seed."""

    photos_per_bank: int = 2
    placements: int = 3
    crops: int = 1
    size: int = 128
    photo_size: int = 384
    seed: int = 0

    def check(self) -> None:
        for name in ("photos_per_bank", "placements", "crops"):
            if getattr(self, name) < 1:
                raise InputError(None, name, f"expected at least 1, got {getattr(self, name)}")
        if self.photo_size < self.size:
            raise InputError(None, "photo_size", f"expected at least the crop size {self.size}, got {self.photo_size}")


@dataclass
class LibraryPairsResult:
    """Banks whose pairs were there before, made now, and crops in all."""

    done: int
    made: int
    pairs: int


def training_photos(out_dir: str | Path, size: int) -> list[Path]:
    """The built-in training photos centre-cropped to size x size, written once into
    out_dir/photos/all (atomic writes); their paths, sorted by name."""
    from lensim.assets.images import available_sample_images, write_centre_crops

    paths = write_centre_crops(available_sample_images(), Path(out_dir) / "photos" / "all", size)
    if not paths:
        raise InputError(None, "photos", "no built-in training photo is installed; expected `bash scripts/setup.sh`")
    return sorted(paths)


def bank_photos(ident: str, photos: list[Path], k: int, seed: int) -> list[Path]:
    """The k photos of bank `ident`: a draw seeded by (seed, ident), sorted by name."""
    rng = random.Random(f"{seed}:{ident}")
    return sorted(rng.sample(photos, min(k, len(photos))))


def _link_photos(folder: Path, chosen: list[Path]) -> None:
    """folder holds exactly the chosen photos (hard links, else copies)."""
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.iterdir():
        if stale.name not in {p.name for p in chosen}:
            stale.unlink()
    for p in chosen:
        target = folder / p.name
        if target.exists():
            continue
        try:
            os.link(p, target)
        except OSError:
            shutil.copyfile(p, target)


def pairs_dir(out_dir: str | Path, ident: str) -> Path:
    return Path(out_dir) / "pairs" / ident


def make_library_pairs(
    library_dir: str | Path,
    out_dir: str | Path,
    settings: LibraryPairsSettings | None = None,
    *,
    holdout: bool = False,
    limit: int | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LibraryPairsResult:
    """Pairs for every complete bank of the library folder (module docstring): the
    trainable lenses' banks (holdout False) or the held-out ones' (True); limit: at most
    this many banks' pairs in this call; workers > 1 (no scheduler): a local Dask cluster of
    that many processes makes whole banks' pairs side by side; scheduler: each bank's
    photos are spread over the cluster at that address, one bank after another.
    progress(done, total) counts banks."""
    s = settings or LibraryPairsSettings()
    s.check()
    banks = library_banks(library_dir, holdout=holdout)
    if not banks:
        raise InputError(str(library_dir), None, "holds no complete library bank; expected a library bank build first")
    photos = training_photos(out_dir, s.photo_size)
    result = LibraryPairsResult(0, 0, 0)
    jobs: list[_PairsJob] = []
    for planned, bdir, sensor_path in banks:
        target = pairs_dir(out_dir, planned.id)
        if (target / MANIFEST).exists():
            result.done += 1
        elif limit is None or len(jobs) < limit:
            folder = Path(out_dir) / "photos" / planned.id
            _link_photos(folder, bank_photos(planned.id, photos, s.photos_per_bank, s.seed))
            jobs.append(_PairsJob(folder, target, bdir, sensor_path, s))
    settled = result.done
    if progress:
        progress(settled, len(banks))

    def made(_: object, pairs: int) -> None:
        nonlocal settled
        result.made += 1
        result.pairs += pairs
        settled += 1
        if progress:
            progress(settled, len(banks))

    from lensim.workers import run_whole_jobs

    run_whole_jobs(_bank_pairs, jobs, workers, scheduler, made)
    if progress:
        progress(len(banks), len(banks))
    return result


@dataclass(frozen=True)
class _PairsJob:
    """One bank's pairs: its photos' folder, the pairs folder, the bank folder, its sensor
    file and the settings."""

    photos: Path
    target: Path
    bank: Path
    sensor: Path
    settings: LibraryPairsSettings


def _bank_pairs(job: _PairsJob, workers: int = 1, scheduler: str | None = None) -> int:
    """Make one bank's pairs folder (lensim.data.pairs.make_dataset); the pairs made."""
    from lensim.data.pairs import make_dataset
    from lensim.psf.bank import PSFBank
    from lensim.sensor.profile import load_sensor

    s = job.settings
    manifest = make_dataset(
        job.photos,
        job.target,
        PSFBank.load(job.bank),
        str(job.sensor),
        load_sensor(job.sensor),
        crops=s.crops,
        size=s.size,
        seed=s.seed,
        placements=s.placements,
        workers=workers,
        scheduler=scheduler,
    )
    return int(manifest["pairs"])


def library_pair_folders(out_dir: str | Path) -> list[Path]:
    """The complete pairs folders under out_dir/pairs, sorted by bank id."""
    root = Path(out_dir) / "pairs"
    return sorted(p for p in root.iterdir() if (p / MANIFEST).exists()) if root.is_dir() else []
