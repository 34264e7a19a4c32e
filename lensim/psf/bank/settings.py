"""How a PSF bank samples the field: normalized radial field positions."""
from __future__ import annotations

import numpy as np

from lensim.errors import InputError

DEFAULT_FIELDS = 64


def default_fields(n: int = DEFAULT_FIELDS) -> np.ndarray:
    """n normalized radial fields 0..1 spaced as sqrt(t), t uniform: denser towards the
    edge, where the PSF changes fastest and where the image area per field is largest.
    One field is the axis alone."""
    if n < 1:
        raise InputError(None, "fields", f"expected at least 1 field, got {n}")
    if n == 1:
        return np.zeros(1)
    return np.sqrt(np.arange(n) / (n - 1))
