"""One way to make and save a figure: matplotlib Figures on their own Agg canvas (no
pyplot: nothing global is touched, nothing is shown), saved atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lensim.errors import InputError
from lensim.io import atomic_writer


def new_figure(
    size: tuple[float, float], layout: Literal["constrained", "compressed", "tight"] | None = None
) -> Figure:
    """A Figure of `size` (width, height) inches on its own Agg canvas; layout: None or a
    matplotlib layout engine name ("constrained", "tight")."""
    fig = Figure(figsize=size, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | Path, dpi: int = 150) -> Path:
    """Save a figure atomically (lensim.io.atomic_writer) and return its path; the format
    comes from the file name's extension (png, pdf, svg, ...)."""
    path = Path(path)
    fmt = path.suffix[1:].lower()
    supported = fig.canvas.get_supported_filetypes()
    if fmt not in supported:
        raise InputError(
            str(path),
            "output",
            f"expected a file name ending in one of {', '.join('.' + k for k in sorted(supported))}",
        )
    with atomic_writer(path, suffix=path.suffix) as fh:
        fig.savefig(fh, format=fmt, dpi=dpi)
    return path
