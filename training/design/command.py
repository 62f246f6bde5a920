"""`lmncell design`: arguments to specs, the programme, its files, plots and the optional proof."""

from __future__ import annotations

import json
from pathlib import Path

from lmncell.design.optimal import (
    CellSpec,
    CyclerSpec,
    DesignSpec,
    compare_on_virtual_cell,
    design_programme,
    parse_profile,
    plot_programme,
    write_programme,
)


def run_design(a) -> int:
    cell = CellSpec(capacity_ah=a.capacity, max_c_rate=a.max_c_rate, r0_ohm=a.r0)
    if a.model:
        from lmncell.runtime.model import load_model

        m = load_model(a.model)
        cell.ocv_soc, cell.ocv_v = tuple(m.ocv_soc), tuple(m.ocv_v)
        cell.voltage_min_v = float(m.limits.get("voltage_v", [cell.voltage_min_v])[0])
        cell.voltage_max_v = float(m.limits.get("voltage_v", [0, cell.voltage_max_v])[1])
    if a.voltage_min is not None:
        cell.voltage_min_v = a.voltage_min
    if a.voltage_max is not None:
        cell.voltage_max_v = a.voltage_max
    cyc = CyclerSpec(max_current_a=a.max_current, hold_s=a.hold, sample_time_s=a.sample_time)
    spec = DesignSpec(parse_profile(a.soc_profile), a.duration, a.sequence)
    print(f"designing {round(spec.duration_s / spec.sequence_s)} sequences of "
          f"{spec.sequence_s:.0f} s through SoC {spec.soc_profile} …", flush=True)
    prog = design_programme(cell, cyc, spec, progress=lambda m: print(m, flush=True))
    files = write_programme(prog, Path(a.out))
    print(f"wrote {', '.join(str(f) for f in files)}; current {prog.current_a.min():.2f} … "
          f"{prog.current_a.max():.2f} A, predicted voltage {prog.voltage_v.min():.3f} … "
          f"{prog.voltage_v.max():.3f} V, SoC reached at the profile points: "
          + ", ".join(f"{p[1]:.3f}" for p in prog.profile_points))
    if a.plot:
        plot_programme(prog, Path(a.plot))
    if a.compare_virtual:
        print("proof on the virtual cell: LMNs trained on the designed and on random "
              "programmes …", flush=True)
        result = compare_on_virtual_cell(prog, cell, cyc, spec)
        print(json.dumps(result, indent=1))
    return 0
