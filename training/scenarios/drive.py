"""Vehicle drive cycles, and cell current profiles, through the LMNCell FMU with fmpy
(`lmncell simulate`).

speed trace (m/s; lmncell.scenarios.traces) → longitudinal vehicle model → pack power → cell
power → cell current i = −P_cell / u_cell (current > 0 charges; u_cell is the FMU's voltage
of the previous step) → FMU. Wheel force F = k_rot·m·a + m·g·(c_r·cos θ + sin θ) + ½·ρ·c_d·A·v²;
battery power P = F·v/η_drive + P_aux when driving, max(F·v·η_regen, −P_regen,max) + P_aux
when braking.
A run stops where the cell is empty: its voltage below the discharge cut-off (by default the
lowest voltage of the model's training records, `cell.voltage_min_v` of the model file every
LMNCell FMU ships) or its SoC below 0; past that the figures would be those of a cell the model
was never trained on, discharged beyond its capacity. It stops too where the cell is full: its
SoC above 1, or for a current profile (run_profile) its voltage above the charge cut-off (by
default the highest voltage of the training records, `cell.voltage_max_v`).
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.data.records import DataError
from lmncell.report.jsontext import json_text
from lmncell.scenarios.traces import (
    CurrentProfile,
    SpeedTrace,
    load_current_profile,
    load_cycle,
    trace_title,
)

G = 9.81
CUTOFF_SHOWN_WITHIN_V = 0.3   # the plot draws the cut-off where the voltage comes this near


@dataclass
class Vehicle:
    name: str
    mass_kg: float
    rotational_inertia_factor: float
    drag_coefficient: float
    frontal_area_m2: float
    rolling_resistance: float
    air_density_kg_m3: float
    drivetrain_efficiency: float
    regen_efficiency: float
    regen_power_limit_w: float
    auxiliary_power_w: float
    n_series: int
    n_parallel: int


# (key, test, what is expected) of a vehicle file's physical values: a negative rolling
# resistance, auxiliary power or regen limit, or an inertia factor below 1, drove a run that
# made energy from nothing (a braking car that draws power, a heater that charges the pack)
VEHICLE_RANGES = (
    *((key, lambda v: v > 0, "> 0") for key in (
        "mass_kg", "drag_coefficient", "frontal_area_m2", "air_density_kg_m3", "n_series",
        "n_parallel")),
    ("rotational_inertia_factor", lambda v: v >= 1, "≥ 1 (rotating parts add to the mass)"),
    *((key, lambda v: v >= 0, "≥ 0") for key in (
        "rolling_resistance", "regen_power_limit_w", "auxiliary_power_w")),
    ("drivetrain_efficiency", lambda v: 0 < v <= 1, "0 < η ≤ 1"),
    ("regen_efficiency", lambda v: 0 <= v <= 1, "0 ≤ η ≤ 1 (0: no regenerative braking)"),
)


def _check_vehicle_values(values: dict, where: str) -> None:
    """DataError naming the key where a vehicle file's keys are not Vehicle's, or a value is
    not of its type: a finite number (the cell counts whole numbers), the name a string."""
    fields = {f.name: f.type for f in dataclasses.fields(Vehicle)}
    unknown, absent = sorted(set(values) - set(fields)), sorted(set(fields) - set(values))
    if unknown or absent:
        raise DataError(f"{where}: " + "; ".join(
            ([f"unknown key(s) {unknown}"] if unknown else [])
            + ([f"missing key(s) {absent}"] if absent else []))
            + "; expected the keys of the shipped compact_ev.toml")
    for key, kind in fields.items():
        value = values[key]
        if kind == "str":
            ok, expected = isinstance(value, str), "a string"
        elif kind == "int":
            ok, expected = isinstance(value, int) and not isinstance(value, bool), "a whole number"
        else:
            ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
                  and math.isfinite(value))
            expected = "a finite number"
        if not ok:
            raise DataError(f"{where}: '{key}' = {value!r}; expected {expected}")


def load_vehicle(path: str | Path | None = None) -> Vehicle:
    """A vehicle TOML file ([vehicle] and [pack] tables; the vehicle's name, where not given,
    the file's; UTF-8, a byte-order mark skipped); None gives the default compact EV."""
    if path is None:
        text = resources.files("lmncell.scenarios").joinpath("vehicles/compact_ev.toml").read_text()
        where = "compact_ev.toml"
    else:
        where = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise DataError(f"{path}: cannot read the vehicle file ({exc.strerror})") from exc
        except UnicodeDecodeError as exc:
            raise DataError(f"{path}: cannot read the vehicle file (not UTF-8 text: {exc})"
                            ) from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise DataError(f"{where}: not a TOML file ({exc})") from exc
    missing = [t for t in ("vehicle", "pack") if not isinstance(doc.get(t), dict)]
    if missing:
        raise DataError(f"{where}: no {' or '.join(f'[{t}]' for t in missing)} table; expected "
                        "[vehicle] and [pack] tables as in the shipped compact_ev.toml")
    values = {"name": Path(where).stem, **doc["vehicle"], **doc["pack"]}   # name: optional
    _check_vehicle_values(values, where)
    veh = Vehicle(**values)
    for key, ok, expected in VEHICLE_RANGES:
        if not ok(getattr(veh, key)):
            raise DataError(f"{where}: '{key}' = {getattr(veh, key)!r}; expected {expected}")
    return veh


def pack_power(vehicle: Vehicle, speed: np.ndarray, grade: np.ndarray, dt: float) -> np.ndarray:
    """Battery power (W, > 0 discharging) for each interval of dt (s) of the trace."""
    v = speed
    a = np.diff(v, append=v[-1]) / dt
    v_mid = v + 0.5 * a * dt
    theta = np.arctan(grade)
    force = (vehicle.rotational_inertia_factor * vehicle.mass_kg * a
             + vehicle.mass_kg * G * (vehicle.rolling_resistance * np.cos(theta) * (v_mid > 0)
                                      + np.sin(theta))
             + 0.5 * vehicle.air_density_kg_m3 * vehicle.drag_coefficient
             * vehicle.frontal_area_m2 * v_mid**2)
    wheel = force * v_mid
    drive = wheel / vehicle.drivetrain_efficiency
    regen = np.maximum(wheel * vehicle.regen_efficiency, -vehicle.regen_power_limit_w)
    return np.where(wheel >= 0, drive, regen) + vehicle.auxiliary_power_w


@dataclass
class CycleResult:
    time_s: np.ndarray
    speed_mps: np.ndarray | None       # None: driven by a current profile, no vehicle
    current_a: np.ndarray
    voltage_v: np.ndarray
    soc: np.ndarray
    out_of_range: np.ndarray
    figures: dict
    cell_temperature_c: np.ndarray | None = None


def step_means(values: np.ndarray, dt: float, h: float, n: int) -> np.ndarray:
    """The mean over each communication step [k·h, (k+1)·h), k < n, of a series held over its
    samples (values[j] over [j·dt, (j+1)·dt)): the sample itself where a step lies inside one
    sample, else the time-weighted mean of those it covers (the energy of a coarse step is the
    cycle's, not that of the sample at its start)."""
    edges = np.arange(n + 1) * h
    integral = np.interp(edges, np.arange(values.size + 1) * dt,
                         np.concatenate([[0.0], np.cumsum(values * dt)]))
    means = np.diff(integral) / h
    first = np.minimum((edges[:-1] / dt + 1e-9).astype(int), values.size - 1)
    inside = edges[1:] <= (first + 1) * dt * (1.0 + 1e-12)
    means[inside] = values[first[inside]]
    return means


def shipped_cell(fmu: str | Path) -> Mapping[str, Any] | None:
    """The `cell` table of an LMNCell FMU's model file (resources/model.json), None without
    one."""
    from lmncell.evaluation.fmueval import shipped_model_doc

    return shipped_model_doc(fmu).get("cell")


def shipped_cutoff_v(fmu: str | Path, key: str = "voltage_min_v") -> float:
    """The discharge cut-off (V) of an LMNCell FMU's model file (resources/model.json), as
    cell_cutoff_v gives it (key "voltage_max_v": the charge cut-off)."""
    return cell_cutoff_v(shipped_cell(fmu), key)


def cell_cutoff_v(cell: Mapping[str, Any] | None, key: str = "voltage_min_v") -> float:
    """The discharge cut-off (V) of a model file's `cell` table: its voltage_min_v, the lowest
    terminal voltage of the training records (key "voltage_max_v": the charge cut-off, the
    highest); 0 (none) where it gives no positive number."""
    value = cell.get(key) if isinstance(cell, Mapping) else None
    if value is None:
        return 0.0
    try:
        volts = float(value)
    except (TypeError, ValueError):
        return 0.0
    return volts if math.isfinite(volts) and volts > 0.0 else 0.0


CUTOFF_EXPECTED = "a cell voltage in V, ≥ 0 and below 10 (0: no cut-off voltage)"


def is_cutoff(cutoff_v: float) -> bool:
    """Whether a value is a cut-off voltage (CUTOFF_EXPECTED); the CLI's and the API's check."""
    return math.isfinite(cutoff_v) and 0.0 <= cutoff_v < 10.0


def check_cutoff(cutoff_v: float, option: str = "--cutoff") -> float:
    """The cut-off voltage as given, or a DataError naming the option."""
    if not is_cutoff(cutoff_v):
        raise DataError(f"{option} {cutoff_v!r}: expected {CUTOFF_EXPECTED}")
    return float(cutoff_v)


def check_cutoff_in_range(cell: Mapping[str, Any] | None, cutoff_v: float,
                          option: str = "--cutoff", charge: bool = False) -> float:
    """A given cut-off (V) checked against the model's training voltages (a model file's
    `cell` table): a discharge cut-off at or above their highest, or a charge cut-off (charge)
    at or below their lowest, would end every run at its first step: DataError naming the
    option. 0 (none) passes."""
    low, high = cell_cutoff_v(cell), cell_cutoff_v(cell, "voltage_max_v")
    bound, own = (low, high) if charge else (high, low)
    if cutoff_v > 0.0 and bound > 0.0 and (cutoff_v <= bound if charge else cutoff_v >= bound):
        where, kind, side = (("at or below the lowest", "charge", "above") if charge else
                             ("at or above the highest", "discharge", "below"))
        raise DataError(f"{option} {cutoff_v:g} V: {where} voltage of the model's training "
                        f"records ({bound:.3f} V), so every run would stop at its first step; "
                        f"expected a {kind} cut-off {side} it (the model's own: {own:.3f} V)")
    return cutoff_v


def _given_cutoff(cell: Mapping[str, Any] | None, cutoff_v: float | None,
                  charge: bool = False) -> float:
    """The run's discharge cut-off (V), or with charge its charge cut-off: the model's own
    (its `cell` table, shipped_cell) for None, else the value given, checked (check_cutoff,
    check_cutoff_in_range)."""
    if cutoff_v is None:
        return cell_cutoff_v(cell, "voltage_max_v" if charge else "voltage_min_v")
    option = "--charge-cutoff" if charge else "--cutoff"
    return check_cutoff_in_range(cell, check_cutoff(cutoff_v, option), option, charge)


def empty_reason(voltage_v: float, soc: float, cutoff_v: float) -> str:
    """Why the cell counts as empty after a step ('' while it does not): its voltage below the
    cut-off (V) or its SoC below 0."""
    if voltage_v < cutoff_v:
        return f"cell voltage {voltage_v:.3f} V below the cut-off {cutoff_v:.3f} V"
    if soc < 0.0:
        return f"SoC {100 * soc:.2f} % below 0"
    return ""


class FmuStepError(DataError):
    """The FMU refused a step (fmi2Error) of a run: what it logged, and when (t_s, s)."""

    def __init__(self, message: str, t_s: float) -> None:
        super().__init__(message)
        self.t_s = t_s


MAX_CYCLE_STEPS = 2_000_000   # communication steps of one run_cycle (1 ms over the WLTC's
# 1800 s: 18 s of fmpy calls with the native FMU); more is refused, not left running for hours


def full_reason(voltage_v: float, soc: float, charge_cutoff_v: float = 0.0) -> str:
    """Why a charge stops after a step ('' while it does not): its voltage above the charge
    cut-off (V; 0: none) or its SoC above 1, beyond the capacity the model was trained on."""
    if 0.0 < charge_cutoff_v < voltage_v:
        return (f"cell voltage {voltage_v:.4f} V above the charge cut-off "
                f"{charge_cutoff_v:.4f} V")
    return "SoC above 100 %" if soc > 1.0 else ""


STEP_ERROR_PREFIX = "error: "   # a sweep row's stop where the FMU refused a step (FmuStepError)


def stop_kind(stop: str) -> str:
    """What a run's stop reason says of it: '' (it ran to the end), "error" (the FMU refused a
    step: STEP_ERROR_PREFIX), "full" (full_reason) or "empty" (empty_reason)."""
    if not stop:
        return ""
    if stop.startswith(STEP_ERROR_PREFIX):
        return "error"
    return "full" if " above " in stop else "empty"


def _communication_steps(fmu: str | Path, step_s: float | None, span_s: float,
                         what: str) -> tuple[Any, float, int]:
    """The FMU's model description (fmpy's, read once for the whole run), the communication
    step (s; step_s, or its default experiment's, or 1 s) and the number of whole steps over
    span_s; DataError where there are none or more than MAX_CYCLE_STEPS. what: the run as
    messages name it ("the UDDS cycle")."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    h = step_s or default_step_s(md)
    return md, h, whole_steps(h, span_s, what)


def default_step_s(md: Any) -> float:
    """The communication step of an FMU's default experiment (s; fmpy's model description),
    1 s where it gives none."""
    default = md.defaultExperiment
    return float(default.stepSize) if default and default.stepSize else 1.0


def step_count(span_s: float, h: float) -> int:
    """The number of whole steps of h (s) over span_s (s), a step that ends within 1e-9 of a
    step's length past the span counted: the runs and the sweep's pre-check count alike."""
    return math.floor(span_s / h + 1e-9)


def unrun_s(span_s: float, h: float, n: int) -> float:
    """The end of a run's span_s (s) that its n whole steps of h (s) leave unrun (s; 0 where
    they cover it to round-off): a step that does not divide the cycles drops what is left."""
    left = span_s - n * h
    return float(left) if left > 1e-9 * span_s else 0.0


def whole_steps(h: float, span_s: float, what: str) -> int:
    """The number of whole steps of h (s) over span_s (s) (step_count); DataError where there
    are none or more than MAX_CYCLE_STEPS. what: the run as messages name it ("the UDDS
    cycle")."""
    n = step_count(span_s, h)
    if n < 1:
        raise DataError(f"communication step {h:g} s: longer than {what} ({span_s:g} s); "
                        f"expected at most {span_s:g} s")
    if n > MAX_CYCLE_STEPS:
        raise DataError(f"communication step {h:g} s: {n} steps over {what} ({span_s:g} s), "
                        f"more than {MAX_CYCLE_STEPS}, which would take hours and gigabytes; "
                        f"expected a step of at least {span_s / MAX_CYCLE_STEPS:.3g} s")
    return n


def _drive_fmu(fmu: str | Path, md: Any, load: np.ndarray, by_power: bool, h: float,
               soc0: float, temperature_c: float, cutoff_v: float,
               charge_cutoff_v: float = 0.0, cell_temperature_start_c: float | None = None
               ) -> tuple[dict[str, np.ndarray], str, str]:
    """Step the FMU (md: its model description, fmpy's) with fmpy through one load value per
    communication step h (s): the cell
    power (W, > 0 discharging; by_power, i = −P/u with u the previous step's voltage) or the
    cell current (A, > 0 charges). Stops after the first step that leaves the cell empty
    (empty_reason) or full (full_reason). Returns the steps' time (s, each step's end),
    current, voltage, SoC, out-of-range flag and cell temperature (NaN without a thermal
    model), why it stopped early ('' where it did not), and the FMU's first warning (the
    start of its first out-of-range excursion: what left the trained region; '' for none)."""
    from fmpy import extract
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave
    from lmncell.evaluation.fmueval import first_warning, fmu_log

    vr = {v.name: v.valueReference for v in md.modelVariables}
    n = load.size
    out = {k: np.empty(n) for k in ("time", "current", "voltage", "soc", "oor", "cell_t")}
    has_cell_t = "cell_temperature" in vr
    outputs = [vr["voltage"], vr["soc"], *([vr["cell_temperature"]] if has_cell_t else [])]
    stop = ""
    unzipped = extract(str(fmu))
    with fmu_log("lmncell-cycle") as (name, callbacks, log):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        try:
            slave.instantiate(callbacks=callbacks, loggingOn=True)   # its warnings kept in log
            u = _initialised(slave, vr, soc0, temperature_c, cell_temperature_start_c, log,
                             FMICallException)
            for k in range(n):
                t0 = k * h
                i = -load[k] / u if by_power else float(load[k])
                u, soc, cell_t = _stepped(slave, vr, outputs, t0, h, i, log, FMICallException)
                out["time"][k], out["current"][k], out["voltage"][k] = t0 + h, i, u
                out["soc"][k], out["cell_t"][k] = soc, cell_t
                out["oor"][k] = slave.getBoolean([vr["out_of_range"]])[0]
                stop = empty_reason(u, soc, cutoff_v) or full_reason(u, soc, charge_cutoff_v)
                if stop:
                    n = k + 1
                    break
            slave.terminate()
        finally:
            slave.freeInstance()
            shutil.rmtree(unzipped, ignore_errors=True)
        first = first_warning(log, name)
    return {key: values[:n] for key, values in out.items()}, stop, first


def _initialised(slave: Any, vr: dict[str, int], soc0: float, temperature_c: float,
                 cell_temperature_start_c: float | None, log: list[str],
                 refused: type[Exception]) -> float:
    """Take the instantiated FMU through initialisation with the start SoC and temperature
    (°C; the cell starting at cell_temperature_start_c where given); returns its voltage (V)
    there. DataError where the FMU has no such parameter (built by an earlier LMNCell) or
    refuses the parameters, with what it logged."""
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["soc0"]], [soc0])
    slave.setReal([vr["temperature"]], [temperature_c])
    if cell_temperature_start_c is not None:
        if "use_cell_temperature_start" not in vr:
            raise DataError("a cell start temperature (--cell-temperature-start) was given, "
                            "but this FMU has no parameter use_cell_temperature_start (an "
                            "earlier LMNCell built it); build it again from its model with "
                            "lmncell build-fmu")
        slave.setReal([vr["cell_temperature_start"]], [cell_temperature_start_c])
        slave.setBoolean([vr["use_cell_temperature_start"]], [True])
    try:
        slave.exitInitializationMode()
    except refused:
        said = log[-1] if log else "nothing in its log"
        raise DataError(f"the FMU refused its parameters: {said}") from None
    return slave.getReal([vr["voltage"]])[0]


def _stepped(slave: Any, vr: dict[str, int], outputs: list[int], t0: float, h: float,
             current_a: float, log: list[str], refused: type[Exception]
             ) -> tuple[float, float, float]:
    """One communication step from t0 (s) over h (s) with the cell current (A, > 0 charges);
    returns the voltage (V), SoC and cell temperature (°C; NaN without that output) after it.
    FmuStepError where the FMU refuses the step (fmpy raises `refused`, its
    FMICallException, imported once per run by the caller, not once per step), with the last
    message of its log."""
    slave.setReal([vr["current"]], [current_a])
    try:
        slave.doStep(currentCommunicationPoint=t0, communicationStepSize=h)
    except refused:
        said = log[-1] if log else "nothing in its log"
        raise FmuStepError(f"the FMU refused the step at t = {t0:g} s with the cell current "
                           f"{current_a:g} A: {said}", t0) from None
    u, soc, *cell_t = slave.getReal(outputs)
    return u, soc, cell_t[0] if cell_t else math.nan


def _cell_figures(out: dict[str, np.ndarray], h: float, soc0: float, temperature_c: float,
                  cutoff_v: float, stop: str, first: str = "",
                  cell_temperature_start_c: float | None = None) -> dict:
    """The figures of any run (_drive_fmu's steps): duration, charge, energy, extremes, the
    FMU's first out-of-range warning (out_of_range_first, None without one) and the cell's
    start temperature where one was given."""
    cur, volt, n = out["current"], out["voltage"], out["time"].size
    has_cell_t = not np.isnan(out["cell_t"]).all()
    return {
        "step_s": h, "duration_s": float(n * h),
        "cell_energy_wh": float(np.sum(-cur * volt) * h / 3600.0),
        "ah_throughput": float(np.sum(np.abs(cur)) * h / 3600.0),
        "current_min_a": float(cur.min()), "current_max_a": float(cur.max()),
        "voltage_min_v": float(volt.min()), "voltage_max_v": float(volt.max()),
        "soc_start": soc0, "soc_end": float(out["soc"][-1]),
        "soc_swing": float(out["soc"].max() - out["soc"].min()),
        "out_of_range_steps": int(out["oor"].sum()), "out_of_range_first": first or None,
        "ambient_c": float(temperature_c), "cell_temperature_start_c": cell_temperature_start_c,
        "cell_temperature_max_c": float(np.max(out["cell_t"])) if has_cell_t else None,
        "cutoff_v": cutoff_v, "stop": stop, "stopped_at_s": float(n * h) if stop else None,
    }


def run_cycle(fmu: str | Path, cycle: str | Path | SpeedTrace = "wltc",
              vehicle: Vehicle | None = None,
              repeat: int = 1, soc0: float = 0.9, step_s: float | None = None,
              temperature_c: float = 25.0, cutoff_v: float | None = None,
              cell_temperature_start_c: float | None = None) -> CycleResult:
    """Drive the FMU through `repeat` copies of a cycle (a shipped cycle's name, a speed-trace
    file or a SpeedTrace: load_cycle) with fmpy; inputs held over each step (the cycle's mean
    power over a step longer than its samples, step_means; a step longer than the cycles is
    refused with a DataError).
    temperature_c is the ambient temperature (the model computes the cell temperature where it
    has a thermal model), cell_temperature_start_c (°C) the cell's at the start where given
    (the FMU's use_cell_temperature_start; None: rested at the ambient). The run stops after
    the first step that leaves the cell empty
    (empty_reason): cutoff_v in V, None for the FMU's own (shipped_cutoff_v), 0 for none (a
    SoC or a voltage below 0 still stops it); or over-full (full_reason: SoC above 1)."""
    vehicle = vehicle or load_vehicle()
    trace = load_cycle(cycle)
    dt = trace.step_s
    power = np.tile(pack_power(vehicle, trace.speed_mps, trace.grade, dt), repeat)
    cell_power = power / (vehicle.n_series * vehicle.n_parallel)
    cutoff = _given_cutoff(shipped_cell(fmu), cutoff_v)
    copies = f"{repeat} × " if repeat > 1 else ""
    md, h, n = _communication_steps(fmu, step_s, power.size * dt,
                                    f"{copies}the {trace.title} cycle")
    speed = step_means(np.tile(trace.speed_mps, repeat), dt, h, n)
    out, stop, first = _drive_fmu(fmu, md, step_means(cell_power, dt, h, n), True, h, soc0,
                                  temperature_c, cutoff,
                                  cell_temperature_start_c=cell_temperature_start_c)
    speed = speed[:out["time"].size]
    cell = _cell_figures(out, h, soc0, temperature_c, cutoff, stop, first,
                         cell_temperature_start_c)
    figures = {"cycle": trace.name, "repetitions": repeat, "step_s": h,
               "duration_s": cell["duration_s"], "unrun_s": unrun_s(power.size * dt, h, n),
               "distance_km": float(np.sum(speed) * h / 1000.0),
               "cell_energy_wh": cell["cell_energy_wh"],
               "pack_energy_kwh": cell["cell_energy_wh"] * vehicle.n_series
               * vehicle.n_parallel / 1000.0, **cell, "vehicle": vehicle.name}
    cell_t = out["cell_t"] if figures["cell_temperature_max_c"] is not None else None
    return CycleResult(out["time"], speed, out["current"], out["voltage"], out["soc"],
                       out["oor"].astype(bool), figures, cell_t)


def run_profile(fmu: str | Path, profile: str | Path | CurrentProfile, repeat: int = 1,
                soc0: float = 0.9, step_s: float | None = None, temperature_c: float = 25.0,
                cutoff_v: float | None = None, discharge_positive: bool = False,
                charge_cutoff_v: float | None = None,
                cell_temperature_start_c: float | None = None) -> CycleResult:
    """Drive the FMU through `repeat` copies of a cell current profile (a CSV file or a
    CurrentProfile: load_current_profile) with fmpy, the current's mean over each
    communication step held over it; stops as run_cycle does, and also where the voltage
    rises above charge_cutoff_v (V; None: the highest voltage of the model's training
    records; 0: none). speed_mps of the result is None."""
    prof = load_current_profile(profile, discharge_positive)
    dt = prof.step_s
    current = np.tile(prof.current_a, repeat)
    cell = shipped_cell(fmu)
    cutoff = _given_cutoff(cell, cutoff_v)
    charge_cutoff = _given_cutoff(cell, charge_cutoff_v, charge=True)
    copies = f"{repeat} × " if repeat > 1 else ""
    md, h, n = _communication_steps(fmu, step_s, current.size * dt,
                                    f"{copies}the profile {prof.name}")
    out, stop, first = _drive_fmu(fmu, md, step_means(current, dt, h, n), False, h, soc0,
                                  temperature_c, cutoff, charge_cutoff,
                                  cell_temperature_start_c)
    figures = {"profile": prof.name, "repetitions": repeat,
               **_cell_figures(out, h, soc0, temperature_c, cutoff, stop, first,
                               cell_temperature_start_c),
               "unrun_s": unrun_s(current.size * dt, h, n),
               "charge_cutoff_v": charge_cutoff}
    cell_t = out["cell_t"] if figures["cell_temperature_max_c"] is not None else None
    return CycleResult(out["time"], None, out["current"], out["voltage"], out["soc"],
                       out["oor"].astype(bool), figures, cell_t)


def stopped_outside_range(res: CycleResult) -> bool:
    """Whether the run stopped on a voltage cut-off at a step where the model was outside its
    trained range: the voltage is then its extrapolation (a cold ambient far below the trained
    temperatures collapses it at a SoC of 0.9), not a cell that is empty or full."""
    return res.figures["stop"].startswith("cell voltage") and bool(res.out_of_range[-1])


def stop_title(res: CycleResult) -> str:
    """What the plot's title adds on a run that stopped early ('' for one that did not): the
    cell empty or full and when, or, where it stopped outside the trained range
    (stopped_outside_range), that it stopped at the cut-off there."""
    f = res.figures
    if not f["stop"]:
        return ""
    if stopped_outside_range(res):
        return (f" — stopped at the cut-off after {f['stopped_at_s']:g} s, outside the trained "
                "range")
    return f" — stopped, the cell {stop_kind(f['stop'])} after {f['stopped_at_s']:g} s"


def plot_cycle(res: CycleResult, path: str | Path) -> Path:
    """Speed (for a drive cycle), current, voltage, SoC and cell temperature over the run."""
    from lmncell.report.plots import plt, save_figure

    t = res.time_s / 60.0
    f = res.figures
    panels = 4 if res.speed_mps is not None else 3
    fig, axes = plt.subplots(panels, 1, figsize=(10, 2.1 * panels + 0.1), sharex=True,
                             constrained_layout=True)
    stop = stop_title(res)
    if res.speed_mps is not None:
        axes[0].plot(t, 3.6 * res.speed_mps)
        axes[0].set(ylabel="speed / km/h", title=f"{trace_title(f['cycle'])} through the FMU "
                    f"({f['vehicle']}){stop}")
    else:
        axes[0].set_title(f"current profile {f['profile']} through the FMU{stop}")
    ax = axes[panels - 3:]
    ax[0].plot(t, res.current_a, lw=0.7)
    ax[0].set(ylabel="cell current / A")
    ax[1].plot(t, res.voltage_v, color="k", lw=0.7)
    if res.out_of_range.any():
        ax[1].plot(t[res.out_of_range], res.voltage_v[res.out_of_range], "r.", ms=2,
                   label="outside trained range")
        ax[1].legend()
    if f["cutoff_v"] > 0 and res.voltage_v.min() < f["cutoff_v"] + CUTOFF_SHOWN_WITHIN_V:
        ax[1].axhline(f["cutoff_v"], color="tab:red", lw=0.8, ls="--",
                      label=f"cut-off {f['cutoff_v']:.3f} V")
        ax[1].legend()
    ax[1].set(ylabel="cell voltage / V")
    ax[2].plot(t, 100 * res.soc, color="tab:green")
    ax[2].set(ylabel="SoC / %", xlabel="time / min")
    if res.cell_temperature_c is not None:
        tx = ax[2].twinx()
        tx.plot(t, res.cell_temperature_c, color="tab:red", lw=0.8)
        start = f.get("cell_temperature_start_c")
        tx.set_ylabel(f"cell temperature / °C (ambient {f['ambient_c']:g})"
                      + (f"\nfrom {start:g} °C at the start" if start is not None else ""),
                      color="tab:red")
    return save_figure(fig, path)


def simulate_cycle_cli(a) -> int:
    """`lmncell simulate`: a drive cycle (--cycle) or a current profile (--current)."""
    from lmncell.evaluation.fmueval import read_fmu_info

    read_fmu_info(a.fmu)               # ConfigError naming the file unless an LMNCell FMU
    if a.current:
        res = run_profile(a.fmu, a.current, a.repeat, a.soc0, a.step, a.ambient, a.cutoff,
                          a.discharge_positive, a.charge_cutoff, a.cell_temperature_start)
    else:
        res = run_cycle(a.fmu, a.cycle, load_vehicle(a.vehicle), a.repeat, a.soc0, a.step,
                        a.ambient, a.cutoff, a.cell_temperature_start)
    plotted = plot_cycle(res, a.plot) if a.plot else None
    f = res.figures
    notes = sys.stderr if a.json else sys.stdout    # with --json, stdout is the JSON alone
    if a.json:
        print(json_text(f))
    else:
        print(_run_line(f))
        if f["stop"]:
            print(_stop_line(res))
    if f["unrun_s"] and not f["stop"]:
        print(f"note: the last {f['unrun_s']:g} s of the "
              + ("profile" if a.current else "cycle") + f"{'s' if a.repeat > 1 else ''}, "
              f"shorter than one communication step of {f['step_s']:g} s, were not run "
              "(--step sets it)", file=notes)
    if f["out_of_range_steps"]:
        first = f["out_of_range_first"]
        print(f"warning: {f['out_of_range_steps']} step(s) left the model's trained range "
              "(current, SoC, temperature or its voltage)"
              + (f"; the FMU's first warning: {first}" if first else "") + "; see the plot",
              file=notes)
    if plotted:
        print(f"plot: {plotted}", file=notes)
    return 0


def _stop_line(res: CycleResult) -> str:
    """The line on a run that stopped early: the cell empty or full, with the option that sets
    the cut-off; where it stopped outside the trained range (stopped_outside_range), that, with
    the SoC there."""
    f = res.figures
    where = f", {f['distance_km']:.1f} km" if "distance_km" in f else ""
    state = stop_kind(f["stop"])
    hint = ("; --cutoff sets the cut-off voltage" if state == "empty" else
            "; --charge-cutoff sets the charge cut-off voltage" if "voltage" in f["stop"] else "")
    if stopped_outside_range(res):
        return (f"stopped after {f['stopped_at_s']:g} s{where}: {f['stop']} at SoC "
                f"{100 * float(res.soc[-1]):.1f} %, with the model outside its trained range "
                f"(the warning below): an extrapolated voltage, not necessarily a cell that is "
                f"{state}{hint}")
    return f"stopped after {f['stopped_at_s']:g} s{where}: the cell is {state} ({f['stop']}){hint}"


def _run_line(f: dict) -> str:
    """One line of a run's figures (run_cycle's or run_profile's)."""
    if "cycle" in f:
        head = (f"{trace_title(f['cycle'])} x{f['repetitions']} at {f['step_s']} s steps: "
                f"{f['distance_km']:.1f} km, cell energy {f['cell_energy_wh']:.2f} Wh (pack "
                f"{f['pack_energy_kwh']:.2f} kWh)")
    else:
        head = (f"{f['profile']} x{f['repetitions']} at {f['step_s']} s steps: "
                f"{f['duration_s']:g} s, cell energy {f['cell_energy_wh']:.2f} Wh")
    return (head + f", {f['ah_throughput']:.3f} Ah throughput, current "
            f"{f['current_min_a']:.2f}…{f['current_max_a']:.2f} A, minimum voltage "
            f"{f['voltage_min_v']:.3f} V, SoC {100 * f['soc_start']:.1f} → "
            f"{100 * f['soc_end']:.1f} % (swing {100 * f['soc_swing']:.1f} points)"
            + ("" if f["cell_temperature_max_c"] is None else
               f", cell temperature up to {f['cell_temperature_max_c']:.1f} °C at "
               f"{f['ambient_c']:g} °C ambient"
               + ("" if f.get("cell_temperature_start_c") is None else
                  f" (from {f['cell_temperature_start_c']:g} °C at the start)")))
