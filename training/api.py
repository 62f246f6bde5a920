"""The Python API of LMNCell: read data, train a model, simulate and evaluate it, build an FMU.

    import lmncell
    rec = lmncell.read_record("cell.csv", columns={"time": "t", "current": "I", "voltage": "U"})
    model = lmncell.train(["cycle1.mat", "cycle2.mat"], "cell.json", capacity_ah=2.85)
    sim = lmncell.simulate(model, current_a, soc0=1.0)          # 25 °C ambient: sim.voltage_v
    rows = lmncell.evaluate(model, ["cycle3.mat"])              # whole record and 20–80 % SoC
    lmncell.build_fmu("cell.json", "cell.fmu")                  # native=True: C, no Python

Units are SI (s, A, V, Ah, °C); current > 0 charges the cell; SoC is a fraction 0…1.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.data.readers import read_record
from lmncell.data.records import DataError, Record, is_cell_temperature
from lmncell.evaluation.evaluate import warn_outside_training
from lmncell.fmu.interface import NativeBuildError
from lmncell.progress import Progress, print_progress
from lmncell.runtime.cosim import held_delayed_currents
from lmncell.runtime.model import LmnModel, load_model
from lmncell.runtime.step import SimResult, simulate_ambient
from lmncell.runtime.step import simulate as _simulate_runtime
from lmncell.runtime.thermal import CELL_TEMPERATURE_RANGE_C, DEFAULT_TEMPERATURE_C

__all__ = ["LmnModel", "Record", "SimResult", "build_fmu", "evaluate", "load_model",
           "read_record", "simulate", "sweep", "train"]


def train(paths: str | Path | Sequence[str | Path], out: str | Path,
          capacity_ah: float | None = None, soc0: float | Sequence[float] | None = None, *,
          ocv_tests: str | Path | Sequence[str | Path] | None = None,
          baselines: bool = False, config: str | Path | None = None,
          read_options: Mapping[str, Any] | None = None, progress: Progress = print_progress,
          **settings: Any) -> LmnModel:
    """Identify an LMN from cycler files and write it to `out` (model file, JSON).

    capacity_ah: the cell's capacity (default: the charge of the full discharges found);
    soc0: every record's start SoC, or one per file in order (default: 1.0 for records that
    start rested at full charge); ocv_tests: slow OCV test files that fix the OCV (one file,
    or a list of one or two);
    settings: training settings of lmncell.config.TrainConfig (e.g. max_local_models=4,
    partition=["soc", "current"]);
    read_options: a column mapping and reader options for your own CSV (see read_record).
    Returns the model (also written to `out`)."""
    if isinstance(ocv_tests, (str, Path)):
        ocv_tests = [ocv_tests]              # one round-trip test file, given on its own
    if ocv_tests:
        settings["ocv_tests"] = [str(p) for p in ocv_tests]
    from lmncell.identification.train import train_files

    model, _ = train_files(_path_list("train", paths), out, capacity_ah, soc0, baselines=baselines,
                           config=config, progress=progress, read_options=read_options,
                           **settings)
    return model


def _one_or_many(values: Any) -> list:
    """A sweep axis as a list: one value given on its own (a cycle name or file, a number,
    None) is a list of one, so that "wltc" is not read letter by letter."""
    if values is None or isinstance(values, (str, os.PathLike, int, float)):
        return [values]
    return list(values)


def _path_list(caller: str, paths: Any) -> list[str | Path]:
    """The data files as a list: one path (str or path-like) given on its own is a list of
    one (iterating over a string would read '/' as a file); anything else must be a sequence
    of paths, or DataError naming the caller's argument."""
    if isinstance(paths, (str, os.PathLike)):
        return [paths if isinstance(paths, str) else Path(paths)]
    try:
        out = list(paths)
    except TypeError:
        raise DataError(f"{caller}: paths is {paths!r:.60}; expected a data file's path or a "
                        "list of them") from None
    bad = [p for p in out if not isinstance(p, (str, os.PathLike))]
    if bad:
        raise DataError(f"{caller}: paths holds {bad[0]!r:.60}; expected data files' paths "
                        "(str or pathlib.Path)")
    if not out:
        raise DataError(f"{caller}: no data files given; expected a data file's path or a list "
                        "of them")
    return out


def _model(caller: str, model: Any) -> LmnModel:
    """The model itself, or the one in the model file at that path; DataError naming the
    caller's argument for anything else (load_model's TypeError said only 'expected str')."""
    if isinstance(model, LmnModel):
        return model
    if not isinstance(model, (str, os.PathLike)):
        raise DataError(f"{caller}: model is {model!r:.60}; expected an LmnModel or a model "
                        "file's path")
    return load_model(Path(model))


def simulate(model: LmnModel | str | Path, current_a: np.ndarray,
             temperature_c: np.ndarray | float | None = None, soc0: float = 1.0,
             capacity_ah: float | None = None, *,
             ambient_c: np.ndarray | float | None = None,
             cell_temperature_start_c: float | None = None) -> SimResult:
    """Free-run simulation of a current profile sampled at the model's sample time
    (model.sample_time_s; each value held over one step, > 0 charges).

    temperature_c: cell temperature per step or one value (°C), as the FMU with
    temperature_is_cell = true takes it; or instead ambient_c: the ambient temperature per
    step or one value (°C), from which the model's thermal model computes the cell temperature
    (the FMU's default; returned as `cell_temperature_c`; a model without a thermal model takes
    the ambient as the cell temperature). Neither given: an ambient of 25 °C, as the FMU with
    its start values. cell_temperature_start_c: with the ambient, the cell's temperature before
    the first step (°C; the FMU's cell_temperature_start with use_cell_temperature_start =
    true), for a cell warmer or colder than the air it starts in; None: rested at the first
    ambient. soc0: the SoC before the first step. Returns arrays
    `voltage_v` (V, the mean over each step) and `soc` (after each step), plus the network
    output `y` and the local models' `validity`. A model
    with a current delay δ (model.current_delay_s) takes each step's current δ late, as its FMU
    stepped at Ts with the same profile does: (δ·i(k−1) + (Ts − δ)·i(k))/Ts, i(−1) = i(0).
    Where the current, temperature or SoC leaves what the model was trained on, a UserWarning
    says so (the model extrapolates there; below SoC 0 the cell is past empty)."""
    model = _model("simulate", model)
    current = _profile("current_a", current_a, "A")
    if not 0.0 <= float(soc0) <= 1.0:
        raise DataError(f"simulate: soc0 = {float(soc0)!r}; expected a fraction within 0…1")
    if capacity_ah is not None:
        capacity_ah = _positive("capacity_ah", capacity_ah, "Ah, or None for the model's")
    if temperature_c is not None and ambient_c is not None:
        raise DataError("simulate: temperature_c (the cell's) and ambient_c given; expected one "
                        "of them")
    if temperature_c is not None and cell_temperature_start_c is not None:
        raise DataError("simulate: cell_temperature_start_c given with temperature_c (the "
                        "cell's own from the first step on); expected it with ambient_c")
    taken = np.array(held_delayed_currents(current.tolist(), model.sample_time_s,
                                           model.current_delay_s))
    if temperature_c is None and ambient_c is None:
        ambient_c = DEFAULT_TEMPERATURE_C             # the FMU's start values
    if ambient_c is not None:
        ambient = _temperature_profile(ambient_c, current.size, "ambient_c")
        start = _cell_start(model, cell_temperature_start_c)
        sim, temp = simulate_ambient(model, taken, ambient, float(soc0), capacity_ah,
                                     cell_temperature_start_c=start)
    else:
        temp = _temperature_profile(temperature_c, current.size)
        sim = _simulate_runtime(model, taken, temp, float(soc0), capacity_ah)
    warn_outside_training(model, "simulate", current, temp, sim.soc)
    return sim


def _cell_start(model: LmnModel, start_c: Any) -> float | None:
    """simulate's cell_temperature_start_c as a float (°C), None where not given; DataError
    where the model has no thermal model or it is no cell temperature."""
    if start_c is None:
        return None
    if model.thermal is None:
        raise DataError("simulate: cell_temperature_start_c given, but this model has no "
                        "thermal model: it takes ambient_c as the cell temperature")
    try:
        start = float(start_c)
    except (TypeError, ValueError):
        start = math.nan
    if not is_cell_temperature(start):
        raise DataError(f"simulate: cell_temperature_start_c = {start_c!r:.60}; expected a cell "
                        "temperature within {:g}…{:g} °C".format(*CELL_TEMPERATURE_RANGE_C))
    return start


def _positive(name: str, value: Any, unit: str) -> float:
    """value as a finite float > 0, or DataError naming `name` (unit: what it is in)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise DataError(f"simulate: {name} = {value!r:.60}; expected a finite number > 0 ({unit})")
    return number


def _profile(name: str, values: Any, unit: str) -> np.ndarray:
    """A non-empty 1-D array of finite floats (one number: an array of one), or DataError
    naming `name` (complex numbers too: numpy would drop their imaginary parts)."""
    if np.iscomplexobj(values):
        raise DataError(f"simulate: {name} holds complex numbers; expected real numbers ({unit})")
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError):
        raise DataError(f"simulate: {name} is {values!r:.60}; expected numbers ({unit})") from None
    if arr.ndim != 1 or arr.size == 0:
        raise DataError(f"simulate: {name} has shape {arr.shape}; expected a non-empty 1-D "
                        f"array ({unit})")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise DataError(f"simulate: {name} has {int(bad.sum())} NaN or infinite value(s), first "
                        f"at index {first}; expected finite numbers ({unit})")
    return arr


def _temperature_profile(temperature_c: Any, steps: int,
                         name: str = "temperature_c") -> np.ndarray:
    """One temperature or one per step (°C) as an array of `steps`, within
    CELL_TEMPERATURE_RANGE_C, or DataError naming the argument `name`."""
    temp = _profile(name, temperature_c, "°C")
    if np.ndim(temperature_c) == 0:
        temp = np.full(steps, temp[0])
    if temp.size != steps:
        raise DataError(f"simulate: {name} has {temp.size} values for {steps} current "
                        "steps; expected one value or one per step")
    if not is_cell_temperature(temp):
        what = "an ambient" if name == "ambient_c" else "a cell"
        raise DataError(f"simulate: {name} must lie within "
                        "{:g}…{:g} °C ".format(*CELL_TEMPERATURE_RANGE_C)
                        + f"({what} temperature in °C, not K)")
    return temp


def evaluate(model: LmnModel | str | Path, paths: str | Path | Sequence[str | Path],
             soc0: float | Sequence[float] | None = None,
             read_options: Mapping[str, Any] | None = None, *, ambient: bool = False,
             through_hidden_pauses: bool = False) -> list[dict]:
    """Free-run error of a model (and its baselines) on records: one row per segment with,
    per model, RMSE, MAE and maximum error in mV over the whole record and RMSE over the
    20–80 % SoC window and each end (`rmse_mv`, `window_rmse_mv`, …), and where the record
    logs the tester's Ah counters `soc_drift_pct`, how far the SoC counted from its logged
    current (as the model counts it) ends from the counters' (% of capacity). soc0 as in train;
    ambient: driven by the chamber temperature (the thermal model computes the cell's);
    through_hidden_pauses: as `lmncell evaluate --through-hidden-pauses`. model may also be an
    LMNCell FMU (a path ending in .fmu): fmpy then drives it through the records' samples and
    the row has its figures under "fmu" (as `lmncell evaluate CELL.fmu`)."""
    if not isinstance(model, LmnModel) and str(model).lower().endswith(".fmu"):
        from lmncell.evaluation.fmueval import evaluate_fmu

        _, rows = evaluate_fmu(model, _path_list("evaluate", paths), soc0, ambient, read_options,
                               through_hidden_pauses, progress=lambda _m: None)
        return rows
    model = _model("evaluate", model)
    from lmncell.evaluation.evaluate import evaluate_model

    _, rows = evaluate_model(model, _path_list("evaluate", paths), soc0, read_options=read_options,
                             ambient=ambient, through_hidden_pauses=through_hidden_pauses)
    return rows


def build_fmu(model_path: LmnModel | str | Path, out: str | Path, native: bool = False,
              platforms: Sequence[str] | None = None) -> Path:
    """Package a model file (or a loaded model, written as its file) as an FMI 2.0
    co-simulation FMU: pythonfmu (the importer needs Python with numpy) or, with native=True,
    generated C compiled here (no Python needed) with a binary for each of platforms
    ("linux64", the default; "win64" and "darwin64", the latter a universal binary for Intel
    and Apple silicon Macs, cross-compiled with zig: pip install ziglang)."""
    if platforms is not None and not native:
        raise NativeBuildError("build_fmu: platforms are for native=True (the pythonfmu FMU "
                               "is built for this machine's platform only)")
    if isinstance(model_path, LmnModel):
        import tempfile

        from lmncell.runtime.model import save_model

        with tempfile.TemporaryDirectory(prefix="lmncell-build-") as tmp:
            path = Path(tmp) / "model.json"
            save_model(model_path, path)
            return build_fmu(path, out, native, platforms)
    if not isinstance(model_path, (str, os.PathLike)):
        raise DataError(f"build_fmu: model_path is {model_path!r:.60}; expected a model file's "
                        "path or an LmnModel")
    if native:
        from lmncell.fmu.native_build import build_native_fmu

        return build_native_fmu(model_path, out,
                                platforms=("linux64",) if platforms is None else platforms)
    from lmncell.fmu.pythonfmu_build import build_fmu as _build

    return _build(model_path, out)


def sweep(fmu: str | Path, cycles: Sequence[str | Path] = ("wltc",),
          ambient_c: Sequence[float] = (25.0,), soc0: Sequence[float] = (0.9,),
          vehicles: Sequence[str | Path | None] = (None,),
          repeat: int = 1, workers: int | None = None, scheduler: str | None = None,
          progress: bool = True, cutoff_v: float | None = None,
          cell_temperature_start_c: float | None = None):
    """Drive an FMU through every combination of cycles (shipped cycles' names or speed-trace
    CSV files, as `lmncell simulate --cycle` takes them) × vehicles × ambient temperatures (°C)
    × start SoC on Dask (a LocalCluster of `workers` processes, or the cluster behind
    `scheduler`); returns a pandas DataFrame, one row per scenario (distance driven, minimum and
    maximum cell voltage, end SoC, Ah throughput, energy, maximum cell temperature,
    out-of-range steps, why and when a run stopped with the cell empty, wall time). A run stops
    where the cell voltage falls below cutoff_v (V; None: the lowest voltage of the model's
    training records; 0: none, then below 0 V) or its SoC below 0. cell_temperature_start_c:
    every run's cell starts at this temperature (°C) and tends towards its ambient (a model
    with a thermal model; None: rested at the ambient). Needs the `sweep` extra
    (dask[distributed], pandas)."""
    from lmncell.scenarios.sweep import scenarios
    from lmncell.scenarios.sweep import sweep as _sweep

    cases = scenarios(_one_or_many(cycles), _one_or_many(ambient_c), _one_or_many(soc0),
                      [None if v is None else str(v) for v in _one_or_many(vehicles)], repeat,
                      cutoff_v=cutoff_v, cell_temperature_start_c=cell_temperature_start_c)
    return _sweep(fmu, cases, workers, scheduler, progress)
