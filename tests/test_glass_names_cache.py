"""The catalogues' glass names cached on disk (lensim.optics.materials._catalog_names): a
glass that is not an exact vendor name searches every catalogue's names, which without the
cache means loading all six catalogues in every process."""

from __future__ import annotations

import json

import pytest

import lensim.optics.materials as materials


@pytest.fixture
def fresh_names(tmp_path, monkeypatch):
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()
    yield tmp_path / "cache"
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()


def test_names_are_cached_per_catalogue_and_read_back_without_loading(fresh_names, monkeypatch):
    glass, note = materials.resolve_glass("SK16")  # no exact name: every catalogue's names searched
    assert glass.name == "N-SK16" and glass.catalog == "Schott" and "family" in note
    files = sorted(fresh_names.glob("glass_names/opticalglass-*/*.json"))
    assert [f.stem for f in files] == sorted(materials.CATALOGS)
    assert "N-SK16" in json.loads((files[0].parent / "Schott.json").read_text())
    materials._catalog_names.cache_clear()
    materials.catalog_glass.cache_clear()

    def no_loading(catalog: str) -> list[str]:
        raise AssertionError(f"{catalog} loaded although its names are cached")

    monkeypatch.setattr(materials, "_load_catalog_names", no_loading)
    again, _ = materials.resolve_glass("SK16")
    assert (again.name, again.catalog) == ("N-SK16", "Schott")
    assert again.index(0.5875618) == pytest.approx(glass.index(0.5875618), abs=0)


def test_a_damaged_or_unwritable_cache_loads_the_names_again(fresh_names, monkeypatch):
    folder = fresh_names / "glass_names"
    folder.mkdir(parents=True)
    materials.resolve_glass("N-BK7")
    schott = next(folder.glob("opticalglass-*/Schott.json"))
    schott.write_text("{not json")
    materials._catalog_names.cache_clear()
    assert "NBK7" in materials._catalog_names("Schott")  # loaded again, and the file repaired
    assert "N-BK7" in json.loads(schott.read_text())
    materials._catalog_names.cache_clear()
    monkeypatch.setattr(materials, "_name_cache", lambda catalog: fresh_names / "file" / f"{catalog}.json")
    (fresh_names / "file").write_text("a file where the cache folder would be")
    assert "NBK7" in materials._catalog_names("Schott")  # nothing written, no error
