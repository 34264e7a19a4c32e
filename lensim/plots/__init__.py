"""Every figure lensim draws, in one style: lens layouts and spot diagrams
(lensim.plots.lens), PSF-bank figures (lensim.plots.bank). Figures are made with
new_figure and written with save_figure (lensim.plots.figure)."""

from lensim.plots.figure import new_figure, save_figure

__all__ = ["new_figure", "save_figure"]
