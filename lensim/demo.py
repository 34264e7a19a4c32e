"""The main job: the whole method on the built-in camera, ending in an HTML report.

Stages (each cached in the output folder, so a second run reuses what exists and a
killed run resumes): lens figures -> PSF bank at the sensor's pitch -> training pairs from
the built-in photos -> the field-aware network (the PSF-informed network, fine-tuned from
the shipped universal model where it serves the camera) and the plain version of it (every
field-aware part off, from scratch) of about the same size, trained on the same time
budget -> evaluation on held-out photos against the aberrated input, the Wiener oracle and
the universal model zero-shot ->
slanted-edge MTF and lateral colour before and after -> report.json and a self-contained
report.html.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lensim.assets import DEFAULT_LENS
from lensim.assets.images import available_sample_images, write_centre_crops
from lensim.errors import InputError
from lensim.io import atomic_write_json, folder_lock, read_json
from lensim.optics.analysis import first_order_summary
from lensim.optics.lens_file import load_lens
from lensim.sensor.profile import DEFAULT_SENSOR, SensorProfile, load_sensor

if TYPE_CHECKING:
    from lensim.optics.shooting import ShootingSettings
    from lensim.psf.bank import PSFBank

#: Adam's learning rate when the demo's network starts from the universal model (2e-4, as
#: benchmarks/universal_finetune.py); from scratch 5e-4.
FINE_TUNE_LR = 2e-4
Say = Callable[[str], None]
#: progress(done, total) of the stage last announced by ``say``: PSF fields, photos,
#: training seconds, held-out crops.
StageProgress = Callable[[float, float], None]


@dataclass(frozen=True)
class DemoSettings:
    """Sizes of a demo run. quick: about 3 minutes on 2 cores; default: about 15.

    width, deformable_scales: the field-aware UNet whose parameter count every network of
    the demo matches. arch, stem: the demo's field-aware network: "psfnet" (the PSF-informed
    network, issue 23: the default network's body refining the Wiener stage's image, with
    FOV channels and a ``stem``x``stem`` pixel-unshuffle stem; benchmarks/psfnet_demo.py),
    "nafnet" (the default network of `lensim train`: the same body on the image and FOV
    channels only; benchmarks/nafnet_vs_unet.py) or "unet", the paper's UNet. The baseline
    (:func:`plain_network`) is the same body with every field-aware part off, of the same
    size: plain NAFNet with the same stem (the stronger plain network measured,
    benchmarks/nafnet_vs_unet.py), or the plain UNet.

    init, init_width: where the demo's network starts: "universal" (the shipped universal
    model, lensim.restore.universal; the network is then its PSF-informed network of width
    init_width, and every network of the demo matches its parameter count) or None (from
    scratch; :func:`with_universal_start` decides)."""

    fields: int
    wavelengths_nm: tuple[float, ...]
    pupil_samples: int
    photo_size: int
    placements: int
    crops: int
    crop_size: int
    train_seconds: float
    width: int
    train_crop: int
    deformable_scales: int
    arch: str = "psfnet"
    stem: int = 2
    init: str | None = None
    init_width: int | None = None

    @classmethod
    def make(cls, quick: bool) -> DemoSettings:
        if quick:
            return cls(5, (450.0, 500.0, 550.0, 600.0, 650.0), 96, 256, 3, 2, 96, 35.0, 16, 64, 1)
        return cls(12, tuple(float(w) for w in range(400, 701, 25)), 128, 512, 3, 4, 128, 300.0, 32, 96, 1)


def _stage(out: Path, name: str) -> Path:
    d = out / name
    d.mkdir(parents=True, exist_ok=True)
    return d


def _claim_folder(out: Path, settings: DemoSettings, quick: bool, seed: int, shooting: dict | None = None) -> None:
    """Record the run's settings in out/demo.json; refuse a folder made with others, whose
    cached stages would not match. shooting: the lens's shooting settings (to_dict), when
    any is given."""
    marker = out / "demo.json"
    mine = json.loads(
        json.dumps({**asdict(settings), "quick": quick, "seed": seed, **({"shooting": shooting} if shooting else {})})
    )
    if marker.exists():
        try:
            theirs = read_json(marker, "demo settings record")
        except InputError:
            theirs = None  # unreadable: made by something else
        if theirs != mine:
            what = (
                "other settings"
                if not isinstance(theirs, dict)
                else ", ".join(f"{k}={theirs.get(k)!r}" for k in mine if theirs.get(k) != mine[k])
            )
            raise InputError(
                str(marker),
                "settings",
                f"this folder holds a demo run with {what}; expected the "
                "same settings (`quick`, `seed`) to resume it, or a new output folder",
            )
    else:
        atomic_write_json(marker, mine)


def _photos(out: Path, size: int) -> Path:
    """The built-in sample photos, centre-cropped to size x size (sharp, sRGB)."""
    d = _stage(out, "photos")
    write_centre_crops(available_sample_images(), d, size)
    return d


def _target_parameters(settings: DemoSettings) -> int:
    """The parameter count every network of the demo matches: the universal model's network
    when the demo starts from it, else the field-aware UNet of settings.width (deformable
    blocks at settings.deformable_scales decoder scales)."""
    import torch

    from lensim.restore.models import build_model
    from lensim.restore.network import FieldAwareUNet, count_parameters

    with torch.device("meta"):
        if settings.init_width is not None:
            return count_parameters(
                build_model({"arch": "psfnet", "width": settings.init_width, "stem": settings.stem, "use_fov": True})
            )
        return count_parameters(FieldAwareUNet(width=settings.width, deformable_scales=settings.deformable_scales))


def with_universal_start(settings: DemoSettings, pixel_pitch_um: float, fno: float) -> DemoSettings:
    """The settings with init "universal" when the shipped universal model can start the
    demo's network: it is a PSF-informed network (settings.arch "psfnet") with the demo's
    stem, and the sensor's pitch (um) and the lens's F-number lie inside its trained ranges
    (lensim.restore.universal.check_range); else the settings unchanged (from scratch)."""
    from lensim.restore.checkpoint import read_checkpoint
    from lensim.restore.universal import NAME, check_range, model_path

    if settings.arch != "psfnet":
        return settings
    try:
        ckpt = read_checkpoint(model_path(NAME))
        config, universal = ckpt["model_config"], ckpt.get("universal") or {}
        check_range(universal, "pixel_pitch_um", pixel_pitch_um, "sensor")
        check_range(universal, "fno", fno, "lens")
    except (InputError, KeyError):
        return settings
    if config.get("arch") != "psfnet" or int(config.get("stem", 1)) != settings.stem:
        return settings
    return replace(settings, init=NAME, init_width=int(config["width"]))


def plain_network(settings: DemoSettings) -> dict[str, Any]:
    """The demo's baseline, as train() keyword arguments: the demo's network with every
    field-aware part off (no FOV channels, deformable blocks or context block), sized like
    it. arch "nafnet": plain NAFNet with the demo's stem (nafnet_width); "unet": the plain
    UNet (plain_unet_width, 3 scales)."""
    from lensim.restore.nafnet import nafnet_width
    from lensim.restore.network import plain_unet_width

    target = _target_parameters(settings)
    switches: dict[str, Any] = dict(use_fov=False, use_deformable=False, use_context=False)
    if settings.arch in ("nafnet", "psfnet"):
        switches["stem"] = settings.stem
        return dict(arch="nafnet", width=nafnet_width(target, **switches), **switches)
    return dict(arch="unet", width=plain_unet_width(target, 3), **switches)


def _train(
    pairs: Path,
    run: Path,
    settings: DemoSettings,
    plain: bool,
    seed: int,
    device: str = "cpu",
    progress: StageProgress | None = None,
) -> dict:
    """Train once (cached by RUN/done.json) on a time budget; progress(seconds, budget).
    plain: the baseline (:func:`plain_network`), else the demo's network."""
    from lensim.restore.nafnet import nafnet_width
    from lensim.restore.train import budget_progress, train

    marker = run / "done.json"
    if marker.exists():
        return read_json(marker, "training record")
    if run.exists():
        shutil.rmtree(run)  # an unfinished run: start it again (its budget was not spent)
    kw: dict[str, Any] = dict(
        epochs=100_000,
        batch_size=4,
        lr=5e-4,
        lr_schedule="cosine",
        crop=settings.train_crop,
        seed=seed,
        time_budget_s=settings.train_seconds,
        val_fraction=0.25,
        device=device,
    )
    if plain:
        kw.update(plain_network(settings))
    elif settings.arch in ("nafnet", "psfnet"):  # psfnet: NAFNet's width (lensim.restore.models.default_width)
        switches: dict[str, Any] = dict(use_fov=True, use_deformable=False, use_context=False, stem=settings.stem)
        kw.update(arch=settings.arch, width=nafnet_width(_target_parameters(settings), **switches), **switches)
        if settings.init is not None:  # the universal model's own network, from its weights, at a
            # fine-tuning rate (the demo's seed 0 at 5e-4: 83 steps ended 0.2 dB below the zero-shot start)
            kw.update(width=settings.init_width, init=settings.init, lr=FINE_TUNE_LR)
    else:
        kw.update(
            arch="unet",
            width=settings.width,
            deformable_scales=settings.deformable_scales,
            use_fov=True,
            use_deformable=True,
            use_context=True,
        )
    res = train(pairs, run, progress=budget_progress(progress, settings.train_seconds), **kw)
    info = {k: v for k, v in asdict(res).items() if k != "history"}
    info["init"] = None if plain else settings.init
    atomic_write_json(marker, info)
    return info


def _train_job(job: tuple[Path, Path, DemoSettings, bool, int, str]) -> dict:
    """_train(pairs, run, settings, plain, seed, device) in a worker process (no progress)."""
    return _train(*job)


def _train_both(
    out: Path, settings: DemoSettings, seed: int, device: str, workers: int, say: Say, step: StageProgress
) -> tuple[dict, dict]:
    """Train the demo's network and the plain baseline, each on the same time budget:
    side by side in two worker processes of one torch thread each when training runs on
    the CPU and workers >= 2 (a small network's training step scales poorly to a second
    thread, so two cores give each network nearly what both cores would, in half the wall
    time), else one after the other in this process. Returns their training records."""
    budget = settings.train_seconds
    jobs = [
        (out / "pairs", out / f"run-{name}", settings, name == "plain", seed, device) for name in ("model", "plain")
    ]
    if workers < 2 or device != "cpu":
        say(f"training the field-aware network ({budget:.0f} s)")
        model = _train(*jobs[0][:-1], device=device, progress=step)
        say(f"training the plain network ({budget:.0f} s)")
        return model, _train(*jobs[1][:-1], device=device, progress=step)
    import threading

    from lensim.workers import run_jobs

    say(f"training the field-aware and the plain network side by side ({budget:.0f} s, one core each)")
    done: dict[bool, dict] = {}
    stop = threading.Event()
    start = time.perf_counter()

    def tick() -> None:  # the workers report nothing until they finish: show the budget's clock
        while not stop.wait(1.0):
            step(min(time.perf_counter() - start, budget), budget)

    ticker = threading.Thread(target=tick, name="lensim-demo-training-clock", daemon=True)
    ticker.start()
    try:
        run_jobs(_train_job, jobs, workers=2, on_result=lambda job, info: done.__setitem__(job[3], info))
    finally:
        stop.set()
        ticker.join()
    return done[False], done[True]


def run_demo(
    out_dir: str | Path,
    quick: bool = False,
    seed: int = 0,
    workers: int | None = None,
    say: Say | None = None,
    device: str = "cpu",
    progress: StageProgress | None = None,
    shooting: ShootingSettings | None = None,
) -> dict:
    """Run the demo into out_dir; returns the report's JSON (also written). workers: processes
    for the PSF bank and the pairs, and two or more train the two networks side by side on
    the CPU (None: one per available core, lensim.workers.available_cores). device: where the
    networks train and run ("cpu", "cuda", "cuda:N"). say(stage) announces each stage and
    progress(done, total) reports within it. shooting: the built-in lens's shooting
    settings (lensim.optics.shooting; default the lens file's). out_dir is locked while the
    demo runs (lensim.io.folder_lock: a second demo into it is refused at once)."""
    from lensim.workers import available_cores

    workers = available_cores() if workers is None else workers
    with folder_lock(out_dir):
        return _run_demo(Path(out_dir), quick, seed, workers, say, device, progress, shooting)


def _set_lens(shooting: ShootingSettings | None) -> tuple[Any, dict | None]:
    """The built-in lens at the shooting settings and their record (None: the file's own)."""
    from lensim.optics.shooting import lens_and_record

    return lens_and_record(load_lens(DEFAULT_LENS), shooting)


def _fno(lens: Any, shooting: ShootingSettings | None) -> float:
    """The F-number the demo's lens works at (the shooting settings', else the lens's own)."""
    from lensim.restore.universal import zero_shot_fno

    return zero_shot_fno(lens, None if shooting is None else shooting.fno)


def _run_demo(
    out: Path,
    quick: bool,
    seed: int,
    workers: int,
    say: Say | None,
    device: str,
    progress: StageProgress | None,
    shooting: ShootingSettings | None = None,
) -> dict:
    """run_demo's stages, the folder locked."""
    from lensim.data.pairs import make_dataset
    from lensim.plots.bank import write_bank_figures
    from lensim.plots.lens import plot_layout, plot_spots
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.report import write_report

    say = say or (lambda msg: None)
    step = progress or (lambda done, total: None)
    lens, described = _set_lens(shooting)  # before the folder is claimed: a refused setting leaves nothing
    sensor = load_sensor(DEFAULT_SENSOR)
    settings = with_universal_start(DemoSettings.make(quick), sensor.pixel_pitch_um, _fno(lens, shooting))
    _claim_folder(out, settings, quick, seed, None if described is None or shooting is None else shooting.to_dict())
    timings: dict[str, float] = {}
    figs = _stage(out, "figures")

    t = time.perf_counter()
    say("lens figures")
    plot_layout(lens, path=figs / "layout.png")
    plot_spots(lens, path=figs / "spots.png")
    summary = first_order_summary(lens)
    timings["lens"] = time.perf_counter() - t

    t = time.perf_counter()
    say("PSF bank")
    bank_settings = BankSettings(
        fields=settings.fields,
        wavelengths_nm=settings.wavelengths_nm,
        pupil_samples=settings.pupil_samples,
        kernel_limit=41,
    )
    # at shooting settings the bank's manifest records them, and so do the pairs made from it
    shot = None if shooting is None or shooting.is_default else shooting
    bank = get_bank(
        load_lens(DEFAULT_LENS) if shot is not None else lens,
        sensor.pixel_pitch_um,
        bank_settings,
        response=sensor.spectral_response,
        shooting=shot,
        out_dir=out / "bank",
        workers=workers,
        progress=step,
    )
    write_bank_figures(bank, figs)
    timings["bank"] = time.perf_counter() - t

    t = time.perf_counter()
    say("training pairs")
    photos = _photos(out, settings.photo_size)
    make_dataset(
        photos,
        out / "pairs",
        bank,
        DEFAULT_SENSOR,
        sensor,
        crops=settings.crops,
        size=settings.crop_size,
        seed=seed,
        placements=settings.placements,
        workers=workers,
        progress=step,
    )
    timings["pairs"] = time.perf_counter() - t

    if settings.arch == "psfnet":  # once, before the two trainings run side by side
        from lensim.restore.psf_stage import ensure_wiener_cache

        t = time.perf_counter()
        say("Wiener stage of the pairs")
        ensure_wiener_cache(out / "pairs", bank=bank, progress=step)
        timings["wiener_stage"] = time.perf_counter() - t

    t = time.perf_counter()
    model_info, plain_info = _train_both(out, settings, seed, device, workers, say, step)
    timings["training"] = time.perf_counter() - t

    t = time.perf_counter()
    say("evaluation on held-out photos")
    evaluation = _evaluate(out, (bank, sensor), settings, figs, seed, device, step)
    timings["evaluation"] = time.perf_counter() - t

    t = time.perf_counter()
    say("a held-out photo as a camera raw file, restored")
    raw_file = _raw_stage(out, bank, sensor, figs, seed, device)
    timings["raw"] = time.perf_counter() - t

    report = {
        "lens": summary,
        "sensor": {"name": sensor.name, "pixel_pitch_um": sensor.pixel_pitch_um, "resolution": list(sensor.resolution)},
        "settings": {
            **asdict(settings),
            "quick": quick,
            "seed": seed,
            "workers": workers,
            "device": device,
            "kernel_pixels": bank.kernel_pixels,
        },
        "bank": _bank_summary(bank),
        "shooting": described,
        "training": {
            "model": {**model_info, "network": _network(out / "run-model")},
            "plain": {**plain_info, "network": _network(out / "run-plain")},
        },
        **evaluation,
        "raw_file": raw_file,
        "timings_s": timings,
    }
    write_report(out, report, figs)
    return report


def _evaluate(
    out: Path,
    camera: tuple[PSFBank, SensorProfile],
    settings: DemoSettings,
    figs: Path,
    seed: int,
    device: str,
    progress: StageProgress,
) -> dict:
    """The held-out evaluation of both networks, the Wiener oracle and (when the demo's
    network started from it) the universal model zero-shot, the sample crops and the edge
    study (slanted-edge MTF, lateral colour): the report's entries held_out_photos,
    sample_crops, metrics, slanted_edge and lateral_colour."""
    from lensim.data.manifest import read_held_out, read_pairs_manifest
    from lensim.evaluate.harness import builtin_method, checkpoint_method, evaluate
    from lensim.report import edge_study, sample_crops
    from lensim.restore.universal import model_path

    bank, sensor = camera

    held_out = read_held_out(out / "run-model")
    manifest = read_pairs_manifest(out / "pairs")

    # the last checkpoints: best.pt is picked by validation PSNR on these very photos
    def run(name: str) -> Any:
        return checkpoint_method(
            out / f"run-{name}" / "last.pt", manifest.get("lens"), manifest.get("sensor"), device=device
        )

    # the report's table in the order of the stages: oracle, plain from scratch, zero-shot, the demo's
    methods = {"wiener": builtin_method("wiener"), "plain": run("plain")}
    if settings.init is not None:
        methods["universal"] = checkpoint_method(model_path(settings.init), device=device)
    methods["model"] = run("model")
    metrics = evaluate(out / "pairs", methods, bank=bank, sources=held_out, progress=progress)
    samples = sample_crops(out / "pairs", manifest, held_out, methods["model"], bank, figs)
    edges = edge_study(bank, sensor, methods["model"], figs, seed=seed)
    return {
        "held_out_photos": held_out,
        "sample_crops": samples,
        "metrics": metrics,
        "slanted_edge": edges["slanted_edge"],
        "lateral_colour": edges["lateral_colour"],
    }


def _raw_stage(out: Path, bank: PSFBank, sensor: SensorProfile, figs: Path, seed: int, device: str) -> dict:
    """The first held-out photo as the camera's raw file: simulated at the sensor's right
    edge and written as a CFA DNG (what `lensim simulate --raw` writes), then through
    `lensim restore`'s raw path (develop, restore, 16-bit TIFF) with the field-aware
    network; the report's raw_file entry and figure (developed input, restored, truth)."""
    import torch

    from lensim.data.manifest import read_held_out
    from lensim.images import read_image
    from lensim.raw.restore import RestoreSettings, restore_raw_files
    from lensim.render.mapping import native_mapping
    from lensim.render.pipeline import simulate
    from lensim.report import raw_file_figure
    from lensim.restore.checkpoint import load_checkpoint

    d = _stage(out, "raw")
    name = Path(read_held_out(out / "run-model")[0]).stem
    truth, _ = read_image(out / "photos" / f"{name}.png")
    h, w = truth.shape[1:]
    top, left = (sensor.height - h) // 4 * 2, (sensor.width - w - 16) // 2 * 2  # mid-height, at the right edge
    dng = d / f"{name}.dng"
    if not dng.exists():
        simulate(
            truth,
            bank,
            sensor,
            torch.Generator().manual_seed(seed),
            mapping=native_mapping(h, w, sensor, top, left),
            raw_path=dng,
        )
    checkpoint = out / "run-model" / "last.pt"
    model, _ = load_checkpoint(checkpoint, device=device)
    settings = RestoreSettings(str(checkpoint), sensor.to_dict(), device=device, bank=str(out / "bank"))
    record = restore_raw_files([dng], d / "restored", model, settings)[0]
    entry = raw_file_figure(dng, Path(record["output"]), truth, sensor, figs)
    return {"photo": name, "dng": str(dng.relative_to(out)), "sensor_top": top, "sensor_left": left, **entry}


def _network(run: Path) -> str:
    """The network a run's last checkpoint holds, in words (lensim.restore.models.describe_network):
    read back, not assumed, since done.json reuses a run an older lensim trained."""
    from lensim.restore.checkpoint import read_checkpoint
    from lensim.restore.models import describe_network

    return describe_network(read_checkpoint(run / "last.pt")["model_config"])


def _bank_summary(bank: PSFBank) -> dict:
    """The report's bank entry: normalized fields, image heights (mm), Strehl ratios and the
    green channel's relative illumination, one value per field."""
    return {
        "fields": [float(f.field) for f in bank.fields],
        "image_height_mm": [float(r) for r in bank.radii_mm],
        "strehl": [float(f.strehl) for f in bank.fields],
        "relative_illumination_green": [float(f.rgb[1].sum()) for f in bank.fields],
    }
