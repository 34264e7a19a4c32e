"""Issue 17 part 1's measurement: NAFNet and its field-aware variants against the default
field-aware UNet and the plain UNet, each trained for the same wall-clock budget on the
same pairs, evaluated on held-out and unseen photos (PSNR / SSIM by field zone, paired per
crop), the way benchmarks/field_aware_vs_plain.sh measures the UNets.

Usage (from the repository root, after scripts/setup.sh with the Debian wallpapers):

    .venv/bin/python benchmarks/nafnet_vs_unet.py [OUT] [--seconds 1800] [--networks a,b,...]

Every stage is cached in OUT (a rerun skips what exists):

1. data, the recipe of benchmarks/generalization.sh: the default demo's PSF bank (Cooke
   triplet on the APS-C sensor, 12 fields, 13 wavelengths 400-700 nm, 128 pupil samples);
   the 20 training photos lensim had before issue 17 (scikit-image, sporco,
   mate-backgrounds: every exported photo but the KDE and Lomiri wallpapers) and the 11
   unseen test photos (lensim.assets.images.TEST_IMAGES); pairs: 3 sensor placements x 8
   crops of 128 px, seed 0;
2. the networks, two at a time, one thread (one core) each, for --seconds each, with
   field_aware_vs_plain.sh's recipe: Adam from 5e-4, cosine over the budget, batch 4, 96-px
   crops, dihedral augmentation, a quarter of the photos held out (the same for every run:
   the split depends only on the photo names and the seed, 0 for every run but
   the "-seed1" runs): unet (the default: width 32, FOV input, context block, DCN at the
   coarsest decoder scale), nafnet-fov-stem2 (FOV, pixel-unshuffle stem, size-matched),
   plain-unet (width 37, the same size, no switch), nafnet (plain, size-matched),
   nafnet-fov, nafnet-full (FOV, DCN at the coarsest decoder scale, context block),
   unet-seed1, nafnet-fov-stem2-seed1, plain-unet-seed1 (the same from seed 1: how far two
   runs of one network differ; seed 1 holds out other photos), nafnet-stem2 (the plain
   NAFNet with the pixel-unshuffle stem),
   nafnet-fov-stem2-w64 (width 64, 1.6 M parameters);
3. the last checkpoints (no model selection on the test photos), the aberrated input and
   the Wiener oracle (true PSFs) scored with lensim.evaluate.harness on the held-out
   photos' crops of each split (seed 0's networks on OUT/held_out.*, seed 1's on
   OUT/held_out-seed1.*, each paired against its split's UNet) and on every unseen test
   crop (every network, paired against the seed-0 UNet): OUT/held_out*.json,
   OUT/test_photos.json (summaries by zone), OUT/held_out*.csv, OUT/test_photos.csv (per
   crop), OUT/table.md (the tables, printed too): PSNR / SSIM overall and per zone, each
   network against its reference paired per crop (mean difference, its standard
   deviation, crops and photos ahead), and the networks run from two seeds, per seed and
   averaged.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
RECIPE = [
    "--threads",
    "1",
    "--crop",
    "96",
    "--batch-size",
    "4",
    "--lr",
    "5e-4",
    "--lr-schedule",
    "cosine",
    "--epochs",
    "100000",
    "--val-fraction",
    "0.25",
    "--quiet",
]
OFF = ["--no-fov", "--no-deformable", "--no-context"]
UNET = ["--arch", "unet", "--width", "32", "--deformable-scales", "1"]
# in the order they train, two at a time: the default UNet beside the fast candidate, ...
NETWORKS: dict[str, list[str]] = {
    "unet": [*UNET, "--seed", "0"],
    "nafnet-fov-stem2": ["--arch", "nafnet", "--stem", "2", "--no-deformable", "--no-context", "--seed", "0"],
    "plain-unet": ["--arch", "unet", "--width", "37", *OFF, "--seed", "0"],
    "nafnet": ["--arch", "nafnet", "--stem", "1", *OFF, "--seed", "0"],
    "nafnet-fov": ["--arch", "nafnet", "--stem", "1", "--no-deformable", "--no-context", "--seed", "0"],
    "nafnet-full": [
        "--arch",
        "nafnet",
        "--stem",
        "1",
        "--deformable",
        "--context",
        "--deformable-scales",
        "1",
        "--seed",
        "0",
    ],
    "unet-seed1": [*UNET, "--seed", "1"],  # the default again from another seed: run-to-run spread
    "nafnet-fov-stem2-seed1": ["--arch", "nafnet", "--stem", "2", "--no-deformable", "--no-context", "--seed", "1"],
    "plain-unet-seed1": ["--arch", "unet", "--width", "37", *OFF, "--seed", "1"],
    "nafnet-stem2": ["--arch", "nafnet", "--stem", "2", *OFF, "--seed", "0"],  # the plain NAFNet, made fast
    "nafnet-fov-stem2-w64": [
        "--arch",
        "nafnet",
        "--stem",
        "2",
        "--width",
        "64",
        "--no-deformable",
        "--no-context",
        "--seed",
        "0",
    ],
}
REFERENCE = "unet"
BANK = """import sys
from lensim.assets import DEFAULT_LENS
from lensim.demo import DemoSettings
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, get_bank
from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

if __name__ == "__main__":
    s = DemoSettings.make(quick=False)  # the demo's bank
    lens, sensor = load_lens(DEFAULT_LENS), load_sensor(DEFAULT_SENSOR)
    settings = BankSettings(fields=s.fields, wavelengths_nm=s.wavelengths_nm, pupil_samples=s.pupil_samples,
                            kernel_limit=41)
    get_bank(lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, workers=2, out_dir=sys.argv[1])
"""


def lensim(*args: str) -> None:
    subprocess.run([str(BIN / "lensim"), *args], check=True, cwd=ROOT)


def make_data(out: Path) -> None:
    """Stage 1 (cached): bank, photos-old (20), photos-test (11), pairs-old, pairs-test."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "make_bank.py").write_text(BANK)
    subprocess.run([sys.executable, str(out / "make_bank.py"), str(out / "bank")], check=True, cwd=ROOT)
    if not (out / "photos-old").is_dir():
        tmp_all, tmp_old, tmp_test = out / "photos-all.tmp", out / "photos-old.tmp", out / "photos-test.tmp"
        for d in (tmp_all, tmp_old, tmp_test):
            shutil.rmtree(d, ignore_errors=True)
        lensim("assets", "--export-photos", str(tmp_all), "--export-test-photos", str(tmp_test))
        tmp_old.mkdir()
        for f in sorted(tmp_all.glob("*.png")):  # the 20 of before issue 17
            if not f.name.startswith(("kde-", "lomiri-")):
                shutil.copy(f, tmp_old / f.name)
        shutil.rmtree(tmp_all)
        tmp_test.rename(out / "photos-test")
        tmp_old.rename(out / "photos-old")
    pairs = [
        "--bank",
        str(out / "bank"),
        "--placements",
        "3",
        "--crops",
        "8",
        "--size",
        "128",
        "--seed",
        "0",
        "--workers",
        "2",
        "--quiet",
    ]
    for name in ("old", "test"):
        if not (out / f"pairs-{name}" / "manifest.json").is_file():
            lensim("dataset", "make", str(out / f"photos-{name}"), "-o", str(out / f"pairs-{name}"), *pairs)


def train_all(out: Path, names: list[str], seconds: float) -> None:
    """Stage 2 (cached by NAME.done): the networks two at a time, one thread each."""
    todo = [n for n in names if not (out / f"{n}.done").exists()]
    for i in range(0, len(todo), 2):
        procs = []
        for name in todo[i : i + 2]:
            shutil.rmtree(out / name, ignore_errors=True)
            cmd = [
                str(BIN / "lensim"),
                "train",
                str(out / "pairs-old"),
                "-o",
                str(out / name),
                "--time-budget-s",
                f"{seconds:g}",
                *RECIPE,
                *NETWORKS[name],
            ]
            procs.append((name, subprocess.Popen(cmd, cwd=ROOT)))
        for name, p in procs:
            if p.wait() != 0:
                raise SystemExit(f"training {name} failed (exit {p.returncode})")
            (out / f"{name}.done").write_text(time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()) + "\n")


def _split_groups(out: Path, names: list[str]) -> list[tuple[str, str, list[str], list[str]]]:
    """(label, reference, held-out photos, networks) for each held-out split among the
    runs (the split depends on the seed): "held_out" for the reference's split, then
    "held_out-seedN" for the others; each group's reference is its first UNet run."""
    from lensim.data.manifest import read_held_out

    groups: dict[tuple[str, ...], list[str]] = {}
    for n in [REFERENCE, *[n for n in names if n != REFERENCE]]:
        groups.setdefault(tuple(read_held_out(out / n)), []).append(n)
    result = []
    for i, (held_out, nets) in enumerate(groups.items()):
        seed = json.loads((out / nets[0] / "split.json").read_text())["seed"]
        reference = next((n for n in nets if n.startswith("unet")), nets[0])
        result.append(("held_out" if i == 0 else f"held_out-seed{seed}", reference, list(held_out), nets))
    return result


def evaluate_all(out: Path, names: list[str], wiener: bool = True) -> dict:
    """Stage 3: every network, input and Wiener on each split's held-out crops (the networks
    of that split) and on the test crops (every network)."""
    from lensim.data.manifest import read_pairs_manifest
    from lensim.evaluate.harness import builtin_method, checkpoint_method, evaluate, write_csv

    results: dict = {}
    stages = [
        (label, reference, out / "pairs-old", held_out, nets)
        for label, reference, held_out, nets in _split_groups(out, names)
    ]
    stages.append(("test_photos", REFERENCE, out / "pairs-test", None, names))
    for label, reference, pairs, sources, nets in stages:
        manifest = read_pairs_manifest(pairs)
        methods = {
            n: checkpoint_method(out / n / "last.pt", manifest.get("lens"), manifest.get("sensor")) for n in nets
        }
        if wiener:
            methods["wiener"] = builtin_method("wiener")
        rows: list[dict] = []
        summary = evaluate(pairs, methods, bank=out / "bank", sources=sources, rows=rows)
        (out / f"{label}.json").write_text(json.dumps(summary, indent=2) + "\n")
        write_csv(rows, out / f"{label}.csv")
        results[label] = {"summary": summary, "rows": rows, "networks": nets, "reference": reference, "photos": sources}
    return results


def _zone_table(summary: dict) -> list[str]:
    methods = summary["methods"]
    base = methods["input"]
    lines = [
        "| method | PSNR (dB) | gain | SSIM | centre | middle | edge |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, m in methods.items():
        zones = []
        for z in ("centre", "middle", "edge"):
            a, b = m["zones"][z]["psnr_db"], base["zones"][z]["psnr_db"]
            zones.append(f"{a:.2f} ({a - b:+.2f}) / {m['zones'][z]['ssim']:.3f}")
        lines.append(
            f"| {name} | {m['psnr_db']:.2f} | {m['psnr_db'] - base['psnr_db']:+.2f} | {m['ssim']:.4f} | "
            + " | ".join(zones)
            + " |"
        )
    return lines


def _paired(rows: list[dict], names: list[str], reference: str) -> list[str]:
    crops: dict[tuple, dict] = {}
    for r in rows:
        crops.setdefault((r["record"], r["crop"], r["source"]), {})[r["method"]] = float(r["psnr_db"])
    lines = [
        f"| network - {reference} | mean (dB) | sd | crops ahead | photos ahead (by mean) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for n in names:
        if n == reference:
            continue
        diff = [c[n] - c[reference] for c in crops.values()]
        per_photo: dict[str, list[float]] = {}
        for (_, _, src), c in crops.items():
            per_photo.setdefault(Path(src).name, []).append(c[n] - c[reference])
        ahead = sum(statistics.mean(v) > 0 for v in per_photo.values())
        lines.append(
            f"| {n} | {statistics.mean(diff):+.3f} | {statistics.stdev(diff):.3f} | "
            f"{sum(d > 0 for d in diff)} of {len(diff)} | {ahead} of {len(per_photo)} |"
        )
    return lines


def _seed_table(results: dict, names: list[str]) -> list[str]:
    """Networks run from more than one seed: PSNR per seed and the mean, held out (each
    seed's own split) and on the unseen test photos."""
    runs: dict[str, list[str]] = {}
    for n in names:
        runs.setdefault(n.removesuffix("-seed1"), []).append(n)
    held = {
        n: r["summary"]["methods"][n]["psnr_db"]
        for label, r in results.items()
        if label.startswith("held_out")
        for n in r["networks"]
    }
    unseen = results["test_photos"]["summary"]["methods"]
    lines = [
        "| network | seeds | held out, per seed (dB) | held out, mean | unseen, per seed (dB) | unseen, mean |",
        "| --- | ---: | --- | ---: | --- | ---: |",
    ]
    for base, seeds in runs.items():
        if len(seeds) < 2:
            continue
        h, u = [held[n] for n in seeds], [unseen[n]["psnr_db"] for n in seeds]
        lines.append(
            f"| {base} | {len(seeds)} | {' / '.join(f'{v:.2f}' for v in h)} | {statistics.mean(h):.2f} | "
            f"{' / '.join(f'{v:.2f}' for v in u)} | {statistics.mean(u):.2f} |"
        )
    return lines


def report(out: Path, names: list[str], results: dict, seconds: float) -> str:
    lines = [f"# NAFNet vs UNet, {seconds:g} s of training each (benchmarks/nafnet_vs_unet.py)", ""]
    lines.append("| network | params | steps | seconds |")
    lines.append("| --- | ---: | ---: | ---: |")
    from lensim.restore.checkpoint import load_checkpoint
    from lensim.restore.network import count_parameters

    for n in names:
        model, info = load_checkpoint(out / n / "last.pt")
        lines.append(f"| {n} | {count_parameters(model):,} | {info['step']} | {info['train_seconds']:.0f} |")
    for label, r in results.items():
        title = (
            f"Held-out photos, {label.partition('-')[2].replace('seed', 'seed ') or 'seed 0'} ({', '.join(r['photos'])})"
            if label.startswith("held_out")
            else "Unseen test photos"
        )
        lines += ["", f"## {title}", "", "PSNR (dB), gain over the input, SSIM; zones: PSNR (gain) / SSIM", ""]
        lines += _zone_table(r["summary"])
        lines += ["", "Paired per crop:", ""] + _paired(r["rows"], r["networks"], r["reference"])
    seeds = _seed_table(results, names)
    if len(seeds) > 2:
        lines += ["", "## Across seeds", ""] + seeds
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="bench-nafnet")
    ap.add_argument("--seconds", type=float, default=1800.0, help="Training seconds per network.")
    ap.add_argument("--networks", default=",".join(NETWORKS), help="Comma list of " + ", ".join(NETWORKS))
    ap.add_argument(
        "--no-wiener",
        action="store_true",
        help="Leave out the Wiener oracle (it does not depend on the networks; the slowest method to evaluate).",
    )
    args = ap.parse_args()
    out = Path(args.out).resolve()
    names = [n.strip() for n in args.networks.split(",") if n.strip()]
    unknown = [n for n in names if n not in NETWORKS]
    if unknown or REFERENCE not in names:
        raise SystemExit(f"unknown networks {unknown}; expected some of {', '.join(NETWORKS)} including {REFERENCE}")
    make_data(out)
    train_all(out, names, args.seconds)
    results = evaluate_all(out, names, wiener=not args.no_wiener)
    text = report(out, names, results, args.seconds)
    (out / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
