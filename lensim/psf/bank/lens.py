"""Which lens goes with a bank: a bank stores the lens it was computed for (its manifest's
native-format mapping); bank_lens gives that lens, or checks that a lens given with the
bank is that lens, so a bank of another lens is never used silently."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.psf.bank.grid import GridBank
from lensim.psf.bank.types import PSFBank


def same_optics(a: dict, b: dict) -> bool:
    """Whether two native lens mappings describe the same optics (their names aside;
    JSON-normalized, so tuples and lists compare equal)."""

    def optics(d: dict) -> Any:
        return json.loads(json.dumps({k: v for k, v in d.items() if k != "name"}))

    return bool(optics(a) == optics(b))


def bank_lens(bank: PSFBank | GridBank, lens: Lens | None = None) -> Lens:
    """The lens to use with a bank (or grid of banks): the lens its manifest stores when
    `lens` is None (a grid's: its lens file's lens), else `lens` once it is checked to be
    that lens (names aside).

    Raises InputError naming the parameter `lens`: the bank records no lens and none is
    given, or the given lens is not the bank's."""
    from lensim.optics.lens_file import lens_from_dict, lens_to_dict

    stored = bank.lens if isinstance(bank, GridBank) else bank.manifest.get("lens")
    where = Path(bank.directory) if bank.directory is not None else "the bank"
    if lens is None:
        if not isinstance(stored, dict):
            raise InputError(str(where), "lens", "the bank records no lens; expected a lens to be given")
        return lens_from_dict(stored, source=f"{where} (manifest lens)")
    if isinstance(stored, dict) and not same_optics(lens_to_dict(lens), stored):
        raise InputError(
            lens.source,
            "lens",
            f"not the lens the bank {where} was computed for ({stored.get('name') or 'unnamed'}); expected that lens",
        )
    return lens
