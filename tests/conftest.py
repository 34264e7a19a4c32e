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


@pytest.fixture
def one_torch_thread():
    """Run the test with one torch thread (training tests are steadier and no slower on a
    shared 2-core machine), restoring the count afterwards. Use it per module with
    ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def fault_world(tmp_path_factory):
    """The fault suite's jobs and their uninterrupted outputs (tests/fault_world.py), made once."""
    from fault_world import build_fault_world

    return build_fault_world(tmp_path_factory.mktemp("fault-world"))
