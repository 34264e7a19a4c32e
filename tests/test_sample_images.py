"""Built-in sample photos (lensim.assets.images): every listed photo that is installed
reads as an 8-bit sRGB image; a missing package only removes its photos."""
from __future__ import annotations

from pathlib import Path

import pytest

from lensim.assets import images
from lensim.assets.images import SAMPLE_IMAGES, available_sample_images, sample_image_path
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


def test_scaled_photos_are_resampled_and_exported(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """read_sample_image applies each photo's scale; `lensim assets --export-photos` writes
    every installed photo at that scale."""
    from lensim.assets.images import read_sample_image
    from cli_runner import run_cli

    have = available_sample_images()
    for img in have:
        if img.scale != 1.0:
            full, _ = read_image(sample_image_path(img.name))
            small = read_sample_image(img.name)
            assert small.shape[1] == round(full.shape[1] * img.scale) and small.shape[2] == round(full.shape[2] * img.scale)
            break
    code, out, err = run_cli(["assets", "--export-photos", str(tmp_path / "photos")], capsys, monkeypatch)
    assert code == 0, err
    files = sorted(p.stem for p in (tmp_path / "photos").glob("*.png"))
    assert files == sorted(i.name for i in have)
