"""lensim.png_encode: the multithreaded PNG encoder behind lensim.images.write_image,
checked with independent decoders (Pillow, pypng, OpenCV)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from lensim import png_encode


@pytest.fixture
def small_blocks(monkeypatch):
    monkeypatch.setattr(png_encode, "BLOCK_BYTES", 1000)  # many deflate blocks on a small image


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 37, 3), (29, 1, 3), (61, 83, 3)])
def test_8_bit_frames_decode_exactly_with_pillow_and_opencv(shape, small_blocks):
    import cv2
    from PIL import Image

    rng = np.random.default_rng(sum(shape))
    q = rng.integers(0, 256, shape, dtype=np.uint8)
    data = png_encode.encode_png(q, threads=3)
    with Image.open(io.BytesIO(data)) as im:
        assert im.mode == "RGB" and np.array_equal(np.asarray(im), q)
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(bgr[..., ::-1].reshape(shape), q)


def test_16_bit_frames_decode_exactly_with_pypng(small_blocks):
    import png

    q = np.random.default_rng(1).integers(0, 65536, (23, 41, 3), dtype=np.uint16)
    w, h, rows, info = png.Reader(bytes=png_encode.encode_png(q, threads=2)).asDirect()
    assert (w, h, info["bitdepth"], info["planes"]) == (41, 23, 16, 3)
    assert np.array_equal(np.vstack([np.asarray(r, np.uint16) for r in rows]).reshape(q.shape), q)


def test_the_bytes_do_not_depend_on_the_thread_count(small_blocks):
    q = np.random.default_rng(2).integers(0, 256, (50, 70, 3), dtype=np.uint8)
    one = png_encode.encode_png(q, threads=1)
    assert len(range(0, 50 * (1 + 70 * 3), png_encode.BLOCK_BYTES)) > 5
    assert png_encode.encode_png(q, threads=4) == one


def test_the_srgb_chunk_is_read_as_perceptual_srgb():
    from PIL import Image

    q = np.zeros((4, 4, 3), np.uint8)
    with Image.open(io.BytesIO(png_encode.encode_png(q, srgb=True))) as im:
        assert im.info.get("srgb") == 0
    with Image.open(io.BytesIO(png_encode.encode_png(q))) as im:
        assert "srgb" not in im.info


def test_smooth_photos_compress_and_other_inputs_are_refused():
    ramp = np.broadcast_to(np.arange(256, dtype=np.uint8)[None, :, None], (64, 256, 3)).copy()
    assert len(png_encode.encode_png(ramp)) < ramp.nbytes / 20  # Up-filtered rows of a ramp are zeros
    for bad in (np.zeros((4, 4), np.uint8), np.zeros((4, 4, 4), np.uint8), np.zeros((4, 4, 3), np.float32)):
        with pytest.raises(ValueError, match="expected"):
            png_encode.encode_png(bad)
