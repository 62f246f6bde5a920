"""Scenarios: vehicle drive cycles turned into cell current and driven through an FMU."""
