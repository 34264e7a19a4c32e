"""Built-in natural sample photos that may be redistributed, with their licences, in two
splits that never meet:

* the training photos (:data:`SAMPLE_IMAGES`, :func:`available_sample_images`): what
  `lensim assets --export-photos`, the demo and the benchmarks train on;
* the unseen test photos (:data:`TEST_IMAGES`, :func:`unseen_photos`): scenes unlike the
  training photos (architecture, foliage, text, faces, dark and noisy scenes), from
  packages that hold no training photo (scikit-learn, matplotlib) and from scikit-image
  photos of other collections than its four training photos. Nothing trains on them;
  `lensim assets --export-test-photos` writes them for `lensim dataset make` and
  `lensim evaluate`.

They are not copied into this repository: they ship inside packages that the set-up
command installs (scikit-image, sporco, scikit-learn and matplotlib from the Python
package registry; where the machine has apt and root, Debian's `mate-backgrounds`
(12 nature photos, GPL-2+), `plasma-workspace-wallpapers` (11 KDE photos, GPL-2+ / LGPL-3)
and `lomiri-wallpapers-16.04` (14 photos of the Ubuntu 18.04 wallpaper contest, CC-BY-4.0,
CC-BY-SA-4.0 or CC0 per photo)) and are read from there. No image is downloaded at run
time. A package that is missing only removes its photos.
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
    file inside it. ``scale`` resamples it when read (the file is left as is);
    ``exposure_ev`` changes its exposure by that many stops in linear light when read
    (negative: a darker scene, which the simulated camera then records with more noise
    relative to the signal)."""

    name: str
    package: str
    relative_path: str
    licence: str
    credit: str
    scale: float = 1.0
    exposure_ev: float = 0.0
    content: str = ""  # what the photo shows (the test split's categories)


DEBIAN_ROOTS = {
    "mate-backgrounds": Path("/usr/share/backgrounds/mate"),
    "plasma-workspace-wallpapers": Path("/usr/share/wallpapers"),
    "lomiri-wallpapers-16.04": Path("/usr/share/backgrounds"),
}
_MATE_CREDITS = {
    "Aqua": "Charles Barbin",
    "Blinds": "Lennart Poettering, Andrea Cimitan",
    "Dune": "Marco Cogoni, Hylke Bons",
    "FreshFlower": "Jens Ansorg",
    "Garden": "Charles Barbin",
    "GreenMeadow": "Timothy Schellhase, Lapo Calamandrei",
    "LadyBird": "Charles Barbin",
    "RainDrops": "blackcombwhistler07",
    "Storm": "Sergey Nazarov",
    "TwoWings": "Charles Barbin, Hylke Bons",
    "Wood": "Jean-François Fortin Tam",
    "YellowFlower": "Charles Barbin",
}
# KDE Plasma 5.27's photographic wallpapers (the others are renders and drawings); authors and
# licence from each wallpaper's metadata.json (LGPLv3), the package's debian/copyright says GPL-2+
_KDE_CREDITS = {
    "BytheWater": "Maciej Wiklo",
    "ColdRipple": "Risto Saukonpää",
    "ColorfulCups": "Dmitri Popov",
    "DarkestHour": "Risto Saukonpää",
    "EveningGlow": "Ian Hex",
    "FallenLeaf": "Martin Klapetek",
    "Grey": "Sigi Sagi",
    "Kite": "Risto Saukonpää",
    "OneStandsOut": "Risto Saukonpää",
    "Path": "Risto Saukonpää",
    "summer_1am": "Risto Saukonpää",
}
# Lomiri (Ubuntu Touch) 16.04 wallpapers, all photographs but umang (a render); licence per
# file from debian/copyright; scale brings each to about 1-1.6 megapixels, where it is sharp
_LOMIRI = (
    ("Bridge_by_Sander_Klootwijk", "Sander Klootwijk", "CC-BY-SA-4.0", 0.25),
    ("Dragonfly_by_Bolly", "Bolly", "CC-BY-SA-4.0", 0.25),
    ("Picture_0B_by_freespace", 'Trevor "Freespace"', "CC-BY-4.0", 0.5),
    ("Picture_1A_by_freespace", 'Trevor "Freespace"', "CC-BY-4.0", 0.75),
    ("Wine_by_Jakkub_Mede", "Jakub Mede", "CC-BY-4.0", 0.4),
    ("aitzgorri_by_Aitzol_Berasategi", "Aitzol Berasategi", "CC-BY-4.0", 0.4),
    ("analogpattern_by_Peter_Nerlich", "Peter Nerlich", "CC-BY-SA-4.0", 0.4),
    ("free_by_Peter_Nerlich", "Peter Nerlich", "CC-BY-SA-4.0", 0.4),
    ("friends_by_Aitzol_Berasategi", "Aitzol Berasategi", "CC-BY-4.0", 0.4),
    ("greentock_by_Peter_Nerlich", "Peter Nerlich", "CC-BY-SA-4.0", 0.4),
    ("life_by_Aitzol_Berasategi", "Aitzol Berasategi", "CC-BY-4.0", 0.4),
    ("picosdeeuropa_by_Aitzol_Berasategi", "Aitzol Berasategi", "CC-BY-4.0", 0.4),
    ("seeding_by_Clements_Engelhardt", "Clemens Engelhardt", "CC0-1.0", 0.25),
    ("sunset_by_Aitzol_Berasategi", "Aitzol Berasategi", "CC-BY-4.0", 0.25),
)


SAMPLE_IMAGES: tuple[SampleImage, ...] = (
    (
        SampleImage(
            "astronaut", "skimage", "data/astronaut.png", "public domain", "NASA, Eileen Collins (scikit-image data)"
        ),
        SampleImage("coffee", "skimage", "data/coffee.png", "CC0", "Rachel Michetti (scikit-image data)"),
        SampleImage("chelsea", "skimage", "data/chelsea.png", "CC0", "Stefan van der Walt (scikit-image data)"),
        SampleImage("rocket", "skimage", "data/rocket.jpg", "public domain", "SpaceX (scikit-image data)"),
        SampleImage(
            "kodim23",
            "sporco",
            "data/kodim23.png",
            "unrestricted use (Kodak PhotoCD test set)",
            "Eastman Kodak (sporco data)",
        ),
        SampleImage(
            "monarch",
            "sporco",
            "data/monarch.png",
            "free of copyright restrictions (Waterloo BragZone)",
            "University of Waterloo (sporco data)",
        ),
        SampleImage(
            "sail",
            "sporco",
            "data/sail.png",
            "free of copyright restrictions (Waterloo BragZone)",
            "University of Waterloo (sporco data)",
        ),
        SampleImage(
            "tulips",
            "sporco",
            "data/tulips.png",
            "free of copyright restrictions (Waterloo BragZone)",
            "University of Waterloo (sporco data)",
        ),
    )
    + tuple(
        SampleImage(
            f"mate-{stem.lower()}",
            "debian:mate-backgrounds",
            f"nature/{stem}.jpg",
            "GPL-2+",
            f"{who} (Debian mate-backgrounds)",
            scale=0.5,
        )
        for stem, who in _MATE_CREDITS.items()
    )
    + tuple(
        SampleImage(
            f"kde-{stem.lower().replace('_', '')}",
            "debian:plasma-workspace-wallpapers",
            f"{stem}/contents/images/2560x1600.jpg",
            "LGPL-3 (wallpaper metadata; Debian: GPL-2+)",
            f"{who} (Debian plasma-workspace-wallpapers)",
            scale=0.5,
        )
        for stem, who in _KDE_CREDITS.items()
    )
    + tuple(
        SampleImage(
            f"lomiri-{stem.split('_by_')[0].lower().replace('_', '')}",
            "debian:lomiri-wallpapers-16.04",
            f"{stem}.jpg",
            licence,
            f"{who} (Debian lomiri-wallpapers-16.04)",
            scale=scale,
        )
        for stem, who, licence, scale in _LOMIRI
    )
)

_SKIMAGE = "scikit-image data"
#: The unseen test split: never trained on (tests/test_sample_images.py checks that it shares
#: no photo, file or package entry with SAMPLE_IMAGES); two dark scenes are made from
#: well-exposed photos by lowering their exposure 3 stops in linear light.
TEST_IMAGES: tuple[SampleImage, ...] = (
    SampleImage(
        "test-china",
        "sklearn",
        "datasets/images/china.jpg",
        "CC-BY-2.0",
        "Daniel Buechele (scikit-learn data)",
        content="architecture, fine detail",
    ),
    SampleImage(
        "test-flower",
        "sklearn",
        "datasets/images/flower.jpg",
        "CC-BY-2.0",
        "vultilion (scikit-learn data)",
        content="close-up flower and foliage",
    ),
    SampleImage(
        "test-grace-hopper",
        "matplotlib",
        "mpl-data/sample_data/grace_hopper.jpg",
        "public domain (US Navy)",
        "US Navy (matplotlib sample data)",
        content="face, portrait",
    ),
    SampleImage(
        "test-cameraman",
        "skimage",
        "data/camera.png",
        "CC0",
        f"Lav Varshney ({_SKIMAGE})",
        content="face, buildings, grey",
    ),
    SampleImage(
        "test-motorcycle",
        "skimage",
        "data/motorcycle_left.png",
        "Middlebury 2014 stereo data set",
        f"Middlebury College ({_SKIMAGE})",
        content="indoor detail, clutter",
    ),
    SampleImage(
        "test-text", "skimage", "data/text.png", "public domain", f"Wikipedia ({_SKIMAGE})", content="text, grey"
    ),
    SampleImage(
        "test-page",
        "skimage",
        "data/page.png",
        "BSD-3-Clause (scikit-image)",
        f"scikit-image ({_SKIMAGE})",
        content="printed text, grey",
    ),
    SampleImage(
        "test-grass", "skimage", "data/grass.png", "CC0", f"linolafett ({_SKIMAGE})", content="foliage texture, grey"
    ),
    SampleImage(
        "test-hubble",
        "skimage",
        "data/hubble_deep_field.jpg",
        "public domain (NASA)",
        f"NASA, ESA ({_SKIMAGE})",
        content="dark scene",
    ),
    SampleImage(
        "test-china-dark",
        "sklearn",
        "datasets/images/china.jpg",
        "CC-BY-2.0",
        "Daniel Buechele (scikit-learn data)",
        exposure_ev=-3.0,
        content="dark, noisy (3 stops under)",
    ),
    SampleImage(
        "test-motorcycle-dark",
        "skimage",
        "data/motorcycle_left.png",
        "Middlebury 2014 stereo data set",
        f"Middlebury College ({_SKIMAGE})",
        exposure_ev=-3.0,
        content="dark indoor, noisy (3 stops under)",
    ),
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
    """The built-in photo (either split) called name; a clear error naming the choices if there is none."""
    for img in SAMPLE_IMAGES + TEST_IMAGES:
        if img.name == name:
            return img
    raise InputError(
        name, "sample image", f"unknown; expected one of {', '.join(i.name for i in SAMPLE_IMAGES + TEST_IMAGES)}"
    )


def sample_image_path(name: str) -> Path:
    """Path of a built-in sample image; a clear error if its package is not installed."""
    img = _sample(name)
    base = _package_dir(img.package)
    path = None if base is None else base / img.relative_path
    if path is None or not path.is_file():
        raise InputError(
            name,
            "sample image",
            f"not found; it ships with the '{img.package}' package, which scripts/setup.sh installs",
        )
    return path


def read_sample_image(name: str) -> torch.Tensor:
    """A built-in photo as (3, H, W) float32 sRGB in [0, 1], resampled by its ``scale`` and
    brought to its ``exposure_ev`` (linear light times 2**ev, back to sRGB).

    The Debian wallpapers are JPEGs of 1.3 to 16 megapixels that are soft at full size;
    they are reduced (antialiased bilinear), which makes them sharp at the pixel level, as
    a ground truth for training pairs should be."""
    from lensim.sensor.isp import expose

    arr, _ = read_image(sample_image_path(name))
    img = _sample(name)
    if img.scale != 1.0:
        arr = F.interpolate(arr[None], scale_factor=img.scale, mode="bilinear", antialias=True, align_corners=False)[
            0
        ].clamp(0.0, 1.0)
    return expose(arr, img.exposure_ev)


def _installed(images: tuple[SampleImage, ...]) -> list[SampleImage]:
    out = []
    for img in images:
        base = _package_dir(img.package)
        if base is not None and (base / img.relative_path).is_file():
            out.append(img)
    return out


def available_sample_images() -> list[SampleImage]:
    """The training photos whose package is installed (never a test photo)."""
    return _installed(SAMPLE_IMAGES)


def unseen_photos() -> list[SampleImage]:
    """The unseen test photos whose package is installed (:data:`TEST_IMAGES`): for
    evaluation only; no default of lensim trains on them."""
    return _installed(TEST_IMAGES)


def write_centre_crops(images: list[SampleImage], folder: str | Path, size: int) -> list[Path]:
    """Write each photo centre-cropped to size x size (or its shorter side) as
    folder/<name>.png, once: a file already there is kept. Returns the paths in the order
    of ``images``."""
    from lensim.images import write_image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for img in images:
        target = folder / f"{img.name}.png"
        if not target.exists():
            arr = read_sample_image(img.name)
            _, h, w = arr.shape
            s = min(size, h, w)
            y, x = (h - s) // 2, (w - s) // 2
            write_image(target, arr[:, y : y + s, x : x + s])
        paths.append(target)
    return paths
