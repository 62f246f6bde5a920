"""`lmncell design`: arguments to specs, the programme, its files, plots and the optional proof."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from lmncell.design import CAPACITY_TOLERANCE
from lmncell.design.optimal import (
    CellSpec,
    CyclerSpec,
    DesignSpec,
    Programme,
    check_sampling,
    design_programme,
    parse_profile,
    plot_programme,
    predict,
    sequence_count,
    shrink_to_fit,
    soc_window,
    write_programme,
)
from lmncell.progress import Progress
from lmncell.report.jsontext import json_text
from lmncell.runtime.model import LmnModel, write_text_whole
from lmncell.runtime.thermal import DEFAULT_TEMPERATURE_C


def default_virtual_cell() -> str:
    """pybamm where it is installed (the `sim` extra), else the built-in ECM."""
    import importlib.util

    return "pybamm" if importlib.util.find_spec("pybamm") is not None else "builtin"


DEFAULT_R0_OHM = 0.010   # the design model's R0 without --r0 or a model file


def _cell(a, say=print) -> tuple[CellSpec, LmnModel | None]:
    """The design's cell: --model's OCV, voltage limits and (unless --r0) its impedance
    (design_impedance), or the defaults; --voltage-min/--voltage-max over both; and the model
    (None without --model)."""
    cell = CellSpec(capacity_ah=a.capacity, max_c_rate=a.max_c_rate,
                    r0_ohm=DEFAULT_R0_OHM if a.r0 is None else a.r0)
    m = None
    if a.model:
        from lmncell.evaluation.fmueval import model_or_shipped

        m = model_or_shipped(a.model)
        if abs(a.capacity / m.capacity_ah - 1.0) > CAPACITY_TOLERANCE:
            say(f"note: --capacity {a.capacity:g} Ah is not the {m.capacity_ah:g} Ah of "
                f"{Path(a.model).name}: the design counts SoC with {a.capacity:g} Ah on the "
                "model's OCV over SoC, as the FMU's capacity parameter does for an aged cell; "
                f"give --capacity {m.capacity_ah:g} for the cell the model describes")
        cell.ocv_soc, cell.ocv_v = tuple(m.ocv_soc), tuple(m.ocv_v)
        cell.voltage_min_v = float(m.limits.get("voltage_v", [cell.voltage_min_v])[0])
        cell.voltage_max_v = float(m.limits.get("voltage_v", [0, cell.voltage_max_v])[1])
        impedance = design_impedance(m) if a.r0 is None else None
        if impedance:
            cell.r0_ohm, cell.rc = impedance
            say(f"design model from {Path(a.model).name}: R0 {1e3 * cell.r0_ohm:.1f} mΩ, RC "
                + ", ".join(f"{1e3 * r:.1f} mΩ at {t:g} s" for r, t in cell.rc)
                + f" (the median of its local models at {m.reference_temperature_c:g} °C)")
            cell.r_scale_soc, cell.r_scale = model_resistance_scale(m, cell,
                                                                    parse_profile(a.soc_profile))
            say("  its resistances × " + ", ".join(
                f"{g:.2f} at SoC {s:.2f}" for s, g in list(zip(
                    cell.r_scale_soc, cell.r_scale, strict=True))[::SCALE_SAID_EVERY])
                + " (the model's own pulse response over the profile's SoC)")
    if a.voltage_min is not None:
        cell.voltage_min_v = a.voltage_min
    if a.voltage_max is not None:
        cell.voltage_max_v = a.voltage_max
    return cell, m


SCALE_POINTS = 13          # SoC points of the design model's resistance scale from a model
SCALE_SAID_EVERY = 4       # every how many of them progress names
PULSE_REST_S, PULSE_S = 60, 30
SCALE_BOUNDS = (0.2, 5.0)  # as the characterisation of a virtual cell bounds its factors


def model_resistance_scale(model: LmnModel, cell: CellSpec, profile: list[float]
                           ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """SoC points over the profile's range (widened by the design's SoC margin) and, at each,
    the factor on the design model's resistances that best matches the model's own response
    (lmncell.simulate, its reference temperature) to a PULSE_S discharge and charge pulse from
    rest: least squares of the voltages' departures from the OCV, less their value at rest.
    A model's resistance rises towards empty (R_d, its local models there), which the median
    impedance of design_impedance misses: a programme designed without it took the Panasonic
    model to 2.03 V at SoC 0.1 (limit 2.55 V)."""
    import warnings

    from lmncell.api import simulate

    lo, hi = soc_window(DesignSpec(profile))
    socs = np.linspace(max(lo, 0.02), min(hi, 0.98), SCALE_POINTS)
    low_i, high_i = model.limits.get("current_a", (-cell.capacity_ah, cell.capacity_ah))
    amp = min(abs(low_i), abs(high_i), cell.max_c_rate * cell.capacity_ah) or cell.capacity_ah
    rest = np.zeros(PULSE_REST_S)
    current = np.concatenate([rest, np.full(PULSE_S, -amp), rest, np.full(PULSE_S, amp), rest])
    factors = []
    for soc0 in socs:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")       # a pulse may leave the trained region
            v = simulate(model, current, DEFAULT_TEMPERATURE_C, float(soc0),
                         capacity_ah=cell.capacity_ah)
        u, soc, _ = predict(cell, current, model.sample_time_s, float(soc0),
                            np.zeros(len(cell.rc)))
        own = v.voltage_v - cell.ocv(soc)
        design = u - cell.ocv(soc)
        own, design = own - own[PULSE_REST_S - 1], design - design[PULSE_REST_S - 1]
        factor = float(own @ design / (design @ design)) if design @ design > 0 else 1.0
        factors.append(float(np.clip(factor, *SCALE_BOUNDS)) if np.isfinite(factor) else 1.0)
    return tuple(float(s) for s in socs), tuple(factors)


def voltage_check(v: np.ndarray, cell: CellSpec) -> str:
    """What design --model says of the model's own voltage v (V) over its programme
    (model_voltage): its range, and a warning where it leaves the design's voltage limits
    (after _fit_to_model: where even a sequence's mean current, the charge the profile needs
    in it, takes the model there)."""
    low, high = float(v.min()), float(v.max())
    text = f"the model itself runs the programme at {low:.3f} … {high:.3f} V"
    if low < cell.voltage_min_v or high > cell.voltage_max_v:
        text += (f"; warning: outside the limits {cell.voltage_min_v:.3f} … "
                 f"{cell.voltage_max_v:.3f} V even where a sequence holds its mean current "
                 "(a longer --duration, or a SoC profile that stays further from empty or full)")
    return text


def model_voltage(model: LmnModel, current_a: np.ndarray, sample_time_s: float, soc0: float,
                  capacity_ah: float) -> np.ndarray:
    """The model's own voltage (V) over a programme: free run from soc0 at its reference
    temperature, the current held over samples of sample_time_s taken as its FMU takes it at
    its own sample time; one value per model step."""
    import math
    import warnings

    from lmncell.api import simulate
    from lmncell.scenarios.drive import step_means

    ts = model.sample_time_s
    steps = math.floor(current_a.size * sample_time_s / ts + 1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # the pulses may leave the trained current
        return simulate(model, step_means(current_a, sample_time_s, ts, steps),
                        DEFAULT_TEMPERATURE_C, soc0, capacity_ah=capacity_ah).voltage_v


def _fit_to_model(prog: Programme, model: LmnModel, cell: CellSpec, cyc: CyclerSpec,
                  spec: DesignSpec, say) -> tuple[Programme, np.ndarray]:
    """The programme with the sequences that take the model itself outside the voltage
    window shrunk towards their mean current (optimal.shrink_to_fit), said where any were;
    and the model's voltage (model_voltage, V) over that programme, the last one simulated."""
    ts, soc0 = model.sample_time_s, spec.soc_profile[0]
    dt = cyc.sample_time_s
    last: list[np.ndarray] = []          # the latest run's voltage, one value per model step

    def at_samples(current: np.ndarray) -> np.ndarray:
        v = model_voltage(model, current, dt, soc0, cell.capacity_ah)
        last[:] = [v]
        step = np.minimum((np.arange(1, current.size + 1) * dt / ts - 1e-9).astype(int),
                          v.size - 1)
        return v[np.maximum(step, 0)]

    prog, shrunk = shrink_to_fit(prog, cell, cyc, spec, at_samples)
    if shrunk:
        say("  the model itself left the voltage window in sequence(s) "
            + ", ".join(f"{k + 1} ({100 * kept:.0f} % of the spread kept)"
                        for k, kept in shrunk.items())
            + "; their current shrunk towards each one's mean (same charge)")
    return prog, last[0]           # shrink_to_fit's last run is of the programme it returns


def design_impedance(model: LmnModel) -> tuple[float, list[tuple[float, float]]] | None:
    """R0 (Ω) and RC elements [(R Ω, τ s)] of a model's RC-ladder local models at its reference
    temperature, each the median over the local models (elements whose median is 0 left out);
    None where its local models are not RC ladders."""
    from lmncell.evaluation.interpret import local_model_table

    rows = local_model_table(model, model.reference_temperature_c)
    if not all(r.get("rc_positive") and "rc_mohm_by_tau_s" in r for r in rows):
        return None
    taus = list(rows[0]["rc_mohm_by_tau_s"])
    median = {k: 1e-3 * float(np.median([r["rc_mohm_by_tau_s"][k] for r in rows]))
              for k in taus}
    rc = [(median[k], float(k)) for k in taus if k != "0" and median[k] > 0.0]
    return (median["0"], rc) if median.get("0", 0.0) > 0.0 else None


def programme_figures(prog, files: list[Path], model_check_text: str | None) -> dict:
    """What `lmncell design --json` prints without --compare-virtual: the files written, the
    programme's current (A) and predicted voltage (V) ranges, its duration (s), the SoC reached
    at each profile point, and with --model the model's own run of it (voltage_check) and the
    share of their current's spread kept by sequences shrunk for it (numbered from 1)."""
    return {"files": [str(f) for f in files],
            "current_a": [float(prog.current_a.min()), float(prog.current_a.max())],
            "predicted_voltage_v": [float(prog.voltage_v.min()), float(prog.voltage_v.max())],
            "duration_s": float(prog.time_s[-1] + (prog.time_s[1] - prog.time_s[0])),
            "soc_at_profile_points": [float(p[1]) for p in prog.profile_points],
            "model_check": model_check_text,
            "spread_kept_by_sequence": prog.settings.get("spread_kept_by_sequence", {})}


def run_design(a: argparse.Namespace) -> int:
    """`lmncell design`: design the programme (on the virtual cell's design model with
    --compare-virtual, and prove it there against random programmes), write it, print its
    figures. With --json, stdout carries the JSON only; progress goes to stderr."""
    out_stream = sys.stderr if a.json else sys.stdout

    def say(msg: str) -> None:
        print(msg, file=out_stream, flush=True)

    # with --compare-virtual the design model comes from the virtual cell, not from --model
    cell, model = _cell(a, (lambda _m: None) if a.compare_virtual else say)
    cyc = CyclerSpec(max_current_a=a.max_current, hold_s=a.hold, sample_time_s=a.sample_time)
    spec = DesignSpec(parse_profile(a.soc_profile), a.duration, a.sequence, method=a.method,
                      information=a.information)
    check_sampling(cyc, spec)        # before a virtual cell is characterised

    def design(c: CellSpec):
        n_seq = sequence_count(spec)
        rounded = ("" if n_seq * spec.sequence_s == spec.duration_s else
                   f"; --duration {spec.duration_s:g} s rounded to whole sequences: "
                   f"{n_seq * spec.sequence_s:g} s")
        say(f"designing {n_seq} sequence(s) of "
            f"{spec.sequence_s:.0f} s through SoC {spec.soc_profile} ({spec.method}, "
            f"{spec.information} information{rounded}) …")
        return design_programme(c, cyc, spec, progress=say)

    result = model_v = None
    if a.compare_virtual:
        from lmncell.design.proof import make_virtual_cell, prove_design

        kind = a.virtual_cell or default_virtual_cell()
        vc = make_virtual_cell(kind, cell.capacity_ah)
        say(f"virtual cell: {kind}; the design model comes from its OCV and pulse tests")
        result, prog = prove_design(vc, cell, cyc, spec, design, progress=say)
    else:
        prog = design(cell)
        if model is not None:
            prog, model_v = _fit_to_model(prog, model, cell, cyc, spec, say)
    files = write_programme(prog, Path(a.out))
    say(f"wrote {', '.join(str(f) for f in files)}; current {prog.current_a.min():.2f} … "
        f"{prog.current_a.max():.2f} A, predicted voltage {prog.voltage_v.min():.3f} … "
        f"{prog.voltage_v.max():.3f} V, SoC reached at the profile points: "
        + ", ".join(f"{p[1]:.3f}" for p in prog.profile_points))
    check = None
    if model_v is not None:
        check = voltage_check(model_v, cell)
        say(check)
    if a.plot:
        plot_programme(prog, Path(a.plot))
    if a.json and result is None:
        print(json_text(programme_figures(prog, files, check)))
    if result is not None:
        _write_proof(result, a, say)
    return 0


def _write_proof(result: dict, a: argparse.Namespace, say: Progress) -> None:
    """Write the proof's JSON beside the programme and its figure (in --plot's folder, else
    beside the programme), say so, and print the proof (its profiles only without --json)."""
    from lmncell.design.proof import plot_proof

    proof_json = Path(a.out).with_suffix(".proof.json")
    write_text_whole(proof_json, json_text(result))
    fig = plot_proof(result, Path(a.plot) if a.plot else Path(a.out).parent, Path(a.out).stem)
    left_out = result["skipped"]
    say(f"wrote {proof_json}, {fig}; the design beats the median of every random kind on "
        f"every profile: {'yes' if result['designed_beats_every_median'] else 'no'}"
        + (f" ({len(left_out)} random programme(s) left out, the virtual cell could not run "
           f"them: {', '.join(left_out)})" if left_out else ""))
    print(json_text(result if a.json else result["profiles"]))
