"""Experiment design: D-optimal excitation programmes and the virtual cells that prove them.

The names each choice accepts live here (no numerical imports) so that the CLI offers them
without loading the design code."""

DESIGN_METHODS = ("spacefill", "slsqp")      # see optimal.design_sequence
INFORMATION_KINDS = ("lmn", "rc")            # see optimal.sensitivities
VIRTUAL_CELLS = ("pybamm", "builtin")        # see proof.make_virtual_cell
