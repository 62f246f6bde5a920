"""Sweeps of drive-cycle scenarios on Dask: the Cartesian product of cycles × vehicles × ambient
temperatures × start SoC (the cell starting rested at its ambient, or at one given cell start
temperature), each scenario one FMU run (run_cycle, as `lmncell simulate`), on a
`dask.distributed` LocalCluster or on the cluster behind a scheduler address.

The FMU travels to the workers as bytes (scattered once), so a remote cluster needs no shared
file system; each worker unpacks it once per process. The table has one row per scenario in the
order of the product, whatever the number of workers; every column but `wall_s` is
deterministic.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import io
import itertools
import json
import math
import tempfile
import time
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.data.records import (
    CELL_TEMPERATURE_RANGE_C,
    DataError,
    is_cell_temperature,
    present,
)
from lmncell.runtime.model import LmnModel, model_from_dict, replaced_whole
from lmncell.runtime.thermal import cell_start_fault
from lmncell.scenarios.drive import (
    MAX_CYCLE_STEPS,
    STEP_ERROR_PREFIX,
    FmuStepError,
    Vehicle,
    cell_cutoff_v,
    check_cutoff,
    check_cutoff_in_range,
    default_step_s,
    load_vehicle,
    pack_power,
    run_cycle,
    step_count,
    step_means,
)
from lmncell.scenarios.pack import PackSpec, drive_pack, parse_pack, parse_spread
from lmncell.scenarios.traces import SpeedTrace, load_cycle

RESULT_COLUMNS = ("distance_km", "voltage_min_v", "voltage_max_v", "soc_end", "ah_throughput",
                  "cell_energy_wh", "pack_energy_kwh", "cell_temperature_max_c",
                  "out_of_range_steps", "stop", "stopped_at_s")


@dataclass(frozen=True)
class Scenario:
    """One run: a cycle (repeated), a vehicle, the ambient temperature (°C), the start SoC.
    The cycle's trace travels with the scenario: a worker needs no access to its file."""

    cycle: SpeedTrace
    vehicle: Vehicle
    vehicle_file: str
    ambient_c: float
    soc0: float
    repeat: int = 1
    pack: PackSpec | None = None     # None: one cell through the FMU; else the vectorised pack
    cutoff_v: float | None = None    # discharge cut-off (V); None: the FMU's model's
    cell_temperature_start_c: float | None = None   # °C; None: rested at the ambient


def check_distinct(option: str, values: Sequence[Any]) -> None:
    """DataError where a list option names one value twice: the product would run the same
    scenarios again (and count them twice in the summaries)."""
    seen: set[Any] = set()
    for v in values:
        if v in seen:
            raise DataError(f"sweep: {option} names {v!r} twice; expected each value once (a "
                            "repeated value runs the same scenarios again)")
        seen.add(v)


def scenarios(cycles: Sequence[str | Path], ambients: Sequence[float], soc0s: Sequence[float],
              vehicle_files: Sequence[str | None] = (None,), repeat: int = 1,
              pack: str | None = None, spread: str | None = None,
              seed: int = 0, cells: int | None = None,
              cutoff_v: float | None = None,
              cell_temperature_start_c: float | None = None) -> list[Scenario]:
    """The Cartesian product, cycle slowest and start SoC fastest; values checked with
    messages that name the option. cycles: shipped cycles' names or speed-trace files
    (load_cycle), each read here once. pack ('96s3p') or spread ('capacity=0.02,resistance=0.05')
    simulate the whole pack with the vectorised runtime (the pack of the vehicle file where
    only a spread is given); cells N without pack: a string of N cells in series (each
    carrying the cell current of the vehicle's pack, spread as given). cutoff_v: every run
    stops where a cell's voltage falls below it (V; None: the FMU model's lowest training
    voltage, drive.shipped_cutoff_v) or its SoC below 0. cell_temperature_start_c: every
    run's cells start at this temperature (°C; the FMU's use_cell_temperature_start, for a
    model with a thermal model) and tend towards their ambient; None: rested at the ambient."""
    if not cycles or not ambients or not soc0s or not vehicle_files:
        raise DataError("sweep: --cycles, --ambient and --soc0 each need at least one value")
    for option, values in (("--cycles", [str(c) for c in cycles]), ("--ambient", ambients),
                           ("--soc0", soc0s), ("--vehicle", [str(v) for v in vehicle_files])):
        check_distinct(option, values)
    traces = [load_cycle(c, "sweep: --cycles") for c in cycles]
    for t in ambients:
        if not is_cell_temperature(t):
            raise DataError(f"sweep: --ambient {t!r}: expected temperatures in °C within "
                            "{:g}…{:g} (not K)".format(*CELL_TEMPERATURE_RANGE_C))
    for s in soc0s:
        if not (math.isfinite(s) and 0.0 <= s <= 1.0):
            raise DataError(f"sweep: --soc0 {s!r}: expected fractions within 0…1")
    if repeat < 1:
        raise DataError(f"sweep: --repeat {repeat!r}: expected a whole number ≥ 1")
    if cutoff_v is not None:
        check_cutoff(cutoff_v, "sweep: --cutoff")
    if cell_temperature_start_c is not None and not is_cell_temperature(cell_temperature_start_c):
        raise DataError(f"sweep: --cell-temperature-start {cell_temperature_start_c!r}: "
                        "expected a temperature in °C within {:g}…{:g} (not K)".format(
                            *CELL_TEMPERATURE_RANGE_C))
    vehicles = [(load_vehicle(v), str(v) if v else "built-in") for v in vehicle_files]
    spreads = parse_spread(spread) if spread else {}
    if cells is not None and (cells < 1 or pack):
        raise DataError(f"sweep: --cells {cells!r}: expected a whole number ≥ 1, without --pack")
    size = parse_pack(pack) if pack else None

    def spec(veh: Vehicle, source: str) -> PackSpec | None:
        if size is None and not spreads and cells is None:
            return None
        whole = veh.n_series * veh.n_parallel
        ns, npar = (cells, 1) if cells is not None else size or (veh.n_series, veh.n_parallel)
        check_pack_size(int(ns) * int(npar), "--cells" if cells is not None else
                        "--pack" if size else f"the [pack] of the vehicle {source}")
        return PackSpec(int(ns), int(npar), spreads.get("capacity", 0.0),
                        spreads.get("resistance", 0.0), int(seed),
                        whole if cells is not None else None)

    specs = {vf: spec(veh, vf) for veh, vf in vehicles}
    return [Scenario(c, veh, vf, float(t), float(s), int(repeat), specs[vf], cutoff_v,
                     cell_temperature_start_c)
            for c, (veh, vf), t, s in itertools.product(traces, vehicles, ambients, soc0s)]


MAX_PACK_CELLS = 1_000_000   # cells one pack scenario simulates at once (about 0.7 kB each and
#                              2 µs per model step on one core: 1e6 cells, 1 h for a WLTC)


def check_pack_size(n_cells: int, source: str) -> None:
    """DataError naming the source where a pack scenario would simulate more than
    MAX_PACK_CELLS cells (100000s100000p was accepted, and ran out of memory on a worker)."""
    if n_cells > MAX_PACK_CELLS:
        sample = "" if source == "--cells" else " (or a sample string of it: --cells N)"
        raise DataError(f"sweep: {source}: {n_cells} cells, more than {MAX_PACK_CELLS} in one "
                        "pack scenario, which would take hours and gigabytes; expected a pack "
                        f"of at most that many cells{sample}")


_UNPACKED: dict[str, Path] = {}
_MODELS: dict[str, LmnModel] = {}


@functools.cache
def _cache_dir() -> tempfile.TemporaryDirectory:
    """This process's folder for the FMU files of _fmu_file, made on first use and removed
    when the process exits (TemporaryDirectory's finaliser; a Dask worker's at the cluster's
    close; tempfile.mkdtemp left one behind per worker process and run)."""
    return tempfile.TemporaryDirectory(prefix="lmncell-sweep-")


def _fmu_file(fmu_bytes: bytes) -> Path:
    """The FMU as a file in this process (written once per process and FMU)."""
    key = hashlib.sha256(fmu_bytes).hexdigest()[:16]
    if key not in _UNPACKED or not _UNPACKED[key].exists():
        path = Path(_cache_dir().name) / f"{key}.fmu"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(fmu_bytes)
        _UNPACKED[key] = path
    return _UNPACKED[key]


def _model_of(fmu_bytes: bytes) -> LmnModel:
    """The model file every LMNCell FMU carries (resources/model.json), read once per
    process and FMU."""
    key = hashlib.sha256(fmu_bytes).hexdigest()[:16]
    if key not in _MODELS:
        with zipfile.ZipFile(io.BytesIO(fmu_bytes)) as z:
            _MODELS[key] = model_from_dict(json.loads(z.read("resources/model.json")),
                                           "FMU resources/model.json")
    return _MODELS[key]


def _settings(sc: Scenario, pack: str) -> dict:
    """The scenario's columns of a row."""
    return {"cycle": sc.cycle.name, "vehicle": sc.vehicle.name, "vehicle_file": sc.vehicle_file,
            "ambient_c": sc.ambient_c, "soc0": sc.soc0,
            "cell_temperature_start_c": _or_nan(sc.cell_temperature_start_c),
            "repeat": sc.repeat, "pack": pack}


def _or_nan(value: float | None) -> float:
    """A table cell: the value, NaN for None (no such figure)."""
    return math.nan if value is None else float(value)


def run_pack_scenario(fmu_bytes: bytes, sc: Scenario) -> dict:
    """A pack scenario: the vehicle's pack power through the vectorised pack model."""
    t0 = time.perf_counter()
    model = _model_of(fmu_bytes)
    pack = present(sc.pack, "the pack scenario's pack")
    dt = sc.cycle.step_s
    power = (np.tile(pack_power(sc.vehicle, sc.cycle.speed_mps, sc.cycle.grade, dt), sc.repeat)
             * pack.power_share)
    ts = model.sample_time_s
    steps = step_count(power.size * dt, ts)
    cutoff = cell_cutoff_v(model.cell) if sc.cutoff_v is None else sc.cutoff_v
    f = drive_pack(model, pack, step_means(power, dt, ts, steps), sc.ambient_c, sc.soc0,
                   cutoff, sc.cell_temperature_start_c)
    driven = step_means(np.tile(sc.cycle.speed_mps, sc.repeat), dt, ts, steps)[: f["steps"]]
    return {**_settings(sc, pack.label), "capacity_spread": pack.capacity_spread,
            "resistance_spread": pack.resistance_spread, "seed": pack.seed,
            "distance_km": float(np.sum(driven) * ts / 1000.0),
            "voltage_min_v": f["voltage_min_v"], "voltage_max_v": f["voltage_max_v"],
            "soc_end": f["soc_end"], "soc_end_min": f["soc_end_min"],
            "ah_throughput": f["ah_throughput"], "cell_energy_wh": math.nan,
            "pack_energy_kwh": f["pack_energy_kwh"],
            "cell_temperature_max_c": f["cell_temperature_max_c"],
            "out_of_range_steps": f["out_of_range_steps"],
            "stop": f["stop"], "stopped_at_s": _or_nan(f["stopped_at_s"]),
            "steps": f["steps"], "wall_s": time.perf_counter() - t0}


def run_scenario(fmu_bytes: bytes, sc: Scenario) -> dict:
    """One row of the table: the scenario's settings and its results (run_cycle's figures,
    or the pack's for a pack scenario)."""
    if sc.pack is not None:
        return run_pack_scenario(fmu_bytes, sc)
    t0 = time.perf_counter()
    pack = f"{sc.vehicle.n_series}s{sc.vehicle.n_parallel}p"
    try:
        res = run_cycle(_fmu_file(fmu_bytes), sc.cycle, sc.vehicle, sc.repeat, sc.soc0,
                        temperature_c=sc.ambient_c, cutoff_v=sc.cutoff_v,
                        cell_temperature_start_c=sc.cell_temperature_start_c)
    except FmuStepError as exc:        # the row says so; the other scenarios' rows stand
        return {**_settings(sc, pack), **dict.fromkeys(RESULT_COLUMNS, math.nan),
                "out_of_range_steps": 0, "stop": f"{STEP_ERROR_PREFIX}{exc}",
                "stopped_at_s": exc.t_s, "steps": 0, "wall_s": time.perf_counter() - t0}
    f = res.figures
    return {**_settings(sc, pack),
           "distance_km": f["distance_km"],
           "voltage_min_v": f["voltage_min_v"], "voltage_max_v": f["voltage_max_v"],
           "soc_end": f["soc_end"], "ah_throughput": f["ah_throughput"],
           "cell_energy_wh": f["cell_energy_wh"], "pack_energy_kwh": f["pack_energy_kwh"],
           "cell_temperature_max_c": _or_nan(f["cell_temperature_max_c"]),
           "out_of_range_steps": f["out_of_range_steps"], "stop": f["stop"],
           "stopped_at_s": _or_nan(f["stopped_at_s"]), "steps": int(res.time_s.size),
           "wall_s": time.perf_counter() - t0}


USER_ERROR_KEY = "user_error"   # a worker's row that carries a DataError's message instead


def run_on_worker(fmu_bytes: bytes, sc: Scenario) -> dict:
    """run_scenario as a Dask task: a DataError (the user's mistake) comes back as a row
    {USER_ERROR_KEY: message}, which sweep raises again, so that no worker logs it as a
    failed task with a traceback."""
    try:
        return run_scenario(fmu_bytes, sc)
    except DataError as exc:
        return {USER_ERROR_KEY: str(exc)}


def check_sweep(fmu: str | Path, cases: list[Scenario], workers: int | None = None) -> Path:
    """The FMU's path, once it is known to be an LMNCell FMU (ConfigError naming the file if
    not) whose model's voltages the scenarios' cut-off lies within (check_cutoff_in_range),
    every scenario a whole number of steps within MAX_CYCLE_STEPS (check_steps), and workers a
    whole number ≥ 1 or None; DataError naming the option otherwise. So a user's mistake is
    refused here, before any worker starts, not logged by a worker as a failed task."""
    from fmpy import read_model_description
    from lmncell.evaluation.fmueval import read_fmu_info, shipped_model_doc

    fmu = Path(fmu)
    read_fmu_info(fmu)
    doc = shipped_model_doc(fmu)
    for cutoff_v in {sc.cutoff_v for sc in cases if sc.cutoff_v is not None}:
        check_cutoff_in_range(doc.get("cell"), cutoff_v, "sweep: --cutoff")
    description = read_model_description(str(fmu))
    model = model_from_dict(doc, f"{fmu}: resources/model.json")
    check_cell_starts(fmu, cases, model, {v.name for v in description.modelVariables})
    check_steps(cases, default_step_s(description), model.sample_time_s)
    if workers is not None and workers < 1:
        raise DataError(f"sweep: --workers {workers!r}: expected a whole number ≥ 1")
    return fmu


def check_cell_starts(fmu: Path, cases: list[Scenario], model: LmnModel,
                      variables: set[str]) -> None:
    """DataError naming --cell-temperature-start where a scenario starts its cell at a
    temperature that the FMU (its variable names) or its model would not take: an FMU built
    before the parameter existed, or the FMU's own refusal (thermal.cell_start_fault, e.g. a
    model without a thermal model)."""
    for start in {sc.cell_temperature_start_c for sc in cases
                  if sc.cell_temperature_start_c is not None}:
        if "use_cell_temperature_start" not in variables:
            raise DataError(f"sweep: --cell-temperature-start {start:g}: {fmu} has no parameter "
                            "use_cell_temperature_start (an earlier LMNCell built it); build it "
                            "again from its model with lmncell build-fmu")
        fault = cell_start_fault(start, model.thermal is not None, False)
        if fault:
            raise DataError(f"sweep: --cell-temperature-start {start:g}: {fmu} would refuse "
                            f"it: {fault}")


def check_steps(cases: list[Scenario], fmu_step_s: float, model_step_s: float) -> None:
    """DataError naming --repeat or the cycle where a scenario's repeated cycle holds no whole
    step or more than MAX_CYCLE_STEPS (as run_cycle would refuse it on a worker): steps of the
    FMU's default communication step fmu_step_s (s) for a one-cell scenario, of the model's
    sample time model_step_s (s) for a pack scenario (run_pack_scenario)."""
    for sc in cases:
        h = model_step_s if sc.pack is not None else fmu_step_s
        cycle_s = sc.cycle.speed_mps.size * sc.cycle.step_s
        n = step_count(sc.cycle.speed_mps.size * sc.repeat * sc.cycle.step_s, h)   # as the runs
        if n < 1:
            raise DataError(f"sweep: --cycles {sc.cycle.title!r}: {cycle_s * sc.repeat:g} s "
                            f"long, shorter than one step of {h:g} s; expected a longer trace "
                            "or more --repeat")
        if n > MAX_CYCLE_STEPS:
            raise DataError(f"sweep: --repeat {sc.repeat}: {n} steps of {h:g} s over "
                            f"{sc.repeat} × the {sc.cycle.title} cycle, more than "
                            f"{MAX_CYCLE_STEPS}, which would take hours and gigabytes; expected "
                            f"at most {math.floor(MAX_CYCLE_STEPS * h / cycle_s)} repeats")


SWEEP_MODULES = ("dask", "distributed", "pandas")   # the `sweep` extra's (pyproject.toml)


def require_sweep_extra() -> None:
    """Nothing, or DataError naming the modules of the `sweep` extra that are not installed
    (a plain `pip install -e .` leaves them out) and how to install them."""
    missing = [m for m in SWEEP_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        raise DataError(f"sweep runs on Dask and writes a pandas table; not installed: "
                        f"{', '.join(missing)}; expected the sweep extra: pip install -e "
                        "'.[sweep]' in the LMNCell clone")


def sweep(fmu: str | Path, cases: list[Scenario], workers: int | None = None,
          scheduler: str | None = None, progress: bool = True, client=None):
    """Run the scenarios on Dask and return the table (pandas DataFrame), one row per
    scenario in the given order. workers: LocalCluster processes (default: the cores);
    scheduler: the address of a running Dask scheduler instead (then workers is ignored);
    client: a dask.distributed Client to use as it is (then both are ignored)."""
    require_sweep_extra()
    import pandas as pd
    from dask.distributed import Client, LocalCluster
    from dask.distributed import progress as dask_progress

    fmu = check_sweep(fmu, cases, workers)
    data = fmu.read_bytes()
    cluster = None
    own = client is None
    if own and scheduler is None:
        cluster = _local_cluster(LocalCluster, workers)
        client = Client(cluster)
    elif own and scheduler is not None:
        client = _connect(Client, scheduler)
    try:
        blob = client.scatter(data, broadcast=True, hash=False)   # own key per sweep
        futures = [client.submit(run_on_worker, blob, sc, pure=False) for sc in cases]
        if progress:
            dask_progress(futures)
            print(flush=True)
        rows = client.gather(futures)
        refused = [row[USER_ERROR_KEY] for row in rows if USER_ERROR_KEY in row]
        if refused:
            raise DataError(refused[0])
    finally:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()
    return pd.DataFrame(rows)


PARQUET_ENGINES = ("pyarrow", "fastparquet")   # pandas writes Parquet with either


def check_table_path(path: str | Path) -> Path:
    """The table's path, checked before a sweep runs (whose results would otherwise be lost
    when they are written): DataError unless it ends in .csv, or in .parquet with a Parquet
    engine (PARQUET_ENGINES) installed."""
    path = Path(path)
    if path.suffix not in (".csv", ".parquet"):
        raise DataError(f"{path}: --out must end in .csv or .parquet")
    if path.suffix == ".parquet" and not any(importlib.util.find_spec(e)
                                              for e in PARQUET_ENGINES):
        raise DataError(f"{path}: writing Parquet needs pyarrow or fastparquet (pip install "
                        "pyarrow), neither is installed; or give a .csv name")
    return path


def _local_cluster(cluster_class, workers: int | None):
    """A LocalCluster of `workers` single-threaded processes; where its workers cannot start,
    a RuntimeError that says the usual cause (dask raises "Nanny failed to start")."""
    try:
        return cluster_class(n_workers=workers, threads_per_worker=1, processes=True,
                             dashboard_address=None)
    except RuntimeError as exc:
        raise RuntimeError(
            f"sweep: the Dask worker processes did not start ({exc}). A script that calls "
            "lmncell.sweep must call it under `if __name__ == \"__main__\":`, because each "
            "worker process imports the script again, and code piped to python's standard "
            "input cannot start them at all (see examples/sweep_local_cluster.py)") from exc


def _connect(client_class, scheduler: str):
    """A Client of the Dask scheduler at that address; DataError naming it where none
    answers (dask raises OSError or TimeoutError after its connect timeout) or the address
    is not one."""
    try:
        return client_class(scheduler)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise DataError(f"sweep: --scheduler {scheduler!r}: cannot connect to a Dask scheduler "
                        f"there ({type(exc).__name__}: {exc}); expected the address of a "
                        "running one, e.g. tcp://host:8786") from None


def write_table(table, path: str | Path) -> Path:
    """CSV, or Parquet for a .parquet name (needs pyarrow or fastparquet): check_table_path.
    The CSV's numbers are the shortest that read back to the same floats (0.8, not the
    0.80000000000000004 of a fixed 17 digits)."""
    path = check_table_path(path)
    with replaced_whole(path) as part:       # a full disk leaves no truncated table
        if path.suffix == ".parquet":
            table.to_parquet(part, index=False)
        else:
            table.to_csv(part, index=False)
    return path


def plot_sweep(table, out_dir: str | Path) -> list[Path]:
    """Distance driven, minimum cell voltage and end SoC over ambient × cycle (mean over the
    other settings; a run that stopped with the cell empty counts up to there); the title
    names a cell start temperature where the runs had one."""
    from lmncell.report.plots import plt, save_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    starts = table["cell_temperature_start_c"].dropna().unique()
    start = "".join(f", cells from {t:g} °C at the start" for t in starts)
    files = []
    for column, label in (("distance_km", "distance / km"),
                          ("voltage_min_v", "minimum cell voltage / V"),
                          ("soc_end", "end SoC")):
        grid = table.pivot_table(index="cycle", columns="ambient_c", values=column,
                                 aggfunc="mean")
        fig, ax = plt.subplots(figsize=(7, 0.6 * len(grid) + 2), constrained_layout=True)
        im = ax.imshow(grid.to_numpy(), aspect="auto", cmap="viridis")
        ax.set(xticks=range(grid.shape[1]), xticklabels=[f"{c:g}" for c in grid.columns],
               yticks=range(grid.shape[0]), yticklabels=list(grid.index),
               xlabel="ambient temperature / °C", ylabel="cycle",
               title=f"{label} (mean over start SoC and vehicles{start})")
        for (r, c), v in np.ndenumerate(grid.to_numpy()):
            ax.text(c, r, f"{v:.3f}", ha="center", va="center", color="w", fontsize=8)
        fig.colorbar(im, ax=ax, label=label)
        path = out / f"sweep_{column}.png"
        files.append(save_figure(fig, path))
    return files

