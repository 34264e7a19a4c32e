"""JSON-ready copies of results: scalars with .item() (numpy, torch) become Python
numbers, tuples become lists, and non-finite floats become null (jsonable: results, where
a non-finite number means "none") or the strings "inf", "-inf", "nan" (strict_json: settings
and metadata, where an infinite focus distance keeps its meaning; from_strict reads them
back)."""

from __future__ import annotations

import math
from typing import Any


def jsonable(x):
    """A copy of x that json.dumps writes as strict JSON (NaN/inf -> None)."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if hasattr(x, "item") and getattr(x, "ndim", 0) == 0:
        return jsonable(x.item())
    return x


def strict_json(x: Any) -> Any:
    """A copy of x that json.dumps writes as strict JSON, non-finite floats as the strings
    "inf", "-inf", "nan" (float() reads them back); mapping keys become strings."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {str(k): strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict_json(v) for v in x]
    if hasattr(x, "item") and getattr(x, "ndim", 0) == 0:
        return strict_json(x.item())
    return x


NON_FINITE = ("inf", "-inf", "nan")  # the strings strict_json writes for non-finite floats


def from_strict(value: Any) -> Any:
    """One value as strict_json wrote it, read back: "inf", "-inf", "nan" become floats,
    anything else is returned as it is."""
    return float(value) if isinstance(value, str) and value in NON_FINITE else value
