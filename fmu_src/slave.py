"""pythonfmu adapter: the LMNCell FMU's slave class, a thin layer over lmncell.runtime.cosim.

The build copies this package into the FMU's resources under a name unique to the model and
generates a one-line module that subclasses LmnCellSlave, so that two LMNCell FMUs in one
process each run their own code. The model file travels as resources/model.json.
"""

from __future__ import annotations

import atexit
import ctypes
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from .cosim import (
    OUT_OF_RANGE_DESCRIPTION,
    STOP_TOLERANCE,
    CellCosim,
    InputError,
    Parameters,
    state_fault,
)
from .model import ModelFileError, is_cell_capacity, load_model
from .observers import OBSERVER_NAMES as OBSERVERS
from .thermal import (
    CELL_START_DESCRIPTION,
    CELL_TEMPERATURE_RANGE_C,
    DEFAULT_TEMPERATURE_C,
    TEMPERATURE_DESCRIPTION,
    USE_CELL_START_DESCRIPTION,
)

UNREADABLE = "unreadable"   # key of the state that _fmu_state_from_bytes gives for bad bytes

# pythonfmu 0.7.0's native wrapper (findClass) re-executes the slave module's source in the
# module's namespace and then releases one reference to the module's __dict__ that it never
# owned, at every instantiation: without a counterweight the module dictionary is freed while
# still in use. The generated slave module calls keep_module_dict(globals()) at its top level,
# so each (re-)execution keeps one reference here (8 bytes each), balancing that release.
_MODULE_DICT_REFS: list[dict] = []


def value_text(value: Any, kind: type) -> str:
    """A value of a get or set call as the log writes it, in the native FMU's words
    (value_text in lmncell.c): a Boolean true or false, an Integer in decimal, a Real in the
    fewest significant digits that read back to it, in %g's form and without an exponent
    below 1e6 (0.2, 40, 250000, 2.5e+06, 1e-300, 0.30000000000000004), nan, inf or -inf."""
    if kind is Boolean:
        return "true" if value else "false"
    if kind is Integer:
        return str(int(value))
    x = float(value)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    digits = next(p for p in range(1, 18) if float(f"{x:.{p - 1}e}") == x)
    exponent = int(f"{x:.{digits - 1}e}".split("e")[1])
    return f"{x:.{max(digits, min(exponent + 1, 6))}g}"


def keep_module_dict(namespace: dict) -> None:
    """Keep a reference to a slave module's namespace (see _MODULE_DICT_REFS)."""
    _MODULE_DICT_REFS.append(namespace)


# pythonfmu 0.7.0's own wrapper keeps its interpreter state in a static shared_ptr. When a host
# exits with the FMU's library still loaded, the C++ runtime destroys that pointer first and the
# library's destructor then assigns to it (finalizePythonInterpreter): the state is released
# twice and the heap corrupted, so that the host may abort at exit ("corrupted double-linked
# list"). In a Python host, calling finalizePythonInterpreter at interpreter exit, before the C++
# runtime's turn, empties the pointer and the later calls find nothing to release. LMNCell's
# build keeps the pointer on the heap and needs no help: its binaries/linux64/<id>.so is the
# entry library (shim.c), which exports no finalizePythonInterpreter, so the call is skipped.
_EXIT_HOOKED: set[str] = set()


def release_wrapper_state_at_exit(binary: Path) -> bool:
    """Register (once per library) a call of `binary`'s finalizePythonInterpreter at interpreter
    exit, in a Python host (sys.orig_argv is empty where the wrapper started the interpreter
    itself). True if registered now."""
    key = str(binary)
    if os.name != "posix" or not sys.orig_argv or key in _EXIT_HOOKED or not binary.is_file():
        return False
    _EXIT_HOOKED.add(key)
    atexit.register(_finalize_wrapper_state, key)
    return True


def _finalize_wrapper_state(binary: str) -> None:
    """Call the wrapper library's finalizePythonInterpreter if it is still loaded (RTLD_NOLOAD:
    never loads it again)."""
    try:
        lib = ctypes.CDLL(binary, mode=os.RTLD_NOLOAD | os.RTLD_NOW)
        finalize = lib.finalizePythonInterpreter
    except (OSError, AttributeError):
        return
    finalize.restype = None
    finalize()


class CallError(RuntimeError):
    """An ordinary FMI call error (unknown reference, wrong type, refused step, …)."""


class LmnCellSlave(Fmi2Slave):
    """FMI 2.0 co-simulation slave of an LMN cell model (see GUIDE: FMU interface)."""

    author = "LMNCell"
    description = "Local model network battery cell model"

    def __init__(self, **kwargs) -> None:
        # LMNCell's build of the wrapper (build/pythonfmu_wrapper) passes errors_as_status: it
        # returns fmi2Error for an exception and keeps the instance; pythonfmu 0.7's own does not
        self._errors_as_status = bool(kwargs.pop("errors_as_status", False))
        super().__init__(**kwargs)
        self._dedupe_sys_path()
        res = Path(self.resources) if self.resources else Path(__file__).resolve().parent.parent
        if self.resources:
            release_wrapper_state_at_exit(res.parent / "binaries" / "linux64" /
                                          f"{type(self).__name__}.so")
        self._model = load_model(res / "model.json")
        self.current = 0.0
        self.voltage_measured = 0.0
        self.temperature = DEFAULT_TEMPERATURE_C
        self.soc0 = 1.0
        self.capacity = float(self._model.capacity_ah)
        self.observer = 0
        self.temperature_is_cell = False
        self.cell_temperature_start = DEFAULT_TEMPERATURE_C
        self.use_cell_temperature_start = False
        self._cosim: CellCosim | None = None
        self._time = 0.0
        self._stop_time: float | None = None   # fmi2SetupExperiment's, where defined (s)
        self._terminated = False
        self._in_initialization = False
        self._register_variables(self._model.thermal is not None)
        # the per-step calls' fast path: the Real variables that get_real may read and the
        # inputs that set_real may always set (anything else goes through the checks)
        self._real_getters = {vr: v.getter for vr, v in self.vars.items() if isinstance(v, Real)}
        self._input_names = {vr: v.local_name for vr, v in self.vars.items()
                             if isinstance(v, Real) and v.causality == Fmi2Causality.input}

    def _register_variables(self, has_thermal: bool) -> None:
        """Declare the FMU's variables (inputs, outputs, parameters; GUIDE: FMU interface),
        in the order of their value references; has_thermal: the model carries a thermal
        model, so `temperature` is the ambient by default."""
        reg = self.register_variable
        reg(Real("current", causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                 description="cell current held over the step, > 0 charges [A]"))
        reg(Real("voltage_measured", causality=Fmi2Causality.input,
                 variability=Fmi2Variability.continuous,
                 description="measured terminal voltage, mean over the step, for the observer; "
                             "0 = not measured [V]"))
        reg(Real("temperature", causality=Fmi2Causality.input,
                 variability=Fmi2Variability.continuous,
                 description=TEMPERATURE_DESCRIPTION if has_thermal else
                 "cell temperature (this model has no thermal model) [degC]"))
        reg(Real("voltage", causality=Fmi2Causality.output,
                 variability=Fmi2Variability.continuous,
                 getter=lambda: (self._cosim or self._initial_cosim()).voltage_v,
                 description=("model terminal voltage now: the last model step's, or "
                              "between model steps the step in progress previewed [V]")))
        reg(Real("soc", causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                 getter=lambda: (self._cosim or self._initial_cosim()).soc,
                 description="state of charge: coulomb counting, or the observer's estimate "
                             "[1]"))
        reg(Real("soc_std", causality=Fmi2Causality.output,
                 variability=Fmi2Variability.continuous,
                 getter=lambda: (self._cosim or self._initial_cosim()).soc_std,
                 description="observer's SoC standard deviation (0 without observer) [1]"))
        reg(Boolean("out_of_range", causality=Fmi2Causality.output,
                    variability=Fmi2Variability.discrete,
                    getter=lambda: bool(self._cosim and self._cosim.out_of_range),
                    description=OUT_OF_RANGE_DESCRIPTION))
        reg(Real("soc0", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                 description="initial state of charge [1]"))
        reg(Real("capacity", causality=Fmi2Causality.parameter,
                 variability=Fmi2Variability.fixed,
                 description="capacity for coulomb counting [Ah]"))
        reg(Integer("observer", causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.fixed,
                    description="SoC observer: 0 none (coulomb counting), 1 EKF, 2 fuzzy "
                                "observer, 3 IMM; uses voltage_measured"))
        reg(Boolean("temperature_is_cell", causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.fixed,
                    description="true: the input 'temperature' is the measured cell "
                                "temperature; false (default): the ambient temperature, the "
                                "cell temperature follows the model's thermal model"))
        reg(Real("cell_temperature", causality=Fmi2Causality.output,
                 variability=Fmi2Variability.continuous,
                 getter=lambda: (self._cosim or self._initial_cosim()).cell_temperature_c,
                 description="cell temperature at the end of the last completed model step "
                             "(the next step's) [degC]"))
        reg(Real("cell_temperature_start", causality=Fmi2Causality.parameter,
                 variability=Fmi2Variability.fixed, description=CELL_START_DESCRIPTION))
        reg(Boolean("use_cell_temperature_start", causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.fixed, description=USE_CELL_START_DESCRIPTION))

    def _dedupe_sys_path(self) -> None:
        """The wrapper inserts the resources folder into sys.path at every instantiation: keep
        one entry for it, and drop entries of FMU resources folders that no longer exist (left by
        earlier, since removed extractions)."""
        if not self.resources:
            return
        kept: list[str] = []
        for p in sys.path:
            if p == self.resources and p in kept:
                continue
            if p != self.resources and p.endswith("resources") and not Path(p).is_dir():
                continue
            kept.append(p)
        sys.path[:] = kept

    def _initial_cosim(self) -> CellCosim:
        """Before initialisation, the engine exitInitializationMode will make from the
        parameters and inputs set so far: the outputs read now are those it will give (nothing
        changed in between, nothing differs)."""
        m = self._model
        soc0 = min(max(float(self.soc0), 0.0), 1.0) if math.isfinite(self.soc0) else 1.0
        cap = float(self.capacity)
        cap = cap if is_cell_capacity(cap) else float(m.capacity_ah)
        observer = int(self.observer) if self.observer in OBSERVERS else 0
        is_cell = bool(self.temperature_is_cell)
        try:
            cosim = CellCosim(m, Parameters(soc0, cap, observer, is_cell, self._cell_start()))
        except InputError:     # a start temperature exitInitializationMode will refuse:
            cosim = CellCosim(m, Parameters(soc0, cap, observer, is_cell))   # until then unset
        cosim.reset(self._start_temperature())
        return cosim

    def _cell_start(self) -> float | None:
        """The cell's start temperature the parameters ask for (°C), or None: rested at the
        first step's temperature input (use_cell_temperature_start false)."""
        return float(self.cell_temperature_start) if self.use_cell_temperature_start else None

    def _start_temperature(self) -> float:
        """The temperature input the engine starts from (degC): as set, or
        DEFAULT_TEMPERATURE_C where it is not one that a step takes (not finite, or outside
        CELL_TEMPERATURE_RANGE_C: the first step refuses it; the outputs until then stay
        finite, a model with temperature terms read NaN at −1e308 °C)."""
        low, high = CELL_TEMPERATURE_RANGE_C
        t = float(self.temperature)
        return t if math.isfinite(t) and low <= t <= high else DEFAULT_TEMPERATURE_C

    # ----- guarded access. With LMNCell's build of the wrapper an ordinary call error raises
    # CallError, which the wrapper logs and returns as fmi2Error (nothing is changed). pythonfmu
    # 0.7's own wrapper turns any Python exception into fmi2Fatal and frees the slave object
    # while it is still in use (PySlaveInstance::cleanPyObject in handle_py_exception), so the
    # host crashes on the next call: with that wrapper the error is logged through the FMI
    # logger and the call ignored (status OK; a refused step is fmi2Discard).
    def _problem(self, vr: int, kind: type[Any], setting: bool) -> str:
        var = self.vars.get(vr)
        if var is None:
            return f"no variable with value reference {vr}"
        if not isinstance(var, kind):
            article = "an" if kind.__name__[0] in "AEIOU" else "a"
            return f"value reference {vr} ('{var.name}') is not {article} {kind.__name__}"
        if setting and var.causality not in (Fmi2Causality.input, Fmi2Causality.parameter):
            return f"'{var.name}' is an {var.causality.name} and cannot be set"
        if setting and var.causality == Fmi2Causality.parameter and self._cosim is not None:
            return (f"parameter '{var.name}' is fixed after initialisation (value kept: "
                    f"{value_text(var.getter(), kind)})")
        return ""

    def _check_readable(self, call: str) -> None:
        """An error (see _error) where FMI 2.0 does not let the host read variables: before
        fmi2EnterInitializationMode. Under pythonfmu's own wrapper the error is only logged and
        the call still answers (the outputs the initialisation would give, all finite)."""
        self._allowed(call, "initialization mode", "step mode", "terminated")

    def _get(self, vrs: list[int], kind: type, call: str, bad: object) -> list:
        self._check_readable(call)
        out = []
        for vr in vrs:
            problem = self._problem(vr, kind, setting=False)
            if problem:
                self._error(f"{call}: {problem}")
                out.append(bad)
            else:
                out.append(self.vars[vr].getter())
        return out

    def _set(self, vrs: list[int], values: list, kind: type, call: str) -> None:
        if not self._allowed(call, "instantiated", "initialization mode", "step mode"):
            return
        problems = [(vr, value, self._problem(vr, kind, setting=True))
                    for vr, value in zip(vrs, values, strict=False)]
        bad = [f"{problem}; {value_text(value, kind)} was not set"
               for _, value, problem in problems if problem]
        if bad and self._errors_as_status:     # the native FMU's words (all_settable)
            more = len(bad) - 1
            self._error(f"{call}: {bad[0]}"
                        + (f"; {more} more value{'s' if more > 1 else ''} refused" if more
                           else "") + " (nothing of this call was set)")
        for vr, value, problem in problems:
            if problem:
                self._error(f"{call}: {problem}; {value_text(value, kind)} was not set")
            else:
                self.vars[vr].setter(value)

    def get_real(self, vrs: list[int]) -> list[float]:
        if self._cosim is None:
            self._check_readable("fmi2GetReal")
        try:
            return [float(get()) for get in map(self._real_getters.__getitem__, vrs)]
        except (KeyError, TypeError):   # a reference that is not a Real: the checked path
            pass
        return [float(v) for v in self._get(vrs, Real, "fmi2GetReal", math.nan)]

    def get_integer(self, vrs: list[int]) -> list[int]:
        return [int(v) for v in self._get(vrs, Integer, "fmi2GetInteger", 0)]

    def get_boolean(self, vrs: list[int]) -> list[bool]:
        return [bool(v) for v in self._get(vrs, Boolean, "fmi2GetBoolean", False)]

    def get_string(self, vrs: list[int]) -> list[str]:
        self._check_readable("fmi2GetString")
        for vr in vrs:
            self._error(f"fmi2GetString: value reference {vr}: this FMU has no String "
                        "variables")
        return ["" for _ in vrs]

    def set_real(self, vrs: list[int], values: list[float]) -> None:
        try:
            names = [self._input_names[vr] for vr in vrs]
        except (KeyError, TypeError):
            names = None
        if names is not None and len(names) == len(values) and not self._terminated:
            for name, value in zip(names, values, strict=True):
                setattr(self, name, value)
            return
        self._set(vrs, values, Real, "fmi2SetReal")

    def set_integer(self, vrs: list[int], values: list[int]) -> None:
        self._set(vrs, values, Integer, "fmi2SetInteger")

    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        self._set(vrs, values, Boolean, "fmi2SetBoolean")

    def set_string(self, vrs: list[int], values: list[str]) -> None:
        for vr in vrs:
            self._error(f"fmi2SetString: value reference {vr}: this FMU has no String "
                        "variables; nothing was set")

    def _error(self, msg: str) -> None:
        """Report an ordinary call error: raised as CallError (→ fmi2Error) where the wrapper
        allows it, else logged (the call is then ignored)."""
        if self._errors_as_status:
            raise CallError(msg)
        self.log(msg, Fmi2Status.error)

    def _mode(self) -> str:
        """The FMI 2.0 co-simulation state, named as the native FMU names it."""
        if self._terminated:
            return "terminated"
        if self._in_initialization:
            return "initialization mode"
        return "step mode" if self._cosim is not None else "instantiated"

    def _allowed(self, call: str, *modes: str) -> bool:
        """True where the FMU is in one of the modes, else an error (see _error) naming the
        call and the mode, as the native FMU's in_mode."""
        mode = self._mode()
        if mode in modes:
            return True
        self._error(f"{call} is not allowed in {mode}")
        return False

    def enter_initialization_mode(self) -> None:
        if self._allowed("fmi2EnterInitializationMode", "instantiated"):
            self._in_initialization = True

    def exit_initialization_mode(self) -> None:
        """Bad parameters are errors (see _error) and leave the FMU in Initialization Mode,
        uninitialised, so that every doStep is refused until the parameters are set right and
        this is called again (as in the native FMU)."""
        if not self._allowed("fmi2ExitInitializationMode", "initialization mode"):
            return
        if self.observer not in OBSERVERS:
            self._error(f"parameter 'observer' = {self.observer}: expected 0 none, 1 EKF, "
                        "2 fuzzy, 3 IMM; not initialised, every step will be refused")
            return
        try:
            self._cosim = CellCosim(self._model, Parameters(float(self.soc0),
                                                            float(self.capacity),
                                                            int(self.observer),
                                                            bool(self.temperature_is_cell),
                                                            self._cell_start()))
            self._cosim.reset(self._start_temperature())
        except InputError as exc:
            self._cosim = None
            self._error(f"{exc}; not initialised, every step will be refused")
            return
        self._in_initialization = False

    def setup_experiment(self, start_time: float, stop_time: float | None,
                         tolerance: float | None) -> None:
        """The start time (s), before initialisation only; a non-finite one is refused (it
        would make every later step's communication point wrong)."""
        if not self._allowed("fmi2SetupExperiment", "instantiated"):
            return
        if not math.isfinite(start_time):
            self._error(f"fmi2SetupExperiment: startTime {start_time:g} is not finite")
            return
        if stop_time is not None and not (math.isfinite(stop_time) and stop_time >= start_time):
            self._error(f"fmi2SetupExperiment: stopTime {stop_time:g} is not a finite time at "
                        f"or after startTime {start_time:g} (stopTimeDefined is true); nothing "
                        "was set")
            return
        self._time = float(start_time)
        self._stop_time = None if stop_time is None else float(stop_time)

    def terminate(self) -> None:
        if self._allowed("fmi2Terminate", "initialization mode", "step mode"):
            self._terminated = True

    def do_step(self, current_time: float, step_size: float) -> bool:
        cosim, now = self._cosim, self._time
        if not self._allowed("fmi2DoStep", "step mode") or cosim is None:
            return False
        if not abs(current_time - now) <= 1e-9 * max(1.0, abs(now)):  # NaN too
            self._error(f"fmi2DoStep: currentCommunicationPoint {current_time:.17g} s is not the "
                        f"FMU's time {now:.17g} s (steps must follow on from each other)")
            return False
        if self._past_stop(now, step_size):
            self._error(f"fmi2DoStep: a step of {step_size:.17g} s from {now:.17g} s ends past "
                        f"the stop time {self._stop_time:.17g} s given to fmi2SetupExperiment; "
                        "the step was not taken")
            return False
        try:
            was = cosim.out_of_range
            cosim.advance(step_size, self.current, self.temperature, self.voltage_measured)
        except InputError as exc:
            self._error(f"t = {now:.9g} s: {exc}; the step was not taken")
            return False
        self._time = now + step_size
        if cosim.out_of_range and not was:
            self.log(f"t = {now:.9g} s: {cosim.range_message}", Fmi2Status.warning)
        return True

    def _past_stop(self, now: float, step_size: float) -> bool:
        """True where a finite step from now (s) would end past the stop time the host defined
        (beyond STOP_TOLERANCE of it, relative, at least 1 s times it): FMI 2.0 asks fmi2Error
        there."""
        stop = self._stop_time
        return (stop is not None and math.isfinite(step_size)
                and not now + step_size <= stop + STOP_TOLERANCE * max(1.0, abs(stop)))

    def _last_successful_time(self) -> float:
        """The FMU's time (s): the end of the last completed communication step, the start time
        before the first; LMNCell's wrapper answers fmi2GetRealStatus(fmi2LastSuccessfulTime)
        with it."""
        return self._time

    # ----- FMU state: parameters, inputs and the whole engine state ------------------------
    def _get_fmu_state(self) -> dict:
        return {"inputs": [self.current, self.voltage_measured, self.temperature],
                "time": self._time,
                "params": [self.soc0, self.capacity, self.observer, self.temperature_is_cell,
                           self.cell_temperature_start, self.use_cell_temperature_start],
                "cosim": None if self._cosim is None else self._cosim.get_state()}

    def _set_fmu_state(self, state: dict) -> None:
        """Restore a _get_fmu_state() dict. One that is not a state of this FMU (another shape,
        values of the wrong kind, a non-finite time) is refused as an ordinary call error
        (fmi2Error with LMNCell's wrapper) and changes nothing."""
        if UNREADABLE in state:   # pythonfmu's own wrapper: bytes that were no state
            self._error(f"fmi2SetFMUstate: {state[UNREADABLE]}; nothing was changed")
            return
        try:
            inputs = [float(x) for x in state["inputs"]]
            time = float(state["time"])
            soc0, capacity, observer, is_cell, start, use_start = state["params"]
            start = float(start)
            if not isinstance(use_start, bool):
                raise ValueError(f"use_cell_temperature_start {use_start!r}: expected true or "
                                 "false")
            if len(inputs) != 3 or not math.isfinite(time):
                raise ValueError(f"inputs {state['inputs']!r}, time {time!r}: expected three "
                                 "inputs and a finite time")
            cosim = self._restored_cosim(state["cosim"], float(soc0), float(capacity))
        except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:
            self._error(f"fmi2SetFMUstate: the FMU state is not one of this FMU's "
                        f"({state_fault(exc)}); nothing was changed")
            return
        self._cosim = cosim
        self.current, self.voltage_measured, self.temperature = inputs
        self._time = time
        self.soc0, self.capacity, self.observer, self.temperature_is_cell = (
            soc0, capacity, observer, is_cell)
        self.cell_temperature_start, self.use_cell_temperature_start = start, use_start
        # as the native FMU: step mode where the state is initialised, else instantiated
        self._terminated = self._in_initialization = False

    def _restored_cosim(self, cosim_state: dict | None, soc0: float,
                        capacity: float) -> CellCosim | None:
        """The engine of an FMU state (None: not initialised): this instance's own with the
        state restored, or a new one; ValueError (nothing changed) where it cannot be."""
        if cosim_state is None:
            return None
        cosim = self._cosim or CellCosim(self._model, Parameters(soc0, capacity))
        cosim.set_state(cosim_state)
        return cosim

    @staticmethod
    def _fmu_state_to_bytes(state: dict) -> bytes:
        return json.dumps(state, allow_nan=True).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(data: bytes) -> dict:
        """The state of serialised bytes, never raising (pythonfmu's own wrapper, the win64
        binary's, turns an exception here into fmi2Fatal and frees the instance): bytes that
        are no state of this FMU read as {UNREADABLE: why}, which fmi2SetFMUstate refuses."""
        try:
            return _state_document(data)
        except ValueError as exc:
            return {UNREADABLE: f"the state read back by fmi2DeSerializeFMUstate: {exc}"}

    @staticmethod
    def _read_fmu_state_bytes(data: bytes) -> dict:
        """The state of serialised bytes, CallError where they are not this FMU's JSON object:
        LMNCell's wrapper calls it, so that fmi2DeSerializeFMUstate itself returns fmi2Error
        with the message."""
        try:
            return _state_document(data)
        except ValueError as exc:
            raise CallError(f"fmi2DeSerializeFMUstate: {exc}; nothing was changed") from None


def _state_document(data: bytes) -> dict:
    """The JSON object of serialised state bytes; ValueError naming what is wrong."""
    try:
        doc = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"the {len(data)} bytes are not a state of this FMU ({exc.reason} "
                         f"at byte {exc.start}; expected fmi2SerializeFMUstate's JSON)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"the {len(data)} bytes are not a state of this FMU ({exc.msg} at "
                         f"byte {exc.pos}; expected fmi2SerializeFMUstate's JSON)") from None
    except RecursionError:
        raise ValueError(f"the {len(data)} bytes are not a state of this FMU (JSON nested too "
                         "deeply; expected fmi2SerializeFMUstate's JSON)") from None
    if not isinstance(doc, dict):
        raise ValueError(f"the {len(data)} bytes are not a state of this FMU (JSON "
                         f"{type(doc).__name__}, expected an object)")
    return doc


__all__ = ["LmnCellSlave", "ModelFileError", "keep_module_dict"]
