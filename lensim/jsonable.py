"""JSON-ready copies of results: non-finite floats become null, scalars with .item()
(numpy, torch) become Python numbers, tuples become lists."""
from __future__ import annotations

import math


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
