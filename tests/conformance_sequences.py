"""FMI 2.0 call sequences for tests/test_conformance.py, each run in a child process so that a
crash of the host is a test failure, not the end of the run:

    python -m tests.conformance_sequences FMU SEQUENCE    → prints one JSON object

Each sequence returns the statuses (0 OK … 4 fatal) and values the test then checks.
"""

from __future__ import annotations

import ctypes
import json
import math
import random
import struct
import sys
from collections.abc import Callable

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import ModelDescription

from tests.fmu_helpers import Instance

OK = 0


def _status(call) -> int:
    """The FMI status of a call (0 when it returned OK or warning-free)."""
    try:
        call()
        return OK
    except FMICallException as exc:
        return int(exc.status)


def _c_function(slave: FMU2Slave, fn: str, argtypes: list | None = None) -> Callable[..., int]:
    """The FMU's C function fn itself, returning its status as an int (fmpy's wrappers raise
    only for statuses worse than fmi2Warning, so a warning would read as OK), with these
    argument types or, without them, its arguments passed as given. A function object of its
    own: fmpy's share the library's, and keep their argument types."""
    raw = getattr(ctypes.CDLL(slave.dll._name), fn)
    raw.argtypes, raw.restype = argtypes, ctypes.c_int
    return raw


def _raw(fmu: str, logging: bool = True, name: str = "raw", callbacks=None):
    """An instantiated FMU2Slave of the FMU (with fmu_log's instance name and callbacks where
    its messages are kept) and its value references by variable name."""
    md = read_model_description(fmu)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    slave.instantiate(callbacks=callbacks, loggingOn=logging)
    return slave, {v.name: v.valueReference for v in md.modelVariables}


def init_mode_outputs(fmu: str) -> dict:
    """Row 2: outputs read in Initialization Mode equal those right after it."""
    slave, vr = _raw(fmu)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["soc0"], vr["temperature"]], [0.55, 31.0])
    names = ["voltage", "soc", "soc_std", "cell_temperature"]
    before = slave.getReal([vr[n] for n in names])
    slave.exitInitializationMode()
    after = slave.getReal([vr[n] for n in names])
    slave.terminate()
    slave.freeInstance()
    return {"before": before, "after": after}


def temperature_outside_range_at_start(fmu: str) -> dict:
    """A temperature input no step takes (−1e308 °C), set before initialisation: the outputs
    read in Initialization Mode and after it stay finite (a model with temperature terms read
    NaN with OK), the first step is refused, and one at 25 °C then runs."""
    slave, vr = _raw(fmu)
    names = ["voltage", "soc", "soc_std", "cell_temperature"]
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["temperature"]], [-1e308])
    out = {"init": slave.getReal([vr[n] for n in names])}
    out["exit"] = _status(slave.exitInitializationMode)
    out["after_exit"] = slave.getReal([vr[n] for n in names])
    slave.setReal([vr["current"]], [-1.0])
    out["step"] = _status(lambda: slave.doStep(0.0, 1.0))
    out["after_step"] = slave.getReal([vr[n] for n in names])
    slave.setReal([vr["temperature"]], [25.0])
    out["step_25"] = _status(lambda: slave.doStep(0.0, 1.0))
    out["after_25"] = slave.getReal([vr[n] for n in names])
    slave.terminate()
    slave.freeInstance()
    return out


def state_machine(fmu: str) -> dict:
    """Row 4: calls out of order and a communication point that is not the FMU's time."""
    out = {}
    slave, _ = _raw(fmu)
    out["exit_without_enter"] = _status(slave.exitInitializationMode)
    slave.freeInstance()
    inst = Instance(fmu)
    out["first_step"] = _status(lambda: inst.slave.doStep(0.0, 1.0))
    out["wrong_point"] = _status(lambda: inst.slave.doStep(5.0, 1.0))
    out["right_point"] = _status(lambda: inst.slave.doStep(1.0, 1.0))
    out["tiny_step"] = _status(lambda: inst.slave.doStep(2.0, 1e-12))
    out["after_tiny"] = _status(lambda: inst.slave.doStep(2.0 + 1e-12, 1.0))
    inst.slave.terminate()
    out["step_after_terminate"] = _status(lambda: inst.slave.doStep(3.0 + 1e-12, 1.0))
    inst.slave.freeInstance()
    return out


def stop_time(fmu: str) -> dict:
    """FMI 2.0: with stopTimeDefined, a step that would end past stopTime is fmi2Error (nothing
    changed); steps up to it on a grid of 0.1 s (its rounding) are taken; a stop time that is
    not finite or lies before the start is refused; fmi2Reset forgets it."""
    out: dict = {}
    slave, vr = _raw(fmu, False, "stop")
    for bad in (-1.0, math.nan):
        out[f"setup_stop_{bad}"] = _status(lambda b=bad: slave.setupExperiment(startTime=0.0,
                                                                              stopTime=b))
    out["setup"] = _status(lambda: slave.setupExperiment(startTime=0.0, stopTime=0.3))
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.setReal([vr["current"]], [-2.0])
    t = 0.0
    out["grid"] = []
    for _ in range(3):          # 0.1 + 0.1 + 0.1 = 0.30000000000000004 > 0.3
        out["grid"].append(_status(lambda t=t: slave.doStep(t, 0.1)))
        t += 0.1
    before = slave.getReal([vr["voltage"], vr["soc"]])
    out["past"] = _status(lambda: slave.doStep(t, 0.1))
    out["unchanged"] = slave.getReal([vr["voltage"], vr["soc"]]) == before
    slave.reset()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    out["after_reset"] = _status(lambda: slave.doStep(0.0, 5.0))
    slave.terminate()
    slave.freeInstance()
    return out


MODES = ("instantiated", "initialization mode", "step mode", "terminated")


def _in_mode(fmu: str, mode: str) -> tuple[FMU2Slave, dict[str, int]]:
    """A fresh instance brought into one of the co-simulation MODES by the usual calls."""
    slave, vr = _raw(fmu, False, f"m{MODES.index(mode)}")
    if mode != "instantiated":
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
    if mode in ("step mode", "terminated"):
        slave.exitInitializationMode()
        slave.doStep(0.0, 1.0)
    if mode == "terminated":
        slave.terminate()
    return slave, vr


def mode_rules(fmu: str) -> dict:
    """Row 4: each call of the co-simulation state machine in each mode, on a fresh instance
    (its status by "call in mode"); setupExperiment with a non-finite start time; an FMU state
    saved in step mode and restored after terminate (then a step at its time), and one saved
    in initialization mode restored in step mode (then a step)."""
    calls = {"setupExperiment": lambda s, vr: s.setupExperiment(startTime=2.0),
             "enterInitializationMode": lambda s, vr: s.enterInitializationMode(),
             "exitInitializationMode": lambda s, vr: s.exitInitializationMode(),
             "terminate": lambda s, vr: s.terminate(),
             "doStep": lambda s, vr: s.doStep(1.0, 1.0),
             "setReal current": lambda s, vr: s.setReal([vr["current"]], [-1.0]),
             "getReal voltage": lambda s, vr: s.getReal([vr["voltage"]]),
             "getInteger observer": lambda s, vr: s.getInteger([vr["observer"]]),
             "getBoolean out_of_range": lambda s, vr: s.getBoolean([vr["out_of_range"]]),
             "getString none": lambda s, vr: s.getString([]),
             "reset": lambda s, vr: s.reset()}
    out: dict = {}
    for mode in MODES:
        for name, call in calls.items():
            slave, vr = _in_mode(fmu, mode)
            out[f"{name} in {mode}"] = _status(lambda c=call, s=slave, v=vr: c(s, v))
            slave.freeInstance()
    for start in (math.nan, math.inf):
        slave, _ = _in_mode(fmu, "instantiated")
        out[f"setupExperiment at {start}"] = _status(lambda s=slave, t=start: s.setupExperiment(
            startTime=t))
        slave.freeInstance()
    out["restore after terminate"], out["step after restore"] = _restore_then_step(
        fmu, "step mode", FMU2Slave.terminate, 1.0)
    out["restore uninitialised"], out["step after restore uninitialised"] = _restore_then_step(
        fmu, "initialization mode", FMU2Slave.exitInitializationMode, 0.0)
    return out


def _restore_then_step(fmu: str, saved_in: str, then: Callable[[FMU2Slave], object],
                       step_at: float) -> tuple[int, int]:
    """The statuses of fmi2SetFMUstate and of a 1-s step at step_at, for a state saved in the
    mode saved_in and restored after the call `then`."""
    slave, _ = _in_mode(fmu, saved_in)
    state = slave.getFMUstate()
    then(slave)
    restored = _status(lambda: slave.setFMUstate(state))
    stepped = _status(lambda: slave.doStep(step_at, 1.0))
    slave.freeFMUstate(state)
    slave.freeInstance()
    return restored, stepped


def impossible_inputs(fmu: str) -> dict:
    """Row 5: a finite but absurd current, a temperature below absolute zero (outside the
    accepted −60…100 °C) and a step of more model steps than one call may take are refused;
    the outputs stay finite and unchanged."""
    inst = Instance(fmu)
    inst.step(-2.0)
    before = inst.get("voltage", "soc")
    out = {"huge_current": _status(lambda: inst.step(1e308)), "after_huge": inst.get(
        "voltage", "soc")}
    out["below_zero_kelvin"] = _status(lambda: inst.step(-1.0, temperature=-300.0))
    out["after_cold"] = inst.get("voltage", "soc")
    out["nan_current"] = _status(lambda: inst.step(math.nan))
    out["after_nan"] = inst.get("voltage", "soc")
    out["endless_step"] = _status(lambda: inst.step(-1.0, h=1e300))   # looped for ever
    out["after_endless"] = inst.get("voltage", "soc")
    out["before"] = before
    out["still_steps"] = _status(lambda: inst.step(-1.0))
    out["finite"] = all(math.isfinite(x) for x in inst.get("voltage", "soc", "soc_std"))
    inst.free()
    return out


def logged_messages(fmu: str) -> dict:
    """Every message the FMU logs (the instance's name left out), the statuses and the final
    outputs over one sequence: doStep before and during initialisation, bad parameters at
    exitInitializationMode (a capacity of 1e-300 Ah with the EKF among them) and then good ones, an out-of-range warning, each input refused,
    a partial model step, a temperature in K given as degC, a wrong communication point, a
    step after terminate."""
    from lmncell.evaluation.fmueval import fmu_log

    statuses = []
    with fmu_log("seq") as (name, callbacks, log):
        slave, vr = _raw(fmu, True, name, callbacks)
        statuses.append(_status(lambda: slave.doStep(0.0, 1.0)))
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        statuses.append(_status(lambda: slave.doStep(0.0, 1.0)))
        slave.setInteger([vr["observer"]], [1])     # 1e-300 Ah overflowed the EKF's noise
        for ref, bad, good in (("capacity", 1e-300, 2.0), ("soc0", 1.5, 0.5), ("observer", 7, 0),
                               ("capacity", -1.0, 2.0)):
            setter = slave.setInteger if ref == "observer" else slave.setReal
            setter([vr[ref]], [bad])
            statuses.append(_status(slave.exitInitializationMode))
            setter([vr[ref]], [good])
        statuses.append(_status(slave.exitInitializationMode))
        statuses.append(_status(slave.exitInitializationMode))
        t = 0.0
        for current, temperature, h in ((2.0, 298.15, 1.0), (1.0, 60.0, 1.0),
                                        (math.nan, 25.0, 1.0), (0.0, math.inf, 1.0),
                                        (1.0, -300.0, 1.0), (1e6, 25.0, 1.0), (0.0, 25.0, 0.5),
                                        (0.0, 25.0, -1.0), (0.0, 25.0, 1e30),
                                        (-1.0, 25.0, 0.25)):
            slave.setReal([vr["current"], vr["temperature"]], [current, temperature])
            status = _status(lambda t=t, h=h: slave.doStep(t, h))
            statuses.append(status)
            t += h if status == OK else 0.0
        statuses.append(_status(lambda: slave.doStep(t + 5.0, 1.0)))
        outputs = slave.getReal([vr["voltage"], vr["soc"], vr["cell_temperature"]])
        slave.terminate()
        statuses.append(_status(lambda: slave.doStep(t, 1.0)))
        slave.freeInstance()
        messages = [entry.replace(name, "NAME") for entry in log]
    return {"messages": messages, "statuses": statuses, "outputs": outputs}


def cell_start_parameters(fmu: str) -> dict:
    """use_cell_temperature_start / cell_temperature_start: a start temperature outside
    −60…100 °C refused at exitInitializationMode (the FMU stays in Initialization Mode, its
    outputs those of a rested start until then), one within read back as the cell temperature
    in Initialization Mode and after it, the parameter fixed after initialisation, and a start
    temperature with temperature_is_cell = true refused."""
    from lmncell.evaluation.fmueval import fmu_log

    out: dict = {"statuses": [], "cell_temperature": []}
    with fmu_log("seq") as (name, callbacks, log):
        slave, vr = _raw(fmu, True, name, callbacks)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.setBoolean([vr["use_cell_temperature_start"]], [True])
        for start in (150.0, math.nan, 40.0):
            slave.setReal([vr["cell_temperature_start"]], [start])
            out["cell_temperature"].append(slave.getReal([vr["cell_temperature"]])[0])
            out["statuses"].append(_status(slave.exitInitializationMode))
        out["cell_temperature"].append(slave.getReal([vr["cell_temperature"]])[0])
        slave.setReal([vr["current"]], [-2.0])
        out["statuses"].append(_status(lambda: slave.doStep(0.0, 1.0)))
        out["cell_temperature"].append(slave.getReal([vr["cell_temperature"]])[0])
        out["statuses"].append(_status(lambda: slave.setReal([vr["cell_temperature_start"]],
                                                             [30.0])))
        out["read_back"] = [slave.getReal([vr["cell_temperature_start"]])[0],
                            slave.getBoolean([vr["use_cell_temperature_start"]])[0]]
        slave.freeInstance()
        slave, vr = _raw(fmu, True, name, callbacks)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.setBoolean([vr["use_cell_temperature_start"], vr["temperature_is_cell"]],
                         [True, True])
        out["statuses"].append(_status(slave.exitInitializationMode))
        slave.freeInstance()
        out["messages"] = [entry.replace(name, "NAME") for entry in log]
    return out


def access_refusals(fmu: str) -> dict:
    """Gets and sets that FMI 2.0 lets a host try and the FMU refuses, in Initialization Mode
    and after it: an unknown value reference, a variable read or set as another type, an
    output set, parameters set after initialisation (a call that also sets an input first, and
    one with three refused values), String variables. The statuses, the messages and the
    values read back after each refused set (nothing of the call set)."""
    from lmncell.evaluation.fmueval import fmu_log

    out: dict = {"statuses": [], "read_back": []}
    with fmu_log("acc") as (name, callbacks, log):
        slave, vr = _raw(fmu, True, name, callbacks)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()

        def read_back() -> None:
            out["read_back"].append([*slave.getReal([vr["current"], vr["soc0"], vr["capacity"],
                                                     vr["cell_temperature_start"]]),
                                     *slave.getInteger([vr["observer"]]),
                                     *slave.getBoolean([vr["temperature_is_cell"],
                                                        vr["use_cell_temperature_start"]])])

        def refused(calls) -> None:
            for call in calls:
                out["statuses"].append(_status(call))
                read_back()

        refused([lambda: slave.setReal([vr["voltage"]], [3.3]),
                 lambda: slave.setInteger([vr["current"]], [1]),
                 lambda: slave.setBoolean([vr["observer"]], [True]),
                 lambda: slave.setReal([vr["soc0"], 999], [0.5, 0.1 + 0.2])])
        slave.setReal([vr["soc0"], vr["capacity"], vr["current"]], [0.7, 2.5, -1.0])
        slave.exitInitializationMode()
        refused([lambda: slave.setReal([vr["current"], vr["soc0"]], [-4.0, 0.2]),
                 lambda: slave.setReal([vr["soc0"], vr["capacity"], vr["cell_temperature_start"]],
                                       [1e-300, math.nan, 40.0]),
                 lambda: slave.setInteger([vr["observer"]], [2]),
                 lambda: slave.setBoolean([vr["temperature_is_cell"],
                                           vr["use_cell_temperature_start"]], [True, False]),
                 lambda: slave.getReal([999]),
                 lambda: slave.getInteger([vr["soc0"]]),
                 lambda: slave.getBoolean([vr["current"]]),
                 lambda: slave.getString([vr["voltage"]]),
                 lambda: slave.setString([vr["voltage"]], ["x"])])
        out["values_refused"] = [_status(lambda x=x: slave.setReal([vr["soc0"]], [x]))
                                 for x in REFUSED_VALUES]
        out["steps_after"] = _status(lambda: slave.doStep(0.0, 1.0))
        slave.freeInstance()
        out["messages"] = [entry.replace(name, "NAME") for entry in log]
    return out


# Reals the refusals write (value_text), the awkward ones and 40 doubles of random bits
REFUSED_VALUES = [40.0, 250000.0, 2.5e6, 123456789.0, 99.99999999, -0.0, math.inf, -math.inf,
                  5e-324, 1.7976931348623157e308, 9.999999999999999e5, 1e-5] + [
    x for x in (struct.unpack("<d", random.Random(5 + k).getrandbits(64).to_bytes(8, "little"))[0]
                for k in range(40)) if math.isfinite(x)]


def debug_logging_categories(fmu: str) -> dict:
    """fmi2SetDebugLogging with each kind of category list, each followed by a step outside
    the trained temperatures (a warning where warnings are on) and one back inside, then a
    NULL array and a NULL entry: the messages, the statuses and the voltage of a last step."""
    from fmpy.fmi2 import fmi2False, fmi2String, fmi2True
    from lmncell.evaluation.fmueval import fmu_log

    statuses, after = [], {}
    with fmu_log("dbg") as (name, callbacks, log):
        slave, vr = _raw(fmu, False, name, callbacks)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.setBoolean([vr["temperature_is_cell"]], [True])   # the input is the cell's
        slave.exitInitializationMode()
        t = 0.0
        settings = (("off", fmi2False, []), ("all", fmi2True, []),
                    ("errors only", fmi2True, ["logStatusError"]),
                    ("warnings", fmi2True, ["logStatusWarning", "logStatusError"]),
                    ("unknown only", fmi2True, ["noSuchCategory"]),
                    ("logAll", fmi2True, ["logAll"]),
                    ("unknown and warnings", fmi2True, ["noSuchCategory", "logStatusWarning"]),
                    ("warnings off", fmi2False, ["logStatusWarning"]))
        set_logging = _c_function(slave, "fmi2SetDebugLogging", [
            ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t, ctypes.POINTER(ctypes.c_char_p)])
        for label, on, cats in settings:
            array = (fmi2String * len(cats))(*(c.encode() for c in cats)) if cats else None
            statuses.append(set_logging(slave.component, on, len(cats), array))
            log.append(f"[{label}]")
            for temperature in (60.0, 27.0):      # out of the trained range, and back in
                slave.setReal([vr["current"], vr["temperature"]], [-1.0, temperature])
                statuses.append(_status(lambda t=t: slave.doStep(t, 1.0)))
                t += 1.0
        slave.fmi2SetDebugLogging(slave.component, fmi2True, 0, None)
        statuses.append(_status(lambda: slave.fmi2SetDebugLogging(slave.component, fmi2True, 2,
                                                                  None)))
        statuses.append(_status(lambda: slave.fmi2SetDebugLogging(
            slave.component, fmi2False, 2, (fmi2String * 2)(b"logStatusError", None))))
        log.append("[after the NULLs]")           # still on for all: this step warns
        slave.setReal([vr["temperature"]], [60.0])
        statuses.append(_status(lambda: slave.doStep(t, 1.0)))
        after["voltage"] = slave.getReal([vr["voltage"]])[0]
        slave.terminate()
        slave.freeInstance()
        messages = [entry.replace(name, "NAME") for entry in log]
    return {"messages": messages, "statuses": statuses, **after}


def observers_at_full(fmu: str) -> dict:
    """Issue 19: each observer from SoC 1.0 with a ±2 A square wave that starts by charging,
    the FMU's own voltage fed back as the measurement, then contradictory measurements."""
    out = {}
    for observer in (1, 2, 3):
        inst = Instance(fmu, start={"soc0": 1.0}, observer=observer)
        worst, finite = OK, True
        v = inst.get("voltage")[0]
        for k in range(600):
            i = 2.0 if (k // 30) % 2 == 0 else -2.0
            meas = v if k < 300 else (0.5 if k % 2 else 4.9)
            inst.slave.setReal([inst.vr["voltage_measured"]], [meas])
            worst = max(worst, _status(lambda i=i, inst=inst: inst.step(i)))
            v, soc, sd = inst.get("voltage", "soc", "soc_std")
            finite = finite and all(math.isfinite(x) for x in (v, soc, sd)) and 0 <= soc <= 1
        out[str(observer)] = {"worst_status": worst, "finite": finite}
        inst.free()
    return out


def ordinary_errors(fmu: str) -> dict:
    """Row 1 and 7: unknown references, wrong types, outputs and fixed parameters set after
    initialisation, bad parameters at exitInitializationMode: no crash, nothing changed."""
    out = {}
    inst = Instance(fmu, start={"soc0": 0.8})
    inst.step(-1.0)
    out["unknown_get"] = [_status(lambda: inst.slave.getReal([999])) for _ in range(6)]
    out["set_output"] = _status(lambda: inst.slave.setReal([inst.vr["voltage"]], [1.0]))
    out["set_fixed"] = _status(lambda: inst.slave.setReal([inst.vr["soc0"]], [0.2]))
    out["soc0_after"] = inst.get("soc0")[0]
    out["set_observer"] = _status(lambda: inst.slave.setInteger([inst.vr["observer"]], [2]))
    out["wrong_type"] = _status(lambda: inst.slave.setInteger([inst.vr["current"]], [1]))
    out["steps_after"] = _status(lambda: inst.step(-1.0))
    out["finite"] = all(math.isfinite(x) for x in inst.get("voltage", "soc"))
    inst.free()
    slave, vr = _raw(fmu)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["soc0"]], [2.0])
    out["bad_param_exit"] = _status(slave.exitInitializationMode)
    out["step_uninitialised"] = _status(lambda: slave.doStep(0.0, 1.0))
    slave.freeInstance()
    return out


def _raw_initialised(fmu: str, name: str, callbacks) -> tuple[FMU2Slave, dict[str, int]]:
    """_raw's instance with logging on, set up at 0 s and initialised with its defaults."""
    slave, vr = _raw(fmu, True, name, callbacks)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    return slave, vr


def _instantiate_with(fmu: str, unzipped: str, uri: str | None = None, guid: str | None = None,
                      fmu_type: int | None = None, name: str = "uri",
                      callbacks=None, given_name: str | None = None) -> FMU2Slave | None:
    """An FMU2Slave of the FMU extracted in `unzipped`, instantiated through fmi2Instantiate with
    the given resource location (default: the file URI of its resources folder, as fmpy gives
    it), GUID and FMU type, and fmpy's callbacks or the given ones (the string "none": no
    callbacks at all), under the instance name given_name where given (default: name); None
    where the FMU refuses (returns NULL)."""
    from ctypes import byref
    from pathlib import Path

    from fmpy.fmi2 import defaultCallbacks, fmi2CoSimulation

    md = read_model_description(fmu)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    slave.callbacks = defaultCallbacks if callbacks in (None, "none") else callbacks
    where = Path(unzipped, "resources").as_uri() if uri is None else uri
    slave.component = slave.fmi2Instantiate(
        (name if given_name is None else given_name).encode(),
        fmi2CoSimulation if fmu_type is None else fmu_type,
        (md.guid if guid is None else guid).encode(), where.encode(),
        None if callbacks == "none" else byref(slave.callbacks), False, False)
    return None if slave.component is None else slave


def wrong_guid_or_type(fmu: str) -> dict:
    """Row 7: fmi2Instantiate with another FMU's GUID, as Model Exchange, with an empty or a
    missing resource location, an empty instance name or no callbacks: "refused" (NULL) or
    "instantiated"."""
    from fmpy.fmi2 import fmi2ModelExchange

    unzipped = extract(fmu)
    cases = {"wrong_guid": {"guid": "{00000000-0000-0000-0000-000000000000}"},
             "model_exchange": {"fmu_type": fmi2ModelExchange},
             "no_resources": {"uri": ""},
             "missing_resources": {"uri": "file:///nonexistent/lmncell/resources"},
             "empty_name": {"given_name": ""}, "no_callbacks": {"callbacks": "none"},
             "right": {}}
    out = {}
    for key, kw in cases.items():
        slave = _instantiate_with(fmu, unzipped, name=key, **kw)
        out[key] = "refused" if slave is None else "instantiated"
        if slave is not None:
            slave.freeInstance()
    return out


# Where a host may unpack an FMU: spaces, non-ASCII letters and URI delimiters in the folders
AWKWARD_FOLDER = "lmn cell #1 50% (ü)"


def resource_locations(fmu: str) -> dict:
    """Row 7: the forms of the resources folder's file URI that FMI 2.0 asks an FMU to take
    (with and without the authority, localhost, every %XX decoded, the scheme in any case), for
    an FMU unpacked under AWKWARD_FOLDER, each instantiated, initialised and stepped once (its
    voltage, or "refused"); and locations that name no local folder ("refused" or, where the
    FMU needs no resources, "instantiated")."""
    import tempfile
    from pathlib import Path
    from urllib.parse import quote

    unzipped = extract(fmu, unzipdir=str(Path(tempfile.mkdtemp(), AWKWARD_FOLDER, "unzipped")))
    path = quote(str(Path(unzipped, "resources")))           # /…/lmn%20cell%20%231…
    forms = {"fmpy": None, "no_authority": f"file:{path}", "localhost": f"file://LocalHost{path}",
             "upper_scheme": f"FILE://{path}", "trailing_slash": f"file://{path}/",
             "bare_path": str(Path(unzipped, "resources"))}
    wrong = {"other_host": f"file://elsewhere.example{path}",
             "http": "http://example.com/resources", "relative": "file:resources",
             "bad_escape": f"file://{path}%2"}
    voltage = next(v.valueReference for v in read_model_description(fmu).modelVariables
                   if v.name == "voltage")
    out = {}
    for key, uri in {**forms, **wrong}.items():
        slave = _instantiate_with(fmu, unzipped, uri, name=key)
        if slave is None:
            out[key] = "refused"
            continue
        if key in wrong:
            out[key] = "instantiated"
        else:
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            slave.exitInitializationMode()
            slave.doStep(0.0, 1.0)
            out[key] = slave.getReal([voltage])[0]
            slave.terminate()
        slave.freeInstance()
    return out


def logged_resource_refusals(fmu: str) -> dict:
    """Row 7: what the FMU logs when it refuses a resource location that names no local folder
    (the messages of each attempt)."""
    from lmncell.evaluation.fmueval import fmu_log

    unzipped = extract(fmu)
    out = {}
    with fmu_log("res") as (name, callbacks, log):
        for key, uri in (("other_host", "file://elsewhere.example/x/resources"),
                         ("bad_escape", "file:///a%2x/resources"),
                         ("http", "http://example.com/resources")):
            before = len(log)
            slave = _instantiate_with(fmu, unzipped, uri, name=name, callbacks=callbacks)
            if slave is not None:
                slave.freeInstance()
            out[key] = " | ".join(log[before:])
    return out


def null_pointers(fmu: str) -> dict:
    """Row 7: every FMI function that takes an array or a pointer, given NULL for it (with
    nvr = 1) on an initialised instance: its status and what it logged, per call; then whether
    the instance still steps (the status of one step and its finite voltage)."""
    from lmncell.evaluation.fmueval import fmu_log

    calls = {
        "fmi2GetReal": (None, 1, None), "fmi2GetInteger": (None, 1, None),
        "fmi2GetBoolean": (None, 1, None), "fmi2GetString": (None, 1, None),
        "fmi2SetReal": (None, 1, None), "fmi2SetInteger": (None, 1, None),
        "fmi2SetBoolean": (None, 1, None), "fmi2SetString": (None, 1, None),
        "fmi2GetFMUstate": (None,), "fmi2SetFMUstate": (None,), "fmi2FreeFMUstate": (None,),
        "fmi2SerializedFMUstateSize": (None, None), "fmi2SerializeFMUstate": (None, None, 8),
        "fmi2DeSerializeFMUstate": (None, 8, None),
        "fmi2GetRealStatus": (2, None), "fmi2GetBooleanStatus": (3, None)}
    out: dict = {}
    with fmu_log("null") as (name, callbacks, log):
        slave, vr = _raw_initialised(fmu, name, callbacks)
        # one real value and value reference, for the calls that need the other array given
        vr_one, value_one = (ctypes.c_uint * 1)(vr["current"]), (ctypes.c_double * 1)(0.0)
        calls["fmi2GetReal (value NULL)"] = ("fmi2GetReal", vr_one, 1, None)
        calls["fmi2SetReal (vr NULL)"] = ("fmi2SetReal", None, 1, value_one)
        for key, args in calls.items():
            fn, args = (args[0], args[1:]) if isinstance(args[0], str) else (key, args)
            raw = _c_function(slave, fn)
            before = len(log)
            status = raw(ctypes.c_void_p(slave.component), *args)
            out[key] = {"status": status,
                        "log": [entry.replace(name, "NAME") for entry in log[before:]]}
        slave.setReal([vr["current"]], [-1.0])
        out["step_after"] = _status(lambda: slave.doStep(0.0, 1.0))
        out["finite_after"] = math.isfinite(slave.getReal([vr["voltage"]])[0])
        slave.terminate()
        slave.freeInstance()
    return out


def status_inquiries(fmu: str) -> dict:
    """Row 7: fmi2GetXXXStatus of every kind (its status, value and message), and
    fmi2LastSuccessfulTime through a run: instantiated, set up at 5 s, after two 1-s steps, after
    a refused step, after fmi2SetFMUstate to the state saved at 6 s; fmi2Terminated after it."""
    from lmncell.evaluation.fmueval import fmu_log

    def inquire(slave, fn: str, kind: int, ctype) -> tuple[int, float | None]:
        raw = _c_function(slave, fn)
        value = ctype(-7)
        status = raw(ctypes.c_void_p(slave.component), kind, ctypes.byref(value))
        return status, (float(value.value) if status <= 1 else None)

    out: dict = {"last_time": [], "kinds": {}}
    with fmu_log("status") as (name, callbacks, log):
        slave, vr = _raw(fmu, True, name, callbacks)
        last = lambda: inquire(slave, "fmi2GetRealStatus", 2, ctypes.c_double)  # noqa: E731
        out["last_time"].append(last())
        slave.setupExperiment(startTime=5.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        out["last_time"].append(last())
        slave.setReal([vr["current"]], [-1.0])
        slave.doStep(5.0, 1.0)
        state = slave.getFMUstate()
        slave.doStep(6.0, 1.0)
        out["last_time"].append(last())
        out["refused_step"] = _status(lambda: slave.doStep(6.0, 1.0))     # not the FMU's time
        out["last_time"].append(last())
        slave.setFMUstate(state)
        out["last_time"].append(last())
        slave.freeFMUstate(state)
        for fn, ctype in (("fmi2GetStatus", ctypes.c_int), ("fmi2GetRealStatus", ctypes.c_double),
                          ("fmi2GetIntegerStatus", ctypes.c_int),
                          ("fmi2GetBooleanStatus", ctypes.c_int),
                          ("fmi2GetStringStatus", ctypes.c_void_p)):
            for kind in range(4):
                before = len(log)
                status, value = inquire(slave, fn, kind, ctype)
                out["kinds"][f"{fn} {kind}"] = {
                    "status": status, "value": value if ctype is not ctypes.c_void_p else None,
                    "log": [entry.replace(name, "NAME") for entry in log[before:]]}
        slave.terminate()
        slave.freeInstance()
    return out


def state_reuse(fmu: str) -> dict:
    """Row 7: FMU states as hosts that roll back use them. fmi2GetFMUstate 2,000 times into
    the same state, as FMI 2.0 allows (the FMU reuses or replaces it): the resident memory (kB)
    after 200 and after all; fmi2FreeFMUstate empties the host's pointer and takes an empty one;
    a freed state and a block of zeros, given to fmi2SetFMUstate, fmi2SerializedFMUstateSize,
    fmi2GetFMUstate (as the state to reuse) and fmi2FreeFMUstate: their statuses and messages;
    then whether the instance still steps."""
    from lmncell.evaluation.fmueval import fmu_log

    out: dict = {}
    with fmu_log("reuse") as (name, callbacks, log):
        slave, vr = _raw_initialised(fmu, name, callbacks)
        c = ctypes.c_void_p(slave.component)
        get, put = _c_function(slave, "fmi2GetFMUstate"), _c_function(slave, "fmi2SetFMUstate")
        free, size = _c_function(slave, "fmi2FreeFMUstate"), _c_function(slave,
                                                                   "fmi2SerializedFMUstateSize")
        state, statuses = ctypes.c_void_p(), set()
        for k in range(2000):
            statuses.add(get(c, ctypes.byref(state)))
            if k + 1 in (200, 2000):
                out[f"rss_{k + 1}"] = _rss_kb()
        out["reuse_statuses"] = sorted(statuses)
        out["free"] = free(c, ctypes.byref(state))
        out["freed_pointer_emptied"] = state.value is None
        out["free_empty"] = free(c, ctypes.byref(state))
        zeros = ctypes.create_string_buffer(65536)
        stale = ctypes.c_void_p()
        get(c, ctypes.byref(stale))
        free(c, ctypes.byref(ctypes.c_void_p(stale.value)))      # the host keeps a copy
        for label, bad in (("freed", stale.value), ("zeros", ctypes.addressof(zeros))):
            for call, args in (("fmi2SetFMUstate", (put, ctypes.c_void_p(bad))),
                               ("fmi2SerializedFMUstateSize",
                                (size, ctypes.c_void_p(bad), ctypes.byref(ctypes.c_size_t()))),
                               ("fmi2GetFMUstate", (get, ctypes.byref(ctypes.c_void_p(bad)))),
                               ("fmi2FreeFMUstate", (free, ctypes.byref(ctypes.c_void_p(bad))))):
                before = len(log)
                status = args[0](c, *args[1:])
                out[f"{call} {label}"] = {"status": status, "log": [
                    entry.replace(name, "NAME") for entry in log[before:]]}
        slave.setReal([vr["current"]], [-1.0])
        out["step_after"] = _status(lambda: slave.doStep(0.0, 1.0))
        slave.terminate()
        slave.freeInstance()
    return out


def _damaged(serialized: bytes) -> dict[str, bytes]:
    """Damaged copies of a serialised FMU state: for the pythonfmu FMU's JSON, a non-finite
    time, a part missing, parameters, model state and accumulators of the wrong shape or kind,
    bytes that are no JSON or JSON of another kind;
    for the native FMU's bytes, everything after the magic number set to 0xFF (a NaN time,
    switches out of range)."""
    try:
        doc = json.loads(serialized)
    except (UnicodeDecodeError, ValueError):
        return {"0xFF after the magic number": serialized[:4] + b"\xff" * (len(serialized) - 4)}

    def changed(edit: Callable[[dict], object]) -> bytes:
        copy = json.loads(serialized)
        edit(copy)
        return json.dumps(copy, allow_nan=True).encode()

    return {"NaN time": changed(lambda d: d.update(time=math.nan)),
            "no engine": changed(lambda d: d.pop("cosim")),
            "one parameter": changed(lambda d: d.update(params=d["params"][:1])),
            "model state cut short": changed(
                lambda d: d["cosim"].update(stepper=d["cosim"]["stepper"][:3])),
            "text accumulator": changed(lambda d: d["cosim"]["acc"].__setitem__(0, "x")),
            "NaN voltage": changed(lambda d: d["cosim"]["stepper"].__setitem__(-1, math.nan)),
            "not JSON": b"\xff" + serialized[1:],
            "not a JSON object": b"[]",
            "JSON nested too deeply": b"[" * 100_000,
            } if doc.get("cosim") else {}


def _read_back(slave: FMU2Slave, data: bytes) -> tuple[int, int | None]:
    """The statuses of fmi2DeSerializeFMUstate of data and, where it gave a state,
    fmi2SetFMUstate of that state (else None)."""
    got: list = []
    read = _status(lambda: got.append(slave.deSerializeFMUstate(data)))
    return read, _status(lambda: slave.setFMUstate(got[0])) if got else None


def damaged_states(fmu: str) -> dict:
    """A state saved after 10 s at −1 A, serialised, damaged (_damaged) and read back
    (fmi2DeSerializeFMUstate, then fmi2SetFMUstate) at 11 s: the statuses, the messages, and
    whether the instance's outputs and time are still those of 11 s (its next step gives the
    voltage of an undamaged twin)."""
    from lmncell.evaluation.fmueval import fmu_log

    out: dict = {}
    with fmu_log("damaged") as (name, callbacks, log):
        slave, vr = _raw_initialised(fmu, name, callbacks)
        outputs = [vr["voltage"], vr["soc"], vr["soc_std"], vr["cell_temperature"]]
        slave.setReal([vr["current"]], [-1.0])
        for k in range(10):
            slave.doStep(float(k), 1.0)
        serialized = bytes(slave.serializeFMUstate(slave.getFMUstate()))
        slave.setReal([vr["current"]], [-2.0])
        slave.doStep(10.0, 1.0)
        now, at_11 = slave.getFMUstate(), slave.getReal(outputs)
        slave.doStep(11.0, 1.0)
        out["twin_next"] = slave.getReal([vr["voltage"]])[0]
        for label, data in _damaged(serialized).items():
            slave.setFMUstate(now)
            before = len(log)
            read, put = _read_back(slave, data)
            kept = slave.getReal(outputs) == at_11
            nxt = _status(lambda: slave.doStep(11.0, 1.0))
            out[label] = {"read": read, "set": put, "kept": kept, "next_step": nxt,
                          "next": slave.getReal([vr["voltage"]])[0],
                          "log": [entry.replace(name, "NAME") for entry in log[before:]]}
        slave.freeInstance()
    return out


def _rss_kb() -> int:
    """Resident set size of this process (kB, Linux)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4


def instantiate_many(fmu: str, cycles: int = 2000) -> dict:
    """Row 7: memory over many instantiate/setup/initialise/step/free cycles (kB of resident
    memory after the first 200 cycles and after all)."""
    md = read_model_description(fmu)
    where = extract(fmu)
    rss = {}
    for k in range(cycles):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=where,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"i{k}")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slave.doStep(0.0, 1.0)
        slave.terminate()
        slave.freeInstance()
        if k + 1 in (200, cycles):
            rss[str(k + 1)] = _rss_kb()
    return rss


HOSTILE_REALS = (0.0, 1.0, -1.0, 0.5, 2.0, 4.2, 25.0, -40.0, 80.0, 1e-300, 1e308, -1e308,
                 math.nan, math.inf, -math.inf)
STEP_SIZES = (1.0, 1.0, 1.0, 0.1, 10.0, 3600.0, 1e5, 1e-12, 0.0, -1.0, math.nan, math.inf,
              1e300)   # 1e300: more model steps than one call may take (looped for ever)


class RandomHost:
    """A host that makes the FMI 2.0 calls of one instance in an order and with arguments
    chosen by a seeded random generator: NaN, ±inf, ±1e308, negative or zero step sizes,
    communication points that are not the FMU's time, unknown references, NULL log
    categories, FMU states saved, restored, serialised (some damaged on the way) and freed
    in any mode. With stock=True, the calls that pythonfmu's own wrapper itself gets wrong
    (NULL log categories, freed states: crashes; fmi2LastSuccessfulTime: NaN with fmi2OK) are
    left out, so that what remains tests the slave under that wrapper."""

    STOCK_WRAPPER_FAULTS = ("debug_logging", "free_state", "last_time")

    def __init__(self, slave: FMU2Slave, md: ModelDescription, rng: random.Random,
                 stock: bool = False) -> None:
        self.slave, self.rng, self.clock = slave, rng, 0.0
        self.states: list[tuple[object, float]] = []     # saved FMU states and their times
        self.vars = {t: [v for v in md.modelVariables if v.type == t]
                     for t in ("Real", "Integer", "Boolean", "String")}
        self.outputs = [v.valueReference for v in self.vars["Real"] if v.causality == "output"]
        self.other_refs = {t: [v.valueReference for v in self.vars[t]]
                           for t in ("Integer", "Boolean", "String")}
        self.calls = {   # call: (method, relative frequency); most hosts mostly step and read
            "setup": (self.setup, 0.3), "enter": (self.enter, 0.3), "exit": (self.exit, 0.3),
            "set_real": (self.set_real, 3.0), "set_integer": (self.set_integer, 0.5),
            "set_boolean": (self.set_boolean, 0.5), "get_outputs": (self.get_outputs, 3.0),
            "get_others": (self.get_others, 0.5), "step": (self.step, 6.0),
            "reset": (self.reset, 0.2), "terminate": (self.terminate, 0.2),
            "unknown_reference": (self.unknown_reference, 0.5),
            "debug_logging": (self.debug_logging, 0.3), "save_state": (self.save_state, 0.4),
            "restore_state": (self.restore_state, 0.4),
            "serialize_state": (self.serialize_state, 0.2), "free_state": (self.free_state, 0.2),
            "last_time": (self.last_time, 0.3)}
        for name in self.STOCK_WRAPPER_FAULTS if stock else ():
            del self.calls[name]

    def call(self) -> str:
        """One random call: its name, arguments and status; AssertionError where an OK status
        came with a non-finite output."""
        name = self.rng.choices(list(self.calls), [w for _, w in self.calls.values()])[0]
        what, status = self.calls[name][0]()
        return f"{name}{what} -> {status}"

    def initialise(self) -> list[str]:
        """What most hosts do first: setupExperiment at 0, enter, set a few values (an observer
        among them), exit, so that the random calls after it reach step mode."""
        self.clock = 0.0
        calls = [("setup", (" 0.0", _status(lambda: self.slave.setupExperiment(startTime=0.0)))),
                 ("enter", self.enter())]
        calls += [("set_real", self.set_real()) for _ in range(self.rng.randint(0, 3))]
        calls += [("set_integer", self.set_integer()) for _ in range(self.rng.randint(0, 1))]
        calls.append(("exit", self.exit()))
        return [f"{name}{what} -> {status}" for name, (what, status) in calls]

    def setup(self) -> tuple[str, int]:
        start = self.rng.choice((0.0, 0.0, 5.0, -1.0, math.nan))
        stop = self.rng.choice((None, 1e4, -5.0))
        self.clock = start if math.isfinite(start) else 0.0
        return f" {start!r}…{stop!r}", _status(
            lambda: self.slave.setupExperiment(startTime=start, stopTime=stop))

    def enter(self) -> tuple[str, int]:
        return "", _status(self.slave.enterInitializationMode)

    def exit(self) -> tuple[str, int]:
        return "", _status(self.slave.exitInitializationMode)

    def set_real(self) -> tuple[str, int]:
        return self._set_one("Real", self._real_value, self.slave.setReal)

    def set_integer(self) -> tuple[str, int]:
        return self._set_one("Integer", lambda: self.rng.choice((0, 1, 2, 3, 4, -1, 2**31 - 1)),
                             self.slave.setInteger)

    def set_boolean(self) -> tuple[str, int]:
        return self._set_one("Boolean", lambda: self.rng.random() < 0.5, self.slave.setBoolean)

    def _real_value(self) -> float:
        if self.rng.random() < 0.5:
            return self.rng.choice(HOSTILE_REALS)
        return self.rng.uniform(-10.0, 60.0)

    def _set_one(self, kind: str, value_of: Callable[[], object],
                 setter: Callable[[list[int], list], None]) -> tuple[str, int]:
        """Set one random variable of a type (Real, Integer, Boolean) to value_of()."""
        if not self.vars[kind]:
            return "", -1
        var = self.rng.choice(self.vars[kind])
        value = value_of()
        return f" {var.name}={value!r}", _status(lambda: setter([var.valueReference], [value]))

    def get_outputs(self) -> tuple[str, int]:
        got: list[float] = []
        status = _status(lambda: got.extend(self.slave.getReal(self.outputs)))
        assert status != OK or all(math.isfinite(x) for x in got), f"OK with outputs {got}"
        return "", status

    def get_others(self) -> tuple[str, int]:
        refs = self.other_refs
        statuses = [_status(lambda: self.slave.getInteger(refs["Integer"])),
                    _status(lambda: self.slave.getBoolean(refs["Boolean"])),
                    _status(lambda: self.slave.getString(refs["String"]))]
        return "", max(statuses)

    def step(self) -> tuple[str, int]:
        size = self.rng.choice(STEP_SIZES)
        point = (self.clock if self.rng.random() < 0.85
                 else self.rng.choice((self.clock + 1.0, math.nan, -1.0)))
        status = _status(lambda: self.slave.doStep(currentCommunicationPoint=point,
                                                   communicationStepSize=size))
        if status == OK:
            self.clock = point + size
        return f" at {point!r} by {size!r}", status

    def reset(self) -> tuple[str, int]:
        self.clock = 0.0
        return "", _status(self.slave.reset)

    def terminate(self) -> tuple[str, int]:
        return "", _status(self.slave.terminate)

    def unknown_reference(self) -> tuple[str, int]:
        ref = self.rng.choice((9999, 2**31, 2**32 - 1))
        return f" {ref}", _status(lambda: self.slave.getReal([ref]))

    def save_state(self) -> tuple[str, int]:
        got: list = []
        status = _status(lambda: got.append(self.slave.getFMUstate()))
        if status == OK:
            self.states.append((got[0], self.clock))
        return f" #{len(self.states)}", status

    def restore_state(self) -> tuple[str, int]:
        if not self.states:
            return " (none saved)", -1
        k = self.rng.randrange(len(self.states))
        status = _status(lambda: self.slave.setFMUstate(self.states[k][0]))
        if status == OK:
            self.clock = self.states[k][1]
        return f" #{k + 1}", status

    def serialize_state(self) -> tuple[str, int]:
        """A saved state serialised and read back as a new one, in two of five cases with one
        of its bytes after the first four (the native FMU's magic number) overwritten."""
        if not self.states:
            return " (none saved)", -1
        k = self.rng.randrange(len(self.states))
        data = bytearray(self.slave.serializeFMUstate(self.states[k][0]))
        damage = ""
        if self.rng.random() < 0.4 and len(data) > 4:
            at, value = self.rng.randrange(4, len(data)), self.rng.randrange(256)
            data[at], damage = value, f" with byte {at} = {value}"
        got: list = []
        status = _status(lambda: got.append(self.slave.deSerializeFMUstate(bytes(data))))
        if status == OK:
            self.states.append((got[0], self.states[k][1]))
        return f" #{k + 1}{damage}", status

    def free_state(self) -> tuple[str, int]:
        if not self.states:
            return " (none saved)", -1
        k = self.rng.randrange(len(self.states))
        state, _ = self.states.pop(k)
        return f" #{k + 1}", _status(lambda: self.slave.freeFMUstate(state))

    def free_states(self) -> None:
        """Every saved state freed (before the instance is)."""
        while self.states:
            self.slave.freeFMUstate(self.states.pop()[0])

    def last_time(self) -> tuple[str, int]:
        """fmi2GetRealStatus(fmi2LastSuccessfulTime): a finite time where it says OK."""
        value = ctypes.c_double(math.nan)
        status = _c_function(self.slave, "fmi2GetRealStatus")(
            ctypes.c_void_p(self.slave.component), 2, ctypes.byref(value))
        assert status != OK or math.isfinite(value.value), f"OK with last time {value.value}"
        return "", status

    def debug_logging(self) -> tuple[str, int]:
        """fmi2SetDebugLogging on or off with a random category list: declared, undeclared or
        NULL entries, or a NULL array with nCategories > 0."""
        from fmpy.fmi2 import fmi2String

        on = self.rng.random() < 0.5
        names = [self.rng.choice((b"logStatusWarning", b"logStatusError", b"logAll",
                                  b"noSuchCategory", None)) for _ in range(self.rng.randint(0, 3))]
        n, array = len(names), (fmi2String * len(names))(*names) if names else None
        if self.rng.random() < 0.1:
            n, array = self.rng.randint(1, 3), None
        return f" {on} {names if array is not None else f'NULL x{n}'}", _status(
            lambda: self.slave.fmi2SetDebugLogging(self.slave.component, on, n, array))


def random_calls(fmu: str, seed: int = 1, sequences: int = 20, stock: bool = False) -> dict:
    """Seeded RandomHost sequences of 5…60 calls each between instantiation and freeInstance,
    seven in ten after an ordinary initialisation.
    The host must not die (the test sees the child's exit code), and an OK status never comes
    with a non-finite output."""
    rng = random.Random(seed)
    md = read_model_description(fmu)
    where = extract(fmu)
    findings, calls = [], 0
    for k in range(sequences):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=where,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"r{k}")
        slave.instantiate(loggingOn=False)
        host = RandomHost(slave, md, rng, stock)
        log = host.initialise() if rng.random() < 0.7 else []
        try:
            for _ in range(rng.randint(5, 60)):
                log.append(host.call())
                calls += 1
        except AssertionError as exc:
            findings.append({"sequence": k, "finding": str(exc), "calls": log})
        host.free_states()
        slave.freeInstance()
    return {"sequences": sequences, "calls": calls, "findings": findings}


def random_calls_long(fmu: str) -> dict:
    """random_calls over 300 sequences of another seed (the slow test)."""
    return random_calls(fmu, seed=2, sequences=300)


def random_calls_stock(fmu: str) -> dict:
    """random_calls without the calls that pythonfmu's own wrapper gets wrong itself
    (RandomHost.STOCK_WRAPPER_FAULTS), for an FMU built with that wrapper."""
    return random_calls(fmu, seed=3, sequences=40, stock=True)


SEQUENCES = {f.__name__: f for f in (init_mode_outputs, temperature_outside_range_at_start,
                                     state_machine, stop_time, impossible_inputs,
                                     logged_messages, cell_start_parameters, access_refusals,
                                     debug_logging_categories,
                                      observers_at_full, ordinary_errors, wrong_guid_or_type,
                                      resource_locations, logged_resource_refusals,
                                      null_pointers, status_inquiries, mode_rules,
                                      state_reuse, damaged_states,
                                      instantiate_many, random_calls, random_calls_long,
                                      random_calls_stock)}

if __name__ == "__main__":
    print(json.dumps(SEQUENCES[sys.argv[2]](sys.argv[1])))
