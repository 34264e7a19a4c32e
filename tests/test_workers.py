"""lensim.workers.run_jobs, the one engine of `psf bank`, `dataset make` and `restore`: jobs run here
or on a Dask cluster given by address with the same results, errors cross as themselves,
a scheduler that does not answer is one line. (Local clusters and their workers' death
with the parent: tests/test_kill_resume.py.)"""

from __future__ import annotations

import socket
import warnings

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.optics.lens_file import load_lens
from lensim.psf.bank import BankRequest, BankSettings, GridAxes, get_bank, get_banks
from lensim.workers import run_jobs


def _square(x: int) -> int:
    return x * x


def _refuse(x: int) -> int:
    if x == 2:
        raise InputError("job.yaml", "x", f"expected anything but 2, got {x}")
    return x


@pytest.fixture(scope="module")
def scheduler():
    """The address of a Dask cluster with two worker threads in this process (a cluster
    given by address, as `--scheduler` takes it)."""
    distributed = pytest.importorskip("distributed")
    threads = torch.get_num_threads()
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0") as c:
        yield c.scheduler_address
    torch.set_num_threads(threads)  # the jobs set one thread in their worker: this process


def test_jobs_here_report_each_result_and_keep_torch_threads():
    threads = torch.get_num_threads()
    got = []
    run_jobs(_square, [1, 2, 3], workers=1, on_result=lambda j, r: got.append((j, r)))
    assert got == [(1, 1), (2, 4), (3, 9)] and torch.get_num_threads() == threads
    run_jobs(_square, [], workers=4, on_result=lambda j, r: got.append((j, r)))  # nothing: no cluster
    assert len(got) == 3


def _broken(x: int) -> int:
    return {}[x]


def test_jobs_on_a_cluster_by_address(scheduler, capfd):
    got = {}
    run_jobs(_square, list(range(6)), scheduler=scheduler, on_result=lambda j, r: got.__setitem__(j, r))
    assert got == {j: j * j for j in range(6)}
    with pytest.raises(InputError, match="expected anything but 2") as e:
        run_jobs(_refuse, [1, 2, 3], scheduler=scheduler)
    assert (e.value.source, e.value.field) == ("job.yaml", "x")
    assert "Compute Failed" not in capfd.readouterr().err  # the one-line error only, no worker traceback logged
    with pytest.raises(KeyError) as k:  # a bug keeps the worker's traceback, as a note
        run_jobs(_broken, [7], scheduler=scheduler)
    assert any("in a Dask worker" in n and "_broken" in n for n in k.value.__notes__)


def test_bank_on_a_cluster_by_address_is_bitwise_the_bank_computed_here(scheduler, tmp_path):
    lens = load_lens("cooke_triplet")
    settings = BankSettings(fields=(0.0, 0.7, 1.0), wavelengths_nm=(500.0, 600.0), pupil_samples=32, kernel_pixels=15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        here = get_bank(lens, 4.0, settings, memory_only=True)
        calls = []
        there = get_bank(
            lens, 4.0, settings, scheduler=scheduler, out_dir=tmp_path / "b", progress=lambda d, t: calls.append((d, t))
        )
    assert calls[0] == (0, 3) and calls[-1] == (3, 3)
    for a, b in zip(here.fields, there.fields, strict=True):
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.primary_fine, b.primary_fine)
        assert a.strehl == b.strehl


def test_many_banks_and_a_grid_on_one_cluster_are_the_banks_computed_here(scheduler, tmp_path):
    lens = load_lens("cooke_triplet")
    settings = BankSettings(fields=2, wavelengths_nm=(550.0,), pupil_samples=32, kernel_pixels=15)
    axes = GridAxes(fno=(5.6, 8.0))
    requests = [
        BankRequest(lens, 4.0, settings, out_dir=tmp_path / "a"),
        # a second lens: the Cooke triplet at F/10
        BankRequest(lens.with_changes(aperture_value=5.0), 4.0, settings, out_dir=tmp_path / "b"),
        BankRequest(lens, 4.0, settings, shooting=axes, out_dir=tmp_path / "g"),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        there = get_banks(requests, scheduler=scheduler)
        here = [get_bank(r.lens, 4.0, settings, memory_only=True) for r in requests[:2]]
        here += [get_bank(lens, 4.0, settings, shooting=s, memory_only=True) for s in axes.settings()]
    banks = [there[0], there[1], there[2].bank(0), there[2].bank(1)]
    for a, b in zip(here, banks, strict=True):
        for fa, fb in zip(a.fields, b.fields, strict=True):
            assert np.array_equal(fa.rgb, fb.rgb)


def test_a_scheduler_that_does_not_answer_is_one_line():
    dask = pytest.importorskip("dask")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with dask.config.set({"distributed.comm.timeouts.connect": "0.5s"}), pytest.raises(InputError) as e:
        run_jobs(_square, [1, 2], scheduler=address)
    assert str(e.value).startswith(address) and "no Dask scheduler answered" in str(e.value)
    assert "\n" not in str(e.value)


def _malloc_trim(_job: int) -> str | None:
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


@pytest.mark.slow
def test_local_workers_keep_glibcs_malloc_trimming(monkeypatch):
    """A local cluster's worker processes start without Dask's MALLOC_TRIM_THRESHOLD_
    (which slows array work down: lensim.workers._local_cluster)."""
    pytest.importorskip("distributed")
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    got: list[str | None] = []
    run_jobs(_malloc_trim, [1, 2], workers=2, on_result=lambda j, r: got.append(r))
    assert got == [None, None]
