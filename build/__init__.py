"""LMNCell FMU builders (``lmncell.fmu``): the pythonfmu FMU and the native C FMU."""
