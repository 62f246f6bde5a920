"""Benchmark of `lmncell sweep`: 48 scenarios (4 cycles × 3 ambients × 4 start SoC, repeat 5)
with the native FMU on 1 and 2 LocalCluster workers; prints scenarios and cell-steps per
second, the speed-up, and whether the two tables are identical (wall time aside). Then a 96s3p
pack with spread: cell-steps per second of the vectorised runtime on one core against
stepping the 288 cells one by one (CellStepper), medians of 3 runs.

    python tests/benchmarks/bench_sweep.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from lmncell.fmu.native_build import build_native_fmu
from lmncell.identification.train import train_files
from lmncell.runtime.model import load_model
from lmncell.runtime.step import CellStepper
from lmncell.scenarios.pack import Pack, PackSpec, cell_parameters
from lmncell.scenarios.sweep import scenarios, sweep

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data/panasonic_18650pf/25degC"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="lmncell-bench-sweep-"))
    files = [DATA / "drive_cycles/03-20-17_05.56_25degC_HWFTa_Pan18650PF.mat",
             DATA / "hppc/03-11-17_08.47_25degC_5Pulse_HPPC_Pan18650PF.mat"]
    train_files(files, tmp / "m.json", capacity_ah=2.85, soc0=1.0, progress=lambda _m: None)
    fmu = build_native_fmu(tmp / "m.json", tmp / "cell.fmu")
    cases = scenarios(["wltc", "udds", "us06", "hwfet"], [0.0, 25.0, 40.0],
                      [0.95, 0.8, 0.65, 0.5], repeat=a.repeat)
    from dask.distributed import Client, LocalCluster

    tables, seconds = {}, {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        with LocalCluster(n_workers=workers, threads_per_worker=1,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            started = time.perf_counter() - t0
            sweep(fmu, cases[:workers], client=client, progress=False)    # warm the workers
            runs = []
            for _ in range(3):
                t1 = time.perf_counter()
                tables[workers] = sweep(fmu, cases, client=client, progress=False)
                runs.append(time.perf_counter() - t1)
        seconds[workers] = float(np.median(runs))
        steps = int(tables[workers]["steps"].sum())
        print(f"{workers} worker(s): {len(cases)} scenarios in {seconds[workers]:.2f} s (median "
              f"of 3), {len(cases) / seconds[workers]:.2f} scenarios/s, "
              f"{steps / seconds[workers]:.0f} cell-steps/s; cluster start {started:.1f} s")
    cols = [c for c in tables[1].columns if c != "wall_s"]
    print(f"speed-up 2 vs 1 worker: {seconds[1] / seconds[2]:.2f}; tables identical: "
          f"{tables[1][cols].equals(tables[2][cols])}")
    bench_pack(load_model(tmp / "m.json"))


def bench_pack(model, steps: int = 600) -> None:
    spec = PackSpec(96, 3, capacity_spread=0.02, resistance_spread=0.05, seed=1)
    n = spec.n_series * spec.n_parallel
    current = -3.0 * np.abs(np.sin(np.arange(steps) / 30.0)) * spec.n_parallel
    vec, loop = [], []
    for _ in range(3):
        pack = Pack(model, spec, 0.9, 25.0, temperature_is_cell=True)
        t0 = time.perf_counter()
        for i in current:
            pack.cells.step(np.full(n, i / spec.n_parallel), 25.0)
        vec.append(steps * n / (time.perf_counter() - t0))
        cells = [CellStepper(model, 0.9, c) for c in cell_parameters(model, spec)[0]]
        t0 = time.perf_counter()
        for i in current[:60]:
            for c in cells:
                c.step(i / spec.n_parallel, 25.0)
        loop.append(60 * n / (time.perf_counter() - t0))
    v, lo = float(np.median(vec)), float(np.median(loop))
    print(f"96s3p pack, vectorised runtime: {v:.0f} cell-steps/s on one core; cell by cell: "
          f"{lo:.0f} cell-steps/s; ratio {v / lo:.1f}")
    shared = Pack(model, spec, 0.9, 25.0)
    t0 = time.perf_counter()
    for i in current:
        shared.step_current(i)
    print(f"96s3p pack with current sharing (two trial steps per step): "
          f"{steps * n / (time.perf_counter() - t0):.0f} cell-steps/s")


if __name__ == "__main__":
    main()
