"""Reading a pairs folder's manifest and a training run's split: the one reader of each,
validated once, with one-line errors naming the file.

DATASET/manifest.json (written last by lensim.data.pairs.make_dataset):
    format       "lensim-pairs"
    sensor       the sensor profile (SensorProfile.to_dict()); ``resolution`` = [width,
                 height] in pixels
    lens, sensor_name, bank, seed, crops, placements, size, noise, demosaic, sources,
    pairs        the settings the pairs were made with
    records[i]   one per photo: ``source`` (the sharp photo's path), ``crops[k]`` =
                 {input, target, sensor_top, sensor_left, placement}: paths relative to
                 DATASET of the aberrated and sharp crops, and the absolute sensor pixel
                 of the crop's top-left corner; ``settings`` (pairs made across a grid
                 of shooting settings; all records or none): lensim.optics.shooting.describe's
                 dict {fno, focus_m, object_m, focal_mm, config}, its fno / focus_m /
                 focal_mm checked by lensim.restore.conditioning.record_settings
RUN/split.json (written by lensim.restore.train): ``train`` and ``val`` lists of source
photo names, ``val_fraction``, ``seed``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lensim.errors import InputError
from lensim.io import read_json

MANIFEST = "manifest.json"
FORMAT = "lensim-pairs"
SPLIT = "split.json"
CROP_KEYS = ("input", "target", "sensor_top", "sensor_left")


def read_pairs_manifest(pairs_dir: str | Path) -> dict[str, Any]:
    """The validated manifest of a pairs folder (module docstring); a one-line InputError
    naming the folder or file when it is missing, corrupt, foreign or incomplete."""
    root = Path(pairs_dir)
    path = root / MANIFEST
    if not root.is_dir():
        raise InputError(str(root), None, "no such folder; expected a pairs folder from `lensim dataset make`")
    if not path.is_file():
        raise InputError(str(path), None, "no such file; expected a finished `lensim dataset make` folder")
    manifest = read_json(path, "pairs manifest")
    if not isinstance(manifest, dict):
        raise InputError(str(path), None, "expected a JSON object")
    if manifest.get("format", FORMAT) != FORMAT:
        raise InputError(
            str(path), "format", f"expected {FORMAT!r}, got {manifest['format']!r}; not a pairs dataset manifest"
        )
    sensor = manifest.get("sensor")
    res = sensor.get("resolution") if isinstance(sensor, dict) else None
    if not (isinstance(res, list) and len(res) == 2 and all(isinstance(v, int) and v > 0 for v in res)):
        raise InputError(str(path), "sensor.resolution", f"expected [width, height] in pixels, got {res!r}")
    records = manifest.get("records")
    if not isinstance(records, list) or not records:
        raise InputError(str(path), "records", "expected a non-empty list of photo records")
    for i, record in enumerate(records):
        crops = record.get("crops") if isinstance(record, dict) else None
        if not isinstance(crops, list) or not crops:
            raise InputError(str(path), f"records[{i}].crops", "expected a non-empty list of crops")
        for k, crop in enumerate(crops):
            if not isinstance(crop, dict) or not all(key in crop for key in CROP_KEYS):
                raise InputError(str(path), f"records[{i}].crops[{k}]", f"expected {{{', '.join(CROP_KEYS)}}}")
    _check_settings(records, str(path))
    return manifest


def _check_settings(records: list[dict[str, Any]], source: str) -> None:
    """Shooting settings are on every record or on none, and each one's numbers are valid."""
    from lensim.restore.conditioning import record_settings

    have = [i for i, r in enumerate(records) if r.get("settings") is not None]
    if have and len(have) != len(records):
        lacking = next(i for i, r in enumerate(records) if r.get("settings") is None)
        raise InputError(
            source,
            f"records[{lacking}].settings",
            f"missing, while records[{have[0]}] has shooting settings; expected settings on every record or on none",
        )
    for i in have:
        record_settings(records[i]["settings"], source, f"records[{i}].settings")


def read_held_out(run_dir: str | Path) -> list[str]:
    """The validation source photos a `lensim train` run recorded in RUN/split.json (file
    names or paths, as the run saw them); a one-line InputError when the file is missing,
    corrupt or holds none."""
    path = Path(run_dir) / SPLIT
    if not path.is_file():
        raise InputError(str(path), None, "missing; expected a `lensim train` run folder")
    split = read_json(path, "training split")
    val = split.get("val") if isinstance(split, dict) else None
    if not isinstance(val, list) or not all(isinstance(v, str) for v in val):
        raise InputError(str(path), "val", "expected the run's validation photos (a list of names)")
    if not val:
        raise InputError(str(path), "val", "is empty: the run held out no photos")
    return list(val)


__all__ = ["CROP_KEYS", "FORMAT", "MANIFEST", "SPLIT", "read_held_out", "read_pairs_manifest"]
