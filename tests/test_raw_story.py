"""The user story of docs/raw.md, for someone with only a lens file and their camera's raw
files: `lensim sensor from-raw` -> `lensim dataset make --sensor` -> `lensim train` ->
`lensim restore` on the raw files, at small sizes. The camera's raw files are written with
pidng (an independent DNG writer, tests/raw_fixtures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from cli_runner import run_cli
from lensim.images import write_image
from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
from lensim.restore.network import FieldAwareUNet
from lensim.sensor.profile import load_sensor

pytest.importorskip("rawpy")
raw_fixtures = pytest.importorskip("raw_fixtures")

PITCH_UM = "40"  # a 192 x 128 sensor at 40 um spans 7.7 x 5.1 mm: inside the Cooke triplet's image circle


def camera_raw(
    path: Path, seed: int, make: str = "Acme", model: str = "Z1", size: tuple[int, int] = (128, 192)
) -> Path:
    """A raw file as the camera would write it: a smooth scene's mosaic, 14-bit, black 512."""
    g = np.random.default_rng(seed)
    coarse = g.uniform(0.1, 0.8, (size[0] // 16, size[1] // 16))
    scene = np.kron(coarse, np.ones((16, 16)))
    dn = np.round(512 + scene * (16383 - 512)).astype(np.uint16)
    path.parent.mkdir(parents=True, exist_ok=True)
    return raw_fixtures.write_dng(
        path,
        dn,
        "RGGB",
        make=make,
        model=model,
        wb_gains=(2.1, 1.5),
        exif={"iso": 200, "exposure_s": 0.01, "fno": 4.0, "focal_length_mm": 50.0},
    )


def test_profile_from_raw_restores_that_cameras_raws(tmp_path: Path, capsys, monkeypatch):
    """The small story: a profile made from the camera's raw is the sensor a checkpoint
    records; that camera's raws restore natively, another camera's are refused."""
    shot = camera_raw(tmp_path / "raws" / "IMG_0001.dng", 0)
    code, _, err = run_cli(
        ["sensor", "from-raw", str(shot), "--pixel-um", PITCH_UM, "-o", str(tmp_path / "cam.yaml")], capsys, monkeypatch
    )
    assert code == 0, err
    sensor = load_sensor(tmp_path / "cam.yaml")
    torch.manual_seed(0)
    model = FieldAwareUNet(8, 2).eval()
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": sensor.to_dict(),
            "lens": None,
        },
        tmp_path / "run" / "last.pt",
    )
    code, out, err = run_cli(
        [
            "restore",
            str(tmp_path / "run"),
            str(tmp_path / "raws"),
            "-o",
            str(tmp_path / "out"),
            "--dng",
            "--json",
            "--quiet",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert '"native": true' in out
    assert (tmp_path / "out" / "IMG_0001.tif").is_file() and (tmp_path / "out" / "IMG_0001.dng").is_file()
    other = camera_raw(tmp_path / "other" / "DSC_1.dng", 1, make="Other", model="Cam")
    code, _, err = run_cli(
        ["restore", str(tmp_path / "run"), str(other), "-o", str(tmp_path / "out2")], capsys, monkeypatch
    )
    assert code == 2 and "Other Cam 192x128" in err and "Acme Z1 192x128" in err


@pytest.mark.slow
def test_the_whole_story_at_small_sizes(tmp_path: Path, capsys, monkeypatch):
    """sensor from-raw -> dataset make --sensor -> train -> restore, each a command."""
    shots = [camera_raw(tmp_path / "raws" / f"IMG_{k:04d}.dng", k) for k in range(2)]
    photos = tmp_path / "photos"
    for k in range(3):  # sharp photos to train on (smooth random scenes)
        coarse = torch.rand(1, 3, 6, 6, generator=torch.Generator().manual_seed(10 + k))
        write_image(
            photos / f"p{k}.png",
            torch.nn.functional.interpolate(coarse, size=(96, 96), mode="bicubic", align_corners=False)[0].clamp(0, 1),
        )
    steps = [
        ["sensor", "from-raw", str(shots[0]), "--pixel-um", PITCH_UM, "-o", str(tmp_path / "cam.yaml")],
        [
            "dataset",
            "make",
            str(photos),
            "-o",
            str(tmp_path / "data"),
            "--sensor",
            str(tmp_path / "cam.yaml"),
            "--lens",
            "cooke_triplet",
            "--crops",
            "2",
            "--size",
            "48",
            "--placements",
            "2",
            "--fields",
            "3",
            "--wavelengths-nm",
            "500,600",
            "--pupil-samples",
            "32",
            "--cache",
            str(tmp_path / "cache"),
            "--quiet",
        ],
        [
            "train",
            str(tmp_path / "data"),
            "-o",
            str(tmp_path / "run"),
            "--epochs",
            "1",
            "--width",
            "8",
            "--depth",
            "2",
            "--crop",
            "32",
            "--batch-size",
            "2",
            "--steps-per-epoch",
            "2",
            "--quiet",
        ],
        ["restore", str(tmp_path / "run"), str(tmp_path / "raws"), "-o", str(tmp_path / "out"), "--dng", "--quiet"],
    ]
    for args in steps:
        code, _, err = run_cli(args, capsys, monkeypatch)
        assert code == 0, f"{args[:2]}: {err}"
    import rawpy

    for shot in shots:
        assert (tmp_path / "out" / f"{shot.stem}.tif").is_file()
        with rawpy.imread(str(tmp_path / "out" / f"{shot.stem}.dng")) as lin, rawpy.imread(str(shot)) as orig:
            assert lin.raw_image.shape[:2] == orig.raw_image_visible.shape
            np.testing.assert_allclose(lin.camera_whitebalance[:3], orig.camera_whitebalance[:3], rtol=1e-6)
            assert lin.other.iso_speed == orig.other.iso_speed == 200
