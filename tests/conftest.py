import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_LENSES = REPO.parent / "shared" / "lenses"


@pytest.fixture(scope="session")
def shared_lenses() -> Path:
    """../shared/lenses beside the checkout (present on every developer machine and in CI)."""
    assert SHARED_LENSES.is_dir(), f"expected the reference lenses at {SHARED_LENSES}"
    return SHARED_LENSES
