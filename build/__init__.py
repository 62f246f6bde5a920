"""LMNCell FMU build recipes (imported as ``lmncell_build``)."""
