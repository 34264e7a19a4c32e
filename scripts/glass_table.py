"""Write lensim/assets/glasses/nd_vd.json: every catalogue glass's nd and Vd from its own
dispersion formula (lensim.optics.materials.twin_table_rows), the table that matches a
patent's nd/Vd pairs to catalogue glasses without loading the six catalogues. Run it after
upgrading opticalglass: python scripts/glass_table.py"""

from __future__ import annotations

import importlib.metadata
import json

from lensim.assets import ASSETS_DIR
from lensim.io import atomic_write_text
from lensim.optics.materials import TWIN_TABLE, twin_table_rows


def main() -> None:
    rows = twin_table_rows()
    source = (
        f"opticalglass {importlib.metadata.version('opticalglass')}: each glass's nd and Vd from its own "
        "dispersion formula (lensim.optics.materials.twin_table_rows)"
    )
    body = ",\n".join("    " + json.dumps(r, ensure_ascii=False) for r in rows)
    atomic_write_text(
        ASSETS_DIR / TWIN_TABLE, f'{{\n  "source": {json.dumps(source)},\n  "glasses": [\n{body}\n  ]\n}}\n'
    )
    print(f"{len(rows)} glasses written to {ASSETS_DIR / TWIN_TABLE}")


if __name__ == "__main__":
    main()
