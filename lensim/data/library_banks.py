"""The lens library's PSF banks: every library lens at several shooting settings on two
pixel pitches, computed through lensim.psf.bank.get_banks (here, on local Dask workers or
on a cluster by address), resumable.

The plan (:func:`bank_plan`): each library entry (lensim.assets.library) at

* two F-numbers: wide open (the entry's F-number) and two stops down (twice it);
* two focus distances: infinity and a near distance of 20 focal lengths (at least 0.1 m and
  twice the lens's length);
* two pixel pitches: the entry is used on a 3:2 sensor of its own format (the largest that
  its image circle covers, at most full frame, 21.63 mm half diagonal), at 6000 and at
  4000 pixels across (a 24 MP and a 10 MP sensor of that format), so the blur in pixels is
  what a camera built around that lens would record (pitches at least 0.7 and 1.05 um:
  a tiny image circle goes on a sensor of fewer pixels).

44 entries x 2 x 2 x 2 = 352 banks. The settings of every library bank are
:data:`LIBRARY_BANK_SETTINGS`: coarser than the demo's (6 fields, 5 wavelengths, 64 pupil
samples, kernels of at most 31 pixels; benchmarks/library_banks.py measures what that
costs against the demo's settings). A bank whose spot outgrows the window 64 pupil samples
resolve without wrap-around is computed with the samples its kernel needs (at most
:data:`MAX_PUPIL_SAMPLES`), and only beyond them with geometric PSFs.

On disk (``out_dir``)::

    plan.json                 the plan (every bank's id, lens, pitch, F-number, focus, sensor base)
    banks/<id>/               each bank (lensim.psf.bank's folder format; resumable per field)
    sensors/<id>.yaml         the sensor profile each bank's pairs are made on: the base profile
                              (phone for phone lenses, full frame otherwise) at the bank's
                              pitch, its resolution fitted inside the bank's field; written
                              after the bank is complete, so it marks the bank done
    failed/<id>.json          a bank the lens cannot give at that setting (the one-line reason);
                              skipped on a rerun (delete the file to try again)

A rerun skips the banks done and failed and finishes the rest (a bank killed half way
keeps its finished fields). Units: pitches um, distances m, lengths mm.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from lensim.assets.library import LibraryLens, list_lenses, load_library_lens
from lensim.errors import InputError, OutputError, PupilSamplingError
from lensim.io import atomic_write_json, atomic_write_text, read_json
from lensim.psf.bank import BankRequest, BankSettings, PSFBank, get_banks
from lensim.psf.bank.settings import PUPIL_TRIES, pupil_samples_for
from lensim.psf.bank.store import MANIFEST

#: the bank settings of every library bank (see the module docstring)
LIBRARY_BANK_SETTINGS = BankSettings(
    fields=6,
    wavelengths_nm=(430.0, 490.0, 550.0, 610.0, 670.0),
    pupil_samples=64,
    kernel_limit=31,
    ri_samples=8,
)
#: the most pupil samples a library bank is raised to where a spot exceeds the window that
#: LIBRARY_BANK_SETTINGS' samples resolve without wrap-around (beyond: geometric PSFs)
MAX_PUPIL_SAMPLES = 512
#: sensor widths (pixels) the library puts each lens on: two pixel pitches per lens
SENSOR_WIDTHS_PX = (6000, 4000)
#: the largest sensor half diagonal (mm) a library lens is put on: full frame
MAX_HALF_DIAGONAL_MM = 21.63
#: how far down from wide open the second F-number is (a factor: 2 = two stops)
STOPPED_DOWN = 2.0
#: near focus distance in focal lengths, and its floors: in m, and in lengths of the lens
#: (first vertex to image plane: the 197 mm fisheye of f = 5.2 mm would otherwise focus at
#: 0.104 m, inside its own front element)
NEAR_FOCAL_LENGTHS = 20.0
NEAR_MIN_M = 0.1
NEAR_MIN_TRACKS = 2.0
#: the smallest pitch (um) of the first and of the second width: tiny image circles
#: (long catadioptrics) go on sensors of fewer pixels, not on pixels smaller than a phone's
MIN_PITCH_UM = (0.7, 1.05)
#: what the format's half diagonal keeps free of the lens's image circle (fraction)
IMAGE_CIRCLE_MARGIN = 0.97
PLAN = "plan.json"
_ASPECT = (3.0, 2.0)


@dataclass(frozen=True)
class PlannedBank:
    """One bank of the library plan. id: its folder name; lens: the library entry's name;
    pitch_um: pixel pitch (um); fno: F-number (image space, at infinity); focus_m: focus
    distance (m, math.inf for infinity); base_sensor: the built-in sensor profile its
    sensor is made from; width_px: the sensor width it was planned for (pixels)."""

    id: str
    lens: str
    family: str
    holdout: bool
    pitch_um: float
    fno: float
    focus_m: float
    base_sensor: str
    width_px: int

    def to_dict(self) -> dict:
        d = asdict(self)
        d["focus_m"] = "inf" if math.isinf(self.focus_m) else self.focus_m
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PlannedBank:
        return cls(**{**d, "focus_m": math.inf if d["focus_m"] == "inf" else float(d["focus_m"])})


def format_half_diagonal_mm(entry: LibraryLens) -> float:
    """The half diagonal (mm) of the 3:2 format the entry is used on: its image circle less
    a margin, at most full frame."""
    return min(MAX_HALF_DIAGONAL_MM, IMAGE_CIRCLE_MARGIN * entry.image_height_mm)


def plan_pitches(entry: LibraryLens) -> list[tuple[int, float]]:
    """(sensor width in pixels, pitch in um rounded to 0.01 um) for each of SENSOR_WIDTHS_PX,
    the pitch at least MIN_PITCH_UM."""
    a, b = _ASPECT
    width_mm = 2.0 * format_half_diagonal_mm(entry) * a / math.hypot(a, b)
    return [(n, max(low, round(width_mm / n * 1e3, 2))) for n, low in zip(SENSOR_WIDTHS_PX, MIN_PITCH_UM, strict=True)]


def near_focus_m(entry: LibraryLens) -> float:
    """The near focus distance (m, from the image plane): NEAR_FOCAL_LENGTHS focal lengths,
    at least NEAR_MIN_M and NEAR_MIN_TRACKS lengths of the lens (entry.track_mm)."""
    near_mm = max(1000.0 * NEAR_MIN_M, NEAR_FOCAL_LENGTHS * entry.focal_mm, NEAR_MIN_TRACKS * entry.track_mm)
    return round(near_mm / 1000.0, 3)


def bank_id(lens: str, pitch_um: float, fno: float, focus_m: float) -> str:
    """A bank's folder name: lens, pitch, F-number and focus (inf or metres)."""
    focus = "inf" if math.isinf(focus_m) else f"{focus_m:g}m"
    return f"{lens}__p{pitch_um:g}_f{fno:g}_{focus}"


def bank_plan(entries: Sequence[LibraryLens] | None = None) -> list[PlannedBank]:
    """The library's banks (module docstring), ordered in rounds: the first bank of every
    lens, then the second of every lens, ... so a partly computed library covers every lens."""
    entries = list_lenses() if entries is None else list(entries)
    per_lens: list[list[PlannedBank]] = []
    for e in entries:
        base = "phone" if e.family == "phone" else "fullframe_dslr"
        banks = []
        for focus in (math.inf, near_focus_m(e)):
            for fno in (e.fno, round(e.fno * STOPPED_DOWN, 1)):
                for width, pitch in plan_pitches(e):
                    ident = bank_id(e.name, pitch, fno, focus)
                    banks.append(PlannedBank(ident, e.name, e.family, e.holdout, pitch, fno, focus, base, width))
        per_lens.append(banks)
    return [lens_banks[k] for k in range(max(map(len, per_lens), default=0)) for lens_banks in per_lens]


def write_plan(out_dir: str | Path, plan: Sequence[PlannedBank]) -> None:
    """Write plan.json into out_dir (atomically); a folder holding another plan is refused."""
    out = Path(out_dir)
    data = {"settings": LIBRARY_BANK_SETTINGS.key_options(), "banks": [b.to_dict() for b in plan]}
    if (out / PLAN).exists():
        old = read_json(out / PLAN, "library plan")
        if old.get("settings") != data["settings"]:
            raise InputError(
                str(out / PLAN), "settings", "holds a library of other bank settings; expected a new folder"
            )
        known = {b["id"] for b in old.get("banks", [])}
        data["banks"] = old["banks"] + [b for b in data["banks"] if b["id"] not in known]
    atomic_write_json(out / PLAN, data)


def read_plan(out_dir: str | Path) -> list[PlannedBank]:
    """The plan in out_dir's plan.json."""
    path = Path(out_dir) / PLAN
    if not path.exists():
        raise InputError(str(path), None, "no library plan here; expected a folder made by the library's bank build")
    return [PlannedBank.from_dict(b) for b in read_json(path, "library plan")["banks"]]


def sensor_file(out_dir: str | Path, ident: str) -> Path:
    """The sensor profile of bank `ident` (exists once the bank is complete)."""
    return Path(out_dir) / "sensors" / f"{ident}.yaml"


def bank_dir(out_dir: str | Path, ident: str) -> Path:
    return Path(out_dir) / "banks" / ident


def _failed_file(out_dir: str | Path, ident: str) -> Path:
    return Path(out_dir) / "failed" / f"{ident}.json"


def bank_state(out_dir: str | Path, ident: str) -> str:
    """'done', 'failed' or 'todo'."""
    if sensor_file(out_dir, ident).exists():
        return "done"
    return "failed" if _failed_file(out_dir, ident).exists() else "todo"


def library_sensor(bank: PSFBank, planned: PlannedBank) -> dict:
    """The sensor profile mapping of a library bank: the base profile at the bank's pitch,
    3:2, the largest even resolution whose half diagonal the bank's field covers (within 1 %)
    and at most MAX_HALF_DIAGONAL_MM."""
    import yaml

    from lensim.sensor.profile import sensor_path

    base = sensor_path(planned.base_sensor)
    assert base is not None, planned.base_sensor
    data = yaml.safe_load(base.read_text(encoding="utf-8"))
    half = min(MAX_HALF_DIAGONAL_MM, 0.99 * float(bank.radii_mm[-1]))
    a, b = _ASPECT
    width = 2 * int(2.0 * half * a / math.hypot(a, b) / (planned.pitch_um * 1e-3) / 2)
    height = 2 * int(width * b / a / 2)
    data.update(
        name=f"{data['name']} at {planned.pitch_um:g} um, {width}x{height} (library: {planned.lens})",
        pixel_pitch_um=planned.pitch_um,
        resolution=[width, height],
    )
    return data


def _request(out_dir: Path, planned: PlannedBank, settings: BankSettings) -> BankRequest:
    from lensim.optics.shooting import ShootingSettings
    from lensim.sensor.profile import load_sensor

    response = load_sensor(planned.base_sensor).spectral_response
    shot = ShootingSettings(fno=planned.fno, focus_m=planned.focus_m)
    lens = load_library_lens(planned.lens)
    return BankRequest(lens, planned.pitch_um, settings, response, shot, bank_dir(out_dir, planned.id))


def _finish(out_dir: Path, planned: PlannedBank, bank: PSFBank) -> None:
    import yaml

    atomic_write_text(sensor_file(out_dir, planned.id), yaml.safe_dump(library_sensor(bank, planned), sort_keys=False))


def _get(out_dir: Path, planned: PlannedBank, settings: BankSettings, workers: int, scheduler: str | None) -> PSFBank:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # wide open within a sixth of a stop: one UserWarning per bank
        bank = get_banks([_request(out_dir, planned, settings)], workers=workers, scheduler=scheduler)[0]
    assert isinstance(bank, PSFBank)
    return bank


def _one(out_dir: Path, planned: PlannedBank, workers: int, scheduler: str | None, settings: BankSettings) -> bool:
    """Compute one bank: Huygens PSFs (settings: LIBRARY_BANK_SETTINGS), with more pupil
    samples (at most MAX_PUPIL_SAMPLES) where the spot is too large for the window that 64
    resolve without wrap-around, or geometric ones where no Huygens window of the kernel
    holds it (the Huygens PSF of such a blur is its geometric envelope); False (and its
    failed/ record) when the lens cannot give the bank at all."""
    folder = bank_dir(out_dir, planned.id)
    manifest = read_json(folder / MANIFEST, "bank manifest") if (folder / MANIFEST).exists() else {}
    if manifest.get("method") == "geometric":
        settings = dataclasses.replace(settings, method="geometric")  # resuming a fallback bank
    elif int(manifest.get("pupil_samples", 0)) > settings.pupil_samples:  # resuming a bank of raised samples
        settings = dataclasses.replace(settings, pupil_samples=int(manifest["pupil_samples"]))
    try:
        try:
            bank = _huygens(out_dir, planned, settings, workers, scheduler)
        except InputError as e:
            if isinstance(e, OutputError) or settings.method == "geometric" or "window" not in e.message:
                raise
            shutil.rmtree(folder, ignore_errors=True)  # its Huygens fields so far: the geometric bank starts afresh
            bank = _get(out_dir, planned, dataclasses.replace(settings, method="geometric"), workers, scheduler)
    except OutputError:
        raise
    except InputError as e:
        if "another lensim run" in e.message:  # the folder is being written (a second build): not the lens's fault
            raise
        atomic_write_json(_failed_file(out_dir, planned.id), {"id": planned.id, "reason": str(e)})
        return False
    _finish(out_dir, planned, bank)
    return True


def _huygens(
    out_dir: Path, planned: PlannedBank, settings: BankSettings, workers: int, scheduler: str | None
) -> PSFBank:
    """The bank at `settings`, again with the pupil samples a field asks for (a
    PupilSamplingError: its spot exceeds the window they resolve without wrap-around) while
    at most MAX_PUPIL_SAMPLES; the folder's fields of fewer samples are dropped first.
    Beyond MAX_PUPIL_SAMPLES the error stands (its message names the window)."""
    folder = bank_dir(out_dir, planned.id)
    for _ in range(PUPIL_TRIES):
        try:
            return _get(out_dir, planned, settings, workers, scheduler)
        except PupilSamplingError as e:
            need = pupil_samples_for(e.needed)
            if settings.method == "geometric" or need <= settings.pupil_samples or need > MAX_PUPIL_SAMPLES:
                raise
            shutil.rmtree(folder, ignore_errors=True)  # fields of the coarser sampling
            settings = dataclasses.replace(settings, pupil_samples=need)
    return _get(out_dir, planned, settings, workers, scheduler)


@dataclass
class LibraryBanksResult:
    """What a library build did: banks done before it and by it, failed (the lens cannot
    give them), and still to do (a limit stopped it)."""

    done: int
    computed: int
    failed: int
    todo: int


def compute_library_banks(
    out_dir: str | Path,
    plan: Sequence[PlannedBank] | None = None,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    limit: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LibraryBanksResult:
    """Compute the library's banks into out_dir (module docstring), resuming: banks done or
    failed are skipped. plan: the banks (None: out_dir's plan.json, else bank_plan());
    workers > 1 (no scheduler): a local Dask cluster of that many processes computes whole
    banks side by side, one bank per worker at a time (the library folder is theirs too);
    scheduler: the cluster at that address computes each bank's fields, one bank after
    another (its workers need not see the folder); limit: at most this many banks in this
    call (None: all); progress(done, total) counts banks (done: complete or failed), once at
    the start and after each bank."""
    if workers < 1:
        raise InputError(None, "workers", f"expected at least 1 worker, got {workers}")
    out = Path(out_dir)
    if plan is None:
        plan = read_plan(out) if (out / PLAN).exists() else bank_plan()
    write_plan(out, plan)
    state = {b.id: bank_state(out, b.id) for b in plan}
    settled = sum(s != "todo" for s in state.values())
    result = LibraryBanksResult(
        sum(s == "done" for s in state.values()), 0, sum(s == "failed" for s in state.values()), 0
    )
    if progress:
        progress(settled, len(plan))
    todo = [b for b in plan if state[b.id] == "todo"]
    if limit is not None and len(todo) > limit:
        result.todo = len(todo) - limit
        todo = todo[:limit]

    def settle(_: object, computed: bool) -> None:
        nonlocal settled
        result.computed += computed
        result.failed += not computed
        settled += 1
        if progress:
            progress(settled, len(plan))

    from lensim.workers import run_whole_jobs

    run_whole_jobs(_bank_job, [(out, planned, LIBRARY_BANK_SETTINGS) for planned in todo], workers, scheduler, settle)
    return result


def _bank_job(job: tuple[Path, PlannedBank, BankSettings], workers: int = 1, scheduler: str | None = None) -> bool:
    """One whole bank (a Dask worker's job with the defaults): _one."""
    out, planned, settings = job
    return _one(out, planned, workers, scheduler, settings)


def library_banks(out_dir: str | Path, holdout: bool | None = None) -> list[tuple[PlannedBank, Path, Path]]:
    """The complete banks of a library folder: (planned bank, bank folder, sensor file),
    in plan order; holdout True/False: only the held-out / only the trainable ones."""
    out = Path(out_dir)
    return [
        (b, bank_dir(out, b.id), sensor_file(out, b.id))
        for b in read_plan(out)
        if (holdout is None or b.holdout == holdout)
        and sensor_file(out, b.id).exists()
        and (bank_dir(out, b.id) / MANIFEST).exists()
    ]
