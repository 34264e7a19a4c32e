"""Lens-level field plots from lensim.optics.field_analysis.field_report: distortion (%),
lateral colour per sensor channel (um) and relative illumination, each against the field.

Matplotlib figures on their own Agg canvas (lensim.plots.figure); given a path they are
saved atomically in the format its extension names.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from lensim.plots.figure import new_figure, save_figure

KINDS = ("distortion", "lateral-colour", "illumination")
CHANNEL_COLORS = {"r": "tab:red", "g": "tab:green", "b": "tab:blue"}


def _axes(report: dict, title: str, ylabel: str):
    fig = new_figure((6.4, 4.2), layout="constrained")
    ax = fig.add_subplot()
    unit = report["field_unit"]
    ax.set_xlabel(f"field ({unit})")
    ax.set_ylabel(ylabel)
    ax.set_title(f"{report['name'] or Path(report['source']).stem}: {title}")
    ax.grid(True, alpha=0.3)
    return fig, ax, [r["field"] for r in report["fields"]]


def distortion_figure(report: dict) -> Figure:
    """Distortion (%) of the real chief ray against the paraxial one (primary wavelength)."""
    fig, ax, x = _axes(report, f"distortion at {report['primary_wavelength_nm']:g} nm", "distortion (%)")
    ax.plot(x, [r["distortion_percent"] for r in report["fields"]], color="black")
    ax.axhline(0.0, color="gray", lw=0.8)
    return fig


def lateral_colour_figure(report: dict) -> Figure:
    """Each channel's chief-ray height minus green's (um), weighted by the sensor's response."""
    fig, ax, x = _axes(report, "lateral colour (channel - green)", "lateral colour (\N{MICRO SIGN}m)")
    for ch in "rb":
        ax.plot(
            x,
            [r["lateral_colour_um"][ch] for r in report["fields"]],
            color=CHANNEL_COLORS[ch],
            label={"r": "red - green", "b": "blue - green"}[ch],
        )
    ax.axhline(0.0, color="gray", lw=0.8)
    ax.legend()
    return fig


def illumination_figure(report: dict) -> Figure:
    """Relative illumination (1 on axis), vignetting and cos^4-type fall-off included."""
    fig, ax, x = _axes(report, "relative illumination", "relative illumination")
    ax.plot(x, [r["relative_illumination"] for r in report["fields"]], color="black")
    ax.set_ylim(0.0, 1.05)
    return fig


def field_figure(report: dict, kind: str, path: str | Path | None = None) -> Figure:
    """The figure of one KINDS entry; saved to path when given."""
    fig = {
        "distortion": distortion_figure,
        "lateral-colour": lateral_colour_figure,
        "illumination": illumination_figure,
    }[kind](report)
    if path is not None:
        save_figure(fig, path)
    return fig
