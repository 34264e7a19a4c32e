"""lensim's on-disk cache of what it reads from the `opticalglass` package: each catalogue's
glass names, and each catalogue glass's refractive index at the wavelengths asked for.

Importing opticalglass and creating a glass costs about 1.3-2 s per process (its import
pulls in pandas and scipy.interpolate, and each catalogue is a spreadsheet). A command that
only needs a cached lens's indices at the sensor's usual wavelengths (``lensim restore``
with a cached bank, say) then pays that on every run. Both caches live in
CACHE/opticalglass-VERSION/ (CACHE: $LENSIM_CACHE or ~/.cache/lensim), so a new
opticalglass release starts a fresh one. Indices are stored exactly as opticalglass
computed them (float64 through JSON's shortest round-trip repr), keyed by the wavelength's
own repr in nm: a cached index is bit-identical to a computed one. A cache that cannot be
read or written (read-only, full, corrupt) is ignored: the data are computed again.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

#: at most this many distinct wavelengths are looked up in (and added to) the index cache
#: per call; a longer array (a dispersion plot's curve, per-ray wavelengths) is computed
MAX_CACHED_WAVELENGTHS = 64
#: at most this many wavelengths are kept per glass: beyond, new ones are computed and not
#: added (each addition rewrites the glass's file; random spectral samples would grow it)
MAX_ENTRIES = 1024


@functools.cache
def _opticalglass_version() -> str | None:
    from importlib import metadata

    try:
        return metadata.version("opticalglass")
    except metadata.PackageNotFoundError:
        return None


def cache_dir() -> Path | None:
    """CACHE/opticalglass-VERSION, or None when opticalglass's version is unknown."""
    from lensim.io import default_cache_dir

    version = _opticalglass_version()
    return None if version is None else default_cache_dir() / f"opticalglass-{version}"


def _read_json(path: Path | None) -> object:
    if path is None:
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _write_json(path: Path | None, data: object) -> None:
    from lensim.errors import OutputError
    from lensim.io import atomic_write_json

    if path is None:
        return
    try:
        atomic_write_json(path, data)
    except (OSError, OutputError):  # a read-only or full cache: computed again next time
        pass


def catalog_names(catalog: str, load: Callable[[str], list[str]]) -> list[str]:
    """The vendor names of one catalogue: from the cache, else ``load(catalog)`` (and cached)."""
    folder = cache_dir()
    path = None if folder is None else folder / "names" / f"{catalog}.json"
    names = _read_json(path)
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        names = load(catalog)
        _write_json(path, names)
    return names


class IndexCache:
    """The refractive indices of one catalogue glass at the wavelengths (nm) already asked
    for, kept in memory and in CACHE/opticalglass-VERSION/index/<catalog>/<name>.json."""

    def __init__(self, name: str, catalog: str) -> None:
        folder = cache_dir()
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
        self.path = None if folder is None else folder / "index" / catalog / f"{safe}.json"
        self._known: dict[str, float] | None = None

    def _table(self) -> dict[str, float]:
        if self._known is None:
            data = _read_json(self.path)
            ok = isinstance(data, dict) and all(isinstance(v, float) for v in data.values())
            self._known = {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) and ok else {}
        return self._known

    def indices(self, lam_nm: np.ndarray, compute: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Indices (float64, lam_nm's shape) at wavelengths lam_nm (nm, float64): cached
        ones looked up, the others ``compute``d (vectorized), added and saved."""
        uniq, inverse = np.unique(lam_nm, return_inverse=True)
        if uniq.size > MAX_CACHED_WAVELENGTHS:
            return np.asarray(compute(lam_nm), dtype=np.float64)
        table = self._table()
        keys = [repr(float(v)) for v in uniq]
        missing = [i for i, k in enumerate(keys) if k not in table]
        if missing and len(table) + len(missing) > MAX_ENTRIES:
            return np.asarray(compute(lam_nm), dtype=np.float64)
        if missing:
            new = np.asarray(compute(uniq[missing]), dtype=np.float64).reshape(-1)
            table.update({keys[i]: float(n) for i, n in zip(missing, new, strict=True)})
            _write_json(self.path, table)
        return np.array([table[k] for k in keys], dtype=np.float64)[inverse].reshape(lam_nm.shape)
