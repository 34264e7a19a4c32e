"""lensim.io.folder_lock: one writer per output folder, never stuck after a kill."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lensim.errors import InputError
from lensim.io import LOCK_NAME, folder_lock

ROOT = Path(__file__).resolve().parents[1]
HOLDER = (
    "import sys, time; from lensim.io import folder_lock\nwith folder_lock(sys.argv[1]):\n"
    "    print('held', flush=True); time.sleep(60)\n"
)


def _hold_in_subprocess(folder: Path) -> subprocess.Popen:
    """A process holding the folder's lock (it prints 'held' once it has it)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, env=env, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_at_once_naming_the_folder_and_pid(tmp_path):
    folder = tmp_path / "out"
    proc = _hold_in_subprocess(folder)
    try:
        t0 = time.perf_counter()
        with pytest.raises(InputError) as err, folder_lock(folder):
            pass
        assert time.perf_counter() - t0 < 1.0
        msg = str(err.value)
        assert "\n" not in msg and str(folder) in msg
        assert f"pid {proc.pid} on {socket.gethostname()}" in msg
    finally:
        proc.kill()
        proc.wait()
    # SIGKILL cannot leave the lock stuck: the kernel dropped the flock with the process
    assert proc.returncode == -signal.SIGKILL and (folder / LOCK_NAME).exists()
    with folder_lock(folder):
        assert (folder / LOCK_NAME).read_text().split()[0] == str(os.getpid())
    assert not (folder / LOCK_NAME).exists()


def test_lock_is_reentrant_in_one_process_and_leaves_no_trace(tmp_path):
    folder = tmp_path / "new" / "out"
    with folder_lock(folder):
        with folder_lock(folder):  # a stage of the same job
            (folder / "a.txt").write_text("x")
        assert (folder / LOCK_NAME).exists()
    assert sorted(p.name for p in folder.iterdir()) == ["a.txt"]


def test_a_failed_run_removes_the_folder_it_created_when_left_empty(tmp_path):
    folder = tmp_path / "made"
    with pytest.raises(RuntimeError), folder_lock(folder):
        raise RuntimeError("refused")
    assert not folder.exists()
    existing = tmp_path / "kept"
    existing.mkdir()
    with folder_lock(existing):
        pass
    assert existing.is_dir() and not any(existing.iterdir())


def test_a_folder_that_cannot_be_written_is_one_line(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    with (
        pytest.raises(InputError, match=f"^{afile / 'out'}: cannot use it as an output folder"),
        folder_lock(afile / "out"),
    ):
        pass
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "ro"
        locked.mkdir(mode=0o500)
        with pytest.raises(InputError, match="cannot use it as an output folder"), folder_lock(locked):
            pass


@pytest.mark.parametrize("command", ["demo", "train", "ablation", "report"])
def test_commands_refuse_a_folder_another_run_writes(command, tmp_path, capsys, monkeypatch):
    """The lock is wired into the commands: each stops at once (before any work) with one
    line naming the folder and the other pid, and leaves the folder as it was."""
    from cli_runner import run_cli
    from test_train import make_pairs

    folder = tmp_path / "out"
    pairs = make_pairs(tmp_path / "pairs") if command in ("train", "ablation") else None
    if command == "report":
        folder.mkdir()
        (folder / "report.json").write_text("{}")
    args = {
        "demo": ["demo", "--quick", "--quiet", "-o", str(folder)],
        "train": ["train", str(pairs), "-o", str(folder), "--width", "8", "--depth", "2", "--crop", "32", "--quiet"],
        "ablation": ["ablation", str(pairs), "-o", str(folder), "--time-budget-s", "1", "--crop", "32"],
        "report": ["report", str(folder)],
    }[command]
    proc = _hold_in_subprocess(folder)
    try:
        before = sorted(p.name for p in folder.iterdir())
        code, _, err = run_cli(args, capsys, monkeypatch)
        assert code == 2 and err.count("\n") == 1, err
        assert f"{folder}: another lensim run (pid {proc.pid} on " in err
        assert sorted(p.name for p in folder.iterdir()) == before
    finally:
        proc.kill()
        proc.wait()
