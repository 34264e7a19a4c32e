"""Model (c) of calibration_restoration.py again: more tolerance draws, the draws' mean PSF
as the Wiener stage's bank, a longer budget (issue 24, item 5's targets).

calibration_restoration.py's model (c) fine-tunes the universal model 300 s on pairs made
through 4 draws of a maker's tolerance file and restores the perturbed camera's photos with
the nominal lens's stage. The variants measured here, on the same camera, test photos and
training photos (the work folder of calibration_restoration.py):

  draws K        the pairs made through K draws of the same file (seed 0: the first 4 draws
                 are the benchmark's); each pair's stage is its draw's bank (lensim's rule);
  mean stage     the pairs' stage in training is the draws' mean bank for every pair
                 (mean_bank: per field the mean of the draws' kernels, the expected PSF
                 over the tolerance distribution);
  nominal stage  the pairs' stage in training is the nominal lens's bank for every pair
                 (the stage inference has, mismatch included);
  epochs E       every network here is trained a fixed number of epochs (18: what the
                 benchmark's 300 s gave (a) and (b) on a quiet machine; a time budget gives
                 fewer steps on a loaded one), (a), (b) and (c) alike, and twice that.

Each network restores with the nominal lens's stage (what (c)'s user has), with the draws'
mean bank, and with the calibrated lens's (what (b)'s user has); the Wiener filter alone
with each bank is scored too. Needs calibration_restoration.py's work folder:

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_tolerance_draws.py \\
        --out /tmp/calibration-restoration \\
        --results benchmarks/results/calibration/restoration/tolerance_draws.json

Resumable (pairs, banks, runs and evaluations are kept under --out and skipped when done);
--steps picks which variants run, in order (a partial run reports what it has).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import calibration_restoration as cr
import numpy as np

from lensim.errors import InputError
from lensim.io import atomic_write_text
from lensim.psf.bank.compute import embed_centred
from lensim.psf.bank.store import MANIFEST, load_bank, read_manifest, write_field
from lensim.psf.bank.types import BankField, PSFBank

#: manifest keys every bank of the mean must share (the sampling of the kernels)
SHARED_KEYS = ("pixel_pitch_um", "oversampling", "fields", "wavelengths_nm", "primary_wavelength_nm", "response")


def _check_shared(banks: Sequence[PSFBank]) -> None:
    """One-line InputError naming the first bank whose sampling differs from the first's."""
    first = banks[0].manifest
    for b in banks[1:]:
        for key in SHARED_KEYS:
            if json.dumps(b.manifest.get(key)) != json.dumps(first.get(key)):
                raise InputError(
                    str(b.directory or "<bank>"),
                    key,
                    f"expected the same {key} as {banks[0].directory or 'the first bank'} "
                    f"({first.get(key)!r}) to average the banks, got {b.manifest.get(key)!r}",
                )


def _mean_field(fields: Sequence[BankField], size: int, fine: int) -> BankField:
    """The mean of one field over the banks: kernels embedded in (size, size), fine PSFs in
    (fine, fine)."""

    def mean(get: Any) -> np.ndarray:
        return np.mean([np.asarray(get(f), dtype=np.float64) for f in fields], axis=0)

    azimuths = None
    if all(f.rgb_azimuths is not None for f in fields):
        azimuths = mean(lambda f: embed_centred(f.rgb_azimuths, size)).astype(np.float32)
    f0 = fields[0]
    return BankField(
        index=f0.index,
        field=f0.field,
        field_value=f0.field_value,
        rgb=mean(lambda f: embed_centred(f.rgb, size)).astype(np.float32),
        reference_xy_mm=mean(lambda f: f.reference_xy_mm),
        paraxial_xy_mm=mean(lambda f: f.paraxial_xy_mm),
        chief_offsets_mm=mean(lambda f: f.chief_offsets_mm),
        relative_illumination=mean(lambda f: f.relative_illumination),
        transmission=mean(lambda f: f.transmission),
        window_energy=mean(lambda f: f.window_energy),
        strehl=float(mean(lambda f: f.strehl)),
        working_fno=float(mean(lambda f: f.working_fno)),
        primary_fine=mean(lambda f: embed_centred(f.primary_fine, fine)).astype(np.float32),
        warnings=sorted({w for f in fields for w in f.warnings}),
        rgb_azimuths=azimuths,
    )


def mean_bank(banks: Sequence[PSFBank], directory: str | Path, lens: Mapping[str, Any], note: Any) -> PSFBank:
    """Write the expected PSF bank of ``banks`` into ``directory`` and return it: per field
    each kernel the mean of the banks' kernels, embedded centred in the largest (every
    kernel is centred on its own lens's primary-wavelength chief-ray point, as the
    simulation places it), so the mean keeps each kernel's sum; every other per-field
    quantity is the banks' mean too. The banks must share their sampling (SHARED_KEYS).

    lens: the native lens mapping the bank records (the nominal lens of the family, named
    so: the bank is no one lens's); note: what the bank is the mean of, recorded under the
    manifest's ``mean_of`` (JSON-able; with the banks' folders). A folder that already holds
    this mean (the same manifest) is loaded, not recomputed; every file is written
    atomically, the manifest first and each field after it (a killed run is redone).
    Raises InputError when ``banks`` is empty or their sampling differs."""
    if not banks:
        raise InputError(None, "banks", "expected at least one bank to average")
    _check_shared(banks)
    d = Path(directory)
    size = max(b.kernel_pixels for b in banks)
    fine = max(f.primary_fine.shape[-1] for b in banks for f in b.fields)
    manifest = {k: v for k, v in banks[0].manifest.items() if k != "lens_file"}
    manifest.update(kernel_pixels=size, lens=dict(lens))
    manifest["mean_of"] = {"banks": [str(b.directory) for b in banks], "note": note}
    manifest = json.loads(json.dumps(manifest))
    old = read_manifest(d) if (d / MANIFEST).is_file() else None
    if old == manifest and len(list(d.glob("field_*.npz"))) == len(banks[0].fields):
        return load_bank(d)
    d.mkdir(parents=True, exist_ok=True)
    for p in d.glob("field_*.npz"):
        p.unlink()
    atomic_write_text(d / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    for i in range(len(banks[0].fields)):
        write_field(d, _mean_field([b.fields[i] for b in banks], size, fine), manifest)
    return load_bank(d)


#: the variants, in the order they run by default: name -> (draws, training stage, seed, epochs).
#: Trained a fixed number of epochs (cosine along the epochs), not on a time budget: the shared
#: machine's load changes the steps a 300 s budget gives (687-818 for the benchmark's runs,
#: about 500 at load 5); 18 epochs (about 730 steps) is what its 300 s gave (a) and (b).
EPOCHS = 18
VARIANTS: dict[str, tuple[int, str, int, int]] = {
    "draws16-s0": (16, "own", 0, EPOCHS),
    "draws16-s1": (16, "own", 1, EPOCHS),
    "draws16-nominalstage-s0": (16, "nominal", 0, EPOCHS),
    "draws4-meanstage-s0": (4, "mean", 0, EPOCHS),
    "draws16-meanstage-s0": (16, "mean", 0, EPOCHS),
    "draws4-s0": (4, "own", 0, EPOCHS),
    "nominal-s0": (0, "nominal", 0, EPOCHS),
    "calibrated-s0": (0, "calibrated", 0, EPOCHS),
    "draws16-s0-36ep": (16, "own", 0, 2 * EPOCHS),
    "nominal-s0-36ep": (0, "nominal", 0, 2 * EPOCHS),
    "calibrated-s0-36ep": (0, "calibrated", 0, 2 * EPOCHS),
}
#: runs on the 300 s budget (the benchmark's own and one here) -> (run folder, draws)
KNOWN = {
    "draws4-300s-s0": ("tolerances", 4),
    "draws4-300s-s1": ("tolerances-own-s1", 4),
    "draws16-300s-s0": ("draws16-300s-s0", 16),  # at load 5: 490 steps
    "nominal-300s": ("nominal", 0),
    "calibrated-300s": ("calibrated", 0),
}


def tolerance_pairs(out: Path, draws: int) -> Path:
    """Pairs through `draws` draws (the benchmark's own for 4)."""
    if draws == cr.FULL["draws"]:
        return out / "pairs" / "tolerances"
    lenses = cr.make_lenses(out)
    s = {**cr.FULL, "draws": draws}
    return cr.make_pairs(
        out, f"tolerances-{draws}", out / "photos" / "train", lenses["nominal"], s, lenses["tolerances"]
    )


def draws_mean(out: Path, draws: int) -> Path:
    """The mean bank of the draws of the `draws`-draw pairs (computed once)."""
    folder = out / "banks" / f"mean{draws}"
    manifest = json.loads((tolerance_pairs(out, draws) / "manifest.json").read_text())
    banks = [PSFBank.load(d["bank"]) for d in manifest["tolerances"]["draws"]]
    lens = {**manifest["lens"], "name": f"{manifest['lens']['name']} (mean of {draws} tolerance draws, seed 0)"}
    mean_bank(banks, folder, lens, {"tolerances": manifest["tolerances"]["file"], "seed": 0, "draws": draws})
    return folder


def one_stage_pairs(out: Path, draws: int, stage: str) -> Path:
    """A hard-linked copy of the draws' pairs whose manifest gives every pair one stage
    bank: the draws' mean ("mean") or the nominal lens's ("nominal")."""
    src = tolerance_pairs(out, draws)
    dst = out / "pairs" / f"tolerances-{draws}-{stage}-stage"
    if not (dst / "manifest.json").exists():
        tmp = dst.with_name(dst.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        subprocess.run(["cp", "-al", str(src), str(tmp)], check=True)
        shutil.rmtree(tmp / "wiener", ignore_errors=True)
        m = json.loads((tmp / "manifest.json").read_text())
        m["bank"] = str(draws_mean(out, draws)) if stage == "mean" else cr.bank_of(out / "pairs" / "nominal")
        m.pop("tolerances")
        m.pop("stage_bank", None)
        os.unlink(tmp / "manifest.json")  # a hard link: the original's must stay
        (tmp / "manifest.json").write_text(json.dumps(m))
        os.rename(tmp, dst)
    return dst


def scores(evals: Path, method: str = "model") -> dict[str, float]:
    v = json.loads((evals / "metrics.json").read_text())["methods"][method]
    return {"all": round(v["psnr_db"], 3), **{z: round(v["zones"][z]["psnr_db"], 3) for z in cr.ZONES}}


def stage_banks(out: Path, draws: int) -> dict[str, str]:
    """The banks a network restores with: nominal, the draws' mean (when there are draws), calibrated."""
    banks = {"nominal": cr.bank_of(out / "pairs" / "nominal")}
    if draws:
        banks[f"mean{draws}"] = str(draws_mean(out, draws))
    banks["calibrated"] = cr.bank_of(out / "pairs" / "calibrated")
    return banks


def evaluate_run(out: Path, run: str, draws: int) -> dict[str, dict[str, float]]:
    """The network of run `run` on the test pairs with each stage bank, and per photo (edge zone)."""
    res: dict[str, dict] = {}
    for stage, bank in stage_banks(out, draws).items():
        d = cr.evaluate(out, f"{run}@{stage}", out / "pairs/test", "input,model", bank, out / "runs" / run)
        res[stage] = scores(d)
        photos = cr.per_photo(d, "model")
        res[stage]["edge_per_photo"] = {p: round(v.get("edge", float("nan")), 3) for p, v in photos.items()}
    return res


def train(out: Path, name: str, pairs: Path, epochs: int, seed: int) -> dict:
    """`lensim train --init universal` for `epochs` epochs (calibration_restoration.train's
    settings otherwise), once."""
    run = out / "runs" / name
    marker = run / "summary.json"
    if marker.exists():
        return dict(json.loads(marker.read_text()))
    cr.log(f"train {name} ({epochs} epochs)")
    args = ["train", str(pairs), "-o", str(run), "--init", "universal", "--epochs", str(epochs), "--batch-size", "4"]
    args += ["--lr", "2e-4", "--lr-schedule", "cosine", "--crop", str(cr.FULL["train_crop"]), "--val-fraction"]
    args += ["0.25", "--seed", str(seed), "--threads", "1", "--json"] + (
        ["--resume"] if (run / "last.pt").exists() else []
    )
    summary = json.loads(cr.lensim(*args))
    marker.write_text(json.dumps(summary, indent=1))
    cr.log(f"train {name}: {summary['steps']} steps, {summary['seconds']:.0f} s")
    return dict(summary)


def one(out: Path, name: str) -> dict:
    """Train variant `name` (once) and evaluate it."""
    draws, stage, seed, epochs = VARIANTS[name]
    if not draws:  # (a) or (b)
        pairs = out / "pairs" / stage
    else:
        pairs = tolerance_pairs(out, draws) if stage == "own" else one_stage_pairs(out, draws, stage)
    run = train(out, name, pairs, epochs, seed)
    info = {k: run[k] for k in ("steps", "epochs_done", "seconds", "val_psnr_db")}
    return {**info, "stage_psnr_db": evaluate_run(out, name, draws)}


def wiener_alone(out: Path, draws: list[int]) -> dict[str, dict[str, float]]:
    """The Wiener filter alone on the test pairs with each bank (true lens's: the oracle)."""
    res = {"truth": scores(out / "evals" / "oracle", "wiener")}
    banks = {"nominal": cr.bank_of(out / "pairs" / "nominal"), "calibrated": cr.bank_of(out / "pairs" / "calibrated")}
    banks.update({f"mean{k}": str(draws_mean(out, k)) for k in draws})
    for stage, bank in banks.items():
        d = cr.evaluate(out, f"wiener@{stage}", out / "pairs/test", "input,wiener", bank, None)
        res[stage] = scores(d, "wiener")
    return res


def _cells(v: dict[str, float]) -> str:
    return " / ".join(f"{v[k]:.2f}" for k in ("all", *cr.ZONES))


#: (network, its user's stage) of models (a), (b), (c) for the differences and per photo
OWN = {"nominal": "nominal", "calibrated": "calibrated"}


def table(res: dict) -> str:
    """The markdown tables of a result: every network with every stage bank, the Wiener
    filter alone, the targets' differences per zone, and the edge zone per photo."""
    lines = ["| network | epochs | steps | stage: nominal lens | draws' mean | calibrated lens |"]
    lines.append("| --- | --- | --- | --- | --- | --- |")
    for name, r in res["runs"].items():
        st = r["stage_psnr_db"]
        mean = next((v for k, v in st.items() if k.startswith("mean")), None)
        cells = [_cells(st["nominal"]), _cells(mean) if mean else "", _cells(st["calibrated"])]
        lines.append(f"| {name} | {r['epochs_done']} | {r['steps']} | " + " | ".join(cells) + " |")
    lines += ["", "| Wiener filter alone, bank | all / centre / middle / edge |", "| --- | --- |"]
    lines += [f"| {b} | {_cells(v)} |" for b, v in res["wiener"].items()]
    own = {
        n: r["stage_psnr_db"]["calibrated" if n.startswith("calibrated") else "nominal"] for n, r in res["runs"].items()
    }
    lines += [
        "",
        "| difference (dB), each with its user's stage | centre | middle | edge |",
        "| --- | --- | --- | --- |",
    ]
    for a, b in (
        ("calibrated-300s", "nominal-300s"),
        ("calibrated-s0", "nominal-s0"),
        ("calibrated-s0-36ep", "nominal-s0-36ep"),
        *((c, "calibrated-300s") for c in own if c.startswith("draws") and "300s" in c),
        *((c, "calibrated-s0") for c in own if c.startswith("draws") and "36ep" not in c and "300s" not in c),
        ("draws16-s0-36ep", "calibrated-s0-36ep"),
    ):
        if a in own and b in own:
            lines.append(f"| {a} - {b} | " + " | ".join(f"{own[a][z] - own[b][z]:+.2f}" for z in cr.ZONES) + " |")
    names = [n for n in own if "edge_per_photo" in own[n]]
    lines += ["", "| photo (edge zone, dB) | " + " | ".join(names) + " |", "|" + " --- |" * (len(names) + 1)]
    for p in own[names[0]]["edge_per_photo"] if names else []:
        lines.append(f"| {p} | " + " | ".join(f"{own[n]['edge_per_photo'][p]:.2f}" for n in names) + " |")
    return "\n".join(lines + _larger_table(res.get("larger_cameras"))) + "\n"


def _larger_table(cams: dict | None) -> list[str]:
    """The larger-error cameras' rows (none without them)."""
    lines: list[str] = []
    for name, lc in (cams or {}).items():
        fit = "calibrated: " + json.dumps(lc["fitted"]) if lc.get("fitted") else "not calibrated"
        lines += ["", f"Camera `{name}` {json.dumps(lc['truth'])} ({fit}); PSNR dB all / centre / middle / edge", ""]
        lines += ["| method | stage: nominal lens | true lens | draws' mean | calibrated lens |"]
        lines += ["| --- | --- | --- | --- | --- |", f"| input | {_cells(lc['input'])} | | | |"]
        for run, st in {"Wiener filter": lc["wiener"], **lc["networks"]}.items():
            mean = next((v for k, v in st.items() if k.startswith("mean")), None)
            cells = [st.get("nominal"), st.get("truth"), mean, st.get("calibrated")]
            lines.append(f"| {run} | " + " | ".join(_cells(c) if c else "" for c in cells) + " |")
    return lines


#: cameras with a larger element error than focus_decentre (the same focus error): "larger",
#: element 3 decentred 15 um and tilted 0.1 deg (element tilts are not among the parameters
#: lensim calibrate fits: not calibrated, it gives the ceiling of (b) - (a), network (a)
#: restoring with the true lens's stage); "larger_decentre", calibration_validation.py's
#: camera of that name, calibrated by it (FITS)
LARGER = {
    "larger": {"image.focus": 0.006, "e3.decentre_x": 0.015, "e3.tilt_x": 0.1},
    "larger_decentre": {"image.focus": 0.006, "e3.decentre_x": 0.012, "image.tilt_y": 0.05},
}
FITS = {"larger_decentre": Path(__file__).parent / "results/calibration/larger/larger_decentre.json"}


def _camera_pairs(out: Path, name: str, values: dict[str, float]) -> Path:
    """Test pairs (the test photos, the benchmark's settings) through the nominal lens perturbed by `values`."""
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens
    from lensim.optics.shooting import ShootingSettings, lens_at

    path = out / "lenses" / f"{name}.json"
    if not path.exists():
        lens = lens_at(load_lens(cr.LENS, warn=False), ShootingSettings(object_m=cr.DISTANCE_M, focus_m=cr.DISTANCE_M))
        save_lens(perturbed_lens(lens, values), path)
    return cr.make_pairs(
        out, f"test-{name}", out / "photos" / "test", path, {**cr.FULL, "crops": cr.FULL["test_crops"]}
    )


def ceiling(out: Path, name: str, networks: list[str]) -> dict:
    """Camera `name` of LARGER: its test pairs, the Wiener filter and each network with the
    nominal, the true, the draws' mean (tolerance networks) and, when its calibration is in
    FITS, the calibrated lens's stage (that lens's bank: pairs through it, for the bank)."""
    test = _camera_pairs(out, name, LARGER[name])
    banks = {"nominal": cr.bank_of(out / "pairs" / "nominal"), "truth": cr.bank_of(test)}
    res: dict = {"truth": LARGER[name], "wiener": {}, "networks": {}}
    fit = FITS.get(name)
    if fit is not None and fit.exists():
        res["fitted"] = json.loads(fit.read_text())["fitted"]
        banks["calibrated"] = cr.bank_of(_camera_pairs(out, f"{name}-calibrated", res["fitted"]))
    pre = "larger" if name == "larger" else name  # the first camera's evaluations keep their names
    for stage, bank in banks.items():
        d = cr.evaluate(out, f"{pre}-wiener@{stage}", test, "input,wiener", bank, None)
        res["wiener"][stage] = scores(d, "wiener")
    res["input"] = scores(out / "evals" / f"{pre}-wiener@truth", "input")
    for run in networks:
        draws = VARIANTS[run][0] if run in VARIANTS else 0
        extra = {f"mean{draws}": str(draws_mean(out, draws))} if draws else {}
        for stage, bank in {**banks, **extra}.items():
            d = cr.evaluate(out, f"{pre}-{run}@{stage}", test, "input,model", bank, out / "runs" / run)
            res["networks"].setdefault(run, {})[stage] = scores(d)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=Path("/tmp/calibration-restoration"), help="the benchmark's work folder"
    )
    ap.add_argument("--results", type=Path, default=None, help="the JSON file to write (and the tables beside it, .md)")
    ap.add_argument("--steps", default=",".join(VARIANTS), help="variants to run, comma-separated, in order")
    ap.add_argument("--larger", default="", help="variants trained already to score on the larger-error cameras too")
    ap.add_argument("--cameras", default=",".join(LARGER), help="the larger-error cameras (LARGER) for --larger")
    args = ap.parse_args()
    names = [v for v in args.steps.split(",") if v]
    unknown = sorted(set(names) - set(VARIANTS))
    if unknown:
        raise SystemExit(f"--steps: unknown variants {unknown}; expected some of {list(VARIANTS)}")
    what = " ".join(" ".join(__doc__.split("\n\n")[1:4]).split())
    res: dict = {"what": what, "command": "benchmarks/calibration_tolerance_draws.py", "runs": {}}

    def write() -> None:
        text = json.dumps(res, indent=1) + "\n"
        (args.out / "tolerance_draws.json").write_text(text)
        (args.out / "tolerance_draws.md").write_text(table(res))
        if args.results:
            args.results.write_text(text)
            args.results.with_suffix(".md").write_text(table(res))

    for known, (run, draws) in KNOWN.items():  # 300 s runs (the benchmark's own) with the same stage banks
        info = json.loads((args.out / "runs" / run / "summary.json").read_text())
        info = {k: info[k] for k in ("steps", "epochs_done", "seconds", "val_psnr_db")}
        res["runs"][known] = {"run": run, **info, "stage_psnr_db": evaluate_run(out=args.out, run=run, draws=draws)}
    res["wiener"] = wiener_alone(args.out, [cr.FULL["draws"]])
    write()
    if args.larger:  # networks trained already (before the variants: it is quick)
        nets = [v for v in args.larger.split(",") if v]
        res["larger_cameras"] = {c: ceiling(args.out, c, nets) for c in args.cameras.split(",") if c}
        write()
    for name in names:
        res["runs"][name] = one(args.out, name)
        draws = sorted({VARIANTS[n][0] for n in names if n in res["runs"] and VARIANTS[n][0]} | {cr.FULL["draws"]})
        res["wiener"] = wiener_alone(args.out, draws)
        write()
    cr.log("done")


if __name__ == "__main__":
    main()
