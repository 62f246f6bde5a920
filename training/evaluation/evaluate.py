"""Evaluation of a model file on records: free-run simulation of the LMN and its baselines,
metrics over the whole record and the 20–80 % SoC window, traces and figures. The library
function behind `lmncell evaluate` and `lmncell.evaluate`."""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from lmncell.data.dataset import (
    FAST_LOG_RATIO,
    Segment,
    record_name,
    record_to_segments,
    start_soc,
    start_socs,
)
from lmncell.data.readers import read_record
from lmncell.data.records import DataError, Record, present
from lmncell.data.soc import logged_current_drift_ah
from lmncell.evaluation.metrics import ENDS, WINDOW, record_metrics
from lmncell.identification.baselines import Ecm2rc
from lmncell.progress import Progress
from lmncell.progress import print_progress as _print
from lmncell.report.jsontext import json_text
from lmncell.runtime.cosim import trained_bounds
from lmncell.runtime.model import LmnModel, load_model, model_from_dict, replaced_whole
from lmncell.runtime.step import initial_hysteresis, simulate, simulate_ambient

Trained = TypeVar("Trained")


def simulate_segment(model: LmnModel, seg: Segment, capacity_ah: float | None = None):
    """Free-run LMN simulation of a segment from its start SoC (coulomb counting in the model)."""
    return simulate(model, seg.current_a, seg.temperature_c, seg.soc0, capacity_ah,
                    initial_hysteresis(seg.soc0))


@dataclass
class Trace:
    """One evaluated segment: inputs, measured and simulated voltages of every model."""

    segment: Segment
    voltage: dict[str, np.ndarray]
    soc_model: np.ndarray
    validity: np.ndarray
    cell_temperature_c: np.ndarray | None = None   # what the LMN was stepped with (ambient runs)


def baseline_voltage(kind: str, doc: dict, seg: Segment, soc: np.ndarray) -> np.ndarray:
    if kind == "lmn":
        return simulate_segment(model_from_dict(doc, "baseline"), seg).voltage_v
    ecm = Ecm2rc.from_dict(doc)
    return ecm.simulate(seg.current_a, seg.temperature_c, soc, initial_hysteresis(seg.soc0))


def check_ambient_known(seg: Segment) -> None:
    """DataError where the record has a measured cell temperature and no chamber temperature:
    its ambient is not known (driven by the cell's own, the cell would be heated twice)."""
    if seg.ambient_temperature() is None and seg.temperature_kind == "measured":
        raise DataError(f"{seg.name}: driving the model by the ambient temperature needs the "
                        "chamber's beside the measured cell temperature, and the record has "
                        "none; expected a chamber column (your own CSV: map it as "
                        "ambient=COL in --columns), or evaluate with the cell temperature "
                        "(without --ambient)")


def ambient_of(seg: Segment) -> np.ndarray:
    """The ambient temperature a vehicle simulation would give for a segment (°C per step):
    the chamber temperature where the record has a measured cell temperature beside it (as the
    record logs it where that varies, else its set point), else the record's own (chamber)
    temperature, else 25 °C; DataError where it is not known (check_ambient_known)."""
    check_ambient_known(seg)
    ambient = seg.ambient_temperature()
    if ambient is not None:
        return np.array(np.broadcast_to(ambient, len(seg)), dtype=float)
    return np.asarray(seg.temperatures(), dtype=float)


def drives_ambient(seg: Segment, ambient: bool) -> bool:
    """Whether a segment is driven by its ambient temperature, the model's thermal model (where
    it has one) computing the cell's, as an FMU takes its `temperature` input by default: asked
    for (ambient: --ambient), or the record has no measured cell temperature, so that its
    chamber temperature (else 25 °C) is the ambient. Given as the cell's own, a model with a
    thermal model would see a cell that never warms (US06 at 25 °C: 18.7 against 5.2 mV)."""
    return ambient or seg.temperature_kind != "measured"


def temperature_input(seg: Segment, ambient: bool) -> str:
    """What temperature drove a segment's evaluation, for its row: "ambient" (--ambient),
    "cell" (its measured cell temperature), "chamber" (its chamber set point: the record has no
    cell temperature, so --ambient or not the same) or "none" (no temperature: 25 °C)."""
    if ambient:
        return "ambient"
    return {"measured": "cell", "chamber": "chamber"}.get(seg.temperature_kind, "none")


def temperature_words(seg: Segment, ambient: bool) -> str:
    """temperature_input in words, for a figure's caption."""
    kind = temperature_input(seg, ambient)
    if kind == "ambient":
        return ("the ambient (chamber) temperature, the thermal model computing the cell's "
                "where the model has one")
    if kind == "chamber":
        chamber = present(seg.temperature_c, "the chamber temperature")
        return (f"the chamber temperature {float(np.median(chamber)):g} °C (the record has "
                "no cell temperature; the thermal model computing the cell's where the model "
                "has one)")
    return ("the measured cell temperature" if kind == "cell" else
            "25 °C as the ambient (no temperature given; the thermal model computing the "
            "cell's where the model has one)")


def read_records(paths: Sequence[str | Path], soc0: float | Sequence[float] | None = None,
                 read_options: Mapping[str, Any] | None = None,
                 through_hidden_pauses: bool = False,
                 ocv: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> Iterator[tuple[Path, Record, float]]:
    """Each record to evaluate with its start SoC: read (read_options go to read_record), not
    split at its hidden pauses where through_hidden_pauses, soc0 as in start_socs (None: 1.0
    for a record that starts rested at full charge, checked against the model's OCV where
    given: see start_soc)."""
    for p, rec_soc0 in zip(paths, start_socs(soc0, len(paths)), strict=True):
        rec = read_record(p, **(read_options or {}))
        if through_hidden_pauses:
            rec = rec.through_hidden_pauses()
        yield Path(p), rec, start_soc(rec, rec_soc0, ocv)


def model_ocv(model: LmnModel) -> tuple[np.ndarray, np.ndarray] | None:
    """The model's OCV (SoC knots, V) to check a full start against, None where it carries no
    rising OCV (an absolute-output model's may be flat)."""
    return (model.ocv_soc, model.ocv_v) if model.ocv_v[-1] > model.ocv_v[0] else None


def evaluate_model(model: LmnModel, paths: Sequence[str | Path],
                   soc0: float | Sequence[float] | None = None,
                   capacity_ah: float | None = None, read_options: Mapping[str, Any] | None = None,
                   ambient: bool = False, through_hidden_pauses: bool = False
                   ) -> tuple[list[Trace], list[dict]]:
    """Free-run simulation of each record's segments with the LMN and its baselines
    (soc0: one start SoC for all records, one per file in order, or None for records that
    start rested at full charge; read_options go to read_record).

    ambient False: the measured cell temperature drives the models (the FMU with
    temperature_is_cell = true); True: only the ambient (chamber) temperature, the LMN's thermal
    model computes the cell temperature (the FMU's default) and the baselines, which have none,
    take the ambient as the cell temperature. through_hidden_pauses False: a pause that only
    the wall clock shows splits the record, and the next segment starts rested at its counted
    SoC (what the cell did); True: no split there, as a host that drives the FMU through the
    record's time column sees it (the model's state runs on through the pause)."""
    return evaluate_records(model, [(rec, rec_soc0) for _, rec, rec_soc0 in read_records(
        paths, soc0, read_options, through_hidden_pauses, model_ocv(model))], capacity_ah,
        ambient)


def evaluate_records(model: LmnModel, records: Sequence[tuple[Record, float]],
                     capacity_ah: float | None = None, ambient: bool = False
                     ) -> tuple[list[Trace], list[dict]]:
    """evaluate_model on records already read, each with its start SoC (a fraction)."""
    traces, rows = [], []
    cap = capacity_ah or model.capacity_ah
    for rec, rec_soc0 in records:
        notes = record_notes(rec, cap, model.sample_time_s)
        for seg in record_to_segments(rec, model.sample_time_s, rec_soc0, cap,
                                      current_delay_s=model.current_delay_s):
            check_range(model, seg)
            cell = None
            if drives_ambient(seg, ambient):
                amb = ambient_of(seg)
                sim, cell = simulate_ambient(model, seg.current_a, amb, seg.soc0, cap,
                                             initial_hysteresis(seg.soc0))
                driven = dataclasses.replace(seg, temperature_c=amb)
            else:
                sim, driven = simulate_segment(model, seg, cap), seg
            volts = {"lmn": sim.voltage_v}
            for name, b in model.extra.get("baselines", {}).items():
                volts[name] = baseline_voltage(b["kind"], b["model"], driven, sim.soc)
            traces.append(Trace(seg, volts, sim.soc, sim.validity, cell))
            row: dict[str, Any] = {"record": seg.name,
                                   "temperature_input": temperature_input(seg, ambient)}
            for name, v in volts.items():
                row[name] = record_metrics(seg.voltage_v, v, seg.soc_ref)
            if cell is not None and seg.ambient_c is not None and seg.temperature_c is not None:
                row["cell_temperature_rmse_k"] = float(np.sqrt(np.mean(
                    (cell - seg.temperature_c) ** 2)))
            rows.append(row | notes)
    return traces, rows


DRIFT_NOTE_PCT = 0.1   # print_rows names a record's SoC drift from this much (% of capacity)


def record_notes(rec: Record, capacity_ah: float, sample_time_s: float) -> dict:
    """What a row of a record's figures also says about the record: the hidden pauses it was
    split at; where the tester's Ah counters are logged the SoC drift of its logged current
    by its end (soc_drift_pct: net charge of the current minus the counters', % of
    capacity_ah; > 0: the model's SoC, counted from the current, ends above the counters');
    where it is logged at least FAST_LOG_RATIO times slower than the model's sample time
    sample_time_s (s), its median logging interval (logged_every_s, s)."""
    notes: dict = {}
    interval = rec.meta.sample_time_s
    if math.isfinite(interval) and interval >= FAST_LOG_RATIO * sample_time_s:
        notes["logged_every_s"] = float(interval)
    if rec.meta.pause_starts:
        notes["hidden_pauses_split"] = len(rec.meta.pause_starts)
    drift = logged_current_drift_ah(rec)
    if drift is not None:
        notes["soc_drift_pct"] = 100.0 * drift / capacity_ah
    return notes


def leave_one_out_folds(records: list[str], hold_out: str = "",
                        soc0: float | Sequence[float] | None = None, together: bool = False
                        ) -> list[tuple[str, float | None, list[str], list[float | None]]]:
    """(held-out record, its start SoC, training records, their start SoCs) for each record
    whose file name contains hold_out, or one of its comma-separated patterns ("N05,P05,P25":
    the folds between the training temperatures; every record for ""); a pattern "A+B" matches
    a name that contains A or B; soc0 as in start_socs (one for all, one per record in order,
    or None). together: the records of each pattern are held out at once, each trained on the
    records that it does not match (10degC: leave one temperature out; "Cycle_1+US06,
    Cycle_1+HWFET": leave two out, a record matched by several patterns held out with each),
    group by group in the patterns' order. DataError where a pattern (or a part of one)
    matches no record or a fold would have nothing to train or test on."""
    if len(set(records)) < 2:
        raise DataError(f"leave-one-out needs at least two different records, got "
                        f"{len(set(records))}: {', '.join(records) or '(none)'}")
    start = dict(zip(records, start_socs(soc0, len(records)), strict=True))
    patterns = hold_out_patterns(hold_out) or [""]
    for part in (part for pat in patterns for part in _parts(pat)):
        if not any(part in Path(p).name for p in records):
            raise DataError(f"hold-out pattern {part!r} is in none of the {len(records)} "
                            "record names: expected part of a file name, e.g. 10degC")
    if together:          # each group's folds one after another (one training per group)
        return [fold for pat in patterns for fold in _group_folds(records, pat, start)]
    return [_fold(h, [p for p in records if p != h], start) for h in records
            if any(_matches(pat, h) for pat in patterns)]


def _matches(pattern: str, path: str) -> bool:
    """Whether a hold-out pattern matches a record: its file name contains the pattern, or
    one of its "+"-separated parts."""
    return any(part in Path(path).name for part in _parts(pattern))


def _parts(pattern: str) -> list[str]:
    """A hold-out pattern's "+"-separated parts, blanks dropped ("" matches every name)."""
    return [q.strip() for q in pattern.split("+") if q.strip()] or [pattern]


def _group_folds(records: list[str], pattern: str, start: Mapping[str, float | None]
                 ) -> list[tuple[str, float | None, list[str], list[float | None]]]:
    """leave_one_out_folds of one pattern's records held out together: each trained on the
    records the pattern does not match."""
    train = [p for p in records if not _matches(pattern, p)]
    if not train:
        raise DataError(f"hold-out pattern {pattern!r} is in every record name, so held "
                        "out together nothing is left to train on; expected a pattern "
                        "that some records lack, e.g. 10degC among 10 and 25 °C records")
    return [_fold(h, train, start) for h in records if _matches(pattern, h)]


def _fold(held: str, train: list[str], start: Mapping[str, float | None]
          ) -> tuple[str, float | None, list[str], list[float | None]]:
    """One fold: the held-out record and its start SoC, the training records and theirs."""
    return held, start[held], train, [start[p] for p in train]


def trained_per_fold(folds: Sequence[tuple[str, float | None, list[str], list[float | None]]],
                     train: Callable[[list[str], list[float | None]], Trained]
                     ) -> Iterator[tuple[str, float | None, Trained]]:
    """(held-out record, its start SoC, train(its training records, their start SoCs)) for
    each fold of leave_one_out_folds, training again only where a fold's training records
    differ from the fold's before: the records of a group held out together (together=True,
    whose folds come one after another) share one training."""
    trained_on: list[str] | None = None
    for held, held_soc0, records, socs in folds:
        if records != trained_on:
            model, trained_on = train(records, socs), records
        yield held, held_soc0, model


def hold_out_patterns(hold_out: str) -> list[str]:
    """The name patterns of a hold_out setting: its comma-separated parts, blanks dropped."""
    return [p.strip() for p in hold_out.split(",") if p.strip()]


def hold_out_clause(hold_out: str) -> str:
    """The words a caption puts after "each record" for leave_one_out_folds' hold_out."""
    patterns = [" or ".join(repr(q) for q in _parts(p)) for p in hold_out_patterns(hold_out)]
    if not patterns:
        return ""
    if len(patterns) == 1:
        return f" whose name contains {patterns[0]}"
    return " whose name contains one of " + ", ".join(
        f"({p})" if " or " in p else p for p in patterns)


def fold_words(hold_out: str, together: bool, n_records: int, what: str = "models"
               ) -> tuple[str, str]:
    """A caption's title and words for the folds of leave_one_out_folds: ("Leave-one-record-
    out", "each record … held out in turn, the models trained on the other N − 1 records") or,
    together, ("Leave-one-group-out", "the records … held out together, …")."""
    if not together:
        return ("Leave-one-record-out", f"each record{hold_out_clause(hold_out)} held out in "
                f"turn, the {what} trained on the other {n_records - 1} records")
    return ("Leave-one-group-out", f"the records{hold_out_clause(hold_out)} held out "
            f"together, one group per pattern, the {what} trained on the records outside the "
            "group")


def through_pauses_clause(through_hidden_pauses: bool, what: str = "model") -> str:
    """The words a caption adds where records were run through their hidden pauses (what:
    the thing that runs on)."""
    if not through_hidden_pauses:
        return ""
    return (f"; pauses that only the wall clock shows not split (the {what} runs on through "
            "them, as in an FMU driven through the time column)")


def check_range(model: LmnModel, seg: Segment) -> list[str]:
    """Warnings for inputs outside what the model was trained on (they are not clamped)."""
    return warn_outside_training(model, seg.name, seg.current_a, seg.temperature_c)


def warn_outside_training(model: LmnModel, name: str, current_a: np.ndarray,
                          temperature_c: np.ndarray | None,
                          soc: np.ndarray | None = None) -> list[str]:
    """Warn (UserWarning) where a run's current (A), cell temperature (°C) or SoC leaves what
    the model was trained on by the margins at which the FMU raises out_of_range
    (lmncell.runtime.cosim.trained_bounds); the values are not clamped. Returns the messages."""
    import warnings

    msgs = []
    lim = model.limits
    ilo, ihi, slo, shi, tlo, thi = trained_bounds(model)[:6]
    imin, imax = float(current_a.min()), float(current_a.max())
    if imin < ilo or imax > ihi:
        lo, hi = lim["current_a"]
        msgs.append(f"{name}: current {imin:.2f}…{imax:.2f} A exceeds the trained range "
                    f"{lo:.2f}…{hi:.2f} A")
    if temperature_c is not None and (temperature_c.min() < tlo or temperature_c.max() > thi):
        lo, hi = lim["temperature_c"]
        msgs.append(f"{name}: temperature {temperature_c.min():.1f}…"
                    f"{temperature_c.max():.1f} °C outside the trained {lo:.1f}…{hi:.1f} °C")
    if soc is not None:
        outside = np.flatnonzero((soc < slo) | (soc > shi))
        if outside.size:
            lo, hi = lim["soc"]
            msgs.append(f"{name}: SoC {soc.min():.3f}…{soc.max():.3f} leaves the trained "
                        f"{lo:.3f}…{hi:.3f} first at step {int(outside[0])}"
                        + (" (below 0 the cell is past empty)" if soc.min() < 0 else ""))
    for m in msgs:
        warnings.warn(m, UserWarning, stacklevel=3)
    return msgs


def write_trace(trace: Trace, path: str | Path, name: str = "lmn") -> Path:
    """One row per model step: time_s (end of step), current_a, the measured voltage, the
    voltage of the trace's model called name, and its SoC."""
    path = Path(path)
    seg = trace.segment
    with replaced_whole(path) as part, open(part, "w", newline="", encoding="utf-8") as fh:
        wr = csv.writer(fh)
        wr.writerow(["time_s", "current_a", "voltage_measured_v", "voltage_model_v", "soc"])
        for row in zip(seg.time_s, seg.current_a, seg.voltage_v, trace.voltage[name],
                       trace.soc_model, strict=True):
            wr.writerow([repr(float(x)) for x in row])
    return path


def write_traces(traces: list[Trace], path: str | Path, name: str = "lmn") -> None:
    """write_trace of each trace: to path where there is one, else to path's stem _0, _1, …"""
    base = Path(path)
    for k, t in enumerate(traces):
        write_trace(t, base if len(traces) == 1
                    else base.with_name(f"{base.stem}_{k}{base.suffix}"), name)


def _mv(value: float | None) -> str:
    """An RMSE for the evaluate table: mV with two decimals, or "(none)" without samples."""
    return "(none)" if value is None else f"{value:.2f} mV"


def evaluate_files(model_path: str | Path, paths: list[str | Path],
                   soc0: float | Sequence[float] | None = None,
                   plot_dir: str | Path | None = None, trace: str | Path | None = None,
                   as_json: bool = False, progress: Progress = _print, ambient: bool = False,
                   read_options: Mapping[str, Any] | None = None,
                   through_hidden_pauses: bool = False) -> list[dict]:
    """`lmncell evaluate`: figures per record for the LMN and its baselines."""
    model = load_model(model_path)
    traces, rows = evaluate_model(model, paths, soc0, read_options=read_options,
                                  ambient=ambient, through_hidden_pauses=through_hidden_pauses)
    if trace is not None:
        write_traces(traces, trace)
    if plot_dir is not None:
        from lmncell.report import plots

        Path(plot_dir).mkdir(parents=True, exist_ok=True)
        titles = [f"{t.segment.name}: {Path(model_path).name} in free run from SoC "
                  f"{t.segment.soc0:.3g}, driven by the record's current and "
                  f"{temperature_words(t.segment, ambient)}; LMN RMSE whole record "
                  f"{_mv(r['lmn']['rmse_mv'])}, SoC 20–80 % {_mv(r['lmn']['window_rmse_mv'])}"
                  for t, r in zip(traces, rows, strict=True)]
        files = plots.evaluation_figures(model, traces, Path(plot_dir), titles)
        figures = [f for f in files if f.suffix == ".png"]
        tables = [f for f in files if f.suffix != ".png"]
        progress(f"wrote {len(figures)} figure(s) and {len(tables)} table(s) to {plot_dir}: "
                 + ", ".join(f.name for f in files))
    if as_json:
        print(json_text(rows))
    else:
        print_rows(rows, progress)
    return rows


def print_rows(rows: list[dict], progress: Progress = _print) -> None:
    """The evaluate table: one line per record and model (RMSE whole, MAE, max, window and
    ends), the cell temperature's RMSE of ambient runs, and which records were split at hidden
    pauses."""
    for r in rows:
        for name, m in r.items():
            if not isinstance(m, dict):
                continue
            progress(f"{r['record'][:48]:48s} {name:12s} RMSE {m['rmse_mv']:7.2f} mV  MAE "
                     f"{m['mae_mv']:6.2f}  max {m['max_mv']:7.1f}  | RMSE at SoC "
                     f"{100 * WINDOW[0]:.0f}–{100 * WINDOW[1]:.0f} % "
                     f"{_mv(m['window_rmse_mv'])}, below {100 * ENDS[0]:.0f} % "
                     f"{_mv(m['low_soc_rmse_mv'])}, above {100 * ENDS[1]:.0f} % "
                     f"{_mv(m['high_soc_rmse_mv'])}")
        if "cell_temperature_rmse_k" in r:
            progress(f"{r['record'][:48]:48s} driven by the ambient temperature: cell "
                     f"temperature RMSE {r['cell_temperature_rmse_k']:.2f} K")
    for name, pauses in record_notes_once(rows, "hidden_pauses_split"):
        progress(f"{name}: split at {pauses} pause(s) that only its "
                 "wall clock shows, each segment after one started rested; an FMU "
                 "driven through its time column runs on through them "
                 "(--through-hidden-pauses scores it that way)")
    _print_drifts(rows, progress)
    _print_slow_logs(rows, progress)


def record_notes_once(rows: list[dict], key: str) -> Iterator[tuple[str, Any]]:
    """(record name, note) for each record whose rows carry the record_notes entry key: once
    per record, however many segments ('#1', '#2') it was split into (each carries the same)."""
    told = set()
    for r in rows:
        name, value = record_name(r["record"]), r.get(key)
        if value is not None and name not in told:
            told.add(name)
            yield name, value


def _print_slow_logs(rows: list[dict], progress: Progress) -> None:
    """One line per record logged at least FAST_LOG_RATIO times slower than the model's
    sample time (record_notes' logged_every_s)."""
    for name, interval in record_notes_once(rows, "logged_every_s"):
        progress(f"{name}: logged every {interval:.3g} s (median), slower than the model's "
                 "sample time: it is scored at the model's steps, each against the mean of the "
                 "two logged voltages around it, so its figures say nothing of what the cell "
                 "did between the logged samples")


def _print_drifts(rows: list[dict], progress: Progress) -> None:
    """One line per record whose logged current drifts from the tester's Ah counters by at
    least DRIFT_NOTE_PCT of the capacity by its end."""
    for name, drift in record_notes_once(rows, "soc_drift_pct"):
        if abs(drift) < DRIFT_NOTE_PCT:
            continue
        side = "above" if drift > 0 else "below"
        progress(f"{name}: the SoC counted from its logged current (as the model and an FMU "
                 f"count it) ends {abs(drift):.2f} % of the capacity {side} the SoC of the "
                 "tester's Ah counters; where the OCV is steep (near empty) that drift shows "
                 "in the whole-record RMSE")
