"""Drive an LMNCell FMU through the four shipped vehicle drive cycles with fmpy.

Usage: python examples/drive_cycles.py CELL.fmu [OUT_DIR]
(build CELL.fmu with `lmncell train …` and `lmncell build-fmu`, or take it from `lmncell demo`).
Prints the figures of each cycle and writes one plot per cycle.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lmncell.cli import output_folder_argument, run_script
from lmncell.evaluation.fmueval import read_fmu_info
from lmncell.scenarios.drive import load_vehicle, plot_cycle, run_cycle
from lmncell.scenarios.traces import CYCLES


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("fmu", help="an LMNCell FMU")
    ap.add_argument("out_dir", nargs="?", default="drive_cycles_out",
                    type=output_folder_argument, help="folder for the plots")
    a = ap.parse_args()
    read_fmu_info(a.fmu)               # ConfigError naming the file unless an LMNCell FMU
    out = Path(a.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = load_vehicle()
    for cycle in CYCLES:
        res = run_cycle(a.fmu, cycle, vehicle, repeat=1, soc0=0.9)
        f = res.figures
        print(f"{cycle:6s} {f['distance_km']:5.1f} km  {f['pack_energy_kwh']:5.2f} kWh  "
              f"min {f['voltage_min_v']:.3f} V  SoC {100 * f['soc_start']:.0f} → "
              f"{100 * f['soc_end']:.1f} %  out of range: {f['out_of_range_steps']} steps")
        plot_cycle(res, out / f"{cycle}.png")


if __name__ == "__main__":
    run_script(main, __file__)
