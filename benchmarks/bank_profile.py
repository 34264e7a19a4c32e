"""Where a PSF bank's time goes: the demo's bank profiled stage by stage.

Run by hand from the repository root (about a minute on 2 cores):

    .venv/bin/python benchmarks/bank_profile.py [--fields 12] [--pupil-samples 128]

The demo's bank (the built-in Cooke triplet on the APS-C sensor, 400-700 nm every 25 nm,
35-pixel kernels) is computed in this process with one torch thread (as `psf bank
--workers 1` does) under cProfile. Each stage's share is the cumulative time of the
function that does it, over the whole bank's time:
* pupil tracing: `pupil_field` (ray aiming, the trace, the reference sphere), of which ray
  aiming (`generate_rays`);
* relative illumination (`relative_illumination_spectrum` or, in older versions,
  `relative_illumination`);
* the Huygens superposition (`huygens_psf`) and the sampling check (`check_sampling`);
* pixel integration (`integrate_pixels`); the Strehl ratio (`strehl_ratio`);
* the spectral response; the kernels turned to other azimuths (`azimuth_kernels`);
* the rest (set-up, the manifest).

Times are CPU seconds of this process (cProfile with time.process_time), which other jobs
on a shared machine disturb less than wall-clock time.

Prints a markdown table.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time

STAGES = [
    ("pupil tracing (pupil_field)", ("pupil_field",)),
    ("  of which ray aiming (generate_rays in _trace_grid)", ("generate_rays",)),
    ("relative illumination", ("relative_illumination_spectrum", "relative_illumination")),
    ("Huygens superposition (huygens_psf)", ("huygens_psf",)),
    ("sampling check (check_sampling)", ("check_sampling",)),
    ("pixel integration (integrate_pixels)", ("integrate_pixels",)),
    ("Strehl ratio (strehl_ratio)", ("strehl_ratio",)),
    ("spectral response (spectral_response)", ("spectral_response",)),
    ("azimuth kernels (azimuth_kernels)", ("azimuth_kernels",)),
]
TOP_LEVEL = {"pupil_field", "relative_illumination_spectrum", "relative_illumination", "huygens_psf"}


def cumulative(stats: pstats.Stats, names: tuple[str, ...], caller: str | None = None) -> float:
    """The cumulative time of the function of one of these names (the one that took
    longest); with caller, only its calls from a function of that name."""
    best = 0.0
    for (_, _, name), (_, _, _, total, callers) in stats.stats.items():  # type: ignore[attr-defined]
        if name in names:
            if caller is not None:
                total = sum(row[3] for (_, _, who), row in callers.items() if who == caller)
            best = max(best, total)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fields", type=int, default=12)
    parser.add_argument("--pupil-samples", type=int, default=128)
    args = parser.parse_args()

    # isort: off
    import lensim  # noqa: F401  (before torch: lensim's OpenMP setting)
    import torch

    # isort: on

    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import load_sensor

    torch.set_num_threads(1)
    lens = load_lens("cooke_triplet")
    sensor = load_sensor("apsc_mirrorless")
    fields = [((i / (args.fields - 1)) ** 0.5) for i in range(args.fields)]
    profiler = cProfile.Profile(time.process_time)
    start = time.process_time()
    profiler.enable()
    settings = BankSettings(
        fields=tuple(fields),
        wavelengths_nm=tuple(range(400, 701, 25)),
        pupil_samples=args.pupil_samples,
        kernel_pixels=35,
    )
    get_bank(lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, memory_only=True)
    profiler.disable()
    total = time.process_time() - start
    stats = pstats.Stats(profiler)
    print(
        f"bank: {args.fields} fields x 13 wavelengths, {args.pupil_samples} pupil samples, one thread: "
        f"{total:.1f} s CPU\n"
    )
    print("| stage | seconds | share |")
    print("| --- | ---: | ---: |")
    accounted = 0.0
    for label, names in STAGES:
        t = cumulative(stats, names, "_trace_grid" if names == ("generate_rays",) else None)
        if names[0] in TOP_LEVEL:
            accounted += t
        print(f"| {label} | {t:.1f} | {100 * t / total:.0f} % |")
    rest = total - accounted - sum(cumulative(stats, n) for _, n in STAGES[4:])
    # (the sampling check, pixel integration, Strehl ratio and spectral response are outside the three big stages)
    print(f"| the rest | {rest:.1f} | {100 * rest / total:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
