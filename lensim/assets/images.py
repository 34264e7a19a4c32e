"""Built-in natural sample photos that may be redistributed, with their licences.

They are not copied into this repository: they ship inside two packages that the set-up
command installs from the package registry (scikit-image, and sporco installed without
its dependencies), and are read from there. No image is downloaded at run time.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

from lensim.errors import InputError


@dataclass(frozen=True)
class SampleImage:
    name: str
    package: str
    relative_path: str
    licence: str
    credit: str


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
)


def _package_dir(package: str) -> Path | None:
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        return None
    return Path(spec.origin).parent


def sample_image_path(name: str) -> Path:
    """Path of a built-in sample image; a clear error if its package is not installed."""
    for img in SAMPLE_IMAGES:
        if img.name == name:
            base = _package_dir(img.package)
            path = None if base is None else base / img.relative_path
            if path is None or not path.is_file():
                raise InputError(name, "sample image", f"not found; it ships with the '{img.package}' package, which "
                                 "scripts/setup.sh installs")
            return path
    raise InputError(name, "sample image", f"unknown; expected one of {', '.join(i.name for i in SAMPLE_IMAGES)}")


def available_sample_images() -> list[SampleImage]:
    """The sample images whose package is installed."""
    out = []
    for img in SAMPLE_IMAGES:
        base = _package_dir(img.package)
        if base is not None and (base / img.relative_path).is_file():
            out.append(img)
    return out
