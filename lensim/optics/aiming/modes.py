"""The ray-aiming modes, in plain Python (no NumPy or torch): the command line checks and
names them without loading the ray tracer (lensim.optics.aiming re-exports both names)."""

from __future__ import annotations

from typing import Literal, get_args

#: how a ray is aimed: through the paraxial entrance pupil, or iterated onto the real stop
Aiming = Literal["paraxial", "real"]

#: the ray-aiming names (the command line's --aiming)
AIMINGS: tuple[str, ...] = get_args(Aiming)
