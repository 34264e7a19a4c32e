"""`lensim restore` with the universal model (zero-shot): no training run, the lens and the
sensor named instead (lensim.restore.universal).

``lensim restore universal PHOTO... --lens LENS --sensor SENSOR -o OUT``, or with --lens the
checkpoint left out (``lensim restore --lens LENS --sensor SENSOR PHOTO... -o OUT``): the
shipped universal model restores the photos. A sensor pitch or an F-number outside the
ranges the model was trained across is one line naming --sensor or --fno (exit status 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lensim.errors import InputError


def universal_inputs(
    checkpoint: Path, images: list[Path], lens: str | None, sensor: str | None
) -> tuple[Path, list[Path], bool]:
    """(checkpoint path, images, zero-shot?): CHECKPOINT "universal" is the shipped model;
    with --lens given, a CHECKPOINT that is a photo or raw file is the first image and the
    shipped model restores them all, and a CHECKPOINT that is a universal model of the user's
    own (`lensim library pretrain --ship`: a folder holding model.pt, or that file) restores
    them zero-shot as the shipped one would. Zero-shot needs --lens and --sensor (one line
    naming them)."""
    from lensim.images import READ_SUFFIXES
    from lensim.raw import RAW_SUFFIXES
    from lensim.restore.universal import NAME, is_universal_model, model_path

    photo = checkpoint.suffix.lower() in (*READ_SUFFIXES, *RAW_SUFFIXES)
    shipped = str(checkpoint) == NAME or (lens is not None and photo)
    own = not shipped and lens is not None and is_universal_model(checkpoint)
    if not (shipped or own):
        return checkpoint, images, False
    if lens is None or sensor is None:
        raise InputError(
            "--lens/--sensor", None, "the universal model restores a lens it is told: expected --lens and --sensor"
        )
    if own:
        return model_path(checkpoint), images, True
    return model_path(NAME), (images if str(checkpoint) == NAME else [checkpoint, *images]), True


def zero_shot_bank_folder(
    model: Any, lens: Any, sensor_data: dict, shooting: tuple[float | None, float | None], quiet: bool
) -> Path | dict[str, Path] | None:
    """The PSF bank folder of the lens (loaded) at the sensor's pitch and shooting =
    (fno, focus_m), from the bank cache or computed into it with a progress bar, for a
    universal model that is PSF-informed (lensim.restore.psfnet); for a lens with poses
    (an as-built lens from `lensim calibrate`) its banks' folders by sensor source
    (lensim.render.posed.sensor_banks: 8 banks); None for a model that is not PSF-informed."""
    if not getattr(model, "uses_wiener", False):
        return None
    from lensim.cli.common import progress_bar
    from lensim.render.posed import sensor_banks
    from lensim.restore.universal import zero_shot_bank
    from lensim.sensor.profile import sensor_from_dict

    sensor = sensor_from_dict(sensor_data, "--sensor")
    title = "PSF banks of the lens with poses (8)" if lens.has_poses else "PSF bank of the lens"
    with progress_bar(title, "fields", quiet) as report:
        banks = sensor_banks(
            lens, sensor, lambda one: zero_shot_bank(one, sensor, shooting[0], shooting[1], progress=report)
        )
    if isinstance(banks, dict):  # cached banks: in their folders
        return {key: Path(str(bank.directory)) for key, bank in banks.items()}
    return Path(str(banks.directory))


def run_lens_bank_folder(
    model: Any,
    info: dict,
    lens_file: str | None,
    sensor_data: dict,
    shooting: tuple[float | None, float | None],
    quiet: bool,
) -> Path | dict[str, Path] | None:
    """The banks' folders a trained PSF-informed network's stage takes for photos of
    --lens when that lens has poses (lensim.render.posed.sensor_banks): None (the run's
    own bank, lensim.restore.psf_stage.network_bank) when no lens is given, the network
    is not PSF-informed, the lens has no poses, or the run's pairs were rendered through
    this very lens's posed banks (its stage takes those); else the lens's posed banks as
    zero-shot computes them (zero_shot_bank_folder)."""
    if lens_file is None or not getattr(model, "uses_wiener", False):
        return None
    import json

    from lensim.optics.lens_file import lens_to_dict, load_lens
    from lensim.restore.psf_stage import network_bank

    lens = load_lens(lens_file, warn=False)
    if not lens.has_poses:
        return None
    same = json.dumps(info.get("lens"), sort_keys=True, default=str)
    if same == json.dumps(lens_to_dict(lens), sort_keys=True, default=str):
        try:
            if isinstance(network_bank(info), dict):
                return None
        except InputError:
            pass  # the run's pairs are not here: the lens's banks are computed
    return zero_shot_bank_folder(model, lens, sensor_data, shooting, quiet)


def check_zero_shot(info: dict, sensor_data: dict, lens: str, fno: float | None) -> Any:
    """The lens (loaded) after checking that the universal model serves it: the sensor's
    pitch and the F-number (--fno, else the lens's own) inside the model's trained ranges;
    one-line InputErrors naming the option."""
    from lensim.restore.checkpoint import read_checkpoint
    from lensim.restore.universal import check_range, load_lens_or_entry, zero_shot_fno

    universal = read_checkpoint(info["path"]).get("universal") or {}
    lens_obj = load_lens_or_entry(lens)
    check_range(universal, "pixel_pitch_um", float(sensor_data["pixel_pitch_um"]), "--sensor")
    check_range(universal, "fno", zero_shot_fno(lens_obj, fno), "--fno" if fno is not None else "--lens")
    return lens_obj
