"""Figures of a tolerance analysis (lensim.calibrate.tolerance_report) and of a
calibration (lensim.calibrate.fit)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lensim.plots.figure import new_figure, save_figure


def tolerance_figure(report: dict, path: str | Path | None = None, top: int = 12) -> Figure:
    """Three panels: RMS spot (um) and corner-relevant MTF per field over the draws (box
    plots, nominal marked), and the `top` parameters whose one-at-a-time change lowers the
    corner MTF most."""
    fig = new_figure((13.0, 4.2), layout="constrained")
    axes = fig.subplots(1, 3)
    fields = report["fields"]
    labels = [f"{f:g}" for f in fields]
    draws = report["per_draw"]
    for ax, key, title in (
        (axes[0], "rms_spot_um", "RMS spot (um)"),
        (axes[1], "mtf_tangential", f"MTF tangential at {report['frequency_lp_mm']:g} lp/mm"),
    ):
        if draws:
            data = np.array([row[key] for row in draws])
            ax.boxplot([data[:, i] for i in range(len(fields))], tick_labels=labels)
        ax.plot(range(1, len(fields) + 1), report["nominal"][key], "r*", ms=10, label="nominal")
        ax.set_xlabel(f"field ({report['field_type']})")
        ax.set_title(title)
        ax.legend(loc="best")
    ax = axes[2]
    rows = report.get("sensitivity", [])[:top]
    if rows:
        ax.barh(range(len(rows)), [r["worst"] for r in rows], color="tab:orange")
        ax.set_yticks(range(len(rows)), [f"{r['parameter']} ±{r['range']:g}" for r in rows])
        ax.invert_yaxis()
    ax.set_xlabel("corner MTF change (worst sign)")
    ax.set_title("sensitivity")
    fig.suptitle(f"{report['lens']}: {report['draws']} draws, seed {report['seed']}")
    if path is not None:
        save_figure(fig, path)
    return fig
