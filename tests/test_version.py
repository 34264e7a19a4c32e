"""The version is written once, in lensim/__init__.py; pyproject.toml reads it."""

from pathlib import Path

import lensim

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def test_pyproject_takes_the_version_from_the_package():
    from setuptools.config.pyprojecttoml import read_configuration

    written = read_configuration(PYPROJECT, expand=False)["project"]
    assert "version" not in written and "version" in written["dynamic"]
    assert read_configuration(PYPROJECT)["project"]["version"] == lensim.__version__
