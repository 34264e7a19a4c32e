"""SIGTERM or Ctrl-C (SIGINT to the whole process group, as a terminal sends it) in the
middle of a long command: it stops at once with one line on stderr and exit status 128 +
the signal (143, 130), its Dask workers are gone, the output folder's lock is released
(its lock file removed), no half file is left, and the same command run again ends with
the outputs of an uninterrupted run."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from fault_world import cli, differences
from faults import alive, half_files, interrupt, lensim_process, one_line_error, wait_for, workers_of

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")

#: seconds a stopped command may take to end (a local Dask cluster closes in this time)
STOP_S = 10.0


def _catches(pid: int, sig: signal.Signals) -> bool:
    """Whether process ``pid`` has a handler for ``sig`` (/proc/PID/status SigCgt)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(mask >> (int(sig) - 1) & 1)


def _started(out: Path, proc, workers: bool) -> bool:
    """Whether the job is under way: its output folder locked, and with workers, two
    worker processes up and the cluster started (lensim ignores SIGINT while it starts
    one, so that its workers inherit ignoring a terminal's Ctrl-C)."""
    if proc.poll() is not None:
        return True
    if not (out / ".lensim.lock").exists():
        return False
    return not workers or (len(workers_of(proc.pid)) >= 2 and _catches(proc.pid, signal.SIGINT))


def _stop_and_resume(world, tmp_path: Path, job: str, sig: signal.Signals, workers: bool) -> None:
    out = tmp_path / "out"
    more = ("--workers", "2") if workers else ()
    args = world.args(job, out, *more)
    proc = lensim_process(args)
    try:
        assert wait_for(lambda: _started(out, proc, workers), 120, poll_s=0.01)
        assert proc.poll() is None, f"the job ended before the signal: {proc.stderr.read() if proc.stderr else ''}"
        pool = workers_of(proc.pid)
        seconds, err = interrupt(proc, sig, timeout_s=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert seconds < STOP_S, f"took {seconds:.1f} s to stop"
    line = one_line_error(err)
    assert proc.returncode == 128 + sig, (proc.returncode, err)
    assert "rerun" in line or "resume" in line, line
    assert wait_for(lambda: not any(alive(w) for w in pool), 5.0), "workers outlived the command"
    assert not (out / ".lensim.lock").exists(), "lock file left behind"
    assert not half_files(out), half_files(out)
    rerun = [*args, "--resume"] if job == "train" and (out / "last.pt").exists() else args
    assert cli(rerun) == 0
    assert differences(job, world.reference(job), out) == []


@pytest.mark.parametrize(("job", "sig"), [("bank", signal.SIGTERM), ("train", signal.SIGINT)])
def test_a_stopped_command_ends_at_once_and_resumes(fault_world, tmp_path, job, sig):
    _stop_and_resume(fault_world, tmp_path, job, sig, workers=False)


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.parametrize(
    ("job", "workers"),
    [
        ("bank", False),
        ("bank", True),
        ("grid", True),
        ("pairs", False),
        ("pairs", True),
        ("train", False),
        ("restore", True),
    ],
)
def test_every_long_command_stops_at_once_and_resumes(fault_world, tmp_path, job, workers, sig):
    _stop_and_resume(fault_world, tmp_path, job, sig, workers)
