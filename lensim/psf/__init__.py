"""Point spread functions: coherent Huygens superposition (the paper's optical PSF
model), Fourier-optics and geometric references, sampling checks, pixel integration,
metrics and PSF banks."""
