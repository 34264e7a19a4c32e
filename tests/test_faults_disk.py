"""A disk that fills up during a long command (tests/faults.DiskQuota: ENOSPC from write(),
as a full file system raises it). The command fails in one line naming the file it could
not write, exit status 2; what was in the output folder before is untouched, no half file
is left, and the rerun once there is space again ends with the outputs of an
uninterrupted run. In this process (one worker); with Dask workers and on a real, small
tmpfs under -m slow."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from cli_runner import run_cli
from fault_world import cli, differences
from faults import DiskQuota, folder_bytes, half_files, one_line_error, quota_env, run_lensim, snapshot

JOBS = ("bank", "grid", "pairs", "train", "restore")


def _start(out: Path) -> dict[str, bytes]:
    """An output folder holding a file of the user's: it must come through untouched."""
    out.mkdir(parents=True)
    (out / "notes.txt").write_text("the user's own notes\n")
    return snapshot(out)


def _rerun_args(world, job: str, out: Path, *more: str) -> list[str]:
    args = world.args(job, out, *more)
    return [*args, "--resume"] if job == "train" and (out / "last.pt").exists() else args


def _check_failure(world, job: str, out: Path, before: dict[str, bytes], code: int, err: str) -> None:
    line = one_line_error(err)
    assert code == 2, err
    assert "no space left on device" in line.lower() and str(out) in line, line
    assert not half_files(out), half_files(out)
    after = snapshot(out)
    assert all(after.get(k) == v for k, v in before.items()), "a file that was there before changed"


@pytest.mark.parametrize("job", [j if j != "grid" else pytest.param(j, marks=pytest.mark.slow) for j in JOBS])
def test_disk_full_fails_in_one_line_and_the_rerun_finishes_the_job(fault_world, tmp_path, capsys, monkeypatch, job):
    out = tmp_path / "out"
    before = _start(out)
    quota = DiskQuota(out, folder_bytes(out) + fault_world.size(job) // 2)
    with quota.installed():
        code, _, err = run_cli(fault_world.args(job, out), capsys, monkeypatch)
    assert quota.refusals, "the disk never filled up"
    _check_failure(fault_world, job, out, before, code, err)
    assert cli(_rerun_args(fault_world, job, out)) == 0
    assert differences(job, fault_world.reference(job), out) == []
    assert snapshot(out)["notes.txt"] == before["notes.txt"]


@pytest.mark.slow
@pytest.mark.parametrize("job", ("bank", "grid", "pairs", "restore"))
def test_disk_full_on_dask_workers(fault_world, tmp_path, job):
    out = tmp_path / "out"
    before = _start(out)
    env = quota_env(out, folder_bytes(out) + fault_world.size(job) // 2)
    code, _, err = run_lensim(fault_world.args(job, out, "--workers", "2"), env)
    _check_failure(fault_world, job, out, before, code, err)
    code, _, err = run_lensim(fault_world.args(job, out, "--workers", "2"))
    assert code == 0, err
    assert differences(job, fault_world.reference(job), out) == []


def _mount_tmpfs(where: Path, size: int) -> bool:
    where.mkdir(parents=True, exist_ok=True)
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    return res.returncode == 0


@pytest.mark.slow
@pytest.mark.parametrize("job", JOBS)
def test_disk_full_on_a_real_small_file_system(fault_world, tmp_path, job):
    """A tmpfs of half the job's output (where this machine lets us mount one)."""
    disk = tmp_path / "disk"
    size = (fault_world.size(job) // 2 + 4095) // 4096 * 4096
    if not _mount_tmpfs(disk, size):
        pytest.skip("cannot mount a tmpfs here")
    try:
        out = disk / "out"
        before = _start(out)
        more = ("--workers", "2") if job in ("pairs", "restore") else ()
        code, _, err = run_lensim(fault_world.args(job, out, *more))
        _check_failure(fault_world, job, out, before, code, err)
        subprocess.run(["mount", "-o", f"remount,size={4 * size + (1 << 20)}", str(disk)], check=True)
        code, _, err = run_lensim(_rerun_args(fault_world, job, out, *more))
        assert code == 0, err
        assert differences(job, fault_world.reference(job), out) == []
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)
