"""Drive an LMNCell FMU through the four shipped vehicle drive cycles with fmpy.

Usage: python examples/drive_cycles.py CELL.fmu [OUT_DIR]
(build CELL.fmu with `lmncell train …` and `lmncell build-fmu`, or take it from `lmncell demo`).
Prints the figures of each cycle and writes one plot per cycle.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lmncell.scenarios.drive import load_vehicle, plot_cycle, run_cycle
from lmncell.scenarios.traces import CYCLES


def main(fmu: str, out_dir: str = "drive_cycles_out") -> None:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = load_vehicle()
    for cycle in CYCLES:
        res = run_cycle(fmu, cycle, vehicle, repeat=1, soc0=0.9)
        f = res.figures
        print(f"{cycle:6s} {f['distance_km']:5.1f} km  {f['pack_energy_kwh']:5.2f} kWh  "
              f"min {f['voltage_min_v']:.3f} V  SoC {100 * f['soc_start']:.0f} → "
              f"{100 * f['soc_end']:.1f} %  out of range: {f['out_of_range_steps']} steps")
        plot_cycle(res, out / f"{cycle}.png")


if __name__ == "__main__":
    main(*sys.argv[1:])
