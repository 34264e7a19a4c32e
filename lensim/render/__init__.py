"""Rendering a sharp photo into what a camera would capture.

mapping (where an image lies on the sensor), kernels (the bank's kernel at image pixels,
the tile-centre grid), rotation (kernels turned to an image point's azimuth), blur
(seam-free spatially-variant convolution), distortion (the lens's warp), pipeline (the
capture stages, with hooks for the lens and the raw output). The banks themselves, cached by
the BankSettings that asked for them: lensim.psf.bank.get_bank.
"""
