"""Lumped thermal model of the cell (numpy-free; used by the runtime, the FMU and training).

One thermal mass with heat capacity C (J/K) that exchanges heat with the ambient through a
thermal resistance R (K/W); time constant τ = R·C. Heat: the irreversible loss of the step,
q(k) = i(k)·(u(k) − OCV(SoC(k))) (W; ≥ 0 for a resistive cell whatever the sign of the current,
current > 0 charges). Exact discretisation at the sample time Ts with the heat held over the step:

    T(k) = T_amb(k) + offset + a·(T(k−1) − T_amb(k) − offset) + R·(1 − a)·q(k),  a = exp(−Ts/τ)

`offset` (K) is the rested cell's temperature above the given ambient (a chamber set point that
the chamber does not quite hold, or a thermocouple offset); identified with R and τ. The LMN's
step k uses T(k−1), the cell temperature at the start of the step, so the loop model → heat →
temperature → model has no algebraic loop. At the start of a record the cell is taken as rested
at T_amb + offset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeGuard, TypeVar

if TYPE_CHECKING:
    import numpy as np

CELL_TEMPERATURE_RANGE_C = (-60.0, 100.0)   # a cell's or an ambient temperature (degC) in
# the records the readers take, in --ambient and in the FMUs' `temperature` input: outside it a
# value is refused (298.15 is a temperature in K given as degC)

DEFAULT_TEMPERATURE_C = 25.0   # the temperature (degC) taken where none is given: a record
# without a temperature, a model step, simulation or FMU whose temperature is not set or not
# finite (the native FMU's generated header carries it too)

TEMPERATURE_DESCRIPTION = ("ambient temperature (the model computes the cell temperature); the "
                           "measured cell temperature with temperature_is_cell = true [degC]")
CELL_START_DESCRIPTION = ("the cell temperature at the start, where use_cell_temperature_start "
                          "is true: a cell warmer or colder than the ambient it starts in "
                          "[degC]")
USE_CELL_START_DESCRIPTION = ("true: the cell starts at cell_temperature_start (needs the thermal "
                              "model: temperature_is_cell false); false (default): rested at the "
                              "first ambient temperature")


def cell_start_fault(start_c: float, thermal_active: bool, temperature_is_cell: bool
                     ) -> str | None:
    """Why the FMU parameters use_cell_temperature_start = true and cell_temperature_start =
    start_c (°C) cannot be taken, or None: they need the thermal model active (a model with
    one, temperature_is_cell false) and a temperature within CELL_TEMPERATURE_RANGE_C. The
    native FMU logs the same messages."""
    if not thermal_active:
        why = ("temperature_is_cell = true" if temperature_is_cell else
               "this model has no thermal model")
        return (f"parameter 'use_cell_temperature_start' = true: {why}, so the temperature "
                "input is the cell temperature, from the first step on")
    low, high = CELL_TEMPERATURE_RANGE_C
    if not (math.isfinite(start_c) and low <= start_c <= high):
        return (f"parameter 'cell_temperature_start' = {start_c:g}: expected a cell temperature "
                f"within {low:g}...{high:g} degC")
    return None


def is_real_number(value: object) -> TypeGuard[float]:
    """A real number: an int or a float, not a bool (True is an int); for model files and the
    training settings alike (lmncell.runtime.model re-exports it)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class ThermalModel:
    """Parameters of the lumped model (see the module docstring)."""

    resistance_k_per_w: float
    time_constant_s: float
    offset_k: float = 0.0

    @property
    def heat_capacity_j_per_k(self) -> float:
        return self.time_constant_s / self.resistance_k_per_w

    def check(self, where: str) -> ThermalModel:
        """self, or ValueError naming `where` and the bad parameter."""
        for name, value, positive in (("resistance_k_per_w", self.resistance_k_per_w, True),
                                      ("time_constant_s", self.time_constant_s, True),
                                      ("offset_k", self.offset_k, False)):
            if not (is_real_number(value) and math.isfinite(value)
                    and (value > 0 or not positive)):
                raise ValueError(f"{where}: thermal.{name} is {value!r}, expected a finite "
                                 f"number{' > 0' if positive else ''}")
        return self

    def to_dict(self) -> dict:
        return {"resistance_k_per_w": self.resistance_k_per_w,
                "time_constant_s": self.time_constant_s, "offset_k": self.offset_k}


Value = TypeVar("Value", float, "np.ndarray")   # one cell's figure, or a pack's array of them


def heat_w(current_a: Value, voltage_v: Value, ocv_v: Value) -> Value:
    """Irreversible heat of a step (W): current times overpotential (elementwise on arrays
    too, as the functions below)."""
    return current_a * (voltage_v - ocv_v)


def step_coefficients(model: ThermalModel, sample_time_s: float) -> tuple[float, float]:
    """(a, R·(1 − a)) of the discretised model at the sample time."""
    a = math.exp(-sample_time_s / model.time_constant_s)
    return a, model.resistance_k_per_w * (1.0 - a)


def next_temperature(model: ThermalModel, temperature_c: Value, ambient_c: Value,
                     heat: Value, sample_time_s: float,
                     coefficients: tuple[float, float] | None = None) -> Value:
    """The cell temperature at the end of a step (°C) from the one at its start
    (coefficients: step_coefficients(model, sample_time_s), if already at hand)."""
    a, gain = coefficients or step_coefficients(model, sample_time_s)
    rest = ambient_c + model.offset_k
    return rest + a * (temperature_c - rest) + gain * heat


def rested_temperature(model: ThermalModel | None, ambient_c: Value) -> Value:
    """The temperature of a cell rested at ambient_c (°C)."""
    return ambient_c + (model.offset_k if model is not None else 0.0)
