"""Training-pair generation (the paper's "Simulate Training Data").

Each sharp photo is placed on the sensor at its native scale (one image pixel = one sensor
pixel; a random crop of it if it is larger than the sensor) at `placements` seeded random
positions, simulated through the lens and sensor at each (lensim.render.pipeline, a fresh
capture draw each time), and cut into `crops` aligned pairs of size x size pixels per placement:
the simulated camera image (network input) and the original (target), each with the
absolute sensor position of its top-left pixel, so a network can be fed field-of-view
channels.

Placement k of K is uniformly random among the positions that keep the photo on the
sensor with its centre at a normalized field radius (1 at the sensor corner) in
[k/K, (k+1)/K). With K = 3 every photo is seen in the centre, middle and edge zones of
lensim.evaluate (as far as its size allows), so a held-out photo scores every zone; one
uniform position leaves small photos on a large sensor mostly in the middle zone.

Exposure (``exposure_ev`` = (lo, hi) stops, off at (0, 0)): each placement first draws an
exposure uniformly in [lo, hi] and scales the photo's linear light by 2**ev (the scene and
so the target get darker or brighter; lensim.sensor.isp.expose); the camera then adds
its noise in absolute raw units, so a darker scene is noisier relative to its signal. The
colour temperature and the noise levels are drawn per capture already
(lensim.render.pipeline); this widens the brightness range the pairs cover.

Determinism: image i's random stream is seeded from (seed, i, file name); results do not
depend on worker count or order. Resumability: an image is done when its JSON record
exists and reads back as this image's and its crop files are whole (a corrupt record, or a
crop removed or cut short, is recomputed with its photo); the record is written
last, atomically, after its PNGs (also atomic), so a killed job is re-run from the first
unfinished image. The manifest (settings + every record) is rewritten at the end. One
writer at a time: the folder is locked (lensim.io.folder_lock) while pairs are made.

Parallelism (lensim.workers.run_jobs, the engine of `psf bank` too): `workers > 1` starts
a local dask.distributed cluster (one thread per worker process); `scheduler` connects to
an existing Dask cluster instead.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from lensim.data.manifest import FORMAT, MANIFEST
from lensim.errors import InputError, ParameterError
from lensim.images import READ_SUFFIXES, read_image, write_image
from lensim.io import atomic_write_json, folder_lock, read_json
from lensim.psf.bank import GridBank, PSFBank
from lensim.psf.bank.store import load_bank_cached
from lensim.render.mapping import native_mapping
from lensim.render.pipeline import simulate
from lensim.sensor.isp import expose
from lensim.sensor.profile import SensorProfile, load_sensor
from lensim.workers import run_jobs


@dataclass
class PairJob:
    """Everything one worker needs for one image (picklable)."""

    index: int
    path: str
    out_dir: str
    bank_dir: str | dict[str, str]  # a bank's folder, or a lens with poses' banks' (PosedBanks)
    sensor: str
    seed: int
    crops: int
    size: int
    noise: bool
    demosaic: str
    placements: int = 1
    exposure_ev: tuple[float, float] = (0.0, 0.0)
    settings: dict | None = None  # the bank's shooting settings (describe()), recorded when known
    grid_setting: int | None = None  # the setting's index in a grid of banks
    tolerance_draw: int | None = None  # the perturbed lens's index in a ToleranceBanks


#: A pairs manifest's "stage_bank" when each record's Wiener stage (lensim.restore.psf_stage)
#: uses its own tolerance draw's bank, tolerances.draws[record["tolerance_draw"]].bank.
STAGE_PER_DRAW = "tolerance_draw"
#: A pairs manifest's "stage_bank" when every record's Wiener stage is the tolerance-robust
#: one over all the draws (lensim.restore.psf_stage.wiener_channels with the draws' banks,
#: each draw's posed banks where it has them): what a restoration of a unit whose draw is
#: unknown can compute.
STAGE_ROBUST = "tolerance_robust"


@dataclass
class ToleranceBanks:
    """Banks of perturbed copies of one lens (lensim.calibrate.tolerances.drawn_lens),
    one per draw: each photo is simulated through one of them, every draw equally often
    (seeded, as grid settings are: grid_settings_of_photos). lens: the nominal lens (native
    mapping); tolerances: the tolerance file; draws: per bank {"seed", "draw", "parameters"};
    nominal: the nominal lens's bank, the pairs' "bank": what a restoration has at inference,
    where the unit's draw is unknown. The PSF-informed network's Wiener stage of each pair
    uses the bank of its own draw (the manifest's "stage_bank": STAGE_PER_DRAW;
    lensim.restore.psf_stage.stage_bank_entry). posed: per draw, the banks its photos are
    simulated through instead of banks[k] (a draw with decentres or tilts has poses:
    PosedBanks), recorded as the draw's "posed_banks"; its Wiener stage uses them too
    (lensim.evaluate.harness.record_banks). nominal_posed: a nominal lens with poses' posed
    banks (lensim.render.posed.sensor_banks; tolerances about an as-built lens), the pairs'
    "posed_banks": what a restoration uses instead of ``nominal``."""

    banks: list[PSFBank]
    lens: dict
    tolerances: str
    draws: list[dict]
    nominal: PSFBank
    posed: list[PosedBanks] | None = None
    nominal_posed: dict[str, PSFBank] | None = None


@dataclass
class PosedBanks:
    """The banks that render a lens with poses (lensim.render.posed.posed_banks: one per
    sensor quadrant and its mirrored lens's), each pixel of a photo simulated through its
    own (lensim.render.pipeline.simulate). stage: the lens's bank along +y (turned to
    every azimuth), the pairs' "bank" (kept for what reads one bank: a restoration of the
    lens, its Wiener stage and the oracles use "posed_banks", the folders of ``banks``:
    lensim.render.posed.sensor_banks, lensim.evaluate.harness.record_banks). In
    ToleranceBanks.posed, draw k's photos are simulated through posed[k] (and its Wiener
    stage too)."""

    banks: dict[str, PSFBank]
    stage: PSFBank

    def dirs(self) -> dict[str, str]:
        if any(b.directory is None for b in self.banks.values()):
            raise InputError(None, "bank", "expected banks stored on disk (workers load them)")
        return {k: str(b.directory) for k, b in self.banks.items()}


def image_seed(seed: int, index: int, name: str) -> int:
    """A 63-bit seed for one image, stable across runs and machines."""
    h = hashlib.sha256(f"{seed}:{index}:{name}".encode()).digest()
    return int.from_bytes(h[:8], "little") >> 1


def list_images(folder: str | Path) -> list[Path]:
    """Photos in a folder (sorted by name); a clear error if there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(str(folder), None, "no such folder; expected a folder of sharp photos")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in READ_SUFFIXES)
    if not files:
        raise InputError(str(folder), None, f"holds no images; expected {', '.join(READ_SUFFIXES)} files")
    return files


def record_path(out_dir: Path, index: int) -> Path:
    return out_dir / "records" / f"{index:06d}.json"


def crop_capture(record: Mapping[str, Any], crop: Mapping[str, Any]) -> dict | None:
    """The capture draws (colour temperature, noise levels) behind one crop of a record."""
    if "placements" in record:
        return record["placements"][int(crop.get("placement", 0))].get("capture")
    return record.get("capture")


def place_on_sensor(
    h: int, w: int, sensor: SensorProfile, k: int, placements: int, gen: torch.Generator, tries: int = 256
) -> tuple[int, int]:
    """Top-left sensor pixel (even, to keep the Bayer phase) of an h x w photo for placement
    k of `placements`: uniformly random among the positions that keep the photo on the
    sensor and put its centre at a normalized radius in [k, k + 1) / placements (the
    position nearest that band when none of `tries` draws falls in it)."""
    u = torch.rand(tries, 2, generator=gen, dtype=torch.float64)
    top = u[:, 0] * (sensor.height - h)
    left = u[:, 1] * (sensor.width - w)
    half_diag = math.hypot(sensor.width, sensor.height) / 2
    rho = torch.hypot(top + (h - sensor.height) / 2, left + (w - sensor.width) / 2) / half_diag
    lo, hi = k / placements, (k + 1) / placements
    inside = ((rho >= lo) & (rho < hi)).nonzero()
    i = int(inside[0]) if len(inside) else int((rho - (lo + hi) / 2).abs().argmin())
    return 2 * int(top[i] / 2), 2 * int(left[i] / 2)


def draw_exposure(ev_range: tuple[float, float], gen: torch.Generator) -> float:
    """An exposure change in stops, uniform in ev_range; no draw (the generator untouched)
    when the range is a single value."""
    lo, hi = ev_range
    if lo == hi:
        return float(lo)
    return lo + (hi - lo) * float(torch.rand(1, generator=gen, dtype=torch.float64)[0])


def make_pairs_for_image(job: PairJob) -> dict:
    """Simulate one photo and write its crops; returns (and writes) its record."""
    torch.set_num_threads(1)
    out = Path(job.out_dir)
    sensor = load_sensor(job.sensor)
    bank: PSFBank | dict[str, PSFBank]  # once per process, not per photo
    if isinstance(job.bank_dir, dict):
        bank = {k: load_bank_cached(d) for k, d in job.bank_dir.items()}
    else:
        bank = load_bank_cached(job.bank_dir)
    img, bits = read_image(job.path)
    gen = torch.Generator().manual_seed(job.seed)
    _, h, w = img.shape
    if h < job.size or w < job.size:
        raise InputError(
            job.path,
            "size",
            f"image is {w}x{h}; expected at least {job.size}x{job.size} pixels for {job.size}-pixel crops",
        )
    # a random crop of the photo if it is larger than the sensor
    h2, w2 = min(h, sensor.height), min(w, sensor.width)
    y = int(torch.randint(0, h - h2 + 1, (1,), generator=gen))
    x = int(torch.randint(0, w - w2 + 1, (1,), generator=gen))
    img = img[:, y : y + h2, x : x + w2]
    crops: list[dict] = []
    placed: list[dict] = []
    stem = f"{job.index:06d}"
    for p in range(job.placements):
        top, left = place_on_sensor(h2, w2, sensor, p, job.placements, gen)
        mapping = native_mapping(h2, w2, sensor, top, left)
        ev = draw_exposure(job.exposure_ev, gen)
        scene = expose(img, ev)
        sim, params = simulate(scene, bank, sensor, gen, noise=job.noise, demosaic=job.demosaic, mapping=mapping)
        placed.append(
            {
                "sensor_top": top,
                "sensor_left": left,
                "capture": params.to_dict(),
                **({"exposure_ev": ev} if job.exposure_ev != (0.0, 0.0) else {}),
            }
        )
        for _ in range(job.crops):
            cy = int(torch.randint(0, h2 - job.size + 1, (1,), generator=gen))
            cx = int(torch.randint(0, w2 - job.size + 1, (1,), generator=gen))
            name_in = f"pairs/{stem}_{len(crops):03d}_input.png"
            name_gt = f"pairs/{stem}_{len(crops):03d}_target.png"
            write_image(out / name_in, sim[:, cy : cy + job.size, cx : cx + job.size], 8)
            write_image(out / name_gt, scene[:, cy : cy + job.size, cx : cx + job.size], 8)
            crops.append(
                {"input": name_in, "target": name_gt, "sensor_top": top + cy, "sensor_left": left + cx, "placement": p}
            )
    record = {
        "index": job.index,
        "source": job.path,
        "seed": job.seed,
        "source_crop": [y, x, h2, w2],
        "placements": placed,
        "crops": crops,
    }
    if job.settings is not None:
        record["settings"] = job.settings
    if job.grid_setting is not None:
        record["grid_setting"] = job.grid_setting
    if job.tolerance_draw is not None:
        record["tolerance_draw"] = job.tolerance_draw
    atomic_write_json(record_path(out, job.index), record)
    return record


def grid_settings_of_photos(seed: int, photos: int, settings: int) -> list[int]:
    """The grid setting (index) of each photo: photos in blocks of `settings`, each block
    a seeded random permutation of the settings, so every setting gets the same number of
    photos (within one) and the draw depends on the seed and the photo's index only."""
    out: list[int] = []
    for block in range(-(-photos // settings)):
        order = list(range(settings))
        random.Random(image_seed(seed, block, "grid settings")).shuffle(order)
        out.extend(order)
    return out[:photos]


@dataclass
class _BankUse:
    """Which bank each photo is simulated with, and what the dataset records of it."""

    dirs: list[str | dict[str, str]]  # bank folder per photo (a lens with poses: PosedBanks.dirs)
    settings: list[dict | None]  # shooting settings per photo (describe()'s), None when unknown
    grid_settings: list[int | None]  # the setting's index per photo in a grid
    recorded: dict  # what settings.json records of the bank(s)
    pitch_um: float
    where: str  # the bank's or grid's folder


def _tolerance_use(banks: ToleranceBanks, photos: int, seed: int) -> _BankUse:
    """Each photo's perturbed lens's bank (balanced and seeded); grid_settings holds the
    draw's index per photo. The recorded "bank" is the nominal lens's (ToleranceBanks),
    each draw's bank is in "tolerances", and "stage_bank" says that each pair's Wiener
    stage uses its draw's."""
    nominal_posed = list((banks.nominal_posed or {}).values())
    if any(b.directory is None for b in [*banks.banks, banks.nominal, *nominal_posed]) or not banks.banks:
        raise InputError(None, "bank", "expected banks stored on disk (workers load them)")
    picks = grid_settings_of_photos(seed, photos, len(banks.banks))
    dirs = [str(b.directory) for b in banks.banks]
    posed = [p.dirs() for p in banks.posed] if banks.posed is not None else None
    recorded = {
        "lens": banks.lens,
        "bank": str(banks.nominal.directory),
        "stage_bank": STAGE_PER_DRAW,
        "tolerances": {
            "file": banks.tolerances,
            "draws": [
                {**d, "bank": b, **({"posed_banks": posed[k]} if posed else {})}
                for k, (d, b) in enumerate(zip(banks.draws, dirs, strict=True))
            ],
        },
    }
    if banks.nominal_posed:
        recorded["posed_banks"] = {k: str(b.directory) for k, b in banks.nominal_posed.items()}
    render = posed if posed else dirs
    return _BankUse(
        [render[k] for k in picks], [None] * photos, list(picks), recorded, banks.banks[0].pixel_pitch_um, dirs[0]
    )


def _bank_use(bank: PSFBank | GridBank | ToleranceBanks | PosedBanks, photos: int, seed: int) -> _BankUse:
    """A single bank for every photo, or a grid's banks drawn per photo
    (grid_settings_of_photos); records carry the bank's resolved settings when its
    manifest describes them (a grid's, or a bank of one setting). A lens with poses'
    banks (PosedBanks) for every photo, the recorded "bank" their stage's."""
    if isinstance(bank, ToleranceBanks):
        return _tolerance_use(bank, photos, seed)
    if isinstance(bank, PosedBanks):
        use = _bank_use(bank.stage, photos, seed)
        use.dirs = [bank.dirs()] * photos
        use.recorded["posed_banks"] = bank.dirs()
        return use
    if isinstance(bank, GridBank):
        picks = grid_settings_of_photos(seed, photos, len(bank))
        entries = bank.manifest["settings"]
        recorded = {
            "lens": bank.lens,
            "bank": str(bank.directory),
            "grid": [{"bank": e["bank"], "resolved": e["resolved"]} for e in entries],
        }
        return _BankUse(
            [str(bank.bank_dir(k)) for k in picks],
            [entries[k]["resolved"] for k in picks],
            list(picks),
            recorded,
            float(bank.manifest["bank"]["pixel_pitch_um"]),
            str(bank.directory),
        )
    if bank.directory is None:
        raise InputError(None, "bank", "expected a bank stored on disk (workers load it)")
    shooting = bank.manifest.get("shooting")
    resolved = shooting.get("resolved") if isinstance(shooting, dict) else None
    return _BankUse(
        [str(bank.directory)] * photos,
        [resolved] * photos,
        [None] * photos,
        {"lens": bank.manifest.get("lens"), "bank": str(bank.directory)},
        bank.pixel_pitch_um,
        str(bank.directory),
    )


def make_dataset(
    sharp_dir: str | Path,
    out_dir: str | Path,
    bank: PSFBank | GridBank | ToleranceBanks | PosedBanks,
    sensor_name: str,
    sensor: SensorProfile,
    crops: int = 8,
    size: int = 256,
    seed: int = 0,
    placements: int = 1,
    noise: bool = True,
    demosaic: str = "ahd",
    workers: int = 1,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    exposure_ev: tuple[float, float] = (0.0, 0.0),
) -> dict:
    """Generate pairs for every photo in sharp_dir into out_dir (resumable); returns the
    manifest. `crops` crops are cut at each of a photo's `placements` sensor positions.
    The bank must be at the sensor's native pitch and cover its diagonal. A grid of banks
    (lensim.psf.bank.GridBank) gives each photo one of its settings (balanced and seeded:
    grid_settings_of_photos); its records carry "settings" (describe()'s numbers) and
    "grid_setting" (the index), the manifest a "grid" summary. ToleranceBanks (perturbed
    lenses) likewise: records carry "tolerance_draw", the manifest "tolerances" (each
    draw's parameters, bank and photo count), its "bank" is the nominal lens's and its
    "stage_bank" STAGE_PER_DRAW (ToleranceBanks); with ToleranceBanks.posed each draw's
    photos go through its PosedBanks (the draw's "posed_banks"). A lens with poses
    (PosedBanks): every photo through its quadrants' banks, the manifest's "bank" the
    stage's and "posed_banks" the folders. exposure_ev: the range of
    exposure changes in stops drawn per placement (module docstring)."""
    if size < 16 or size % 2:
        raise InputError(None, "size", f"expected an even crop size of at least 16 pixels, got {size}")
    if crops < 1:
        raise InputError(None, "crops", f"expected at least one crop per image, got {crops}")
    if placements < 1:
        raise InputError(None, "placements", f"expected at least one placement per image, got {placements}")
    exposure_ev = (float(exposure_ev[0]), float(exposure_ev[1]))
    if not (math.isfinite(exposure_ev[0]) and math.isfinite(exposure_ev[1]) and exposure_ev[0] <= exposure_ev[1]):
        raise InputError(None, "exposure_ev", f"expected (low, high) stops with low <= high, got {exposure_ev}")
    files = list_images(sharp_dir)
    use = _bank_use(bank, len(files), seed)
    if abs(use.pitch_um / sensor.pixel_pitch_um - 1) > 1e-6:
        raise InputError(
            use.where,
            "pixel_pitch_um",
            f"the bank is at {use.pitch_um:g} um; expected "
            f"the pitch of the sensor {sensor_name} ({sensor.pixel_pitch_um:g} um)",
        )
    check_photos(files, size)
    out = Path(out_dir)
    settings = {
        "format": FORMAT,
        "seed": seed,
        "crops": crops,
        "placements": placements,
        "size": size,
        "noise": noise,
        "demosaic": demosaic,
        "sensor": sensor.to_dict(),
        "sensor_name": sensor_name,
        **use.recorded,
        "sources": [str(p) for p in files],
    }
    if exposure_ev != (0.0, 0.0):
        settings["exposure_ev"] = list(exposure_ev)  # absent when off: folders made before keep resuming
    jobs = [
        PairJob(
            i,
            str(p),
            str(out),
            use.dirs[i],
            sensor_name,
            image_seed(seed, i, p.name),
            crops,
            size,
            noise,
            demosaic,
            placements,
            exposure_ev,
            use.settings[i],
            None if isinstance(bank, ToleranceBanks) else use.grid_settings[i],
            use.grid_settings[i] if isinstance(bank, ToleranceBanks) else None,
        )
        for i, p in enumerate(files)
    ]
    with folder_lock(out):
        claimed = _claim_folder(out, settings)
        todo = [j for j in jobs if _read_record(j) is None]
        try:
            _run_jobs(todo, len(jobs), workers, scheduler, progress)
        except BaseException:
            if claimed and not any(record_path(out, j.index).exists() for j in jobs):
                _release_folder(out)  # nothing done: a corrected rerun starts afresh
            raise
        records = [read_json(record_path(out, j.index), "photo record") for j in jobs]
        manifest = {**settings, "records": records, "pairs": sum(len(r["crops"]) for r in records)}
        if isinstance(bank, GridBank):
            manifest["grid"] = [{**e, "photos": use.grid_settings.count(k)} for k, e in enumerate(settings["grid"])]
        if isinstance(bank, ToleranceBanks):
            draws = [{**d, "photos": use.grid_settings.count(k)} for k, d in enumerate(settings["tolerances"]["draws"])]
            manifest["tolerances"] = {**settings["tolerances"], "draws": draws}
        atomic_write_json(out / MANIFEST, manifest)
    return manifest


def _read_record(job: PairJob) -> dict | None:
    """The finished record of a job's photo, or None when it is still to be made: missing,
    or unreadable or not this job's (a corrupt per-photo record is recomputed)."""
    path = record_path(Path(job.out_dir), job.index)
    if not path.exists():
        return None
    try:
        record = read_json(path, "photo record")
    except InputError:
        return None
    ok = (
        isinstance(record, dict)
        and record.get("index") == job.index
        and record.get("seed") == job.seed
        and isinstance(record.get("crops"), list)
    )
    return record if ok and _crops_whole(Path(job.out_dir), record["crops"]) else None


_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # a PNG file's last chunk, IEND (PNG spec 11.2.5)


def _crops_whole(out: Path, crops: list) -> bool:
    """Whether every crop file of a record is there and ends as a whole PNG does (a crop
    removed, emptied or cut short since is made again with its photo); no decoding."""
    for crop in crops:
        for key in ("input", "target"):
            name = crop.get(key) if isinstance(crop, dict) else None
            try:
                with open(out / str(name), "rb") as fh:
                    fh.seek(-len(_PNG_END), os.SEEK_END)
                    if fh.read() != _PNG_END:
                        return False
            except (OSError, TypeError):
                return False
    return True


def check_photos(files: list[Path], size: int) -> None:
    """Every photo decodes and holds a size x size crop, before any output (one-line
    errors naming the photo)."""
    for path in files:
        img, _ = read_image(path)
        _, h, w = img.shape
        if h < size or w < size:
            raise ParameterError(
                str(path),
                "size",
                f"image is {w}x{h}; expected at least {size}x{size} pixels for {size}-pixel crops",
            )


def _claim_folder(out: Path, settings: dict) -> bool:
    """Record the dataset's settings in OUT/settings.json, or check them against those
    already recorded there (a one-line InputError naming what differs; the bank folders
    may move). True when this call made the record (a new dataset)."""
    path = out / "settings.json"
    if not path.exists():
        atomic_write_json(path, settings)
        return True
    prev = read_json(path, "pairs settings record")
    if not isinstance(prev, dict) or prev.get("format") != FORMAT:
        raise InputError(
            str(path),
            "format",
            f"expected the {FORMAT!r} settings record of `lensim dataset make`; "
            "delete the file (or choose a new output folder) to start afresh",
        )
    # the bank folders may move; an older tolerance folder (draw 0's bank as "bank", no
    # "stage_bank") resumes, its photos being the same, and gets today's manifest
    diff = sorted(k for k in settings if k not in ("bank", "stage_bank", "posed_banks") and prev.get(k) != settings[k])
    if ("posed_banks" in prev) != ("posed_banks" in settings):  # their folders may move, not come or go
        diff.append("posed_banks")
    if diff:
        raise InputError(
            str(out),
            ", ".join(diff),
            "differs from the dataset already in this folder; expected the "
            "same settings to resume, or a new output folder",
        )
    return False


def _release_folder(out: Path) -> None:
    """Undo a claim that produced nothing: settings.json and the empty records and pairs
    folders (folder_lock removes OUT itself when it made it and it is left empty)."""
    (out / "settings.json").unlink(missing_ok=True)
    for folder in (out / "records", out / "pairs"):
        with contextlib.suppress(OSError):
            folder.rmdir()  # only when empty


def _run_jobs(
    todo: list[PairJob], total: int, workers: int, scheduler: str | None, progress: Callable[[int, int], None] | None
) -> None:
    """Run the unfinished jobs through lensim.workers.run_jobs (here, on a local Dask
    cluster of ``workers`` processes, or on the one at ``scheduler``); progress(done,
    total) counts photos, the ones finished before included."""
    done = total - len(todo)
    if progress:
        progress(done, total)

    def finished(_job: PairJob, _record: dict) -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, total)

    run_jobs(make_pairs_for_image, todo, workers, scheduler, finished)
