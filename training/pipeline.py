"""Library functions behind `lmncell train` and `lmncell evaluate`."""

from __future__ import annotations

import copy
import csv
import json
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_src.model import LmnModel, load_model, model_from_dict, model_to_dict, save_model
from fmu_src.observers import offline_fuzzy_design
from fmu_src.runtime import exo_series, initial_hysteresis, simulate
from training import __version__
from training.baselines import Ecm2rc, fit_ecm2rc
from training.config import TrainConfig, load_config
from training.dataset import Segment, estimate_capacity, file_sha256, record_to_segments, start_soc
from training.identify import train_lmn, with_soc_reference_weights
from training.metrics import WINDOW, pooled, record_metrics
from training.ocvfit import lowpass
from training.readers import read_record
from training.records import DataError, Record

Progress = Callable[[str], None]


def _print(msg: str) -> None:
    print(msg, flush=True)


def load_segments(paths: list[str | Path], cfg: TrainConfig, capacity_ah: float | None,
                  soc0: float | None, progress: Progress = _print
                  ) -> tuple[list[Segment], list[Record], float]:
    """Read files, fix capacity and start SoC, split and resample to the model rate."""
    if not paths:
        raise DataError("no data files given")
    if cfg.record_weights and len(cfg.record_weights) != len(paths):
        raise DataError(f"setting 'record_weights' has {len(cfg.record_weights)} value(s) for "
                        f"{len(paths)} data file(s): expected one weight per file, in order")
    records = []
    for p in paths:
        progress(f"reading {p}")
        records.append(read_record(p))
    if capacity_ah is None:
        capacity_ah = estimate_capacity(records)
        progress(f"capacity estimated from full discharges: {capacity_ah:.4f} Ah "
                 "(a lower bound; give --capacity for a measured value)")
    segs: list[Segment] = []
    weights = cfg.record_weights or [1.0] * len(records)
    for rec, weight in zip(records, weights, strict=True):
        for seg in record_to_segments(rec, cfg.sample_time_s, start_soc(rec, soc0), capacity_ah,
                                      tuple(cfg.soc_window), cfg.outside_weight):
            seg.weight = seg.weight * float(weight)
            seg.record_weight = float(weight)
            segs.append(seg)
    return segs, records, float(capacity_ah)


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


def simulate_segment(model: LmnModel, seg: Segment, capacity_ah: float | None = None):
    """Free-run LMN simulation of a segment from its start SoC (coulomb counting in the model)."""
    return simulate(model, seg.current_a, seg.temperature_c, seg.soc0, capacity_ah,
                    initial_hysteresis(seg.soc0))


HISTORY_TAU_S = 150.0


def _recent_current_rms(segs: list[Segment], ts: float) -> float:
    """RMS over the training samples of the current low-passed with HISTORY_TAU_S (A): how far
    the mean current of the last minutes typically is from rest, the spread an observer gives
    an unknown load history (ObserverSettings.history_current_sigma_a)."""
    both = np.concatenate([lowpass(s.current_a, HISTORY_TAU_S, ts) for s in segs])
    return float(np.sqrt(np.mean(both * both)))


def train_files(paths: list[str | Path], out: str | Path, capacity_ah: float | None = None,
                soc0: float | None = None, partition: list[str] | None = None,
                baselines: bool = False, config: str | Path | None = None,
                progress: Progress = _print, **overrides) -> tuple[LmnModel, dict]:
    """Train an LMN (and baselines if asked) on files and write the model file."""
    t0 = time.perf_counter()
    cfg = load_config(config, partition=partition, **overrides)
    segs, records, cap = load_segments(paths, cfg, capacity_ah, soc0, progress)
    n = sum(len(s) for s in segs)
    progress(f"training on {len(segs)} segment(s), {n} samples at Ts = {cfg.sample_time_s} s")
    result = train_lmn(segs, cfg, cap, progress)
    model = result.model
    model.limits = _limits(segs, model)
    model.cell = {"name": _cell_name(records), "voltage_min_v": model.limits["voltage_v"][0],
                  "voltage_max_v": model.limits["voltage_v"][1]}
    train_metrics = [{"segment": s.name, **_metrics(model, s)} for s in segs]
    model.noise = {"residual_std_v": 1e-3 * pooled(train_metrics),
                   "recent_current_rms_a": _recent_current_rms(segs, cfg.sample_time_s)}
    baseline_docs = {}
    if baselines:
        baseline_docs = fit_baselines(segs, cfg, cap, model, result.info.get("hysteresis_gamma"),
                                      progress)
    seconds = time.perf_counter() - t0
    model.extra = {
        "description": f"LMN of {model.cell['name']} with {model.n_local_models} local models",
        "training": {
            "software": f"lmncell {__version__} (python {platform.python_version()}, numpy "
                        f"{np.__version__})",
            "files": [{"path": str(p), "sha256": file_sha256(p)} for p in paths],
            "capacity_ah": cap, "settings": cfg.to_dict(), "curve": result.curve,
            "chosen_local_models": result.chosen_m, "info": result.info,
            "train_metrics": train_metrics,
        },
    }
    model.extra["observers"] = {"fuzzy": offline_fuzzy_design(model)}
    if baseline_docs:
        model.extra["baselines"] = baseline_docs
    save_model(model, out)
    summary = {"local_models": model.n_local_models,
               "train_rmse_mv": pooled(train_metrics),
               "train_window_rmse_mv": pooled(train_metrics, "window_"),
               "validation_rmse_mv": result.info.get("refined_validation_freerun_rmse_mv"),
               "seconds_lmn": result.info["seconds"], "seconds_total": seconds,
               "baselines": {k: v.get("fit", {}) for k, v in baseline_docs.items()}}
    progress(f"wrote {out}: {model.n_local_models} local models, free-run training RMSE "
             f"{summary['train_rmse_mv']:.2f} mV (20–80 % SoC: "
             f"{summary['train_window_rmse_mv']:.2f} mV), LMN training "
             f"{result.info['seconds']:.1f} s, total {seconds:.1f} s")
    return model, summary


def _cell_name(records: list[Record]) -> str:
    names = " ".join(r.name for r in records)
    if "A123" in names:
        return "A123 26650 LFP (Plett data)"
    if "Pan18650PF" in names or "3349" in names:
        return "Panasonic NCR18650PF NCA (Kollmeyer data)"
    return "cell of " + ", ".join(r.name for r in records[:3])


def _metrics(model: LmnModel, seg: Segment) -> dict:
    sim = simulate_segment(model, seg)
    return record_metrics(seg.voltage_v, sim.voltage_v, seg.soc_ref)


def fit_baselines(segs: list[Segment], cfg: TrainConfig, cap: float, lmn: LmnModel,
                  gamma: float | None, progress: Progress) -> dict:
    """ARX (one local model) and 2RC ECMs (without and with hysteresis) on the same segments."""
    out: dict = {}
    arx_cfg = copy.copy(cfg)
    arx_cfg.max_local_models = 1
    arx_cfg.pre_partition = "none"
    progress("baseline arx: one local linear model")
    arx = train_lmn(segs, arx_cfg, cap, lambda _m: None)
    out["arx"] = {"kind": "lmn", "model": model_to_dict(arx.model),
                  "fit": {"seconds": arx.info["seconds"]}}
    socs = [exo_series(lmn, s.current_a, s.temperature_c, s.soc0).soc for s in segs]
    h0s = [initial_hysteresis(s.soc0) for s in segs]
    weighted = with_soc_reference_weights(segs, socs, lmn.ocv_soc, lmn.ocv_v, cfg)  # as the LMN
    for name, g in (("ecm2rc", None), ("ecm2rc_hyst", gamma or 100.0)):
        progress(f"baseline {name}: fitting on the free-run error")
        ecm, info = fit_ecm2rc(weighted, socs, lmn.ocv_soc, lmn.ocv_v, cap, cfg.sample_time_s, g,
                               h0s)
        progress(f"  {name}: {info['seconds']:.1f} s, {info['evaluations']} evaluations")
        out[name] = {"kind": "ecm2rc", "model": ecm.to_dict(), "fit": info}
    return out


# ----- evaluation ------------------------------------------------------------------------
@dataclass
class Trace:
    """One evaluated segment: inputs, measured and simulated voltages of every model."""

    segment: Segment
    voltage: dict[str, np.ndarray]
    soc_model: np.ndarray
    validity: np.ndarray


def baseline_voltage(kind: str, doc: dict, seg: Segment, soc: np.ndarray) -> np.ndarray:
    if kind == "lmn":
        return simulate_segment(model_from_dict(doc, "baseline"), seg).voltage_v
    ecm = Ecm2rc.from_dict(doc)
    return ecm.simulate(seg.current_a, seg.temperature_c, soc, initial_hysteresis(seg.soc0))


def evaluate_model(model: LmnModel, paths: list[str | Path], soc0: float | None = None,
                   capacity_ah: float | None = None) -> tuple[list[Trace], list[dict]]:
    """Free-run simulation of each record's segments with the LMN and its baselines."""
    traces, rows = [], []
    cap = capacity_ah or model.capacity_ah
    for p in paths:
        rec = read_record(p)
        for seg in record_to_segments(rec, model.sample_time_s, start_soc(rec, soc0), cap):
            check_range(model, seg)
            sim = simulate_segment(model, seg, cap)
            volts = {"lmn": sim.voltage_v}
            for name, b in model.extra.get("baselines", {}).items():
                volts[name] = baseline_voltage(b["kind"], b["model"], seg, sim.soc)
            traces.append(Trace(seg, volts, sim.soc, sim.validity))
            row = {"record": seg.name}
            for name, v in volts.items():
                row[name] = record_metrics(seg.voltage_v, v, seg.soc_ref)
            rows.append(row)
    return traces, rows


def check_range(model: LmnModel, seg: Segment) -> list[str]:
    """Warnings for inputs outside what the model was trained on (they are not clamped)."""
    import warnings

    msgs = []
    lim = model.limits
    lo, hi = lim.get("current_a", [-np.inf, np.inf])
    imin, imax = float(seg.current_a.min()), float(seg.current_a.max())
    if imin < 1.1 * lo - 0.01 or imax > 1.1 * hi + 0.01:
        msgs.append(f"{seg.name}: current {imin:.2f}…{imax:.2f} A exceeds the trained range "
                    f"{lo:.2f}…{hi:.2f} A")
    if seg.temperature_c is not None and "temperature_c" in lim:
        tlo, thi = lim["temperature_c"]
        if seg.temperature_c.min() < tlo - 2 or seg.temperature_c.max() > thi + 2:
            msgs.append(f"{seg.name}: temperature {seg.temperature_c.min():.1f}…"
                        f"{seg.temperature_c.max():.1f} °C outside the trained {tlo:.1f}…"
                        f"{thi:.1f} °C")
    for m in msgs:
        warnings.warn(m, UserWarning, stacklevel=2)
    return msgs


def write_trace(trace: Trace, path: str | Path) -> Path:
    """One row per model step: time_s (end of step), current_a, voltages, soc."""
    path = Path(path)
    seg = trace.segment
    with open(path, "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["time_s", "current_a", "voltage_measured_v", "voltage_model_v", "soc"])
        for row in zip(seg.time_s, seg.current_a, seg.voltage_v, trace.voltage["lmn"],
                       trace.soc_model, strict=True):
            wr.writerow([repr(float(x)) for x in row])
    return path


def evaluate_files(model_path: str | Path, paths: list[str | Path], soc0: float | None = None,
                   plot_dir: str | Path | None = None, trace: str | Path | None = None,
                   as_json: bool = False, progress: Progress = _print) -> list[dict]:
    """`lmncell evaluate`: figures per record for the LMN and its baselines."""
    model = load_model(model_path)
    traces, rows = evaluate_model(model, paths, soc0)
    if trace is not None:
        if len(traces) == 1:
            write_trace(traces[0], trace)
        else:
            base = Path(trace)
            for k, t in enumerate(traces):
                write_trace(t, base.with_name(f"{base.stem}_{k}{base.suffix}"))
    if plot_dir is not None:
        from training import plots

        Path(plot_dir).mkdir(parents=True, exist_ok=True)
        files = plots.evaluation_figures(model, traces, Path(plot_dir))
        progress(f"wrote {len(files)} figure(s) to {plot_dir}")
    if as_json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            for name, m in r.items():
                if name == "record":
                    continue
                win = m["window_rmse_mv"]
                win_txt = "  (none)" if win is None else f"{win:6.2f} mV"
                progress(f"{r['record'][:48]:48s} {name:12s} RMSE {m['rmse_mv']:7.2f} mV  MAE "
                         f"{m['mae_mv']:6.2f}  max {m['max_mv']:7.1f}  | {WINDOW[0]:.0%}–"
                         f"{WINDOW[1]:.0%} SoC RMSE {win_txt}")
    return rows
