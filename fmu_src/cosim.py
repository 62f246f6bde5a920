"""Co-simulation engine of the LMNCell FMU, independent of the FMI wrapper (numpy + stdlib).

Communication steps and the model sample time Ts: inputs are held over each communication step.
The engine integrates them; whenever a full Ts has been covered it takes one model step with the
means over that Ts (a communication step that is a multiple of Ts gives that many sub-steps with
the held input; a shorter or uneven step is accumulated exactly across calls). Outputs are those
of the last completed model step. This is the resampling rule of training (step means), so the FMU
and the pipeline see the same inputs. Between model steps (a communication step shorter than Ts
ended inside one) the voltage is the step in progress previewed: taken on a copy, and not kept,
as if the latest current input had been held over the whole step (with a current delay δ and a
communication step shorter than δ, the mean current of the open delayed window instead), the
temperature input's mean so far (CellCosim._preview). A host that steps at a record's 10 Hz
samples then sees the cell's response to each sample's current, not to the mean current so far
(tests/test_fmu.py, test_between_model_steps_the_voltage_follows_the_latest_input).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .model import CAPACITY_RANGE_AH, LmnModel, is_cell_capacity
from .observers import OBSERVER_NAMES, SocObserver
from .step import CellStepper, CellThermal
from .thermal import CELL_TEMPERATURE_RANGE_C, DEFAULT_TEMPERATURE_C

STEP_TOL = 1e-9   # a model step completes when its covered time is within STEP_TOL·Ts of Ts
MAX_C_RATE = 1000.0          # |current| beyond 1000 C is refused as not physical
VOLTAGE_MARGIN_V = 0.1   # out_of_range also when the model's voltage leaves the trained
# voltage range by more than this (a free run beyond its data: a cold knee extrapolated below
# the SoC its records reached went to −1.1 V with current, SoC and temperature in range)
CURRENT_MARGIN = 0.05       # out_of_range: the current beyond a trained bound by 5 % of it
CURRENT_MARGIN_A = 1e-3     # … plus 1 mA,
SOC_MARGIN = 0.02           # the SoC beyond the trained range by 0.02,
TEMPERATURE_MARGIN_K = 2.0  # the cell temperature by 2 K (where the model has a trained range)
OUT_OF_RANGE_DESCRIPTION = (
    "true while current, SoC or temperature leave the trained region or the model's voltage "
    f"its trained range by more than {VOLTAGE_MARGIN_V:g} V (the model extrapolates)")
MIN_TEMPERATURE_C, MAX_TEMPERATURE_C = CELL_TEMPERATURE_RANGE_C   # a `temperature` input
# outside it is refused: no cell runs there, and 298.15 is a temperature in K
MAX_STEPS_PER_CALL = 10_000_000   # model steps one communication step may span (116 days at
# Ts = 1 s, about 2.5 min of this engine): a longer step is refused, where it would hold the
# host for hours, or for ever once Ts no longer changes the remaining time (h ≳ 1e16·Ts)
STOP_TOLERANCE = 1e-8   # how far (relative, at least 1 s times it) a communication step may end
# past the stop time a host defined in fmi2SetupExperiment: a grid's rounding (fmpy: 1e-9)
ACCUMULATORS = 9   # get_state's "acc": the step's five, the current delay's three, the preview's
#                   current


def held_delayed_currents(current_a: list[float], ts: float, delay_s: float) -> list[float]:
    """The currents a model with current delay δ = delay_s takes, step by step, when it is
    given current_a held over successive communication steps of exactly Ts (what
    CellCosim.advance computes, in the same operations): (δ·i(k−1) + (Ts − δ)·i(k))/Ts, with
    i(−1) = i(0)."""
    if not delay_s or not current_a:
        return list(current_a)
    out = []
    covered, charge = delay_s, current_a[0] * delay_s
    for i in current_a:
        take = ts - covered              # the delayed window closes first, δ before the step
        charge += i * take
        out.append(charge / ts)
        covered = ts - take              # then the rest of the step opens the next one
        charge = i * covered
    return out


class InputError(ValueError):
    """A non-finite or impossible input; the message names the variable."""


def trained_bounds(model: LmnModel) -> tuple[float, ...]:
    """(current lo, hi (A), SoC lo, hi, cell temperature lo, hi (°C), model voltage lo, hi (V)):
    the model's trained region widened by the margins above, beyond which out_of_range is
    raised (and lmncell evaluate / simulate warn); ±∞ where the model has no such range. The
    temperature counts wherever the model has a trained range, whether or not it is in the
    partition: outside it a model extrapolates its temperature gains, or has none."""
    lim, inf = model.limits, math.inf
    lo, hi = lim.get("current_a", (-inf, inf))
    slo, shi = lim.get("soc", (-inf, inf))
    tlo, thi = lim.get("temperature_c", (-inf, inf))
    vlo, vhi = lim.get("voltage_v", (-inf, inf))
    return (lo - CURRENT_MARGIN * abs(lo) - CURRENT_MARGIN_A,
            hi + CURRENT_MARGIN * abs(hi) + CURRENT_MARGIN_A, slo - SOC_MARGIN, shi + SOC_MARGIN,
            tlo - TEMPERATURE_MARGIN_K, thi + TEMPERATURE_MARGIN_K, vlo - VOLTAGE_MARGIN_V,
            vhi + VOLTAGE_MARGIN_V)


@dataclass
class Parameters:
    soc0: float
    capacity_ah: float
    observer: int = 0
    temperature_is_cell: bool = False
    cell_temperature_start_c: float | None = None   # None: rested at the first step's input


def state_fault(exc: Exception) -> str:
    """What an exception raised while reading an FMU state says is wrong with it."""
    return f"no {exc}" if isinstance(exc, KeyError) else str(exc)


class CellCosim:
    """Holds a CellStepper, the partial-step accumulators and the trained-range flag."""

    def __init__(self, model: LmnModel, params: Parameters) -> None:
        self.model = model
        self.params = params
        self.reset()

    def reset(self, temperature_c: float = DEFAULT_TEMPERATURE_C) -> None:
        p = self.params
        if not 0.0 <= p.soc0 <= 1.0 or not math.isfinite(p.soc0):
            raise InputError(f"parameter 'soc0' = {p.soc0:g}: expected a fraction within 0..1")
        if not is_cell_capacity(p.capacity_ah):
            raise InputError(f"parameter 'capacity' = {p.capacity_ah:g}: expected a cell's "
                             "capacity within {:g}...{:g} Ah".format(*CAPACITY_RANGE_AH))
        if p.observer not in OBSERVER_NAMES:
            raise InputError(f"parameter 'observer' = {p.observer!r}: expected one of "
                             f"{OBSERVER_NAMES}")
        self.thermal = CellThermal(self.model, p.temperature_is_cell, p.cell_temperature_start_c)
        fault = self.thermal.start_fault()
        if fault:
            raise InputError(fault)
        t_cell = self.thermal.start(temperature_c)   # else the first step's input sets it
        self.observer: SocObserver | None = None
        if p.observer:
            self.observer = SocObserver(self.model, OBSERVER_NAMES[p.observer], p.soc0,
                                        p.capacity_ah, t_cell)
            self.stepper = self.observer.stepper
        else:
            self.stepper = CellStepper(self.model, p.soc0, p.capacity_ah, t_cell)
        self.covered_s = 0.0
        self.charge_as = 0.0
        self.temp_int = 0.0
        self.volt_int = 0.0
        self.volt_time = 0.0
        self.delay_covered_s = self.model.current_delay_s   # the delayed window (s, A·s)
        self.delay_charge_as = math.nan      # nan until the first input fills its start
        self.delayed_current_a = 0.0         # the last closed delayed window's mean (A)
        self.out_of_range = False
        self.range_message = ""
        self.steps = 0
        self.preview_v: float | None = None
        self.preview_current_a = 0.0     # the current the preview takes (A)
        self._start_temperature_c = t_cell
        self._bounds = trained_bounds(self.model)
        self._i_max = MAX_C_RATE * p.capacity_ah

    @property
    def voltage_v(self) -> float:
        """The terminal voltage now (V): the last model step's, or while a model step is
        partly covered (communication steps shorter than Ts) and no observer runs, that
        step's preview (preview_v)."""
        return self.stepper.voltage_v if self.preview_v is None else self.preview_v

    def _preview_current(self, step_s: float, current_a: float) -> float:
        """The current the preview takes after a communication step of step_s with the input
        current_a (A): that input, which the cell sees now unless the model's current delay δ
        is longer than the step; then the open delayed window's mean current (the last closed
        window's where it is empty)."""
        delay = self.model.current_delay_s
        if not delay or step_s >= delay:
            return current_a
        return (self.delay_charge_as / self.delay_covered_s if self.delay_covered_s > 0.0
                else self.delayed_current_a)

    def _preview(self) -> float | None:
        """The model step in progress taken, but not kept, as if the preview's current
        (_preview_current) had been held over the whole step, at the temperature input's mean
        over the part covered so far: the voltage now, which follows the current now instead
        of the mean current since the step began. None at a model-step boundary and with an
        observer (its outputs are the model steps')."""
        if self.covered_s <= 0.0 or self.observer:
            return None
        temp = self.thermal.next_temperature(self.temp_int / self.covered_s)
        saved = self.stepper.get_state()
        v = self.stepper.step(self.preview_current_a, temp)
        self.stepper.set_state(saved)
        return v

    @property
    def soc(self) -> float:
        return self.observer.state.soc if self.observer else self.stepper.soc

    @property
    def cell_temperature_c(self) -> float:
        """The cell temperature of the last step (°C); before the first step the rested cell
        at the last `temperature` input given (nan if none yet)."""
        t = self.thermal.temperature_c
        return t if t is not None else self._start_temperature_c

    @property
    def soc_std(self) -> float:
        """Observer's SoC standard deviation; 0 without an observer (coulomb counting)."""
        return self.observer.soc_std if self.observer else 0.0

    def check_range(self, current_a: float, temperature_c: float) -> str:
        """'' when inside the trained region, else a message (the model still extrapolates)."""
        ilo, ihi, slo, shi, tlo, thi = self._bounds[:6]
        soc = self.stepper.state.soc
        if ilo <= current_a <= ihi and slo <= soc <= shi and tlo <= temperature_c <= thi:
            return ""
        lim, msgs = self.model.limits, []
        if not ilo <= current_a <= ihi:
            lo, hi = lim["current_a"]
            msgs.append(f"current {current_a:.3f} A outside the trained {lo:.3f}..{hi:.3f} A")
        if not slo <= soc <= shi:
            lo, hi = lim["soc"]
            msgs.append(f"SoC {soc:.3f} outside the trained {lo:.3f}..{hi:.3f}")
        if not tlo <= temperature_c <= thi:
            lo, hi = lim["temperature_c"]
            msgs.append(f"temperature {temperature_c:.1f} degC outside the trained "
                        f"{lo:.1f}..{hi:.1f} degC")
        return "; ".join(msgs)

    def check_voltage(self) -> str:
        """'' while the model's voltage lies within the trained voltage range (± VOLTAGE_MARGIN_V),
        else a message."""
        v = self.stepper.voltage_v
        if self._bounds[6] <= v <= self._bounds[7]:
            return ""
        lim = self.model.limits.get("voltage_v")
        if lim is None:                  # a model without a voltage range: never flagged
            return ""
        return f"model voltage {v:.3f} V outside the trained {lim[0]:.3f}..{lim[1]:.3f} V"

    def advance(self, step_s: float, current_a: float, temperature_c: float = DEFAULT_TEMPERATURE_C,
                voltage_measured_v: float = 0.0) -> int:
        """Advance by one communication step with held inputs; returns model steps taken.

        voltage_measured_v ≤ 0 means "not measured". Raises InputError, with the state as it
        was, for an input that is not acceptable (naming the variable, or the step size where
        it spans more than MAX_STEPS_PER_CALL model steps) and where the model's arithmetic
        fails or its outputs are not finite, as the native FMU does.
        """
        i_max = self._i_max
        ts = self.model.sample_time_s
        if not (-i_max <= current_a <= i_max and MIN_TEMPERATURE_C <= temperature_c
                <= MAX_TEMPERATURE_C and 0.0 < step_s <= MAX_STEPS_PER_CALL * ts
                and math.isfinite(voltage_measured_v)):
            self._refuse(step_s, current_a, temperature_c, voltage_measured_v)
        before = self.get_state()
        try:
            taken = self._advance(step_s, current_a, temperature_c, voltage_measured_v)
            finite = self._outputs_finite()
        except (ArithmeticError, ValueError):   # OverflowError of math.exp, LinAlgError, …
            finite = False
        if not finite:
            self._restore(before)   # this instance's own state: no rollback needed
            raise InputError("the model produced a non-finite output (inputs far outside the "
                             "trained region?)")
        return taken

    def _outputs_finite(self) -> bool:
        """Whether every output and the preview are finite (the native FMU's outputs_finite)."""
        values = (self.voltage_v, self.soc, self.soc_std, self.cell_temperature_c)
        return all(math.isfinite(v) for v in values)

    def _advance(self, step_s: float, current_a: float, temperature_c: float,
                 voltage_measured_v: float) -> int:
        """advance() once its inputs are known to be acceptable."""
        ts = self.model.sample_time_s
        delay = self.model.current_delay_s
        if delay and math.isnan(self.delay_charge_as):   # before the start: the first current
            self.delay_charge_as = current_a * delay
        if step_s == ts and self.covered_s == 0.0 and not delay:   # the usual case
            self.covered_s = ts
            self.charge_as += current_a * ts
            self.temp_int += temperature_c * ts
            if voltage_measured_v > 0:
                self.volt_int += voltage_measured_v * ts
                self.volt_time += ts
            self._model_step()
            self.preview_v = None
            return 1
        remaining = step_s
        taken = 0
        while remaining > 0.0:           # every positive step counts, however short
            take = min(ts - self.covered_s, remaining)
            if delay:
                take = min(take, ts - self.delay_covered_s)
                self.delay_covered_s += take
                self.delay_charge_as += current_a * take
            self.covered_s += take
            self.charge_as += current_a * take
            self.temp_int += temperature_c * take
            if voltage_measured_v > 0:
                self.volt_int += voltage_measured_v * take
                self.volt_time += take
            remaining -= take
            if delay and self.delay_covered_s >= ts * (1.0 - STEP_TOL):
                self.delayed_current_a = self.delay_charge_as / ts
                self.delay_covered_s = self.delay_charge_as = 0.0
            if self.covered_s >= ts * (1.0 - STEP_TOL):
                self._model_step()
                taken += 1
                if remaining < STEP_TOL * ts:   # the rest is rounding of the step's end
                    remaining = 0.0
        self.preview_current_a = self._preview_current(step_s, current_a)
        self.preview_v = self._preview()
        return taken

    def _refuse(self, step_s: float, current_a: float, temperature_c: float,
                voltage_measured_v: float) -> None:
        """Raise InputError naming the first input of advance() that is not acceptable."""
        for name, val in (("current", current_a), ("temperature", temperature_c)):
            if not math.isfinite(val):
                raise InputError(f"input '{name}' = {val:g}: expected a finite number")
        if not math.isfinite(voltage_measured_v):
            raise InputError(f"input 'voltage_measured' = {voltage_measured_v:g}: expected a "
                             "finite number (0 when not measured)")
        if not math.isfinite(step_s) or step_s <= 0:
            raise InputError(f"communication step size {step_s:g} s: expected > 0 s")
        ts = self.model.sample_time_s
        if step_s > MAX_STEPS_PER_CALL * ts:
            raise InputError(f"communication step size {step_s:g} s: more than "
                             f"{MAX_STEPS_PER_CALL} model steps of {ts:g} s; expected at most "
                             f"{MAX_STEPS_PER_CALL * ts:g} s in one step (split it)")
        if abs(current_a) > self._i_max:
            raise InputError(f"input 'current' = {current_a:g} A: beyond {MAX_C_RATE:g} C of "
                             f"{self.params.capacity_ah:g} Ah, not a current a cell carries")
        raise InputError(f"input 'temperature' = {temperature_c:g} degC: expected "
                         f"{MIN_TEMPERATURE_C:g}..{MAX_TEMPERATURE_C:g} degC (degC, not K)")

    def _model_step(self) -> None:
        ts = self.model.sample_time_s
        i = self.delayed_current_a if self.model.current_delay_s else self.charge_as / ts
        temp_input = self.temp_int / ts
        temp = self.thermal.cell_temperature(temp_input)
        inputs = self.check_range(i, temp)
        if self.observer:
            v = self.volt_int / self.volt_time if self.volt_time >= ts * (1 - STEP_TOL) else 0.0
            self.observer.step(i, v if v > 0 else math.nan, temp)
        else:
            self.stepper.step(i, temp)
        volt = self.check_voltage()
        self.range_message = f"{inputs}; {volt}" if inputs and volt else inputs or volt
        self.out_of_range = bool(self.range_message)
        self.thermal.update(temp_input, i, self.stepper)
        self.steps += 1
        self.covered_s = self.charge_as = self.temp_int = 0.0
        self.volt_int = self.volt_time = 0.0

    # ----- state --------------------------------------------------------------------------
    def get_state(self) -> dict:
        return {"stepper": self.stepper.get_state(),
                "observer": self.observer.get_state() if self.observer else None,
                "acc": [self.covered_s, self.charge_as, self.temp_int, self.volt_int,
                        self.volt_time, self.delay_covered_s, self.delay_charge_as,
                        self.delayed_current_a, self.preview_current_a],
                "flags": [self.out_of_range, self.range_message, self.steps],
                "thermal": [self.thermal.temperature_c, self._start_temperature_c],
                "params": [self.params.soc0, self.params.capacity_ah, self.params.observer,
                           self.params.temperature_is_cell, self.params.cell_temperature_start_c]}

    def set_state(self, state: dict) -> None:
        """Restore a get_state() dict. One that cannot be restored (another shape, e.g. saved by
        another LMNCell version, or values of the wrong kind or out of range) is refused with a
        ValueError, and the instance stays as it was."""
        saved = self.get_state()
        try:
            self._restore(state)
        except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:
            self._restore(saved)
            raise ValueError(state_fault(exc)) from exc

    def _restore(self, state: dict) -> None:
        """set_state's work, which may stop half-way on a bad state."""
        acc = [float(x) for x in state["acc"]]
        if len(acc) != ACCUMULATORS:
            raise ValueError(f"'acc' holds {len(acc)} values, expected {ACCUMULATORS}")
        soc0, cap, obs, is_cell, start = state["params"]
        self.params = Parameters(float(soc0), float(cap), int(obs), bool(is_cell),
                                 None if start is None else float(start))
        self.reset()
        t_cell, t_last = state["thermal"]
        self.thermal.temperature_c = None if t_cell is None else float(t_cell)
        self._start_temperature_c = float(t_last)
        if self.observer:
            self.observer.set_state(state["observer"])
        else:
            self.stepper.load_state(list(state["stepper"]))
        (self.covered_s, self.charge_as, self.temp_int, self.volt_int, self.volt_time,
         self.delay_covered_s, self.delay_charge_as, self.delayed_current_a,
         self.preview_current_a) = acc
        self.out_of_range, self.range_message, self.steps = (
            bool(state["flags"][0]), str(state["flags"][1]), int(state["flags"][2]))
        self.preview_v = self._preview()
        if not self._outputs_finite():
            raise ValueError("its outputs are not finite")
