"""Worker processes: one engine for lensim's parallel jobs, and workers that die with
their parent.

:func:`run_jobs` runs picklable jobs (``fn(job)`` for each job) in this process, on a
local Dask cluster of worker processes (one torch thread each), or on an existing Dask
cluster (``scheduler``: its address); `psf bank`, `dataset make` and `restore` (raw
files) run on it, so a cluster computes banks, grids of banks, training pairs and restored
raws alike (their ``--workers`` and ``--scheduler`` options).

Worker processes of a killed parent must not compute on at full CPU for nobody. The local
cluster's workers are children of this process; they end with it twice over: Dask's
nanny, which lives in the parent, holds a pipe to each of them that closes when the
parent dies, and each job calls :func:`exit_with_parent` in its worker first, which ends
the worker within ``poll_s`` seconds of its parent's death through a daemon thread that
watches the parent pid (a dead parent's children are re-parented, so ``os.getppid()``
changes). Linux's ``PR_SET_PDEATHSIG`` is not used: it fires when the *thread* that
started the worker ends. tests/test_kill_resume.py checks each command. Workers of a
cluster given by address belong to that cluster and are left alone.

A worker that dies in the middle of a job (killed, out of memory) is replaced by Dask's
nanny and the job computed again elsewhere; a job on which workers died more often than
the scheduler allows (distributed.scheduler.allowed-failures, 3) is a one-line
:class:`lensim.errors.WorkerLostError` naming it (tests/test_faults_workers.py).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

J = TypeVar("J")
R = TypeVar("R")

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


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity masks (macOS, Windows)
        return max(1, os.cpu_count() or 1)


class _Failed:
    """An exception raised by a job, sent back as its result (so the worker does not log a
    multi-line traceback of an error the parent reports in one line); an unexpected one
    carries the worker's traceback as a note."""

    def __init__(self, error: BaseException) -> None:
        from lensim.errors import LensimError

        if not isinstance(error, LensimError):
            import traceback

            error.add_note("in a Dask worker:\n" + "".join(traceback.format_exception(error)).rstrip())
        self.error = error


def _in_worker(fn: Callable[[Any], Any], job: Any, parent_pid: int | None) -> Any:
    """fn(job) in a Dask worker: tied to its parent when that is a local cluster's
    (parent_pid), with one torch thread (a job's tensors are small; more threads would
    fight the other workers for cores) and warnings dropped (a job returns what its
    parent should report); an exception comes back as a _Failed result."""
    import warnings

    import torch

    if parent_pid is not None and os.getppid() == parent_pid:  # (a forkserver's worker relies on its nanny alone)
        exit_with_parent(parent_pid)
    torch.set_num_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return fn(job)
        except Exception as e:  # noqa: BLE001  (re-raised in the parent)
            return _Failed(e)


def run_jobs(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    workers: int = 1,
    scheduler: str | None = None,
    on_result: Callable[[J, R], None] | None = None,
) -> None:
    """Run ``fn(job)`` for every job, calling ``on_result(job, result)`` in this process as
    each finishes (in order of completion; results are not kept).

    Where: with no scheduler and ``workers`` <= 1 or at most one job, in this process with
    one torch thread (restored afterwards); with no scheduler, on a local Dask cluster of
    min(workers, jobs) worker processes, one thread each, started here and closed on
    return; with ``scheduler`` (an address such as ``tcp://host:8786``), on that cluster,
    whose workers must be able to import lensim. ``fn`` and the jobs must be picklable (a
    module-level function and plain data). An exception from a job (an InputError
    crosses the process boundary as itself) cancels the rest and is raised here."""
    import torch

    if not jobs:
        return
    if scheduler is None and (workers <= 1 or len(jobs) <= 1):
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for job in jobs:
                result = fn(job)
                if on_result is not None:
                    on_result(job, result)
        finally:
            torch.set_num_threads(threads)
        return
    _run_on_dask(fn, jobs, min(workers, len(jobs)), scheduler, on_result)


def run_whole_jobs(
    fn: Callable[..., R],
    jobs: Sequence[J],
    workers: int = 1,
    scheduler: str | None = None,
    on_result: Callable[[J, R], None] | None = None,
) -> None:
    """Run ``fn(job, workers, scheduler)`` for every job whose own work can be spread over
    workers (a whole bank: its fields), calling ``on_result(job, result)`` as each finishes.

    With no scheduler and ``workers`` > 1: whole jobs side by side on a local Dask cluster,
    ``fn(job)`` in one worker each (``fn``'s defaults must be one worker and no scheduler;
    the workers share this machine's folders). Otherwise one job after another here, each
    ``fn(job, workers, scheduler)`` spreading its own parts over the cluster at
    ``scheduler`` (whose workers need not see this machine's folders)."""
    if scheduler is None and workers > 1:
        run_jobs(fn, jobs, workers, None, on_result)
        return
    for job in jobs:
        result = fn(job, workers, scheduler)
        if on_result is not None:
            on_result(job, result)


def _client(client_type: Any, address: Any) -> Any:
    """A Dask client of the cluster (or at the address); a scheduler that does not answer
    is a one-line InputError naming its address."""
    from lensim.errors import InputError

    try:
        return client_type(address)
    except OSError as e:  # TimeoutError included
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(
            str(address),
            None,
            f"no Dask scheduler answered ({reason}); expected the address of a "
            "running scheduler (dask scheduler, or a cluster's scheduler_address)",
        ) from None


@contextlib.contextmanager
def _workers_ignore_sigint() -> Iterator[None]:
    """Worker processes started in the block ignore SIGINT, a disposition they inherit: a
    terminal's Ctrl-C reaches the whole process group, and only the parent is to stop (its
    workers end with it, without a traceback each). This process ignores SIGINT meanwhile
    (while the cluster starts); off the main thread nothing changes."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def _local_cluster(workers: int) -> Any:
    """A local Dask cluster of ``workers`` processes, one thread each, on no fixed port,
    logging nothing below CRITICAL: no warnings of cancelled jobs, and no traceback when a
    worker's heartbeat misses a scheduler that is busy (the demo printed one; a job that
    fails still raises in the client, and a lost worker is WorkerLostError). Its workers keep glibc's own
    malloc trimming: Dask's nanny would start them with MALLOC_TRIM_THRESHOLD_=65536
    (distributed.nanny.pre-spawn-environ), which also turns off glibc's adaptive mmap
    threshold, so every large temporary array is mmapped and page-faulted afresh; that
    made `lensim restore --workers 2` take about 1.7 times as long as a process pool
    (measured on 6 raws, 2 loaded cores)."""
    import logging

    import dask
    from distributed import LocalCluster

    from lensim.errors import WorkerLostError

    try:
        with (
            dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}),
            _workers_ignore_sigint(),
        ):
            return LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.CRITICAL,
            )
    except (RuntimeError, OSError) as e:  # a worker process died while starting ("Nanny failed to start")
        raise WorkerLostError(
            None,
            "workers",
            f"a local Dask cluster of {workers} worker processes did not start ({str(e).splitlines()[0][:120]}); "
            "expected worker processes that start and stay up: run the command again, with fewer workers if "
            "memory is short",
        ) from None


def _job_name(job: Any, k: int, n: int) -> str:
    """A job in an error message: the file it works on when it names one, else its place."""
    for owner in (job, getattr(job, "job", None)):
        for attr in ("path", "source"):
            value = getattr(owner, attr, None)
            if isinstance(value, (str, os.PathLike)):
                return str(value)
    return f"job {k + 1} of {n}"


def _lost(job: Any, k: int, n: int) -> Exception:
    from lensim.errors import WorkerLostError

    return WorkerLostError(
        _job_name(job, k, n),
        None,
        "the Dask worker processes running it died over and over (killed, or out of "
        "memory); expected workers that stay up: run the command again (the work finished "
        "so far is kept), with fewer workers if memory is short",
    )


def _run_on_dask(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    workers: int,
    scheduler: str | None,
    on_result: Callable[[J, R], None] | None,
) -> None:
    from distributed import Client, as_completed

    cluster = None if scheduler else _local_cluster(workers)
    parent = os.getpid() if cluster is not None else None
    try:
        with _client(Client, scheduler or cluster) as client:
            futures = client.map(_in_worker, [fn] * len(jobs), list(jobs), parent_pid=parent, pure=False)
            job_of = {f.key: (k, job) for k, (f, job) in enumerate(zip(futures, jobs, strict=True))}
            try:
                for fut in as_completed(futures):
                    result = _result(fut, job_of, len(jobs))
                    if isinstance(result, _Failed):
                        raise result.error
                    if on_result is not None:
                        on_result(job_of[fut.key][1], result)
            except BaseException:
                client.cancel(futures)
                raise
    finally:
        if cluster is not None:
            cluster.close()


def _result(fut: Any, job_of: dict[Any, tuple[int, Any]], n: int) -> Any:
    """A finished future's result; Dask's KilledWorker is a one-line WorkerLostError."""
    from distributed import KilledWorker

    try:
        return fut.result()
    except KilledWorker:
        raise _lost(job_of[fut.key][1], job_of[fut.key][0], n) from None


__all__ = ["available_cores", "exit_with_parent", "run_jobs", "run_whole_jobs"]
