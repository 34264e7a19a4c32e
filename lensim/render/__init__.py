"""Rendering a sharp photo into what a camera would capture.

mapping (where an image lies on the sensor), kernels (the bank's kernel at image pixels,
the tile-centre grid), blur (seam-free spatially-variant convolution), distortion (the
lens's warp), pipeline (the capture stages, with hooks for the lens and the raw output),
bank_cache (PSF banks cached by what they were computed from).
"""
