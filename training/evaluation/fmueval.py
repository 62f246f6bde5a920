"""`lmncell evaluate CELL.fmu`: an LMNCell FMU (pythonfmu or native) driven by fmpy through
measured records and scored like a model file: free run from each segment's start SoC, RMSE
over the whole record, the 20–80 % SoC window and each end. This is how a user who was handed
only the FMU (a supplier's, say) checks it against their own cycler data."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
import uuid
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.config import ConfigError
from lmncell.data.dataset import Segment, record_parts
from lmncell.data.records import Record
from lmncell.evaluation.evaluate import (
    Trace,
    ambient_of,
    check_ambient_known,
    drives_ambient,
    model_ocv,
    print_rows,
    read_records,
    record_notes,
    temperature_input,
    temperature_words,
    write_traces,
)
from lmncell.evaluation.metrics import record_metrics
from lmncell.progress import Progress
from lmncell.progress import print_progress as _print
from lmncell.report.jsontext import json_text
from lmncell.runtime.model import LmnModel, model_from_dict
from lmncell.runtime.thermal import DEFAULT_TEMPERATURE_C

# the variables evaluate needs; every LMNCell FMU has them
REQUIRED_VARIABLES = ("current", "temperature", "voltage", "soc", "out_of_range", "soc0",
                      "capacity", "temperature_is_cell")


@dataclass(frozen=True)
class FmuInfo:
    """What evaluate reads from an FMU's modelDescription.xml."""

    path: Path
    description: Any       # fmpy's ModelDescription
    step_s: float          # DefaultExperiment stepSize: the model's sample time (s)
    capacity_ah: float     # start value of the parameter capacity (Ah)
    current_delay_s: float  # the shipped model file's current delay δ (s; 0 without one)


def _is_model_file(path: Path) -> bool:
    """Whether a file is an LMNCell model file (JSON of format 'lmncell-model')."""
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return head.lstrip().startswith(b"{") and b'"lmncell-model"' in head


def read_fmu_info(fmu: str | Path) -> FmuInfo:
    """The FMU's sample time and capacity; ConfigError naming the file where it cannot be read
    or is not an LMNCell FMU."""
    from fmpy import read_model_description

    path = Path(fmu)
    if not path.is_file():
        raise ConfigError(f"{path}: no such FMU file")
    try:
        md = read_model_description(str(path))
    except Exception as exc:          # fmpy raises several kinds for a broken archive
        hint = (": it is a model file; build an FMU of it with `lmncell build-fmu "
                f"{path} --out CELL.fmu`" if _is_model_file(path) else "")
        raise ConfigError(f"{path}: not a readable FMU ({type(exc).__name__}: {exc}){hint}"
                          ) from None
    names = {v.name: v for v in md.modelVariables}
    missing = [n for n in REQUIRED_VARIABLES if n not in names]
    if missing:
        raise ConfigError(f"{path}: not an LMNCell FMU: it has no variable(s) "
                          f"{', '.join(missing)}")
    step = md.defaultExperiment.stepSize if md.defaultExperiment is not None else None
    if step is None or not float(step) > 0:
        raise ConfigError(f"{path}: its modelDescription.xml has no DefaultExperiment "
                          "stepSize > 0 (an LMNCell FMU gives its model's sample time there)")
    try:
        capacity = float(names["capacity"].start)
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: its parameter 'capacity' has no numeric start value "
                          f"({names['capacity'].start!r})") from None
    return FmuInfo(path, md, float(step), capacity, shipped_current_delay(path, float(step)))


def shipped_current_delay(path: Path, step_s: float) -> float:
    """current_delay_s of the model file an LMNCell FMU ships (resources/model.json), 0 where
    there is none or it is not a delay 0 ≤ δ < Ts: the points at which evaluate splits the
    communication steps, not the model itself, which the FMU runs."""
    try:
        delay = float(shipped_model_doc(path).get("current_delay_s", 0.0))
    except (ValueError, TypeError):
        return 0.0
    return delay if 0.0 <= delay < step_s else 0.0


def shipped_model_doc(path: str | Path) -> dict:
    """The model file an LMNCell FMU ships (resources/model.json) as parsed JSON, {} where the
    FMU has none or it is not a JSON object."""
    try:
        with zipfile.ZipFile(path) as z:
            doc = json.loads(z.read("resources/model.json"))
    except (KeyError, ValueError, OSError, zipfile.BadZipFile):
        return {}
    return doc if isinstance(doc, dict) else {}


def shipped_ocv(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The OCV (model_ocv) of the model file an LMNCell FMU ships, to check a full start
    against (read_records); None where the FMU ships none that the model loader reads."""
    try:
        return model_ocv(model_from_dict(shipped_model_doc(path),
                                         f"{path}: resources/model.json"))
    except ValueError:      # ModelFileError: no model file, or one this LMNCell refuses
        return None


def shipped_model(path: str | Path) -> LmnModel:
    """The model an LMNCell FMU ships (resources/model.json), checked as a model file is;
    ConfigError naming the FMU where it is none or carries no model."""
    read_fmu_info(path)
    doc = shipped_model_doc(path)
    if not doc:
        raise ConfigError(f"{path}: carries no readable resources/model.json (every LMNCell "
                          "FMU ships its model there)")
    return model_from_dict(doc, f"{path}: resources/model.json")


def model_or_shipped(path: str | Path) -> LmnModel:
    """A model file, or the model an LMNCell FMU (*.fmu) ships (shipped_model)."""
    from lmncell.runtime.model import load_model

    return shipped_model(path) if Path(path).suffix.lower() == ".fmu" else load_model(path)


@contextmanager
def model_file_of(path: str | Path) -> Iterator[Path]:
    """The model file itself, or for an LMNCell FMU (*.fmu) a temporary copy of the model file
    it ships (resources/model.json, checked by shipped_model), removed afterwards."""
    path = Path(path)
    if path.suffix.lower() != ".fmu":
        yield path
        return
    shipped_model(path)
    with tempfile.TemporaryDirectory(prefix="lmncell-shipped-") as tmp, \
            zipfile.ZipFile(path) as z:
        out = Path(tmp) / f"{path.stem}.json"
        out.write_bytes(z.read("resources/model.json"))
        yield out


def communication_points(sample_times_s: np.ndarray, ts: float, n: int,
                         delay_s: float = 0.0) -> np.ndarray:
    """The times (s from the part's first sample) at which evaluate_fmu ends a communication
    step: every sample of the record, every model step end k·Ts (k = 1…n) and, with a current
    delay δ, every k·Ts − δ where the FMU's delayed current window closes; once each."""
    grid = ts * np.arange(1, n + 1)
    t = sample_times_s[(sample_times_s > 0.0) & (sample_times_s < grid[-1])]
    extra = grid - delay_s if delay_s else np.empty(0)
    points = np.union1d(np.union1d(t, extra[extra > 0.0]), grid)
    # points within rounding of a model step end are that step end
    points = np.union1d(points[~at_step_ends(points, ts)], grid)
    keep = np.concatenate([[True], np.diff(points) > 1e-9 * ts])
    return points[keep]


def at_step_ends(points: np.ndarray, ts: float) -> np.ndarray:
    """Which points (s) lie on a model step end k·Ts, within rounding."""
    return np.abs(points - ts * np.round(points / ts)) < 1e-9 * ts


def held_inputs(part: Record, signals: Sequence[np.ndarray], points: np.ndarray,
                start_s: float = 0.0) -> list[np.ndarray]:
    """Each signal's value to hold over the communication steps that start at start_s and end
    at points (s from the part's first sample): the mean of the two samples around the step,
    which resampling holds over each sample interval (lmncell.data.resample), so that the FMU's
    means over its model steps are the pipeline's."""
    t = part.time_s - part.time_s[0]
    mids = 0.5 * (np.concatenate([[start_s], points[:-1]]) + points)
    j = np.clip(np.searchsorted(t, mids) - 1, 0, len(t) - 2)
    return [0.5 * (np.asarray(x, dtype=float)[j] + np.asarray(x, dtype=float)[j + 1])
            for x in signals]


@dataclass
class FmuRun:
    """The FMU's outputs at the end of each model step it was driven through; driven through
    the samples, also its voltage at every communication point (s from the part's start)."""

    voltage_v: np.ndarray
    soc: np.ndarray
    soc_std: np.ndarray
    out_of_range: np.ndarray
    points_s: np.ndarray | None = None
    point_voltage_v: np.ndarray | None = None
    first_warning: str = ""     # the FMU's first out-of-range warning (first_warning)


# fmpy's native logger proxy (which formats the printf-style arguments that ctypes cannot
# pass) keeps ONE Python logger for the whole process, for every instance whose callbacks it
# wraps, fmpy's own default callbacks included. So the logger registered here lives as long
# as the process: it keeps the messages of the instances named in _FMU_LOGS (fmu_log) and
# prints the others' as fmpy's default logger does.
_FMU_LOGS: dict[str, list[str]] = {}
_LOGGER: list[Any] = []        # [callbacks] once registered


def _keep_or_print(env, name, status, category, message) -> None:
    """The process's FMU logger (see _FMU_LOGS)."""
    from fmpy.fmi1 import printLogMessage

    log = _FMU_LOGS.get((name or b"").decode("utf-8", "replace"))
    if log is None:
        printLogMessage(env, name, status, category, message)
        return
    text = (message or b"").decode("utf-8", "replace")
    # LMNCell's pythonfmu wrapper logs a call error as its message; another exception (a fault
    # of the slave) as "[doStep] PyObject_CallMethod\nTypeError('…')"
    inner = re.search(r"\w+Error\((['\"])(.*)\1\)\s*$", text, re.DOTALL)
    log.append(f"{inner.group(2) if inner else text} "
               f"[{(category or b'').decode('utf-8', 'replace')}, status {status}]")


def _process_callbacks() -> Any:
    """The FMI 2.0 callbacks with the process's logger, registered with fmpy's proxy once."""
    if not _LOGGER:
        import ctypes

        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )
        from fmpy.logging import addLoggerProxy

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(_keep_or_print)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)   # fmpy's own
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(ctypes.byref(callbacks))
        _LOGGER.append(callbacks)
    return _LOGGER[0]


@contextmanager
def fmu_log(prefix: str) -> Iterator[tuple[str, Any, list[str]]]:
    """A unique instance name, the callbacks to instantiate it with, and the list in which its
    messages are kept while the context lasts."""
    name = f"{prefix}-{uuid.uuid4().hex[:12]}"
    log: list[str] = []
    callbacks = _process_callbacks()
    _FMU_LOGS[name] = log
    try:
        yield name, callbacks, log
    finally:
        _FMU_LOGS.pop(name, None)


def first_warning(log: list[str], instance_name: str) -> str:
    """The first message an FMU logged with the status fmi2Warning (fmu_log's entries; with
    logging on, both LMNCell FMUs warn so at the start of each out-of-range excursion, naming
    what left the trained region), without the instance's name before it and the category
    after it; '' where it logged none."""
    for entry in log:
        text, _, tail = entry.rpartition(" [")
        if tail.endswith("status 1]"):
            return text.removeprefix(f"{instance_name}: ")
    return ""


class _Slave:
    """One instance of the FMU in fmpy's FMU2Slave, initialised at a start SoC (with an
    observer: its start estimate)."""

    def __init__(self, info: FmuInfo, unzipped: str, soc0: float, cell: bool,
                 inputs: Sequence[float], observer: int = 0) -> None:
        from fmpy.fmi2 import FMU2Slave

        md = info.description
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        # the instance's log (fmu_log) is released by free()
        self._log = fmu_log("lmncell-evaluate")
        self.name, callbacks, self.log = self._log.__enter__()
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                               modelIdentifier=md.coSimulation.modelIdentifier,
                               instanceName=self.name)
        self.inputs = [self.vr[n] for n in ("current", "temperature", "voltage_measured")
                       ][:len(inputs)]
        self.slave.instantiate(callbacks=callbacks, loggingOn=True)   # warnings kept in log
        self.slave.setupExperiment(startTime=0.0)
        self.slave.enterInitializationMode()
        self.slave.setReal([self.vr["soc0"]], [float(soc0)])
        self.slave.setBoolean([self.vr["temperature_is_cell"]], [cell])
        if observer:
            self.slave.setInteger([self.vr["observer"]], [int(observer)])
        self.set_inputs(inputs)
        self.slave.exitInitializationMode()
        self.out = [self.vr["voltage"], self.vr["soc"], self.vr["soc_std"]]

    def set_inputs(self, values: Sequence[float]) -> None:
        """current (A), temperature (°C) and, for an observer, voltage_measured (V)."""
        self.slave.setReal(self.inputs, [float(v) for v in values])

    def voltage(self) -> float:
        """The voltage output alone (V): all a sample between model-step ends needs."""
        return self.slave.getReal(self.out[:1])[0]

    def outputs(self) -> tuple[float, float, float, bool]:
        voltage, soc, std = self.slave.getReal(self.out)
        return voltage, soc, std, bool(self.slave.getBoolean([self.vr["out_of_range"]])[0])

    def free(self) -> None:
        try:
            self.slave.terminate()
            self.slave.freeInstance()
        finally:
            self._log.__exit__(None, None, None)


def ambient_at_samples(part: Record, seg: Segment) -> np.ndarray | None:
    """The ambient temperature at each of the part's own samples (°C), as ambient_of gives it
    at the model's steps: the chamber's beside the cell's as the record logs it where the
    segment follows it (Segment.ambient_trace_c), else its set point; without a cell
    temperature, the record's own (the chamber's; None where it has none). DataError where
    it is not known (check_ambient_known)."""
    check_ambient_known(seg)
    if seg.ambient_trace_c is not None and part.ambient_c is not None:
        return part.ambient_c
    if seg.ambient_c is not None:
        return np.full(len(part), float(seg.ambient_c))
    return part.temperature_or_chamber()


def drive_at_samples(info: FmuInfo, unzipped: str, part: Record, seg: Segment,
                     ambient: bool, observer: int = 0, start_step: int = 0,
                     soc0: float | None = None) -> FmuRun:
    """The FMU's outputs at the end of each model step of the segment from start_step on: the
    FMU stepped through the record's own samples (and every model step end), each step holding
    the record's mean current and temperature over it, from soc0 (default the segment's start
    SoC). With ambient, or without a measured cell temperature (drives_ambient), the
    temperature is the segment's ambient and temperature_is_cell false (the FMU's thermal
    model), else the measured cell temperature and temperature_is_cell true.
    With an observer (1 EKF, 2 fuzzy, 3 IMM) the FMU also gets the measured voltage and soc0 is
    its start estimate. The FMU applies its model's current delay itself, so its voltage is the
    pipeline's (evaluate MODEL.json)."""
    n, ts = len(seg), info.step_s
    ambient = drives_ambient(seg, ambient)
    temperature = ambient_at_samples(part, seg) if ambient else part.temperature_or_chamber()
    if temperature is None:
        temperature = np.full(len(part), DEFAULT_TEMPERATURE_C)
    start_s = start_step * ts
    points = communication_points(part.time_s - part.time_s[0], ts, n, info.current_delay_s)
    points = points[points > start_s * (1.0 + 1e-12)]
    signals = [part.current_a, temperature] + ([part.voltage_v] if observer else [])
    inputs = np.column_stack(held_inputs(part, signals, points, start_s))
    ends = at_step_ends(points, ts)
    out = np.empty((n - start_step, 4))
    every = np.empty(points.size)
    step_of = np.cumsum(ends) - 1                     # the model step that point j ends

    def keep(slave: _Slave, j: int) -> None:
        if ends[j]:
            out[step_of[j]] = slave.outputs()
            every[j] = out[step_of[j], 0]
        else:
            every[j] = slave.voltage()

    warned = _step_through(info, unzipped, seg, seg.soc0 if soc0 is None else soc0,
                           not ambient, observer, inputs.tolist(), points.tolist(), keep,
                           start_s)
    return FmuRun(out[:, 0], out[:, 1], out[:, 2], out[:, 3].astype(bool), points, every,
                  warned)


def _step_through(info: FmuInfo, unzipped: str, seg: Segment, soc0: float, cell: bool,
                  observer: int, inputs: list[list[float]], points: list[float],
                  after_step: Callable[[_Slave, int], None], start_s: float = 0.0) -> str:
    """One instance of the FMU (_Slave) stepped from start_s (s) to each point in turn, the
    step to points[j] holding inputs[j], after_step(slave, j) after it; returns the FMU's first
    out-of-range warning (first_warning); a failed call is a ConfigError naming the record and
    the time."""
    slave, t = None, start_s
    try:
        slave = _Slave(info, unzipped, soc0, cell, inputs[0], observer)
        for j, (point, values) in enumerate(zip(points, inputs, strict=True)):
            slave.set_inputs(values)
            slave.slave.doStep(currentCommunicationPoint=t - start_s,
                               communicationStepSize=point - t)
            t = point
            after_step(slave, j)
        return first_warning(slave.log, slave.name)
    except Exception as exc:          # fmpy raises where a call returns an error status
        raise _failed(info, seg, t, exc, slave) from None
    finally:
        if slave is not None:
            slave.free()


def _failed(info: FmuInfo, seg: Segment, t: float, exc: Exception, slave: _Slave | None
            ) -> ConfigError:
    """The error of an FMU call that failed at time t of a segment, with the FMU's last
    message where it logged one."""
    said = f" ({slave.log[-1]})" if slave is not None and slave.log else ""
    return ConfigError(f"{info.path}: the FMU failed on {seg.name} at t = {t:g} s: {exc}{said}")


def sample_metrics(part: Record, seg: Segment, run: FmuRun, ts: float) -> dict | None:
    """The FMU's figures against the record's own samples (its voltage output at each sample
    time, between model steps the step in progress; SoC windows by the reference SoC at that
    time), where the record is sampled faster than Ts; None otherwise (then every sample is a
    model step end and the figures are the model steps')."""
    if run.points_s is None or run.point_voltage_v is None:
        return None
    t = part.time_s - part.time_s[0]
    if t.size < 2 or float(np.median(np.diff(t))) >= ts * (1.0 - 1e-6):
        return None
    inside = (t > 0.0) & (t <= run.points_s[-1] * (1.0 + 1e-12))
    at = np.clip(np.searchsorted(run.points_s, t[inside] - 1e-9 * ts), 0,
                 run.points_s.size - 1)
    soc = np.interp(t[inside], ts * np.arange(1, len(seg) + 1), seg.soc_ref)
    return record_metrics(part.voltage_v[inside], run.point_voltage_v[at], soc)


def drive_at_model_steps(info: FmuInfo, unzipped: str, seg: Segment, ambient: bool
                         ) -> FmuRun:
    """drive_at_samples' results with the FMU stepped in steps of Ts, each holding the
    segment's mean current and temperature over it (as fmucheck.run_fmu_on_segment drives it
    through fmpy.simulate_fmu): what a host that steps at Ts with averaged inputs gives; with a
    current delay the FMU then has only (δ·i(k−1) + (Ts − δ)·i(k))/Ts, not what the current
    did within the step."""
    n, ts = len(seg), info.step_s
    ambient = drives_ambient(seg, ambient)
    temperature = ambient_of(seg) if ambient else seg.temperatures()
    inputs = np.column_stack([seg.current_a, temperature]).tolist()
    out = np.empty((n, 4))

    def keep(slave: _Slave, k: int) -> None:
        out[k] = slave.outputs()

    warned = _step_through(info, unzipped, seg, seg.soc0, not ambient, 0, inputs,
                           (ts * np.arange(1, n + 1)).tolist(), keep)
    return FmuRun(out[:, 0], out[:, 1], out[:, 2], out[:, 3].astype(bool),
                  first_warning=warned)


def evaluate_fmu(fmu: str | Path, paths: Sequence[str | Path],
                 soc0: float | Sequence[float] | None = None, ambient: bool = False,
                 read_options: Mapping[str, Any] | None = None,
                 through_hidden_pauses: bool = False, at_model_steps: bool = False,
                 progress: Progress = _print) -> tuple[list[Trace], list[dict]]:
    """Each record's segments through the FMU: traces and one row of metrics per segment (as
    evaluate_model's, the FMU under the name "fmu", plus how many model steps it flagged
    out_of_range; driven through the samples of a record sampled faster than Ts, also
    "fmu_samples", its figures against every sample: sample_metrics). The FMU is stepped
    through the record's own samples (drive_at_samples), or with at_model_steps in steps of Ts
    with the mean inputs (drive_at_model_steps). The reference SoC counts the record's current
    with the FMU's capacity. soc0, ambient and through_hidden_pauses as in evaluate_model."""
    from fmpy import extract

    info = read_fmu_info(fmu)
    unzipped = extract(str(info.path))
    traces, rows = [], []
    how = "in steps of Ts with mean inputs" if at_model_steps else "through the samples"
    try:
        for _, rec, rec_soc0 in read_records(paths, soc0, read_options, through_hidden_pauses,
                                             shipped_ocv(info.path)):
            notes = record_notes(rec, info.capacity_ah, info.step_s)
            for part, seg in record_parts(rec, info.step_s, rec_soc0, info.capacity_ah):
                progress(f"driving {info.path.name} {how} of {seg.name}: {len(seg)} model "
                         f"steps of {info.step_s:g} s")
                run = (drive_at_model_steps(info, unzipped, seg, ambient) if at_model_steps
                       else drive_at_samples(info, unzipped, part, seg, ambient))
                traces.append(Trace(seg, {"fmu": run.voltage_v}, run.soc,
                                    np.zeros((len(seg), 0))))
                raw = sample_metrics(part, seg, run, info.step_s)   # None at model steps
                rows.append({"record": seg.name,
                             "temperature_input": temperature_input(seg, ambient),
                             "fmu": record_metrics(seg.voltage_v, run.voltage_v, seg.soc_ref),
                             **({"fmu_samples": raw} if raw else {}),
                             "out_of_range_steps": int(run.out_of_range.sum()),
                             "out_of_range_first": run.first_warning or None,
                             "steps": len(seg),
                             "driven": "model_steps" if at_model_steps else "samples"}
                            | notes)
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return traces, rows


def evaluate_fmu_files(fmu: str | Path, paths: Sequence[str | Path],
                       soc0: float | Sequence[float] | None = None,
                       plot_dir: str | Path | None = None, trace: str | Path | None = None,
                       as_json: bool = False, progress: Progress = _print,
                       ambient: bool = False, read_options: Mapping[str, Any] | None = None,
                       through_hidden_pauses: bool = False,
                       at_model_steps: bool = False) -> list[dict]:
    """`lmncell evaluate CELL.fmu`: figures per record for the FMU."""
    traces, rows = evaluate_fmu(fmu, paths, soc0, ambient, read_options, through_hidden_pauses,
                                at_model_steps, progress)
    if trace is not None:
        write_traces(traces, trace, "fmu")
    if plot_dir is not None:
        _plot(Path(fmu), traces, Path(plot_dir), ambient, at_model_steps, progress)
    if as_json:
        print(json_text(rows))
        return rows
    print_rows(rows, progress)
    for r in rows:
        if r["out_of_range_steps"]:
            first = r.get("out_of_range_first")
            progress(f"{r['record'][:48]:48s} the FMU flagged out_of_range in "
                     f"{r['out_of_range_steps']} of {r['steps']} steps (outside its training "
                     "data: current, SoC, temperature or its own voltage)"
                     + (f"; its first warning: {first}" if first else ""))
    return rows


def _plot(fmu: Path, traces: list[Trace], out: Path, ambient: bool, at_model_steps: bool,
          progress: Progress) -> None:
    """One fit figure per segment, captioned with the FMU, how it was stepped and the
    temperature it was given."""
    from lmncell.report import plots

    out.mkdir(parents=True, exist_ok=True)
    how = ("in steps of Ts with the mean current over each" if at_model_steps
           else "through the record's own samples")
    files = [plots.fit_figure(t, out / f"fmu_{plots.safe_name(t.segment.name)}.png",
                              title=f"{t.segment.name}: {fmu.name} driven by fmpy {how}, "
                              f"with {temperature_words(t.segment, ambient)}; free run from "
                              f"SoC {t.segment.soc0:.3g}, voltage compared with the measured "
                              "mean over each model step")
             for t in traces]
    progress(f"wrote {len(files)} figure(s) to {out}: " + ", ".join(f.name for f in files))


OBSERVER_CODES = {"ekf": 1, "fuzzy": 2, "imm": 3}   # the FMUs' parameter `observer`


def evaluate_fmu_observer_files(fmu: str | Path, paths: Sequence[str | Path], kind: str,
                                soc0: float | Sequence[float] | None, soc0_est: float,
                                start_at: float | None, plot_dir: str | Path | None = None,
                                as_json: bool = False,
                                read_options: Mapping[str, Any] | None = None,
                                through_hidden_pauses: bool = False,
                                progress: Progress = _print) -> list[dict]:
    """`lmncell evaluate CELL.fmu --observer KIND`: the FMU's own observer (its parameter
    `observer`, given the measured voltage) and its coulomb counting, each started at soc0_est
    where the reference SoC first reaches start_at (or at the record's start), driven through
    the record's samples with the measured cell temperature; the figures of
    `lmncell evaluate MODEL --observer` (lmncell.evaluation.observe)."""
    from fmpy import extract
    from lmncell.evaluation.observe import (
        ObserverRun,
        observer_figure,
        observer_result,
        observer_segment,
        print_observer_results,
        start_index,
    )

    info = read_fmu_info(fmu)
    unzipped = extract(str(info.path))
    results = []
    try:
        for p, rec, rec_soc0 in read_records(paths, soc0, read_options, through_hidden_pauses,
                                             shipped_ocv(info.path)):
            parts = record_parts(rec, info.step_s, rec_soc0, info.capacity_ah)
            seg = observer_segment([s for _, s in parts], start_at)
            part = next(pt for pt, s in parts if s is seg)
            k0 = start_index(seg, start_at) if start_at is not None else 0
            runs = []
            for name, code in ((kind, OBSERVER_CODES[kind]), ("coulomb", 0)):
                progress(f"driving {info.path.name} through the samples of {seg.name} with "
                         f"observer {code} ({name}) from SoC {soc0_est:g}")
                run = drive_at_samples(info, unzipped, part, seg, False, code, k0, soc0_est)
                runs.append(ObserverRun(name, seg.time_s[k0:], seg.soc_ref[k0:], run.soc,
                                        run.soc_std, None))
            results.append(observer_result(seg.name, runs, soc0_est))
            if plot_dir is not None:
                Path(plot_dir).mkdir(parents=True, exist_ok=True)
                observer_figure(runs, Path(plot_dir) / f"fmu_soc_{kind}_{p.stem}.png")
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    print_observer_results(results, kind, as_json)
    return results
