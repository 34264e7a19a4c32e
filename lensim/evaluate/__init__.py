"""Image-quality measurements: slanted-edge MTF (ISO 12233 style) and lateral colour."""

from lensim.evaluate.chromatic import EdgeShiftResult, PointShiftResult, lateral_color_edge, lateral_color_point
from lensim.evaluate.edge_target import make_slanted_edge
from lensim.evaluate.slanted_edge import (
    EdgeFit,
    MTFCurve,
    SFRResult,
    default_frequencies,
    edge_spread_function,
    locate_edge,
    mtf_area,
    mtf_area_ratio,
    mtf_from_psf,
    pixel_aperture_mtf,
    slanted_edge_mtf,
    slanted_edge_mtf_channels,
)

__all__ = [
    "EdgeFit",
    "EdgeShiftResult",
    "MTFCurve",
    "PointShiftResult",
    "SFRResult",
    "default_frequencies",
    "edge_spread_function",
    "lateral_color_edge",
    "lateral_color_point",
    "locate_edge",
    "make_slanted_edge",
    "mtf_area",
    "mtf_area_ratio",
    "mtf_from_psf",
    "pixel_aperture_mtf",
    "slanted_edge_mtf",
    "slanted_edge_mtf_channels",
]
