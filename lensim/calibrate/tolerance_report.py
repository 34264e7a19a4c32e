"""Monte Carlo tolerance analysis: the spread of RMS spot and MTF over seeded draws, and
the sensitivity of the corner MTF to each toleranced parameter.

Fields lie along +y (the lens's field unit). A perturbed lens is not rotationally
symmetric, but the draws are (each parameter's x and y parts are drawn alike), so the
+y fields of N draws sample the same distribution as any azimuth would.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from lensim.calibrate.tolerances import Tolerances, drawn_lens, perturbed_lens
from lensim.optics.lens import Lens
from lensim.optics.pose import Pose, mirror_pose, rotate_pose
from lensim.optics.spot import rms_spot_radius
from lensim.psf.mtf import field_otf

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Probe:
    """What is measured per lens: fields (lens units, along +y), wavelengths (um) with
    weights, the MTF frequency (lp/mm), pupil samples across and the ray aiming."""

    fields: Sequence[float]
    wavelengths_um: Sequence[float]
    weights: Sequence[float]
    frequency_lp_mm: float
    samples: int = 64
    aiming: str = "real"


def _with_poses(lens: Lens, transform: Callable[[Pose], Pose]) -> Lens:
    """The lens with transform applied to every surface pose and to the sensor tilt (as
    the tilt part of a pose)."""
    import dataclasses

    surfaces = [dataclasses.replace(s, pose=transform(s.pose)) for s in lens.surfaces]
    tilt = transform((0.0, 0.0, *lens.image_tilt))[2:]
    return lens.with_changes(surfaces=surfaces, image_tilt=(tilt[0], tilt[1]))


def lens_at_azimuth(lens: Lens, azimuth_deg: float) -> Lens:
    """The lens turned so that its field point at azimuth_deg (counter-clockwise from +y,
    seen looking along +z) lies along +y: every surface pose and the sensor tilt rotated
    (lensim.optics.pose.rotate_pose). Tangential (y) results of the returned lens are the
    radial ones of the original at that azimuth, sagittal (x) the azimuthal ones."""
    if not lens.has_poses or azimuth_deg == 0.0:
        return lens
    return _with_poses(lens, lambda pose: rotate_pose(pose, azimuth_deg))


def mirrored_lens(lens: Lens) -> Lens:
    """The lens mirrored in the y-z plane (x -> -x): every surface pose and the sensor tilt
    mirrored (lensim.optics.pose.mirror_pose). Its PSF at a +y field is the original's
    flipped left-right: a bank's kernel mirrored about its +y direction (what
    lensim.psf.bank.azimuth does for half the azimuths, exact for a symmetric lens) is
    the original's when the bank holds this lens."""
    if not lens.has_poses:
        return lens
    return _with_poses(lens, mirror_pose)


def measure(lens: Lens, probe: Probe) -> dict[str, list[float]]:
    """Per field: rms_spot_um (polychromatic, centroid reference, the lens's wavelengths),
    mtf_sagittal and mtf_tangential at the probe's frequency (polychromatic, probe weights)."""
    spot, sag, tan = [], [], []
    for f in probe.fields:
        otf = field_otf(lens, f, probe.wavelengths_um, probe.weights, probe.samples, probe.aiming)  # type: ignore[arg-type]
        s, t = otf.mtf([probe.frequency_lp_mm])
        sag.append(float(s[0]))
        tan.append(float(t[0]))
        spot.append(1e3 * rms_spot_radius(lens, f))
    return {"rms_spot_um": spot, "mtf_sagittal": sag, "mtf_tangential": tan}


def corner_mtf(m: dict[str, list[float]]) -> float:
    """The mean of the sagittal and tangential MTF at the last (largest) field."""
    return 0.5 * (m["mtf_sagittal"][-1] + m["mtf_tangential"][-1])


def _stats(values: np.ndarray) -> dict[str, list[float]]:
    """(draws, fields) -> per field mean, std, min, p10, p50, p90, max."""
    q = np.percentile(values, [10, 50, 90], axis=0)
    return {
        "mean": values.mean(0).tolist(),
        "std": values.std(0).tolist(),
        "min": values.min(0).tolist(),
        "p10": q[0].tolist(),
        "p50": q[1].tolist(),
        "p90": q[2].tolist(),
        "max": values.max(0).tolist(),
    }


def sensitivity(
    lens: Lens, tol: Tolerances, probe: Probe, nominal: float, progress: Progress | None = None
) -> list[dict]:
    """Each toleranced parameter alone at -range and +range: the corner MTF change against
    the nominal corner MTF `nominal`; sorted by the larger loss (worst first)."""
    params = tol.parameters()
    rows = []
    for k, (name, r) in enumerate(sorted(params.items())):
        deltas = [corner_mtf(measure(perturbed_lens(lens, {name: s * r}), probe)) - nominal for s in (-1.0, 1.0)]
        rows.append(
            {"parameter": name, "range": r, "delta_minus": deltas[0], "delta_plus": deltas[1], "worst": min(deltas)}
        )
        if progress:
            progress(k + 1, len(params))
    return sorted(rows, key=lambda row: row["worst"])


def tolerance_report(
    lens: Lens,
    tol: Tolerances,
    probe: Probe,
    draws: int,
    seed: int,
    progress: Progress | None = None,
    with_sensitivity: bool = True,
) -> dict:
    """Nominal metrics, the metrics of draws 0..draws-1 of `seed` with their per-field
    statistics, and (with_sensitivity) the one-at-a-time sensitivity table. Units: um for
    spots, MTF as a fraction at probe.frequency_lp_mm."""
    nominal = measure(lens, probe)
    total = draws + (2 * len(tol.parameters()) if with_sensitivity else 0)
    per_draw = []
    for k in range(draws):
        d = drawn_lens(lens, tol, seed, k)
        per_draw.append({"draw": k, "parameters": d.as_built["parameters"], **measure(d, probe)})
        if progress:
            progress(k + 1, max(total, 1))
    keys = ("rms_spot_um", "mtf_sagittal", "mtf_tangential")
    spread = {key: _stats(np.array([row[key] for row in per_draw])) for key in keys} if per_draw else {}
    report: dict = {
        "lens": lens.name,
        "tolerances": tol.source,
        "distribution": tol.distribution,
        "seed": seed,
        "draws": draws,
        "fields": list(probe.fields),
        "field_type": lens.field_type,
        "frequency_lp_mm": probe.frequency_lp_mm,
        "nominal": nominal,
        "spread": spread,
        "per_draw": per_draw,
    }
    if with_sensitivity:
        base = corner_mtf(nominal)

        def sub(i: int, n: int) -> None:
            if progress:
                progress(draws + 2 * i, max(total, 1))

        report["sensitivity"] = sensitivity(lens, tol, probe, base, sub)
    return report
