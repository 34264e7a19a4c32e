"""`lensim dataset make`: aligned training pairs from a folder of sharp photos."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lensim import assets
from lensim.cli.bank_options import (
    bank_or_grid_for_lens,
    bank_settings,
    cache_option,
    check_response,
    fields_option,
    pupil_samples_option,
    refuse_posed_bank,
    scheduler_option,
    setting_list_option,
    wavelengths_option,
    workers_option,
)
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.validate import at_least, choice, even, in_range, input_folder, output_folder, scheduler_address
from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.data.pairs import PosedBanks, ToleranceBanks
    from lensim.optics.lens import Lens
    from lensim.psf.bank import BankSettings, GridAxes, GridBank, PSFBank
    from lensim.sensor.profile import SensorProfile

dataset_app = typer.Typer(help="Training data: aligned (aberrated, sharp) pairs.", no_args_is_help=True)


def _check_options(
    sharp_dir: Path,
    output: Path,
    crops: int,
    size: int,
    placements: int,
    workers: int,
    demosaic: str,
    cache: Path | None,
) -> None:
    """The command's folders and numbers, before any work (one-line errors naming the option)."""
    from lensim.sensor.isp import DEMOSAIC_METHODS

    input_folder(sharp_dir, what="folder of sharp photos")
    output_folder(output)
    if cache is not None:
        output_folder(cache, "--cache")
    at_least(crops, 1, "--crops", what="a number of crops per photo")
    even(size, "--size", "a crop size in pixels")
    at_least(size, 16, "--size", "px", "a crop size")
    at_least(placements, 1, "--placements", what="a number of sensor positions per photo")
    at_least(workers, 1, "--workers", what="a number of processes")
    choice(demosaic, DEMOSAIC_METHODS, "--demosaic")


def exposure_range(text: str) -> tuple[float, float]:
    """--exposure-ev: "EV" or "LOW,HIGH" stops, each in [-8, 4], LOW <= HIGH (one-line errors)."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2):
        raise InputError("--exposure-ev", None, f"expected a number of stops or LOW,HIGH (e.g. -3,0), got {text!r}")
    for v in values:
        in_range(v, -8.0, 4.0, "--exposure-ev", "stops", "an exposure change")
    lo, hi = values[0], values[-1]
    if lo > hi:
        raise InputError("--exposure-ev", None, f"expected LOW <= HIGH, got {text!r}")
    return lo, hi


@dataset_app.command("make")
def make(
    sharp_dir: Path = typer.Argument(..., help="Folder of sharp photos (PNG, TIFF, JPEG)."),
    output: Path = typer.Option(
        ..., "-o", "--output", help="Dataset folder (resumes if it exists with the same settings)."
    ),
    lens_file: str = typer.Option(
        None,
        "--lens",
        help=f"Lens file or built-in lens name (default: the bank's lens with --bank, else {assets.DEFAULT_LENS}).",
    ),
    sensor_file: str = typer.Option(assets.DEFAULT_SENSOR, "--sensor", help="Sensor profile file or built-in name."),
    crops: int = typer.Option(8, "--crops", help="Crops per photo and placement."),
    placements: int = typer.Option(
        1,
        "--placements",
        help="Sensor positions per photo, stratified by field radius (3: centre, middle and edge zones).",
    ),
    size: int = typer.Option(256, "--size", help="Crop size in pixels (even)."),
    seed: int = typer.Option(
        0, "--seed", help="Seed of every random draw (placement, colour temperature, noise, crops)."
    ),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add shot and read noise."),
    exposure_ev: str = typer.Option(
        "0",
        "--exposure-ev",
        help="Exposure change in stops drawn per placement, "
        "uniform in LOW,HIGH (one value: fixed), applied to the photo's linear light "
        "before the camera: e.g. -3,0 adds darker, noisier scenes. 0: off.",
    ),
    demosaic: str = typer.Option("ahd", "--demosaic", help="ahd, malvar, menon or bilinear."),
    bank_dir: Path = typer.Option(
        None, "--bank", help="A PSF bank, or a grid of banks, at the sensor's pitch (default: computed and cached)."
    ),
    fno: str = setting_list_option("fno"),
    focus_m: str = setting_list_option("focus_m"),
    object_m: str = setting_list_option("object_m"),
    config: str = setting_list_option("config"),
    fields: int = fields_option(),
    wavelengths: str = wavelengths_option(),
    pupil_samples: int = pupil_samples_option(),
    workers: int = workers_option(),
    scheduler: str = scheduler_option(),
    cache: Path = cache_option(),
    tolerances: Path = typer.Option(
        None,
        "--tolerances",
        help="Tolerance file (YAML, docs/calibration.md): simulate each photo through one of "
        "--tolerance-draws perturbed copies of the lens (seeded by --seed, banks cached).",
    ),
    tolerance_draws: int = typer.Option(8, "--tolerance-draws", help="Perturbed lenses (banks) with --tolerances."),
    posed_draws: bool = typer.Option(
        False,
        "--posed-draws/--turned-draws",
        help="With --tolerances: simulate each draw with decentres or tilts through its posed banks "
        "(one per sensor quadrant and its mirrored lens's, 8 more banks per draw: every pixel gets "
        "the draw's own PSF, as calibration photographs a perturbed camera) instead of its one bank "
        "turned to every azimuth (exact for a symmetric lens only).",
    ),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    json_out: bool = typer.Option(False, "--json", help="Print a summary as JSON."),
) -> None:
    """Place each photo on the sensor at native scale (--placements seeded random positions,
    stratified by field radius), simulate the camera at each, and cut aligned crops: DATASET/pairs/*_input.png (camera) and *_target.png
    (sharp), with every crop's sensor position and every random draw in
    DATASET/manifest.json.

    Across shooting settings: --bank GRID (a grid from `psf bank --fno 2,2.8 ...`) or the
    same lists here (--fno, --focus-m, --object-m, --config: a cached grid) give each photo
    one of the grid's settings (seeded, every setting equally often); its record carries
    "settings" (resolved F-number, distances, focal length).

    Example: lensim dataset make photos/ --lens cooke_triplet --sensor apsc_mirrorless -o data/ --crops 8 --size 256 --placements 3

    With --tolerances: --tolerance-draws perturbed lenses (draws 0..K-1 of --seed), one
    cached bank each; each photo goes through one of them, every draw equally often; records
    carry "tolerance_draw", the manifest every draw's parameters. The pairs' bank (what a
    restoration uses by default) is the nominal lens's; the PSF-informed network's Wiener
    stage of each pair uses its own draw's bank. With --posed-draws each draw's photos go
    through its posed banks (lensim.render.posed; the manifest's draws list them as
    "posed_banks"), and so does their Wiener stage.

    A lens with poses (an as-built lens from `lensim calibrate`: decentred or tilted
    elements, a tilted sensor) renders through its posed banks, one per sensor quadrant and
    its mirrored lens's (8, computed with the lens's own bank: the manifest's "bank"; they
    are its "posed_banks"); `lensim train`, `evaluate` and `restore` then use them too.

    Example: lensim dataset make photos/ --lens double_gauss --sensor full_frame --fno 2,2.8,4 --focus-m inf,3 -o data/

    Example: lensim dataset make photos/ --lens cooke_triplet --tolerances tol.yaml --tolerance-draws 8 -o data/
    """
    from lensim.data.pairs import make_dataset
    from lensim.psf.bank import GridAxes, GridBank
    from lensim.sensor.profile import load_sensor

    settings = bank_settings(fields, wavelengths, pupil_samples, cache)
    _check_options(sharp_dir, output, crops, size, placements, workers, demosaic, cache)
    scheduler_address(scheduler)
    ev_range = exposure_range(exposure_ev)
    axes = GridAxes.from_options(fno, focus_m, object_m, config)
    if bank_dir is not None and axes.given:
        raise InputError(
            "--bank",
            None,
            "the bank (or grid of banks) fixes the shooting settings; expected --bank or "
            "--fno/--focus-m/--object-m/--config, not both",
        )
    if posed_draws and tolerances is None:
        raise InputError("--posed-draws", None, "renders tolerance draws; expected --tolerances with it")
    sensor = load_sensor(sensor_file)
    quiet = quiet or json_out
    bank: PSFBank | GridBank | ToleranceBanks | PosedBanks
    if tolerances is not None:
        _check_tolerances(tolerances, tolerance_draws, bank_dir, axes)
        bank = _tolerance_banks(
            lens_file,
            tolerances,
            (tolerance_draws, seed, posed_draws),
            (sharp_dir, size, sensor, settings),
            workers,
            quiet,
            scheduler,
        )
    elif bank_dir is not None:
        bank, bank_lens = bank_or_grid_for_lens(bank_dir, lens_file)
        refuse_posed_bank(bank_lens)
    else:
        bank = _lens_bank(lens_file, sharp_dir, size, sensor, settings, axes, workers, quiet, scheduler)
    with progress_bar("pairs", "photos", quiet) as cb:
        manifest = make_dataset(
            sharp_dir,
            output,
            bank,
            sensor_file,
            sensor,
            crops=crops,
            size=size,
            seed=seed,
            placements=placements,
            noise=noise,
            demosaic=demosaic,
            workers=workers,
            scheduler=scheduler,
            progress=cb,
            exposure_ev=ev_range,
        )
    summary = {
        "output": str(output),
        "photos": len(manifest["records"]),
        "pairs": manifest["pairs"],
        "bank": str(manifest["bank"]),
        "seed": seed,
        **({"settings": len(bank)} if isinstance(bank, GridBank) else {}),
        **({"tolerance_draws": len(manifest["tolerances"]["draws"])} if "tolerances" in manifest else {}),
    }
    if json_out:
        print_json(summary)
    elif not quiet:
        console.print(f"wrote {summary['pairs']} pairs from {summary['photos']} photos to {output}", highlight=False)


def _lens_bank(
    lens_file: str | None,
    sharp_dir: Path,
    size: int,
    sensor: SensorProfile,
    settings: BankSettings,
    axes: GridAxes,
    workers: int,
    quiet: bool,
    scheduler: str | None,
) -> PSFBank | GridBank | PosedBanks:
    """The lens's bank at the sensor's pitch (a grid of banks over ``axes`` when given),
    cached or computed, once the spectral response and the photos are known to work; a
    lens with poses: its posed banks (_posed_lens_banks)."""
    from lensim.data.pairs import check_photos, list_images
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import get_bank

    lens = load_lens(lens_file or assets.DEFAULT_LENS)
    if lens.has_poses and axes.given:
        raise InputError(
            "--lens",
            lens_file,
            "is a lens with poses, rendered through its posed banks at one setting; expected no "
            "--fno, --focus-m, --object-m or --config lists with it",
        )
    check_response(settings, sensor.spectral_response, sensor=sensor)
    check_photos(list_images(sharp_dir), size)  # before the bank, which takes minutes
    if lens.has_poses:
        return _posed_lens_banks(lens, sensor, settings, (workers, scheduler), quiet)
    with progress_bar("PSF grid" if axes.given else "PSF bank", "fields", quiet) as report:
        return get_bank(
            lens,
            sensor.pixel_pitch_um,
            settings,
            response=sensor.spectral_response,
            shooting=axes if axes.given else None,
            workers=workers,
            scheduler=scheduler,
            progress=report,
        )


def _posed_lens_banks(
    lens: Lens, sensor: SensorProfile, settings: BankSettings, where: tuple[int, str | None], quiet: bool
) -> PosedBanks:
    """A lens with poses' posed banks over the whole sensor (lensim.render.posed.sensor_banks)
    and its own bank (the pairs' "bank"), cached or computed together; where: (workers,
    scheduler)."""
    from lensim.data.pairs import PosedBanks
    from lensim.psf.bank import BankRequest, PSFBank, get_banks
    from lensim.render.posed import sensor_banks

    lenses = [lens]

    def index_of(one: Lens) -> int:
        lenses.append(one)
        return len(lenses) - 1

    keyed = sensor_banks(lens, sensor, index_of)
    requests = [BankRequest(m, sensor.pixel_pitch_um, settings, response=sensor.spectral_response) for m in lenses]
    with progress_bar(f"PSF banks of the lens with poses ({len(lenses)})", "fields", quiet) as report:
        computed = get_banks(requests, workers=where[0], scheduler=where[1], progress=report)
    banks = [b for b in computed if isinstance(b, PSFBank)]
    by_source = keyed if isinstance(keyed, dict) else {"all": keyed}
    return PosedBanks({k: banks[i] for k, i in by_source.items()}, banks[0])


def _check_tolerances(tolerances: Path, draws: int, bank_dir: Path | None, axes: GridAxes) -> None:
    """--tolerances with --tolerance-draws, and without a given bank or grid."""
    from lensim.cli.validate import input_file

    input_file(tolerances, "--tolerances", "tolerance file")
    in_range(draws, 1, 1000, "--tolerance-draws", what="a number of perturbed lenses")
    if bank_dir is not None or axes.given:
        raise InputError(
            "--tolerances",
            None,
            "perturbed lenses get banks of their own; expected --tolerances without --bank, --fno, "
            "--focus-m, --object-m or --config",
        )


def _tolerance_banks(
    lens_file: str | None,
    tolerances: Path,
    how: tuple[int, int, bool],
    job: tuple[Path, int, SensorProfile, BankSettings],
    workers: int,
    quiet: bool,
    scheduler: str | None,
) -> ToleranceBanks:
    """The nominal lens's bank and the banks of draws 0..draws-1 of `seed` (how: draws,
    seed, posed: also each draw's posed banks, lensim.render.posed.posed_banks over the
    whole sensor; a nominal lens with poses, an as-built one, also gets its posed banks:
    ToleranceBanks.nominal_posed), cached (a rerun or a killed run reuses every field computed), computed
    together once the photos are known to work. job: (folder of sharp photos, crop size,
    sensor, bank settings)."""
    from lensim.calibrate.tolerances import drawn_lens, load_tolerances
    from lensim.data.pairs import PosedBanks, ToleranceBanks, check_photos, list_images
    from lensim.optics.lens_file import lens_to_dict, load_lens
    from lensim.psf.bank import BankRequest, PSFBank, get_banks
    from lensim.render.mapping import native_mapping
    from lensim.render.posed import posed_banks, sensor_banks

    draws, seed, posed = how
    sharp_dir, size, sensor, settings = job
    lens = load_lens(lens_file or assets.DEFAULT_LENS)
    tol = load_tolerances(tolerances, lens)
    check_response(settings, sensor.spectral_response, sensor=sensor)
    check_photos(list_images(sharp_dir), size)
    drawn = [drawn_lens(lens, tol, seed, k) for k in range(draws)]
    records = [{k: m.as_built[k] for k in ("seed", "draw", "parameters")} for m in drawn]
    lenses = [lens, *drawn]

    def index_of(one: Lens) -> int:
        lenses.append(one)
        return len(lenses) - 1

    keyed: list[dict[str, int]] = []  # each draw's posed banks as indices into lenses (appended)
    if posed:
        full = native_mapping(sensor.height, sensor.width, sensor, 0, 0)
        keyed = [posed_banks(m, full, index_of) for m in drawn]
    nominal = sensor_banks(lens, sensor, index_of)  # 0, or a lens with poses' posed banks
    requests = [BankRequest(m, sensor.pixel_pitch_um, settings, response=sensor.spectral_response) for m in lenses]
    with progress_bar("PSF banks (nominal lens, tolerance draws)", "fields", quiet) as report:
        computed = get_banks(requests, workers=workers, scheduler=scheduler, progress=report)
    banks = [b for b in computed if isinstance(b, PSFBank)]
    out = ToleranceBanks(banks[1 : draws + 1], lens_to_dict(lens), str(tolerances), records, banks[0])
    if isinstance(nominal, dict):
        out.nominal_posed = {k: banks[i] for k, i in nominal.items()}
    if posed:
        out.posed = [
            PosedBanks({k: banks[i] for k, i in ks.items()}, b) for ks, b in zip(keyed, out.banks, strict=True)
        ]
    return out
