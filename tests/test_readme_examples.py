"""The README's Python examples run as written (slow: the second one trains and runs the
quick demo). The examples read `photo.png` and the folder `photos/`, which the test fills
with built-in sample photos; everything else they use is created by the examples."""
from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from lensim.assets.images import available_sample_images, read_sample_image
from lensim.images import write_image

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_has_the_api_examples() -> None:
    blocks = python_blocks()
    assert len(blocks) >= 2
    text = "\n".join(blocks)
    for name in ("load_lens", "compute_psf", "simulate", "make_dataset", "train", "restore_image",
                 "evaluate_methods", "run_demo"):
        assert name in text, name


@pytest.mark.slow
def test_readme_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    images = available_sample_images()[:4]
    crop = lambda img: img[:, :256, :256]  # noqa: E731
    write_image(tmp_path / "photo.png", crop(read_sample_image(images[0].name)))
    (tmp_path / "photos").mkdir()
    for img in images:
        write_image(tmp_path / "photos" / f"{img.name}.png", crop(read_sample_image(img.name)))
    namespace: dict = {}
    for block in python_blocks():
        exec(compile(block, str(README), "exec"), namespace)
    assert (tmp_path / "restored.png").is_file()
    assert math.isfinite(namespace["summary"]["methods"]["model"]["psnr_db"])
    assert (tmp_path / "demo" / "report.html").is_file()
