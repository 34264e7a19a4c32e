"""Run the `lensim` console script in-process for tests (shared by the CLI test modules)."""

import sys
import warnings

import pytest

from lensim.cli import main


def run_cli(args: list[str], capsys, monkeypatch) -> tuple[int, str, str]:
    """Run `lensim ARGS` in this process exactly as the console script does; returns
    (exit status, stdout, stderr)."""
    monkeypatch.setattr(sys, "argv", ["lensim", *args])
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # run_guarded replaces it
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main()
    out, err = capsys.readouterr()
    code = exc.value.code
    return (0 if code is None else int(code)), out, err
