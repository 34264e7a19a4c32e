"""The Wiener stage of the PSF-informed network (issue 23, ``arch="psfnet"``): what the
lens's PSF bank knows, as an image the network sees beside the aberrated one.

The stage is the Wiener oracle of lensim.evaluate.baselines (:func:`baselines.wiener`;
the computation's one home is lensim.evaluate.wiener_tiles): per square tile of ``tile``
pixels the bank's kernel at the tile's sensor position and azimuth, per colour channel,
deconvolves a window (the tile, ``ramp`` / 2 + ``margin`` pixels of context per side) in
the camera's energy domain with a natural-image prior (NSR falling as 1/|f|^2), and
neighbouring tiles cross-fade over ``ramp`` pixels (seamless). The
stage gives it exactly the same arguments the oracle gets: the capture's colour pipeline
(CCM, white-balance gains) and noise levels when they are known (simulated pairs record
them; a raw file's develop gives the colour, not the noise level), else the sRGB curve
only and the noise floor. Nothing in it depends on the lens except through the bank's
kernels, so a network trained on its output is lens-agnostic given the bank.

Shapes: images (3, H, W) float32 sRGB in [0, 1]; the stage's output likewise (clipped to
[0, 1] in linear sRGB by from_energy).

Cache (:func:`ensure_wiener_cache`, training): the stage of every crop of a pairs folder,
computed once and read by the training crops. Layout:

    DATASET/wiener/<key>/<crop input file name>   16-bit PNG, the stage's output for
                                                  that input crop (quantisation 1/65535)
    DATASET/wiener/<key>/stage.json               {"format": "lensim-wiener-cache",
                                                  "version": 2, "stage": WienerStage.to_dict(),
                                                  "bank": stage_bank_entry(manifest),
                                                  "crops": how many} written last

The stage of a crop is computed with the bank its photo was simulated with
(:func:`stage_bank_entry`; lensim.evaluate.harness.record_banks): the manifest's "bank" (a
grid's bank of the record's setting); for pairs of a lens with poses, rendered through its
posed banks (the manifest's "posed_banks"; an as-built lens from `lensim calibrate`),
those banks by source at the crop's place on the sensor (:func:`wiener_channels`), as for
a tolerance draw rendered through its posed banks (the draw's "posed_banks");
and for pairs made through tolerance draws (``lensim dataset make --tolerances``; their
manifest says "stage_bank": "tolerance_draw") the bank of the record's draw, not the
nominal lens's, which is their "bank" (what a restoration has at inference). Measured
(docs/calibration.md, section 6): a network fine-tuned with each draw's own stage restores
a perturbed unit with the nominal lens's stage 0.1-0.6 dB better (centre to edge) than one
fine-tuned with the nominal lens's stage on every pair. ``key`` is a digest of the stage's
settings and its banks, so a change of either computes a new cache beside the old one.
Every file is written atomically and an existing one is kept: a killed computation
resumes where it stopped.

Whole photos (:func:`photo_wiener`): the stage runs on the whole photo (it is tiled and
seamless itself) before the network's tiles are cut, so each network tile reads the same
stage pixels it would in a whole-image pass. The bank must be at the photo's pixel scale:
photos are taken at the sensor's native resolution (a full frame, or a frame whose place
on the sensor is known).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lensim.errors import InputError

if TYPE_CHECKING:  # torch is imported where the stage runs, not by the configs that name it
    import torch

#: Where a pairs folder's stage caches live (one sub-folder per stage key).
CACHE_DIR = "wiener"
CACHE_FORMAT = "lensim-wiener-cache"
#: 2: the stage of lensim.evaluate.wiener_tiles (64 px tiles, float32); 1: the
#: per-32-pixel mirrored windows before it.
CACHE_VERSION = 2
STAGE_JSON = "stage.json"


FIELDS = ("tile", "noise_floor", "ramp", "margin")


@dataclass(frozen=True)
class WienerStage:
    """The stage's settings (recorded in the network's config as ``stage``).

    tile: side of the square tiles, pixels, one kernel and NSR each (default 64);
    ramp: width of the cross-fade between neighbouring tiles, pixels (even, <= tile);
    margin: context beyond the cross-fade on every side of a tile's window, pixels;
    noise_floor: variance added to the capture's noise, normalized raw units squared
        (lensim.evaluate.baselines.DEFAULT_NOISE_FLOOR).

    Configs written before the stage's fast computation ({tile, noise_floor}, tile then
    the spacing of 32 px mirrored windows, which no longer exist) read as that noise
    floor with today's layout: the two stages' images differ by about 55 dB PSNR."""

    tile: int = 64
    noise_floor: float = 1e-5
    ramp: int = 16
    margin: int = 16

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "stage") -> WienerStage:
        """The stage a config records (None: the defaults; a config without ``ramp``: the
        old stage's, see the class docstring); InputError naming ``source`` for unknown
        keys or values out of range."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping) or set(data) - set(FIELDS):
            raise InputError(source, "stage", f"expected {{{', '.join(FIELDS)}}}, got {data!r}")
        if "ramp" not in data and "margin" not in data:  # the old stage's config
            data = {"noise_floor": data.get("noise_floor", 1e-5)}
        d = cls()
        try:
            stage = cls(
                int(data.get("tile", d.tile)),
                float(data.get("noise_floor", d.noise_floor)),
                int(data.get("ramp", d.ramp)),
                int(data.get("margin", d.margin)),
            )
        except (TypeError, ValueError) as e:
            raise InputError(source, "stage", f"expected numbers, got {data!r}") from e
        good = stage.tile >= 1 and 0 <= stage.ramp <= stage.tile and stage.ramp % 2 == 0 and stage.margin >= 0
        if not good or not stage.noise_floor >= 0:
            raise InputError(
                source,
                "stage",
                f"expected tile >= 1, an even ramp in [0, tile], margin >= 0 and noise_floor >= 0, got {data!r}",
            )
        return stage


def wiener_channels(
    image: torch.Tensor,
    mapping: Any,
    bank: Any,
    capture: Mapping[str, Any] | None = None,
    stage: WienerStage | None = None,
) -> torch.Tensor:
    """The stage's output for one image: (3, H, W) float32 sRGB in [0, 1].

    image: (3, H, W) sRGB in [0, 1]; mapping: its pixels on the sensor
    (lensim.render.mapping.SensorMapping, at the bank's pitch); bank: lensim.psf.bank.PSFBank,
    or the banks of a lens with poses by source (lensim.render.posed.posed_banks): then each
    pixel takes the stage computed with its own source's bank, as the lens is rendered
    (pixel_sources; only the sources with pixels in the image are computed, each on the
    box of its pixels: _posed_stage); or a list (tuple) of either, a tolerance
    distribution's draws, for a unit whose draw is unknown: the tolerance-robust stage, per
    tile and channel the minimum-mean-square-error linear filter over the draws,
    conj(E[H]) / (E[|H|^2] + NSR) (lensim.evaluate.wiener_tiles; draws with poses: per
    source, the draws' banks of that source, a symmetric draw's one bank in every source);
    capture: the capture record (ccm, r_gain, b_gain, shot, read; lensim.data.pairs
    crop_capture) or None. The Wiener oracle itself (lensim.evaluate.baselines.wiener)."""
    from lensim.evaluate.baselines import wiener

    st = stage or WienerStage()
    if isinstance(bank, (list, tuple)):
        if not bank:
            raise ValueError("expected a PSF bank, or several; got an empty list")
        if any(isinstance(b, Mapping) for b in bank):
            return _posed_stage(image, mapping, draws_by_source(bank), capture, st)
        bank = tuple(bank)
    elif isinstance(bank, Mapping):
        return _posed_stage(image, mapping, bank, capture, st)
    return wiener(image, mapping, bank, capture, st.tile, None, st.noise_floor, st.ramp, st.margin)


def draws_by_source(draws: Sequence[Any]) -> dict[str, tuple[Any, ...]]:
    """Several draws' banks (each a PSFBank, or a lens with poses' banks by source:
    lensim.render.posed.posed_banks) -> per posed source, the draws' banks of that source
    (a symmetric draw's one bank, or its "all", in every source): the tolerance-robust
    stage's banks (wiener_channels). Every draw with poses must have the same sources."""
    from lensim.render.posed import MIRROR, QUADRANTS

    posed = [set(b) - {"all"} for b in draws if isinstance(b, Mapping) and set(b) - {"all"}]
    keys = posed[0] if posed else {"all"}
    if any(k != keys for k in posed):
        raise ValueError(f"expected every draw with poses to have the same sources, got {sorted(map(sorted, posed))}")
    if posed and not keys <= {q + m for q in QUADRANTS for m in ("", MIRROR)}:
        raise ValueError(f"unknown posed sources {sorted(keys)}")

    def of(b: Any, key: str) -> Any:
        if not isinstance(b, Mapping):
            return b
        return b[key] if key in b else b["all"]

    return {k: tuple(of(b, k) for b in draws) for k in sorted(keys)}


def _posed_stage(
    image: torch.Tensor, mapping: Any, banks: Mapping[str, Any], capture: Mapping[str, Any] | None, st: WienerStage
) -> torch.Tensor:
    """wiener_channels with banks by source (lensim.render.posed): each source's stage is
    computed on the box of its pixels grown by `pad` (whole tiles holding every window
    that reaches the box: the tiles' grid stays the whole image's, so the box's pixels
    are what a whole-image pass gives) and kept at its pixels. A 24 MP frame with 8 posed
    banks: 9.9-10.5 s on 2 threads, against 3.3 s with one bank (21-22 s before the boxes
    and the vectorized mirrored_pixels)."""
    import numpy as np
    import torch

    from lensim.render.mapping import SensorMapping
    from lensim.render.posed import MIRROR, pixel_sources

    if "all" in banks:
        return wiener_channels(image, mapping, banks["all"], capture, st)
    h, w = int(image.shape[-2]), int(image.shape[-1])
    pad = st.tile * (2 + (st.ramp + st.margin) // st.tile)  # a tile's window reaches tile + ramp / 2 + margin
    p = mapping.pitch_um * 1e-3
    out = torch.zeros(3, h, w, dtype=torch.float32)
    for key, mask in pixel_sources((h, w), mapping, any(k.endswith(MIRROR) for k in banks)).items():
        if not mask.any():
            continue
        rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
        y0, x0 = max(0, (int(rows[0]) - pad) // st.tile * st.tile), max(0, (int(cols[0]) - pad) // st.tile * st.tile)
        y1, x1 = min(h, int(rows[-1]) + 1 + pad), min(w, int(cols[-1]) + 1 + pad)
        box = SensorMapping(y1 - y0, x1 - x0, mapping.pitch_um, mapping.x0_mm + x0 * p, mapping.y0_mm + y0 * p)
        part = wiener_channels(image[:, y0:y1, x0:x1], box, banks[key], capture, st)
        inside = torch.from_numpy(mask[y0:y1, x0:x1])
        out[:, y0:y1, x0:x1][:, inside] = part[:, inside]
    return out


def photo_wiener(
    image: torch.Tensor,
    bank: Any,
    sensor: Any,
    sensor_top_left: tuple[float, float],
    sensor_size: tuple[float, float],
    capture: Mapping[str, Any] | None = None,
    stage: WienerStage | None = None,
    source: str = "photo",
) -> torch.Tensor:
    """The stage over a whole photo placed on the sensor as lensim.restore.infer places it
    (sensor_top_left, sensor_size: in image pixels, image_sensor_geometry). The photo must
    be at the sensor's native pixel scale (its sensor_size the sensor's resolution), since
    the bank's kernels are sampled at the sensor's pitch; otherwise a one-line InputError
    naming ``source``. Returns (3, H, W) float32."""
    from lensim.render.mapping import SensorMapping

    check_native_scale(sensor_size, (sensor.width, sensor.height), source)
    sh, sw = (float(v) for v in sensor_size)
    top, left = (float(v) for v in sensor_top_left)
    p = sensor.pixel_pitch_um * 1e-3
    _, h, w = image.shape
    mapping = SensorMapping(h, w, sensor.pixel_pitch_um, (left - sw / 2.0) * p, (top - sh / 2.0) * p)
    return wiener_channels(image, mapping, bank, capture, stage)


def check_native_scale(sensor_size: tuple[float, float], sensor_wh: tuple[int, int], source: str) -> None:
    """One-line InputError naming ``source`` unless a photo whose sensor spans sensor_size
    (height, width) of its pixels (lensim.restore.infer.image_sensor_geometry) is at the
    sensor's native pixel scale (sensor_wh: the sensor's (width, height) in pixels): the
    bank's kernels are sampled at the sensor's pitch."""
    sh, sw = (float(v) for v in sensor_size)
    if abs(sh - sensor_wh[1]) > 1e-6 or abs(sw - sensor_wh[0]) > 1e-6:
        raise InputError(
            source,
            "size",
            f"is not at the sensor's native pixel scale (the sensor would span {sw:g}x{sh:g} of its pixels, "
            f"expected {sensor_wh[0]}x{sensor_wh[1]}); the PSF-informed network restores photos at the "
            "sensor's resolution (a whole frame, or a crop placed with its sensor offset)",
        )


def stage_of(model: Any) -> WienerStage:
    """The WienerStage a network (lensim.restore.psfnet.PSFNet) or engine (an exported one:
    lensim.restore.engines.OnnxEngine) was trained with."""
    stage = getattr(model, "stage", None)
    return stage if isinstance(stage, WienerStage) else WienerStage()


def network_bank(info: Mapping[str, Any], bank: Any = None) -> Any:
    """The PSF bank a PSF-informed network restores with: ``bank`` (a PSFBank or its
    folder) when given, else the bank of the pairs the network was trained on (``info``:
    what lensim.restore.checkpoint.load_checkpoint / engines.load_engine return; its
    "dataset" manifest's "bank", or the posed banks by source of pairs of a lens with
    poses: lensim.evaluate.harness.pairs_bank_entry). One-line InputError naming the
    checkpoint (field "bank") when neither is found, or when it is a grid of banks (one
    setting's bank is needed)."""
    from lensim.psf.bank import GridBank, PSFBank

    where = str(info.get("path", "checkpoint"))
    found: Any = None
    if isinstance(bank, PSFBank):
        found = bank
    elif bank is not None:
        found = PSFBank.load(bank)
    elif info.get("dataset"):
        from lensim.data.manifest import read_pairs_manifest
        from lensim.evaluate.harness import _load_bank

        pairs = Path(str(info["dataset"]))
        if (pairs / "manifest.json").is_file():
            found = _load_bank(read_pairs_manifest(pairs), pairs, None)
    if found is None:
        raise InputError(
            where,
            "bank",
            f"is a PSF-informed network, which needs the PSF bank of the lens; the pairs it was trained on "
            f"({info.get('dataset')}) name none that exists here; expected the bank's folder",
        )
    if isinstance(found, GridBank):
        raise InputError(where, "bank", "is a grid of banks; expected the bank of the photos' shooting settings")
    return found


# ----------------------------------------------------------------------------- cache


def stage_bank_entry(manifest: Mapping[str, Any], where: str = "manifest.json") -> Any:
    """What the Wiener stage of a pairs folder is computed with, as its cache key records
    it: the manifest's "bank" (for a grid, each record's setting's bank), or its posed
    banks' folders by source (pairs of a lens with poses: a dict, so that a stage of
    posed banks never reads a cache of the single bank's), or for pairs made through
    tolerance draws ("stage_bank": "tolerance_draw"; older manifests have their
    "tolerances" only) {"tolerance_draw": [each draw's bank folder, or posed banks' folders]}:
    each record's stage uses the bank of the draw its photo went through (its
    "tolerance_draw"; lensim.evaluate.harness.record_banks); for pairs whose stage is the
    tolerance-robust one ("stage_bank": "tolerance_robust") {"tolerance_robust": [each
    draw's bank folder, or posed banks' folders]}: every record's stage is the robust stage
    over all the draws. where: the manifest's path, named by a one-line InputError when a
    robust stage's draws are missing."""
    from lensim.data.pairs import STAGE_PER_DRAW, STAGE_ROBUST
    from lensim.evaluate.harness import pairs_bank_entry, robust_draws, tolerance_draw_banks

    if manifest.get("stage_bank") == STAGE_ROBUST:  # every record: the robust stage over all draws
        return {STAGE_ROBUST: [pairs_bank_entry(d) for d in robust_draws(manifest, where)]}
    draws = tolerance_draw_banks(manifest)
    return pairs_bank_entry(manifest) if draws is None else {STAGE_PER_DRAW: draws}


def _stage_banks(manifest: Mapping[str, Any], root: Path, bank: Any) -> Callable[[int, Mapping[str, Any]], Any]:
    """(record index, record) -> the PSF bank of that record's stage
    (lensim.evaluate.harness.record_banks); a bank not found is a one-line InputError naming
    the manifest."""
    from lensim.data.manifest import MANIFEST
    from lensim.data.pairs import STAGE_PER_DRAW, STAGE_ROBUST
    from lensim.evaluate.harness import record_banks

    resolve = record_banks(manifest, root, bank)

    def get(i: int, rec: Mapping[str, Any]) -> Any:
        found = resolve(i, rec)
        if found is None:
            entry = stage_bank_entry(manifest)
            if isinstance(entry, dict) and STAGE_ROBUST in entry:
                entry = {str(k): v for k, v in enumerate(entry[STAGE_ROBUST])}
            elif isinstance(entry, dict) and STAGE_PER_DRAW in entry:
                entry = entry[STAGE_PER_DRAW][rec["tolerance_draw"]]
            named = ", ".join(sorted(map(str, entry.values()))) if isinstance(entry, dict) else entry
            raise InputError(
                str(root / MANIFEST),
                "bank",
                f"names the bank {named!r}, which was not found; the PSF-informed "
                "network needs the bank the pairs were made with",
            )
        return found

    return get


def cache_key(stage: WienerStage, bank_entry: Any) -> str:
    """The cache folder name of a stage on a pairs folder whose stage bank is ``bank_entry``
    (:func:`stage_bank_entry`)."""
    text = json.dumps({"stage": stage.to_dict(), "bank": bank_entry, "version": CACHE_VERSION}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def cache_folder(dataset_dir: str | Path, stage: WienerStage | None = None) -> Path:
    """DATASET/wiener/<key> of a stage (the folder may not exist yet)."""
    from lensim.data.manifest import read_pairs_manifest

    manifest = read_pairs_manifest(dataset_dir)
    return Path(dataset_dir) / CACHE_DIR / cache_key(stage or WienerStage(), stage_bank_entry(manifest))


def cached_path(folder: Path, input_path: Path) -> Path:
    """The cache file of the crop whose aberrated input is ``input_path``."""
    return folder / (Path(input_path).stem + ".png")


def ensure_wiener_cache(
    dataset_dir: str | Path,
    stage: WienerStage | None = None,
    bank: Any = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Compute the stage of every crop of a pairs folder that is not cached yet (module
    docstring); returns the cache folder. bank: the PSF bank (or grid) the pairs were made
    with, loaded already or its folder if it moved (default: the manifest's; the cache is
    named after the manifest's, so give no other; none for pairs made through tolerance
    draws, each record's is its draw's: :func:`stage_bank_entry`). A bank that cannot be
    found is a one-line InputError naming the pairs folder. progress(done, total) counts
    crops."""
    from lensim.data.manifest import MANIFEST, read_pairs_manifest
    from lensim.data.pairs import STAGE_PER_DRAW, STAGE_ROBUST, crop_capture
    from lensim.images import read_image, write_image
    from lensim.io import atomic_write_json
    from lensim.render.mapping import native_mapping
    from lensim.sensor.profile import sensor_from_dict

    root = Path(dataset_dir)
    st = stage or WienerStage()
    manifest = read_pairs_manifest(root)
    entry = stage_bank_entry(manifest, str(root / MANIFEST))
    if bank is not None and isinstance(entry, dict) and (STAGE_PER_DRAW in entry or STAGE_ROBUST in entry):
        raise InputError(
            str(root / MANIFEST),
            "bank",
            "names pairs made through tolerance draws, whose Wiener stage uses the draws' banks; "
            "expected no other bank",
        )
    folder = root / CACHE_DIR / cache_key(st, entry)
    sensor = sensor_from_dict(manifest["sensor"], str(root / MANIFEST))
    crops = [(i, rec, cr) for i, rec in enumerate(manifest["records"]) for cr in rec.get("crops", [])]
    todo = [(i, rec, cr) for i, rec, cr in crops if not cached_path(folder, root / cr["input"]).exists()]
    if todo or not (folder / STAGE_JSON).is_file():
        bank_of = _stage_banks(manifest, root, bank)
        todo.sort(key=lambda t: str(t[1].get("tolerance_draw", "")))  # one draw's bank after the other
        for i, rec, _ in todo[:1]:
            bank_of(i, rec)  # a bank not found: nothing written
        folder.mkdir(parents=True, exist_ok=True)
        for done, (i, rec, cr) in enumerate(todo, 1):
            x, _ = read_image(root / cr["input"])
            _, h, w = x.shape
            mapping = native_mapping(h, w, sensor, int(cr["sensor_top"]), int(cr["sensor_left"]))
            out = wiener_channels(x, mapping, bank_of(i, rec), crop_capture(rec, cr), st)
            write_image(cached_path(folder, root / cr["input"]), out.clamp(0.0, 1.0), bits=16)
            if progress is not None:
                progress(done, len(todo))
        info = {
            "format": CACHE_FORMAT,
            "version": CACHE_VERSION,
            "stage": st.to_dict(),
            "bank": entry,
            "crops": len(crops),
        }
        atomic_write_json(folder / STAGE_JSON, info)
    return folder


def training_cache(dataset_dir: str | Path, model_config: Mapping[str, Any]) -> Path | None:
    """The Wiener stage cache a network of ``model_config`` trains from (computed where
    missing: :func:`ensure_wiener_cache`), or None for a network without the stage."""
    if model_config.get("arch") != "psfnet":
        return None
    return ensure_wiener_cache(dataset_dir, WienerStage.from_dict(model_config.get("stage")))


__all__ = [
    "CACHE_DIR",
    "WienerStage",
    "cache_folder",
    "cache_key",
    "cached_path",
    "check_native_scale",
    "draws_by_source",
    "ensure_wiener_cache",
    "network_bank",
    "photo_wiener",
    "stage_bank_entry",
    "stage_of",
    "training_cache",
    "wiener_channels",
]
