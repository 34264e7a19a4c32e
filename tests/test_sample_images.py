"""Built-in sample photos (lensim.assets.images): every listed photo that is installed
reads as an 8-bit sRGB image; a missing package only removes its photos; a photo's scale
resamples it as Pillow does, on an always-installed photo (and on Debian's wallpapers,
the scaled ones, where they are installed); the unseen test split shares nothing with the
training photos, covers its scene types, and its dark scenes are 3 stops under in linear
light."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from lensim.assets import images
from lensim.assets.images import (
    SAMPLE_IMAGES,
    TEST_IMAGES,
    available_sample_images,
    read_sample_image,
    sample_image_path,
    unseen_photos,
)
from lensim.errors import InputError
from lensim.images import read_image
from lensim.sensor.isp import srgb_to_linear


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


def test_export_writes_every_installed_photo_at_its_scale(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
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


@pytest.mark.skipif(
    not any(i.package.startswith("debian:") for i in available_sample_images()),
    reason="Debian's wallpapers are not installed (scripts/setup.sh installs them where it can)",
)
def test_debian_photos_are_reduced_at_their_scale() -> None:
    """The Debian wallpapers carry a scale below 1 and read at that scale, as Pillow reduces
    them (1e-5): one installed photo of each package."""
    debian = [i for i in SAMPLE_IMAGES if i.package.startswith("debian:")]
    assert len(debian) == 37 and all(0.2 <= i.scale < 1 for i in debian)
    seen = set()
    for img in available_sample_images():
        if not img.package.startswith("debian:") or img.package in seen:
            continue
        seen.add(img.package)
        full, _ = read_image(sample_image_path(img.name))
        np.testing.assert_allclose(
            read_sample_image(img.name).numpy(), _pillow_resized(full, img.scale), atol=1e-5, rtol=0
        )


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_unseen_split_is_disjoint_from_every_training_source() -> None:
    """No test photo is a training photo: names, (package, file) entries and, for every
    installed file, its content differ; the test photos come from packages that hold no
    training photo (scikit-learn, matplotlib) or from scikit-image files other than its
    training ones; no Debian wallpaper or sporco photo is a test photo; the training
    listing (what the demo and `--export-photos` use) never holds one."""
    train_names = {i.name for i in SAMPLE_IMAGES}
    assert not train_names & {i.name for i in TEST_IMAGES}
    assert not {(i.package, i.relative_path) for i in SAMPLE_IMAGES} & {
        (i.package, i.relative_path) for i in TEST_IMAGES
    }
    train_packages = {i.package for i in SAMPLE_IMAGES}
    assert {i.package for i in TEST_IMAGES} - train_packages == {"sklearn", "matplotlib"}
    assert {i.package for i in TEST_IMAGES} & train_packages == {"skimage"}
    assert not any(i.package.startswith("debian:") or i.package == "sporco" for i in TEST_IMAGES)
    train_files = {_digest(sample_image_path(i.name)) for i in available_sample_images()}
    assert not train_files & {_digest(sample_image_path(i.name)) for i in unseen_photos()}
    assert {i.name for i in available_sample_images()} <= train_names


def test_unseen_photos_are_installed_and_cover_the_scene_types() -> None:
    """scikit-learn (the test extra) and matplotlib are installed by scripts/setup.sh: all 11
    test photos exist, and they cover architecture, foliage, text, faces and dark scenes."""
    assert [i.name for i in unseen_photos()] == [i.name for i in TEST_IMAGES] and len(TEST_IMAGES) == 11
    contents = " ".join(i.content for i in TEST_IMAGES)
    for kind in ("architecture", "foliage", "text", "face", "dark"):
        assert kind in contents, kind
    for img in unseen_photos():
        arr = read_sample_image(img.name)
        assert arr.shape[0] == 3 and min(arr.shape[1:]) >= 128 and img.licence and img.credit


def test_dark_test_photos_are_three_stops_under_in_linear_light() -> None:
    """test-china-dark is test-china with its linear light divided by 8 (exposure -3 EV), to
    within the sRGB curve's round trip; its mean sRGB value is far below the original's."""
    bright, dark = read_sample_image("test-china"), read_sample_image("test-china-dark")
    assert bright.shape == dark.shape
    np.testing.assert_allclose(srgb_to_linear(dark).numpy(), srgb_to_linear(bright).numpy() / 8, atol=2e-6, rtol=1e-4)
    assert float(dark.mean()) < 0.45 * float(bright.mean())


def test_export_test_photos_keeps_them_apart(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--export-test-photos` writes the test photos only; the same folder as
    `--export-photos` is refused in one line, before anything is written."""
    from cli_runner import run_cli

    monkeypatch.setattr(images, "SAMPLE_IMAGES", (COFFEE,))
    monkeypatch.setattr(images, "TEST_IMAGES", tuple(i for i in TEST_IMAGES if i.name in ("test-text", "test-page")))
    code, out, err = run_cli(
        ["assets", "--export-photos", str(tmp_path / "a"), "--export-test-photos", str(tmp_path / "b")],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["coffee.png"]
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["test-page.png", "test-text.png"]
    code, out, err = run_cli(
        ["assets", "--export-photos", str(tmp_path / "c"), "--export-test-photos", str(tmp_path / "c")],
        capsys,
        monkeypatch,
    )
    assert code == 2 and "--export-test-photos" in err and not (tmp_path / "c").exists()
