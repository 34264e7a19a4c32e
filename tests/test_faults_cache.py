"""A corrupt cache entry is detected and recomputed: a bank field file that is truncated,
emptied or has a flipped byte, a bank cache's manifest that is not JSON, a dataset's photo
record that is garbage or whose crop is gone. The command that meets it recomputes what
it stood for and ends with the outputs of an uninterrupted run."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from fault_world import cli, differences, npz_arrays


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x5A
    path.write_bytes(bytes(data))


def empty(path: Path) -> None:
    path.write_bytes(b"")


def garbage(path: Path) -> None:
    path.write_bytes(b"\x00\x13garbage{" * 7)


DAMAGE: dict[str, Callable[[Path], None]] = {
    "truncated": truncate,
    "flipped byte": flip_a_byte,
    "empty": empty,
    "garbage": garbage,
}


def _quick(values: list, quick: set) -> list:
    """The values as parameters, those outside ``quick`` under -m slow (the default run keeps a few)."""
    return [
        v if v in quick else pytest.param(*(v if isinstance(v, tuple) else (v,)), marks=pytest.mark.slow)
        for v in values
    ]


@pytest.mark.parametrize("damage", _quick(list(DAMAGE), {"flipped byte"}))
def test_a_damaged_field_of_a_bank_is_recomputed(fault_world, tmp_path, damage):
    out = tmp_path / "bank"
    shutil.copytree(fault_world.bank, out)
    DAMAGE[damage](out / "field_0002.npz")
    assert cli(fault_world.args("bank", out)) == 0
    assert differences("bank", fault_world.bank, out) == []


@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    """A bank computed into a bank cache (as simulate and dataset make use it)."""
    import lensim
    from lensim.psf.bank import BankSettings, get_bank

    settings = BankSettings(fields=3, wavelengths_nm=[550.0], pupil_samples=32, cache_dir=tmp_path_factory.mktemp("c"))
    lens = lensim.load_lens("cooke_triplet")
    bank = get_bank(lens, 3.92, settings)
    return lens, settings, bank.directory, npz_arrays(bank.directory, "field_*.npz")


@pytest.mark.parametrize(
    ("entry", "damage"),
    _quick(
        [("field_0001.npz", d) for d in DAMAGE] + [("manifest.json", "garbage"), ("manifest.json", "truncated")],
        {("field_0001.npz", "truncated"), ("manifest.json", "garbage")},
    ),
)
def test_a_damaged_bank_cache_entry_is_recomputed(cached, entry, damage):
    import numpy as np

    from lensim.psf.bank import get_bank

    lens, settings, directory, reference = cached
    DAMAGE[damage](directory / entry)
    bank = get_bank(lens, 3.92, settings)
    assert bank.directory == directory
    got = npz_arrays(directory, "field_*.npz")
    assert list(got) == list(reference)
    for name, arrays in reference.items():
        for key, value in arrays.items():
            np.testing.assert_array_equal(got[name][key], value, err_msg=f"{name}:{key}")


@pytest.mark.parametrize(
    "damage",
    _quick(
        ["garbage record", "empty record", "truncated record", "crop gone", "empty crop", "truncated crop"],
        {"garbage record", "truncated crop"},
    ),
)
def test_a_damaged_photo_record_of_a_dataset_is_recomputed(fault_world, tmp_path, damage):
    out = tmp_path / "pairs"
    shutil.copytree(fault_world.pairs, out)
    record = out / "records" / "000001.json"
    crop = out / "pairs" / "000001_001_target.png"
    {
        "garbage record": lambda: garbage(record),
        "empty record": lambda: empty(record),
        "truncated record": lambda: truncate(record),
        "crop gone": crop.unlink,
        "empty crop": lambda: empty(crop),
        "truncated crop": lambda: truncate(crop),
    }[damage]()
    assert cli(fault_world.args("pairs", out)) == 0
    assert differences("pairs", fault_world.pairs, out) == []
