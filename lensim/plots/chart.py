"""The chart check's figure (lensim.calibrate.compare): the photo's and the simulation's
mean slanted-edge SFR in each field zone, with the MTF-area ratio and the checker PSNR."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from matplotlib.figure import Figure

from lensim.plots.figure import new_figure

if TYPE_CHECKING:
    from lensim.calibrate.compare import ChartComparison


def chart_comparison_figure(comparison: ChartComparison, title: str = "") -> Figure:
    """One panel per field zone: SFR of the photo (solid) and of lensim's simulation
    (dashed) against cycles/pixel up to Nyquist, titled with the zone's mean field, the
    MTF-area ratio (simulation / photo) and the checker-crop PSNR."""
    from lensim.calibrate.chart_measure import ZONE_FREQ

    zones = comparison.zones
    n = max(1, len(zones))
    fig = new_figure((3.0 * n, 3.4), layout="constrained")
    axes = fig.subplots(1, n, sharey=True, squeeze=False)[0]
    for ax, z in zip(axes, zones, strict=False):
        ax.plot(ZONE_FREQ, z.photo_mtf, color="black", label="photo")
        ax.plot(ZONE_FREQ, z.sim_mtf, color="tab:red", ls="--", label="lensim")
        psnr = "" if math.isnan(z.psnr_db) else f", {z.psnr_db:.1f} dB"
        ax.set_title(f"field {z.mean_field:.2f}: ratio {z.mtf_area_ratio:.3f}{psnr}", fontsize=9)
        ax.set_xlabel("cycles/pixel")
        ax.set_xlim(0.0, 0.5)
        ax.set_ylim(0.0, 1.05)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("SFR (MTF)")
    axes[0].legend(loc="lower left", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig
