"""`lensim restore`: restore photos with a trained network, tile by tile.

Register in lensim/cli/__init__.py with
    app.command("restore")(restore_command)
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from lensim.cli.bank_options import scheduler_option
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, choice, distinct_outputs, output_folder, scheduler_address
from lensim.cli.validate import device as check_device
from lensim.cli.zero_shot import check_zero_shot, run_lens_bank_folder, universal_inputs, zero_shot_bank_folder
from lensim.errors import InputError, OutOfMemory
from lensim.io import folder_lock

if TYPE_CHECKING:
    import torch


def _parse_pair(text: str, option: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.replace("x", ",").split(","))
        return a, b
    except ValueError:
        raise InputError(option, None, f"expected two integers TOP,LEFT, got {text!r}") from None


def _split_inputs(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    """(raw files, other photos): folders are expanded to their raw files
    (lensim.raw.raw_files), files go by their suffix."""
    from lensim.raw import RAW_SUFFIXES, raw_files

    raw_given: list[str | Path] = [p for p in paths if p.is_dir() or p.suffix.lower() in RAW_SUFFIXES]
    photos = [p for p in paths if p not in raw_given]
    return (raw_files(raw_given) if raw_given else []), photos


def _restore_raws(
    files: list[Path], output: Path, model, settings, dng: bool, where: tuple[int, str | None], quiet: bool
) -> list[dict]:
    """Restore raw files with a progress bar over the batch (lensim.raw.restore); where:
    (--workers, --scheduler)."""
    from lensim.raw.restore import restore_raw_files

    workers, scheduler = where
    with progress_bar("restoring raw files", "files", quiet) as step:
        records = restore_raw_files(
            files, output, model, settings, dng=dng, workers=workers, progress=step, scheduler=scheduler
        )
    if not quiet:
        for r in records:
            what = "skipped (done)" if r["skipped"] else "->"
            console.print(f"restored {r['input']} {what} {r['output']}", highlight=False)
    return records


def restore_command(
    checkpoint: Path = typer.Argument(
        ...,
        help="Run folder (best.pt, else last.pt) or checkpoint file; with --engine "
        "onnxruntime also an .onnx file from `lensim export`; 'universal' (or left out, with --lens and "
        "--sensor): the shipped universal model, zero-shot; with --lens and --sensor, a universal model "
        "of your own (`lensim library pretrain --ship` folder) restores zero-shot too.",
    ),
    images: list[Path] = typer.Argument(
        None,
        help="Photos to restore (8/16-bit PNG, TIFF or JPEG), camera raw files "
        "(DNG, CR2, NEF, ARW, ...) or folders of raw files.",
    ),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    sensor_file: str = typer.Option(
        None, "--sensor", help="Sensor profile of the photos (default: the one trained for)."
    ),
    lens_file: str = typer.Option(
        None,
        "--lens",
        help="Lens of the photos (checked against the checkpoint's); a lens with poses (an as-built lens "
        "from `lensim calibrate`) gives a PSF-informed network's stage its posed banks (8, computed and cached).",
    ),
    sensor_offset: str = typer.Option(
        None,
        "--sensor-offset",
        help="TOP,LEFT sensor pixel of the image's top-left "
        "pixel at native scale (default: the image is a full frame).",
    ),
    tile: int = typer.Option(
        None,
        "--tile",
        help="Largest tile side in pixels (default: the network's: 1024 for NAFNet and the PSF-informed "
        "network, 512 for the UNet).",
    ),
    overlap: int = typer.Option(
        None,
        "--overlap",
        help="Least overlap of neighbouring tiles in pixels (default: the network's: 96 for NAFNet and the "
        "PSF-informed network, 192 for the UNet).",
    ),
    bits: int = typer.Option(0, "--bits", help="Output bit depth 8 or 16 (0: that of the input)."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:N."),
    engine: str = typer.Option(
        "torch",
        "--engine",
        help="torch (the PyTorch network) or onnxruntime (an .onnx file, "
        "or the run exported on the fly); same tiling, same results within 1e-3 (torch with --precision float32).",
    ),
    threads: int = typer.Option(0, "--threads", help="CPU threads for PyTorch / onnxruntime (0: their default)."),
    precision: str = typer.Option(
        "auto",
        "--precision",
        help="The network's arithmetic with --engine torch: float32, bfloat16, or auto (bfloat16 on a CPU "
        "with native bfloat16, AVX512-BF16 or AMX: a 24 MP photo about 1.35x faster, its tiles within 65 dB "
        "PSNR of float32's; else float32).",
    ),
    dng: bool = typer.Option(
        False,
        "--dng",
        help="Raw inputs: also write OUT/<name>.dng, the restored photo as a "
        "LinearRaw DNG with the raw's colour matrices, white balance and EXIF.",
    ),
    allow_other_camera: bool = typer.Option(
        False,
        "--allow-other-camera",
        help="Restore raws from another camera or of another size than the checkpoint's sensor (as full frames of it).",
    ),
    workers: int = typer.Option(
        1,
        "--workers",
        help="Raw inputs restored side by side: a local Dask cluster of N "
        "worker processes when > 1, sharing the CPU threads, each loading the model once.",
    ),
    scheduler: str = scheduler_option(),
    fno: float = typer.Option(
        None,
        "--fno",
        help="F-number the photos were taken at (overrides their EXIF "
        "FNumber); needed by a network trained across F-numbers.",
    ),
    focus_m: float = typer.Option(
        None,
        "--focus-m",
        help="Focus distance in metres from the sensor, inf for infinity (overrides their EXIF SubjectDistance).",
    ),
    focal_mm: float = typer.Option(None, "--focal-mm", help="Focal length in mm (overrides their EXIF FocalLength)."),
    bank: Path = typer.Option(
        None,
        "--bank",
        help="PSF bank folder of the lens, for a PSF-informed network (--arch psfnet; default: the bank "
        "of the pairs it was trained on).",
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print what was written as JSON."),
) -> None:
    """Restore photos with a trained network: tiled (any resolution), each tile fed its
    absolute field-of-view coordinates; writes OUT/<name>.png (or .tif for TIFF input).

    Camera raw files are developed with the simulator's own chain (no sharpening), restored
    with the field-of-view of their active area on the sensor and written as OUT/<name>.tif
    (16-bit sRGB; with --dng also a linear DNG). A raw from another camera than the
    checkpoint's sensor is refused unless --allow-other-camera. Every raw is checked
    before the first output; finished outputs are skipped, so a rerun resumes. --workers N
    restores N raws side by side on a local Dask cluster, --scheduler ADDRESS on an existing
    one (its workers must see the same files: they write the outputs).

    A network trained across shooting settings needs the photos' settings: their EXIF
    (FNumber, SubjectDistance, FocalLength; raw files, TIFF, JPEG, PNG) or
    --fno/--focus-m/--focal-mm (which override it). Settings outside the trained range give
    a warning, far outside a refusal.

    --engine onnxruntime runs the network with onnxruntime: CHECKPOINT may then be an .onnx
    file written by `lensim export` (its metadata gives the sensor and lens trained for), or
    a run, exported on the fly in memory.

    A PSF-informed network's Wiener stage takes --bank, else the bank of the pairs it was
    trained on (pairs of a lens with poses: their posed banks, one per sensor quadrant and
    its mirrored lens's, composed per pixel); with --lens a lens with poses, that lens's
    posed banks.

    Zero-shot: CHECKPOINT 'universal' (or, with --lens, no CHECKPOINT) restores with the
    shipped universal model (lensim.restore.universal), no training run: --lens (a file, a
    built-in or a library lens) and --sensor say what took the photos; a sensor pitch or
    F-number (--fno, else the lens's own) outside the model's trained ranges is refused.

    Example: lensim restore runs/a photo.png -o restored/;
    lensim restore --lens cooke_triplet --sensor fullframe_dslr photo.png -o restored/;
    lensim restore runs/a raws/ -o restored/ --dng --workers 2;
    lensim restore model.onnx photo.png -o restored/ --engine onnxruntime
    """
    from lensim.restore.conditioning import given_settings

    checkpoint, images, zero_shot = universal_inputs(checkpoint, images or [], lens_file, sensor_file)
    if not images:
        raise InputError("IMAGES", None, "expected at least one photo, raw file or folder of raw files")
    _check_options(bits, tile, overlap, workers, threads, device, output, checkpoint, engine)
    _check_precision(precision, engine)
    scheduler_address(scheduler)
    shooting = given_settings(fno, focus_m, focal_mm)
    offset = _parse_pair(sensor_offset, "--sensor-offset") if sensor_offset else None
    raws, photos = _split_inputs(images)
    if dng and not raws:
        raise InputError("--dng", None, "applies to camera raw inputs; none were given")
    if scheduler is not None and not raws:
        raise InputError(
            "--scheduler", None, "applies to camera raw inputs (photos are restored here); none were given"
        )
    if offset is not None and raws:
        raise InputError(
            "--sensor-offset",
            None,
            "applies to developed photos; a raw file's place on the sensor is its "
            "active area (or the place a simulated DNG records)",
        )
    if threads > 0:
        import torch

        torch.set_num_threads(threads)
    model, info, sensor_data, (sensor_w, sensor_h) = _load_model(
        checkpoint, None if zero_shot else lens_file, sensor_file, device, engine, threads
    )
    if overlap is None or tile is None:
        from lensim.restore.infer import default_overlap, default_tile

        defaults = overlap is None
        tile = default_tile(model) if tile is None else tile
        overlap = default_overlap(model) if overlap is None else overlap
        _check_tiling(tile, overlap, default=defaults)
    lens_obj = check_zero_shot(info, sensor_data, lens_file, fno) if zero_shot else None
    decoded = _check_photos(photos, offset, (sensor_w, sensor_h), getattr(model, "uses_wiener", False))
    bank_dir: Path | dict[str, Path] | None = bank
    if zero_shot and bank_dir is None:
        bank_dir = zero_shot_bank_folder(model, lens_obj, sensor_data, (fno, focus_m), quiet or json_out)
    elif bank_dir is None:  # a lens with poses: its posed banks (the run's, or computed)
        bank_dir = run_lens_bank_folder(model, info, lens_file, sensor_data, (fno, focus_m), quiet or json_out)
    photo_settings = _photo_settings(photos, shooting, info)
    stage = _stage_inputs(model, info, bank_dir, sensor_data)
    written = []
    with folder_lock(output), _tile_memory(workers):  # one writer at a time
        if raws:
            from lensim.raw.restore import RestoreSettings

            settings = RestoreSettings(
                checkpoint=info["path"],
                sensor=dict(sensor_data),
                tile=tile,
                overlap=overlap,
                device=device,
                allow_other_camera=allow_other_camera,
                shooting=shooting,
                conditioning=info["conditioning"],
                engine=engine,
                onnx=info.get("onnx"),
                bank=None if stage is None else _bank_folders(stage[0]),
                precision=precision,
            )
            written += _restore_raws(raws, output, model, settings, dng, (workers, scheduler), quiet or json_out)
        for path in photos:
            written.append(
                _restore_photo(
                    path,
                    output,
                    model,
                    (sensor_w, sensor_h),
                    offset,
                    (tile, overlap),
                    bits,
                    quiet or json_out,
                    photo_settings[path],
                    stage,
                    precision,
                    decoded.pop(path, None),
                )
            )
    if json_out:
        from lensim.restore.infer import as_engine, tile_dtype

        ran = "bfloat16" if tile_dtype(precision, as_engine(model)) is not None else "float32"
        print_json({"checkpoint": info["path"], "engine": engine, "precision": ran, "images": written})


@contextlib.contextmanager
def _tile_memory(workers: int) -> Iterator[None]:
    """A tile that no memory holds (lensim.errors.OutOfMemory of restore_image's "tile")
    as the line naming the options that size it."""
    try:
        yield
    except OutOfMemory as e:
        if e.field != "tile":
            raise
        more = ", or fewer --workers" if workers > 1 else ""
        raise OutOfMemory(
            e.source,
            "--tile",
            f"{e.message}; expected more free memory, or a smaller --overlap with a smaller --tile{more}",
        ) from None


def _check_precision(precision: str, engine: str) -> None:
    """--precision: one of lensim.restore.infer.PRECISIONS; bfloat16 only with --engine torch."""
    from lensim.restore.infer import PRECISIONS

    choice(precision, PRECISIONS, "--precision")
    if precision == "bfloat16" and engine != "torch":
        raise InputError("--precision", None, f"bfloat16 applies to --engine torch; {engine} runs float32")


def _check_tiling(tile: int | None, overlap: int | None, default: bool = False) -> None:
    """--tile and --overlap; None: the network's, known (and checked) once it is loaded."""
    too_large = tile is not None and overlap is not None and overlap >= tile
    if (tile is not None and tile < 16) or (overlap is not None and overlap < 0) or too_large:
        given = f"the network's default overlap {overlap}" if default else f"overlap {overlap}"
        raise InputError(
            "--tile/--overlap",
            None,
            f"expected a tile of at least 16 pixels and 0 <= overlap < tile, got tile {tile}, {given}",
        )


def _check_options(
    bits: int,
    tile: int | None,
    overlap: int | None,
    workers: int,
    threads: int,
    device: str,
    output: Path,
    checkpoint: Path,
    engine: str = "torch",
) -> None:
    """restore's numbers, engine, device, output folder and checkpoint path, before any work."""
    from lensim.restore.engines import ENGINES, is_onnx_path, providers_for

    choice(engine, ENGINES, "--engine")
    if bits not in (0, 8, 16):
        raise InputError("--bits", None, f"expected 8 or 16, got {bits}")
    _check_tiling(tile, overlap)
    at_least(workers, 1, "--workers", what="a number of processes")
    at_least(threads, 0, "--threads", what="a number of threads (0: PyTorch's default)")
    if engine == "torch":
        check_device(device)
    else:
        providers_for(device)
    output_folder(output)
    if not Path(checkpoint).exists():
        raise InputError(str(checkpoint), None, "no such run folder, checkpoint or ONNX file")
    if is_onnx_path(checkpoint) and engine != "onnxruntime":
        raise InputError(str(checkpoint), "--engine", "is an ONNX model; expected --engine onnxruntime to run it")


def _photo_settings(photos: list[Path], shooting: dict[str, float], info: dict) -> dict[Path, torch.Tensor | None]:
    """The settings vector of each (developed) photo (lensim.restore.conditioning.photo_vector
    of its EXIF's settings and the options'), checked before any output."""
    from lensim.raw.read import photo_exif_settings
    from lensim.restore.conditioning import Conditioning, photo_vector

    cond = Conditioning.from_dict(info["conditioning"], info["path"])
    return {path: photo_vector(cond, photo_exif_settings(path), shooting, str(path)) for path in photos}


def _photo_output_name(path: Path) -> str:
    """OUT/<name> of a restored photo: .tif for TIFF input, else .png."""
    return path.stem + (".tif" if path.suffix.lower() in (".tif", ".tiff") else ".png")


def _check_photos(
    photos: list[Path], offset: tuple[int, int] | None, sensor_wh: tuple[int, int], native: bool = False
) -> dict[Path, tuple[torch.Tensor, int]]:
    """Every photo decodes (and fits on the sensor at --sensor-offset; is at the sensor's
    native scale when ``native``: a PSF-informed network), and no two write the same
    output, before the first output. Returns the first photo's read_image, which is
    restored next (a 24 MP JPEG decodes in about 0.6 s)."""
    from lensim.images import read_image
    from lensim.restore.infer import image_sensor_geometry
    from lensim.restore.psf_stage import check_native_scale

    distinct_outputs(photos, _photo_output_name)
    first: dict[Path, tuple[torch.Tensor, int]] = {}
    for path in photos:
        image = read_image(path)
        _, h, w = image[0].shape
        _check_offset(path, offset, (w, h), sensor_wh)
        if native:
            check_native_scale(image_sensor_geometry(h, w, sensor_wh, offset)[1], sensor_wh, str(path))
        if not first:
            first[path] = image
    return first


def _check_offset(
    path: Path, offset: tuple[int, int] | None, image_wh: tuple[int, int], sensor_wh: tuple[int, int]
) -> None:
    """A native-scale crop at (top, left) = offset must lie on the sensor."""
    (w, h), (sensor_w, sensor_h) = image_wh, sensor_wh
    if offset is not None and not (0 <= offset[0] <= sensor_h - h and 0 <= offset[1] <= sensor_w - w):
        raise InputError(
            str(path),
            "--sensor-offset",
            f"a {w}x{h} image at (top, left) {offset} does not fit on the {sensor_w}x{sensor_h} sensor",
        )


def _load_model(
    checkpoint: Path,
    lens_file: str | None,
    sensor_file: str | None,
    device: str,
    engine: str = "torch",
    threads: int = 0,
) -> tuple[Any, dict, dict, tuple[int, int]]:
    """(model or engine, its info, sensor profile dict, its (width, height) in pixels): the network of a checkpoint
    (or the ONNX model: lensim.restore.engines.load_engine), warned about when the given lens or sensor differs from
    its own; the sensor is --sensor's, else the one trained for, and must record its resolution [width, height]."""
    from lensim.restore.engines import load_engine
    from lensim.sensor.profile import load_sensor

    lens_dict = None
    if lens_file is not None:
        from lensim.optics.lens_file import lens_to_dict, load_lens

        lens_dict = lens_to_dict(load_lens(lens_file))
    sensor_dict = load_sensor(sensor_file).to_dict() if sensor_file is not None else None
    model, info = load_engine(checkpoint, engine, device, threads, lens=lens_dict, sensor=sensor_dict)
    sensor_data = sensor_dict or info.get("sensor") or {}
    res = sensor_data.get("resolution") if isinstance(sensor_data, dict) else None
    if not (isinstance(res, (list, tuple)) and len(res) == 2 and all(isinstance(v, int) and v > 0 for v in res)):
        raise InputError(info["path"], "sensor", "records no sensor resolution; expected --sensor")
    return model, info, sensor_data, (int(res[0]), int(res[1]))


def _bank_folders(bank: Any) -> str | dict[str, str]:
    """A bank's folder, or a lens with poses' banks' folders by source, for the raw workers."""
    if isinstance(bank, dict):
        return {k: str(b.directory) for k, b in bank.items()}
    return str(bank.directory)


def _stage_inputs(
    model: Any, info: dict, bank: Path | dict[str, Path] | None, sensor_data: dict
) -> tuple[Any, Any] | None:
    """(PSF bank, sensor profile) for a PSF-informed network (lensim.restore.psf_stage), else
    None; a bank that is not found is one line naming --bank. A lens with poses' folders
    by source give its banks by source (the stage composes them per pixel)."""
    if isinstance(bank, dict):
        from lensim.psf.bank import PSFBank
        from lensim.sensor.profile import sensor_from_dict

        return {k: PSFBank.load(v) for k, v in bank.items()}, sensor_from_dict(sensor_data, str(info["path"]))
    if not getattr(model, "uses_wiener", False):
        if bank is not None:
            raise InputError("--bank", None, "applies to a PSF-informed network (--arch psfnet); this one is not")
        return None
    from lensim.restore.psf_stage import network_bank
    from lensim.sensor.profile import sensor_from_dict

    try:
        found = network_bank(info, bank)
    except InputError as e:
        if bank is not None or e.field != "bank":
            raise
        raise InputError("--bank", None, f"{info['path']} {e.message}") from None
    return found, sensor_from_dict(sensor_data, str(info["path"]))


def _restore_photo(
    path: Path,
    output: Path,
    model: Any,
    sensor_wh: tuple[int, int],
    offset: tuple[int, int] | None,
    tiling: tuple[int, int],
    bits: int,
    quiet: bool,
    settings: torch.Tensor | None,
    stage: tuple[Any, Any] | None = None,
    precision: str = "float32",
    decoded: tuple[torch.Tensor, int] | None = None,
) -> dict:
    """Restore one photo (a full frame, or a native-scale crop at ``offset`` = (top, left)
    sensor pixels; tiling: (tile, overlap); settings: its settings vector for a conditioned
    network; stage: (bank, sensor profile) for a PSF-informed network; precision: the
    tiles' arithmetic, lensim.restore.infer.PRECISIONS; decoded: its read_image when
    already read) into
    OUTPUT/<stem>.png (.tif for TIFF input); returns what was written."""
    tile, overlap = tiling
    from lensim.images import read_image, write_image
    from lensim.restore.infer import image_sensor_geometry, restore_image

    sensor_w, sensor_h = sensor_wh
    img, in_bits = decoded if decoded is not None else read_image(path)
    decoded = None  # the image is freed below once restored
    _, h, w = img.shape
    if offset is None:
        scale = min(sensor_w / w, sensor_h / h)
        if abs(scale - 1.0) > 0.01:
            warnings.warn(
                f"{path}: {w}x{h} pixels mapped onto the {sensor_w}x{sensor_h} sensor at "
                f"{scale:.3g} sensor pixels per image pixel; the network was trained at native scale "
                f"(1), so blur sizes differ (give --sensor-offset for a native-scale crop)",
                UserWarning,
            )
    else:
        _check_offset(path, offset, (w, h), sensor_wh)
    top_left, size = image_sensor_geometry(h, w, (sensor_w, sensor_h), offset)
    wiener = None
    if stage is not None:
        from lensim.restore.psf_stage import photo_wiener, stage_of

        wiener = photo_wiener(img, stage[0], stage[1], top_left, size, None, stage_of(model), str(path))
    with progress_bar(f"restoring {path.name}", "tiles", quiet) as tiles_done:
        try:
            out = restore_image(
                model,
                img,
                top_left,
                size,
                tile=tile,
                overlap=overlap,
                progress=tiles_done,
                settings=settings,
                wiener=wiener,
                precision=precision,
            )
        except OutOfMemory as e:
            raise OutOfMemory(str(path), e.field, e.message) from None
    del img  # bound peak memory: only the output lives while it is encoded
    out.clamp_(0, 1)
    dest = output / _photo_output_name(path)
    write_image(dest, out, bits or in_bits)
    if not quiet:
        console.print(f"restored {path} -> {dest}", highlight=False)
    return {"input": str(path), "output": str(dest), "bits": bits or in_bits, "width": w, "height": h}


__all__ = ["restore_command"]
