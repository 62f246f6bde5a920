"""SoC observers judged on real records: `lmncell evaluate MODEL DATA --observer …`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.data.dataset import Segment, record_name, record_to_segments
from lmncell.data.records import DataError
from lmncell.evaluation.evaluate import model_ocv, read_records
from lmncell.report.jsontext import json_text
from lmncell.runtime.model import LmnModel, load_model
from lmncell.runtime.observers import ObserverSettings, SocObserver
from lmncell.runtime.step import exo_series

SETTLE_S = 600.0
BAND = 0.02


@dataclass
class ObserverRun:
    name: str
    time_s: np.ndarray
    soc_ref: np.ndarray
    estimate: np.ndarray
    std: np.ndarray
    skipped: int | None      # measurements the observer skipped (None: not known, an FMU's)


def run_observer(model: LmnModel, seg: Segment, kind: str, soc0_est: float,
                 start: int = 0) -> ObserverRun:
    """The observer (or 'coulomb' counting) from sample `start` with the estimate soc0_est and
    the FMUs' default settings (ObserverSettings.for_model: the load history before the start
    unknown to the observer, at rest or under load)."""
    k0 = start
    if kind == "coulomb":
        est = exo_series(model, seg.current_a[k0:], None, soc0_est).soc
        return ObserverRun(kind, seg.time_s[k0:], seg.soc_ref[k0:], est, np.zeros_like(est), 0)
    temp = seg.temperatures()
    settings = ObserverSettings.for_model(model)
    ob = SocObserver(model, kind, soc0_est, temperature_c=float(temp[k0]), settings=settings)
    est, std = np.empty(len(seg) - k0), np.empty(len(seg) - k0)
    for j, k in enumerate(range(k0, len(seg))):
        est[j] = ob.step(float(seg.current_a[k]), float(seg.voltage_v[k]), float(temp[k]))
        std[j] = ob.soc_std
    return ObserverRun(kind, seg.time_s[k0:], seg.soc_ref[k0:], est, std, ob.state.skipped)


def soc_metrics(run: ObserverRun) -> dict:
    """RMSE, MAE, max after the first 10 minutes (%), time until the error stays within 2 %
    (s; None where it is outside 2 % at the end, as coulomb counting from a wrong start is),
    share of time outside ±3σ (consistency), the median half-width of the ±3σ band after the
    first 10 minutes (%; a band can hold the truth by being wide, this says how wide),
    skipped measurements."""
    t = run.time_s - run.time_s[0]
    err = run.estimate - run.soc_ref
    after = t >= SETTLE_S
    outside = np.abs(err) > BAND
    last_out = np.flatnonzero(outside)
    settle: float | None = float(t[last_out[-1]] + (t[1] - t[0])) if last_out.size else 0.0
    if last_out.size and last_out[-1] == err.size - 1:
        settle = None            # still outside 2 % at the end (JSON null, not Infinity)
    e = err[after] if after.any() else err
    out3 = (np.abs(err) > 3 * run.std) if run.std.any() else np.ones_like(err, dtype=bool)
    return {"rmse_pct": 100 * float(np.sqrt(np.mean(e * e))),
            "mae_pct": 100 * float(np.mean(np.abs(e))),
            "max_pct": 100 * float(np.max(np.abs(e))),
            "time_to_2pct_s": settle,
            "outside_3sigma_share": float(np.mean(out3)),
            "median_3sigma_pct": 300 * float(np.median(run.std[after] if after.any()
                                                       else run.std)),
            "skipped_measurements": run.skipped}


def observer_figure(runs: list[ObserverRun], path: Path) -> Path:
    from lmncell.report.plots import plt, save_figure

    fig, ax = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, constrained_layout=True)
    r0 = runs[0]
    t = (r0.time_s - r0.time_s[0]) / 60
    ax[0].plot(t, 100 * r0.soc_ref, "k", lw=1.2, label="reference (counters)")
    for r in runs:
        ax[0].plot(t, 100 * r.estimate, lw=0.9, label=r.name)
        if r.std.any():
            ax[0].fill_between(t, 100 * (r.estimate - 3 * r.std), 100 * (r.estimate + 3 * r.std),
                               alpha=0.2)
        ax[1].plot(t, 100 * (r.estimate - r.soc_ref), lw=0.8, label=r.name)
    ax[0].set(ylabel="SoC / %", title="SoC estimate with ±3σ band")
    ax[0].legend(fontsize=8)
    for b in (-2, 2):
        ax[1].axhline(b, color="k", ls=":", lw=0.7)
    ax[1].set(ylabel="estimate − reference / %", xlabel="time / min")
    return save_figure(fig, path)


def _reached(seg: Segment, start_at: float) -> np.ndarray:
    """Samples where the segment's reference SoC has reached start_at: fallen to it on a
    segment that starts above it (a discharge), risen to it otherwise (a charge)."""
    soc = seg.soc_ref
    return soc <= start_at if soc[0] > start_at else soc >= start_at


def _never_reached(name: str, socs: list[np.ndarray], start_at: float) -> DataError:
    low = min(float(soc.min()) for soc in socs)
    high = max(float(soc.max()) for soc in socs)
    return DataError(f"{name}: the reference SoC ({low:.3f} … {high:.3f}) never reaches the "
                     f"observer start SoC {start_at:g}: expected a start SoC within the "
                     "record's range")


def start_index(seg: Segment, start_at: float) -> int:
    """The first sample where the segment's reference SoC reaches start_at: falling to it on a
    record that starts above it (a discharge), rising to it otherwise (a charge)."""
    reached = _reached(seg, start_at)
    if not reached.any():
        raise _never_reached(seg.name, [seg.soc_ref], start_at)
    return int(np.argmax(reached))


def observer_segment(segs: list[Segment], start_at: float | None) -> Segment:
    """The segment of a record that the observer runs on: the first whose reference SoC
    reaches start_at (a record split by a logging gap can reach it in a later segment), or
    the first segment if start_at is None; DataError if none reaches it."""
    if start_at is None:
        return segs[0]
    for seg in segs:
        if _reached(seg, start_at).any():
            return seg
    raise _never_reached(record_name(segs[0].name), [seg.soc_ref for seg in segs], start_at)


def observer_runs(model: LmnModel, seg: Segment, kinds: list[str], soc0_est: float,
                  start_at: float | None) -> list[ObserverRun]:
    """Each observer kind and plain coulomb counting on a segment, started with soc0_est where
    the reference first reaches start_at (under load, start_index), or at the segment start if
    None."""
    k0 = start_index(seg, start_at) if start_at is not None else 0
    return [run_observer(model, seg, kind, soc0_est, k0) for kind in [*kinds, "coulomb"]]


def evaluate_observer_files(model_path: str | Path, paths: list[str | Path], kind: str,
                            soc0: float | Sequence[float] | None, soc0_est: float,
                            start_at: float | None,
                            plot_dir: str | Path | None = None, as_json: bool = False,
                            read_options: Mapping[str, Any] | None = None,
                            through_hidden_pauses: bool = False) -> list:
    """`lmncell evaluate --observer`: SoC error of an observer on records (read_options go to
    read_record; through_hidden_pauses as in lmncell.evaluation.evaluate.evaluate_model)."""
    model = load_model(model_path)
    results = []
    for p, rec, rec_soc0 in read_records(paths, soc0, read_options, through_hidden_pauses,
                                         model_ocv(model)):
        seg = observer_segment(record_to_segments(rec, model.sample_time_s, rec_soc0,
                                                  model.capacity_ah,
                                                  current_delay_s=model.current_delay_s),
                               start_at)
        runs = observer_runs(model, seg, [kind], soc0_est, start_at)
        results.append(observer_result(seg.name, runs, soc0_est))
        if plot_dir is not None:
            Path(plot_dir).mkdir(parents=True, exist_ok=True)
            observer_figure(runs, Path(plot_dir) / f"soc_{kind}_{p.stem}.png")
    print_observer_results(results, kind, as_json)
    return results


def observer_result(record: str, runs: list[ObserverRun], soc0_est: float) -> dict:
    """One record's row of `lmncell evaluate --observer`: the true SoC at the start, the start
    estimate and soc_metrics of each run (the observer and coulomb counting)."""
    return {"record": record, "start_soc_true": float(runs[0].soc_ref[0]),
            "start_estimate": soc0_est, **{r.name: soc_metrics(r) for r in runs}}


def _settle_text(settle_s: float | None) -> str:
    """'within 2 % after … s', or 'never within 2 %' (None: outside 2 % at the end)."""
    return "never within 2 %" if settle_s is None else f"within 2 % after {settle_s:.0f} s"


def print_observer_results(results: list[dict], kind: str, as_json: bool = False) -> None:
    """The observer table of `lmncell evaluate --observer` (or its JSON): per record the
    observer and coulomb counting from the same wrong start."""
    if as_json:
        print(json_text(results))
        return
    for r in results:
        for name in (kind, "coulomb"):
            m = r[name]
            print(f"{r['record'][:44]:44s} {name:8s} SoC RMSE {m['rmse_pct']:5.2f} %  MAE "
                  f"{m['mae_pct']:5.2f} %  max {m['max_pct']:5.2f} %  "
                  f"{_settle_text(m['time_to_2pct_s'])}  outside 3σ "
                  f"{100 * m['outside_3sigma_share']:.0f} % (median ±3σ "
                  f"{m['median_3sigma_pct']:.1f} %)")
