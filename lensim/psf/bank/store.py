"""A PSF bank on disk: ``manifest.json`` (every setting that shapes the kernels, the lens
as a native-format mapping, the spectral weights) and one ``field_XXXX.npz`` per field,
each written atomically. Rerunning with the same settings finds the fields already on
disk (resume after a kill); a bank made with different settings is refused."""

from __future__ import annotations

import contextlib
import hashlib
import json
import warnings
from pathlib import Path

import numpy as np

from lensim.errors import InputError
from lensim.io import atomic_write_bytes, atomic_write_text
from lensim.psf.bank.types import BankField, PSFBank

MANIFEST = "manifest.json"
FORMAT = "lensim-psf-bank"
FORMAT_VERSION = 1
# manifest keys that may differ between runs of the same bank (they do not shape kernels: a
# setting's lens is in "lens"; "shooting" only describes it)
_INFORMATIVE_KEYS = ("lens_file", "lensim_version", "shooting")


def lensim_version() -> str:
    """The lensim version recorded in manifests (lensim.__version__, its one home)."""
    from lensim import __version__

    return __version__


def field_file(index: int) -> str:
    """File name of field `index` inside a bank directory."""
    return f"field_{index:04d}.npz"


def read_manifest(directory: str | Path) -> dict | None:
    """The manifest of a bank directory, or None if there is none."""
    p = Path(directory) / MANIFEST
    if not p.exists():
        return None
    try:
        m = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(str(p), None, f"not valid JSON: {e}") from None
    if isinstance(m, dict) and m.get("format") == "lensim-psf-grid":
        raise InputError(
            str(p),
            "format",
            f"a grid of {len(m.get('settings') or [])} banks, not one bank; expected "
            "one setting's bank, a sub-folder s000, s001, ... (its manifest.json lists the settings)",
        )
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise InputError(str(p), "format", f"expected {FORMAT!r}; not a PSF bank manifest")
    if m.get("format_version") != FORMAT_VERSION:
        raise InputError(str(p), "format_version", f"expected {FORMAT_VERSION}, got {m.get('format_version')!r}")
    return m


def _normalized(d: dict) -> dict:
    return json.loads(json.dumps(d))


def manifest_differences(old: dict, new: dict) -> list[str]:
    """The manifest keys whose values differ (informative keys such as the version aside)."""
    a = {k: v for k, v in _normalized(old).items() if k not in _INFORMATIVE_KEYS}
    b = {k: v for k, v in _normalized(new).items() if k not in _INFORMATIVE_KEYS}
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def settings_key(manifest: dict) -> str:
    """A short hash of the settings that shape the kernels (the manifest without its
    informative keys); every field file stores the key it was computed under, so a field
    of another bank's settings is never taken for one of this bank."""
    kept = {k: v for k, v in _normalized(manifest).items() if k not in _INFORMATIVE_KEYS}
    return hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()[:16]


def _read_field(path: Path, manifest: dict, index: int) -> BankField:
    """Field ``index`` of a bank from its file, checked against the manifest (its field,
    its kernel size and, when the file records one, its settings key); a one-line
    InputError naming the file when it is unreadable or belongs to other settings."""
    bf = BankField.from_npz(path)
    expected = float(manifest["fields"][index])
    size = int(manifest["kernel_pixels"])
    if abs(bf.field - expected) > 1e-12:
        raise InputError(str(path), "field", f"expected field {expected!r} as the manifest says, got {bf.field!r}")
    if bf.rgb.shape != (3, size, size):
        raise InputError(
            str(path), "rgb", f"expected a (3, {size}, {size}) kernel as the manifest says, got {bf.rgb.shape}"
        )
    if bf.settings_key and bf.settings_key != settings_key(manifest):
        raise InputError(
            str(path),
            "settings_key",
            f"computed with other settings than {MANIFEST} says (another "
            "bank's field); rerun `lensim psf bank` with the manifest's settings to recompute it",
        )
    return bf


def open_bank_directory(directory: Path, manifest: dict, fields: np.ndarray) -> dict[int, BankField]:
    """Prepare `directory` for the bank `manifest` describes and return the fields already
    computed there, by index (a resumed run skips them).

    A directory holding field files made with other settings is refused (InputError naming
    the differing keys); a manifest without any field file is replaced. Unreadable
    (truncated) field files, and files of another field, kernel size or settings key, are
    left to be recomputed."""
    old = read_manifest(directory)
    if old is not None and not any(directory.glob("field_*.npz")):
        old = None  # nothing computed under the old settings: start afresh
    if old is not None:
        diff = manifest_differences(old, manifest)
        if diff:
            raise InputError(
                str(directory / MANIFEST),
                ", ".join(diff),
                "the bank on disk was made with different "
                "settings; expected the same settings to resume, or a new output directory",
            )
    else:
        directory.mkdir(parents=True, exist_ok=True)
        atomic_write_text(directory / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    done: dict[int, BankField] = {}
    for i in range(len(fields)):
        p = directory / field_file(i)
        if p.exists():
            try:
                done[i] = _read_field(p, manifest, i)
            except InputError:
                continue  # unreadable or foreign: recompute
    return done


def release_bank_directory(directory: Path, fields: str = "field_*.npz") -> None:
    """Undo open_bank_directory's (or a grid's) claim when no field was computed (no file
    matches ``fields``): the manifest goes, and the folder when that leaves it empty (a
    failed first run leaves nothing behind)."""
    if any(directory.glob(fields)):
        return
    (directory / MANIFEST).unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        directory.rmdir()  # only when empty


def drop_damaged_manifests(entry: Path) -> None:
    """Remove the manifests of a bank cache entry (a bank, or a grid and its banks) that do
    not read as a bank's or a grid's (damaged on disk): the entry is then recomputed,
    keeping the field files that still read and match its settings. A warning names each.
    Only for cache entries: a folder the user named keeps its manifest (read_manifest's
    one-line error names it)."""
    for path in (entry / MANIFEST, *sorted(entry.glob(f"s[0-9][0-9][0-9]/{MANIFEST}"))):
        try:
            m = json.loads(path.read_text(encoding="utf-8"))
            damaged = not (isinstance(m, dict) and m.get("format") in (FORMAT, "lensim-psf-grid"))
        except FileNotFoundError:
            continue
        except (OSError, UnicodeDecodeError, ValueError):
            damaged = True
        if damaged:
            warnings.warn(f"{path}: a damaged bank cache entry; recomputing it", UserWarning, stacklevel=4)
            path.unlink(missing_ok=True)


def write_field(directory: Path, bank_field: BankField, manifest: dict) -> None:
    """Write one computed field into the bank directory (atomically), stamped with the
    settings key of the bank's ``manifest``."""
    bank_field.settings_key = settings_key(manifest)
    atomic_write_bytes(directory / field_file(bank_field.index), bank_field.to_npz_bytes())


def load_bank(directory: str | Path) -> PSFBank:
    """Load a complete bank directory (manifest.json + one npz per field)."""
    d = Path(directory)
    manifest = read_manifest(d)
    if manifest is None:
        raise InputError(str(d), MANIFEST, "missing; expected a PSF bank directory written by `lensim psf bank`")
    fields = manifest.get("fields")
    if not isinstance(fields, list) or not fields:
        raise InputError(str(d / MANIFEST), "fields", f"expected a non-empty list of field values, got {fields!r}")
    flds = []
    for i in range(len(fields)):
        p = d / field_file(i)
        if not p.exists():
            raise InputError(
                str(d),
                field_file(i),
                "missing: the bank is incomplete; rerun `lensim psf bank` with the same settings to finish it",
            )
        flds.append(_read_field(p, manifest, i))
    return PSFBank(manifest, flds, d)


#: banks loaded by :func:`load_bank_cached` in this process: folder -> (its files' stamp, bank)
_LOADED: dict[Path, tuple[tuple, PSFBank]] = {}
_LOADED_MAX = 16  # banks kept (a grid's or a tolerance study's banks: a few MB each)


def _stamp(directory: Path) -> tuple:
    """(name, size, mtime_ns) of every file in a bank folder: changes when any is rewritten."""
    try:
        entries = sorted((e.name, e.stat().st_size, e.stat().st_mtime_ns) for e in directory.iterdir() if e.is_file())
    except OSError:
        return ()
    return tuple(entries)


def load_bank_cached(directory: str | Path) -> PSFBank:
    """:func:`load_bank`, once per process: the bank loaded earlier from the same folder
    when none of its files changed since (sizes and modification times), else loaded
    again. For jobs that each need a bank (training pairs: one job per photo). The bank
    returned is shared: callers must not change it."""
    d = Path(directory).resolve()
    stamp = _stamp(d)
    hit = _LOADED.get(d)
    if hit is not None and stamp and hit[0] == stamp:
        return hit[1]
    bank = load_bank(directory)
    if len(_LOADED) >= _LOADED_MAX:
        _LOADED.pop(next(iter(_LOADED)))
    _LOADED[d] = (stamp, bank)
    return bank
