"""Faults for the fault-injection suite (tests/test_faults_*.py): a disk that fills up, a
process tree to watch and signal, and snapshots of output folders.

A full disk by injection (:class:`DiskQuota`), so any machine can run it without a
mount: every file opened for writing under a folder is a :class:`_QuotaFile`, whose
``write`` (what a buffered file, PIL, tifffile, torch.save and csv call) raises
``OSError(ENOSPC)`` once the folder's files would exceed the quota, as a full file
system does: errno 28, no file name attached. ``os.fsync`` checks the quota too (data
written around Python, such as numpy's ``tofile``, is counted there). The quota is the
folder's own bytes (the sizes of every file under it), so it holds across processes:
subprocesses and their Dask workers install it from the environment through
``FAULT_SITE/sitecustomize.py`` (:func:`quota_env`).
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import lensim

ROOT = Path(lensim.__file__).resolve().parents[1]  # the lensim the subprocesses run
FAULT_SITE = Path(__file__).resolve().parent / "fault_site"  # its sitecustomize.py installs the quota
QUOTA_ENV = "LENSIM_TEST_DISK_QUOTA"  # "BYTES:FOLDER"

_real_open = builtins.open
_real_fsync = os.fsync


def folder_bytes(folder: Path) -> int:
    """The sizes of every file under ``folder`` added up (0 when it does not exist)."""
    total = 0
    for dirpath, _, files in os.walk(folder):
        for name in files:
            try:
                total += os.stat(os.path.join(dirpath, name)).st_size
            except OSError:
                pass
    return total


class DiskQuota:
    """``limit`` bytes for the files under ``folder``; beyond them writes fail with ENOSPC."""

    def __init__(self, folder: str | Path, limit: int) -> None:
        self.folder = os.path.abspath(folder)
        self.limit = int(limit)
        self.refusals = 0

    def covers(self, file: object) -> bool:
        if not isinstance(file, (str, bytes, os.PathLike)):
            return False
        path = os.path.abspath(os.fsdecode(file))
        return path == self.folder or path.startswith(self.folder + os.sep)

    def check(self, more: int) -> None:
        """ENOSPC when ``more`` bytes would take the folder beyond the limit."""
        if folder_bytes(Path(self.folder)) + more > self.limit:
            self.refusals += 1
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def open(self, file, mode="r", buffering=-1, encoding=None, errors=None, newline=None, closefd=True, opener=None):
        """builtins.open, with files under the folder opened for writing as _QuotaFile."""
        if not self.covers(file) or not any(c in mode for c in "wax+"):
            return _real_open(file, mode, buffering, encoding, errors, newline, closefd, opener)
        raw = _QuotaFile(file, mode.replace("b", "").replace("t", ""), closefd=closefd, opener=opener)
        raw.quota = self
        if buffering == 0:
            return raw
        buffered = io.BufferedRandom(raw) if "+" in mode else io.BufferedWriter(raw)
        if "b" in mode:
            return buffered
        text = io.TextIOWrapper(buffered, encoding, errors, newline, line_buffering=buffering == 1)
        text.mode = mode  # type: ignore[misc]
        return text

    def fsync(self, fd: int) -> None:
        self.check(0)
        _real_fsync(fd)

    @contextmanager
    def installed(self) -> Iterator[DiskQuota]:
        """The quota in force in this process for the block."""
        saved = builtins.open, io.open, os.fsync
        builtins.open = io.open = self.open  # type: ignore[assignment]
        os.fsync = self.fsync
        try:
            yield self
        finally:
            builtins.open, io.open, os.fsync = saved


class _QuotaFile(io.FileIO):
    quota: DiskQuota

    def write(self, b) -> int:  # type: ignore[override]
        self.quota.check(memoryview(b).nbytes)
        return super().write(b)


def quota_env(folder: Path, limit: int) -> dict[str, str]:
    """Environment for a subprocess (and its Dask workers) that installs a DiskQuota."""
    path = os.pathsep.join([str(FAULT_SITE), str(Path(__file__).resolve().parent), str(ROOT)])
    return {QUOTA_ENV: f"{int(limit)}:{folder}", "PYTHONPATH": path}


def install_from_env() -> None:
    """Install the DiskQuota QUOTA_ENV names for the rest of this process (sitecustomize)."""
    spec = os.environ.get(QUOTA_ENV)
    if not spec:
        return
    limit, folder = spec.split(":", 1)
    quota = DiskQuota(folder, int(limit))
    builtins.open = io.open = quota.open  # type: ignore[assignment]
    os.fsync = quota.fsync


# ----------------------------------------------------------------------------- folders


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (the lock file aside) by relative path: its bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != ".lensim.lock"
    }


def half_files(folder: Path) -> list[str]:
    """Temporary files of lensim.io.atomic_writer left under ``folder`` (hidden .NAME.*)."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*") if p.is_file() and p.name != ".lensim.lock")


def one_line_error(err: str) -> str:
    """The one stderr line of a failed command (asserted: one line, no traceback, 'error: ')."""
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("warning:")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return lines[0]


# ----------------------------------------------------------------------------- processes


def lensim_process(args: list[str], env: dict[str, str] | None = None, **kw) -> subprocess.Popen:
    """`python -m lensim ARGS` in a subprocess (the lensim under test, output captured),
    in a session of its own (a terminal's Ctrl-C reaches its whole process group)."""
    full = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", **(env or {})}
    return subprocess.Popen(
        [sys.executable, "-m", "lensim", *args],
        env=full,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        **kw,
    )


def run_lensim(args: list[str], env: dict[str, str] | None = None, timeout: float = 600) -> tuple[int, str, str]:
    """`lensim ARGS` in a subprocess to its end: (exit status, stdout, stderr)."""
    proc = lensim_process(args, env)
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def children(pid: int) -> list[int]:
    """The live (not zombie) child processes of ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2 :].split()  # after "pid (comm) ": state, ppid, ...
        if fields[0] != "Z" and int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its new parent to reap it does not)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return text[text.rindex(")") + 2] != "Z"


def wait_for(condition: Callable[[], object], timeout_s: float, poll_s: float = 0.05) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(poll_s)
    return bool(condition())


def workers_of(pid: int, marker: str = "spawn_main") -> list[int]:
    """Children of ``pid`` whose command line holds ``marker`` (Dask's worker processes)."""
    out = []
    for child in children(pid):
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if marker in cmd:
            out.append(child)
    return out


def interrupt(proc: subprocess.Popen, sig: signal.Signals, timeout_s: float = 30.0) -> tuple[float, str]:
    """Send ``sig`` to the process (SIGINT to its whole group, as a terminal's Ctrl-C
    does); (seconds it took to end, its stderr)."""
    t0 = time.monotonic()
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        return float("inf"), err
    return time.monotonic() - t0, err
