"""Figures of the lens analyses, drawn from their JSON-ready reports
(lensim.psf.analysis_reports, lensim.optics.fans): MTF, wavefront, ray fans, field curves,
encircled and ensquared energy.

Matplotlib figures on their own Agg canvas (lensim.plots.figure); given a path they are
saved atomically in the format its extension names. Fields along +y; tangential lines
solid, sagittal dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lensim.plots.figure import new_figure, save_figure
from lensim.plots.lens import FIELD_COLORS, _wavelength_colors


def _title(report: dict) -> str:
    """The lens's name without a parenthesized source, or its file's stem."""
    name = report.get("name") or Path(report.get("source", "lens")).stem
    return name.split(" (")[0]


def _field_text(report: dict, value: float) -> str:
    unit = report["field_unit"]
    return f"{value:g}\N{DEGREE SIGN}" if unit == "deg" else f"{value:g} mm"


def _save(fig: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        save_figure(fig, path)
    return fig


def mtf_figure(report: dict, path: str | Path | None = None) -> Figure:
    """MTF against frequency per field; against field at the chosen frequencies; through
    focus at the first chosen frequency (when the report has it)."""
    tf = report.get("through_focus")
    panels = 3 if tf else 2
    fig = new_figure((5.0 * panels, 4.2), layout="constrained")
    axes = fig.subplots(1, panels)
    ax = axes[0]
    for i, f in enumerate(report["fields"]):
        c = FIELD_COLORS[i % len(FIELD_COLORS)]
        ax.plot(f["frequency_lp_mm"], f["tangential"], color=c, label=f"{_field_text(report, f['field'])} T")
        ax.plot(f["frequency_lp_mm"], f["sagittal"], color=c, ls="--", label="S")
    ax.set(xlabel="frequency (lp/mm)", ylabel="MTF", ylim=(0, 1.02), title="MTF against frequency")
    ax.legend(fontsize="small", ncol=2)
    ax = axes[1]
    sweep = report["against_field"]
    for k, freq in enumerate(sweep["frequency_lp_mm"]):
        c = FIELD_COLORS[k % len(FIELD_COLORS)]
        ax.plot(sweep["fields"], sweep["tangential"][k], color=c, label=f"{freq:.4g} lp/mm T")
        ax.plot(sweep["fields"], sweep["sagittal"][k], color=c, ls="--", label="S")
    ax.set(xlabel=f"field ({report['field_unit']})", ylabel="MTF", ylim=(0, 1.02), title="MTF against field")
    ax.legend(fontsize="small", ncol=2)
    if tf:
        ax = axes[2]
        z_um = np.asarray(tf["focus_shift_mm"]) * 1e3
        for i, f in enumerate(tf["fields"]):
            c = FIELD_COLORS[i % len(FIELD_COLORS)]
            ax.plot(z_um, f["tangential"][0], color=c, label=f"{_field_text(report, f['field'])} T")
            ax.plot(z_um, f["sagittal"][0], color=c, ls="--", label="S")
        ax.set(
            xlabel="focus shift (\N{MICRO SIGN}m, + away from the lens)",
            ylabel="MTF",
            ylim=(0, 1.02),
            title=f"through focus at {tf['frequency_lp_mm'][0]:.4g} lp/mm",
        )
        ax.legend(fontsize="small", ncol=2)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    nm = ", ".join(f"{w:g}" for w in report["wavelengths_nm"][:6]) + (
        "..." if len(report["wavelengths_nm"]) > 6 else ""
    )
    fig.suptitle(f"{_title(report)}: diffraction MTF ({nm} nm)")
    return _save(fig, path)


def wavefront_figure(report: dict, opd_map: np.ndarray, path: str | Path | None = None) -> Figure:
    """The OPD map (waves, piston and tilt removed) and the Zernike coefficients."""
    fig = new_figure((10.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2, width_ratios=(1.0, 1.3))
    lim = float(np.nanmax(np.abs(opd_map))) or 1e-6
    im = ax.imshow(opd_map, origin="lower", extent=(-1, 1, -1, 1), cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, label="OPD (waves)")
    ax.set(
        xlabel="pupil x", ylabel="pupil y", title=f"RMS {report['rms_waves']:.3f}, PV {report['pv_waves']:.3f} waves"
    )
    z = report["zernike"]
    terms = [t["term"] for t in z["terms"]]
    bx.bar(terms, [t["waves"] for t in z["terms"]], color="tab:blue")
    bx.axhline(0.0, color="0.5", lw=0.8)
    bx.set(xlabel=f"{z['convention']} term", ylabel="coefficient (waves)", title="Zernike coefficients")
    bx.grid(True, alpha=0.3)
    fig.suptitle(
        f"{_title(report)}: wavefront at {_field_text(report, report['field'])}, "
        f"{report['wavelength_nm']:g} nm (Strehl {report['strehl']:.3f})"
    )
    return _save(fig, path)


def fans_figure(report: dict, path: str | Path | None = None) -> Figure:
    """Tangential (ey against py) and sagittal (ex against px) fans, one row per field."""
    fields = report["fields"]
    fig = new_figure((9.0, 2.6 * len(fields) + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(fields), 2, sharex=True, squeeze=False))
    cols = _wavelength_colors([w / 1000.0 for w in report["wavelengths_nm"]])
    p = report["pupil"]
    for i, f in enumerate(fields):
        for w, nm in enumerate(report["wavelengths_nm"]):
            ey = [np.nan if v is None else v for v in f["tangential_ey_um"][w]]
            ex = [np.nan if v is None else v for v in f["sagittal_ex_um"][w]]
            axes[i, 0].plot(p, ey, color=cols[w], label=f"{nm:.4g} nm")
            axes[i, 1].plot(p, ex, color=cols[w])
        axes[i, 0].set_ylabel(f"{_field_text(report, f['field'])}\ney (\N{MICRO SIGN}m)")
        axes[i, 1].set_ylabel("ex (\N{MICRO SIGN}m)")
        for ax in axes[i]:
            ax.axhline(0.0, color="0.6", lw=0.6)
            ax.axvline(0.0, color="0.6", lw=0.6)
            ax.grid(True, alpha=0.3)
    axes[0, 0].set_title("tangential fan")
    axes[0, 1].set_title("sagittal fan")
    axes[-1, 0].set_xlabel("pupil py")
    axes[-1, 1].set_xlabel("pupil px")
    axes[0, 0].legend(fontsize="small")
    fig.suptitle(f"{_title(report)}: transverse ray aberration")
    return _save(fig, path)


def field_curves_figure(report: dict, path: str | Path | None = None) -> Figure:
    """Tangential (solid) and sagittal (dashed) foci against the field, per wavelength."""
    fig = new_figure((5.6, 4.6), layout="constrained")
    ax = fig.add_subplot()
    cols = _wavelength_colors([w["wavelength_nm"] / 1000.0 for w in report["wavelengths"]])
    y = report["fields"]
    for k, w in enumerate(report["wavelengths"]):
        t = [np.nan if v is None else v for v in w["tangential_mm"]]
        s = [np.nan if v is None else v for v in w["sagittal_mm"]]
        ax.plot(t, y, color=cols[k], label=f"{w['wavelength_nm']:.4g} nm T")
        ax.plot(s, y, color=cols[k], ls="--", label="S")
    ax.axvline(0.0, color="0.5", lw=0.8)
    ax.set(
        xlabel="focus from the image plane (mm, + away from the lens)",
        ylabel=f"field ({report['field_unit']})",
        title=f"{_title(report)}: field curvature",
        ylim=(0, max(y) if max(y) > 0 else 1),
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small", ncol=2)
    return _save(fig, path)


def energy_figure(report: dict, path: str | Path | None = None) -> Figure:
    """Encircled energy against radius and ensquared energy against half-width, per field."""
    fig = new_figure((10.0, 4.2), layout="constrained")
    ax, bx = fig.subplots(1, 2, sharey=True)
    for i, f in enumerate(report["fields"]):
        c = FIELD_COLORS[i % len(FIELD_COLORS)]
        label = _field_text(report, f["field"])
        ax.plot(f["radius_um"], f["encircled"], color=c, label=label)
        bx.plot(f["half_width_um"], f["ensquared"], color=c, label=label)
    ax.set(xlabel="radius (\N{MICRO SIGN}m)", ylabel="fraction of the energy", title="encircled energy", ylim=(0, 1.02))
    bx.set(xlabel="half-width (\N{MICRO SIGN}m)", title="ensquared energy")
    for a in (ax, bx):
        a.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    fig.suptitle(f"{_title(report)}: {report['method']} PSF, around the {report['centre']}")
    return _save(fig, path)
