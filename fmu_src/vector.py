"""Many cells of one LMN model stepped at once with numpy (packs, sweeps): the same step as
step.CellStepper (and the same thermal model as step.CellThermal) on arrays over cells, plus
per-cell capacity and an overpotential scale for cell-to-cell spread.

Cell k's voltage is OCV(SoC_k) + r_k·ŷ_k for a relative-OCV model (r_k = 1: the model as
identified; r_k > 1: a cell whose resistances and polarisation are r_k times larger), or r_k·ŷ_k
for an absolute model. With r = 1 and the model's capacity every cell equals CellStepper
given the currents the model takes after its current delay, i.e. the FMU's engine.
"""

from __future__ import annotations

import numpy as np

from .cosim import trained_bounds
from .model import LmnModel
from .step import (
    CHARGE,
    DISCHARGE,
    CellThermal,
    arrhenius_gain,
    core_rise_coefficient,
    filter_coefficients,
    fixed_point,
    initial_hysteresis,
)
from .thermal import (
    DEFAULT_TEMPERATURE_C,
    heat_w,
    next_temperature,
    rested_temperature,
)


class VectorCells:
    """N cells: step(current_a (N,), temperature_c (N,) or scalar) → voltages (N,).

    temperature_is_cell False with a thermal model: the temperature given is the ambient and
    each cell heats up by its own losses (as the FMU's default), starting rested at the first
    step's ambient, or at cell_temperature_start_c (°C) where given (the FMU's
    use_cell_temperature_start; ValueError with the FMU's words where it would refuse it)."""

    def __init__(self, model: LmnModel, soc0: np.ndarray | float, n: int | None = None,
                 capacity_ah: np.ndarray | float | None = None,
                 resistance_scale: np.ndarray | float = 1.0,
                 temperature_c: float = DEFAULT_TEMPERATURE_C,
                 temperature_is_cell: bool = True,
                 cell_temperature_start_c: float | None = None) -> None:
        soc0 = np.atleast_1d(np.asarray(soc0, dtype=float))
        n = int(n if n is not None else soc0.size)
        self.model, self.n = model, n
        m, ts = model, model.sample_time_s
        cap = np.broadcast_to(np.asarray(model.capacity_ah if capacity_ah is None
                                         else capacity_ah, dtype=float), (n,)).copy()
        if not (np.isfinite(cap).all() and (cap > 0).all()):
            raise ValueError("capacity_ah: expected finite values > 0 Ah for every cell")
        self.r = np.broadcast_to(np.asarray(resistance_scale, dtype=float), (n,)).copy()
        self.soc_gain = ts / (3600.0 * cap)
        self.coef = np.array(filter_coefficients(m))
        self._taus = np.array(m.filter_taus())
        self.soc = np.broadcast_to(soc0, (n,)).copy()
        self.lp = np.zeros((n, 2 * len(m.filters)))
        self.h = np.array([initial_hysteresis(s) for s in self.soc])
        d0 = CHARGE if m.initial_direction == "charge" else DISCHARGE
        self.direction = np.full(n, d0, dtype=np.intp)
        self.past = np.zeros((n, m.current_terms - 1))
        self.core = np.zeros(n)         # LP_τ(i²) of the core rise (A²; step.ExoState.core)
        self._core_a = core_rise_coefficient(m)
        self.thermal_active = m.thermal is not None and not temperature_is_cell
        self._start_c = cell_temperature_start_c
        start = CellThermal(m, temperature_is_cell, cell_temperature_start_c)  # as the FMU's
        fault = start.start_fault()
        if fault:
            raise ValueError(fault)
        t0 = float(start.start(temperature_c))
        self.cell_temperature_c = np.full(n, float(t0))
        self._started = False
        y0 = np.array([fixed_point(m, float(s), t0, float(h)) for s, h in zip(self.soc, self.h,
                                                                              strict=True)])
        self.lags = np.repeat(y0[:, None], m.output_lags, axis=1)
        ocv0 = m.ocv(self.soc) if m.relative_ocv else 0.0
        self.voltage_v = ocv0 + self.r * y0
        self._src = np.array(m.temperature_source_indices(), dtype=np.intp)
        self._in_activation = np.array([m.in_activation_step(c)
                                        for c in m.temperature_term_sources()], dtype=bool)
        self._any_activation = bool(self._in_activation.any())
        self._depletion_states = ([] if m.depletion is None
                                  else m.depletion.state_indices(m.filters))
        self._bounds = trained_bounds(m)
        self.out_of_range = np.zeros(n, dtype=bool)
        self._delay_share = m.current_delay_s / ts        # δ/Ts of the model's current delay
        self._last_input: np.ndarray | None = None        # the last step's currents given (A)

    # ----- the step ---------------------------------------------------------------------------
    def _features(self, i: np.ndarray, t: np.ndarray, soc: np.ndarray, lp: np.ndarray,
                  h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, n = self.model, self.n
        g = arrhenius_gain(t, m.arrhenius_k, n, m.reference_temperature_c, m.activation_t0_k)
        cols = [g * i, *(g * self.past[:, k] for k in range(self.past.shape[1])),
                *(g * (lp[:, 2 * f] - lp[:, 2 * f + 1]) for f in range(len(m.filters)))]
        if m.hysteresis_gamma is not None:
            cols.append(h)
        if m.depletion is not None:
            factor = m.depletion.factors(soc)
            cols += [g * lp[:, k] * factor for k in self._depletion_states]
        if m.ocv_input:
            cols.append(m.ocv(soc))
        if m.soc_input:
            cols.append(soc)
        if m.offset:
            cols.append(np.ones(n))
        x = np.column_stack(cols)
        if m.temperature_terms:
            dt = m.temperature_step(t)
            da = m.activation_step(t, g) if self._any_activation else dt
            terms, power, power_a = [], np.ones(n), np.ones(n)
            for _ in range(m.temperature_terms):
                power, power_a = power * dt, power_a * da
                term = power[:, None] * x[:, self._src]
                if self._any_activation:      # those columns in dA instead
                    term[:, self._in_activation] = (power_a[:, None]
                                                    * x[:, self._src[self._in_activation]])
                terms.append(term)
            x = np.hstack([x, *terms])
        z = np.zeros((n, len(m.partition_variables)))
        for k, name in enumerate(m.partition_variables):
            z[:, k] = {"soc": soc, "current": i, "temperature": t}.get(
                name, lp[:, 1] if lp.shape[1] else i)
        return x, z

    def _coefficients(self, t: np.ndarray) -> np.ndarray:
        """The filter coefficients per cell (N, 2F) at the cells' temperatures (°C), or those
        of the file's time constants (2F,) without Eτ (step.filter_coefficients)."""
        m = self.model
        if m.tau_activation_k is None:
            return self.coef
        k = arrhenius_gain(t, m.tau_activation_k, self.n, m.reference_temperature_c,
                           m.activation_t0_k)
        return np.exp(-m.sample_time_s / (self._taus[None, :] * k[:, None]))

    def _advance(self, i: np.ndarray, t: np.ndarray):
        """The state after one step and the voltage, without storing anything (t: the cells'
        temperatures, °C; the core rise is added here)."""
        m = self.model
        eta = np.where(i > 0, m.efficiency_charge, m.efficiency_discharge)
        soc = self.soc + self.soc_gain * eta * i
        core = self.core
        if m.core_rise_k_per_a2:        # the temperature the LMN takes (ExoStepper.update)
            core = self._core_a * core + (1.0 - self._core_a) * i * i
            t = t + m.core_rise_k_per_a2 * core
        coef = self._coefficients(t)
        lp = coef * self.lp + (1.0 - coef) * i[:, None]
        h = self.h
        if m.hysteresis_gamma is not None:
            e = np.exp(-m.hysteresis_gamma * np.abs(i) * self.soc_gain)
            h = e * self.h + (1.0 - e) * np.sign(i)
        rest = m.rest_current_a
        direction = np.where(i > rest, CHARGE, np.where(i < -rest, DISCHARGE, self.direction))
        x, z = self._features(i, t, soc, lp, h)
        A, b, _ = m.blend(x, m.normalise(z), direction)
        y = b + np.sum(A * self.lags, axis=1) if m.output_lags else b
        u = (m.ocv(soc) if m.relative_ocv else 0.0) + self.r * y
        return soc, lp, h, direction, core, y, u

    def _temperatures(self, temperature_c: np.ndarray) -> np.ndarray:
        if not self.thermal_active:
            return temperature_c
        if not self._started and self._start_c is None:
            self.cell_temperature_c = rested_temperature(self.model.thermal, temperature_c)
        return self.cell_temperature_c

    def _taken(self, current_a: np.ndarray) -> np.ndarray:
        """The currents the model takes in a step given current_a (A) held over it: with a
        current delay δ, (δ·i(k−1) + (Ts − δ)·i(k))/Ts, i(−1) = i(0), as the FMU takes them
        (cosim.held_delayed_currents)."""
        if not self._delay_share:
            return current_a
        last = current_a if self._last_input is None else self._last_input
        return self._delay_share * last + (1.0 - self._delay_share) * current_a

    def peek(self, current_a: np.ndarray, temperature_c: np.ndarray | float) -> np.ndarray:
        """The voltages a step with these currents would give; nothing changes."""
        i = self._taken(np.asarray(current_a, dtype=float))
        t = np.broadcast_to(np.asarray(temperature_c, dtype=float), (self.n,))
        started, cell = self._started, self.cell_temperature_c
        u = self._advance(i, self._temperatures(t))[-1]
        self._started, self.cell_temperature_c = started, cell
        return u

    def _outside(self, i: np.ndarray, soc: np.ndarray, t: np.ndarray,
                 u: np.ndarray) -> np.ndarray:
        """Per cell, the FMU's out_of_range for a step (cosim.trained_bounds): its current (A),
        its SoC at the step's start, the cell temperature it was taken at (°C) or its voltage
        after it (V) beyond the trained region and its margins."""
        ilo, ihi, slo, shi, tlo, thi, vlo, vhi = self._bounds
        return ~((ilo <= i) & (i <= ihi) & (slo <= soc) & (soc <= shi) & (tlo <= t) & (t <= thi)
                 & (vlo <= u) & (u <= vhi))

    def step(self, current_a: np.ndarray, temperature_c: np.ndarray | float) -> np.ndarray:
        """One model step of every cell (currents held over it, > 0 charges; with a current
        delay the model takes them δ late, _taken); the voltages. out_of_range then says which
        cells left the trained region in it."""
        given = np.array(current_a, dtype=float)
        i = self._taken(given)
        self._last_input = given
        t_in = np.broadcast_to(np.asarray(temperature_c, dtype=float), (self.n,))
        t = self._temperatures(t_in)
        soc_before = self.soc
        self.soc, self.lp, self.h, self.direction, self.core, y, self.voltage_v = \
            self._advance(i, t)
        self.out_of_range = self._outside(i, soc_before, t, self.voltage_v)
        if self.past.shape[1]:
            self.past = np.column_stack([i, self.past[:, :-1]])
        if self.model.output_lags:
            self.lags = np.column_stack([y, self.lags[:, :-1]])
        self._started = True
        thermal = self.model.thermal
        if self.thermal_active and thermal is not None:    # active: the model has one
            q = heat_w(i, self.voltage_v, self.model.ocv(self.soc))
            self.cell_temperature_c = next_temperature(thermal, t, t_in, q,
                                                       self.model.sample_time_s)
        else:
            self.cell_temperature_c = t_in.copy()
        return self.voltage_v
