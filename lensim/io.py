"""File output that is never half-written, and JSON input with one-line errors.

Every file lensim writes goes through :func:`atomic_writer`: the data goes to a
temporary file in the destination folder, is flushed to disk (fsync), gets the usual
permissions (0666 minus the umask, not mkstemp's 0600) and is renamed over the
destination (``os.replace``). Readers see the old file or the new one, never a partial
one; a failed or killed write leaves at most a hidden ``.NAME.*`` temporary file, and a
failure inside the ``with`` block removes it (as does SIGTERM or Ctrl-C under the
command line, which turns them into an exception). A write the file system refuses (no
space left, a quota, a read-only file system) is one :class:`lensim.errors.OutputError`
line naming the file (:func:`write_failure`): the file keeps its old contents. Logs that
grow line by line use :func:`append_text`: a line is appended whole or not at all.

One writer at a time per output folder: :func:`folder_lock` (an flock on
FOLDER/.lensim.lock, the one file written in place, since a lock must keep its inode).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from lensim.errors import InputError, OutputError


def default_cache_dir() -> Path:
    """Where lensim caches what it computed (PSF banks, glass catalogues' names):
    $LENSIM_CACHE or ~/.cache/lensim."""
    return Path(os.environ.get("LENSIM_CACHE", Path.home() / ".cache" / "lensim"))


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


#: errno values of a write refused for want of room
NO_ROOM = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
#: errno values of a write the environment refuses (not a bug of the program)
ENVIRONMENT = NO_ROOM | {errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EMFILE, errno.ENFILE}


def os_error_of(error: BaseException) -> OSError | None:
    """The OSError behind an exception: itself, or one it was raised from or while handling
    (torch.save reports its file's ENOSPC as a RuntimeError raised while handling it)."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        if isinstance(e, OSError):
            return e
        seen.add(id(e))
        e = e.__cause__ if e.__cause__ is not None else (None if e.__suppress_context__ else e.__context__)
    return None


def _no_room(folder: Path) -> bool:
    """Whether the file system of ``folder`` has less than 1 MiB left for this user."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < 1 << 20


def why_not_written(error: OSError, folder: Path | None = None) -> str:
    """A failed write's reason in a few words, with its errno name: an OSError without
    one (numpy's short write) on a file system that is full reads as ENOSPC."""
    code = error.errno
    if code is None and folder is not None and _no_room(folder):
        code = errno.ENOSPC
    if code is None:
        return str(error) or type(error).__name__
    return f"{os.strerror(code).lower()} ({errno.errorcode.get(code, code)})"


def write_failure(path: str | Path, error: BaseException) -> OutputError | None:
    """The one-line OutputError for an exception raised while writing ``path``, or None
    when no OSError is behind it (a bug or a bad value, to be raised as it is)."""
    os_error = os_error_of(error)
    if os_error is None:
        return None
    path = Path(path)
    reason = why_not_written(os_error, path.parent)
    if os_error.errno in NO_ROOM or reason.endswith("(ENOSPC)"):
        expected = (
            "expected room for it on its file system: free some space and run the command "
            "again (the work finished so far is kept)"
        )
    else:
        expected = "expected a place lensim can write to"
    return OutputError(str(path), None, f"could not be written: {reason}; {expected}")


@contextlib.contextmanager
def atomic_writer(path: str | Path, suffix: str = "") -> Iterator[IO[bytes]]:
    """Open a binary file handle whose contents replace ``path`` when the block ends
    without an error. The parent folder is created when missing. ``suffix`` is appended to
    the temporary name (some writers pick a format from it). The handle is opened for
    reading too (``w+b``; writers such as tifffile seek back and read) and its ``name`` is
    the temporary file's path. A failed write (an OSError in the block, or behind its
    exception) raises :func:`write_failure`'s OutputError; ``path`` is left as it was."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    except OSError as e:
        raise write_failure(path, e) from None  # type: ignore[misc]  # an OSError always gives one
    os.close(fd)
    try:
        os.chmod(tmp, _umask_mode())
        with open(tmp, "w+b") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        failure = None if isinstance(e, InputError) else write_failure(path, e)
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if failure is not None:
            raise failure from None
        raise
    _fsync_dir(path.parent)


def append_text(path: str | Path, text: str) -> None:
    """Append UTF-8 ``text`` to a file (made when missing), whole or not at all: a write
    that fails part-way is cut back off (the file truncated to its old length) and raised
    as :func:`write_failure`'s OutputError."""
    path = Path(path)
    data = text.encode("utf-8")
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, _umask_mode())
    except OSError as e:
        raise write_failure(path, e) from None  # type: ignore[misc]
    try:
        size = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
        except BaseException as e:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            failure = write_failure(path, e)
            if failure is not None:
                raise failure from None
            raise
    finally:
        os.close(fd)


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


def read_bytes(path: str | Path, what: str = "file") -> bytes:
    """The bytes of a file; a missing file, a folder or an unreadable file raises one
    :class:`InputError` line naming the file and ``what`` it should have been."""
    path = Path(path)
    try:
        return path.read_bytes()
    except IsADirectoryError:
        raise InputError(str(path), None, f"is a folder; expected a {what}") from None
    except FileNotFoundError:
        raise InputError(str(path), None, f"no such {what}") from None
    except OSError as e:
        raise InputError(str(path), None, f"could not read the {what}: {e.strerror or e}") from None


_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def read_text(path: str | Path, what: str = "file") -> str:
    """A UTF-8 text file (a byte-order mark allowed); a binary or UTF-16 file, a folder or
    a missing file raises one :class:`InputError` line naming the file."""
    raw = read_bytes(path, what)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        found = (
            "UTF-16 text" if raw.startswith(_UTF16_BOMS) else f"not UTF-8 text (byte {e.start} is 0x{raw[e.start]:02x})"
        )
        raise InputError(str(path), None, f"is {found}; expected a {what} in UTF-8 (save it as UTF-8)") from None


def decode_text(raw: bytes, src: str) -> str:
    """Text of a lens-design file from any of the encodings design programs write:
    UTF-16 (by byte-order mark, or by NUL bytes), UTF-8, else Latin-1."""
    try:
        if raw.startswith(b"\xff\xfe"):
            return raw[2:].decode("utf-16-le")
        if raw.startswith(b"\xfe\xff"):
            return raw[2:].decode("utf-16-be")
        if raw.startswith(b"\xef\xbb\xbf"):
            return raw[3:].decode("utf-8")
        head = raw[:512]
        if b"\x00" in head:
            odd = sum(1 for i in range(1, len(head), 2) if head[i] == 0)
            even = sum(1 for i in range(0, len(head), 2) if head[i] == 0)
            return raw.decode("utf-16-le" if odd >= even else "utf-16-be")
    except UnicodeDecodeError as e:
        raise InputError(src, "encoding", f"not valid UTF-16 text ({e.reason} at byte {e.start})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


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


LOCK_NAME = ".lensim.lock"
_held_locks: dict[Path, int] = {}  # folders this process holds: how many nested holds


def _lock_holder(path: Path) -> str:
    """Who holds a lock file, as its text says ('pid P on HOST'), for error messages."""
    try:
        pid, host = path.read_text(encoding="utf-8").split()[:2]
        return f"pid {pid} on {host}"
    except (OSError, ValueError, UnicodeDecodeError):
        return "another process"


def _acquire(folder: Path) -> int:
    """Open and flock FOLDER/.lensim.lock without waiting; the open descriptor (the lock
    lasts while it is open). Retries when the file was removed between open and flock
    (its last holder finished), so two processes never hold different inodes."""
    import fcntl

    path = folder / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, _umask_mode())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError(
                str(folder),
                None,
                f"another lensim run ({_lock_holder(path)}) is writing into this "
                "folder; expected one writer at a time: wait for it to finish or choose another "
                "folder",
            ) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
            return fd
        os.close(fd)


@contextlib.contextmanager
def folder_lock(folder: str | Path) -> Iterator[Path]:
    """Hold the one-writer lock of an output folder for the block (the folder is created).

    The lock is an ``fcntl.flock`` on FOLDER/.lensim.lock, which holds the holder's pid
    and host: the kernel drops it when the process dies, so a killed run never leaves it
    stuck. A second process taking the same folder's lock gets a one-line InputError at
    once naming the folder and the other pid. Nested holds of one folder in one process
    are allowed (the demo's stages). On release the lock file is removed, and so is the
    folder when this hold created it and it is left empty (a refused run leaves nothing)."""
    folder = Path(folder)
    key = folder.resolve()
    if key in _held_locks:
        _held_locks[key] += 1
        try:
            yield folder
        finally:
            _held_locks[key] -= 1
        return
    created = not folder.exists()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = _acquire(folder)
    except OSError as e:  # a file in the way, no permission, read-only file system
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise InputError(
            str(folder), None, f"cannot use it as an output folder ({e.strerror or e}); expected a writable folder"
        ) from None
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    _held_locks[key] = 1
    try:
        yield folder
    finally:
        del _held_locks[key]
        with contextlib.suppress(OSError):
            os.unlink(folder / LOCK_NAME)  # before unlocking: a waiting opener retries on the new file
        os.close(fd)
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()  # only succeeds when empty


__all__ = [
    "LOCK_NAME",
    "append_text",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "atomic_writer",
    "decode_text",
    "folder_lock",
    "read_bytes",
    "read_json",
    "read_text",
    "write_failure",
]
