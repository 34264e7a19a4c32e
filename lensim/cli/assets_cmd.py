"""`lensim assets`: list the built-in lenses, sensors and sample photos."""
from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lensim import assets
from lensim.assets.images import SAMPLE_IMAGES, available_sample_images
from lensim.cli.common import console, print_json
from lensim.cli.validate import output_folder


def assets_command(
    export_photos: Path = typer.Option(None, "--export-photos", help="Write every installed sample photo (at its "
                                       "scale, 8-bit PNG) into this folder, for `lensim dataset make`."),
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object."),
) -> None:
    """List built-in lenses, sensor profiles and sample photos (with licences).

    Example: lensim assets --export-photos photos/ && lensim dataset make photos/ -o pairs/
    """
    if export_photos is not None:
        from lensim.assets.images import read_sample_image
        from lensim.images import write_image

        output_folder(export_photos, "--export-photos")
        export_photos.mkdir(parents=True, exist_ok=True)
        for img in available_sample_images():
            write_image(export_photos / f"{img.name}.png", read_sample_image(img.name), 8)
    lenses = assets.lens_names()
    sensors = sorted(p.stem for p in (assets.ASSETS_DIR / "sensors").glob("*.yaml"))
    have = {i.name for i in available_sample_images()}
    images = [{"name": i.name, "licence": i.licence, "credit": i.credit, "installed": i.name in have} for i in SAMPLE_IMAGES]
    if json_out:
        print_json({"lenses": lenses, "default_lens": assets.DEFAULT_LENS, "sensors": sensors, "images": images})
        return
    t = Table(title="Built-in assets")
    t.add_column("kind")
    t.add_column("name")
    t.add_column("details")
    for name in lenses:
        t.add_row("lens", name, "default" if name == assets.DEFAULT_LENS else "")
    for name in sensors:
        t.add_row("sensor", name, "")
    for img in images:
        t.add_row("image", img["name"], f"{img['licence']}; {img['credit']}" + ("" if img["installed"] else " (not installed)"))
    console.print(t)
