"""Figures of a PSF bank: the kernels over the sensor, Strehl ratio, MTF and relative
illumination against image height.

Units: image heights mm, kernel windows um, spatial frequencies cycles/mm, wavelengths nm.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from lensim.plots.figure import new_figure, save_figure
from lensim.psf.bank import PSFBank

FIGURE_NAMES = ("psf_map.png", "strehl.png", "mtf.png", "relative_illumination.png")


def _bank_title(bank: PSFBank) -> str:
    lens = bank.manifest.get("lens", {})
    name = lens.get("name") or Path(str(bank.manifest.get("lens_file", "lens"))).stem
    return (
        f"{name}: {bank.kernel_pixels}x{bank.kernel_pixels} px kernels, {bank.pixel_pitch_um:g} um pixels, "
        f"{len(bank.fields)} fields x {len(bank.wavelengths_nm)} wavelengths"
    )


def _field_unit(bank: PSFBank) -> str:
    return "deg" if bank.manifest.get("field_type") == "angle" else "mm"


def kernel_image(rgb: np.ndarray, gamma: float = 0.5) -> np.ndarray:
    """(3, P, P) kernel -> (P, P, 3) image in 0..1 for display: divided by its largest
    value over all channels (so lateral colour keeps its hue) and raised to `gamma`."""
    k = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, None)
    m = k.max()
    img = (k / m) ** gamma if m > 0 else k
    return np.moveaxis(img, 0, -1)


def _fine_mtf(fine: np.ndarray, spacing_um: float, pad: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MTF of a fine PSF zero-padded pad-fold (finer frequency sampling, same OTF)."""
    from lensim.psf.metrics import mtf

    n = fine.shape[0]
    big = np.zeros((n * pad, n * pad))
    c = n * pad // 2 - n // 2
    big[c : c + n, c : c + n] = fine
    return mtf(big, spacing_um)


def _field_axis(ax: Axes, bank: PSFBank, unit: str) -> None:
    """A top axis with the field (lens unit) over an image-height bottom axis."""
    r = bank.radii_mm
    v = np.asarray([f.field_value for f in bank.fields])
    if len(r) < 2 or np.any(np.diff(r) <= 0) or np.any(np.diff(v) <= 0):
        return
    ax.set_xlim(0.0, float(r[-1]))
    top = ax.secondary_xaxis("top", functions=(lambda x: np.interp(x, r, v), lambda y: np.interp(y, v, r)))
    top.set_xlabel(f"field ({unit})", fontsize=8)
    top.tick_params(labelsize=8)


def _sensor_box_mm(r_max: float) -> tuple[float, float]:
    """Width and height (mm) of a 3:2 sensor inscribed in the circle of radius r_max."""
    if r_max > 0:
        return 2 * r_max * 3 / math.hypot(3, 2), 2 * r_max * 2 / math.hypot(3, 2)
    return 3.0, 2.0


def _draw_kernel_grid(ax: Axes, bank: PSFBank, gamma: float, title: str) -> None:
    """RGB kernels at a 7 x 5 grid of positions on a 3:2 sensor inscribed in the image
    circle of the outermost field."""
    from matplotlib.patches import Circle, Rectangle

    radii = bank.radii_mm
    r_max = float(radii.max()) if radii.size else 0.0
    w, h = _sensor_box_mm(r_max)
    nx, ny = 7, 5
    xs, ys = np.linspace(-w / 2, w / 2, nx), np.linspace(-h / 2, h / 2, ny)
    tile = 0.92 * min(w / (nx - 1), h / (ny - 1))
    ax.set_facecolor("black")
    for y in ys:
        for x in xs:
            img = kernel_image(bank.psf_at(float(x), float(y)), gamma)
            ax.imshow(
                img,
                origin="lower",
                extent=(x - tile / 2, x + tile / 2, y - tile / 2, y + tile / 2),
                interpolation="nearest",
            )
    ax.add_patch(Rectangle((-w / 2, -h / 2), w, h, fill=False, edgecolor="0.6", lw=1.0, ls="--"))
    if r_max > 0:
        ax.add_patch(Circle((0, 0), r_max, fill=False, edgecolor="0.45", lw=0.8, ls=":"))
    pad = tile / 2 + 0.02 * w
    ax.set_xlim(-w / 2 - pad, w / 2 + pad)
    ax.set_ylim(-h / 2 - pad, h / 2 + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x on the image plane (mm)")
    ax.set_ylabel("y (mm)")
    window_um = bank.kernel_pixels * bank.pixel_pitch_um
    mag = tile * 1e3 / window_um
    ax.set_title(
        f"{title}\nRGB kernels over a 3:2 sensor in the {2 * r_max:.1f} mm image circle "
        f"(each tile {window_um:g} um wide, magnified x{mag:.0f}; gamma {gamma:g}, each tile scaled to its peak)",
        fontsize=9.5,
    )


def psf_map_figure(bank: PSFBank, gamma: float = 0.5) -> Figure:
    """The kernels over the sensor (gamma-stretched) and six stored radial kernels enlarged."""
    from matplotlib.gridspec import GridSpec

    fig = new_figure((11.0, 9.6))
    gs = GridSpec(
        2,
        6,
        figure=fig,
        height_ratios=[4.2, 1.3],
        hspace=0.28,
        wspace=0.08,
        left=0.07,
        right=0.98,
        top=0.93,
        bottom=0.04,
    )
    _draw_kernel_grid(fig.add_subplot(gs[0, :]), bank, gamma, _bank_title(bank))
    radii, unit = bank.radii_mm, _field_unit(bank)
    window_um = bank.kernel_pixels * bank.pixel_pitch_um
    picks = np.unique(np.linspace(0, len(bank.fields) - 1, 6).round().astype(int))
    for j, i in enumerate(picks):
        f = bank.fields[i]
        a = fig.add_subplot(gs[1, j])
        a.imshow(
            kernel_image(f.rgb, gamma),
            origin="lower",
            interpolation="nearest",
            extent=(-window_um / 2, window_um / 2, -window_um / 2, window_um / 2),
        )
        a.set_title(f"field {f.field:.2f} ({f.field_value:.3g} {unit})\nr = {radii[i]:.2f} mm", fontsize=8)
        a.tick_params(labelsize=7)
        tick = float(np.floor(window_um / 3.0 / 5.0) * 5.0) or window_um / 3.0
        a.set_xticks([-tick, 0.0, tick])
        a.set_yticks([-tick, 0.0, tick])
        if j == 0:
            a.set_ylabel("um", fontsize=8)
        else:
            a.set_yticklabels([])
    return fig


def strehl_figure(bank: PSFBank) -> Figure:
    """Strehl ratio at the primary wavelength against image height."""
    fig = new_figure((7.0, 4.5))
    ax = fig.add_subplot(1, 1, 1)
    radii = bank.radii_mm
    strehl = np.asarray([f.strehl for f in bank.fields])
    ax.plot(radii, strehl, "o-", ms=3, color="tab:blue")
    ax.axhline(0.8, color="0.6", ls=":", lw=1)
    ax.text(radii.min() if radii.size else 0, 0.81, "0.8 (Marechal)", fontsize=8, color="0.4")
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("image height of the chief ray (mm)")
    ax.set_ylabel("Strehl ratio")
    _field_axis(ax, bank, _field_unit(bank))
    ax.set_title(
        f"Strehl ratio at {bank.primary_wavelength_nm:g} nm (sampled peak, {bank.fine_spacing_um:.3g} um grid)\n"
        f"{_bank_title(bank)}",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def mtf_figure(bank: PSFBank) -> Figure:
    """Sagittal and tangential MTF at the primary wavelength (from the fine PSF, without
    the pixel aperture) up to the sensor's Nyquist frequency at four fields, with the
    diffraction limit on axis."""
    fig = new_figure((7.5, 5.0))
    ax = fig.add_subplot(1, 1, 1)
    unit = _field_unit(bank)
    fmax = 1e3 / (2 * bank.pixel_pitch_um)  # sensor Nyquist (cycles/mm)
    chosen = sorted({int(np.argmin(np.abs(bank.field_positions - t))) for t in (0.0, 0.5, 0.75, 1.0)})
    colors = ("tab:blue", "tab:green", "tab:orange", "tab:red", "tab:purple")
    for c, i in zip(colors, chosen):
        f = bank.fields[i]
        fr, sag, tan = _fine_mtf(f.primary_fine.astype(np.float64), bank.fine_spacing_um)
        sel = fr <= fmax * 1.0001
        ax.plot(fr[sel], tan[sel], "-", color=c, lw=1.6, label=f"field {f.field:.2f} ({f.field_value:.3g} {unit}) T")
        ax.plot(fr[sel], sag[sel], "--", color=c, lw=1.2, label=f"field {f.field:.2f} S")
    f0 = bank.fields[0]
    if math.isfinite(f0.working_fno) and f0.working_fno > 0:
        nu_c = 1.0 / (bank.primary_wavelength_nm * 1e-6 * f0.working_fno)
        nu = np.linspace(0, fmax, 200)
        x = np.clip(nu / nu_c, 0, 1)
        dl = 2 / math.pi * (np.arccos(x) - x * np.sqrt(1 - x * x))
        ax.plot(nu, dl, color="0.5", lw=1.0, ls=":", label=f"diffraction limit (F/{f0.working_fno:.2f})")
    ax.set_xlim(0, fmax)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("spatial frequency (cycles/mm); right edge = sensor Nyquist")
    ax.set_ylabel("MTF")
    ax.set_title(
        f"MTF at {bank.primary_wavelength_nm:g} nm, tangential (T, solid) and sagittal (S, dashed)\n"
        f"{_bank_title(bank)}",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5, ncol=2, loc="upper right")
    fig.tight_layout()
    return fig


def relative_illumination_figure(bank: PSFBank) -> Figure:
    """Relative illumination at three wavelengths and the channel kernel sums against
    image height, with cos^4 of the field angle for an object at infinity."""
    fig = new_figure((7.0, 4.5))
    ax = fig.add_subplot(1, 1, 1)
    radii = bank.radii_mm
    ri = np.stack([f.relative_illumination for f in bank.fields])  # (F, W)
    wl = bank.wavelengths_nm
    sums = bank.kernels.astype(np.float64).sum(axis=(-1, -2))  # (F, 3)
    for c, name, col in zip(range(3), ("R", "G", "B"), ("tab:red", "tab:green", "tab:blue")):
        ax.plot(radii, sums[:, c], "-", lw=3.0, alpha=0.45, color=col, label=f"{name} kernel sum")
    for j, m in zip(sorted({0, len(wl) // 2, len(wl) - 1}), ("v", "o", "^")):
        ax.plot(
            radii,
            ri[:, j],
            lw=0.8,
            color="k",
            marker=m,
            ms=3.5,
            mfc="none",
            label=f"{wl[j]:g} nm",
            markevery=max(1, len(radii) // 12),
        )
    lens = bank.manifest.get("lens", {})
    floor = [float(np.nanmin(ri)), float(np.nanmin(sums))]
    if bank.manifest.get("field_type") == "angle" and lens.get("object", {}).get("distance") == "infinity":
        cos4 = np.cos(np.radians([f.field_value for f in bank.fields])) ** 4
        ax.plot(radii, cos4, color="0.4", lw=0.8, ls="-.", label="cos^4 (field angle)")
        floor.append(float(cos4.min()))
    ax.set_xlabel("image height of the chief ray (mm)")
    ax.set_ylabel("relative illumination")
    _field_axis(ax, bank, _field_unit(bank))
    ax.set_ylim(max(0.0, min(floor) - 0.03), 1.02)
    ax.set_title(f"Relative illumination (projected solid angle, vignetting included)\n{_bank_title(bank)}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return fig


def write_bank_figures(bank: PSFBank, out_dir: str | Path, dpi: int = 150, gamma: float = 0.5) -> list[Path]:
    """Write the PNG figures of a bank into out_dir and return their paths (FIGURE_NAMES):
    psf_map.png (psf_map_figure, kernels gamma-stretched by `gamma`), strehl.png,
    mtf.png and relative_illumination.png."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    makers = (
        lambda: psf_map_figure(bank, gamma),
        lambda: strehl_figure(bank),
        lambda: mtf_figure(bank),
        lambda: relative_illumination_figure(bank),
    )
    return [save_figure(make(), out / name, dpi) for make, name in zip(makers, FIGURE_NAMES)]
