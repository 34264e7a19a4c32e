"""lensim's on-disk cache of opticalglass data (lensim.optics.glass_cache): each
catalogue's glass names (a glass that is not an exact vendor name searches every
catalogue's names, which without the cache means loading all six catalogues in every
process) and each catalogue glass's indices (so that a lens whose indices are cached never
imports opticalglass)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import lensim.optics.materials as materials
from lensim.optics import glass_cache


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()
    yield glass_cache.cache_dir()
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()


def test_names_are_cached_per_catalogue_and_read_back_without_loading(fresh_cache, monkeypatch):
    glass, note = materials.resolve_glass("SK16")  # no exact name: every catalogue's names searched
    assert glass.name == "N-SK16" and glass.catalog == "Schott" and "family" in note
    files = sorted((fresh_cache / "names").glob("*.json"))
    assert [f.stem for f in files] == sorted(materials.CATALOGS)
    assert "N-SK16" in json.loads((fresh_cache / "names" / "Schott.json").read_text())
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()

    def no_loading(catalog: str) -> list[str]:
        raise AssertionError(f"{catalog} loaded although its names are cached")

    monkeypatch.setattr(materials, "_load_catalog_names", no_loading)
    again, _ = materials.resolve_glass("SK16")
    assert (again.name, again.catalog) == ("N-SK16", "Schott")
    assert again.index(0.5875618) == pytest.approx(glass.index(0.5875618), abs=0)


def test_a_damaged_or_unwritable_cache_loads_the_names_again(fresh_cache, monkeypatch):
    materials.resolve_glass("N-BK7")
    schott = fresh_cache / "names" / "Schott.json"
    schott.write_text("{not json")
    materials._catalog_names.cache_clear()
    assert "NBK7" in materials._catalog_names("Schott")  # loaded again, and the file repaired
    assert "N-BK7" in json.loads(schott.read_text())
    materials._catalog_names.cache_clear()
    blocked = fresh_cache.parent / "file"
    blocked.write_text("a file where the cache folder would be")
    monkeypatch.setattr(glass_cache, "cache_dir", lambda: blocked)
    assert "NBK7" in materials._catalog_names("Schott")  # nothing written, no error


def test_cached_indices_equal_opticalglass_bit_for_bit(fresh_cache):
    from opticalglass import glassfactory

    lam_um = np.array([[0.4861327, 0.5875618], [0.6562725, 0.4861327]])
    medium = glassfactory.create_glass("N-SK16", "Schott")
    truth = np.asarray(medium.calc_rindex(lam_um * 1000.0), dtype=np.float64)
    first = materials.CatalogGlass("N-SK16", "Schott").index(lam_um)  # computed, then cached
    stored = json.loads((fresh_cache / "index" / "Schott" / "N-SK16.json").read_text())
    assert len(stored) == 3  # the distinct wavelengths only
    again = materials.CatalogGlass("N-SK16", "Schott")  # a fresh glass reads the file
    again._rindex = None  # type: ignore[assignment]  (would fail if anything were computed)
    for got in (first, again.index(lam_um)):
        assert got.shape == lam_um.shape and np.array_equal(got, truth)
    assert again.index(0.5875618) == truth[0, 1]  # a scalar wavelength


def test_a_long_wavelength_array_is_computed_not_cached(fresh_cache, monkeypatch):
    lam_um = np.linspace(0.4, 0.7, glass_cache.MAX_CACHED_WAVELENGTHS + 1)
    glass = materials.CatalogGlass("N-BK7", "Schott")
    n = glass.index(lam_um)
    assert n.shape == lam_um.shape and np.all(np.diff(n) < 0)  # normal dispersion
    path = fresh_cache / "index" / "Schott" / "N-BK7.json"
    assert not path.exists()
    monkeypatch.setattr(glass_cache, "MAX_ENTRIES", 3)  # a full cache computes new wavelengths, adds none
    assert np.array_equal(glass.index(lam_um[:3]), n[:3]) and len(json.loads(path.read_text())) == 3
    assert np.array_equal(glass.index(lam_um[2:5]), n[2:5]) and len(json.loads(path.read_text())) == 3


def test_a_lens_with_cached_indices_never_imports_opticalglass(fresh_cache):
    code = (
        "import sys; from lensim.optics.lens_file import load_lens; "
        "lens = load_lens('cooke_triplet'); lens.paraxial() if hasattr(lens, 'paraxial') else None; "
        "[s.material.index(0.5875618) for s in lens.surfaces if hasattr(s, 'material')]; "
        "print('opticalglass' in sys.modules)"
    )
    runs = [
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()[-1]
        for _ in range(2)
    ]
    assert runs == ["True", "False"]  # the first process fills the cache, the second reads it
