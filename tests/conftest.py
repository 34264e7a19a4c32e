from pathlib import Path

import pytest

from reference_lenses import REFERENCE_LENSES


@pytest.fixture(scope="session")
def reference_lenses() -> Path:
    """The vendored reference lens files (tests/data/lenses, published design data)."""
    return REFERENCE_LENSES
