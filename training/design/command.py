"""`lmncell design`: arguments to specs, the programme, its files, plots and the optional proof."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from lmncell.design.optimal import (
    CellSpec,
    CyclerSpec,
    DesignSpec,
    design_programme,
    parse_profile,
    plot_programme,
    sequence_count,
    write_programme,
)


def default_virtual_cell() -> str:
    """pybamm where it is installed (the `sim` extra), else the built-in ECM."""
    import importlib.util

    return "pybamm" if importlib.util.find_spec("pybamm") is not None else "builtin"


def _cell(a) -> CellSpec:
    cell = CellSpec(capacity_ah=a.capacity, max_c_rate=a.max_c_rate, r0_ohm=a.r0)
    if a.model:
        from lmncell.evaluation.fmueval import model_or_shipped

        m = model_or_shipped(a.model)
        cell.ocv_soc, cell.ocv_v = tuple(m.ocv_soc), tuple(m.ocv_v)
        cell.voltage_min_v = float(m.limits.get("voltage_v", [cell.voltage_min_v])[0])
        cell.voltage_max_v = float(m.limits.get("voltage_v", [0, cell.voltage_max_v])[1])
    if a.voltage_min is not None:
        cell.voltage_min_v = a.voltage_min
    if a.voltage_max is not None:
        cell.voltage_max_v = a.voltage_max
    return cell


def run_design(a) -> int:
    # with --json, stdout carries the JSON only; progress goes to stderr
    out_stream = sys.stderr if a.json else sys.stdout

    def say(msg: str) -> None:
        print(msg, file=out_stream, flush=True)

    cell = _cell(a)
    cyc = CyclerSpec(max_current_a=a.max_current, hold_s=a.hold, sample_time_s=a.sample_time)
    spec = DesignSpec(parse_profile(a.soc_profile), a.duration, a.sequence, method=a.method,
                      information=a.information)

    def design(c: CellSpec):
        say(f"designing {sequence_count(spec)} sequence(s) of "
            f"{spec.sequence_s:.0f} s through SoC {spec.soc_profile} ({spec.method}, "
            f"{spec.information} information) …")
        return design_programme(c, cyc, spec, progress=say)

    result = None
    if a.compare_virtual:
        from lmncell.design.proof import make_virtual_cell, plot_proof, prove_design

        kind = a.virtual_cell or default_virtual_cell()
        vc = make_virtual_cell(kind, cell.capacity_ah)
        say(f"virtual cell: {kind}; the design model comes from its OCV and pulse tests")
        result, prog = prove_design(vc, cell, cyc, spec, design, progress=say)
    else:
        prog = design(cell)
    files = write_programme(prog, Path(a.out))
    say(f"wrote {', '.join(str(f) for f in files)}; current {prog.current_a.min():.2f} … "
        f"{prog.current_a.max():.2f} A, predicted voltage {prog.voltage_v.min():.3f} … "
        f"{prog.voltage_v.max():.3f} V, SoC reached at the profile points: "
        + ", ".join(f"{p[1]:.3f}" for p in prog.profile_points))
    if a.plot:
        plot_programme(prog, Path(a.plot))
    if result is not None:
        proof_json = Path(a.out).with_suffix(".proof.json")
        proof_json.write_text(json.dumps(result, indent=1))
        fig = plot_proof(result, Path(a.plot) if a.plot else Path(a.out).parent,
                         Path(a.out).stem)
        say(f"wrote {proof_json}, {fig}; the design beats the median of every random kind on "
            f"every profile: {'yes' if result['designed_beats_every_median'] else 'no'}")
        print(json.dumps(result if a.json else result["profiles"], indent=1))
    return 0
