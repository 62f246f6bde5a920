"""Experiment design: D-optimal excitation programmes and the virtual cells that prove them."""
