"""Training from files: read, segment, identify the LMN (and baselines), write the model file.
The library function behind `lmncell train` and `lmncell.train`."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import platform
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from lmncell import __version__
from lmncell.config import (
    AUTO_SAMPLE_TIME_S,
    ConfigError,
    TrainConfig,
    config_from_settings,
    given_settings,
    output_file_problem,
    sample_time_given,
)
from lmncell.data.dataset import (
    FAST_LOG_RATIO,
    Segment,
    check_sampling_interval,
    estimate_capacity,
    file_sha256,
    record_to_segments,
    start_soc,
    start_socs,
    starts_rested_full,
)
from lmncell.data.lag import estimate_current_delay
from lmncell.data.readers import read_record
from lmncell.data.records import DataError, Record, present
from lmncell.evaluation.evaluate import simulate_segment
from lmncell.evaluation.metrics import ENDS, pooled, record_metrics
from lmncell.identification.baselines import fit_ecm2rc
from lmncell.identification.construction import TrainResult, train_lmn
from lmncell.identification.ocvfit import lowpass, measured_ocv, ocv_test_capacity_ah
from lmncell.identification.prefit import with_soc_reference_weights
from lmncell.identification.thermal import fit_thermal
from lmncell.progress import Progress
from lmncell.progress import print_progress as _print
from lmncell.runtime.model import (
    CAPACITY_RANGE_AH,
    LmnModel,
    ModelFileError,
    is_cell_capacity,
    model_from_dict,
    model_to_dict,
    save_model,
    xml_text,
)
from lmncell.runtime.observers import offline_fuzzy_design
from lmncell.runtime.step import exo_series, initial_hysteresis
from lmncell.runtime.thermal import ThermalModel


def load_segments(paths: list[str | Path], cfg: TrainConfig, capacity_ah: float | None,
                  soc0: float | Sequence[float] | None, progress: Progress = _print,
                  read_options: Mapping[str, Any] | None = None
                  ) -> tuple[list[Segment], list[Record], float, float]:
    """Read files, fix capacity, start SoC and the current delay (s; cfg.current_delay_s),
    split and resample to the model rate; returns segments, records, capacity and delay."""
    records = read_training_records(paths, cfg, progress, read_options)
    if capacity_ah is None:
        capacity_ah = lower_bound_capacity(records, soc0, progress)
    delay = current_delay(cfg, records, progress)
    return (training_segments(records, cfg, capacity_ah, soc0, delay), records,
            float(capacity_ah), delay)


def read_training_records(paths: list[str | Path], cfg: TrainConfig,
                          progress: Progress = _print,
                          read_options: Mapping[str, Any] | None = None) -> list[Record]:
    """The training files' records (one record weight per file where the setting gives them)."""
    if not paths:
        raise DataError("no data files given")
    if cfg.record_weights and len(cfg.record_weights) != len(paths):
        raise DataError(f"setting 'record_weights' has {len(cfg.record_weights)} value(s) for "
                        f"{len(paths)} data file(s): expected one weight per file, in order")
    _check_paths_once(paths)
    records = []
    for p in paths:
        progress(f"reading {p}")
        records.append(read_record(p, **(read_options or {})))
    _check_records_once(records)
    peak = max(float(np.max(np.abs(r.current_a))) for r in records)
    if not peak > cfg.rest_current_a:
        raise DataError(f"no training record carries a current above the rest current "
                        f"{cfg.rest_current_a:g} A (largest |current| {peak:g} A): a model of "
                        "the cell's response to current needs one; expected the current column "
                        "in A (check the column, and --current-unit for mA)")
    return records


def _check_paths_once(paths: list[str | Path]) -> None:
    """DataError where one file is given twice (the same file by any path)."""
    seen: dict[Path, str | Path] = {}
    for p in paths:
        key = Path(p).resolve()
        if key in seen:
            raise DataError(f"{p}: given twice (also as {seen[key]}); expected each training "
                            "file once (a record given twice counts twice in the fit and in its "
                            "validation)")
        seen[key] = p


def _check_records_once(records: list[Record]) -> None:
    """DataError where two files hold the same measurements (a copy under another name)."""
    seen: dict[str, Record] = {}
    for rec in records:
        digest = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in (
            rec.time_s, rec.current_a, rec.voltage_v))).hexdigest()
        if digest in seen:
            raise DataError(f"{rec.meta.source}: the same samples (time, current, voltage) as "
                            f"{seen[digest].meta.source}; expected each record once (a copy "
                            "counts twice in the fit and in its validation)")
        seen[digest] = rec


FULL_START_SPREAD_V = 0.08   # records taken as full whose rested start voltages lie further
#                              apart than this (V) get a note (full_start_note)


def check_full_starts(records: list[Record], soc0: float | Sequence[float] | None,
                      cfg: TrainConfig, progress: Progress = _print) -> None:
    """Where slow OCV tests are given, refuse a record taken as starting full (no start SoC
    given, rested at its top voltage) whose start voltage the tests' OCV puts part-way down
    (start_soc); the SoC scale is that of the records' largest discharge from full. Without
    them, say full_start_note's note, if any."""
    given = start_socs(soc0, len(records))
    if all(g is not None for g in given):
        return
    if not cfg.ocv_tests:
        note = full_start_note([r for r, g in zip(records, given, strict=True)
                                if g is None and starts_rested_full(r)])
        if note:
            progress(note)
        return
    knots = np.linspace(0.0, 1.0, 101)
    ocv = (knots, measured_ocv(cfg.ocv_tests, estimate_capacity(records, given), knots))
    for rec, rec_soc0 in zip(records, given, strict=True):
        start_soc(rec, rec_soc0, ocv, "the OCV of the slow tests (--ocv-tests)")


OCV_TEST_CAPACITY_SPREAD = 0.10   # a given capacity further than this from the slow OCV
#                                  tests' own gets a note (capacity_note); they lie 1.4 % (A123
#                                  C/30) and 2 % (Panasonic C/20) from the capacities advised


def capacity_note(capacity_ah: float | None, ocv_tests: Sequence[str]) -> str | None:
    """A note where the given capacity (Ah) lies more than OCV_TEST_CAPACITY_SPREAD from what
    the slow OCV tests deliver from full to empty: the tests are put on the model's SoC scale
    with the capacity, so such a model has its OCV in the wrong place (2.85 Ah given with the
    A123 C/30 tests of 2.06 Ah: 71 mV free-run RMSE over its training records, no word of
    why). None where there is no capacity given, no test, or no such gap."""
    if capacity_ah is None or not ocv_tests:
        return None
    test = ocv_test_capacity_ah(list(ocv_tests))
    if abs(capacity_ah / test - 1.0) <= OCV_TEST_CAPACITY_SPREAD:
        return None
    return (f"note: --capacity {capacity_ah:g} Ah lies {100 * abs(capacity_ah / test - 1):.0f} % "
            f"{'above' if capacity_ah > test else 'below'} the {test:.3f} Ah that the OCV "
            f"tests ({', '.join(Path(p).name for p in ocv_tests)}) deliver from full to empty; "
            "they are put on the model's SoC scale with it, so the model's OCV lies that far "
            "off: check --capacity (the cell's Ah from full to the cut-off at a slow rate)")


def full_start_note(full: list[Record]) -> str | None:
    """A note on each record taken as starting full (rested at its top voltage, no start SoC
    given) whose start voltage lies more than FULL_START_SPREAD_V below the highest such start
    among them: with no OCV test to check it against, a record that starts rested part-way
    down looks the same. None where there is none (or fewer than two records)."""
    if len(full) < 2:
        return None
    top = max(full, key=lambda r: float(r.voltage_v[0]))
    v_top = float(top.voltage_v[0])
    notes = [f"note: {r.meta.source} is taken as starting full (rested at its top voltage, no "
             f"--soc0), but starts at {float(r.voltage_v[0]):.4g} V, "
             f"{1000.0 * (v_top - float(r.voltage_v[0])):.0f} mV below {top.meta.source} "
             f"({v_top:.4g} V): if it starts part-way down, give its start SoC (--soc0, one "
             "per file in order) or an OCV test (--ocv-tests), which checks it"
             for r in full if float(r.voltage_v[0]) < v_top - FULL_START_SPREAD_V]
    return "\n".join(notes) or None


def lower_bound_capacity(records: list[Record], soc0: float | Sequence[float] | None,
                         progress: Progress = _print) -> float:
    """The largest discharge from full among the records (Ah, estimate_capacity), said."""
    capacity_ah = estimate_capacity(records, start_socs(soc0, len(records)))
    if not is_cell_capacity(capacity_ah):
        raise DataError(f"the largest discharge from full among the records is {capacity_ah:.3g} "
                        "Ah, outside a cell's {:g}…{:g} Ah: too little to estimate the capacity "
                        "from; give it (--capacity, capacity_ah=)".format(*CAPACITY_RANGE_AH))
    progress(f"capacity estimated from full discharges: {capacity_ah:.4f} Ah "
             "(a lower bound; give --capacity for a measured value)")
    return capacity_ah


def current_delay(cfg: TrainConfig, records: list[Record], progress: Progress = _print) -> float:
    """The current delay (s): the setting, or for 'auto' the voltage channel's lag."""
    delay = cfg.current_delay_s
    if delay == "auto":
        delay = estimate_current_delay(records, cfg.sample_time_s)
        progress(f"current delay {delay:.3f} s: the lag of the voltage channel behind the "
                 "current (lmncell.data.lag)")
    return float(delay)


def sampling_note(records: list[Record], sample_time_s: float) -> str | None:
    """A note where the records are logged faster than the model's sample time (the fastest
    record's median sample interval, its meta.sample_time_s, at least FAST_LOG_RATIO times
    below Ts): the model then follows each Ts-mean of the voltage, not every sample, and a host
    that scores the FMU at the log's samples sees the fast part of each current pulse missing.
    Likewise where a record is logged slower (FAST_LOG_RATIO times above Ts): each of its
    samples is held over several model steps, and the model learns nothing within a sample.
    None where neither."""
    logged = [(r.meta.sample_time_s, r.name) for r in records
              if math.isfinite(r.meta.sample_time_s)]
    if not logged:
        return None
    notes = []
    fastest, name = min(logged)
    if fastest * FAST_LOG_RATIO <= sample_time_s:
        notes.append(
            f"note: {name} is logged every {fastest:.3g} s (median), faster than the model's "
            f"Ts = {sample_time_s:g} s: the model follows the voltage's {sample_time_s:g}-s "
            "means, not every sample; where the voltage at each sample matters and the host "
            f"steps the model at the log's rate, train at that rate (--set "
            f"sample_time_s={round_step(fastest):g}, which takes longer)")
    slowest, name = max(logged)
    if slowest >= FAST_LOG_RATIO * sample_time_s:
        notes.append(
            f"note: {name} is logged every {slowest:.3g} s (median), slower than the model's "
            f"Ts = {sample_time_s:g} s: each sample is held over {slowest / sample_time_s:.3g} "
            "model steps, so the model learns nothing of what the cell does between samples "
            "(its fast time constants rest on the faster records alone, or on none)")
    return "\n".join(notes) or None


def auto_sample_time(records: list[Record]) -> float:
    """Ts (s) where sample_time_s is not given: the coarsest record's logging interval (its median
    sample step, meta.sample_time_s) rounded down to 1, 2 or 5 × 10^k s (round_step) and held
    within AUTO_SAMPLE_TIME_S, so that every record resolves each step; the largest of that
    range where no record says its interval."""
    low, high = AUTO_SAMPLE_TIME_S
    logged = [r.meta.sample_time_s for r in records if math.isfinite(r.meta.sample_time_s)
              and r.meta.sample_time_s > 0]
    return min(max(round_step(max(logged)), low), high) if logged else high


def with_records_sample_time(cfg: TrainConfig, records: list[Record],
                             progress: Progress = _print) -> TrainConfig:
    """cfg with Ts taken from the records (auto_sample_time), said; checked again, so that a
    setting that does not fit that Ts (a current delay of at least Ts, say) is refused by name."""
    ts = auto_sample_time(records)
    progress(f"sample time Ts = {ts:g} s: the records' logging interval within "
             f"{AUTO_SAMPLE_TIME_S[0]:g}…{AUTO_SAMPLE_TIME_S[1]:g} s (sample_time_s not given; "
             "a host stepping the FMU at Ts with each step's mean current then gives it what "
             "the log resolves)")
    return dataclasses.replace(cfg, sample_time_s=ts).check()


def round_step(interval_s: float) -> float:
    """The largest of 1, 2 or 5 × 10^k s within 5 % above an interval (0.101 s → 0.1 s)."""
    exponent = math.floor(math.log10(interval_s * 1.05))
    return max(m * 10.0**exponent for m in (1, 2, 5) if m * 10.0**exponent <= interval_s * 1.05)


def training_segments(records: list[Record], cfg: TrainConfig, capacity_ah: float,
                      soc0: float | Sequence[float] | None, delay: float) -> list[Segment]:
    """The records split and resampled to the model rate, their reference SoC counted with
    capacity_ah from each record's start SoC, weighted by the record weights."""
    segs: list[Segment] = []
    weights = cfg.record_weights or [1.0] * len(records)
    for rec, weight, rec_soc0 in zip(records, weights, start_socs(soc0, len(records)),
                                     strict=True):
        start = start_soc(rec, rec_soc0)
        check_sampling_interval(rec, cfg.sample_time_s)
        for seg in record_to_segments(rec, cfg.sample_time_s, start, capacity_ah,
                                      (cfg.soc_window[0], cfg.soc_window[1]),
                                      cfg.outside_weight,
                                      float(delay)):
            seg.weight = seg.weight * float(weight)
            seg.record_weight = float(weight)
            segs.append(seg)
    return segs


def _thermal_text(thermal: ThermalModel | None, info: dict, ocv_measured: bool) -> str:
    """The progress line's account of the thermal model (or why there is none); ocv_measured:
    the model's OCV comes from slow OCV tests (else training estimated it from the records)."""
    if thermal is None:
        return f"off ({info['reason']})"
    return (f"R = {thermal.resistance_k_per_w:.2f} K/W, τ = {thermal.time_constant_s:.0f}"
            f" s, rested {thermal.offset_k:+.2f} K above ambient; cell temperature RMSE "
            f"{info['rmse_k']:.2f} K on {len(info['segments'])} segment(s)"
            + (f"; at the bound of the search range, so not determined by these records: "
               f"{', '.join(info['at_bound'])} ({_undetermined_advice(ocv_measured)})"
               if info.get("at_bound") else ""))


def _undetermined_advice(ocv_measured: bool) -> str:
    """What determines a thermal model that the records left at a bound of its search."""
    if ocv_measured:
        return "records that warm up and cool down determine R and τ"
    return ("the heat i·(u − OCV) takes the OCV that training estimated from the records, "
            "which records without rests leave undetermined; with a slow OCV test "
            "(--ocv-tests, ocv_tests = [...]) it is the cell's own")


def _noise_doc(segs: list[Segment], sims: list[np.ndarray], residual_v: float, info: dict,
               sample_time_s: float) -> dict:
    """The model file's noise block: the free-run training residual (V), overall and by SoC,
    and the recent current RMS, for the observers."""
    return {"residual_std_v": residual_v,
            "recent_current_rms_a": _recent_current_rms(segs, sample_time_s),
            "residual_std_by_soc": residual_std_by_soc(
                segs, sims, residual_v, generalisation_factor(info)),
            "residual_rms_by_soc": training_rms_by_soc(segs, sims, residual_v)}


def _training_doc(paths: list[str | Path], cap: float, cfg: TrainConfig, result: TrainResult,
                  train_metrics: list[dict], thermal_info: dict) -> dict:
    """The model file's record of its training: software, the record files and OCV tests by
    name with their SHA-256, capacity, settings, the growth curve, the choices made and the
    training errors. No folder and no wall-clock time: the model file travels inside the FMU,
    and the same data and settings give the same file, bit for bit, wherever the data lie."""
    settings = cfg.to_dict()
    settings["ocv_tests"] = [Path(p).name for p in cfg.ocv_tests]
    return _without_timings({
        "software": f"lmncell {__version__} (python {platform.python_version()}, numpy "
                    f"{np.__version__})",
        "files": _named_files(paths), "ocv_test_files": _named_files(cfg.ocv_tests),
        "capacity_ah": cap, "settings": settings, "curve": result.curve,
        "chosen_local_models": result.chosen_m, "info": result.info,
        "train_metrics": train_metrics, "thermal": thermal_info,
    })


def _named_files(paths: Sequence[str | Path]) -> list[dict]:
    """Each file's name (without its folder) and SHA-256, for the model file's metadata."""
    return [{"name": Path(p).name, "sha256": file_sha256(p)} for p in paths]


def _without_timings(doc: Any) -> Any:
    """doc (nested dicts and lists) without its wall-clock times, the "seconds" keys at any
    depth: they differ from run to run, and the model file must not."""
    if isinstance(doc, dict):
        return {k: _without_timings(v) for k, v in doc.items() if k != "seconds"}
    if isinstance(doc, list):
        return [_without_timings(v) for v in doc]
    return doc


def _train_summary(model: LmnModel, train_metrics: list[dict], info: dict, seconds: float,
                   baseline_docs: dict) -> dict:
    """train_files' summary: M, the pooled free-run training RMSE (mV) overall, in the window
    and at each end, the refined validation RMSE, the times and the baselines' fits."""
    return {"local_models": model.n_local_models,
            "train_rmse_mv": pooled(train_metrics),
            "train_window_rmse_mv": pooled(train_metrics, "window_"),
            "train_low_soc_rmse_mv": pooled(train_metrics, "low_soc_"),
            "train_high_soc_rmse_mv": pooled(train_metrics, "high_soc_"),
            "validation_rmse_mv": info.get("refined_validation_freerun_rmse_mv"),
            "seconds_lmn": info["seconds"], "seconds_total": seconds,
            "baselines": {k: v.get("fit", {}) for k, v in baseline_docs.items()}}


def _limits(segs: list[Segment], model: LmnModel) -> dict:
    cur = np.concatenate([s.current_a for s in segs])
    volt = np.concatenate([s.voltage_v for s in segs])
    soc = np.concatenate([s.soc_ref for s in segs])
    temps = [s.temperature_c for s in segs if s.temperature_c is not None]
    lim = {"current_a": [float(cur.min()), float(cur.max())],
           "soc": [float(soc.min()), float(soc.max())],
           "voltage_v": [float(volt.min()), float(volt.max())]}
    if temps:
        t = np.concatenate(temps)
        lim["temperature_c"] = [float(t.min()), float(t.max())]
    return lim


HISTORY_TAU_S = 150.0


def _recent_current_rms(segs: list[Segment], ts: float) -> float:
    """RMS over the training samples of the current low-passed with HISTORY_TAU_S (A): how far
    the mean current of the last minutes typically is from rest, the spread an observer gives
    an unknown load history (ObserverSettings.history_current_sigma_a)."""
    both = np.concatenate([lowpass(s.current_a, HISTORY_TAU_S, ts) for s in segs])
    return float(np.sqrt(np.mean(both * both)))


CAPACITY_STEP = 0.01        # fit_capacity: candidates L·(1 + CAPACITY_STEP·k), k = 0 … 15
CAPACITY_CANDIDATES = 16
CAPACITY_PATIENCE = 2       # … stopping after this many candidates worse than the best


def fit_capacity(records: list[Record], cfg: TrainConfig,
                 soc0: float | Sequence[float] | None, delay: float,
                 progress: Progress = _print) -> tuple[float, list[Segment], TrainResult]:
    """The capacity (Ah) for records trained with a slow OCV test and no capacity given: of the
    lower bound L (the largest discharge from full among the records) × 1.00, 1.01, … (at
    most 1.15, stopping two candidates after the best), the one whose model follows its
    training records best in free run (RMSE over the whole records); with its segments and
    its training, which are the model's. At L the records' SoC reaches 0 where they stop,
    and the OCV test's curve meets them at the wrong place near empty (Panasonic 25 °C
    leave-one-out, whole record: 76.9 mV at L = 2.71 Ah against 8.1 mV at 2.85 Ah)."""
    lower = lower_bound_capacity(records, soc0, progress)
    best: tuple[float, float, list[Segment], TrainResult] | None = None
    best_k = 0
    for k in range(CAPACITY_CANDIDATES):
        cap = lower * (1.0 + CAPACITY_STEP * k)
        segs = training_segments(records, cfg, cap, soc0, delay)
        result = train_lmn(segs, cfg, cap)
        err = np.concatenate([simulate_segment(result.model, s).voltage_v - s.voltage_v
                              for s in segs])
        rmse = float(np.sqrt(np.mean(err * err)))
        progress(f"  capacity {cap:.4f} Ah ({100 * k * CAPACITY_STEP:.0f} % above the largest "
                 f"discharge): free-run training RMSE {1e3 * rmse:.2f} mV")
        if best is None or rmse < best[0]:
            best, best_k = (rmse, cap, segs, result), k
        elif k - best_k >= CAPACITY_PATIENCE:
            break
    rmse, cap, segs, result = present(best, "the best capacity")
    progress(f"capacity {cap:.4f} Ah, chosen by the free-run error ({1e3 * rmse:.2f} mV; give "
             "--capacity for a measured value)")
    return cap, segs, result


def check_given_capacity(capacity_ah: Any) -> None:
    """DataError unless capacity_ah is None or a capacity (Ah) the model file can hold
    (CAPACITY_RANGE_AH); before, 1e9 Ah trained a model that no loader would read."""
    if capacity_ah is None:
        return
    try:
        ok = not isinstance(capacity_ah, bool) and is_cell_capacity(float(capacity_ah))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DataError(f"train: capacity_ah = {capacity_ah!r:.60}; expected None (estimated "
                        "from the records) or a cell capacity in Ah within "
                        "{:g}…{:g}".format(*CAPACITY_RANGE_AH))


def train_files(paths: list[str | Path], out: str | Path, capacity_ah: float | None = None,
                soc0: float | Sequence[float] | None = None,
                partition: list[str] | None = None,
                baselines: bool = False, config: str | Path | None = None,
                progress: Progress = _print, read_options: Mapping[str, Any] | None = None,
                **overrides) -> tuple[LmnModel, dict]:
    """Train an LMN (and baselines if asked) on files and write the model file.

    capacity_ah: None estimates it: with slow OCV tests (ocv_tests) fit_capacity, else the
    largest discharge from full among the records (a lower bound);
    soc0: each record's start SoC: one value for all, one per file in order, or None (1.0 for
    records that start rested at full charge); read_options go to read_record (a column
    mapping and its options for your own CSV);
    overrides are training settings (lmncell.config.TrainConfig), e.g. max_local_models=4."""
    t0 = time.perf_counter()
    given = given_settings(config, partition=partition, **overrides)
    cfg = config_from_settings(given, str(config or "configuration"))
    check_given_capacity(capacity_ah)
    problem = output_file_problem(out)
    if problem:
        raise ConfigError(f"{out}: {problem}")
    records = read_training_records(paths, cfg, progress, read_options)
    if not sample_time_given(given):
        cfg = with_records_sample_time(cfg, records, progress)
    check_full_starts(records, soc0, cfg, progress)
    for note in (sampling_note(records, cfg.sample_time_s),
                 capacity_note(capacity_ah, cfg.ocv_tests)):
        if note:
            progress(note)
    cap, delay, segs, result = _identify(records, cfg, capacity_ah, soc0, progress)
    model = result.model
    model.current_delay_s = delay
    train_metrics, thermal_info = _complete_model(model, records, segs, result.info,
                                                  bool(cfg.ocv_tests), progress)
    baseline_docs = {}
    if baselines:
        baseline_docs = fit_baselines(segs, cfg, cap, model, result.info.get("hysteresis_gamma"),
                                      progress)
    seconds = time.perf_counter() - t0
    model.extra = {
        "description": f"LMN of {model.cell['name']} with {model.n_local_models} local models",
        "training": _training_doc(paths, cap, cfg, result, train_metrics, thermal_info),
    }
    model.extra["observers"] = {"fuzzy": offline_fuzzy_design(model)}
    if baseline_docs:
        model.extra["baselines"] = _without_timings(baseline_docs)
    check_trained_model(model, segs, cfg)
    save_model(model, out)
    summary = _train_summary(model, train_metrics, result.info, seconds, baseline_docs)
    progress(f"wrote {out}: {model.n_local_models} local models, free-run RMSE over the "
             f"training records {summary['train_rmse_mv']:.2f} mV (unweighted; 20–80 % SoC: "
             f"{_mv_or_none(summary['train_window_rmse_mv'])}{_ends_text(summary)}), LMN "
             f"training {result.info['seconds']:.1f} s, total {seconds:.1f} s")
    return model, summary


def _complete_model(model: LmnModel, records: list[Record], segs: list[Segment], info: dict,
                    ocv_measured: bool, progress: Progress) -> tuple[list[dict], dict]:
    """Complete the identified model from its training segments: the ranges it was trained on
    (limits), the cell's name and voltage range, the thermal model (fitted where the records
    have a cell temperature beside a known ambient) and the noise document of the observers.
    ocv_measured: the OCV comes from slow tests. Returns each segment's free-run metrics and
    the thermal fit's information."""
    model.limits = _limits(segs, model)
    model.cell = {"name": _cell_name(records), "voltage_min_v": model.limits["voltage_v"][0],
                  "voltage_max_v": model.limits["voltage_v"][1]}
    sims = [simulate_segment(model, s).voltage_v for s in segs]
    train_metrics = [{"segment": s.name, **record_metrics(s.voltage_v, v, s.soc_ref)}
                     for s, v in zip(segs, sims, strict=True)]
    model.thermal, thermal_info = fit_thermal(model, segs)
    progress("thermal model: " + _thermal_text(model.thermal, thermal_info, ocv_measured))
    model.noise = _noise_doc(segs, sims, 1e-3 * pooled(train_metrics), info,
                             model.sample_time_s)
    return train_metrics, thermal_info


def _identify(records: list[Record], cfg: TrainConfig, capacity_ah: float | None,
              soc0: float | Sequence[float] | None, progress: Progress
              ) -> tuple[float, float, list[Segment], TrainResult]:
    """The capacity (Ah), the current delay (s), the model-rate training segments and the LMN
    identified on them. capacity_ah None: fit_capacity with OCV tests, else the records' lower
    bound (lower_bound_capacity)."""
    if capacity_ah is None and cfg.ocv_tests:
        delay = current_delay(cfg, records, progress)
        cap, segs, result = fit_capacity(records, cfg, soc0, delay, progress)
        return cap, delay, segs, result
    cap = (lower_bound_capacity(records, soc0, progress) if capacity_ah is None
           else float(capacity_ah))
    delay = current_delay(cfg, records, progress)
    segs = training_segments(records, cfg, cap, soc0, delay)
    n = sum(len(s) for s in segs)
    progress(f"training on {len(segs)} segment(s), {n} samples at Ts = {cfg.sample_time_s} s")
    return cap, delay, segs, train_lmn(segs, cfg, cap, progress)


def check_trained_model(model: LmnModel, segs: list[Segment], cfg: TrainConfig) -> None:
    """DataError, before anything is written, where the identified model fails the checks
    that loading its file makes (model_from_dict): records that cannot support a model gave
    one whose file no loader would read (an OCV of -153…-3.4 V from 500 s of one drive cycle
    without an OCV test, a residual σ of 9 V from a voltage column with spikes)."""
    try:
        model_from_dict(model_to_dict(model), "the trained model")
    except ModelFileError as exc:
        soc = np.concatenate([s.soc_ref for s in segs])
        volts = np.concatenate([s.voltage_v for s in segs])
        hint = (f"the training samples span SoC {soc.min():.2f}…{soc.max():.2f} (of "
                f"{model.capacity_ah:.4g} Ah) and {volts.min():.3f}…{volts.max():.3f} V")
        if not cfg.ocv_tests:
            hint += ("; without slow OCV tests (--ocv-tests) the OCV is estimated from the "
                     "records alone, which takes records from full to empty at their true "
                     "capacity and start SoC")
        raise DataError(f"training gave a model that fails the model file's checks ({exc}); "
                        f"{hint}. Check the voltage column for spikes or a wrong unit, and "
                        "settings far from their defaults") from None


def _mv_or_none(value: float) -> str:
    """'… mV', or '(none)' where no training sample lies in that SoC range (NaN)."""
    return f"{value:.2f} mV" if np.isfinite(value) else "(none)"


def _ends_text(summary: dict) -> str:
    """", below 10 %: … mV, above 90 %: … mV" for the ends the training records reach."""
    parts = [f", {side} {100 * edge:.0f} %: {summary[key]:.2f} mV"
             for side, edge, key in (("below", ENDS[0], "train_low_soc_rmse_mv"),
                                     ("above", ENDS[1], "train_high_soc_rmse_mv"))
             if np.isfinite(summary[key])]
    return "".join(parts)


SOC_BINS = 10            # residual_std_by_soc: bins of 0.1 SoC
MIN_BIN_SAMPLES = 300


def generalisation_factor(info: dict) -> float:
    """The identification's free-run RMSE on its validation blocks over that on the samples it
    was fitted on, at least 1 (1 without validation): how much larger the model's error on
    new data is than on its own training data."""
    val = info.get("refined_validation_freerun_rmse_mv")
    fit = info.get("refined_train_freerun_rmse_mv")
    if val is None or fit is None or not (np.isfinite(val) and np.isfinite(fit)) or fit <= 0:
        return 1.0
    return max(1.0, float(val) / float(fit))


def training_rms_by_soc(segs: list[Segment], model_v: list[np.ndarray],
                        overall_v: float) -> dict:
    """The free-run training error's RMS (V) per SoC bin of the reference SoC, at the bin
    centres (a bin with fewer than MIN_BIN_SAMPLES samples gets overall_v): the EKF's
    measurement error σ_u(SoC), small on the plateau where the model is good and large near
    empty where the voltage collapses."""
    soc = np.concatenate([s.soc_ref for s in segs])
    err = np.concatenate([v - s.voltage_v for s, v in zip(segs, model_v, strict=True)])
    edges = np.linspace(0.0, 1.0, SOC_BINS + 1)
    idx = np.clip(np.searchsorted(edges, soc, side="right") - 1, 0, SOC_BINS - 1)
    rms = []
    for b in range(SOC_BINS):
        e = err[idx == b]
        value = float(np.sqrt(np.mean(e * e))) if e.size >= MIN_BIN_SAMPLES else overall_v
        rms.append(value if np.isfinite(value) else overall_v)
    return {"soc": (0.5 * (edges[:-1] + edges[1:])).tolist(), "rms_v": rms}


def residual_std_by_soc(segs: list[Segment], model_v: list[np.ndarray],
                        overall_v: float, factor: float = 1.0) -> dict:
    """training_rms_by_soc never below the overall RMS, times factor: the observers'
    persistent model error σ_m(SoC), larger near empty where the voltage collapses than in the
    middle (the floor of their reported SoC variance)."""
    by_soc = training_rms_by_soc(segs, model_v, overall_v)
    return {"soc": by_soc["soc"],
            "std_v": [factor * max(rms, overall_v) for rms in by_soc["rms_v"]]}


def train_arx(segs: list[Segment], cfg: TrainConfig, cap: float, lmn: LmnModel,
              gamma: float | None) -> TrainResult:
    """The ARX baseline: the LMN's settings with one local model and no pre-partition. It takes
    the LMN's hysteresis γ and Arrhenius E rather than choosing them again: the LMN chose E on
    its root model, which is the ARX's model, so the choice is the same without its root-model
    trainings."""
    arx_cfg = dataclasses.replace(
        cfg, max_local_models=1, pre_partition="none",
        hysteresis="off" if gamma is None else gamma,
        temperature_scaling="off" if lmn.arrhenius_k is None else lmn.arrhenius_k)
    return train_lmn(segs, arx_cfg, cap, lambda _m: None)


def _cell_name(records: list[Record]) -> str:
    names = " ".join(r.name for r in records)
    if "A123" in names:
        return "A123 26650 LFP (Plett data)"
    if "Pan18650PF" in names or "3349" in names:
        return "Panasonic NCR18650PF NCA (Kollmeyer data)"
    return xml_text("cell of " + ", ".join(r.name for r in records[:3]))


def fit_baselines(segs: list[Segment], cfg: TrainConfig, cap: float, lmn: LmnModel,
                  gamma: float | None, progress: Progress) -> dict:
    """ARX (one local model) and 2RC ECMs (without and with hysteresis) on the same segments."""
    out: dict = {}
    progress("baseline arx: one local linear model")
    arx = train_arx(segs, cfg, cap, lmn, gamma)
    out["arx"] = {"kind": "lmn", "model": model_to_dict(arx.model),
                  "fit": {"seconds": arx.info["seconds"]}}
    socs = [exo_series(lmn, s.current_a, s.temperature_c, s.soc0).soc for s in segs]
    h0s = [initial_hysteresis(s.soc0) for s in segs]
    weighted = with_soc_reference_weights(segs, socs, lmn.ocv_soc, lmn.ocv_v, cfg)  # as the LMN
    for name, g in (("ecm2rc", None), ("ecm2rc_hyst", gamma or 100.0)):
        progress(f"baseline {name}: fitting on the free-run error")
        ecm, info = fit_ecm2rc(weighted, socs, lmn.ocv_soc, lmn.ocv_v, cap, cfg.sample_time_s, g,
                               h0s, progress=progress)
        progress(f"  {name}: {info['seconds']:.1f} s, {info['evaluations']} evaluations")
        out[name] = {"kind": "ecm2rc", "model": ecm.to_dict(), "fit": info}
    return out
