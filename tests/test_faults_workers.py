"""A Dask worker process killed (SIGKILL) in the middle of a job: the job is computed
again on a fresh worker and the command ends with the outputs of an uninterrupted run;
a job that kills every worker it runs on ends the command in one line (exit status 2)
once Dask gives up on it, with no worker left behind."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from fault_world import differences
from faults import alive, lensim_process, one_line_error, wait_for, workers_of

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")


PROGRESS = {"bank": "field_*.npz", "grid": "s*/field_*.npz", "pairs": "records/*.json", "restore": "*.tif"}
TOTAL = {"bank": 4, "grid": 6, "pairs": 3, "restore": 3}


def _cluster_started(pid: int) -> bool:
    """Whether lensim's local Dask cluster is up: two workers, and the parent catching
    SIGINT again (it ignores SIGINT while the cluster starts: tests/test_faults_signals)."""
    from test_faults_signals import _catches

    return len(workers_of(pid)) >= 2 and _catches(pid, signal.SIGINT)


@pytest.mark.slow
@pytest.mark.parametrize("job", ("bank", "grid", "pairs", "restore"))
def test_a_worker_killed_mid_job_is_replaced_and_the_results_are_those_of_an_uninterrupted_run(
    fault_world, tmp_path, job
):
    out = tmp_path / "out"
    proc = lensim_process(fault_world.args(job, out, "--workers", "2"))
    try:
        assert wait_for(lambda: _cluster_started(proc.pid) or proc.poll() is not None, 120, poll_s=0.01)
        victim = workers_of(proc.pid)[0]
        os.kill(victim, signal.SIGKILL)
        assert len(list(out.glob(PROGRESS[job]))) < TOTAL[job], "the job ended before the kill"
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert differences(job, fault_world.reference(job), out) == []


@pytest.mark.slow
def test_a_worker_killed_while_the_cluster_starts_is_one_line_or_replaced(fault_world, tmp_path):
    out = tmp_path / "out"
    proc = lensim_process(fault_world.args("bank", out, "--workers", "2"))
    try:
        assert wait_for(lambda: len(workers_of(proc.pid)) >= 1 or proc.poll() is not None, 120, poll_s=0.005)
        for w in workers_of(proc.pid):
            os.kill(w, signal.SIGKILL)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    if proc.returncode == 0:
        assert differences("bank", fault_world.reference("bank"), out) == []
    else:
        line = one_line_error(err)
        assert proc.returncode == 2 and "worker" in line, err
        assert not out.exists() or not list(out.glob("field_*.npz")) or not (out / ".lensim.lock").exists()


def die(job: int) -> int:
    """A job that kills the worker process it runs in."""
    os.kill(os.getpid(), signal.SIGKILL)
    return job


@pytest.mark.slow
def test_a_job_that_keeps_killing_its_workers_fails_in_one_line(tmp_path):
    from lensim.errors import LensimError
    from lensim.workers import run_jobs

    with pytest.raises(LensimError) as err:
        run_jobs(die, [1, 2], workers=2)
    assert "\n" not in str(err.value) and "worker" in str(err.value)


@pytest.mark.slow
def test_a_bank_whose_workers_keep_dying_fails_in_one_line_and_leaves_no_worker(fault_world, tmp_path):
    out = tmp_path / "out"
    proc = lensim_process(fault_world.args("bank", out, "--workers", "2"))
    killed: set[int] = set()
    try:
        while proc.poll() is None and len(killed) < 12:
            for w in workers_of(proc.pid):
                if w not in killed and alive(w):
                    os.kill(w, signal.SIGKILL)
                    killed.add(w)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    if proc.returncode == 0:  # Dask retried each field on a fresh worker until it finished
        assert differences("bank", fault_world.reference("bank"), out) == []
        return
    line = one_line_error(err)
    assert proc.returncode == 2 and "worker" in line, err
    assert wait_for(lambda: not any(alive(w) for w in killed), 5.0)
