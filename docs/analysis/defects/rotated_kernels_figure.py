"""Defect 5's before/after figure: a bank kernel turned to 45 degrees, against the PSF
computed directly at that 2-D field point (tests/test_rotated_kernels.py's direct path).

Run from the repository root: python docs/analysis/defects/rotated_kernels_figure.py
Writes docs/analysis/defects/rotated_kernels.png and prints the numbers.
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, "tests")
from lensim.optics.lens_file import load_lens  # noqa: E402
from lensim.psf.bank import BankSettings, get_bank  # noqa: E402
from lensim.render.rotation import rotate_kernel  # noqa: E402
from test_rotated_kernels import FIELDS, WL_NM, _at, direct_kernel, ncc  # noqa: E402


def main() -> None:
    """Truth, old (pixel kernel turned) and new (turned before pixel integration) at 45 deg."""
    lens = load_lens("cooke_triplet")
    settings = BankSettings(fields=FIELDS, wavelengths_nm=(WL_NM,), pupil_samples=64)
    fig, axes = plt.subplots(2, 3, figsize=(9, 6))
    for row, pitch in enumerate((23.0, 3.92)):
        bank = get_bank(lens, pitch, settings, memory_only=True)
        truth = direct_kernel(lens, bank, FIELDS[2], 45.0)
        old = rotate_kernel(bank.fields[2].rgb[1].astype(np.float64), 45.0)
        old /= old.sum()
        new = _at(bank, 2, 45.0)
        for col, (name, k) in enumerate(
            (
                ("direct PSF at 45 deg", truth),
                ("before: pixel kernel turned", old),
                ("after: turned before binning", new),
            )
        ):
            ax = axes[row, col]
            ax.imshow(k, origin="lower", cmap="magma", vmin=0, vmax=truth.max())
            text = f"peak {k.max():.3f}" + ("" if col == 0 else f", NCC {ncc(k, truth):.4f}")
            ax.set_title(f"{pitch:g} um: {name}\n{text}", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
            print(f"{pitch:5.2f} um {name:32s} {text}")
    fig.suptitle(f"Cooke triplet, full field turned to 45 deg, {WL_NM:g} nm, green channel", fontsize=9)
    fig.tight_layout()
    fig.savefig("docs/analysis/defects/rotated_kernels.png", dpi=100)


if __name__ == "__main__":
    main()
