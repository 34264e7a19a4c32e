"""Built-in sample photos (lensim.assets.images): every listed photo that is installed
reads as an 8-bit sRGB image; a missing package only removes its photos; a photo's scale
resamples it as Pillow does, on an always-installed photo (and on Debian's wallpapers,
the scaled ones, where they are installed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from lensim.assets import images
from lensim.assets.images import SAMPLE_IMAGES, available_sample_images, read_sample_image, sample_image_path
from lensim.errors import InputError
from lensim.images import read_image


def test_python_package_photos_are_installed_by_setup() -> None:
    """scikit-image and sporco are installed by scripts/setup.sh: their 8 photos exist."""
    have = {i.name for i in available_sample_images()}
    python_photos = {i.name for i in SAMPLE_IMAGES if not i.package.startswith("debian:")}
    assert len(python_photos) == 8 and python_photos <= have


@pytest.mark.parametrize("img", available_sample_images(), ids=lambda i: i.name)
def test_installed_photos_read_as_rgb(img: images.SampleImage) -> None:
    arr, bits = read_image(sample_image_path(img.name))
    assert arr.shape[0] == 3 and min(arr.shape[1:]) >= 300 and bits == 8
    assert img.licence and img.credit


def test_missing_debian_package_drops_its_photos(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(images.DEBIAN_ROOTS, "mate-backgrounds", tmp_path / "absent")
    names = {i.name for i in available_sample_images()}
    assert not any(n.startswith("mate-") for n in names) and "kodim23" in names
    with pytest.raises(InputError, match="mate-backgrounds"):
        sample_image_path("mate-wood")


def test_unknown_photo_names_the_choices() -> None:
    with pytest.raises(InputError, match="expected one of .*kodim23"):
        sample_image_path("no-such-photo")


def _pillow_resized(img: torch.Tensor, scale: float) -> np.ndarray:
    """(3, H, W) resampled by Pillow (float mode, BILINEAR: a triangle filter widened by
    1/scale when reducing, the antialiasing torch's bilinear mode copies), (3, h, w)."""
    h, w = round(img.shape[1] * scale), round(img.shape[2] * scale)
    return np.stack([np.asarray(Image.fromarray(c.numpy(), mode="F").resize((w, h), Image.BILINEAR)) for c in img])


# an always-installed photo (scikit-image's coffee, 400 x 600) listed a second time at half scale
COFFEE = next(i for i in SAMPLE_IMAGES if i.name == "coffee")
HALF_COFFEE = images.SampleImage("half-coffee", "skimage", "data/coffee.png", "CC0", "test entry", scale=0.5)


def test_scaled_photo_is_resampled_as_pillow_does(monkeypatch: pytest.MonkeyPatch) -> None:
    """read_sample_image applies the photo's scale: the 400 x 600 file becomes 200 x 300,
    equal to Pillow's antialiased bilinear reduction (1e-5); scale 1 reads the file as is."""
    monkeypatch.setattr(images, "SAMPLE_IMAGES", (*SAMPLE_IMAGES, HALF_COFFEE))
    full, _ = read_image(sample_image_path("coffee"))
    assert tuple(full.shape) == (3, 400, 600)
    assert torch.equal(read_sample_image("coffee"), full)
    half = read_sample_image("half-coffee")
    assert tuple(half.shape) == (3, 200, 300)
    np.testing.assert_allclose(half.numpy(), _pillow_resized(full, 0.5), atol=1e-5, rtol=0)


def test_export_writes_every_installed_photo_at_its_scale(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """`lensim assets --export-photos` writes one 8-bit PNG per installed photo, at its scale
    (to within 8-bit rounding of read_sample_image), and none for a missing one."""
    from cli_runner import run_cli

    missing = images.SampleImage("absent", "skimage", "data/no-such-photo.png", "CC0", "test entry")
    monkeypatch.setattr(images, "SAMPLE_IMAGES", (COFFEE, HALF_COFFEE, missing))
    code, out, err = run_cli(["assets", "--export-photos", str(tmp_path / "photos")], capsys, monkeypatch)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "photos").iterdir()) == ["coffee.png", "half-coffee.png"]
    for name in ("coffee", "half-coffee"):
        written, bits = read_image(tmp_path / "photos" / f"{name}.png")
        assert bits == 8
        np.testing.assert_allclose(written.numpy(), read_sample_image(name).numpy(), atol=0.5 / 255 + 1e-6, rtol=0)


@pytest.mark.skipif(not any(i.package.startswith("debian:") for i in available_sample_images()),
                    reason="Debian's mate-backgrounds is not installed (scripts/setup.sh installs it where it can)")
def test_debian_photos_are_halved() -> None:
    """The Debian wallpapers carry scale 0.5 and read at half their file size, as Pillow
    reduces them (1e-5)."""
    debian = [i for i in SAMPLE_IMAGES if i.package.startswith("debian:")]
    assert debian and all(i.scale == 0.5 for i in debian)
    img = next(i for i in available_sample_images() if i.package.startswith("debian:"))
    full, _ = read_image(sample_image_path(img.name))
    np.testing.assert_allclose(read_sample_image(img.name).numpy(), _pillow_resized(full, 0.5), atol=1e-5, rtol=0)
