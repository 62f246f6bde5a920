"""`lmncell inspect`: one summary per record, optionally a plot of current, voltage and SoC."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.data.dataset import starts_rested_full
from lmncell.data.lag import channel_lag_samples
from lmncell.data.readers import read_record
from lmncell.data.records import Record
from lmncell.data.soc import (
    charge_throughput_ah,
    coulomb_count,
    gap_charge_ah,
    logged_current_drift_ah,
)

NOMINAL_AH = {"A123": 2.3, "Pan18650PF": 2.9}


def nominal_capacity(rec: Record) -> float | None:
    for key, cap in NOMINAL_AH.items():
        if key in rec.name:
            return cap
    return None


def summarise(rec: Record, capacity_ah: float | None = None) -> dict:
    """Duration, sample time, current (A and C-rate), voltage, SoC swing and temperature."""
    cap = capacity_ah or nominal_capacity(rec)
    q = charge_throughput_ah(rec)
    current = [float(rec.current_a.min()), float(rec.current_a.max())]
    out: dict = {
        "file": rec.meta.source, "format": rec.meta.fmt, "samples": len(rec),
        "duration_s": rec.duration_s,
        "sample_time_s": rec.meta.sample_time_s if len(rec) > 1 else None,
        "segments": len(rec.meta.segment_starts), "sign": rec.meta.sign_note,
        "current_a": current,
        "voltage_v": [float(rec.voltage_v.min()), float(rec.voltage_v.max())],
        "net_charge_ah": float(q[-1]), "charge_range_ah": [float(q.min()), float(q.max())],
        "starts_full": starts_rested_full(rec),
        "chamber_temp_c": rec.meta.chamber_temp_c, "notes": rec.meta.notes,
    }
    if rec.charge_ah is not None:      # q came from the tester's counters
        out["current_integral_ah"] = float(charge_throughput_ah(rec, use_counters=False)[-1])
        out["logged_drift_ah"] = logged_current_drift_ah(rec)
        out["gap_charge_ah"] = gap_charge_ah(rec)
    if cap:
        out["capacity_ah_assumed"] = cap
        out["c_rate"] = [current[0] / cap, current[1] / cap]
        if out["starts_full"]:
            soc = 1.0 + q / cap
            out["soc_range"] = [float(soc.min()), float(soc.max())]
    if rec.temperature_c is not None:
        out["temperature_c"] = [float(np.min(rec.temperature_c)),
                                float(np.max(rec.temperature_c))]
    if rec.ambient_c is not None:
        out["ambient_c"] = [float(np.min(rec.ambient_c)), float(np.max(rec.ambient_c))]
    lag = channel_lag_samples(rec)
    if lag is not None:
        out["voltage_lag_samples"] = lag
    return out


def format_summary(s: dict) -> str:
    def rng(v: list[float], fmt: str) -> str:
        return f"{v[0]:{fmt}} … {v[1]:{fmt}}"

    if s["samples"] < 2:        # the shared set holds a one-sample file (a tester stub)
        step = "no sample time (too short to train on or evaluate)"
    else:
        step = f"sample time {s['sample_time_s']:.3g} s"
    lines = [f"{s['file']}  [{s['format']}]",
             f"  {s['samples']} samples, {s['duration_s'] / 3600:.2f} h, {step}, "
             f"{s['segments']} segment(s); sign: {s['sign']}",
             f"  current {rng(s['current_a'], '.3f')} A"
             + (f" ({rng(s['c_rate'], '.2f')} C at {s['capacity_ah_assumed']} Ah)"
                if "c_rate" in s else ""),
             f"  voltage {rng(s['voltage_v'], '.4f')} V; net charge {s['net_charge_ah']:+.4f} Ah",
             ]
    if "current_integral_ah" in s:
        lines.append(current_integral_line(s))
    if "soc_range" in s:
        lines.append(f"  SoC {rng([100 * x for x in s['soc_range']], '.1f')} % (starts full)")
    temp = s.get("temperature_c")
    if temp:
        lines.append(f"  temperature {rng(temp, '.1f')} °C")
    if s["chamber_temp_c"] is not None and not (isinstance(s["chamber_temp_c"], float)
                                                and math.isnan(s["chamber_temp_c"])):
        lines.append(f"  chamber {s['chamber_temp_c']:.0f} °C" + _ambient_text(s))
    lag = s.get("voltage_lag_samples")
    if lag:
        lines.append(f"  the voltage channel lags the current by {lag:.2f} sample(s), "
                     f"{lag * s['sample_time_s']:.3f} s (lmncell.data.lag: training's "
                     "current_delay_s 'auto' uses it where records are finer than Ts/2)")
    lines += [f"  note: {n}" for n in s["notes"]]
    return "\n".join(lines)


def _ambient_text(s: dict) -> str:
    """Where the chamber is logged: its range if it varies, and what it is to the model (the
    thermal model's ambient beside a cell temperature, else the model's temperature)."""
    ambient = s.get("ambient_c")
    if ambient is None:
        return ""
    span = "" if ambient[0] == ambient[1] else f" {ambient[0]:.1f} … {ambient[1]:.1f} °C"
    role = ("the thermal model's ambient" if s.get("temperature_c") else
            "no cell temperature: the model's temperature")
    return f", logged{span} ({role})"


GAP_CHARGE_NOTE_AH = 1e-3   # current_integral_line names the charge across gaps from this (Ah)


def current_integral_line(s: dict) -> str:
    """The net charge of the logged current beside the tester's counters: a model driven by
    the current, as an FMU is, integrates it and drifts from the counters' SoC by the gap
    inside the segments; the charge the counters count across the gaps between segments is
    named apart (evaluation starts each segment at the counters' SoC)."""
    cap = s.get("capacity_ah_assumed")

    def share(ah: float) -> str:
        return f", {100 * ah / cap:+.2f} % of {cap} Ah" if cap else ""

    drift = s["logged_drift_ah"]
    inside = " inside its segments" if s["segments"] > 1 else ""
    line = (f"  the net charge is the tester's counters'; the logged current integrates to "
            f"{s['current_integral_ah']:+.4f} Ah\n    ({drift:+.4f} Ah{share(drift)}{inside}: "
            "the SoC drift of a model driven by the current, as an FMU is)")
    gap = s["gap_charge_ah"]
    if abs(gap) >= GAP_CHARGE_NOTE_AH:
        line += (f"\n  the counters count {gap:+.4f} Ah{share(gap)} across the gaps between "
                 "segments, where the log has no samples: evaluation starts each segment at "
                 "the counters' SoC; a host that drives one FMU through the whole record must "
                 "set its SoC there")
    return line


def inspect_files(paths: list[str | Path], plot: str | Path | None = None,
                  capacity_ah: float | None = None,
                  read_options: Mapping[str, Any] | None = None) -> list[dict]:
    """Print a summary of every file; with plot, one figure of all files (current, voltage
    and, for records that start full, SoC over time) written to that path.
    read_options go to read_record."""
    out = []
    shown = []
    for p in paths:
        rec = read_record(p, **(read_options or {}))
        s = summarise(rec, capacity_ah)
        print(format_summary(s), flush=True)
        out.append(s)
        soc = None
        if plot is not None and s.get("soc_range"):
            soc = coulomb_count(rec, 1.0, s["capacity_ah_assumed"])
        shown.append((rec, soc))
    if plot is not None:
        from lmncell.report.plots import records_figure

        caps = sorted({f"{s['capacity_ah_assumed']:g}" for s in out if s.get("soc_range")})
        given = "given" if capacity_ah else "nominal, --capacity to set"
        records_figure(shown, Path(plot), f"SoC counted from full with {' or '.join(caps)} Ah "
                       f"({given})" if caps else "")
        print(f"plot of {len(shown)} record(s): {plot}")
    return out
