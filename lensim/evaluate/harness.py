"""Evaluation harness: PSNR / SSIM of restoration methods on a pairs dataset, overall and
per field zone (issue 5, `lensim evaluate`).

A pairs dataset (lensim.data.pairs) holds aligned crops: the simulated camera image
(``input``) and the sharp original (``target``), each with the absolute sensor position of
its top-left pixel. Every method restores every input crop; the result is scored against
the target with lensim.evaluate.metrics (sRGB values, data range 1; zones by each
pixel's normalized radius on the sensor: centre < 1/3, middle 1/3..2/3, edge >= 2/3 of the
sensor half-diagonal). The method ``input`` (the aberrated crop itself) is always
evaluated first, as the reference every gain is measured from.

A method is a callable ``method(image, ctx) -> image``: image (3, H, W) float32 sRGB in
[0, 1]; ctx a :class:`CropContext` (sensor mapping, sensor, PSF bank, capture record, the
crop's sensor offset). Outputs are clipped to [0, 1] before scoring. Built-in methods:
``input``, ``wiener``, ``rl``, ``unsharp`` (lensim.evaluate.baselines; the first two are
oracles using the true bank), and ``model`` / ``plain`` (the plain network baseline;
``plain-unet`` is its old name, an alias: :data:`METHOD_ALIASES`) from `lensim train`
checkpoints (:func:`checkpoint_method`, via lensim.restore.infer; a PSF-informed network
gets each crop's Wiener stage image, lensim.restore.psf_stage). Pairs of a lens with poses
(made through its posed banks: the manifest's "posed_banks", or a tolerance draw's) give
each crop those banks by source (:func:`record_banks`): the oracles and the stage compose
them per pixel as the pairs were rendered (lensim.render.posed).

Aggregation (the summary JSON):
  * ``psnr_db``, ``ssim``: mean over crops of each crop's PSNR (dB) and mean SSIM;
  * per zone: ``psnr_db`` is the mean of the per-crop zone PSNRs weighted by each crop's
    pixel count in that zone (crops with no pixel there do not count); ``ssim`` is the
    mean of the SSIM map over all the zone's valid SSIM pixels of all crops (pixels at
    least 5 px from a crop border). A zone with no pixel in the whole dataset scores NaN
    (``null`` in the CLI's JSON).

Summary shape (exactly): ``{"methods": {NAME: {"psnr_db": x, "ssim": x, "zones":
{"centre": {"psnr_db": x, "ssim": x}, "middle": {...}, "edge": {...}}}}}``.
Per-crop rows (:func:`evaluate_rows`, :func:`write_csv`) hold every score and the zone
pixel counts; :func:`markdown_table` renders the summary.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lensim.data.manifest import MANIFEST, read_pairs_manifest
from lensim.data.pairs import STAGE_ROBUST, crop_capture
from lensim.errors import InputError, ParameterError
from lensim.evaluate import baselines
from lensim.evaluate.metrics import ZONES, image_scores, normalized_radius
from lensim.images import read_image
from lensim.io import atomic_write_text
from lensim.psf.bank import MANIFEST as BANK_MANIFEST
from lensim.psf.bank import GridBank, PSFBank
from lensim.psf.bank.grid import is_grid
from lensim.render.mapping import SensorMapping, native_mapping
from lensim.sensor.profile import SensorProfile, sensor_from_dict

#: Method names understood by :func:`builtin_method` (``model``, ``plain`` and ``universal``,
#: the shipped universal model (lensim.restore.universal), need a checkpoint: :func:`checkpoint_method`).
BUILTIN_METHODS: tuple[str, ...] = ("input", "wiener", "rl", "unsharp")
CHECKPOINT_METHODS: tuple[str, ...] = ("model", "plain", "universal")
#: Old method names still understood: alias -> the method it names (results stay keyed by
#: the name the user wrote).
METHOD_ALIASES: dict[str, str] = {"plain-unet": "plain"}


@dataclass(frozen=True)
class CropContext:
    """What a method may know about a crop besides its pixels.

    mapping: the crop's pixels on the sensor (pitch um, corner position mm); sensor: the
    dataset's sensor profile; bank: the PSF bank the pairs were simulated with, or the
    banks by source of a lens with poses (lensim.render.posed.sensor_banks; None when
    not found); capture: the record's capture draw (ccm, white-balance gains,
    noise), or None; top, left: sensor pixel of the crop's top-left pixel; record, crop:
    indices in the manifest; settings: the record's shooting settings (fno, focus_m,
    focal_mm; lensim.restore.conditioning.record_settings), None for pairs without."""

    mapping: SensorMapping
    sensor: SensorProfile
    bank: PSFBank | dict[str, PSFBank] | None
    capture: Mapping[str, Any] | None
    top: int
    left: int
    record: int
    crop: int
    settings: Mapping[str, float] | None = None


Method = Callable[[torch.Tensor, CropContext], torch.Tensor]


# ---------------------------------------------------------------------------------------
# methods


def _need_bank(ctx: CropContext, name: str) -> PSFBank | dict[str, PSFBank]:
    if ctx.bank is None:
        raise ParameterError(
            None,
            "bank",
            f"method {name!r} needs the dataset's PSF bank; it was not found (pass its folder as `bank`)",
        )
    return ctx.bank


def _oracle(name: str, baseline: Callable[..., torch.Tensor], options: Mapping[str, Any]) -> Method:
    """A baseline given the crop's bank; with banks by source (a lens with poses) each
    source's result at its pixels, the whole crop restored once per source it holds
    (lensim.render.posed.compose_rendered: as the crop was rendered). Several draws' banks
    (a tuple: the tolerance-robust filter, for the Wiener oracle) go to the baseline
    together, per source where the draws have poses (psf_stage.draws_by_source)."""
    from lensim.render.posed import compose_rendered

    def run(image: torch.Tensor, ctx: CropContext) -> torch.Tensor:
        bank: Any = _need_bank(ctx, name)
        if isinstance(bank, (list, tuple)) and any(isinstance(b, Mapping) for b in bank):
            from lensim.restore.psf_stage import draws_by_source

            bank = draws_by_source(bank)
        if not isinstance(bank, Mapping):
            return baseline(image, ctx.mapping, bank, ctx.capture, **options)
        return compose_rendered(
            lambda key: baseline(image, ctx.mapping, bank[key], ctx.capture, **options),
            bank,
            ctx.mapping,
            (int(image.shape[-2]), int(image.shape[-1])),
        )

    return run


def builtin_method(name: str, **options: Any) -> Method:
    """A built-in method by name: ``input`` (identity), ``wiener``, ``rl``, ``unsharp``;
    options go to the baseline (e.g. ``iterations`` for rl, ``sigma_px`` for unsharp)."""
    if name == "input":
        return lambda image, ctx: image
    if name == "wiener":
        return _oracle(name, baselines.wiener, options)
    if name == "rl":
        return _oracle(name, baselines.richardson_lucy, options)
    if name == "unsharp":
        return lambda image, ctx: baselines.unsharp_mask(image, ctx.mapping, None, ctx.capture, **options)  # no bank
    raise InputError(
        None, "methods", f"unknown method {name!r}; expected one of {', '.join(BUILTIN_METHODS + CHECKPOINT_METHODS)}"
    )


def checkpoint_method(
    run: str | Path,
    lens: Mapping[str, Any] | None = None,
    sensor: Mapping[str, Any] | None = None,
    device: str = "cpu",
    tile: int = 512,
    overlap: int | None = None,
    arch: str | None = None,
    precision: str = "float32",
) -> Method:
    """A trained network (`lensim train` run folder or checkpoint) as a method: each crop is
    restored by lensim.restore.infer.restore_image with its absolute sensor offset (native
    scale) and the sensor's size in pixels. lens / sensor (dataset settings) make
    load_checkpoint warn when the checkpoint was trained for another camera. A network
    conditioned on shooting settings gets each crop's record's settings vector (pairs
    without settings are then an InputError); a crop whose settings lie outside the
    checkpoint's trained ranges is warned about (UserWarning) or, far outside, refused for
    a conditioned network (lensim.restore.conditioning.Conditioning.check). arch: when
    given, the checkpoint must hold that architecture ("unet" or "nafnet"; InputError
    naming the file otherwise). precision: the tiles' arithmetic
    (lensim.restore.infer.PRECISIONS)."""
    from lensim.restore.checkpoint import load_checkpoint
    from lensim.restore.conditioning import Conditioning
    from lensim.restore.infer import restore_image
    from lensim.restore.models import arch_of

    model, info = load_checkpoint(
        run, lens=dict(lens) if lens else None, sensor=dict(sensor) if sensor else None, device=device
    )
    if arch is not None and arch_of(info["model_config"]) != arch:
        raise InputError(
            info["path"],
            "model_config",
            f"holds a {arch_of(info['model_config'])!r} network; expected {arch!r} (`arch`)",
        )
    cond = Conditioning.from_dict(info["conditioning"], info["path"])

    def restore(image: torch.Tensor, ctx: CropContext) -> torch.Tensor:
        vec = None
        if ctx.settings is not None:
            for text in cond.check(ctx.settings, str(run)):
                warnings.warn(text, UserWarning, stacklevel=2)
        if cond.dim:
            if ctx.settings is None:
                raise InputError(
                    str(run),
                    "conditioning",
                    f"the network is conditioned on {', '.join(cond.keys)}; "
                    f"record {ctx.record} of the pairs has no settings; expected pairs made across "
                    "shooting settings",
                )
            vec = cond.vector(ctx.settings, str(run))
        return restore_image(
            model,
            image,
            (float(ctx.top), float(ctx.left)),
            (float(ctx.sensor.height), float(ctx.sensor.width)),
            tile=tile,
            overlap=overlap,
            settings=vec,
            wiener=_stage_image(model, image, ctx),
            precision=precision,
        )

    return restore


def _stage_image(model: Any, image: torch.Tensor, ctx: CropContext) -> torch.Tensor | None:
    """The Wiener stage's image of a crop for a network that takes it (lensim.restore.psfnet:
    the crop's bank, mapping and capture, as the training cache computed it), else None."""
    if not getattr(model, "uses_wiener", False):
        return None
    from lensim.restore.psf_stage import wiener_channels

    return wiener_channels(image, ctx.mapping, _need_bank(ctx, "model"), ctx.capture, model.stage)


# ---------------------------------------------------------------------------------------
# dataset


def pairs_bank_entry(manifest: Mapping[str, Any]) -> Any:
    """The bank folder the pairs (or a tolerance draw's pairs) were rendered with, as the
    manifest names it: its "posed_banks" (a lens with poses: folders by source,
    lensim.data.pairs.PosedBanks) when there, else its "bank"."""
    posed = manifest.get("posed_banks")
    return dict(posed) if isinstance(posed, Mapping) and posed else manifest.get("bank")


def _load_bank(
    manifest: Mapping[str, Any], pairs_dir: Path, bank: PSFBank | GridBank | str | Path | None
) -> PSFBank | GridBank | dict[str, PSFBank] | None:
    """The bank (or grid of banks) the pairs were made with: given, or the manifest's
    (:func:`pairs_bank_entry`; banks by source for a lens with poses, None if one is
    missing)."""
    if isinstance(bank, (PSFBank, GridBank)):
        return bank
    if isinstance(bank, (list, tuple)):  # several draws' banks: the tolerance-robust stage
        return tuple(bank)  # type: ignore[return-value]
    if bank is not None:
        return GridBank.load(bank) if is_grid(bank) else PSFBank.load(bank)
    entry = pairs_bank_entry(manifest)
    if isinstance(entry, dict):
        found = {k: _load_bank({"bank": v}, pairs_dir, None) for k, v in entry.items()}
        ok = all(isinstance(b, PSFBank) for b in found.values())
        return {k: b for k, b in found.items() if isinstance(b, PSFBank)} if ok else None
    path = entry
    if not path:
        return None
    for cand in (Path(path), pairs_dir / path):
        if is_grid(cand):
            return GridBank.load(cand)
        if (cand / BANK_MANIFEST).is_file():
            return PSFBank.load(cand)
    return None


def _record_bank(
    bank: PSFBank | GridBank | dict[str, PSFBank] | None, record: Mapping[str, Any], where: str
) -> PSFBank | dict[str, PSFBank] | None:
    """The bank a record's photo was simulated with: a grid's bank of the record's
    setting (its grid_setting), else the one bank (or banks by source)."""
    if not isinstance(bank, GridBank):
        return bank
    k = record.get("grid_setting")
    if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < len(bank):
        raise InputError(
            where,
            "grid_setting",
            f"expected the index of one of the grid's {len(bank)} settings ({bank.directory}), got {k!r}",
        )
    return bank.bank(k)


def tolerance_draw_banks(manifest: Mapping[str, Any]) -> list[Any] | None:
    """Each draw's bank folder (as the manifest names it; a draw rendered through its
    posed banks: their folders by source, :func:`pairs_bank_entry`) of
    pairs made through tolerance draws (lensim.data.pairs.ToleranceBanks: the manifest's
    "tolerances"), else None."""
    tol = manifest.get("tolerances")
    if not isinstance(tol, Mapping):
        return None
    draws = tol.get("draws")
    return [pairs_bank_entry(d) if isinstance(d, Mapping) else None for d in (draws if isinstance(draws, list) else [])]


def robust_draws(manifest: Mapping[str, Any], where: str) -> list[Mapping[str, Any]]:
    """The draws (the manifest's "tolerances" "draws") of pairs whose Wiener stage is the
    tolerance-robust one; a manifest without them is a one-line InputError naming `where`."""
    tol = manifest.get("tolerances")
    draws = tol.get("draws") if isinstance(tol, Mapping) else None
    if not isinstance(draws, list) or not draws or not all(isinstance(d, Mapping) for d in draws):
        raise InputError(where, "tolerances", "expected the draws of the tolerance-robust stage")
    return draws


def robust_stage_banks(manifest: Mapping[str, Any], pairs_dir: Path) -> tuple[Any, ...] | None:
    """The banks of the tolerance-robust stage of pairs whose manifest says "stage_bank":
    STAGE_ROBUST (lensim.data.pairs): every draw's bank, or its posed banks by source where
    the manifest lists them (:func:`pairs_bank_entry`), as a tuple
    (lensim.restore.psf_stage.wiener_channels takes it); None for other pairs or where a
    bank is not found."""
    if manifest.get("stage_bank") != STAGE_ROBUST:
        return None
    found = [_load_bank(d, pairs_dir, None) for d in robust_draws(manifest, str(pairs_dir / MANIFEST))]
    return tuple(found) if all(isinstance(b, (PSFBank, dict)) for b in found) else None


def record_banks(
    manifest: Mapping[str, Any], pairs_dir: Path, bank: PSFBank | GridBank | str | Path | None = None
) -> Callable[[int, Mapping[str, Any]], PSFBank | dict[str, PSFBank] | None]:
    """(record index, record) -> the PSF bank that record's photo was simulated with
    (CropContext.bank, and the Wiener stage's: lensim.restore.psf_stage): the manifest's
    bank, a grid's bank of the record's setting, or for pairs made through tolerance draws
    the bank of the record's draw (its "tolerance_draw"; the manifest's "bank" is then the
    nominal lens's); pairs (or draws) of a lens with poses rendered through its posed banks
    give those by source (:func:`pairs_bank_entry`); pairs whose stage is the
    tolerance-robust one ("stage_bank": STAGE_ROBUST) give every draw's banks, a tuple
    (:func:`robust_stage_banks`). ``bank`` (a bank, grid or folder, or a list of banks or of
    lenses' posed banks by source: the tolerance-robust stage) replaces the manifest's when
    given. None where the bank is not found; a record without
    a valid setting or draw is a one-line InputError naming the manifest."""
    from functools import lru_cache

    where = str(pairs_dir / MANIFEST)
    if bank is None and manifest.get("stage_bank") == STAGE_ROBUST:
        robust = robust_stage_banks(manifest, pairs_dir)
        return lambda i, rec: robust  # type: ignore[return-value]
    draws = tolerance_draw_banks(manifest) if bank is None else None
    if draws is None:
        the_bank = _load_bank(manifest, pairs_dir, bank)
        return lambda i, rec: _record_bank(the_bank, rec, f"{where}: records[{i}]")
    folders = draws

    @lru_cache(maxsize=8)  # evaluate reads records in order, draws mixed (dataset make draws 8 by default)
    def load(k: int) -> PSFBank | dict[str, PSFBank] | None:
        entry = folders[k]
        found = _load_bank({"posed_banks": entry} if isinstance(entry, dict) else {"bank": entry}, pairs_dir, None)
        return found if isinstance(found, (PSFBank, dict)) else None

    def pick(i: int, rec: Mapping[str, Any]) -> PSFBank | dict[str, PSFBank] | None:
        k = rec.get("tolerance_draw")
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < len(folders):
            raise InputError(
                f"{where}: records[{i}]",
                "tolerance_draw",
                f"expected one of the {len(folders)} draws' index, got {k!r}",
            )
        return load(k)

    return pick


def _record_settings(record: Mapping[str, Any], pairs_dir: Path, index: int) -> dict[str, float] | None:
    """A record's shooting settings for the methods (None when it has none)."""
    from lensim.restore.conditioning import record_settings

    if record.get("settings") is None:
        return None
    return record_settings(record["settings"], str(pairs_dir / MANIFEST), f"records[{index}].settings")


def evaluate_rows(
    pairs_dir: str | Path,
    methods: Mapping[str, Method],
    bank: PSFBank | GridBank | str | Path | None = None,
    sources: Sequence[str] | None = None,
    max_crops: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """Score every method on every crop of a pairs dataset; one row per (crop, method).

    methods: name -> method (``input`` is added first when absent). bank: the PSF bank
    (object or folder; default the one the manifest names, if it exists), or a grid of
    banks (each record then uses its setting's bank, its grid_setting); by default, pairs
    made through tolerance draws use each record's draw's bank (:func:`record_banks`).
    sources: keep only records whose source photo's file name (or full path) is listed (e.g. the
    held-out photos of a training run). max_crops: stop after this many crops.
    progress(done, total) counts crops. Rows: record, crop, source, input, sensor_top,
    sensor_left, method, psnr_db, ssim, mse and per zone <zone>_psnr_db, <zone>_ssim,
    <zone>_pixels, <zone>_ssim_pixels."""
    pairs_dir = Path(pairs_dir)
    manifest = read_pairs_manifest(pairs_dir)
    sensor = sensor_from_dict(manifest["sensor"], str(pairs_dir / MANIFEST))
    bank_of = record_banks(manifest, pairs_dir, bank)
    all_methods: dict[str, Method] = {"input": builtin_method("input")}
    all_methods.update(methods)
    crops = _select_crops(manifest["records"], sources)
    if max_crops is not None:
        crops = crops[:max_crops]
    if not crops:
        raise InputError(str(pairs_dir), "records", "no crops to evaluate (check `sources`)")
    rows: list[dict] = []
    if progress:
        progress(0, len(crops))
    for done, (ri, ci, rec, cr) in enumerate(crops, 1):
        rows += _crop_rows(pairs_dir, sensor, bank_of(ri, rec), all_methods, ri, ci, rec, cr)
        if progress:
            progress(done, len(crops))
    return rows


def _select_crops(records: list[dict], sources: Sequence[str] | None) -> list[tuple[int, int, dict, dict]]:
    """(record index, crop index, record, crop) of every crop, of the records whose source
    photo's file name or full path is in ``sources`` (all records when None)."""
    keep = set(sources) if sources is not None else None
    crops = []
    for ri, rec in enumerate(records):
        src = str(rec.get("source", ""))
        if keep is not None and src not in keep and Path(src).name not in keep:
            continue
        for ci, cr in enumerate(rec.get("crops", [])):
            crops.append((ri, ci, rec, cr))
    return crops


def _crop_rows(
    pairs_dir: Path,
    sensor: SensorProfile,
    bank: PSFBank | dict[str, PSFBank] | None,
    methods: Mapping[str, Method],
    ri: int,
    ci: int,
    rec: dict,
    cr: dict,
) -> list[dict]:
    """The rows of one crop (crop ``ci`` of record ``ri``): one per method (evaluate_rows)."""
    x, _ = read_image(pairs_dir / cr["input"])
    y, _ = read_image(pairs_dir / cr["target"])
    if x.shape != y.shape:
        raise InputError(str(pairs_dir / cr["input"]), "size", f"is {tuple(x.shape)}; its target is {tuple(y.shape)}")
    _, h, w = x.shape
    top, left = int(cr["sensor_top"]), int(cr["sensor_left"])
    ctx = CropContext(
        native_mapping(h, w, sensor, top, left),
        sensor,
        bank,
        crop_capture(rec, cr),
        top,
        left,
        ri,
        ci,
        _record_settings(rec, pairs_dir, ri),
    )
    rho = normalized_radius(h, w, top, left, sensor.height, sensor.width)
    rows = []
    for name, method in methods.items():
        out = method(x, ctx)
        if tuple(out.shape) != tuple(x.shape):
            raise ValueError(f"method {name!r} returned shape {tuple(out.shape)}; expected {tuple(x.shape)}")
        s = image_scores(out.detach().float().cpu().clamp(0.0, 1.0), y, rho)
        row = {
            "record": ri,
            "crop": ci,
            "source": rec.get("source", ""),
            "input": cr["input"],
            "sensor_top": top,
            "sensor_left": left,
            "method": name,
            "psnr_db": s["psnr_db"],
            "ssim": s["ssim"],
            "mse": s["mse"],
        }
        for z in ZONES:
            for k in ("psnr_db", "ssim", "pixels", "ssim_pixels"):
                row[f"{z}_{k}"] = s["zones"][z][k]
        rows.append(row)
    return rows


def _mean(values: list[float], weights: list[float] | None = None) -> float:
    v = np.asarray(values, dtype=np.float64)
    wt = np.ones_like(v) if weights is None else np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(v) & (wt > 0)
    if not ok.any():
        return math.nan
    return float(np.sum(v[ok] * wt[ok]) / np.sum(wt[ok]))


def summarize(rows: Sequence[Mapping[str, Any]]) -> dict:
    """The summary JSON of per-crop rows (shape and aggregation: module docstring). Method
    order is that of first appearance in the rows."""
    names: list[str] = []
    for r in rows:
        if r["method"] not in names:
            names.append(r["method"])
    out: dict = {"methods": {}}
    for name in names:
        rs = [r for r in rows if r["method"] == name]
        zones = {}
        for z in ZONES:
            zones[z] = {
                "psnr_db": _mean([r[f"{z}_psnr_db"] for r in rs], [r[f"{z}_pixels"] for r in rs]),
                "ssim": _mean([r[f"{z}_ssim"] for r in rs], [r[f"{z}_ssim_pixels"] for r in rs]),
            }
        out["methods"][name] = {
            "psnr_db": _mean([r["psnr_db"] for r in rs]),
            "ssim": _mean([r["ssim"] for r in rs]),
            "zones": zones,
        }
    return out


def evaluate(
    pairs_dir: str | Path,
    methods: Mapping[str, Method],
    bank: PSFBank | GridBank | str | Path | None = None,
    sources: Sequence[str] | None = None,
    max_crops: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    rows: list | None = None,
) -> dict:
    """PSNR / SSIM of each method (and ``input``) on a pairs dataset, overall and per zone,
    as ``{"methods": {NAME: {"psnr_db", "ssim", "zones": {zone: {"psnr_db", "ssim"}}}}}``.
    Arguments as :func:`evaluate_rows`; when ``rows`` is a list the per-crop rows are
    appended to it."""
    got = evaluate_rows(pairs_dir, methods, bank=bank, sources=sources, max_crops=max_crops, progress=progress)
    if rows is not None:
        rows.extend(got)
    return summarize(got)


# ---------------------------------------------------------------------------------------
# writers


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """Per-crop rows as CSV text (header from the first row; floats with 6 decimals,
    NaN as empty)."""
    if not rows:
        return ""
    buf = io.StringIO()
    wr = csv.DictWriter(buf, fieldnames=list(rows[0].keys()), lineterminator="\n")
    wr.writeheader()
    for r in rows:
        wr.writerow(
            {
                k: ("" if isinstance(v, float) and not math.isfinite(v) else f"{v:.6f}" if isinstance(v, float) else v)
                for k, v in r.items()
            }
        )
    return buf.getvalue()


def write_csv(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Write per-crop rows as CSV (atomically); returns the path."""
    path = Path(path)
    atomic_write_text(path, csv_text(rows))
    return path


def format_score(x: float | None, digits: int) -> str:
    """A score for a table: ``digits`` decimals, a dash for a missing or non-finite one."""
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """The summary as a markdown table: one row per method, PSNR (dB) and SSIM overall and
    per zone, and the PSNR gain over ``input`` (dB) when it is present."""
    methods = summary["methods"]
    base = methods.get("input")
    head = ["method", "PSNR (dB)", "gain (dB)", "SSIM"]
    for z in ZONES:
        head += [f"{z} PSNR", f"{z} SSIM"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for name, m in methods.items():
        gain = m["psnr_db"] - base["psnr_db"] if base is not None else math.nan
        cells = [name, format_score(m["psnr_db"], 2), format_score(gain, 2), format_score(m["ssim"], 4)]
        for z in ZONES:
            cells += [format_score(m["zones"][z]["psnr_db"], 2), format_score(m["zones"][z]["ssim"], 4)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_markdown(summary: Mapping[str, Any], path: str | Path, title: str | None = None) -> Path:
    """Write the markdown table (with an optional heading) atomically; returns the path."""
    path = Path(path)
    text = (f"# {title}\n\n" if title else "") + markdown_table(summary)
    atomic_write_text(path, text)
    return path
