"""Worker processes that die with their parent.

The PSF bank's process pool starts worker processes; when the parent is killed (SIGKILL,
out of memory) nothing tells them to stop, and they would compute on at full CPU for
nobody. :func:`exit_with_parent`, called in each worker, ends the worker within ``poll_s``
seconds of its parent's death through a daemon thread that watches the parent pid: a dead
parent's children are re-parented, so ``os.getppid()`` changes. (Linux's
``PR_SET_PDEATHSIG`` is not used: it fires when the *thread* that started the worker
ends.) The local Dask cluster of ``dataset make`` needs no help: its workers end with
their nanny, which lives in the parent (tests/test_kill_resume.py checks both).
"""
from __future__ import annotations

import os
import threading
import time

_watching: set[int] = set()  # parent pids this process already watches


def _parent_gone(parent_pid: int) -> bool:
    return os.getppid() != parent_pid


def _watch(parent_pid: int, poll_s: float) -> None:
    while not _parent_gone(parent_pid):
        time.sleep(poll_s)
    os._exit(1)  # no clean-up: the parent that would use our results is gone


def exit_with_parent(parent_pid: int, poll_s: float = 0.25) -> None:
    """End this process (exit status 1, at once) when process ``parent_pid``, its parent,
    dies; at once when it is already gone. Safe to call again (one watcher per parent).
    A process that is not ``parent_pid``'s child must not call it."""
    if _parent_gone(parent_pid):
        os._exit(1)
    if parent_pid in _watching:
        return
    _watching.add(parent_pid)
    threading.Thread(target=_watch, args=(parent_pid, poll_s), name="lensim-exit-with-parent", daemon=True).start()


__all__ = ["exit_with_parent"]
