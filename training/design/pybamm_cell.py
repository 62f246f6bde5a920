"""A physics-based virtual cell for judging experiment designs: PyBaMM's DFN (or SPMe) with the
Prada2013 A123 26650 LFP parameters (Prada et al., J. Electrochem. Soc. 160 (2013) A616), the
kind of cell the shipped A123 data come from. Needs the optional `sim` extra (`pip install
-e '.[sim]'` in the LMNCell clone); `lmncell.design.virtual_cell` is the built-in stand-in
without it.

Parameters changed from Prada2013 (PARAMETER_CHANGES, printed with every result):
- "Negative particle diffusivity [m2.s-1]" 3e-15 → 3e-13. With Prada's value (fitted at low
  rates) the graphite surface empties within 16 s at 20C and within 35 s at 10C from SoC 0.5 and
  the DFN hits 2.0 V, while the A123 26650 is rated for 10C continuous and 20C+ pulses; 3e-13 lies
  inside the published range for graphite (about 1e-14 … 1e-12 m²/s) and lets a 30 s 20C pulse
  at SoC 0.5 run (measured with this module: 0.30 V drop at once, 0.42 V after 30 s).

Every run is a current-driven solve (current held over each sample: the cycler's programme), the
voltage sampled at the end of each sample, 1 mV Gaussian measurement noise with a fixed seed,
and a check that the solve reached its final time (a voltage cut-off or a solver failure is an
error naming the run, the time and the reason, never a shorter record). Current > 0 charges
(PyBaMM's sign is the opposite); SI units.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from lmncell.data.records import DataError
from lmncell.design.optimal import held_soc


class VirtualCellRunError(DataError):
    """A programme the virtual cell cannot run to its end (a voltage limit or its solver);
    the message names the programme and where it stopped."""


PARAMETER_SET = "Prada2013"
PARAMETER_CHANGES: dict[str, float] = {"Negative particle diffusivity [m2.s-1]": 3e-13}
SOLVER_RTOL = 1e-6        # relative tolerance of IDAKLU (the default 1e-4 is ~0.3 mV at 3.3 V)
SOLVER_ATOL = 1e-8


def require_pybamm():
    """The pybamm module, or a clear error naming the extra that installs it."""
    try:
        import pybamm
    except ImportError as exc:
        raise DataError("--virtual-cell pybamm needs PyBaMM: pip install -e '.[sim]' in the "
                        "LMNCell clone (or use --virtual-cell builtin)") from exc
    pybamm.set_logging_level("ERROR")
    return pybamm


@dataclass
class PybammCell:
    """PyBaMM virtual cell with the same run() interface as the built-in VirtualCell."""

    capacity_ah: float = 2.3
    model: str = "DFN"
    changes: dict[str, float] = field(default_factory=lambda: dict(PARAMETER_CHANGES))
    noise_v: float = 0.001
    seed: int = 7
    solves: list[dict] = field(default_factory=list)

    def describe(self) -> str:
        import pybamm

        changed = ", ".join(f"{k} = {v:g}" for k, v in self.changes.items()) or "none"
        return (f"PyBaMM {pybamm.__version__} {self.model} with {PARAMETER_SET} (A123 26650 LFP), "
                f"IDAKLU rtol {SOLVER_RTOL:g}, atol {SOLVER_ATOL:g}; parameters changed: "
                f"{changed}; {1e3 * self.noise_v:g} mV measurement noise")

    def _parameters(self, pybamm):
        pv = pybamm.ParameterValues(PARAMETER_SET)
        pv.update(self.changes)
        return pv

    def _simulation(self, pybamm, pv, experiment=None):
        model = {"DFN": pybamm.lithium_ion.DFN, "SPMe": pybamm.lithium_ion.SPMe}[self.model]()
        solver = pybamm.IDAKLUSolver(rtol=SOLVER_RTOL, atol=SOLVER_ATOL)
        return pybamm.Simulation(model, parameter_values=pv, experiment=experiment,
                                 solver=solver)

    def run(self, current_a: np.ndarray, soc0: float, ts: float = 1.0,
            name: str = "programme") -> tuple[np.ndarray, np.ndarray]:
        """Terminal voltage (V, with noise) at the end of each sample and SoC (coulomb counted
        with capacity_ah) for a current (A, > 0 charges) held over each sample. Each run of
        equal samples is one solver step from the state the previous one left (a held current
        is a step input, which one interpolated solve would smear or step over)."""
        pybamm = require_pybamm()
        current_a = np.asarray(current_a, dtype=float)
        pv = self._parameters(pybamm)
        pv["Current function [A]"] = "[input]"
        sim = self._simulation(pybamm, pv)
        sim.build(initial_soc=soc0)
        n = current_a.size
        edges = np.concatenate([[0], np.flatnonzero(np.diff(current_a) != 0.0) + 1, [n]])
        u = np.empty(n)
        sol, t0 = None, 0.0
        for a, b in itertools.pairwise(edges):
            try:
                sol = sim.step(dt=ts * (b - a), inputs={"Current function [A]": -current_a[a]},
                               save=False, starting_solution=sol)
            except pybamm.SolverError as exc:
                raise VirtualCellRunError(f"virtual cell ({self.model}), {name}: the solve "
                                          f"failed at {t0:.0f} s: {exc}") from exc
            reached = float(sol.t[-1])
            if reached < t0 + ts * (b - a) - 1e-6:
                raise VirtualCellRunError(
                    f"virtual cell ({self.model}), {name}: the solve stopped at {reached:.1f} s "
                    f"of {ts * n:.1f} s ({sol.termination}); the programme leaves the cell's "
                    "voltage limits or its physics")
            t = np.minimum(t0 + ts * np.arange(1, b - a + 1), reached)
            u[a:b] = sol["Terminal voltage [V]"](t)
            t0 = reached
        self.solves.append({"name": name, "final_time_s": ts * n, "reached_s": t0,
                            "steps": int(edges.size - 1)})
        soc = held_soc(soc0, current_a, ts, self.capacity_ah)
        rng = np.random.default_rng(self.seed)
        return u + rng.normal(0.0, self.noise_v, u.size), soc

    def ocv_test(self, c_rate: float = 1 / 20, ts: float = 10.0) -> tuple[np.ndarray,
                                                                           np.ndarray,
                                                                           np.ndarray]:
        """A slow round trip as a cycler runs it: from full (initial SoC 0.999, just below the
        upper cut-off) discharge at c_rate until 2.0 V, then charge until 3.6 V; returns time
        (s), current (A, > 0 charges) and voltage (V, with noise), sampled every ts."""
        pybamm = require_pybamm()
        pv = self._parameters(pybamm)
        lo, hi = pv["Lower voltage cut-off [V]"], pv["Upper voltage cut-off [V]"]
        rate = f"C/{1 / c_rate:g}"
        exp = pybamm.Experiment([f"Discharge at {rate} until {lo} V",
                                 f"Charge at {rate} until {hi} V"], period=f"{ts:g} seconds")
        sim = self._simulation(pybamm, pv, experiment=exp)
        sol = sim.solve(initial_soc=0.999)
        v = np.asarray(sol["Terminal voltage [V]"].entries, dtype=float)
        if v.min() > lo + 0.05 or v[-1] < hi - 0.05:
            raise DataError(f"virtual cell ({self.model}) OCV test: it did not run from "
                            f"{hi} V to {lo} V and back (voltage {v.min():.3f} … {v[-1]:.3f} V)")
        t = np.asarray(sol["Time [s]"].entries, dtype=float)
        keep = np.concatenate([[True], np.diff(t) > 1e-9])  # steps share their boundary time
        i = -np.asarray(sol["Current [A]"].entries, dtype=float)
        self.solves.append({"name": "OCV test", "final_time_s": float(t[-1]),
                            "reached_s": float(t[-1]), "termination": str(sol.termination)})
        rng = np.random.default_rng(self.seed)
        return t[keep], i[keep], v[keep] + rng.normal(0.0, self.noise_v, int(keep.sum()))
