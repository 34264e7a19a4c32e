"""Restoring camera raw files: develop with the simulator's chain, restore, write.

For each raw file (:func:`restore_raw_files`):

1. read it (lensim.raw.read_raw) and check it against the sensor the network was trained
   for (:func:`check_camera`): the camera's name ('Make Model' or the Model, as `lensim
   sensor from-raw` names a profile) and the active area's size must match, else it is
   refused in one line naming both (``allow_other_camera`` lets it through);
2. develop it in the sensor's orientation (lensim.raw.develop.develop_raw with the
   profile's CCM and the as-shot white balance, no rounding: what the network was trained
   on), in strips of rows to bound memory;
3. restore it tile by tile (lensim.restore.infer.restore_image, the network or its ONNX
   export: lensim.restore.engines), each tile fed the
   field-of-view coordinates of its place on the sensor (:func:`raw_geometry`): the active
   area is the whole sensor, the optical axis at its centre; a DNG written by `lensim
   simulate` records where its frame lay on the sensor (:func:`lensim.raw.dng.read_simulation_record`);
   a network conditioned on shooting settings gets the file's (:func:`raw_settings`: EXIF
   FNumber, SubjectDistance and FocalLength, each replaced by a value given for it;
   lensim.restore.conditioning.photo_vector), checked against the ranges it was trained across;
4. write OUT/<stem>.tif (16-bit sRGB, turned by the file's orientation) and, with
   ``dng``, OUT/<stem>.dng: the restored photo as LinearRaw camera RGB with the raw's
   colour matrix, as-shot white balance, orientation and EXIF (lensim.raw.dng).

Every input is read and checked before the first output is written; outputs that exist
are skipped (a rerun resumes); each file is written atomically. ``workers`` > 1 restores
files side by side on a local Dask cluster (lensim.workers.run_jobs, the engine of `psf
bank` and `dataset make`), the CPU threads shared among its processes; ``scheduler`` runs
them on an existing cluster, whose workers write the outputs (they must see the same
files). Each worker process loads the model once, on its first file.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from lensim.errors import InputError, OutOfMemory, ParameterError
from lensim.jsonable import strict_json
from lensim.sensor.profile import SensorProfile, sensor_from_dict

Progress = Callable[[float, float], None]


@dataclass(frozen=True)
class RawJob:
    """One raw file to restore and where its outputs go (dng: None when not asked for)."""

    source: Path
    tif: Path
    dng: Path | None

    @property
    def outputs(self) -> list[Path]:
        return [self.tif] + ([self.dng] if self.dng is not None else [])

    @property
    def finished(self) -> bool:
        return all(p.exists() for p in self.outputs)


@dataclass(frozen=True)
class RestoreSettings:
    """What every file shares: the checkpoint (or ONNX file), the sensor trained for
    (profile mapping), tiling, device, whether other cameras are allowed, the shooting
    settings given for every file (``shooting``: {fno, focus_m, focal_mm}, overriding
    each file's EXIF), the checkpoint's conditioning (Conditioning.to_dict(); None: no
    settings) and the engine: "torch", or "onnxruntime" with ``onnx`` the serialized model
    (worker processes build their sessions from it); ``bank``: the PSF bank's folder, for a
    PSF-informed network (lensim.restore.psf_stage.network_bank), or a lens with poses'
    bank folders by source (lensim.render.posed.posed_banks; the stage composes them per
    pixel); ``precision``: the tiles' arithmetic (lensim.restore.infer.PRECISIONS)."""

    checkpoint: str
    sensor: dict[str, Any]
    tile: int | None = None  # None: the network's (lensim.restore.infer.default_tile)
    overlap: int | None = None  # None: the network's (lensim.restore.infer.default_overlap)
    device: str = "cpu"
    allow_other_camera: bool = False
    shooting: dict[str, float] = field(default_factory=dict)
    conditioning: dict[str, Any] | None = None
    engine: str = "torch"
    onnx: bytes | None = None
    bank: str | dict[str, str] | None = None
    precision: str = "float32"


def plan_jobs(files: list[Path], out_dir: Path, dng: bool) -> list[RawJob]:
    """OUT/<stem>.tif (and OUT/<stem>.dng) per file; two inputs with one stem, or an
    output that would overwrite its input, are refused."""
    jobs: list[RawJob] = []
    seen: dict[Path, Path] = {}
    for f in files:
        job = RawJob(f, out_dir / f"{f.stem}.tif", out_dir / f"{f.stem}.dng" if dng else None)
        if job.tif in seen:
            raise InputError(
                str(f), None, f"has the same name stem as {seen[job.tif]}; both would be written to {job.tif}"
            )
        if job.dng is not None and job.dng.resolve() == f.resolve():
            raise ParameterError(
                str(f), "out_dir", "the restored DNG would overwrite this input; expected another output folder"
            )
        seen[job.tif] = f
        jobs.append(job)
    return jobs


def _names_match(raw: Any, sensor: SensorProfile) -> bool:
    names = {n.strip().lower() for n in (raw.camera, raw.model or "") if n and n.strip()}
    return sensor.name.strip().lower() in names


def check_camera(
    raw: Any, sensor: SensorProfile, placement: dict[str, Any] | None, checkpoint: str, allow_other: bool
) -> bool:
    """True when the raw comes from the sensor the network was trained for, at its native
    pixel scale: its camera name matches the profile's name and its active area is the
    sensor's (rounded down to whole Bayer quads), or, for a DNG written by `lensim
    simulate`, its frame lies on that sensor at the sensor's pitch. Otherwise a one-line
    InputError naming both, unless ``allow_other`` (then False)."""
    w, h = raw.width - raw.width % 2, raw.height - raw.height % 2
    if placement is not None:
        native = abs(float(placement.get("pitch_um", 0.0)) / sensor.pixel_pitch_um - 1.0) < 1e-6
        size_ok = native and _native_offset(placement, sensor, raw.height, raw.width) is not None
    else:
        size_ok = (w, h) == tuple(sensor.resolution)
    if _names_match(raw, sensor) and size_ok:
        return True
    if allow_other:
        return False
    what = f"{raw.camera} {raw.width}x{raw.height}"
    if placement is not None and _names_match(raw, sensor):
        what += f" simulated at {float(placement.get('pitch_um', 0.0)):.4g} um per pixel"
    raise InputError(
        raw.path,
        "camera",
        f"{what}, but {checkpoint} was trained for {sensor.name} "
        f"{sensor.width}x{sensor.height} at {sensor.pixel_pitch_um:g} um; give `allow_other_camera` "
        "to restore it anyway (as a full frame of that sensor)",
    )


def _native_offset(placement: dict[str, Any], sensor: SensorProfile, height: int, width: int) -> tuple[int, int] | None:
    """(top, left) sensor pixel of a simulated frame's top-left pixel, when it lies on the
    sensor's pixel grid and fits on it; else None."""
    p = sensor.pixel_pitch_um * 1e-3
    top = float(placement.get("y0_mm", 0.0)) / p + sensor.height / 2.0
    left = float(placement.get("x0_mm", 0.0)) / p + sensor.width / 2.0
    if abs(top - round(top)) > 1e-3 or abs(left - round(left)) > 1e-3:
        return None
    t, le = round(top), round(left)
    if 0 <= t <= sensor.height - height and 0 <= le <= sensor.width - width:
        return t, le
    return None


def raw_geometry(
    raw: Any, sensor: SensorProfile, placement: dict[str, Any] | None, native: bool
) -> tuple[tuple[float, float], tuple[float, float]]:
    """((top, left), (sensor_height, sensor_width)) in image pixels for fov_channels.

    A native raw (``native``: :func:`check_camera` passed) is the whole active area, the
    optical axis at its centre, or for a simulated DNG its recorded place on the sensor;
    any other raw is taken as a full frame fitted onto the sensor
    (lensim.restore.infer.image_sensor_geometry)."""
    from lensim.restore.infer import image_sensor_geometry

    offset: tuple[int, int] | None = None
    if native:
        offset = (0, 0) if placement is None else _native_offset(placement, sensor, raw.height, raw.width)
    return image_sensor_geometry(raw.height, raw.width, sensor.resolution, offset)


def _dng_colour(raw: Any, r_gain: float, b_gain: float) -> Any:
    """The raw's colour matrices (ColorMatrix1/2 with their illuminants, else its one
    matrix at D65) and the develop's white balance as DNG metadata."""
    from lensim.raw.dng import D65_ILLUMINANT, DngColour

    matrices = list(raw.color_matrices) or [(raw.color_matrix_illuminant or D65_ILLUMINANT, raw.color_matrix)]
    colour = DngColour.from_gains(matrices[0][1], r_gain, b_gain, matrices[0][0])
    if len(matrices) > 1:
        colour = colour.with_second_matrix(matrices[1][1], matrices[1][0])
    return colour


def raw_settings(raw: Any, given: dict[str, float]) -> dict[str, float]:
    """A raw's shooting settings {fno, focus_m, focal_mm}: EXIF FNumber, SubjectDistance
    (lensim.raw.read: 0 is unknown, 0xFFFFFFFF infinity) and FocalLength (LibRaw's aperture
    and focal length where the TIFF tags are missing), each replaced by ``given``'s value
    when there is one; settings known from neither are left out."""
    return {k: v for k, v in {**_exif_settings(raw), **given}.items() if v is not None}


def _exif_settings(raw: Any) -> dict[str, float | None]:
    return {"fno": raw.fno, "focus_m": raw.focus_distance_m, "focal_mm": raw.focal_length_mm}


def settings_vector(raw: Any, settings: RestoreSettings, warn: bool) -> torch.Tensor | None:
    """The settings vector of a raw for the checkpoint's network (None when it is not
    conditioned): lensim.restore.conditioning.photo_vector of its EXIF settings and
    ``settings.shooting`` (range warnings when ``warn``; a missing setting is a
    ParameterError naming the file and the setting)."""
    from lensim.restore.conditioning import Conditioning, photo_vector

    cond = Conditioning.from_dict(settings.conditioning, settings.checkpoint)
    return photo_vector(cond, _exif_settings(raw), settings.shooting, raw.path, warn)


def validate(jobs: list[RawJob], sensor: SensorProfile, settings: RestoreSettings) -> None:
    """Read and check every unfinished job's raw (camera, size, develop settings, shooting
    settings for a conditioned network) before anything is written; one-line InputError on
    the first bad file; range warnings (UserWarning) for every file."""
    from lensim.raw import read_raw
    from lensim.raw.develop import capture_params
    from lensim.raw.dng import read_simulation_record

    for job in jobs:
        if job.finished:
            continue
        raw = read_raw(job.source)
        check_camera(raw, sensor, read_simulation_record(job.source), settings.checkpoint, settings.allow_other_camera)
        capture_params(raw, sensor)  # the develop settings exist (as-shot white balance)
        settings_vector(raw, settings, warn=True)
        if job.dng is not None and raw.color_matrix is None:
            raise InputError(
                str(job.source),
                "color_matrix",
                "the file has no colour matrix to carry into the restored DNG; leave out `dng`",
            )


def restore_raw(
    job: RawJob,
    model: Any,
    sensor: SensorProfile,
    settings: RestoreSettings,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Develop, restore and write one raw file (see the module docstring); returns its
    record: input, outputs, size, whether it was native, the develop's capture parameters.
    ``model``: the network or any lensim.restore.infer.Engine."""
    from lensim.images import write_image
    from lensim.raw import read_raw
    from lensim.raw.develop import apply_orientation, develop_raw
    from lensim.raw.dng import DngCamera, DngExif, read_simulation_record, write_srgb_as_linear_dng
    from lensim.restore.infer import restore_image

    raw = read_raw(job.source)
    placement = read_simulation_record(job.source)
    native = check_camera(raw, sensor, placement, settings.checkpoint, settings.allow_other_camera)
    vec = settings_vector(raw, settings, warn=False)  # validate() warned
    img, params = develop_raw(raw, sensor, orient=False)
    top_left, size = raw_geometry(raw, sensor, placement, native)
    capture = {**params.to_dict(), **_recorded_noise(placement)}
    wiener = _stage_image(model, img, (top_left, size), sensor, settings, capture, str(job.source))
    try:
        out = restore_image(
            model,
            img,
            top_left,
            size,
            tile=settings.tile,
            overlap=settings.overlap,
            progress=progress,
            settings=vec,
            wiener=wiener,
            precision=settings.precision,
        )
    except OutOfMemory as e:
        raise OutOfMemory(str(job.source), e.field, e.message) from None
    del img  # bound peak memory
    out.clamp_(0.0, 1.0)
    if job.dng is not None:
        write_srgb_as_linear_dng(
            job.dng,
            out,
            params.ccm,
            _dng_colour(raw, params.r_gain, params.b_gain),
            DngCamera(raw.make or "", raw.model or ""),
            raw.orientation,
            DngExif.from_mapping(raw.info()),
        )
    write_image(job.tif, apply_orientation(out, raw.orientation), 16, srgb_tag=True)
    return {
        "input": str(job.source),
        "output": str(job.tif),
        "dng": None if job.dng is None else str(job.dng),
        "width": raw.width,
        "height": raw.height,
        "camera": raw.camera,
        "native": native,
        "skipped": False,
        "capture": params.to_dict(),
        "settings": strict_json(raw_settings(raw, settings.shooting)),
    }


def _recorded_noise(placement: dict[str, Any] | None) -> dict[str, float]:
    """The noise levels (shot, read) a DNG written by `lensim simulate` records of its
    capture, for the Wiener stage; empty for any other raw file (its noise is not known)."""
    cap = (placement or {}).get("capture") or {}
    if cap.get("shot") is None or cap.get("read") is None:
        return {}
    return {"shot": float(cap["shot"]), "read": float(cap["read"])}


def _stage_image(
    model: Any,
    img: torch.Tensor,
    geometry: tuple[tuple[float, float], tuple[float, float]],
    sensor: SensorProfile,
    settings: RestoreSettings,
    capture: dict[str, Any],
    source: str,
) -> torch.Tensor | None:
    """The Wiener stage's image of a developed raw for a PSF-informed network (the develop's
    colour pipeline as its capture, with the noise levels a simulated DNG records), else None."""
    if not getattr(model, "uses_wiener", False):
        return None
    from lensim.restore.psf_stage import network_bank, photo_wiener, stage_of

    info, given = {"path": settings.checkpoint}, settings.bank
    if isinstance(given, dict):  # a lens with poses: its banks by source
        bank: Any = {k: network_bank(info, v) for k, v in given.items()}
    else:
        bank = network_bank(info, given)
    return photo_wiener(img, bank, sensor, geometry[0], geometry[1], capture, stage_of(model), source)


# ----------------------------------------------------------------------------- batches


@dataclass(frozen=True)
class WorkerJob:
    """One raw file for a worker process (lensim.workers.run_jobs; plain, picklable data):
    the job with absolute paths (a cluster's workers need not share this process's working
    folder, but must see the same files), the batch's settings and the worker's threads
    (torch's, or onnxruntime's intra-op threads)."""

    job: RawJob
    settings: RestoreSettings
    threads: int


_MODEL_LOCK = threading.Lock()  # a cluster's worker may run several jobs at once, in threads
_MODEL: dict[tuple[Any, ...], Any] = {}  # this process's one model (or engine), by _model_key


def _model_key(settings: RestoreSettings, threads: int) -> tuple[Any, ...]:
    """What identifies a worker's model: the ONNX bytes' digest, or the checkpoint file
    (path, size, modification time: a cluster's long-lived workers load a checkpoint
    rewritten since anew), with the engine, device and threads."""
    if settings.engine == "onnxruntime" and settings.onnx is not None:
        import hashlib

        return ("onnx", hashlib.sha256(settings.onnx).hexdigest(), settings.device, threads)
    try:
        st = os.stat(settings.checkpoint)
    except OSError as e:
        raise InputError(
            settings.checkpoint,
            None,
            f"cannot be read in a worker process ({e.strerror or e}); a "
            "cluster's workers must see the same files as this process",
        ) from None
    return ("torch", settings.checkpoint, st.st_size, st.st_mtime_ns, settings.device, threads)


def _worker_model(settings: RestoreSettings, threads: int) -> Any:
    """This process's model for ``settings``: loaded on its first job (and again only when
    the model changes; the one before is dropped), the same object for every later job."""
    key = _model_key(settings, threads)
    with _MODEL_LOCK:
        if key not in _MODEL:
            _MODEL.clear()
            if key[0] == "onnx":
                from lensim.restore.engines import OnnxEngine

                _MODEL[key] = OnnxEngine(settings.onnx or b"", settings.device, threads, source=settings.checkpoint)
            else:
                from lensim.restore.checkpoint import load_checkpoint

                _MODEL[key] = load_checkpoint(settings.checkpoint, device=settings.device)[0]
        return _MODEL[key]


def restore_in_worker(task: WorkerJob) -> dict[str, Any]:
    """run_jobs' job: restore one raw file (:func:`restore_raw`) in a worker process with
    ``task.threads`` torch threads and the process's cached model (:func:`_worker_model`)."""
    torch.set_num_threads(task.threads)
    model = _worker_model(task.settings, task.threads)
    return restore_raw(task.job, model, sensor_from_dict(task.settings.sensor, "checkpoint sensor"), task.settings)


def _absolute(job: RawJob) -> RawJob:
    return RawJob(job.source.absolute(), job.tif.absolute(), None if job.dng is None else job.dng.absolute())


def _restore_on_workers(
    todo: list[RawJob],
    settings: RestoreSettings,
    workers: int,
    scheduler: str | None,
    finished: Callable[[dict[str, Any]], None],
) -> None:
    """Restore the jobs through lensim.workers.run_jobs: on a local Dask cluster of
    min(workers, jobs) processes sharing this process's torch threads (each gets
    threads // processes, at least 1, as torch.set_num_threads or its default gives them), or
    on the cluster at ``scheduler`` (one thread per job, as its workers are sized);
    ``finished(record)`` per file as it is written, with the paths as given."""
    from lensim.workers import run_jobs

    threads = 1 if scheduler else max(1, torch.get_num_threads() // min(workers, len(todo)))
    shared = replace(settings, checkpoint=str(Path(settings.checkpoint).absolute()))
    given = {_absolute(job): job for job in todo}

    def done(task: WorkerJob, record: dict[str, Any]) -> None:
        job = given[task.job]
        finished(
            {
                **record,
                "input": str(job.source),
                "output": str(job.tif),
                "dng": None if job.dng is None else str(job.dng),
            }
        )

    run_jobs(restore_in_worker, [WorkerJob(job, shared, threads) for job in given], workers, scheduler, done)


def restore_raw_files(
    files: list[Path],
    out_dir: Path,
    model: Any,
    settings: RestoreSettings,
    dng: bool = False,
    workers: int = 1,
    progress: Progress | None = None,
    scheduler: str | None = None,
) -> list[dict[str, Any]]:
    """Restore raw files into ``out_dir`` (see the module docstring). ``model`` is the
    loaded network or engine, used in this process when ``workers`` is 1 or one file is
    left to do (and no ``scheduler``). Otherwise the files are restored side by side
    through lensim.workers.run_jobs (:func:`_restore_on_workers`): on a local Dask cluster
    of ``workers`` processes, or on the cluster at ``scheduler`` (an address such as
    tcp://host:8786; its workers must import lensim and see the same files); each worker
    process loads its own model from ``settings.checkpoint`` (``settings.onnx`` for
    onnxruntime) on its first file. ``progress(done, total)`` counts files (in this
    process, fractions of a file as its tiles finish). Returns one record per file."""
    if workers < 1:
        raise ParameterError(None, "workers", f"expected at least 1, got {workers}")
    sensor = sensor_from_dict(settings.sensor, "checkpoint sensor")
    jobs = plan_jobs(files, out_dir, dng)
    validate(jobs, sensor, settings)
    records = [{"input": str(j.source), "output": str(j.tif), "skipped": True} for j in jobs if j.finished]
    todo = [j for j in jobs if not j.finished]
    total = len(jobs)

    def step(done: float) -> None:
        if progress is not None:
            progress(done, total)

    step(len(records))
    if scheduler is None and (workers == 1 or len(todo) <= 1):
        for job in todo:
            before = len(records)

            def tiles(d: int, n: int, before: int = before) -> None:
                step(before + d / n)

            records.append(restore_raw(job, model, sensor, settings, progress=tiles))
            step(len(records))
        return records
    if todo:

        def finished(record: dict[str, Any]) -> None:
            records.append(record)
            step(len(records))

        _restore_on_workers(todo, settings, workers, scheduler, finished)
    return records


__all__ = [
    "RawJob",
    "RestoreSettings",
    "WorkerJob",
    "check_camera",
    "plan_jobs",
    "raw_geometry",
    "raw_settings",
    "restore_in_worker",
    "restore_raw",
    "restore_raw_files",
    "settings_vector",
    "validate",
]
