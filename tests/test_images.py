"""Image I/O: bit depths, channels, refusals."""

import numpy as np
import pytest
import torch
from PIL import Image

from lensim.errors import InputError
from lensim.images import read_image, write_image


@pytest.mark.parametrize("suffix,bits", [(".png", 8), (".png", 16), (".tif", 8), (".tif", 16)])
def test_round_trip(tmp_path, suffix, bits):
    torch.manual_seed(0)
    img = torch.rand(3, 20, 33)
    p = tmp_path / f"x{suffix}"
    write_image(p, img, bits)
    back, b = read_image(p)
    assert b == bits
    assert back.shape == (3, 20, 33)
    assert (back - img).abs().max().item() <= 0.5 / (2**bits - 1) + 1e-6


def test_grayscale_is_expanded(tmp_path):
    p = tmp_path / "g.png"
    Image.fromarray(np.full((20, 20), 100, np.uint8), "L").save(p)
    img, bits = read_image(p)
    assert img.shape == (3, 20, 20) and bits == 8
    assert torch.allclose(img[0], img[2])


def test_opaque_alpha_dropped_transparent_refused(tmp_path):
    a = np.full((20, 20, 4), 255, np.uint8)
    Image.fromarray(a, "RGBA").save(tmp_path / "o.png")
    assert read_image(tmp_path / "o.png")[0].shape == (3, 20, 20)
    a[0, 0, 3] = 0
    Image.fromarray(a, "RGBA").save(tmp_path / "t.png")
    with pytest.raises(InputError, match=r"t\.png: alpha"):
        read_image(tmp_path / "t.png")


def test_bad_files_give_one_line_errors(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="cannot be decoded") as e:
        read_image(tmp_path / "bad.png")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="expected one of"):
        read_image(tmp_path / "x.bmp")
    import tifffile

    tifffile.imwrite(tmp_path / "f.tif", np.zeros((20, 20, 3), np.float32))
    with pytest.raises(InputError, match="bit depth"):
        read_image(tmp_path / "f.tif")
    tifffile.imwrite(tmp_path / "c.tif", np.zeros((20, 20, 5), np.uint8))
    with pytest.raises(InputError, match="channels"):
        read_image(tmp_path / "c.tif")


@pytest.mark.parametrize("bits", [8, 16])
def test_png_is_lossless_and_written_at_lensims_zlib_level(tmp_path, bits):
    """8- and 16-bit PNGs read back exactly, and their zlib stream says 'fast' (FLEVEL 1:
    levels 2-5), i.e. PNG_COMPRESS_LEVEL 3 and not zlib's default 6 (FLEVEL 2)."""
    import struct

    from lensim.images import PNG_COMPRESS_LEVEL, read_image, write_image

    img = torch.rand(3, 40, 56, generator=torch.Generator().manual_seed(4))
    path = tmp_path / f"x{bits}.png"
    write_image(path, img, bits=bits)
    top = 2**bits - 1
    back, depth = read_image(path)
    assert depth == bits and (back - img).abs().max().item() <= 0.5 / top + 1e-6  # the quantisation only
    data = path.read_bytes()
    at = data.index(b"IDAT")
    (length,) = struct.unpack(">I", data[at - 4 : at])
    flevel = data[at + 5] >> 6  # the zlib header's second byte
    assert length > 0 and PNG_COMPRESS_LEVEL == 3 and flevel == 1


@pytest.mark.parametrize("planes", [1, 2, 3, 4])
def test_16_bit_pngs_of_every_colour_type_read_exactly(tmp_path, planes):
    """16-bit PNGs written by pypng (an independent encoder): gray, gray + alpha, RGB and
    RGBA read back as their RGB samples (gray repeated, an opaque alpha dropped)."""
    import png

    from lensim.images import read_image

    rng = np.random.default_rng(planes)
    samples = rng.integers(0, 65536, (17, 19, planes), dtype=np.uint16)
    if planes in (2, 4):
        samples[..., -1] = 65535  # opaque
    path = tmp_path / f"p{planes}.png"
    with open(path, "wb") as fh:
        png.Writer(19, 17, greyscale=planes < 3, alpha=planes in (2, 4), bitdepth=16).write(
            fh, samples.reshape(17, 19 * planes)
        )
    img, bits = read_image(path)
    colour = samples[..., : 1 if planes < 3 else 3]
    expected = np.repeat(colour, 3 // colour.shape[2], axis=2).transpose(2, 0, 1) / 65535.0
    assert bits == 16 and np.allclose(img.numpy(), expected, rtol=0, atol=1e-7)
