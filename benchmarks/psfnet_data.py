"""Stage 1 of benchmarks/psfnet_demo.py: the demo's data, cached in OUT (a rerun skips what
exists; each step is resumable).

    .venv/bin/python benchmarks/psfnet_data.py OUT

OUT/bank: the demo's PSF bank (lensim.demo.DemoSettings.make(False): Cooke triplet on the
default sensor, 12 fields, 13 wavelengths, 128 pupil samples, kernels up to 41 px);
OUT/photos: the demo's photos (every built-in sample photo, centre-cropped to 512 px);
OUT/photos-test: the 11 unseen test photos (lensim.assets.images.TEST_IMAGES) cropped alike;
OUT/pairs, OUT/pairs-test: pairs made as `lensim demo` makes them (3 placements x 4 crops of
128 px, seed 0).
"""

from __future__ import annotations

import sys
from pathlib import Path


def main(out: Path) -> None:
    from lensim.assets import DEFAULT_LENS
    from lensim.assets.images import read_sample_image, unseen_photos
    from lensim.data.pairs import make_dataset
    from lensim.demo import DemoSettings, _photos
    from lensim.images import write_image
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.sensor.profile import DEFAULT_SENSOR, load_sensor

    s = DemoSettings.make(quick=False)
    lens, sensor = load_lens(DEFAULT_LENS), load_sensor(DEFAULT_SENSOR)
    settings = BankSettings(
        fields=s.fields, wavelengths_nm=s.wavelengths_nm, pupil_samples=s.pupil_samples, kernel_limit=41
    )
    bank = get_bank(
        lens, sensor.pixel_pitch_um, settings, response=sensor.spectral_response, workers=1, out_dir=out / "bank"
    )
    photos = _photos(out, s.photo_size)
    test = out / "photos-test"
    test.mkdir(parents=True, exist_ok=True)
    for img in unseen_photos():
        target = test / f"{img.name}.png"
        if not target.exists():
            arr = read_sample_image(img.name)
            _, h, w = arr.shape
            side = min(s.photo_size, h, w)
            y, x = (h - side) // 2, (w - side) // 2
            write_image(target, arr[:, y : y + side, x : x + side])
    for src, dst in ((photos, out / "pairs"), (test, out / "pairs-test")):
        make_dataset(
            src,
            dst,
            bank,
            DEFAULT_SENSOR,
            sensor,
            crops=s.crops,
            size=s.crop_size,
            seed=0,
            placements=s.placements,
            workers=1,
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]))
