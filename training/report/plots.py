"""Figures people look at: fits and errors, validity functions, the M-selection curve, records."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from lmncell.data.records import Record
from lmncell.runtime.model import LmnModel, replaced_whole
from matplotlib.ticker import FuncFormatter

COLORS = {"measured": "k", "lmn": "tab:red", "fmu": "darkred", "arx": "tab:gray",
          "ecm2rc": "tab:blue", "ecm2rc_hyst": "tab:green", "ekf": "tab:red", "fuzzy": "tab:orange",
          "imm": "tab:purple"}
MAIN = ("lmn", "fmu")      # the model a figure is about (lmn; fmu: an FMU of it)


def save_figure(fig, path: str | Path, dpi: int = 90) -> Path:
    """Write the figure to path (its format by the suffix, PNG without one), whole or not at
    all (replaced_whole), and close it, also where writing fails; returns the path."""
    path = Path(path)
    try:
        with replaced_whole(path) as part:
            fig.savefig(part, dpi=dpi, format=path.suffix[1:] or matplotlib.rcParams[
                "savefig.format"])
    finally:
        plt.close(fig)
    return path


def safe_name(name: str) -> str:
    """A record name as part of a file name: only letters, digits and -_. kept."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def _baselines_first(voltages: dict[str, np.ndarray]) -> list[tuple[str, np.ndarray]]:
    """The LMN (or its FMU) last, so that it is drawn on top of the baselines."""
    return sorted(voltages.items(), key=lambda kv: kv[0] in MAIN)


def _style(name: str) -> dict:
    """Baselines thin and faint behind; the LMN (and the measurement) in front."""
    if name in MAIN:
        return {"lw": 0.9, "zorder": 4}
    return {"lw": 0.6, "alpha": 0.55, "zorder": 2}


def _voltage_lines(ax, t: np.ndarray, measured: np.ndarray,
                   voltages: dict[str, np.ndarray]) -> None:
    for name, v in _baselines_first(voltages):
        ax.plot(t, v, color=COLORS.get(name), label=name, **_style(name))
    ax.plot(t, measured, color="k", lw=1.0, label="measured", zorder=3)


def fit_figure(trace, path: Path, title: str = "", zoom_s: float = 600.0) -> Path:
    """Measured vs simulated voltage over the record, a zoom, and the error (Fig. 7–10)."""
    seg = trace.segment
    t = (seg.time_s - seg.time_s[0]) / 3600.0
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), constrained_layout=True)
    ax = axes[0]
    _voltage_lines(ax, t, seg.voltage_v, trace.voltage)
    ax.set(ylabel="voltage / V", xlabel="time / h")
    ax.set_title(textwrap.fill(title or seg.name, 110), fontsize=10)
    ax.legend(loc="lower left", ncol=5, fontsize=8)
    k0 = int(np.argmax(np.abs(seg.current_a)))
    lo = max(0, k0 - int(zoom_s / 2 / max(np.median(np.diff(seg.time_s)), 1e-9)))
    hi = min(len(t), lo + int(zoom_s / max(np.median(np.diff(seg.time_s)), 1e-9)))
    ax = axes[1]
    _voltage_lines(ax, t[lo:hi] * 60, seg.voltage_v[lo:hi],
                   {k: v[lo:hi] for k, v in trace.voltage.items()})
    ax.set(ylabel="voltage / V", xlabel="time / min", title="zoom around the largest current")
    ax = axes[2]
    for name, v in _baselines_first(trace.voltage):
        ax.plot(t, 1e3 * (v - seg.voltage_v), color=COLORS.get(name), label=name,
                **_style(name))
    errs = np.concatenate([1e3 * (v - seg.voltage_v) for v in trace.voltage.values()])
    lo, hi = np.percentile(errs, [0.5, 99.5])
    span = max(hi - lo, 1.0)
    ax.set(ylabel="model − measured / mV", xlabel="time / h",
           ylim=(lo - 0.3 * span, hi + 0.3 * span),
           title="error (axis clipped to the central 99 % of samples)")
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(loc="lower left", ncol=5, fontsize=8)
    return save_figure(fig, path)


def validity_figure(model: LmnModel, path: Path) -> Path:
    """Validity functions Φ_j over SoC (other partition inputs at their centre)."""
    soc = np.linspace(0, 1, 401)
    raw = np.tile(model.partition_center, (soc.size, 1))
    if "soc" in model.partition_variables:
        raw[:, model.partition_variables.index("soc")] = soc
    gates = [("discharge", 2), ("charge", 1)] if model.gating_mode == "current_sign" else [
        ("", 2)]
    fig, axes = plt.subplots(len(gates), 1, figsize=(8, 3.2 * len(gates)), squeeze=False,
                             constrained_layout=True)
    for ax, (label, code) in zip(axes[:, 0], gates, strict=True):
        Phi = model.validities(model.normalise(raw), np.full(soc.size, code))
        for j in range(Phi.shape[1]):
            if Phi[:, j].max() > 1e-3:
                ax.plot(100 * soc, Phi[:, j], label=f"LM {j + 1}")
        ax.set(xlabel="SoC / %", ylabel="validity Φ", ylim=(-0.02, 1.02),
               title=f"validity functions {label}".strip())
        ax.legend(fontsize=7, ncol=4)
    return save_figure(fig, path)


def curve_figure(curve: list[dict], path: Path, chosen: int) -> Path:
    """One-step and free-run RMSE against the number of local models; where each temperature
    region grew on its own (curve entries with temperature_region_c), one set of lines per
    region, its validation over that region's records."""
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    regions = [c.get("temperature_region_c") for c in curve]
    for n, region in enumerate(dict.fromkeys(regions)):
        part = [c for c, r in zip(curve, regions, strict=True) if r == region]
        _curve_lines(ax, part, "" if region is None else f"{region:.0f} °C region growing: ", n)
    ax.axvline(chosen, color="k", ls="--", lw=0.8, label=f"chosen M = {chosen}")
    ax.set(xlabel="number of local models M", ylabel="RMSE / mV (log scale)", yscale="log")
    plain = FuncFormatter(lambda v, _pos: f"{v:g}")
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.legend(fontsize=7 if len(set(regions)) > 1 else None)
    return save_figure(fig, path)


def _curve_lines(ax: plt.Axes, curve: list[dict], prefix: str, n: int) -> None:
    """The lines of one part of the curve (all of it, or one temperature region's growth)."""
    m = [c["local_models"] for c in curve]
    ls = ("-", "--", ":", "-.")[n % 4]

    def values(key: str) -> np.ndarray:
        return np.array([np.nan if c.get(key) is None else c[key] for c in curve], dtype=float)

    one, free = values("one_step_rmse_mv"), values("train_freerun_rmse_mv")
    if np.allclose(one, free, rtol=1e-6, equal_nan=True):
        ax.plot(m, free, "s" + ls, color="C1", label=f"{prefix}training (all records): one-step "
                                                     "= free-run (no output feedback)")
    else:
        ax.plot(m, one, "o" + ls, color="C0", label=f"{prefix}one-step (training)")
        ax.plot(m, free, "s" + ls, color="C1", label=f"{prefix}free-run (training)")
    val = values("validation_freerun_rmse_mv")
    if np.isfinite(val).any():
        ax.plot(m, val, "^" + ls, color="C2",
                label=f"{prefix}free-run (validation{', its own records' if prefix else ''})")
    by_level = values("validation_level_score_mv")
    if np.isfinite(by_level).any():
        ax.plot(m, by_level, "v" + ls, color="C3", label=f"{prefix}free-run (validation), "
                "geometric mean over the temperature levels: picks M")


def record_figure(rec: Record, path: Path, soc: np.ndarray | None = None) -> Path:
    """Current, voltage and SoC of a record over time (Fig. 6)."""
    return records_figure([(rec, soc)], path)


def records_figure(records: list[tuple[Record, np.ndarray | None]], path: Path,
                   soc_note: str = "") -> Path:
    """Current, voltage and (where known) SoC of one or more records over time from each
    record's start, in one figure; soc: a SoC series per record or None (then soc_ref);
    soc_note: the SoC panel's title (which capacity the SoC counts)."""
    socs = [rec.soc_ref if soc is None else soc for rec, soc in records]
    n = 3 if any(s is not None for s in socs) else 2
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.4 * n), sharex=True, constrained_layout=True)
    one = len(records) == 1
    for (rec, _), soc in zip(records, socs, strict=True):
        t = (rec.time_s - rec.time_s[0]) / 3600.0
        axes[0].plot(t, rec.current_a, lw=0.5, label=rec.name)
        axes[1].plot(t, rec.voltage_v, lw=0.5, color="k" if one else None)
        if soc is not None:
            axes[2].plot(t, 100 * soc, color="tab:green" if one else None)
    title = records[0][0].name if one else f"{len(records)} records"
    axes[0].set(ylabel="current / A", title=f"{title} (current > 0 charges)")
    if not one:
        axes[0].legend(fontsize=7, loc="best")
    axes[1].set(ylabel="voltage / V")
    if n == 3:
        axes[2].set(ylabel="SoC / %")
        axes[2].set_title(soc_note, fontsize=9)
    axes[-1].set(xlabel="time from the record's start / h")
    return save_figure(fig, path)


def write_local_model_table(model: LmnModel, path: Path) -> Path:
    """CSV of each local model's operating point, resistances (mΩ) and time constants (s)."""
    import csv

    from lmncell.evaluation.interpret import local_model_table

    rows = local_model_table(model)
    with replaced_whole(path) as part, open(part, "w", newline="", encoding="utf-8") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0]))
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (" ".join(f"{x:.1f}" for x in v) if isinstance(v, list) else
                             " ".join(f"{a}s:{b:.2f}" for a, b in v.items())
                             if isinstance(v, dict) else v) for k, v in r.items()})
    return path


def evaluation_figures(model: LmnModel, traces: list, out: Path,
                       titles: list[str] | None = None) -> list[Path]:
    """`lmncell evaluate MODEL --plot`: a fit figure per trace (captioned by titles, default
    the segment's name), the local-model table, validity and the training curve."""
    titles = titles or [t.segment.name for t in traces]
    files = [fit_figure(t, out / f"fit_{safe_name(t.segment.name)}.png", title)
             for t, title in zip(traces, titles, strict=True)]
    files.append(write_local_model_table(model, out / "local_models.csv"))
    files.append(validity_figure(model, out / "validity.png"))
    training = model.extra.get("training", {})
    if training.get("curve"):
        files.append(curve_figure(training["curve"], out / "local_models_curve.png",
                                  model.n_local_models))
    return files


def _short_record(name: str) -> str:
    """A record's file name for an axis: no extension, no leading date stamp such as
    '03-20-17_01.43_', at most 26 characters."""
    stem = name.split(".mat")[0].split(".csv")[0]
    return re.sub(r"^\d\d-\d\d-\d\d_\d\d\.\d\d_", "", stem)[:26]


def _grouped_bars(ax, records: list[str], series: dict[str, list[float]]) -> None:
    """One group of bars per record, one bar per series (its value printed on it)."""
    x = np.arange(len(records))
    width = 0.8 / max(len(series), 1)
    for k, (name, values) in enumerate(series.items()):
        bars = ax.bar(x + (k - (len(series) - 1) / 2) * width, values, width,
                      color=COLORS.get(name), label=name,
                      alpha=1.0 if name in ("lmn", "ekf") else 0.6)
        ax.bar_label(bars, fmt="%.1f", fontsize=7)
    ax.set_xticks(x)
    ax.set_xticklabels([_short_record(r) for r in records], fontsize=7, rotation=15)


def _finish_folds_figure(fig, axes: np.ndarray, path: Path, caption: str, n: int) -> Path:
    """One legend under the panels, the caption (wrapped) above them; saved and closed."""
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=n, fontsize=8)
    fig.suptitle(textwrap.fill(caption, 130), fontsize=9, x=0.01, ha="left")
    return save_figure(fig, path)


def folds_figure(folds: list[tuple[str, dict[str, dict[str, tuple[float, float]]]]],
                 path: Path, caption: str) -> Path:
    """Leave-one-out results as bars. folds: per held-out record, {temperature input ("cell"
    or "ambient"): {model: (20–80 % SoC RMSE, whole-record RMSE) in mV}}. One row of panels
    per temperature input, the window left and the whole record right, the models side by side
    per record; the caption (wrapped) says what was run. ValueError for no folds."""
    if not folds:
        raise ValueError("folds_figure: no folds to draw")
    modes = list(dict.fromkeys(mode for _, row in folds for mode in row))
    names = list(dict.fromkeys(m for _, row in folds for by in row.values() for m in by))
    records = [record for record, _ in folds]
    fig, axes = plt.subplots(len(modes), 2, squeeze=False, constrained_layout=True,
                             figsize=(max(8.0, 2.4 * len(folds) + 2), 3.2 * len(modes) + 1.2))
    for r, mode in enumerate(modes):
        for panel, label in enumerate(("20–80 % SoC", "whole record")):
            series = {name: [row.get(mode, {}).get(name, (np.nan, np.nan))[panel]
                             for _, row in folds] for name in names}
            _grouped_bars(axes[r, panel], records, series)
            axes[r, panel].set(ylabel="RMSE / mV", title=f"{label}, {mode} temperature")
    return _finish_folds_figure(fig, axes, path, caption, len(names))


def observer_folds_figure(folds: list[tuple[str, dict[str, tuple[float, float]]]],
                          path: Path, caption: str,
                          consistency_target_pct: float = 5.0) -> Path:
    """Observer leave-one-out results as bars. folds: per held-out record, {observer: (SoC
    RMSE %, share of samples outside ±3σ %)}: the RMSE left, the share right with its target
    line. ValueError for no folds."""
    if not folds:
        raise ValueError("observer_folds_figure: no folds to draw")
    kinds = list(dict.fromkeys(k for _, row in folds for k in row))
    records = [record for record, _ in folds]
    fig, axes = plt.subplots(1, 2, squeeze=False, constrained_layout=True,
                             figsize=(max(8.0, 2.2 * len(folds) + 2), 4.6))
    for panel, label in enumerate(("SoC RMSE / %", "samples outside ±3σ / %")):
        series = {k: [row.get(k, (np.nan, np.nan))[panel] for _, row in folds] for k in kinds}
        _grouped_bars(axes[0, panel], records, series)
        axes[0, panel].set(ylabel=label)
    axes[0, 1].axhline(consistency_target_pct, color="k", lw=0.8, ls="--")
    axes[0, 1].text(0.99, consistency_target_pct, f"target ≤ {consistency_target_pct:g} %",
                    transform=axes[0, 1].get_yaxis_transform(), ha="right", va="bottom",
                    fontsize=8)
    return _finish_folds_figure(fig, axes, path, caption, len(kinds))
