"""Defect 1's before/after figure: the F/1.25 catadioptric focused at 1 m, through focus.

Run from the repository root: python docs/analysis/defects/best_focus_figure.py
Writes docs/analysis/defects/best_focus.png and prints the numbers.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lensim.optics.lens_file import load_lens  # noqa: E402
from lensim.optics.shooting import ShootingSettings, lens_at  # noqa: E402
from lensim.optics.spot import rms_spot_radius  # noqa: E402
from lensim.psf.best_focus import focus_error  # noqa: E402
from lensim.psf.mtf import refocused  # noqa: E402

LENS = "lensim/assets/library/catadioptric_f1.25_hoo_ex27.yaml"


def main() -> None:
    """Scan the image plane around paraxial focus at 1 m; mark each focus mode's plane."""
    lens = load_lens(LENS)
    at = {m: lens_at(lens, ShootingSettings(focus_m=1.0, focus_mode=m)) for m in ("paraxial", "calibrated", "best")}
    ref = at["paraxial"]
    shifts = np.linspace(-0.06, 0.02, 41)
    err = focus_error(ref, shifts)
    spot = np.array([rms_spot_radius(refocused(ref, z), 0.0, aiming="real") * 1e3 for z in shifts])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(shifts * 1e3, np.sqrt(err), label="RMS wavefront (waves)")
    ax2 = ax.twinx()
    ax2.plot(shifts * 1e3, spot, "C1", label="RMS spot (um)")
    for mode, lm, c in (
        ("paraxial", at["paraxial"], "k"),
        ("calibrated", at["calibrated"], "C2"),
        ("best", at["best"], "C3"),
    ):
        dz = lm.surfaces[-1].thickness - ref.surfaces[-1].thickness  # along the light: this lens ends in air, +z
        r = rms_spot_radius(lm, 0.0, aiming="real") * 1e3
        w = float(np.sqrt(focus_error(lm, np.array([0.0]))[0]))
        print(f"{mode:10s} plane {dz * 1e3:+8.2f} um  RMS wavefront {w:.3f} waves  RMS spot {r:.2f} um")
        ax.axvline(dz * 1e3, color=c, ls="--", label=f"--focus-mode {mode}: {w:.2f} waves, spot {r:.1f} um")
    ax.set_xlabel("image plane from the paraxial-offset plane (um, + away from the lens)")
    ax.set_ylabel("RMS wavefront on axis (waves)")
    ax2.set_ylabel("RMS spot radius on axis (um)")
    ax.set_title("F/1.25 catadioptric (Handbook of Optics ex. 27) focused at 1 m")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig("docs/analysis/defects/best_focus.png", dpi=110)


if __name__ == "__main__":
    main()
