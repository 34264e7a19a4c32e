"""Imaging simulation against the PSF bank (the issue's acceptance checks)."""

import math

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.evaluate.edge_target import make_slanted_edge
from lensim.evaluate.slanted_edge import mtf_area_ratio, mtf_from_psf, slanted_edge_mtf
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankSettings, get_bank, suggest_kernel_pixels
from lensim.render.kernels import check_bank_fits
from lensim.render.mapping import SensorMapping, map_to_sensor, native_mapping
from lensim.render.pipeline import blur_energy_image, simulate
from lensim.sensor.profile import load_sensor

PITCH = 3.92  # um, the APS-C sensor


@pytest.fixture(scope="module")
def bank():
    """Cooke triplet at the APS-C pitch: 7 fields, 3 wavelengths (a few seconds)."""
    lens = load_lens("cooke_triplet")
    p = suggest_kernel_pixels(lens, PITCH, limit=31)
    fields = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0)
    settings = BankSettings(fields=fields, wavelengths_nm=(500, 550, 600), pupil_samples=128, kernel_pixels=p)
    return get_bank(lens, PITCH, settings, memory_only=True)


def _ncc(a, b):
    a = np.asarray(a, np.float64) - np.mean(a)
    b = np.asarray(b, np.float64) - np.mean(b)
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def _crop_at(x_mm: float, y_mm: float, size: int) -> SensorMapping:
    """A size x size image centred on sensor point (x_mm, y_mm) at the bank pitch."""
    p = PITCH * 1e-3
    return SensorMapping(size, size, PITCH, x_mm - size * p / 2, y_mm - size * p / 2)


@pytest.mark.parametrize("field,azimuth", [(0.0, 0.0), (0.5, 30.0), (0.7, 135.0), (0.9, 250.0)])
def test_point_source_reproduces_the_bank_psf(bank, field, azimuth):
    # a single bright pixel at field h and azimuth: the blurred image equals the bank's
    # kernel there (NCC >= 0.99) and its energy equals the kernel's sum (RI) within 1 %
    r = field * float(bank.radii_mm[-1]) * 0.999
    x, y = r * math.cos(math.radians(azimuth)), r * math.sin(math.radians(azimuth))
    size = 96
    m = _crop_at(x, y, size)
    img = torch.zeros(3, size, size, dtype=torch.float64)
    img[:, size // 2, size // 2] = 1.0
    out = blur_energy_image(img, bank, m, tile=32).numpy()
    cx, cy = m.pixel_to_mm(torch.tensor(float(size // 2)), torch.tensor(float(size // 2)))
    k = bank.psf_at(float(cx), float(cy))
    p = k.shape[-1]
    win = out[:, size // 2 - p // 2 : size // 2 + p // 2 + 1, size // 2 - p // 2 : size // 2 + p // 2 + 1]
    for c in range(3):
        assert _ncc(win[c], k[c]) >= 0.99
        assert out[c].sum() == pytest.approx(k[c].sum(), rel=0.01)


def test_uniform_field_has_no_seams(bank):
    # a uniform energy image across the whole upper-right quadrant of the sensor: the
    # output divided by the local kernel sum (relative illumination) stays within 0.5 % of
    # 1 away from the borders, and no step between neighbouring pixels exceeds 1e-3
    sensor = load_sensor("apsc_mirrorless")
    h, w = 400, 600  # binned 10x: 39.2 um pixels would need another bank, so use a crop
    m = native_mapping(h, w, sensor, sensor.height // 2 - h, sensor.width // 2)
    img = torch.ones(3, h, w, dtype=torch.float64)
    out = blur_energy_image(img, bank, m, tile=64)
    rows = torch.arange(h, dtype=torch.float64)
    cols = torch.arange(w, dtype=torch.float64)
    # kernel sums along the image diagonal to normalize lens shading
    sums = np.array(
        [
            [bank.psf_at(*(float(v) for v in m.pixel_to_mm(r, c))).sum(axis=(-2, -1)) for c in cols[::50]]
            for r in rows[::50]
        ]
    )
    inner = out[:, 30:-30, 30:-30]
    assert inner.diff(dim=1).abs().max().item() < 1e-3
    assert inner.diff(dim=2).abs().max().item() < 1e-3
    ratio = out[:, ::50, ::50].numpy().transpose(1, 2, 0)[1:-1, 1:-1] / sums[1:-1, 1:-1]
    assert np.abs(ratio - 1.0).max() < 5e-3


@pytest.mark.parametrize("field", [0.0, 0.3, 0.5, 0.7, 0.9])
def test_slanted_edge_mtf_matches_the_bank(bank, field):
    # the paper's Table 1 criterion: MTF-area ratio (to Nyquist) of the slanted edge
    # measured on the simulated image vs the MTF of the bank's kernel: 0.97 - 1.03
    r = field * float(bank.radii_mm[-1])
    size = 96
    m = _crop_at(r, 0.0, size)
    edge = torch.from_numpy(make_slanted_edge(size, 5.0, 0.2, 0.8)).to(torch.float64)
    img = edge.unsqueeze(0).repeat(3, 1, 1)
    out = blur_energy_image(img, bank, m, tile=32)[1].numpy()
    measured = slanted_edge_mtf(out[8:-8, 8:-8])
    k = bank.psf_at(r, 0.0)[1]
    reference = mtf_from_psf(k, PITCH, 5.0, pixel_integrated=False, freq_cy_px=measured.freq_cy_px)
    assert 0.97 <= mtf_area_ratio(measured, reference, 0.5) <= 1.03


def test_simulate_is_deterministic_and_records_draws(bank):
    sensor = load_sensor("apsc_mirrorless")
    torch.manual_seed(0)
    img = torch.rand(3, 64, 96)
    m = native_mapping(64, 96, sensor, 100, 200)
    a, pa = simulate(img, bank, sensor, torch.Generator().manual_seed(7), mapping=m)
    b, pb = simulate(img, bank, sensor, torch.Generator().manual_seed(7), mapping=m)
    assert torch.equal(a, b) and pa.to_dict() == pb.to_dict()
    assert pa.shot is not None and pa.kelvin > 0
    c, _ = simulate(img, bank, sensor, torch.Generator().manual_seed(8), mapping=m)
    assert not torch.equal(a, c)


def test_wrong_pitch_and_uncovered_sensor_are_refused(bank):
    sensor = load_sensor("apsc_mirrorless")
    with pytest.raises(InputError, match="pixel_pitch_um"):
        check_bank_fits(bank, map_to_sensor(512, 768, sensor))
    full = load_sensor("fullframe_dslr")
    m = SensorMapping(4000, 6000, PITCH, -6000 * PITCH * 1e-3 / 2 * 1.6, -4000 * PITCH * 1e-3 / 2 * 1.6)
    with pytest.raises(InputError, match="fields"):
        check_bank_fits(bank, m)
    assert full.sensor_size_mm[0] > 35


def test_distortion_moves_points_from_paraxial_to_real_chief_ray_positions(bank):
    # a small blob whose paraxial image lies at field 0.9 lands where the real chief ray
    # of that field lands (Cooke: ~+5 um at 12.6 mm): centroid within 0.05 px of it
    from lensim.render.distortion import apply_distortion

    f = bank.fields[5]  # field 0.9
    r_par, r_real = float(np.hypot(*f.paraxial_xy_mm)), float(np.hypot(*f.reference_xy_mm))
    size = 64
    m = _crop_at(r_par, 0.0, size)
    yy, xx = torch.meshgrid(
        torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64), indexing="ij"
    )
    x, y = m.pixel_to_mm(yy, xx)
    blob = torch.exp(-((x - r_par) ** 2 + y**2) / (2 * (2 * PITCH * 1e-3) ** 2))
    out = apply_distortion(blob.unsqueeze(0), bank, m)[0]
    cx = float((out * x).sum() / out.sum())
    assert abs(cx - r_real) < 0.05 * PITCH * 1e-3
    assert abs(r_real - r_par) > 0.5 * PITCH * 1e-3  # the test would notice a missing warp
