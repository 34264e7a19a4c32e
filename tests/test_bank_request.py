"""The one way to get banks (lensim.psf.bank.get_bank, get_banks): many requests in one
run, the cache, refusals; the lens that goes with a bank (bank_lens) at the library level
and as `simulate --bank --lens` names it; the lens at shooting settings with its record."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from cli_runner import run_cli
from lensim.errors import InputError
from lensim.optics.lens_file import load_lens
from lensim.optics.shooting import ShootingSettings, describe, lens_and_record, lens_at, record
from lensim.psf.bank import BankRequest, BankSettings, GridAxes, GridBank, PSFBank, bank_lens, get_bank, get_banks

PITCH = 5.0
SETTINGS = BankSettings(fields=2, wavelengths_nm=(550.0,), pupil_samples=32, kernel_pixels=15)


@pytest.fixture(scope="module")
def lens():
    return load_lens("cooke_triplet")


def _same(a: PSFBank, b: PSFBank) -> None:
    assert len(a.fields) == len(b.fields)
    for fa, fb in zip(a.fields, b.fields, strict=True):
        assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.primary_fine, fb.primary_fine)


@pytest.fixture(scope="module")
def batch(lens, tmp_path_factory):
    """Three requests in one run (a cached bank, the same bank again, a grid of two
    settings in a folder), with the progress calls."""
    base = tmp_path_factory.mktemp("batch")
    cached = BankSettings(fields=2, wavelengths_nm=(550.0,), pupil_samples=32, kernel_pixels=15, cache_dir=base)
    requests = [
        BankRequest(lens, PITCH, cached),
        BankRequest(lens, PITCH, cached),
        BankRequest(lens, PITCH, SETTINGS, shooting=GridAxes(fno=(5.6, 8.0)), out_dir=base / "grid"),
    ]
    calls: list[tuple[int, int]] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        banks = get_banks(requests, progress=lambda d, t: calls.append((d, t)))
    return base, requests, banks, calls


def test_many_requests_run_as_one_list_of_fields_each_folder_once(batch, lens):
    base, _, (one, again, grid), calls = batch
    # 2 fields of the bank (asked twice, computed once) + 2 settings x 2 fields of the grid
    assert calls[0] == (0, 6) and calls[-1] == (6, 6) and len(calls) == 7
    assert isinstance(one, PSFBank) and isinstance(grid, GridBank) and len(grid) == 2
    assert one.directory == again.directory and one.directory.parent == base
    assert one.directory.name.startswith("bank-")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _same(one, get_bank(lens, PITCH, SETTINGS, memory_only=True))
        _same(grid.bank(1), get_bank(lens, PITCH, SETTINGS, shooting=ShootingSettings(fno=8.0), memory_only=True))


def test_a_complete_bank_is_loaded_from_its_folder(batch):
    _, requests, (one, _, grid), _ = batch
    calls: list[tuple[int, int]] = []
    again, grid_again = get_banks([requests[0], requests[2]], progress=lambda d, t: calls.append((d, t)))
    assert calls == [(6, 6)]  # every field on disk: nothing computed
    assert again.directory == one.directory and grid_again.directory == grid.directory
    _same(again, one)


def test_a_single_setting_bank_records_its_setting(lens, tmp_path):
    shot = ShootingSettings(fno=8.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bank = get_bank(lens, PITCH, SETTINGS, shooting=shot, out_dir=tmp_path / "b")
    assert bank.manifest["shooting"] == {"request": shot.to_dict(), "resolved": record(describe(lens, shot))}
    assert bank.manifest["lens"]["aperture"]["type"] == "stop_semi_diameter"  # the lens at F/8


def test_bad_requests_are_refused_before_any_work(lens, tmp_path):
    axes = GridAxes(fno=(5.6, 8.0))
    cases = [
        ([BankRequest(lens, PITCH, SETTINGS, shooting=axes, memory_only=True)], "memory_only"),
        ([BankRequest(lens, PITCH, SETTINGS, out_dir=tmp_path / "x", memory_only=True)], "out_dir"),
        ([BankRequest(lens, 0.0, SETTINGS, memory_only=True)], "pixel_pitch_um"),
        ([BankRequest(lens, PITCH, SETTINGS, shooting=GridAxes(), out_dir=tmp_path / "g")], "shooting"),
        (
            [
                BankRequest(lens, PITCH, SETTINGS, out_dir=tmp_path / "same"),
                BankRequest(lens, 4.0, SETTINGS, out_dir=tmp_path / "same"),
            ],
            "requests 0 and 1 ask for different banks",
        ),
    ]
    for requests, needle in cases:
        with pytest.raises(InputError, match=needle) as e:
            get_banks(requests)
        assert "--" not in str(e.value)  # the library names parameters, not command-line options
    with pytest.raises(InputError, match="workers"):
        get_banks([BankRequest(lens, PITCH, SETTINGS, memory_only=True)], workers=0)
    assert not any(tmp_path.iterdir())  # nothing written


def test_bank_settings_take_the_psf_options_and_explicit_fields():
    s = BankSettings(fields=(0.0, 0.3, 1.0), method="fft", max_spacing_um=1.0, illuminant="D65")
    assert list(s.field_positions()) == [0.0, 0.3, 1.0] and s.method == "fft"
    assert BankSettings(fields=3, field_spacing="linear").key_options()["fields"] == [0.0, 0.5, 1.0]
    # the options joined later enter a cache key only when set, so earlier caches keep their folders
    assert "method" not in BankSettings().key_options() and s.key_options()["illuminant"] == "D65"
    for kw, field in (
        ({"method": "ray"}, "method"),
        ({"max_spacing_um": 0.0}, "max_spacing_um"),
        ({"ri_samples": 0}, "ri_samples"),
        ({"fields": ()}, "fields"),
        ({"fields": (0.2, 0.1)}, "fields"),
    ):
        with pytest.raises(InputError) as e:
            BankSettings(**kw)
        assert e.value.field == field


def test_bank_lens_gives_or_checks_the_lens_of_a_bank(batch, lens):
    _, _, (one, _, grid), _ = batch
    assert bank_lens(one).name == lens.name and bank_lens(one, lens) is lens
    assert bank_lens(grid, lens) is lens
    other = load_lens("double_gauss")
    for bank in (one, grid):
        with pytest.raises(InputError) as e:
            bank_lens(bank, other)
        assert e.value.field == "lens" and "not the lens the bank" in e.value.message and "--" not in str(e.value)
    # a lens at other settings is another lens
    with pytest.raises(InputError, match="not the lens the bank"):
        bank_lens(one, lens_at(lens, ShootingSettings(fno=8.0)))
    stripped = PSFBank({k: v for k, v in one.manifest.items() if k != "lens"}, one.fields, one.directory)
    with pytest.raises(InputError, match="records no lens") as e:
        bank_lens(stripped)
    assert e.value.field == "lens"


def test_simulate_names_the_lens_option_for_a_bank_of_another_lens(batch, tmp_path, capsys, monkeypatch):
    import torch

    from lensim.images import write_image

    _, _, (one, _, _), _ = batch
    write_image(tmp_path / "x.png", torch.rand(3, 32, 48), 8)
    args = ["simulate", str(tmp_path / "x.png"), "--bank", str(one.directory), "-o", str(tmp_path / "s")]
    code, _, err = run_cli([*args, "--lens", "double_gauss"], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: --lens: double_gauss: not the lens the bank") and "or no --lens" in err, err
    assert not (tmp_path / "s").exists()


def test_lens_and_record_sets_the_lens_and_records_the_settings(lens):
    assert lens_and_record(lens, None) == (lens, None)
    assert lens_and_record(lens, ShootingSettings()) == (lens, None)
    shot = ShootingSettings(fno=8.0, focus_m=2.0)
    at, described = lens_and_record(lens, shot)
    assert at == lens_at(lens, shot) and described == record(describe(lens, shot))
    assert (
        described["fno"] == pytest.approx(8.0) and described["focus_m"] == 2.0 and not math.isinf(described["object_m"])
    )
