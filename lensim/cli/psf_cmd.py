"""`lensim psf ...`: compute single PSFs (and PSF banks)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from lensim.cli.common import console, print_json
from lensim.optics.lens_file import atomic_write_bytes, load_lens
from lensim.psf.compute import METHODS, compute_psf

psf_app = typer.Typer(help="Point spread functions: single PSFs, banks, pictures.", no_args_is_help=True)


@psf_app.command("compute")
def compute(
    lens_file: str = typer.Argument(..., help="Lens file or built-in lens name."),
    field: float = typer.Option(0.0, "--field", help="Normalized field, 0..1 of the lens's max field along +y."),
    wavelength_nm: float = typer.Option(550.0, "--wavelength-nm", help="Wavelength in nm."),
    method: str = typer.Option("huygens", "--method", help=f"One of {', '.join(METHODS)}."),
    pupil_samples: int = typer.Option(128, "--pupil-samples", help="Pupil grid samples across the diameter."),
    grid: int = typer.Option(128, "--grid", help="PSF window size in samples (grid x grid)."),
    spacing_um: float = typer.Option(0.5, "--spacing-um", help="PSF sample spacing in um."),
    aiming: str = typer.Option("real", "--aiming", help="Ray aiming: real or paraxial."),
    output: Path = typer.Option(None, "-o", "--output", help="Write the PSF array (.npy, energy per sample)."),
    json_out: bool = typer.Option(False, "--json", help="Print the figures (Strehl, RMS spot, EE50/EE80, chief-ray position) as JSON."),
) -> None:
    """One PSF: grid x grid samples at spacing_um, centred on the real chief-ray image point;
    the array sums to the transmitted fraction (inside the window).

    Example: lensim psf compute cooke_triplet --field 0.7 --wavelength-nm 550 -o psf.npy --json
    """
    lens = load_lens(lens_file)
    psf = compute_psf(lens, field, wavelength_nm / 1000.0, method, pupil_samples, grid, spacing_um, aiming)
    if output is not None:
        import io

        buf = io.BytesIO()
        np.save(buf, psf.data)
        atomic_write_bytes(output, buf.getvalue())
    info = {"lens": lens.source, "field": field, "field_value": psf.field_value, "field_type": lens.field_type,
            "wavelength_nm": wavelength_nm, "method": method, "grid": grid, "spacing_um": spacing_um,
            "pupil_samples": pupil_samples, "aiming": aiming, **psf.figures}
    if json_out:
        print_json(info)
        return
    for k, v in info.items():
        console.print(f"{k:22s} {v}", highlight=False)
    if output is not None:
        console.print(f"wrote {output}")
