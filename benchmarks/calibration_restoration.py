"""Restoration of photos from a perturbed camera, three models compared (issue 24, item 5).

The camera (--camera, CAMERAS) is one of calibration_validation.py's: phone_wide at 1 m on
the phone sensor, `larger_decentre` (focus +6 um, element 3 decentred 12 um in x, sensor
tilted 0.05 deg about y; the default) or `focus_decentre` (focus +6 um, e3 decentred 4 um).
Three PSF-informed networks, each fine-tuned from the universal model (`lensim train --init
universal`) on the same budget (--epochs: the same steps; else the time budget) and seed,
are compared on the perturbed camera's photos:

  (a) nominal     trained on pairs through the nominal lens;
  (b) calibrated  trained on pairs through the as-built lens the camera's calibration
                  recovered (CAMERAS: its json's "fitted", made a lens by
                  lensim.calibrate.tolerances.perturbed_lens as the validation does);
  (c) tolerances  trained on pairs through TOLERANCE_DRAWS draws of TOLERANCES
                  (`lensim dataset make --tolerances`'s draws).

Rendering (--render): "posed" (the default) simulates every lens with poses (the truth, the
calibrated lens, each tolerance draw) as the chart validation photographs its cameras:
through lensim.render.posed.posed_banks (one bank per sensor quadrant, the lens turned to
its diagonal, and that turned lens mirrored), each pixel through its own
(lensim.data.pairs.PosedBanks; lensim.data.pairs.make_dataset in this process); the
nominal lens is symmetric and has one bank. "turned" is the earlier rendering (the
committed focus_decentre results): `lensim dataset make` with the lens file, one bank
along +y turned to every azimuth, which for a lens with poses mirrors its kernels in half
of every quadrant (exact only for a symmetric lens), so the test photos are not the
validation camera's.

The test pairs are simulated through the true perturbed lens from photos no training set
contains (every TEST_EVERY-th built-in sample photo; the others are the training photos).
Each network's Wiener stage uses the bank its user would have: the nominal lens's for (a)
and (c), the calibrated lens's for (b) (`lensim evaluate --bank`); the Wiener oracle uses
the true lens's bank. In training, (c)'s stage of each pair uses the bank of the draw the
pair went through (lensim's rule for tolerance pairs; before, every pair's was draw 0's,
and this script computed them all with the nominal lens's). Scored by `lensim evaluate`
per field zone (centre, middle, edge) and per photo.

The Wiener stages and the "wiener (true lens's bank)" oracle use a lens's bank along +y
turned to every azimuth (the pairs' "bank": PosedBanks.stage), what `lensim restore` had
for a lens file; with --render posed the test photos went through the posed banks instead.
Since lensim gives pairs rendered through posed banks their posed stage (the manifest's
"posed_banks": `lensim train`, `evaluate` and `restore` use them; CHANGELOG), a
rerun trains (b) and (c) --render posed with posed stages and scores the oracle with the
posed banks where this script passes no --bank: the committed restoration_v3 rows
"(b) calibrated" and "(c) tolerances" (turned stages) reproduce at commits before that.

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_restoration.py \\
        --camera larger_decentre --epochs 18 --out /tmp/crv3 \\
        --results benchmarks/results/calibration/restoration_v3
    # the committed focus_decentre results (turned rendering, 300 s budgets):
    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_restoration.py \\
        --camera focus_decentre --render turned \\
        --out /tmp/calibration-restoration --results benchmarks/results/calibration/restoration

Another tolerance file (--tolerance-tag TAG --tolerance-file FILE --tolerance-draws N; posed
rendering): after the runs above, pairs through N draws of FILE (OUT/pairs/tolerances-TAG,
each draw's photos through its posed banks) and the tolerance-robust Wiener stage over those
draws (lensim.restore.psf_stage.wiener_channels with the draws' posed banks: per tile and
channel conj(E[H]) / (E[|H|^2] + NSR) over the draws, each pixel through its source's
banks), what a restoration of a unit whose draw is unknown can compute. Evaluated: the
Wiener filter alone with it and with the nominal lens's bank, the networks trained so far
with it at test; then the networks --robust-train names, trained on those pairs, each
evaluated with the stage it trained with: "nominal-stage" (the nominal lens's bank on
every pair), "robust" (the tolerance-robust stage on every pair: "stage_bank":
"tolerance_robust"), "posed-stage" (each pair its draw's posed bank, as (c') above; tested
with the nominal stage).

    # the committed restoration_v4 (on a copy of restoration_v3's work folder):
    cp -al /tmp/crv3 /tmp/crv4
    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_restoration.py \
        --camera larger_decentre --epochs 18 --out /tmp/crv4 \
        --tolerance-tag wide --tolerance-file benchmarks/results/calibration/restoration_v4/tolerances-wide.yaml \
        --tolerance-draws 12 --robust-train robust,nominal-stage \
        --results benchmarks/results/calibration/restoration_v4

Resumable: every stage's output is kept under --out (lenses, photos, pairs, runs, evals)
and skipped on a rerun (dataset make and train resume themselves); --results gets
table.md and restoration.json.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

LENS, SENSOR, DISTANCE_M = "phone_wide", "phone", 1.0
RESULTS = Path(__file__).parent / "results/calibration"
#: camera -> (its true perturbation: calibration_validation.CAMERAS', its calibration's json)
CAMERAS = {
    "focus_decentre": ({"image.focus": 0.006, "e3.decentre_x": 0.004}, RESULTS / "candidates3/focus_decentre.json"),
    "larger_decentre": (
        {"image.focus": 0.006, "e3.decentre_x": 0.012, "image.tilt_y": 0.05},
        RESULTS / "v3/fixed_simulation/larger_decentre.json",
    ),
}
TRUTH, FIT = CAMERAS["focus_decentre"]  # the turned rendering's camera (calibration_tolerance_draws.py's)
#: the unit-to-unit spread model (c) trains with: a maker's tolerance file, not fitted to this unit
TOLERANCES = """\
distribution: uniform
elements:
  all: {decentre_mm: 0.005, tilt_deg: 0.05, spacing_mm: 0.003}
image: {focus_mm: 0.008, tilt_deg: 0.05}
"""
TEST_EVERY = 5
ZONES = ("centre", "middle", "edge")
MODELS = {"nominal": "nominal", "calibrated": "calibrated", "tolerances": "nominal"}  # model -> its stage's lens
FULL = dict(
    photo=384,
    crops=2,
    test_crops=4,
    size=128,
    placements=3,
    fields=7,
    wl="450:650:50",
    pupil=64,
    draws=4,
    budget=300.0,
    train_crop=96,
)
TINY = dict(
    photo=160,
    crops=1,
    test_crops=1,
    size=64,
    placements=3,
    fields=3,
    wl="450,550,650",
    pupil=32,
    draws=2,
    budget=20.0,
    train_crop=64,
)


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def lensim(*args: str) -> str:
    """Run the lensim CLI (this interpreter, one torch thread); its stdout."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-m", "lensim", *args], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"lensim {' '.join(args)} failed ({res.returncode}): {res.stderr.strip()[-2000:]}")
    return res.stdout


def lenses_of(camera: str) -> dict:
    """The nominal, calibrated and true lenses of a camera at the chart's 1 m."""
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens
    from lensim.optics.shooting import ShootingSettings, lens_at

    truth, fit = CAMERAS[camera]
    lens = lens_at(load_lens(LENS, warn=False), ShootingSettings(object_m=DISTANCE_M, focus_m=DISTANCE_M))
    fitted = json.loads(fit.read_text())["fitted"]
    return {"nominal": lens, "calibrated": perturbed_lens(lens, fitted), "truth": perturbed_lens(lens, truth)}


def make_lenses(out: Path, camera: str = "focus_decentre") -> dict[str, Path]:
    """The nominal, calibrated and true lenses at the chart's 1 m (JSON lens files) and the tolerance file."""
    from lensim.optics.lens_file import save_lens

    d = out / "lenses"
    d.mkdir(parents=True, exist_ok=True)
    lenses = lenses_of(camera)
    paths = {k: d / f"{k}.json" for k in lenses}
    for k, m in lenses.items():
        if not paths[k].exists():
            save_lens(m, paths[k])  # JSON: save_lens to YAML fails on a lens_at lens's numpy floats
    paths["tolerances"] = tolerance_file(out)
    return paths


def tolerance_file(out: Path) -> Path:
    """OUT/lenses/tolerances.yaml: TOLERANCES (written once)."""
    tol = out / "lenses" / "tolerances.yaml"
    tol.parent.mkdir(parents=True, exist_ok=True)
    if not tol.exists():
        tol.write_text(TOLERANCES)
    return tol


def split_photos(out: Path, size: int, tiny: bool) -> tuple[Path, Path]:
    """The built-in sample photos centre-cropped: every TEST_EVERY-th to test/, the rest to train/."""
    from lensim.assets.images import available_sample_images, write_centre_crops

    photos = available_sample_images()
    test = photos[::TEST_EVERY]
    train = [p for p in photos if p not in test]
    if tiny:
        test, train = test[:2], train[:6]
    d = out / "photos"
    write_centre_crops(test, d / "test", size)
    write_centre_crops(train, d / "train", size)
    return d / "train", d / "test"


def make_pairs(out: Path, name: str, photos: Path, lens: Path, s: dict, tolerances: Path | None = None) -> Path:
    """`lensim dataset make` (it resumes a folder made with the same settings)."""
    pairs = out / "pairs" / name
    if (pairs / "done").exists():
        return pairs
    log(f"pairs {name}")
    args = [str(photos), "--lens", str(lens), "--sensor", SENSOR, "-o", str(pairs), "--crops", str(s["crops"])]
    args += ["--size", str(s["size"]), "--placements", str(s["placements"]), "--seed", "0", "--fields"]
    args += [str(s["fields"]), "--wavelengths-nm", s["wl"], "--pupil-samples", str(s["pupil"])]
    args += ["--cache", str(out / "cache"), "--quiet"]
    if tolerances is not None:
        args += ["--tolerances", str(tolerances), "--tolerance-draws", str(s["draws"])]
    t = time.perf_counter()
    lensim("dataset", "make", *args)
    (pairs / "done").write_text(json.dumps({"seconds": time.perf_counter() - t}))
    return pairs


class Posed:
    """Pairs of lenses with poses through their posed banks (--render posed), in this
    process: lensim.data.pairs.make_dataset with PosedBanks, or ToleranceBanks whose draws
    have theirs; banks cached under OUT/cache with the settings s."""

    def __init__(self, out: Path, s: dict) -> None:
        from lensim.psf.bank.settings import BankSettings, parse_wavelengths_nm
        from lensim.render.mapping import native_mapping
        from lensim.sensor.profile import load_sensor

        self.out, self.s = out, s
        self.sensor = load_sensor(SENSOR)
        self.full = native_mapping(self.sensor.height, self.sensor.width, self.sensor, 0, 0)
        self.settings = BankSettings(fields=s["fields"], wavelengths_nm=parse_wavelengths_nm(s["wl"]),
                                     pupil_samples=s["pupil"], cache_dir=out / "cache")  # fmt: skip

    def bank(self, lens):
        from lensim.psf.bank import get_bank

        return get_bank(lens, self.sensor.pixel_pitch_um, self.settings, response=self.sensor.spectral_response)

    def banks(self, lens):
        """A symmetric lens's bank, or a lens with poses' PosedBanks (stage: its bank along +y)."""
        from lensim.data.pairs import PosedBanks
        from lensim.render.posed import posed_banks

        banks = posed_banks(lens, self.full, self.bank)
        return banks["all"] if "all" in banks else PosedBanks(banks, self.bank(lens))

    def draws(self, lens, tolerances: Path, count: int | None = None):
        """ToleranceBanks of draws 0..count-1 (default s["draws"]) of seed 0 (as `lensim
        dataset make --tolerances` draws them), each draw's photos through its posed banks."""
        from lensim.calibrate.tolerances import drawn_lens, load_tolerances
        from lensim.data.pairs import ToleranceBanks
        from lensim.optics.lens_file import lens_to_dict

        tol = load_tolerances(tolerances, lens)
        drawn = [drawn_lens(lens, tol, 0, k) for k in range(count or self.s["draws"])]
        posed = [self.banks(m) for m in drawn]
        records = [{k: m.as_built[k] for k in ("seed", "draw", "parameters")} for m in drawn]
        stages = [p.stage if hasattr(p, "stage") else p for p in posed]
        with_poses = [p if hasattr(p, "stage") else None for p in posed]
        if any(p is None for p in with_poses):
            raise SystemExit("a tolerance draw without poses: expected decentres or tilts in every draw")
        return ToleranceBanks(stages, lens_to_dict(lens), str(tolerances), records, self.bank(lens), with_poses)

    def pairs(self, name: str, photos: Path, banks, crops: int) -> Path:
        """lensim.data.pairs.make_dataset (resumes), as make_pairs' `lensim dataset make` would."""
        from lensim.data.pairs import make_dataset
        from lensim.psf.bank import PSFBank

        pairs = self.out / "pairs" / name
        if (pairs / "done").exists():
            return pairs
        log(f"pairs {name}" + ("" if isinstance(banks, PSFBank) else " (posed banks)"))
        t = time.perf_counter()
        s = self.s
        make_dataset(photos, pairs, banks, SENSOR, self.sensor, crops=crops, size=s["size"], seed=0,
                     placements=s["placements"])  # fmt: skip
        (pairs / "done").write_text(json.dumps({"seconds": time.perf_counter() - t}))
        return pairs


def pairs_maker(out: Path, camera: str, s: dict, photos: tuple[Path, Path], render: str):
    """name -> its pairs folder (made once, on first use): "test" through the true lens,
    "nominal", "calibrated", "tolerances" (the training pairs of (a), (b), (c)), rendered
    posed (Posed) or turned (make_pairs: `lensim dataset make` with lens files)."""
    train, test = photos
    photo_of = {"test": test}
    crops = {"test": s["test_crops"]}
    lens_of = {"test": "truth", "tolerances": "nominal"}
    if render == "posed":
        p = Posed(out, s)
        lenses = lenses_of(camera)

        def make(name: str) -> Path:
            lens = lenses[lens_of.get(name, name)]
            banks = p.draws(lens, tolerance_file(out)) if name == "tolerances" else p.banks(lens)
            return p.pairs(name, photo_of.get(name, train), banks, crops.get(name, s["crops"]))

        return make
    files = make_lenses(out, camera)

    def make_turned(name: str) -> Path:
        tol = files["tolerances"] if name == "tolerances" else None
        settings = {**s, "crops": crops.get(name, s["crops"])}
        return make_pairs(out, name, photo_of.get(name, train), files[lens_of.get(name, name)], settings, tol)

    return make_turned


def bank_of(pairs: Path) -> str:
    return json.loads((pairs / "manifest.json").read_text())["bank"]


def train(out: Path, name: str, pairs: Path, budget: float, crop: int, seed: int = 0, epochs: int = 0) -> dict:
    """`lensim train --init universal` on the time budget (as the demo fine-tunes), or for
    `epochs` epochs (the same steps whatever the machine's load), once."""
    run = out / "runs" / name
    marker = run / "summary.json"
    if marker.exists():
        return json.loads(marker.read_text())
    log(f"train {name} ({f'{epochs} epochs' if epochs else f'{budget:.0f} s'})")
    args = ["train", str(pairs), "-o", str(run), "--init", "universal"]
    args += ["--epochs", str(epochs)] if epochs else ["--time-budget-s", str(budget), "--epochs", "100000"]
    args += ["--batch-size", "4", "--lr", "2e-4", "--lr-schedule", "cosine", "--crop", str(crop)]
    args += ["--val-fraction", "0.25", "--seed", str(seed), "--threads", "1", "--json"]
    if (run / "last.pt").exists():
        args.append("--resume")
    t = time.perf_counter()
    summary = json.loads(lensim(*args))
    summary["wall_s"] = time.perf_counter() - t
    marker.write_text(json.dumps(summary, indent=1))
    log(f"train {name}: {summary['steps']} steps, val PSNR {summary['val_psnr_db']:.2f} dB")
    return summary


def evaluate(out: Path, name: str, test: Path, methods: str, bank: str | None, model: Path | None) -> Path:
    """`lensim evaluate` on the test pairs into OUT/evals/<name> (once)."""
    d = out / "evals" / name
    if (d / "metrics.json").exists():
        return d
    log(f"evaluate {name}")
    args = ["evaluate", "--pairs", str(test), "--methods", methods, "-o", str(d), "--quiet"]
    args += (["--bank", bank] if bank else []) + (["--model", str(model)] if model else [])
    lensim(*args)
    return d


def evaluate_banks(out: Path, name: str, test: Path, methods: str, banks: tuple, model: Path | None) -> Path:
    """As :func:`evaluate` (its outputs: metrics.csv, metrics.json), in this process, with a
    stage no lens file gives: ``banks``, several draws' banks (each a lens with poses' banks
    by source), is the tolerance-robust stage (lensim.restore.psf_stage.wiener_channels) of
    "wiener" and of the network's stage, each pixel through its own source's banks."""
    from lensim.evaluate import harness
    from lensim.io import atomic_write_json
    from lensim.jsonable import jsonable

    d = out / "evals" / name
    if (d / "metrics.json").exists():
        return d
    log(f"evaluate {name}")
    table: dict = {}
    for m in methods.split(","):
        if m == "model":
            table[m] = harness.checkpoint_method(model)
        elif m != "input":
            table[m] = harness.builtin_method(m)
    rows = harness.evaluate_rows(test, table, bank=banks)
    d.mkdir(parents=True, exist_ok=True)
    harness.write_csv(rows, d / "metrics.csv")
    atomic_write_json(d / "metrics.json", jsonable(harness.summarize(rows)), indent=2)
    return d


def stage_pairs(out: Path, name: str, stage: str) -> Path:
    """A copy of OUT/pairs/<name> (pairs through tolerance draws; crop files linked) whose
    pairs' Wiener stage in training is ``stage``: "nominal-stage" the nominal lens's bank
    (the manifest's "bank") on every pair (the draws kept as "photos_tolerances"), "robust"
    the tolerance-robust stage over all the draws' posed banks on every pair ("stage_bank":
    "tolerance_robust"). OUT/pairs/<name>@<stage>, made once."""
    from lensim.data.pairs import STAGE_ROBUST

    src = out / "pairs" / name
    dst = out / "pairs" / f"{name}@{stage}"
    if (dst / "manifest.json").exists():
        return dst
    manifest = json.loads((src / "manifest.json").read_text())
    if stage == "nominal-stage":
        new = {k: v for k, v in manifest.items() if k not in ("tolerances", "stage_bank")}
        new["photos_tolerances"] = manifest["tolerances"]
    elif stage == "robust":
        new = {**manifest, "stage_bank": STAGE_ROBUST}
    else:
        raise SystemExit(f"unknown training stage {stage!r}")
    dst.mkdir(parents=True, exist_ok=True)
    if not (dst / "pairs").exists():
        (dst / "pairs").symlink_to(src / "pairs")
    (dst / "manifest.json").write_text(json.dumps(new))
    return dst


#: --robust-train's trainings: stage in training -> what the network is tested with
ROBUST_TRAININGS = ("robust", "nominal-stage", "posed-stage")


def robust_phase(
    out: Path, s: dict, args: argparse.Namespace, pairs: dict[str, Path], done: Callable[[], None]
) -> None:
    """The --tolerance-tag runs (module docstring): pairs through --tolerance-draws draws of
    --tolerance-file, the tolerance-robust stage's checks, the --robust-train networks
    (nothing without --tolerance-tag)."""
    tag, n = args.tolerance_tag, args.tolerance_draws
    if not tag:
        return
    name = f"tolerances-{tag}"
    kept = out / "lenses" / f"{name}.yaml"
    text = args.tolerance_file.read_text()
    if kept.exists() and kept.read_text() != text:
        raise SystemExit(f"{kept} differs from {args.tolerance_file}: another tag, or another work folder")
    kept.parent.mkdir(parents=True, exist_ok=True)
    kept.write_text(text)
    p = Posed(out, s)
    lenses = lenses_of(args.camera)
    draws = p.draws(lenses["nominal"], kept, n)
    robust = tuple(d.banks for d in draws.posed)
    test = pairs["test"]
    p.pairs(name, out / "photos" / "train", draws, s["crops"])
    kernels = out / f"draw_kernels-{tag}.json"  # the draws' kernels against the unit's
    if not kernels.exists():
        found = stage_kernels(out, args.camera, s, {tag: list(robust)})
        kernels.write_text(json.dumps({k: v for k, v in found.items() if k.startswith(tag)}, indent=1))
    evaluate(out, "oracle@nominal", test, "input,wiener", bank_of(pairs["nominal"]), None)
    evaluate_banks(out, f"oracle@robust-{tag}", test, "input,wiener", robust, None)
    done()
    for m in ("nominal", "tolerances@posed-stage", "calibrated@posed-stage"):  # the networks so far
        if (out / "runs" / m / "summary.json").exists():
            evaluate_banks(out, f"{m}@robust-{tag}", test, "input,model", robust, out / "runs" / m)
            done()
    for stage in [k for k in args.robust_train.split(",") if k]:
        if stage not in ROBUST_TRAININGS:
            raise SystemExit(f"--robust-train: unknown {stage!r}; expected some of {', '.join(ROBUST_TRAININGS)}")
        folder = posed_stage_pairs(out, name, s) if stage == "posed-stage" else stage_pairs(out, name, stage)
        run_name = f"{name}@{stage}"
        train(out, run_name, folder, s["budget"], s["train_crop"], epochs=args.epochs)
        run = out / "runs" / run_name
        if stage == "robust":
            evaluate_banks(out, f"{run_name}@robust-{tag}", test, "input,model", robust, run)
            posed_stage_evaluate(out, f"{run_name}@posed-calibrated", s, lenses["calibrated"], "input,model", run)
        else:
            evaluate(out, f"{run_name}@nominal", test, "input,model", bank_of(pairs["nominal"]), run)
        done()


def tolerance_tags(out: Path, tag: str | None = None) -> list[str]:
    """The --tolerance-tag runs of this work folder (OUT/lenses/tolerances-<tag>.yaml), and ``tag``."""
    found = {p.stem[len("tolerances-") :] for p in (out / "lenses").glob("tolerances-*.yaml")}
    return sorted(found | ({tag} if tag else set()))


def robust_rows(out: Path, tag: str) -> dict[str, tuple[Path, str]]:
    """The --tolerance-tag evaluations found under OUT/evals: label -> (folder, method)."""
    ev, name = out / "evals", f"tolerances-{tag}"
    robust = f"tolerance-robust stage ({tag})"
    cands = {
        "wiener (nominal lens's bank)": ("oracle@nominal", "wiener"),
        f"wiener ({robust})": (f"oracle@robust-{tag}", "wiener"),
        f"nominal, {robust}": (f"nominal@robust-{tag}", "model"),
        f"calibrated (posed stages in training), {robust}": (f"calibrated@posed-stage@robust-{tag}", "model"),
        f"tolerances (posed stages in training), {robust}": (f"tolerances@posed-stage@robust-{tag}", "model"),
        f"{name} (nominal stage in training), nominal stage": (f"{name}@nominal-stage@nominal", "model"),
        f"{name} (posed stages in training), nominal stage": (f"{name}@posed-stage@nominal", "model"),
        f"{name} ({robust} in training), {robust}": (f"{name}@robust@robust-{tag}", "model"),
        f"{name} ({robust} in training), posed calibrated stage": (f"{name}@robust@posed-calibrated", "model"),
    }
    return {k: (ev / d, m) for k, (d, m) in cands.items() if (ev / d / "metrics.json").exists()}


def per_photo(evals: Path, method: str) -> dict[str, dict[str, float]]:
    """Per test photo: the mean PSNR (dB) over its crops ("all"), and per zone over the
    crops with pixels in that zone (each crop's PSNR over its pixels there)."""
    acc: dict[str, dict[str, list[float]]] = {}
    with open(evals / "metrics.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["method"] != method:
                continue
            mine = acc.setdefault(Path(row["source"]).stem, {})
            mine.setdefault("all", []).append(float(row["psnr_db"]))
            for z in ZONES:
                if int(row[f"{z}_pixels"]) > 0:
                    mine.setdefault(z, []).append(float(row[f"{z}_psnr_db"]))
    return {p: {k: sum(v) / len(v) for k, v in d.items()} for p, d in sorted(acc.items())}


def gather(
    out: Path,
    runs: dict[str, dict],
    seconds: float,
    camera: str = "focus_decentre",
    posed: bool = False,
    tag: str | None = None,
) -> dict:
    """Per method: overall and per-zone PSNR/SSIM, per-photo PSNR; each model's steps.
    The Wiener oracle is the true lens's bank: its PSFs exactly with the turned rendering,
    along +y turned to every azimuth with the posed one."""
    ev = out / "evals"
    oracle = json.loads((ev / "oracle" / "metrics.json").read_text())["methods"]
    wiener = "wiener (true lens's bank)" if posed else "wiener (true PSFs)"
    rows = {"input": oracle["input"], wiener: oracle["wiener"]}
    photos = {"input": per_photo(ev / "oracle", "input"), wiener: per_photo(ev / "oracle", "wiener")}
    for m in runs:
        rows[m] = json.loads((ev / m / "metrics.json").read_text())["methods"]["model"]
        photos[m] = per_photo(ev / m, "model")
    keys = ("steps", "epochs_done", "seconds", "val_psnr_db", "val_input_psnr_db", "wall_s")
    train_info = {m: {k: runs[m][k] for k in keys} for m in runs}
    if (ev / "oracle@posed-truth" / "metrics.json").exists():
        posed_oracle = json.loads((ev / "oracle@posed-truth" / "metrics.json").read_text())["methods"]["wiener"]
        rows["wiener (true PSFs: posed banks)"] = posed_oracle
        photos["wiener (true PSFs: posed banks)"] = per_photo(ev / "oracle@posed-truth", "wiener")
    for m in MODELS:
        if (ev / f"{m}@posed-calibrated" / "metrics.json").exists():
            rows[f"{m}, posed calibrated stage"] = json.loads(
                (ev / f"{m}@posed-calibrated" / "metrics.json").read_text()
            )["methods"]["model"]
            photos[f"{m}, posed calibrated stage"] = per_photo(ev / f"{m}@posed-calibrated", "model")
    for m in ("calibrated", "tolerances"):  # trained with posed stages (posed_stage_pairs)
        for stage, label in (("posed-calibrated", "posed calibrated stage"), ("nominal", "nominal stage")):
            d = ev / f"{m}@posed-stage@{stage}"
            if (d / "metrics.json").exists():
                rows[f"{m} (posed stages in training), {label}"] = json.loads((d / "metrics.json").read_text())[
                    "methods"
                ]["model"]
                photos[f"{m} (posed stages in training), {label}"] = per_photo(d, "model")
    zero_shot = {"": "nominal stage", "@calibrated": "calibrated lens's turned stage"}
    zero_shot |= {"@posed-calibrated": "posed calibrated stage", "@posed-truth": "posed true stage"}
    for suffix, label in zero_shot.items():
        d = ev / f"universal{suffix}"
        if (d / "metrics.json").exists():
            rows[f"universal (zero-shot), {label}"] = json.loads((d / "metrics.json").read_text())["methods"][
                "universal"
            ]
            photos[f"universal (zero-shot), {label}"] = per_photo(d, "universal")
    for other in tolerance_tags(out, tag):
        for label, (d, method) in robust_rows(out, other).items():
            rows[label] = json.loads((d / "metrics.json").read_text())["methods"][method]
            photos[label] = per_photo(d, method)
    stages = {p.parent.name: json.loads(p.read_text())["seconds"] for p in sorted((out / "pairs").glob("*/done"))}
    fit = str(CAMERAS[camera][1].relative_to(RESULTS.parent.parent))
    return {"camera": camera, "truth": CAMERAS[camera][0], "fit": fit, "metrics": rows, "per_photo": photos,
            "training": train_info, "pairs_seconds": stages, "run_seconds_all_invocations": seconds}  # fmt: skip


def robust_differences(zs: dict[str, dict[str, float]], tag: str | None) -> list[str]:
    """Rows of the difference table: each --tolerance-tag row against (b') and (a)."""
    if not tag:
        return []
    a, b = "nominal", "calibrated (posed stages in training), posed calibrated stage"
    lines = []
    for c in [n for n in zs if n.startswith(f"tolerances-{tag} ") or f"tolerance-robust stage ({tag})" in n]:
        for ref in (b, a):
            if ref in zs:
                lines.append(f"| {c} - {ref} | " + " | ".join(f"{zs[c][z] - zs[ref][z]:+.2f}" for z in ZONES) + " |")
    return lines


def table(res: dict) -> str:
    zones = ZONES
    lines = ["| method | all PSNR / SSIM | " + " | ".join(zones) + " |", "| --- | --- | --- | --- | --- |"]
    for name, m in res["metrics"].items():
        cells = [f"{m['psnr_db']:.2f} / {m['ssim']:.3f}"]
        cells += [f"{m['zones'][z]['psnr_db']:.2f} / {m['zones'][z]['ssim']:.3f}" for z in zones]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    zs = {n: {z: res["metrics"][n]["zones"][z]["psnr_db"] for z in zones} for n in res["metrics"]}
    lines += ["", "| difference (dB) | " + " | ".join(zones) + " |", "| --- | --- | --- | --- |"]
    cal = "calibrated, posed calibrated stage"
    for a, b in (("calibrated", "nominal"), ("tolerances", "calibrated"), ("tolerances", "nominal"), (cal, "nominal"),
                 ("tolerances", cal)):  # fmt: skip
        if a not in zs or b not in zs:
            continue
        lines.append(f"| {a} - {b} | " + " | ".join(f"{zs[a][z] - zs[b][z]:+.2f}" for z in zones) + " |")
    for tag in res.get("tolerance_tags", []):
        lines += robust_differences(zs, tag)
    names = list(res["per_photo"])
    for zone in ("all", "edge"):
        what = "all crops" if zone == "all" else "edge zone"
        lines += ["", f"| photo ({what}, dB) | " + " | ".join(names) + " |", "|" + " --- |" * (len(names) + 1)]
        for p in res["per_photo"]["input"]:
            cells = [res["per_photo"][n].get(p, {}).get(zone, float("nan")) for n in names]
            lines.append(f"| {p} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    lines += ["", "| network (trained on) | Wiener stage's bank | all | centre | middle | edge |"]
    lines.append("| --- | --- | --- | --- | --- | --- |")
    for m, by_stage in res.get("stage_swap", {}).items():
        for stage, v in by_stage.items():
            mark = " (its own)" if stage == MODELS[m] else ""
            cells = " | ".join(f"{v[k]:.2f}" for k in ("all", *ZONES))
            lines.append(f"| {m} | {stage}{mark} | {cells} |")
    lines += seeds_table(res.get("seeds", {}))
    lines += ["", "| model | steps | epochs | trained s | val PSNR |", "| --- | --- | --- | --- | --- |"]
    for n, t in res["training"].items():
        lines.append(f"| {n} | {t['steps']} | {t['epochs_done']} | {t['seconds']:.0f} | {t['val_psnr_db']:.2f} |")
    return "\n".join(lines) + "\n"


def stage_swap(out: Path) -> dict[str, dict[str, dict]]:
    """Each network's PSNR (all and per zone) with each stage bank evaluated so far."""
    swap: dict[str, dict[str, dict]] = {}
    for m, own in MODELS.items():
        for stage in ("nominal", "calibrated", "truth", "posed-calibrated", "posed-truth"):
            d = out / "evals" / (m if stage == own else f"{m}@{stage}") / "metrics.json"
            if d.exists():
                v = json.loads(d.read_text())["methods"]["model"]
                swap.setdefault(m, {})[stage] = {"all": v["psnr_db"], **{z: v["zones"][z]["psnr_db"] for z in ZONES}}
    return swap


def stage_kernels(out: Path, camera: str, s: dict, draws: dict[str, list] | None = None) -> dict[str, dict[str, float]]:
    """How far each stage's kernels are from the test photos' (the true lens's posed
    banks): per zone, the mean NCC at the test crops' centres of the kernels of the
    nominal lens, and of the true and calibrated lenses' banks along +y turned (the
    stages) and posed (--render posed). draws: name -> several draws' posed banks (by
    source): "<name> draws, mean" and "<name> draws, best" (the mean over the draws, and
    the best draw's, of that NCC per zone) and "<name> coherence", per zone the mean over
    the crops' centres and channels of sum |E[H]|^2 / sum E[|H|^2] over 0.1-0.5 cycles
    per pixel (the draws' transfer functions H, unit sum; 1: the draws agree, the
    tolerance-robust filter is the Wiener filter of their mean; near 0: it restores
    little there)."""
    import numpy as np

    from lensim.evaluate.metrics import zone_index
    from lensim.render.mapping import SensorMapping
    from lensim.render.posed import pixel_sources

    p, lenses = Posed(out, s), lenses_of(camera)
    manifest = json.loads((out / "pairs" / "test" / "manifest.json").read_text())
    pitch, size = p.sensor.pixel_pitch_um * 1e-3, s["size"]
    crops = [c for r in manifest["records"] for c in r["crops"]]
    points = [(c["sensor_left"] + size / 2, c["sensor_top"] + size / 2) for c in crops]
    xy = [((col - p.sensor.width / 2) * pitch, (row - p.sensor.height / 2) * pitch) for col, row in points]
    half = float(np.hypot(p.sensor.width, p.sensor.height)) / 2 * pitch

    def kernels(banks) -> list[np.ndarray]:
        if not isinstance(banks, dict):
            return [banks.psfs_at(np.array([x]), np.array([y]))[0] for x, y in xy]
        out_ = []
        for x, y in xy:
            one = SensorMapping(1, 1, pitch * 1e3, x - pitch / 2, y - pitch / 2)
            key = next(k for k, m in pixel_sources((1, 1), one, True).items() if m[0, 0])
            out_.append(banks[key].psfs_at(np.array([x]), np.array([y]))[0])
        return out_

    def ncc(a: np.ndarray, b: np.ndarray) -> float:
        n = max(a.shape[-1], b.shape[-1])  # banks' kernel sizes differ: both centred in n x n
        a, b = (np.pad(k, [(0, 0)] + [((n - k.shape[-1]) // 2, (n - k.shape[-1] + 1) // 2)] * 2) for k in (a, b))
        a, b = a - a.mean(), b - b.mean()
        return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))

    truth = kernels(p.banks(lenses["truth"]).banks)
    cands = {"nominal": p.bank(lenses["nominal"]), "truth turned": p.bank(lenses["truth"])}
    cands["calibrated turned"] = p.bank(lenses["calibrated"])
    cands["calibrated posed"] = p.banks(lenses["calibrated"]).banks
    zones = [ZONES[int(zone_index(np.array(np.hypot(x, y) / half)))] for x, y in xy]

    def by_zone(v: list[float]) -> dict[str, float]:
        return {z: float(np.mean([n for n, q in zip(v, zones, strict=True) if q == z])) for z in ZONES}

    res = {}
    for name, banks in cands.items():
        res[name] = by_zone([ncc(a, b) for a, b in zip(kernels(banks), truth, strict=True)])
    for name, several in (draws or {}).items():
        ks = [kernels(b) for b in several]
        per = [by_zone([ncc(a, b) for a, b in zip(k, truth, strict=True)]) for k in ks]
        res[f"{name} draws, mean"] = {z: float(np.mean([d[z] for d in per])) for z in ZONES}
        res[f"{name} draws, best"] = {z: float(np.max([d[z] for d in per])) for z in ZONES}
        res[f"{name} coherence"] = by_zone([_coherence([k[i] for k in ks]) for i in range(len(xy))])
    return res


def _coherence(kernels: list, n: int = 64) -> float:
    """sum |E[H]|^2 / sum E[|H|^2] over 0.1-0.5 cycles per pixel, mean over the channels,
    of (3, P, P) kernels (several draws' at one point; H: each one's transfer function at
    n x n, unit sum)."""
    import numpy as np

    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n), indexing="ij"))
    band = (f >= 0.1) & (f <= 0.5)
    hs = []
    for k in kernels:
        p = min(k.shape[-1], n)
        big = np.zeros((3, n, n))
        c = (k.shape[-1] - p) // 2
        big[:, :p, :p] = k[:, c : c + p, c : c + p]
        big = np.roll(big, (-(p // 2), -(p // 2)), axis=(1, 2))
        h = np.fft.fft2(big)
        hs.append(h / h[:, :1, :1])
    h = np.array(hs)  # (draws, 3, n, n)
    common = (np.abs(h.mean(axis=0)) ** 2)[:, band].sum(axis=-1)
    power = (np.abs(h) ** 2).mean(axis=0)[:, band].sum(axis=-1)
    return float(np.mean(common / power))


def _crop_source(crop: dict, size: int, sensor) -> str:
    """The posed source (lensim.render.posed.pixel_sources) of a crop's centre pixel."""
    from lensim.render.mapping import native_mapping
    from lensim.render.posed import pixel_sources

    one = native_mapping(1, 1, sensor, crop["sensor_top"] + size // 2, crop["sensor_left"] + size // 2)
    return next(k for k, m in pixel_sources((1, 1), one, True).items() if m[0, 0])


def source_subsets(out: Path, s: dict) -> dict[str, Path]:
    """The test pairs split by the posed source of each crop's centre: OUT/pairs/test@<key>
    (a manifest of those crops, the crop files linked), made once."""
    from lensim.sensor.profile import load_sensor

    test = out / "pairs" / "test"
    manifest = json.loads((test / "manifest.json").read_text())
    sensor = load_sensor(SENSOR)
    groups: dict[str, list[dict]] = {}
    for rec in manifest["records"]:
        by: dict[str, list[dict]] = {}
        for c in rec["crops"]:
            by.setdefault(_crop_source(c, s["size"], sensor), []).append(c)
        for key, crops in by.items():
            groups.setdefault(key, []).append({**rec, "crops": crops})
    folders = {}
    for key, records in sorted(groups.items()):
        d = out / "pairs" / f"test@{key.replace('/', '-')}"
        if not (d / "manifest.json").exists():
            d.mkdir(parents=True, exist_ok=True)
            if not (d / "pairs").exists():
                (d / "pairs").symlink_to(test / "pairs")
            sub = {**manifest, "records": records, "pairs": sum(len(r["crops"]) for r in records)}
            (d / "manifest.json").write_text(json.dumps(sub))
        folders[key] = d
    return folders


def posed_stage_evaluate(out: Path, name: str, s: dict, lens, methods: str, model: Path | None) -> Path:
    """`lensim evaluate` of the test pairs with a posed stage: each crop's stage (and
    Wiener filter) with the bank of the posed source its centre lies in (the lens's
    posed banks; exact where the whole crop has that source), the crops' rows merged
    into OUT/evals/<name> (metrics.csv, metrics.json: lensim.evaluate.harness.summarize)."""
    import csv as csv_

    from lensim.evaluate.harness import summarize

    d = out / "evals" / name
    if (d / "metrics.json").exists():
        return d
    banks = Posed(out, s).banks(lens).banks
    rows: list[dict] = []
    for key, subset in source_subsets(out, s).items():
        part = evaluate(out, f"{name}/{key.replace('/', '-')}", subset, methods, str(banks[key].directory), model)
        with open(part / "metrics.csv", newline="") as f:
            rows += list(csv_.DictReader(f))
    fields = list(rows[0])
    with open(d / "metrics.csv", "w", newline="") as f:
        w = csv_.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)

    def num(v: str) -> float:
        return float(v) if v not in ("", None) else math.nan

    typed = [{k: (v if k in ("method", "source", "input") else num(v)) for k, v in r.items()} for r in rows]
    (d / "metrics.json").write_text(json.dumps(summarize(typed), indent=1))
    return d


def posed_stage_pairs(out: Path, name: str, s: dict) -> Path:
    """A copy of OUT/pairs/<name> (posed pairs of the calibrated lens or of tolerance
    draws; crop files linked) whose pairs' Wiener stage in training is posed: one record
    per crop, its stage the bank of its centre's posed source (of its draw's banks for
    tolerance pairs), through lensim's per-record stage rule ("stage_bank":
    "tolerance_draw", the banks listed as the manifest's draws)."""
    from lensim.data.pairs import STAGE_PER_DRAW
    from lensim.sensor.profile import load_sensor

    src = out / "pairs" / name
    dst = out / "pairs" / f"{name}@posed-stage"
    if (dst / "manifest.json").exists():
        return dst
    manifest = json.loads((src / "manifest.json").read_text())
    if "tolerances" in manifest:
        posed = [d["posed_banks"] for d in manifest["tolerances"]["draws"]]
    else:
        posed = [manifest["posed_banks"]]
    sensor = load_sensor(SENSOR)
    banks: list[dict] = []
    records = []
    for rec in manifest["records"]:
        for crop in rec["crops"]:
            k, key = rec.get("tolerance_draw", 0), _crop_source(crop, s["size"], sensor)
            entry = {"bank": posed[k][key], "draw": k, "source": key}
            if entry not in banks:
                banks.append(entry)
            records.append({**rec, "crops": [crop], "tolerance_draw": banks.index(entry)})
    dst.mkdir(parents=True, exist_ok=True)
    if not (dst / "pairs").exists():
        (dst / "pairs").symlink_to(src / "pairs")
    tolerances = {**manifest.get("tolerances", {}), "draws": banks}
    new = {**manifest, "records": records, "stage_bank": STAGE_PER_DRAW, "tolerances": tolerances}
    (dst / "manifest.json").write_text(json.dumps(new))
    return dst


def seed_runs(out: Path) -> dict[str, dict[str, dict]]:
    """Each network's PSNR and SSIM (all and per zone, its own stage) per training seed
    evaluated so far (seed 0: the run named as the model, seed k: "<model>-s<k>")."""
    found: dict[str, dict[str, dict]] = {}
    for m in MODELS:
        for d in sorted((out / "evals").glob(f"{m}*/metrics.json")):
            name = d.parent.name
            seed = 0 if name == m else int(name[len(m) + 2 :]) if name.startswith(f"{m}-s") else None
            if seed is None:
                continue
            v = json.loads(d.read_text())["methods"]["model"]
            zones = {z: [v["zones"][z]["psnr_db"], v["zones"][z]["ssim"]] for z in ZONES}
            found.setdefault(m, {})[str(seed)] = {"all": [v["psnr_db"], v["ssim"]], **zones}
    return found


def seeds_table(seeds: dict[str, dict[str, dict]]) -> list[str]:
    """PSNR (dB) per zone of each network per seed, and the seeds' mean."""
    if not any(len(v) > 1 for v in seeds.values()):
        return []
    lines = ["", "| network | seed | all | centre | middle | edge |", "| --- | --- | --- | --- | --- | --- |"]
    for m, by_seed in seeds.items():
        for seed, v in sorted(by_seed.items()):
            lines.append(f"| {m} | {seed} | " + " | ".join(f"{v[k][0]:.2f}" for k in ("all", *ZONES)) + " |")
        mean = {k: sum(v[k][0] for v in by_seed.values()) / len(by_seed) for k in ("all", *ZONES)}
        lines.append(f"| {m} | mean | " + " | ".join(f"{mean[k]:.2f}" for k in ("all", *ZONES)) + " |")
    return lines


def report(out: Path, results: Path | None, runs: dict[str, dict], s: dict, seconds: float, camera: str) -> None:
    """OUT/restoration.json and OUT/table.md from the stages done so far (copied to results)."""
    res = gather(out, runs, seconds, camera, s.get("render") == "posed", s.get("tolerance_tag"))
    for m in sorted((out / "runs").glob("tolerances-*/summary.json")):  # the --tolerance-tag networks
        keys = ("steps", "epochs_done", "seconds", "val_psnr_db", "val_input_psnr_db", "wall_s")
        res["training"][m.parent.name] = {k: json.loads(m.read_text())[k] for k in keys}
    res["settings"] = s
    res["tolerance_tags"] = tolerance_tags(out, s.get("tolerance_tag"))
    res["stage_swap"] = stage_swap(out)
    res["seeds"] = seed_runs(out)
    if (out / "stage_kernels.json").exists():  # NCC of each stage's kernels with the test photos' PSFs, per zone
        res["stage_kernel_ncc"] = json.loads((out / "stage_kernels.json").read_text())
        for d in sorted(out.glob("draw_kernels-*.json")):  # the --tolerance-tag draws'
            res["stage_kernel_ncc"] |= json.loads(d.read_text())
    (out / "restoration.json").write_text(json.dumps(res, indent=1))
    (out / "table.md").write_text(table(res))
    if results:
        results.mkdir(parents=True, exist_ok=True)
        for f in ("restoration.json", "table.md"):
            (results / f).write_text((out / f).read_text())


def zero_shot_stages(out: Path, s: dict, lenses: dict, make: Callable[[str], Path]) -> None:
    """The shipped universal model zero-shot (`lensim restore --lens as_built.yaml`) on the
    test pairs with the calibrated lens's turned stage (lensim before the posed stage), its
    posed stage and the true lens's posed stage."""
    test = out / "pairs" / "test"
    evaluate(out, "universal@calibrated", test, "input,universal", bank_of(make("calibrated")), None)
    for stage in ("calibrated", "truth"):
        posed_stage_evaluate(out, f"universal@posed-{stage}", s, lenses[stage], "input,universal", None)


def settings_of(args: argparse.Namespace) -> dict:
    """The run's settings (FULL or TINY, the rendering, epochs, the --tolerance-tag runs')."""
    if args.tolerance_tag and (args.tolerance_file is None or args.render != "posed"):
        raise SystemExit("--tolerance-tag needs --tolerance-file and the posed rendering")
    s = {**(TINY if args.tiny else FULL), "render": args.render, "epochs": args.epochs}
    if args.tolerance_tag:
        s |= {"tolerance_tag": args.tolerance_tag, "tolerance_draws": args.tolerance_draws}
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/calibration-restoration"), help="work folder (resumable)")
    ap.add_argument("--results", type=Path, default=None, help="folder for table.md and restoration.json")
    ap.add_argument("--camera", default="larger_decentre", choices=sorted(CAMERAS), help="the perturbed camera")
    ap.add_argument("--render", default="posed", choices=("posed", "turned"), help="how lenses with poses render")
    ap.add_argument("--epochs", type=int, default=0, help="train this many epochs (0: the time budget)")
    ap.add_argument("--seeds", default="0", help="training seeds, comma-separated (seed 0 first: the main table)")
    ap.add_argument("--tiny", action="store_true", help="a dry run at tiny sizes")
    ap.add_argument("--tolerance-tag", default=None, help="name of another tolerance file's runs (posed rendering)")
    ap.add_argument("--tolerance-file", type=Path, default=None, help="that tolerance file")
    ap.add_argument("--tolerance-draws", type=int, default=8, help="how many of its draws (seed 0)")
    ap.add_argument(
        "--robust-train", default="robust", help=f"networks to train on them: {', '.join(ROBUST_TRAININGS)}"
    )
    args = ap.parse_args()
    s = settings_of(args)
    t0 = time.perf_counter()
    elapsed = args.out / "elapsed.json"  # seconds of earlier invocations (a killed run's are lost)
    before = json.loads(elapsed.read_text())["seconds"] if elapsed.exists() else 0.0
    args.out.mkdir(parents=True, exist_ok=True)
    make = pairs_maker(args.out, args.camera, s, split_photos(args.out, s["photo"], args.tiny), args.render)
    pairs = {"test": make("test")}
    test = pairs["test"]
    evaluate(args.out, "oracle", test, "input,wiener", None, None)
    pairs["nominal"] = make("nominal")
    evaluate(args.out, "universal", test, "input,universal", bank_of(pairs["nominal"]), None)
    runs: dict[str, dict] = {}

    def done() -> None:
        report(args.out, args.results, runs, s, before + time.perf_counter() - t0, args.camera)

    for m, stage_lens in MODELS.items():  # one model after the other: a partial run reports what it has
        pairs[m] = pairs.get(m) or make(m)
        runs[m] = train(args.out, m, pairs[m], s["budget"], s["train_crop"], epochs=args.epochs)
        evaluate(args.out, m, test, "input,model", bank_of(pairs[stage_lens]), args.out / "runs" / m)
        done()
    if args.render == "posed":  # the stages of lenses with poses posed too (per crop: posed_stage_evaluate)
        lenses = lenses_of(args.camera)
        kernels = args.out / "stage_kernels.json"
        if not kernels.exists():
            kernels.write_text(json.dumps(stage_kernels(args.out, args.camera, s), indent=1))
        posed_stage_evaluate(args.out, "oracle@posed-truth", s, lenses["truth"], "input,wiener", None)
        zero_shot_stages(args.out, s, lenses, make)
        done()
        for m in ("calibrated", "nominal", "tolerances"):
            run = args.out / "runs" / m
            posed_stage_evaluate(args.out, f"{m}@posed-calibrated", s, lenses["calibrated"], "input,model", run)
            done()
        for m in ("calibrated", "tolerances"):  # (b), (c) trained with posed stages too
            name = f"{m}@posed-stage"
            train(args.out, name, posed_stage_pairs(args.out, m, s), s["budget"], s["train_crop"], epochs=args.epochs)
            run = args.out / "runs" / name
            posed_stage_evaluate(args.out, f"{name}@posed-calibrated", s, lenses["calibrated"], "input,model", run)
            evaluate(args.out, f"{name}@nominal", test, "input,model", bank_of(pairs["nominal"]), run)
            done()
    banks = {"nominal": bank_of(pairs["nominal"]), "calibrated": bank_of(pairs["calibrated"]), "truth": bank_of(test)}
    for m in MODELS:  # every network with every stage bank: what the training pairs do, what the stage does
        for stage, bank in banks.items():
            if stage != MODELS[m]:
                evaluate(args.out, f"{m}@{stage}", test, "input,model", bank, args.out / "runs" / m)
    done()
    robust_phase(args.out, s, args, pairs, done)
    for seed in [int(k) for k in args.seeds.split(",") if k and int(k) != 0]:  # the same networks, other seeds
        for m, stage_lens in MODELS.items():
            name = f"{m}-s{seed}"
            train(args.out, name, pairs[m], s["budget"], s["train_crop"], seed=seed, epochs=args.epochs)
            evaluate(args.out, name, test, "input,model", bank_of(pairs[stage_lens]), args.out / "runs" / name)
            done()
    elapsed.write_text(json.dumps({"seconds": before + time.perf_counter() - t0}))
    log("done")


if __name__ == "__main__":
    main()
