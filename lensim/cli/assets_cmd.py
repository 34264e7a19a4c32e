"""`lensim assets`: list the built-in lenses, sensors and sample photos."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.table import Table

from lensim import assets
from lensim.cli.common import console, print_json
from lensim.cli.validate import output_folder
from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.assets.images import SampleImage


def assets_command(
    export_photos: Path = typer.Option(
        None,
        "--export-photos",
        help="Write every installed sample photo (at its "
        "scale, 8-bit PNG) into this folder, for `lensim dataset make`.",
    ),
    export_test_photos: Path = typer.Option(
        None,
        "--export-test-photos",
        help="Write every installed unseen test "
        "photo (never trained on) into this folder, for `lensim dataset make` and "
        "`lensim evaluate`.",
    ),
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object."),
) -> None:
    """List built-in lenses, sensor profiles and sample photos (with licences).

    Example: lensim assets --export-photos photos/ && lensim dataset make photos/ -o pairs/
    """
    from lensim.assets.images import SAMPLE_IMAGES, TEST_IMAGES, available_sample_images, unseen_photos

    for folder, option in ((export_photos, "--export-photos"), (export_test_photos, "--export-test-photos")):
        if folder is not None:
            output_folder(folder, option)
    if (
        export_photos is not None
        and export_test_photos is not None
        and export_photos.resolve() == export_test_photos.resolve()
    ):
        raise InputError(
            str(export_test_photos),
            "--export-test-photos",
            "is the --export-photos folder; expected another folder, so that no training run sees the test photos",
        )
    if export_photos is not None:
        _export(available_sample_images(), export_photos)
    if export_test_photos is not None:
        _export(unseen_photos(), export_test_photos)
    lenses = assets.lens_names()
    sensors = sorted(p.stem for p in (assets.ASSETS_DIR / "sensors").glob("*.yaml"))
    images = _listing(SAMPLE_IMAGES, available_sample_images())
    test_images = _listing(TEST_IMAGES, unseen_photos())
    if json_out:
        print_json(
            {
                "lenses": lenses,
                "default_lens": assets.DEFAULT_LENS,
                "sensors": sensors,
                "images": images,
                "test_images": test_images,
            }
        )
        return
    t = Table(title="Built-in assets")
    t.add_column("kind")
    t.add_column("name")
    t.add_column("details")
    for name in lenses:
        t.add_row("lens", name, "default" if name == assets.DEFAULT_LENS else "")
    for name in sensors:
        t.add_row("sensor", name, "")
    for kind, listing in (("image", images), ("test image", test_images)):
        for img in listing:
            t.add_row(
                kind,
                img["name"],
                f"{img['licence']}; {img['credit']}" + ("" if img["installed"] else " (not installed)"),
            )
    console.print(t)


def _export(photos: list[SampleImage], folder: Path) -> None:
    """Each photo as FOLDER/NAME.png (8-bit, at its scale and exposure)."""
    from lensim.assets.images import read_sample_image
    from lensim.images import write_image

    folder.mkdir(parents=True, exist_ok=True)
    for img in photos:
        write_image(folder / f"{img.name}.png", read_sample_image(img.name), 8)


def _listing(listed: tuple[SampleImage, ...], installed: list[SampleImage]) -> list[dict]:
    have = {i.name for i in installed}
    return [{"name": i.name, "licence": i.licence, "credit": i.credit, "installed": i.name in have} for i in listed]
