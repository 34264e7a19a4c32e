"""Calibration and tolerancing, from the prescription to the lens in hand: printable charts,
their detection and pose in photos, the simulated-vs-photographed comparison (the paper's
Table 1), tolerance draws, perturbed lenses, as-built fitting. Import the modules
themselves (lensim.calibrate.chart, lensim.calibrate.tolerances, ...)."""
