"""LMNCell runtime: the LMN step, SoC and observers (numpy and the standard library only)."""
