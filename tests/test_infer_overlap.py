"""The tile overlap each network is restored with by default (lensim.restore.infer
.default_overlap): NAFNet's plain layouts 96 px, everything else the UNet's 192 px, and
NAFNet's tiles at 96 px agreeing with whole-image inference to float32 rounding."""

from __future__ import annotations

import pytest
import torch

from lensim.restore.infer import DEFAULT_OVERLAP, TorchEngine, default_overlap, restore_image
from lensim.restore.models import build_model


def _perturbed(config: dict) -> torch.nn.Module:
    """A network of this config with every weight moved off its initialisation (the
    zero-initialised tail would make the untrained network the identity)."""
    torch.manual_seed(0)
    model = build_model(config).eval()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model


def test_default_overlap_per_architecture() -> None:
    assert default_overlap(build_model({"arch": "nafnet"})) == 96
    assert default_overlap(build_model({"arch": "nafnet", "stem": 2, "width": 8})) == 96
    for wider in ({"use_context": True}, {"sca_window": 5}, {"enc_blocks": [1, 1, 1], "dec_blocks": [1, 1, 1]}):
        assert default_overlap(build_model({"arch": "nafnet", "width": 8, **wider})) == DEFAULT_OVERLAP
    unet = build_model({"arch": "unet"})
    assert default_overlap(unet) == DEFAULT_OVERLAP == 192
    assert TorchEngine(build_model({"arch": "nafnet"})).tile_overlap == 96
    assert default_overlap(object()) == DEFAULT_OVERLAP


@pytest.mark.parametrize(
    "config",
    [
        {"arch": "nafnet", "width": 16, "use_fov": True},
        {"arch": "nafnet", "width": 24, "use_fov": True, "stem": 2},
        {"arch": "nafnet", "width": 16, "stem": 2, "enc_blocks": [2, 2], "dec_blocks": [2, 2], "middle_blocks": 4},
    ],
)
def test_nafnet_tiles_at_its_default_overlap_equal_the_whole_image(config: dict) -> None:
    torch.set_num_threads(1)
    model = _perturbed(config)
    gen = torch.Generator().manual_seed(1)
    image = torch.rand(3, 264, 392, generator=gen)
    geometry = ((100.0, 60.0), (600.0, 800.0))
    whole = restore_image(model, image, *geometry, tile=512, overlap=0)
    tiled = restore_image(model, image, *geometry, tile=160)  # the default overlap: 96 px
    assert float((tiled - whole).abs().max()) < 1e-5 * max(1.0, float(whole.abs().max()))
    cut = restore_image(model, image, *geometry, tile=160, overlap=16)  # a margin inside the field
    assert float((cut - whole).abs().max()) > 1e-4  # the comparison can fail
