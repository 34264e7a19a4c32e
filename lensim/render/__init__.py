"""Spatially-variant rendering of images through a PSF bank."""
