"""From photographed charts to an as-built lens (lensim.calibrate.fit on chart data).

For each photo: the chart is found (lensim.calibrate.chart_detect), simulated through the
nominal lens at the photo's pose without noise (lensim.calibrate.compare.simulate_chart)
and both are measured at the same edge regions (compare_images). Each edge becomes an
observation: its square's centre on the sensor (mm, from the mapping: x along columns, y
along rows, the bank's orientation; the four sides of a square share one trace), the
direction across it (0 deg for a left/right side, 90 for a top/bottom one), the photo's
SFR on FREQ_CY_PX (converted to lp/mm with the pitch), and the system transfer: the
simulation's SFR over the transfer of the nominal lens's pixel kernel there
(lensim.calibrate.model.edge_mtf of an edge with the mapping's pitch: the optical MTF
with the pixel and its aliases), which carries the mosaic and the develop chain.
Frequencies where that transfer is below MIN_OPTICAL_MTF are dropped (the ratio is noise
there).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lensim.calibrate.fit import Fit, Observations, Progress, fit
from lensim.calibrate.model import Edge, edge_mtf
from lensim.optics.lens import Lens

if TYPE_CHECKING:
    from lensim.calibrate.chart import ChartLayout
    from lensim.calibrate.chart_measure import EdgeRegion
    from lensim.calibrate.compare import ChartComparison
    from lensim.psf.bank import PSFBank
    from lensim.render.mapping import SensorMapping
    from lensim.sensor.profile import SensorProfile

#: the frequencies (cycles/pixel) of the SFRs fitted
FREQ_CY_PX = np.array([0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28, 0.32, 0.36, 0.4])
#: below this nominal optical MTF a frequency is not used
MIN_OPTICAL_MTF = 0.08
#: Rec. 709 luminance weights of R, G, B (the SFR is measured on luminance)
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass
class ChartData:
    """One photo's observations: edges, photo SFRs and system transfers (each (F_i,)), the
    nominal comparison (per-zone MTF-area ratios before calibration), and where each edge
    was measured (its region, and the pitch in um: lensim.calibrate.refresh measures a
    simulation there again)."""

    edges: list[Edge]
    measured: list[np.ndarray]
    system: list[np.ndarray]
    comparison: ChartComparison
    regions: list[EdgeRegion] = field(default_factory=list)
    pitch_um: float = 0.0


def luminance_spectrum(sensor: SensorProfile, wavelengths_nm: Sequence[float]) -> tuple[list[float], list[float]]:
    """(wavelengths um, weights): the sensor's channels' responses summed with LUMA."""
    from lensim.sensor.spectral import spectral_response

    w = spectral_response(list(wavelengths_nm), sensor.spectral_response).weights
    lum = np.asarray(LUMA) @ np.asarray(w)[:3]
    return [v / 1000.0 for v in wavelengths_nm], [float(v) for v in lum]


def chart_data(
    photo: np.ndarray,
    layout: ChartLayout,
    lens: Lens,
    bank: PSFBank,
    sensor: SensorProfile,
    mapping: SensorMapping,
    spectrum: tuple[list[float], list[float]],
    source: str,
    samples: int = 32,
) -> ChartData:
    """The observations of one photo (module docstring). photo: (3, H, W) sRGB in [0, 1];
    lens: the nominal lens at the photo's settings and distance; bank: its bank at the
    mapping's pitch; spectrum: (wavelengths um, weights) of the luminance."""
    from lensim.calibrate.chart_detect import check_coverage, detect_chart
    from lensim.calibrate.compare import compare_images, simulate_chart

    det = detect_chart(photo, layout, source)
    check_coverage(layout, det, source)
    sim, _ = simulate_chart(photo, layout, det, bank, sensor, mapping, noise=False)
    cmp = compare_images(photo, sim, layout, det, mapping.pitch_um)
    p_mm = mapping.pitch_um * 1e-3
    centres: dict[int, list[tuple[float, float]]] = {}
    for p in cmp.photo.edges:
        centres.setdefault(p.region.square, []).append(p.region.centre_px)
    edges, measured, system, regions = [], [], [], []
    for p, s in zip(cmp.photo.edges, cmp.sim.edges, strict=True):
        if p.sfr is None or s.sfr is None:
            continue
        col, row = np.mean(centres[p.region.square], axis=0)
        angle = 90.0 if p.region.side in ("top", "bottom") else 0.0
        x, y = mapping.x0_mm + col * p_mm, mapping.y0_mm + row * p_mm
        full = Edge(float(x), float(y), angle, tuple((FREQ_CY_PX / p_mm).tolist()), mapping.pitch_um)
        optical = edge_mtf(lens, full, *spectrum, samples=samples)
        keep = optical >= MIN_OPTICAL_MTF
        if keep.sum() < 2:
            continue
        photo_sfr = np.interp(FREQ_CY_PX, p.sfr.freq_cy_px, p.sfr.mtf)[keep]
        sim_sfr = np.interp(FREQ_CY_PX, s.sfr.freq_cy_px, s.sfr.mtf)[keep]
        kept = tuple(np.asarray(full.frequencies_lp_mm)[keep].tolist())
        edges.append(Edge(full.x_mm, full.y_mm, angle, kept, mapping.pitch_um))
        measured.append(photo_sfr)
        system.append(sim_sfr / optical[keep])
        regions.append(p.region)
    return ChartData(edges, measured, system, cmp, regions, mapping.pitch_um)


def calibrate_charts(
    lens: Lens,
    data: Sequence[ChartData],
    spectrum: tuple[list[float], list[float]],
    names: Sequence[str] | None = None,
    elements_fitted: int = 1,
    samples: int = 32,
    where: str = "chart",
    progress: Progress | None = None,
    candidates: int = 1,
) -> Fit:
    """Fit the lens (at the photos' settings) to every photo's observations together
    (candidates: elements fitted in full for the choice, lensim.calibrate.fit.fit)."""
    obs = observations(data, spectrum, samples)
    return fit(lens, obs, names, elements_fitted, where, progress, candidates=candidates)


def observations(
    data: Sequence[ChartData], spectrum: tuple[list[float], list[float]], samples: int = 32
) -> Observations:
    """Every photo's edges, SFRs and transfers in one set (photos in order); spectrum:
    (wavelengths um, weights); samples: pupil samples across of the model."""
    return Observations(
        edges=[e for d in data for e in d.edges],
        measured=[m for d in data for m in d.measured],
        system=[s for d in data for s in d.system],
        wavelengths_um=list(spectrum[0]),
        weights=list(spectrum[1]),
        samples=samples,
    )
