"""Defect 2's figure: the US 5,331,467 catadioptric's Huygens PSF in lensim and optiland,
sampled at the same image points, with each tool's geometric ray centroid.

Run from the repository root: python docs/analysis/defects/catadioptric_figure.py
Writes docs/analysis/defects/catadioptric.png and prints the numbers.
"""

from __future__ import annotations

import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import optiland.backend as be  # noqa: E402
import rayoptics  # noqa: E402
from optiland.fileio import load_zemax_file  # noqa: E402
from optiland.physical_apertures import RadialAperture  # noqa: E402
from optiland.psf import HuygensPSF  # noqa: E402

from lensim.optics.lens_file import load_lens  # noqa: E402
from lensim.psf.compute import compute_psf  # noqa: E402
from lensim.psf.pupil_field import pupil_field  # noqa: E402

LENS = "lensim/assets/library/catadioptric_1000mm_f7.5_us5331467.yaml"
WL, N, G, SP = 0.5875618, 128, 128, 1.5  # um, pupil samples, window samples, spacing (um)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally framed windows."""
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def main() -> None:
    """On axis and at 14 mm: both PSFs on optiland's sample points."""
    warnings.filterwarnings("ignore")
    be.set_backend("numpy")
    o = load_zemax_file(rayoptics.__path__[0] + "/zemax/models/PhotoPrime/US05331467-1.zmx")
    o.surfaces[2].aperture = RadialAperture(r_max=be.inf, r_min=25.0)
    lens = load_lens(LENS)
    fig, axes = plt.subplots(2, 2, figsize=(7, 7))
    for row, (hy, fv) in enumerate(((0.0, 0.0), (14.0 / 21.0, 14.0))):
        op = HuygensPSF(o, (0.0, hy), WL, num_rays=N, image_size=G, pixel_pitch=SP * 1e-3 * (G - 1) / G)
        theirs = np.asarray(be.to_numpy(op.psf), dtype=np.float64)
        pf = pupil_field(lens, fv, WL, N, "paraxial")
        chief = float(pf.chief[1])
        w = pf.power.numpy()
        ray_centroid = float((w * pf.image_xy[:, 1].numpy()).sum() / w.sum()) - chief
        half = 0.5 * SP * 1e-3
        offset = (float(op.cx) + half, float(op.cy) - chief + half)
        ours = compute_psf(lens, fv / lens.max_field, WL, "huygens", N, G, SP, "paraxial", offset_mm=offset).data
        rows_um = (np.arange(G) - (G - 1) / 2) * SP + (float(op.cy) - chief) * 1e3
        ext = [
            rows_um[0] - (float(op.cy) - chief) * 1e3,
            rows_um[-1] - (float(op.cy) - chief) * 1e3,
            rows_um[0],
            rows_um[-1],
        ]
        for col, (name, p) in enumerate((("lensim", ours), ("optiland", theirs))):
            c = float((p.sum(1) * rows_um).sum() / p.sum())
            ax = axes[row, col]
            ax.imshow(p, origin="lower", extent=ext, cmap="magma")
            ax.axhline(ray_centroid * 1e3, color="c", lw=0.8, label=f"rays' centroid {ray_centroid * 1e3:+.1f} um")
            ax.axhline(c, color="w", lw=0.8, ls="--", label=f"PSF centroid {c:+.1f} um")
            ax.set_title(f"{name}, field {fv:g} mm" + (f" (NCC {ncc(ours, theirs):.4f})" if col else ""), fontsize=8)
            ax.set_xlabel("x (um)", fontsize=7)
            ax.set_ylabel("y from the chief ray (um)", fontsize=7)
            ax.legend(fontsize=6, loc="lower right")
            print(f"field {fv:4.1f} {name:8s} PSF centroid {c:+7.2f} um, rays' centroid {ray_centroid * 1e3:+7.2f} um")
        print(f"field {fv:4.1f} NCC on the same points {ncc(ours, theirs):.5f}")
    fig.suptitle("US 5,331,467 Ex. 1, 587.6 nm, Huygens PSF on the same image points", fontsize=9)
    fig.tight_layout()
    fig.savefig("docs/analysis/defects/catadioptric.png", dpi=100)


if __name__ == "__main__":
    main()
