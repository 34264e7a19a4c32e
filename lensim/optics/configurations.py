"""Lens configurations: zoom positions, focus positions, any named set of thicknesses.

A lens may declare configurations (``Lens.configurations``): an ordered mapping of
configuration name -> {surface index: thickness (mm)}. Surface indices are 0-based into
``Lens.surfaces``, as in the native file's ``surfaces[i]`` (Zemax ``SURF i + 1``); the last
surface's thickness is its distance to the image plane. A configuration changes only the
thicknesses it names; every other value is the lens file's. The native file spells it

    configurations:
      wide: {thicknesses: {5: 20.1, 12: 3.2}}
      tele: {thicknesses: {5: 1.6, 12: 21.7}}

and Zemax multi-configuration ``THIC`` operands are read into it (lensim.optics.zemax).
``apply_configuration(lens, key)`` picks one by name or by 1-based number and returns the
lens at that position. Each configuration is validated with the lens (a thickness that
would put glass backwards or make two lens surfaces overlap is an error when the file is
loaded, naming the configuration).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

from lensim.errors import InputError

if TYPE_CHECKING:
    from lensim.optics.lens import Lens

#: {configuration name: {0-based surface index: thickness (mm)}}, in declaration order
Configurations = dict[str, dict[int, float]]


def configuration_field(name: str) -> str:
    """The field name errors use for a configuration: ``configurations.NAME``."""
    return f"configurations.{name}"


def check_configurations(lens: Lens) -> None:
    """Validate ``lens.configurations``: names, surface indices, finite thicknesses, and
    the lens each configuration gives (through Lens.validate). Raises InputError naming
    ``configurations.NAME`` and, for a bad lens, the surface."""
    n = len(lens.surfaces)
    for position, (name, thicknesses) in enumerate(lens.configurations.items(), start=1):
        fld = configuration_field(name)
        if not isinstance(name, str) or not name.strip():
            raise InputError(lens.source, "configurations", f"expected non-empty configuration names, got {name!r}")
        if name.strip().isdigit() and int(name) != position:
            raise InputError(
                lens.source,
                fld,
                f"a configuration named by a number must be that number in the "
                f"list (it is number {position}); give it a name that is not a number",
            )
        for index, thickness in thicknesses.items():
            if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < n:
                raise InputError(
                    lens.source,
                    f"{fld}.thicknesses",
                    f"expected surface indices 0..{n - 1} (0-based, as in surfaces[i]), got {index!r}",
                )
            if not math.isfinite(thickness):
                raise InputError(
                    lens.source, f"{fld}.thicknesses.{index}", f"expected a finite thickness, got {thickness}"
                )
        try:
            _configured(lens, name)
        except InputError as e:
            raise InputError(lens.source, fld, f"{e.field}: {e.message}" if e.field else e.message) from None


def _configured(lens: Lens, name: str) -> Lens:
    """The lens at configuration ``name`` (validated), with no configurations of its own."""
    thicknesses = lens.configurations[name]
    surfaces = [
        dataclasses.replace(s, thickness=thicknesses[i]) if i in thicknesses else s for i, s in enumerate(lens.surfaces)
    ]
    return lens.with_changes(surfaces=surfaces, configurations={})


def configuration_names(lens: Lens) -> list[str]:
    """The configuration names in declaration order (number k is names[k - 1])."""
    return list(lens.configurations)


def resolve_configuration(lens: Lens, key: str) -> str:
    """The name of the configuration ``key`` picks: a name (exact, else ignoring case) or a
    1-based number. An unknown key, or any key for a lens without configurations, is an
    InputError listing what there is."""
    names = configuration_names(lens)
    key = str(key).strip()
    if not names:
        raise InputError(
            lens.source,
            "configuration",
            f"the lens declares no configurations, so {key!r} cannot be chosen; leave the configuration out",
        )
    if key in lens.configurations:
        return key
    folded = [n for n in names if n.casefold() == key.casefold()]
    if len(folded) == 1:
        return folded[0]
    if key.isdigit() and 1 <= int(key) <= len(names):
        return names[int(key) - 1]
    listing = ", ".join(f"{k} ({n})" for k, n in enumerate(names, start=1))
    raise InputError(
        lens.source,
        "configuration",
        f"unknown configuration {key!r}; expected a name or a number 1..{len(names)}: {listing}",
    )


def apply_configuration(lens: Lens, key: str) -> Lens:
    """A new Lens at configuration ``key`` (a name, or a 1-based number as a string): the
    configuration's thicknesses replace the lens's; the new lens has no configurations
    (so that a second configuration is never applied on top of the first). The lens
    passed in is not changed."""
    return _configured(lens, resolve_configuration(lens, key))
