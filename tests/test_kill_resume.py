"""Long jobs killed with SIGKILL: their worker processes die with them, a second writer
into the same folder is refused at once, and a resumed run ends with the very arrays of
an uninterrupted one. The jobs run as `lensim` subprocesses on small sizes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_runner import run_cli

import lensim

ROOT = Path(lensim.__file__).resolve().parents[1]  # the lensim the subprocesses run


def lensim_process(args: list[str], **kw) -> subprocess.Popen:
    """`python -m lensim ARGS` in a subprocess (the lensim under test, output captured)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "lensim", *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def children(pid: int) -> list[int]:
    """The live (not zombie) child processes of ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) ": state, ppid, ...
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


def wait_for(condition, timeout_s: float, poll_s: float = 0.05) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(poll_s)
    return condition()


def workers_of(pid: int, marker: str) -> list[int]:
    """Children of ``pid`` whose command line holds ``marker``."""
    out = []
    for child in children(pid):
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if marker in cmd:
            out.append(child)
    return out


# a bank whose fields take several seconds each (61 wavelengths): a worker that outlived
# its parent would still be computing long after the kill
SLOW_BANK = ["psf", "bank", "cooke_triplet", "--pixel-um", "4", "--kernel", "15", "--fields", "4",
             "--wavelengths-nm", "400:700:5", "--pupil-samples", "64", "--quiet"]


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_killed_bank_leaves_no_worker_and_a_second_writer_is_refused_meanwhile(tmp_path, capsys, monkeypatch):
    out = tmp_path / "bank"
    proc = lensim_process([*SLOW_BANK, "--workers", "2", "-o", str(out)])
    try:
        assert wait_for(lambda: len(workers_of(proc.pid, "spawn_main")) == 2, 60), proc.stderr
        workers = workers_of(proc.pid, "spawn_main")
        # another bank into the same folder, meanwhile (in this process: no start-up)
        quick = ["psf", "bank", "cooke_triplet", "--pixel-um", "4", "--kernel", "15", "--fields", "2",
                 "--wavelengths-nm", "550", "--pupil-samples", "32", "-o", str(out)]
        code, _, err = run_cli(quick, capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1, err
        assert str(out) in err and f"pid {proc.pid}" in err and "another lensim run" in err
        time.sleep(0.5)
        assert all(alive(w) for w in workers)  # computing their first fields
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert wait_for(lambda: not any(alive(w) for w in workers), 5.0), "bank workers outlived their parent"
