"""Built-in natural sample photos that may be redistributed, with their licences.

They are not copied into this repository: they ship inside packages that the set-up
command installs (scikit-image and sporco from the Python package registry; Debian's
`mate-backgrounds`, 12 nature photos of 1.3-4.1 megapixels, GPL-2+, when the machine
has apt and root) and are read from there. No image is downloaded at run time. A package
that is missing only removes its photos from :func:`available_sample_images`.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from lensim.errors import InputError
from lensim.images import read_image


@dataclass(frozen=True)
class SampleImage:
    """One photo: ``package`` is an importable Python package, or ``debian:NAME`` for a
    Debian package whose files lie under :data:`DEBIAN_ROOTS`; ``relative_path`` is the
    file inside it."""

    name: str
    package: str
    relative_path: str
    licence: str
    credit: str
    scale: float = 1.0  # resampling factor read_sample_image applies (the file is left as is)


DEBIAN_ROOTS = {"mate-backgrounds": Path("/usr/share/backgrounds/mate")}
_MATE_CREDITS = {
    "Aqua": "Charles Barbin", "Blinds": "Lennart Poettering, Andrea Cimitan", "Dune": "Marco Cogoni, Hylke Bons",
    "FreshFlower": "Jens Ansorg", "Garden": "Charles Barbin", "GreenMeadow": "Timothy Schellhase, Lapo Calamandrei",
    "LadyBird": "Charles Barbin", "RainDrops": "blackcombwhistler07", "Storm": "Sergey Nazarov",
    "TwoWings": "Charles Barbin, Hylke Bons", "Wood": "Jean-François Fortin Tam", "YellowFlower": "Charles Barbin",
}


SAMPLE_IMAGES: tuple[SampleImage, ...] = (
    SampleImage("astronaut", "skimage", "data/astronaut.png", "public domain",
                "NASA, Eileen Collins (scikit-image data)"),
    SampleImage("coffee", "skimage", "data/coffee.png", "CC0", "Rachel Michetti (scikit-image data)"),
    SampleImage("chelsea", "skimage", "data/chelsea.png", "CC0", "Stefan van der Walt (scikit-image data)"),
    SampleImage("rocket", "skimage", "data/rocket.jpg", "public domain", "SpaceX (scikit-image data)"),
    SampleImage("kodim23", "sporco", "data/kodim23.png", "unrestricted use (Kodak PhotoCD test set)",
                "Eastman Kodak (sporco data)"),
    SampleImage("monarch", "sporco", "data/monarch.png", "free of copyright restrictions (Waterloo BragZone)",
                "University of Waterloo (sporco data)"),
    SampleImage("sail", "sporco", "data/sail.png", "free of copyright restrictions (Waterloo BragZone)",
                "University of Waterloo (sporco data)"),
    SampleImage("tulips", "sporco", "data/tulips.png", "free of copyright restrictions (Waterloo BragZone)",
                "University of Waterloo (sporco data)"),
) + tuple(
    SampleImage(f"mate-{stem.lower()}", "debian:mate-backgrounds", f"nature/{stem}.jpg", "GPL-2+",
                f"{who} (Debian mate-backgrounds)", scale=0.5)
    for stem, who in _MATE_CREDITS.items()
)


def _package_dir(package: str) -> Path | None:
    if package.startswith("debian:"):
        root = DEBIAN_ROOTS.get(package.split(":", 1)[1])
        return root if root is not None and root.is_dir() else None
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        return None
    return Path(spec.origin).parent


def _sample(name: str) -> SampleImage:
    """The built-in photo called name; a clear error naming the choices if there is none."""
    for img in SAMPLE_IMAGES:
        if img.name == name:
            return img
    raise InputError(name, "sample image", f"unknown; expected one of {', '.join(i.name for i in SAMPLE_IMAGES)}")


def sample_image_path(name: str) -> Path:
    """Path of a built-in sample image; a clear error if its package is not installed."""
    img = _sample(name)
    base = _package_dir(img.package)
    path = None if base is None else base / img.relative_path
    if path is None or not path.is_file():
        raise InputError(name, "sample image", f"not found; it ships with the '{img.package}' package, which "
                         "scripts/setup.sh installs")
    return path


def read_sample_image(name: str) -> torch.Tensor:
    """A built-in photo as (3, H, W) float32 sRGB in [0, 1], resampled by its ``scale``.

    The Debian wallpapers are JPEGs of 1.3-4.1 megapixels that are soft at full size; they
    are halved (antialiased bilinear), which makes them sharp at the pixel level, as a
    ground truth for training pairs should be."""
    arr, _ = read_image(sample_image_path(name))
    scale = _sample(name).scale
    if scale != 1.0:
        arr = F.interpolate(arr[None], scale_factor=scale, mode="bilinear", antialias=True,
                            align_corners=False)[0].clamp(0.0, 1.0)
    return arr


def available_sample_images() -> list[SampleImage]:
    """The sample images whose package is installed."""
    out = []
    for img in SAMPLE_IMAGES:
        base = _package_dir(img.package)
        if base is not None and (base / img.relative_path).is_file():
            out.append(img)
    return out
