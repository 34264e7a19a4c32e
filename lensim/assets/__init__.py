"""Built-in assets: lenses (native format), and later sensors and sample images."""

from __future__ import annotations

from pathlib import Path

ASSETS_DIR = Path(__file__).parent
LENS_DIR = ASSETS_DIR / "lenses"
DEFAULT_LENS = "cooke_triplet"
DEFAULT_SENSOR = "apsc_mirrorless"  # fits inside the default lens's image circle


def lens_names() -> list[str]:
    """Names of the built-in lenses."""
    return sorted(p.stem for p in LENS_DIR.glob("*.yaml"))


def lens_path(name: str) -> Path | None:
    """Path of a built-in lens by name (None if there is none)."""
    p = LENS_DIR / f"{name}.yaml"
    return p if p.exists() else None
