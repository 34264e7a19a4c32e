"""Issue 16 part 3's measurement: one network conditioned on the shooting settings against
a network trained at one setting, per-setting networks with the same total budget and an
unconditioned network trained on the same grid, on held-out photos at settings on the
grid and between grid points, PSNR by field zone.

Usage (from the repository root; every stage is cached in OUT, a rerun skips what exists):

    .venv/bin/python benchmarks/settings_conditioned.py [OUT] [--steps N] [--photos K]

What it does:

1. the lens: the built-in Cooke triplet (f = 50 mm, F/5) on the APS-C sensor (3.92 um);
   the grid: F/5 and F/8 (wide open and 1 1/3 stops down) x focused at infinity and at
   0.5 m (0 and 2 dioptres); between the grid points: F/5.6 at 0.7 m and F/7.1 at 2 m
   (neither in the middle of a cell, so each has one nearest grid setting);
2. per setting a PSF bank (lensim.optics.shooting.lens_at; 6 sqrt-spaced fields, 450-650
   nm every 50 nm, 96 pupil samples) and a pairs folder (`lensim dataset make`'s
   make_dataset: K built-in photos centre-cropped to 256 px, 3 sensor placements x 2 crops
   of 96 px, noise and AHD as always, seed 0), each record given ``"settings":
   describe(lens, settings)``; the grid's four pairs folders merged into one (records of
   all four, crops referenced in place);
3. networks (width 16, DCN at the coarsest decoder scale, 64-px crops, batch 4, Adam 5e-4
   cosine over the steps, one thread, seed 0, a quarter of the photos held out, the same
   photos for every run since the split depends only on the photo names and the seed):
   ``conditioned`` on the grid, N steps; ``mixed``: the grid without settings
   (--no-settings), N steps; ``single``: F/5 at infinity only (the lens file's own
   setting: the network one would train before issue 16), N steps; ``per-setting``: one
   network per grid setting, N/4 steps each (N in all);
4. evaluation (lensim.evaluate.harness) of the last checkpoints on the held-out photos'
   crops at every setting: PSNR overall and in the centre / middle / edge zones; the
   per-setting networks restore each setting with the network of the nearest grid setting
   (in the features the conditioning uses: stops and dioptres, each over the grid's span).

Writes OUT/results.json (every figure, steps and seconds per run) and OUT/table.md.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from pathlib import Path
from typing import Any

import torch

# the defaults (the committed results); --lens, --grid, --between and --single change them
LENS = "cooke_triplet"
GRID = [(5.0, math.inf), (5.0, 0.5), (8.0, math.inf), (8.0, 0.5)]
BETWEEN = [(5.6, 0.7), (7.1, 2.0)]
SINGLE = (5.0, math.inf)


def _settings(text: str) -> list[tuple[float, float]]:
    """'F:D,F:D' -> [(fno, focus_m)] (D may be inf)."""
    return [(float(a), float(b)) for a, b in (item.split(":") for item in text.split(","))]


ZONES = ("centre", "middle", "edge")


def tag(fno: float, focus: float) -> str:
    return f"f{fno:g}_{'inf' if math.isinf(focus) else f'{focus:g}m'}"


def photos(out: Path, k: int) -> Path:
    """The first k built-in photos, centre-cropped to 256 px (as `lensim demo --quick`)."""
    from lensim.assets.images import available_sample_images, read_sample_image
    from lensim.images import write_image

    d = out / "photos"
    if d.is_dir() and len(list(d.glob("*.png"))) == k:
        return d
    d.mkdir(parents=True, exist_ok=True)
    for img in available_sample_images()[:k]:
        arr = read_sample_image(img.name)
        _, h, w = arr.shape
        s = min(256, h, w)
        y, x = (h - s) // 2, (w - s) // 2
        write_image(d / f"{img.name}.png", arr[:, y : y + s, x : x + s])
    return d


def pairs_for(out: Path, sharp: Path, fno: float, focus: float) -> Path:
    """A pairs folder at one setting, its records given the setting (describe's dict)."""
    from lensim.data.pairs import make_dataset
    from lensim.io import atomic_write_json, read_json
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import ShootingSettings, describe, lens_at
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import load_sensor

    d = out / "pairs" / tag(fno, focus)
    if (d / "settings.done").exists():
        return d
    lens, sensor = load_lens(LENS), load_sensor("apsc_mirrorless")
    shot = ShootingSettings(fno=fno, focus_m=focus)
    at = lens_at(lens, shot)
    bank = get_bank(
        at,
        sensor.pixel_pitch_um,
        BankSettings(
            fields=6, wavelengths_nm=(450.0, 500.0, 550.0, 600.0, 650.0), pupil_samples=96, cache_dir=out / "banks"
        ),
        response=sensor.spectral_response,
    )
    make_dataset(sharp, d, bank, "apsc_mirrorless", sensor, crops=2, size=96, placements=3, seed=0)
    manifest = read_json(d / "manifest.json", "pairs manifest")
    settings = describe(lens, shot)
    for r in manifest["records"]:
        r["settings"] = settings
    atomic_write_json(d / "manifest.json", manifest)
    (d / "settings.done").write_text("")
    return d


def merged(out: Path, parts: list[Path]) -> Path:
    """One pairs folder holding the records of ``parts`` (crops referenced in place)."""
    from lensim.io import atomic_write_json, read_json

    d = out / "pairs" / "grid"
    if (d / "manifest.json").exists():
        return d
    d.mkdir(parents=True, exist_ok=True)
    records: list[dict[str, Any]] = []
    manifest: dict[str, Any] = {}
    for p in parts:
        manifest = read_json(p / "manifest.json", "pairs manifest")
        for r in manifest["records"]:
            r = dict(r, index=len(records))
            r["crops"] = [
                dict(c, input=f"../{p.name}/{c['input']}", target=f"../{p.name}/{c['target']}") for c in r["crops"]
            ]
            records.append(r)
    atomic_write_json(
        d / "manifest.json", {**manifest, "records": records, "bank": None, "merged_from": [p.name for p in parts]}
    )
    return d


def train_run(pairs: Path, run: Path, steps: int, **extra: Any) -> dict[str, Any]:
    """Train for ``steps`` optimizer steps (cached by RUN/done.json)."""
    from lensim.restore.train import train

    marker = run / "done.json"
    if marker.exists():
        return json.loads(marker.read_text())
    if run.exists():
        import shutil

        shutil.rmtree(run)
    from lensim.data.manifest import read_pairs_manifest
    from lensim.restore.dataset import crop_refs, split_sources

    refs = crop_refs(pairs, read_pairs_manifest(pairs))
    train_src, _ = split_sources([r.source for r in refs], 0.25, 0)
    n_train = sum(r.source in set(train_src) for r in refs)
    per_epoch = max(1, n_train // 4)
    # the fewest epochs of at most a whole epoch's batches each that make exactly ``steps`` steps
    epochs = next(e for e in range(max(1, math.ceil(steps / per_epoch)), steps + 1) if steps % e == 0)
    t0 = time.perf_counter()
    result = train(
        pairs,
        run,
        epochs=epochs,
        max_steps_per_epoch=steps // epochs,
        batch_size=4,
        lr=5e-4,
        lr_schedule="cosine",
        crop=64,
        arch="unet",
        width=16,
        deformable_scales=1,
        val_fraction=0.25,
        seed=0,
        checkpoint_every_s=None,
        **extra,
    )
    done = {"steps": result.step, "seconds": time.perf_counter() - t0, "val_psnr": result.val_psnr}
    marker.write_text(json.dumps(done))
    return done


def spot_sizes() -> dict[str, list[float]]:
    """Polychromatic RMS spot radius (um) of the lens at every setting, at 0 and at half and
    all of the APS-C sensor's half-diagonal angle, in whole degrees (8 and 16 deg at 50
    mm): how much the blur changes."""
    from lensim.optics.analysis import first_order_summary
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import ShootingSettings, lens_at
    from lensim.optics.spot import rms_spot_radius

    lens = load_lens(LENS)
    edge = math.degrees(math.atan(0.5 * math.hypot(23.52, 15.68) / first_order_summary(lens)["efl_mm"]))
    out = {}
    for s in GRID + BETWEEN:
        at = lens_at(lens, ShootingSettings(fno=s[0], focus_m=s[1]))
        out[tag(*s)] = [round(1000 * rms_spot_radius(at, f), 2) for f in (0.0, round(edge / 2), round(edge))]
    return out


def sensitivity(out: Path, held_out: list[str]) -> dict[str, dict[str, float]]:
    """Whether the conditioned network uses its settings: mean PSNR (dB) of its restorations
    of the held-out crops of two grid settings given each grid setting's vector."""
    from lensim.evaluate.metrics import psnr_batch
    from lensim.images import read_image
    from lensim.io import read_json
    from lensim.restore.checkpoint import load_checkpoint
    from lensim.restore.conditioning import Conditioning
    from lensim.restore.infer import restore_image

    model, info = load_checkpoint(out / "runs" / "conditioned" / "last.pt")
    cond = Conditioning.from_dict(info["conditioning"])
    h, w = (float(v) for v in reversed(info["sensor"]["resolution"]))
    res: dict[str, dict[str, float]] = {}
    for data in (GRID[0], GRID[-1]):
        d = out / "pairs" / tag(*data)
        crops = [
            c
            for r in read_json(d / "manifest.json", "pairs")["records"]
            if Path(r["source"]).name in held_out
            for c in r["crops"]
        ]
        res[tag(*data)] = {}
        for given in GRID:
            vec = cond.vector({"fno": given[0], "focus_m": given[1]})
            ps = []
            for c in crops:
                x, _ = read_image(d / c["input"])
                y, _ = read_image(d / c["target"])
                out_img = restore_image(model, x, (c["sensor_top"], c["sensor_left"]), (h, w), settings=vec)
                ps.append(float(psnr_batch(out_img.clamp(0, 1)[None], y[None])))
            res[tag(*data)][tag(*given)] = round(sum(ps) / len(ps), 3)
    return res


def nearest(fno: float, focus: float) -> tuple[float, float]:
    """The grid setting nearest in stops and dioptres, each over the grid's span."""

    def d(g: tuple[float, float]) -> float:
        n = [math.log2(x[0]) for x in GRID]
        dpt = [1 / x[1] for x in GRID]
        span_n, span_d = (max(n) - min(n)) or 1.0, (max(dpt) - min(dpt)) or 1.0
        return math.hypot((math.log2(fno) - math.log2(g[0])) / span_n, (1 / focus - 1 / g[1]) / span_d)

    return min(GRID, key=d)


def evaluate(pairs: Path, held_out: list[str], runs: dict[str, Path]) -> dict[str, Any]:
    from lensim.evaluate.harness import checkpoint_method
    from lensim.evaluate.harness import evaluate as run_evaluation

    methods = {name: checkpoint_method(run) for name, run in runs.items()}
    with warnings.catch_warnings():  # the single-setting network is warned about at other settings
        warnings.simplefilter("ignore", UserWarning)
        return run_evaluation(pairs, methods, sources=held_out)


def main() -> None:
    global LENS, GRID, BETWEEN, SINGLE
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default="bench-settings")
    ap.add_argument("--steps", type=int, default=1600)
    ap.add_argument("--photos", type=int, default=24)
    ap.add_argument(
        "--stage",
        default="all",
        choices=["data", "conditioned", "mixed", "single", "per-setting", "evaluate", "all"],
        help="run the stages up to this one only (each is cached), to keep heavy jobs short",
    )
    ap.add_argument("--lens", default=LENS)
    ap.add_argument("--grid", help="grid settings FNO:FOCUS_M,... (default: the module's GRID)")
    ap.add_argument("--between", help="settings between grid points, FNO:FOCUS_M,...")
    ap.add_argument("--single", help="the single-setting network's FNO:FOCUS_M (default: the first grid setting)")
    args = ap.parse_args()
    LENS = args.lens
    if args.grid:
        GRID = _settings(args.grid)
        SINGLE = GRID[0]
    BETWEEN = _settings(args.between) if args.between else BETWEEN
    SINGLE = _settings(args.single)[0] if args.single else SINGLE
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sharp = photos(out, args.photos)
    sets = {s: pairs_for(out, sharp, *s) for s in GRID + BETWEEN}
    grid = merged(out, [sets[s] for s in GRID])
    runs = out / "runs"
    record: dict[str, Any] = {
        "lens": LENS,
        "grid": GRID,
        "between": BETWEEN,
        "single": SINGLE,
        "steps_budget": args.steps,
        "photos": args.photos,
        "runs": {},
    }
    stages = ["data", "conditioned", "mixed", "single", "per-setting", "evaluate", "all"]
    last = stages.index(args.stage)
    if last >= 1:
        record["runs"]["conditioned"] = train_run(grid, runs / "conditioned", args.steps)
    if last >= 2:
        record["runs"]["mixed"] = train_run(grid, runs / "mixed", args.steps, use_settings=False)
    if last >= 3:
        record["runs"]["single"] = train_run(sets[SINGLE], runs / "single", args.steps)
    if last >= 4:
        for s in GRID:
            record["runs"][f"per-setting {tag(*s)}"] = train_run(
                sets[s], runs / f"per_{tag(*s)}", args.steps // len(GRID)
            )
    if last < 5:
        return
    held_out = json.loads((runs / "conditioned" / "split.json").read_text())["val"]
    record["held_out"] = held_out
    results: dict[str, Any] = {}
    for s in GRID + BETWEEN:
        near = nearest(*s)
        models = {
            "conditioned": runs / "conditioned" / "last.pt",
            "mixed": runs / "mixed" / "last.pt",
            "single": runs / "single" / "last.pt",
            "per-setting": runs / f"per_{tag(*near)}" / "last.pt",
        }
        summary = evaluate(sets[s], held_out, models)
        results[tag(*s)] = {"on_grid": s in GRID, "per_setting_model": tag(*near), **summary}
    record["results"] = results
    record["rms_spot_um"] = spot_sizes()
    record["conditioned_psnr_given_other_settings"] = sensitivity(out, held_out)
    record["evaluate_seconds"] = time.perf_counter() - t0
    (out / "results.json").write_text(json.dumps(record, indent=1))
    (out / "table.md").write_text(table(record))
    print(table(record))


def _avg(results: dict[str, Any], on_grid: bool, method: str, zone: str | None) -> float:
    vals = []
    for r in results.values():
        if r["on_grid"] != on_grid:
            continue
        m = r["methods"][method]
        vals.append(m["psnr_db"] if zone is None else m["zones"][zone]["psnr_db"])
    return sum(vals) / len(vals)


def table(record: dict[str, Any]) -> str:
    """Markdown: per setting, PSNR (dB) of every method overall and by zone; then the
    on-grid and between-grid means."""
    methods = ["input", "single", "per-setting", "mixed", "conditioned"]
    head = "| setting | method | PSNR | centre | middle | edge |\n|---|---|---:|---:|---:|---:|\n"
    lines = []
    for name, r in record["results"].items():
        where = "grid" if r["on_grid"] else "between"
        for m in methods:
            s = r["methods"][m]
            z = s["zones"]
            label = f"per-setting ({r['per_setting_model']})" if m == "per-setting" else m
            lines.append(
                f"| {name} ({where}) | {label} | {s['psnr_db']:.2f} | {z['centre']['psnr_db']:.2f} | "
                f"{z['middle']['psnr_db']:.2f} | {z['edge']['psnr_db']:.2f} |"
            )
    means = ["", "| mean | method | PSNR | centre | middle | edge |", "|---|---|---:|---:|---:|---:|"]
    for on_grid in (True, False):
        for m in methods:
            vals = [_avg(record["results"], on_grid, m, z) for z in (None, *ZONES)]
            means.append(
                f"| {'on grid' if on_grid else 'between grid'} | {m} | " + " | ".join(f"{v:.2f}" for v in vals) + " |"
            )
    sens = record["conditioned_psnr_given_other_settings"]
    given = list(next(iter(sens.values())))
    spots = [
        "",
        "| crops at | " + " | ".join(f"conditioned given {g}" for g in given) + " |",
        "|---|" + "---:|" * len(given),
    ]
    spots += [f"| {k} | " + " | ".join(f"{v[g]:.2f}" for g in given) + " |" for k, v in sens.items()]
    spots += ["", "| setting | RMS spot radius (um) at the axis, half and all the half-diagonal |", "|---|---|"]
    spots += [f"| {k} | {' / '.join(f'{v:.1f}' for v in vals)} |" for k, vals in record["rms_spot_um"].items()]
    return head + "\n".join(lines) + "\n" + "\n".join(means) + "\n" + "\n".join(spots) + "\n"


if __name__ == "__main__":
    main()
