"""Zero-shot restoration of the held-out library lenses with the universal model (issue 23).

For every held-out library lens (index.yaml's ``holdout: true``; nothing trains on them) it
takes the lens's first complete library bank (wide open, focused at infinity, on the 24 MP
sensor of its format, where done; lensim.data.library_banks),
simulates the 11 unseen test photos through it (lensim.assets.images.unseen_photos, centre
crops of ``--photo-size`` px at 3 sensor positions: centre, middle and edge zones, one crop
each), and scores per lens and per field zone (lensim.evaluate.harness):

* ``input``: the aberrated capture itself;
* ``wiener``: the Wiener oracle (the true bank and the true noise levels);
* ``universal``: the universal model (default: the shipped lensim/assets/models/universal),
  zero-shot: no training on the lens.

Resumable: the pairs of each lens are kept in OUT/<lens>/pairs (made once). Results in
OUT/result.json and OUT/result.md (a table per lens and zone).

    OMP_NUM_THREADS=1 nice -n 15 python benchmarks/universal_zero_shot.py --library LIBDIR -o OUT
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def unseen_folder(out: Path, size: int) -> Path:
    """The unseen test photos, centre-cropped to size x size, in out/unseen (written once)."""
    from lensim.assets.images import unseen_photos, write_centre_crops

    folder = out / "unseen"
    write_centre_crops(unseen_photos(), folder, size)
    return folder


def held_out_banks(library: Path, setting: int = 0) -> list:
    """(planned bank, bank folder, sensor file) of one complete bank of every held-out entry
    in the library folder: its complete bank number `setting` in plan order (0: wide open,
    infinity, 24 MP; 1: the same on the 10 MP sensor; 2, 3: two stops down; 4-7: the same
    focused near), or its last complete one when it has fewer."""
    from lensim.data import library_banks as lb

    banks: dict = {}
    for b, d, s in lb.library_banks(library, holdout=True):
        banks.setdefault(b.lens, []).append((b, d, s))
    return [mine[min(setting, len(mine) - 1)] for mine in banks.values()]


def score_lens(out: Path, photos: Path, bank_dir: Path, sensor_file: Path, model: str, size: int) -> dict:
    from lensim.data.pairs import make_dataset
    from lensim.evaluate import harness
    from lensim.psf.bank import PSFBank
    from lensim.restore.universal import model_path
    from lensim.sensor.profile import load_sensor

    pairs = out / "pairs"
    sensor = load_sensor(sensor_file)
    make_dataset(photos, pairs, PSFBank.load(bank_dir), str(sensor_file), sensor, crops=1, size=size, placements=3)
    methods = {
        "wiener": harness.builtin_method("wiener"),
        "universal": harness.checkpoint_method(model_path(model), tile=size, overlap=0),
    }
    return harness.evaluate(pairs, methods)["methods"]


def table(results: dict) -> str:
    lines = [
        "| lens | family | method | all PSNR | SSIM | centre | middle | edge |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for lens, r in results.items():
        for name, m in r["methods"].items():
            zones = " | ".join(f"{m['zones'][z]['psnr_db']:.2f}" for z in ("centre", "middle", "edge"))
            lines.append(f"| {lens} | {r['family']} | {name} | {m['psnr_db']:.2f} | {m['ssim']:.3f} | {zones} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, required=True, help="the library folder (lensim library banks -o)")
    ap.add_argument("--model", default="universal", help="universal (the shipped model) or a model file / run")
    ap.add_argument("--photo-size", type=int, default=384)
    ap.add_argument("--size", type=int, default=128, help="crop size (pixels)")
    ap.add_argument(
        "--setting", type=int, default=0, help="which bank of each lens, in plan order (0: wide open, infinity, 24 MP)"
    )
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    out = args.output
    photos = unseen_folder(out, args.photo_size)
    results = {}
    t0 = time.perf_counter()
    for planned, bank_dir, sensor_file in held_out_banks(args.library, args.setting):
        t = time.perf_counter()
        methods = score_lens(out / planned.lens, photos, bank_dir, sensor_file, args.model, args.size)
        results[planned.lens] = {
            "family": planned.family,
            "focus_m": planned.focus_m,
            "bank": planned.id,
            "pitch_um": planned.pitch_um,
            "fno": planned.fno,
            "seconds": time.perf_counter() - t,
            "methods": methods,
        }
        print(planned.lens, {k: round(v["psnr_db"], 2) for k, v in methods.items()}, flush=True)
    summary = {"model": args.model, "seconds": time.perf_counter() - t0, "lenses": results}
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    (out / "result.md").write_text(table(results))
    print(table(results))


if __name__ == "__main__":
    main()
