"""The CLI's glibc allocator setting (lensim.cli.allocator): applied through mallopt on
glibc, left alone when the user set the equivalent environment variables."""

from __future__ import annotations

import ctypes.util
import platform

import pytest

from lensim.cli.allocator import keep_freed_memory


def test_user_variables_take_precedence(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("MALLOC_MMAP_MAX_", "65536")
    assert keep_freed_memory() is False
    monkeypatch.delenv("MALLOC_MMAP_MAX_")
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "131072")
    assert keep_freed_memory() is False


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_applied_on_glibc(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("MALLOC_MMAP_MAX_", raising=False)
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    assert ctypes.util.find_library("c")
    assert keep_freed_memory() is True


def test_the_cli_entry_point_applies_it(monkeypatch: pytest.MonkeyPatch):
    import lensim.cli as cli

    calls = []
    monkeypatch.setattr(cli, "keep_freed_memory", lambda: calls.append(1) or True)
    monkeypatch.setattr(cli, "run_guarded", lambda app: None)
    cli.main()
    assert calls == [1]
