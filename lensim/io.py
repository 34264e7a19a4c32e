"""File output that is never half-written, and JSON input with one-line errors.

Every file lensim writes goes through :func:`atomic_writer`: the data goes to a
temporary file in the destination folder, is flushed to disk (fsync), gets the usual
permissions (0666 minus the umask, not mkstemp's 0600) and is renamed over the
destination (``os.replace``). Readers see the old file or the new one, never a partial
one; a failed or killed write leaves at most a hidden ``.NAME.*`` temporary file, and a
failure inside the ``with`` block removes it.
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import IO, Any, Iterator

from lensim.errors import InputError


def _umask_mode() -> int:
    """The mode an ordinary new file gets: 0666 minus the process umask."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _fsync_dir(directory: Path) -> None:
    """Flush a folder's entry list (the rename) to disk where the platform allows it."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_writer(path: str | Path, suffix: str = "") -> Iterator[IO[bytes]]:
    """Open a binary file handle whose contents replace ``path`` when the block ends
    without an error. The parent folder is created when missing. ``suffix`` is appended to
    the temporary name (some writers pick a format from it). The handle is opened for
    reading too (``w+b``; writers such as tifffile seek back and read) and its ``name`` is
    the temporary file's path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        os.chmod(tmp, _umask_mode())
        with open(tmp, "w+b") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_writer`)."""
    with atomic_writer(path) as fh:
        fh.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, data: Any, indent: int = 1) -> None:
    """Write ``data`` as a JSON document (one trailing newline) atomically; objects JSON
    cannot represent are written with ``str``."""
    atomic_write_text(path, json.dumps(data, indent=indent, default=str) + "\n")


def read_json(path: str | Path, what: str = "file") -> Any:
    """Read a JSON document; an unreadable, non-UTF-8 or malformed file raises one
    :class:`InputError` line naming the file and ``what`` it should have been."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except IsADirectoryError:
        raise InputError(str(path), None, f"expected a {what} (a JSON file), found a directory") from None
    except FileNotFoundError:
        raise InputError(str(path), None, f"expected a {what} (a JSON file), found nothing") from None
    except (UnicodeDecodeError, ValueError) as e:
        raise InputError(str(path), None, f"expected a {what} in JSON, could not parse it ({e})") from None
    except OSError as e:
        raise InputError(str(path), None, f"could not read the {what}: {e.strerror or e}") from None


__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_text", "atomic_writer", "read_json"]
