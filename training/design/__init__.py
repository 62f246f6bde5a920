"""Experiment design: D-optimal excitation programmes and the virtual cells that prove them.

The names each choice accepts live here (no numerical imports) so that the CLI offers them
without loading the design code."""

DESIGN_METHODS = ("spacefill", "slsqp")      # see optimal.design_sequence
INFORMATION_KINDS = ("lmn", "rc")            # see optimal.sensitivities
VIRTUAL_CELLS = ("pybamm", "builtin")        # see proof.make_virtual_cell

# how far --capacity may lie from the capacity of the cell a design is for: beyond it a virtual
# cell's (what its slow discharge delivers) is refused and a --model's noted. The pulse tests and
# the design are placed on SoC with --capacity: 2.85 Ah given for the 2.30 Ah PyBaMM cell made
# every LMN of the proof 5…10 times worse.
CAPACITY_TOLERANCE = 0.03
