"""Calibration and tolerancing: tolerance draws, perturbed lenses, as-built fitting."""
