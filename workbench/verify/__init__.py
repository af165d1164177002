"""Nonlinear verification: the exported controller in closed loop with the full plant; sweeps."""
