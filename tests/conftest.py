from pathlib import Path

import pytest

from reference_lenses import REFERENCE_LENSES


@pytest.fixture(scope="session")
def reference_lenses() -> Path:
    """The vendored reference lens files (tests/data/lenses, published design data)."""
    return REFERENCE_LENSES


@pytest.fixture(scope="session")
def world(tmp_path_factory):
    """Valid inputs for the hostile-input suite (tests/hostile_world.py), made once."""
    from hostile_world import build_world

    return build_world(tmp_path_factory.mktemp("world"))
