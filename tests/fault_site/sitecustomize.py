"""Installs the fault suite's disk quota (tests/faults.py) in every Python process that
starts with this folder on its path: a `lensim` subprocess and its Dask workers."""

import faults

faults.install_from_env()
