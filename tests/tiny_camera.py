"""A tiny camera for restoration tests (shared by the test modules): two sample photos cut
to 128 x 96 pixels, a 128 x 96 pixel sensor at the APS-C profile's pitch, and a coarse
Cooke-triplet bank at that pitch."""

import json
from pathlib import Path

from lensim.assets.images import sample_image_path
from lensim.images import read_image, write_image
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, PSFBank, get_bank
from lensim.sensor.profile import SensorProfile, load_sensor, sensor_from_dict


def tiny_camera(base: Path) -> tuple[Path, Path, SensorProfile, PSFBank]:
    """(folder of sharp photos, sensor file, sensor, bank), all written below base."""
    sharp = base / "sharp"
    for name in ("kodim23", "coffee"):
        img, _ = read_image(sample_image_path(name))
        write_image(sharp / f"{name}.png", img[:, 100:196, 100:228])
    d = load_sensor("apsc_mirrorless").to_dict()
    d["resolution"] = [128, 96]
    d["name"] = "tiny"
    sensor_file = base / "tiny_sensor.json"
    sensor_file.write_text(json.dumps(d))
    sensor = sensor_from_dict(d, str(sensor_file))
    settings = BankSettings(fields=(0.0, 0.5, 1.0), wavelengths_nm=(500, 600), pupil_samples=64, kernel_pixels=21)
    bank = get_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, settings, out_dir=base / "bank")
    return sharp, sensor_file, sensor, bank
