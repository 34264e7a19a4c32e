"""Calibration validated in simulation, where the truth is known (issue 24, item 5).

Each "camera" is the phone lens (phone_wide, the chart at 1 m) with a perturbation: its
chart photo is simulated through the full pipeline (perspective homography, the lens's
PSF bank, mosaic, shot and read noise, AHD demosaic, develop) and calibrated as
`lensim calibrate` does (lensim.calibrate.calibrate: nominal simulation, per-edge SFRs,
the fit). A perturbed lens is not rotationally symmetric and a PSF bank rotates its +y
PSFs to every azimuth, so a perturbed camera is rendered with one bank per diagonal of the
chart (the lens turned to that azimuth, lensim.calibrate.tolerance_report.lens_at_azimuth):
each quadrant of the frame through its diagonal's bank (the chart's edge squares lie on
the four diagonals). The calibrated camera is rendered the same way.

The calibration is lensim calibrate's: the fit with the nominal lens's system transfer,
then up to REFRESH_ROUNDS transfer refreshes at the fitted lens (lensim.calibrate.refresh;
the first fit and each round are checkpointed in OUT/<camera>.first.json and
OUT/<camera>.rounds.json, so a killed run resumes after the last round).

Reported per camera: the MTF-area ratio simulation/photo per zone before (nominal lens)
and after (as-built lens) calibration, and through the true lens ("at_truth": the ratio's
own noise floor, the photo's and the simulation's SFR noise; --truth-again adds it to a
recorded result), the NCC of the as-built (and nominal) Huygens PSFs against the true ones
at the centre, 0.7 and the corner (550 nm; on the lower-right diagonal, and the worst of
the four diagonals), the fitted parameters against the truth, the degenerate pairs, the
fit's run time, model evaluations and traces. The NCC is taken on a 16 um window (the rows
before 2026-11-28 07:00; it holds 92 % of a field's spot) and on a 40 um one (the whole
spot; fields "<field> 40um").

Camera "held_out" is draw 0 of seed 2024 of HELD_OUT_TOLERANCES (element tilts and
spacings the fit does not model included); it was not run while the method was developed.

    nice -n 15 env OMP_NUM_THREADS=1 python benchmarks/calibration_validation.py --out benchmarks/results/calibration

Resumable: banks are cached under --cache (not committed), each camera's result is written to
OUT/<camera>.json as it finishes and skipped on a rerun; OUT/table.md gathers them.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from lensim.calibrate.calibrate import calibrate_charts, chart_data, luminance_spectrum, observations
from lensim.calibrate.chart import design_chart
from lensim.calibrate.chart_detect import detect_chart
from lensim.calibrate.chart_draw import render_view
from lensim.calibrate.compare import compare_images, simulate_chart
from lensim.calibrate.fit import Fit
from lensim.calibrate.refresh import chart_simulator, refine
from lensim.calibrate.tolerance_report import lens_at_azimuth
from lensim.calibrate.tolerances import drawn_lens, perturbed_lens, tolerances_from_dict
from lensim.optics.lens_file import load_lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.shooting import ShootingSettings, lens_at
from lensim.psf.bank import BankSettings, get_bank
from lensim.psf.compute import compute_psf
from lensim.render.mapping import map_to_sensor
from lensim.render.pipeline import simulate
from lensim.render.posed import compose_quadrants, posed_banks, quadrant_azimuths
from lensim.sensor.profile import load_sensor

LENS, SENSOR, DISTANCE_M = "phone_wide", "phone", 1.0
ROWS, COLS = 720, 960
WAVELENGTHS_NM = (450.0, 550.0, 650.0)
CAMERAS = {
    "focus_decentre": {"image.focus": 0.006, "e3.decentre_x": 0.004},
    "focus_tilt_decentre": {"image.focus": -0.005, "image.tilt_x": 0.12, "e2.decentre_y": -0.004},
    # a larger element error (3x focus_decentre's decentre) and a small sensor tilt: restoration's
    # second camera (calibration_tolerance_draws.py --larger)
    "larger_decentre": {"image.focus": 0.006, "e3.decentre_x": 0.012, "image.tilt_y": 0.05},
}
#: elements whose decentres are fitted by default (lensim calibrate --elements; --elements here)
ELEMENTS_FITTED = 1
#: most transfer refreshes (lensim calibrate --refresh-rounds)
REFRESH_ROUNDS = 4
HELD_OUT_TOLERANCES = {
    "elements": {"all": {"decentre_mm": 0.004, "tilt_deg": 0.05, "spacing_mm": 0.002}},
    "image": {"focus_mm": 0.006, "tilt_deg": 0.1},
}
#: cameras drawn from HELD_OUT_TOLERANCES: name -> seed (draw 0). fresh_draw was first run
#: after the v5 method (three elements) was chosen on held_out, as a check it was not tuned on
DRAWN_CAMERAS = {"held_out": 2024, "fresh_draw": 2025}


def _srgb(linear: np.ndarray) -> np.ndarray:
    a = np.clip(linear, 0.0, 1.0)
    return np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.maximum(a, 0.0031308) ** (1 / 2.4) - 0.055)


def _homography(frame_mm: tuple[float, float], fill: float = 0.97) -> np.ndarray:
    """The chart's footprint at `fill` of the photo's width, seen with perspective."""
    s = COLS / frame_mm[0] * fill
    persp = np.array([[1.0, 0.02, 0.0], [-0.015, 1.0, 0.0], [0.06 / frame_mm[0], -0.04 / frame_mm[0], 1.0]])
    return np.array([[s, 0, (COLS - 1) / 2], [0, s, (ROWS - 1) / 2], [0, 0, 1.0]]) @ persp


class World:
    """The sensor, mapping, nominal lens at the chart distance, chart and bank settings."""

    def __init__(self, cache: Path, candidates: int = 1, elements: int = ELEMENTS_FITTED, moves: int = 0) -> None:
        self.candidates = candidates
        self.elements = elements
        self.moves = moves
        self.rounds = REFRESH_ROUNDS
        self.sensor = load_sensor(SENSOR)
        self.mapping = map_to_sensor(ROWS, COLS, self.sensor)
        self.base = load_lens(LENS, warn=False)
        self.lens = lens_at(self.base, ShootingSettings(object_m=DISTANCE_M, focus_m=DISTANCE_M))
        mag = abs(paraxial_data(self.lens).magnification)
        size = self.sensor.sensor_size_mm
        self.layout = design_chart((size[0] / mag, size[1] / mag), 1200.0)
        self.h = _homography(self.layout.frame_mm)
        self.settings = BankSettings(fields=7, wavelengths_nm=WAVELENGTHS_NM, pupil_samples=64, cache_dir=cache)
        self.spectrum = luminance_spectrum(self.sensor, WAVELENGTHS_NM)
        self.azimuths = quadrant_azimuths(self.mapping)
        self.half_diagonal = math.hypot(self.mapping.x0_mm, self.mapping.y0_mm)

    def bank(self, lens):
        return get_bank(lens, self.mapping.pitch_um, self.settings, response=self.sensor.spectral_response)

    def banks(self, lens) -> dict:
        """One bank per diagonal (the lens turned to its azimuth); one for a symmetric lens."""
        return posed_banks(lens, self.mapping, self.bank)


def photograph(world: World, lens, seed: int) -> np.ndarray:
    """The chart photographed by a camera with this lens ((3, H, W) sRGB)."""
    lin = render_view(world.layout, world.h, (0, 0, ROWS, COLS), levels=(np.full(3, 0.04), np.full(3, 0.8)))
    scene = torch.from_numpy(_srgb(lin)).float()
    shots = {}
    for k, bank in world.banks(lens).items():
        img, _ = simulate(scene, bank, world.sensor, torch.Generator().manual_seed(seed), mapping=world.mapping,
                          bits=16, kelvin=5000.0)  # fmt: skip
        shots[k] = img.double().numpy()
    return compose_quadrants(shots, world.mapping)


def ratios(world: World, photo: np.ndarray, lens, det) -> list[dict]:
    """MTF-area ratio simulation/photo per zone, the simulation through `lens`."""
    sims = {}
    for k, bank in world.banks(lens).items():
        sims[k], _ = simulate_chart(photo, world.layout, det, bank, world.sensor, world.mapping,
                                    generator=torch.Generator().manual_seed(5), noise=True)  # fmt: skip
    cmp = compare_images(photo, compose_quadrants(sims, world.mapping), world.layout, det, world.mapping.pitch_um)
    return [{"zone": z.zone, "edges": z.edges, "ratio": z.mtf_area_ratio} for z in cmp.zones]


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


#: the PSF windows (um across) the NCC is taken on: 16 um (the earlier rows; it holds 92 %
#: of a field's spot, compute_psf warns) and 40 um (the whole spot)
NCC_WINDOWS_UM = {"": 16.0, " 40um": 40.0}


def _psf(lens, r: float, az: float, window_um: float) -> np.ndarray:
    """The lens's Huygens PSF (550 nm, 0.25 um samples, window_um across) at radius r mm
    on the diagonal at azimuth az deg."""
    turned = lens_at_azimuth(lens, az).with_changes(field_type="paraxial_image_height", fields=[r or 1e-9])
    grid = round(window_um / 0.25)
    return compute_psf(turned, 1.0, 0.55, pupil_samples=64, grid=grid, spacing_um=0.25, aiming="real").data


def psf_nccs(world: World, truth, others: dict) -> list[dict]:
    """NCC of each lens's Huygens PSF (_psf) against the truth's at centre, 0.7, corner:
    on the lower-right diagonal, and the worst of the four diagonals ("<name> worst"), in
    each window of NCC_WINDOWS_UM (its suffix on the keys)."""
    rows = []
    for label, frac in (("centre", 0.0), ("0.7", 0.7), ("corner", 0.95)):
        r = frac * world.half_diagonal
        row: dict = {"field": label}
        for az_key, az in world.azimuths.items() if r else [("lr", 0.0)]:
            for suffix, window in NCC_WINDOWS_UM.items():
                t = _psf(truth, r, az, window)
                for k, v in others.items():
                    ncc = _ncc(_psf(v, r, az, window), t)
                    if az_key == "lr":
                        row[k + suffix] = ncc
                    row[f"{k} worst{suffix}"] = min(row.get(f"{k} worst{suffix}", 1.0), ncc)
        rows.append(row)
    return rows


def run_camera(world: World, name: str, truth, out: Path) -> dict:
    path = out / f"{name}.json"
    if path.exists():
        return json.loads(path.read_text())
    photo = photograph(world, truth, seed=11)
    det = detect_chart(photo, world.layout, name)
    nominal_bank = world.bank(world.lens)
    t0 = time.perf_counter()
    data = chart_data(photo, world.layout, world.lens, nominal_bank, world.sensor, world.mapping, world.spectrum, name)
    data_s = time.perf_counter() - t0
    log(f"{name}: chart data {data_s:.0f} s, {len(data.edges)} edges")
    first = _first_fit(world, name, data, out)
    seconds = data_s + first.seconds
    sim = chart_simulator(photo, world.layout, det, data, world.sensor, world.mapping, world.bank)
    state = out / f"{name}.rounds.json"
    done = json.loads(state.read_text()) if state.exists() else []

    def checkpoint(rounds: list[dict]) -> None:
        state.write_text(json.dumps(rounds, indent=1))
        r = rounds[-1]
        rms = f"rms {r['rms_at_start']:.4f} -> {r['rms_after']:.4f}, moved {r['moved_sigma']:.1f} sigma"
        cost = f"{r['simulate_s']:.0f}+{r['fit_s']:.0f} s"
        bound = f"; at bound: {r.get('at_bound')}" if r.get("at_bound") else ""
        log(f"{name}: round {r['round']} ({r['start_from']}): {_short(r['values'])} {rms}; {cost}{bound}")

    obs = observations([data], world.spectrum)
    options = {"candidates": world.candidates, "moves": world.moves}
    refined = refine(world.lens, obs, [sim], first, world.rounds, name, done=done, on_round=checkpoint, **options)
    rounds_s = sum(r["simulate_s"] + r["fit_s"] for r in refined.rounds)
    log(f"{name}: refined ({'converged' if refined.converged else 'not converged'}); ratios and PSFs")
    result = {
        "camera": name,
        "truth": truth.as_built["parameters"],
        "fitted": refined.values,
        "sigma": refined.sigma,
        "first_fit": first.values,
        "first_fit_sigma": first.sigma,
        "refresh_rounds": refined.rounds,
        "refresh_converged": refined.converged,
        "sensitivity_top": first.sensitivity[:8],
        "rms_residual": [first.rms_before, first.rms_after, refined.rms_after],
        "edges": len(data.edges),
        "calibration_seconds": seconds + rounds_s,
        "first_fit_seconds": seconds,
        "evaluations": first.evaluations + sum(r["evaluations"] for r in refined.rounds),
        "traces": first.traces + sum(r["traces"] for r in refined.rounds),
        "degenerate": first.degenerate,
        "starts": first.lens.as_built.get("starts", []),
        "ranking": first.lens.as_built.get("ranking"),
        "elements_fitted": world.elements,
        "moves_after_refresh": world.moves,
        "candidates": world.candidates,
        "before": ratios(world, photo, world.lens, det),
        "after": ratios(world, photo, refined.lens, det),
        "at_truth": ratios(world, photo, truth, det),
        **{k: refined.lens.as_built.get(k) for k in ("bounds", "priors", "at_bound", "held_at_nominal")},
        "psf_ncc": psf_nccs(world, truth, {"nominal": world.lens, "first fit": first.lens, "calibrated": refined.lens}),
    }
    path.write_text(json.dumps(result, indent=1))
    return result


def ncc_again(world: World, truth, path: Path) -> dict:
    """A camera's result with its PSF NCCs (psf_nccs) recomputed from its recorded first
    fit and calibrated values, written back to path."""
    result = json.loads(path.read_text())
    lenses = {"nominal": world.lens, "first fit": perturbed_lens(world.lens, result["first_fit"])}
    lenses["calibrated"] = perturbed_lens(world.lens, result["fitted"])
    result["psf_ncc"] = psf_nccs(world, truth, lenses)
    path.write_text(json.dumps(result, indent=1))
    return result


def truth_again(world: World, truth, path: Path) -> dict:
    """A camera's result with the zone ratios of the true lens on its photo ("at_truth":
    what the ratio reads with no calibration error, its noise floor) added."""
    result = json.loads(path.read_text())
    photo = photograph(world, truth, seed=11)
    result["at_truth"] = ratios(world, photo, truth, detect_chart(photo, world.layout, result["camera"]))
    path.write_text(json.dumps(result, indent=1))
    return result


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def _short(values: dict) -> str:
    return ", ".join(f"{k} {v:+.5f}" for k, v in values.items())


def _first_fit(world: World, name: str, data, out: Path) -> Fit:
    """The fit with the nominal transfer (lensim calibrate's first step), kept in
    OUT/<camera>.first.json so that a killed run resumes after it."""
    path = out / f"{name}.first.json"
    if path.exists():
        d = json.loads(path.read_text())
        lens = perturbed_lens(world.lens, d["values"], d["as_built"])
        return Fit(d["values"], d["sigma"], d["sensitivity"], d["rms_before"], d["rms_after"], lens,
                   d["evaluations"], d["seconds"], d["correlation"], d["degenerate"], d["traces"])  # fmt: skip
    f = calibrate_charts(
        world.lens, [data], world.spectrum, elements_fitted=world.elements, where=name, candidates=world.candidates
    )
    record = {k: v for k, v in f.lens.as_built.items() if k != "parameters"}
    keep = {k: getattr(f, k) for k in ("values", "sigma", "sensitivity", "rms_before", "rms_after", "evaluations",
                                      "seconds", "correlation", "degenerate", "traces")}  # fmt: skip
    path.write_text(json.dumps(keep | {"as_built": record}, indent=1))
    log(f"{name}: first fit {_short(f.values)}, rms {f.rms_after:.4f}, {f.seconds:.0f} s")
    rank = record.get("ranking") or {}
    for key in ("linear", "prefits"):
        moves = ", ".join(f"{r['move']} {r['rms']:.4f}" for r in rank.get(key, []))
        log(f"{name}: ranking ({rank.get('by')}), {key} residual RMS: {moves}")
    return f


def _rounds_table(results: list[dict]) -> list[str]:
    """The transfer refreshes: per round where it started, the fitted values, RMS and cost."""
    lines = [
        "",
        "| camera | round | start | fitted | RMS at start -> after | moved (sigma) | simulate + fit s | evaluations |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        for x in r.get("refresh_rounds", []):
            fitted = ", ".join(f"{k} {v:+.5f}" for k, v in x["values"].items())
            cost = f"{x['moved_sigma']:.1f} | {x['simulate_s']:.0f} + {x['fit_s']:.0f} | {x['evaluations']}"
            rms = f"{x['rms_at_start']:.4f} -> {x['rms_after']:.4f}"
            lines.append(f"| {r['camera']} | {x['round']} | {x['start_from']} | {fitted} | {rms} | {cost} |")
    return lines


def table(results: list[dict]) -> str:
    lines = [
        "| camera | zone | ratio before | ratio after | true lens (the ratio's floor) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in results:
        after = {z["zone"]: z["ratio"] for z in r["after"]}
        truth = {z["zone"]: z["ratio"] for z in r.get("at_truth", [])}
        for z in r["before"]:
            row = f"{z['ratio']:.3f} | {after.get(z['zone'], math.nan):.3f} | {truth.get(z['zone'], math.nan):.3f}"
            lines.append(f"| {r['camera']} | {z['zone']:g} | {row} |")
    lines += [
        "",
        "| camera | field | PSF NCC nominal | first fit | calibrated | worst diagonal: nominal | first | calibrated |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    kinds = ("nominal", "first fit", "calibrated")
    for suffix in NCC_WINDOWS_UM:
        for r in results:
            for row in r["psf_ncc"]:
                if f"calibrated{suffix}" not in row:
                    continue
                lr = " | ".join(f"{row.get(k + suffix, math.nan):.4f}" for k in kinds)
                worst = " | ".join(f"{row.get(f'{k} worst{suffix}', math.nan):.4f}" for k in kinds)
                lines.append(f"| {r['camera']} | {row['field']}{suffix} | {lr} | {worst} |")
    lines += [
        "",
        "| camera | parameter | truth | fitted +- 1 sigma | bound (+-) | prior sigma |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        names = sorted(set(r["truth"]) | set(r["fitted"]))
        bounds, priors, at = r.get("bounds") or {}, r.get("priors") or {}, set(r.get("at_bound") or [])
        for n in names:
            fit = f"{r['fitted'][n]:+.5f} +- {r['sigma'][n]:.5f}" if n in r["fitted"] else "(not fitted)"
            fit += " (at its bound)" if n in at else ""
            prior = "none" if priors.get(n) is None else f"{priors[n]:.5f}"
            extra = f"{bounds[n]:.5f} | {prior}" if n in bounds else " | "
            lines.append(f"| {r['camera']} | {n} | {r['truth'].get(n, 0.0):+.5f} | {fit} | {extra} |")
        for h in r.get("held_at_nominal") or []:
            lines.append(f"| {r['camera']} | {h['parameter']} | | held at nominal: {h['reason']} | | |")
    lines += [
        "",
        "| camera | edges | RMS residual before -> after | evaluations | traces | calibration s |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        rms = " -> ".join(f"{v:.4f}" for v in r["rms_residual"])
        runs = f"{r['evaluations']} | {r.get('traces', r['evaluations'])} | {r['calibration_seconds']:.0f}"
        lines.append(f"| {r['camera']} | {r['edges']} | {rms} | {runs} |")
    lines += _rounds_table(results)
    lines += [
        "",
        "| camera | degenerate pairs (correlation beyond 0.9) | starts: focus mm -> RMS |",
        "| --- | --- | --- |",
    ]
    for r in results:
        pairs = ", ".join(f"{p['pair'][0]} ~ {p['pair'][1]} ({p['correlation']:+.2f})" for p in r.get("degenerate", []))
        starts = ", ".join(f"{s['focus']:+.4f} -> {s['rms']:.4f}" for s in r.get("starts", []))
        lines.append(f"| {r['camera']} | {pairs or 'none'} | {starts or '-'} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calibration"))
    ap.add_argument("--cameras", default="focus_decentre,focus_tilt_decentre,held_out")
    ap.add_argument("--cache", type=Path, default=Path("benchmarks/results/calibration-cache"), help="bank cache")
    ap.add_argument("--rounds", type=int, default=REFRESH_ROUNDS, help="most transfer refreshes (--refresh-rounds)")
    ap.add_argument("--candidates", type=int, default=1, help="elements fitted in full for the choice (--candidates)")
    ap.add_argument("--elements", type=int, default=ELEMENTS_FITTED, help="elements fitted (--elements)")
    ap.add_argument("--refresh-moves", type=int, default=0, help="element moves added in round 1 (refine's moves)")
    ap.add_argument("--table-only", action="store_true", help="only gather OUT/*.json into OUT/table.md")
    ap.add_argument("--truth-again", action="store_true", help="add the true lens's zone ratios to OUT/<camera>.json")
    ap.add_argument(
        "--ncc-again", action="store_true", help="recompute the PSF NCCs of OUT/<camera>.json (all windows)"
    )
    args = ap.parse_args()
    if args.table_only:
        found = [json.loads((args.out / f"{n}.json").read_text()) for n in args.cameras.split(",")]
        (args.out / "table.md").write_text(table([r for r in found]))
        return
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    world = World(args.cache, args.candidates, args.elements, args.refresh_moves)
    world.rounds = args.rounds
    results = []
    for name in args.cameras.split(","):
        if name in DRAWN_CAMERAS:
            tol = tolerances_from_dict(HELD_OUT_TOLERANCES, world.lens, "held-out tolerances")
            truth = drawn_lens(world.lens, tol, DRAWN_CAMERAS[name], 0)
        else:
            truth = perturbed_lens(world.lens, CAMERAS[name])
        if args.ncc_again or args.truth_again:
            again = ncc_again if args.ncc_again else truth_again
            results.append(again(world, truth, args.out / f"{name}.json"))
            continue
        results.append(run_camera(world, name, truth, args.out))
        (args.out / "table.md").write_text(table(results))
        log(f"{name} done")


if __name__ == "__main__":
    main()
