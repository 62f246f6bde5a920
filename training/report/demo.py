"""`lmncell demo`: the paper's story on the shipped A123 data, from measurements to a validated FMU.

Training: the dynamic tests at −15, −5, 5 and 45 °C with the 25 °C C/30 OCV test, as the README
advises (temperature through an Arrhenius gain and, with four training temperatures, temperature
terms of degree 2; every other setting the default of `lmncell train`). Validation: the 25 °C
test, a temperature the training never saw. Then the pythonfmu FMU, the WLTC and US06 scenarios
through fmpy, FMU against pipeline, the SoC observers on the unseen record from a wrong start
under load, and report.html with its figures.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from lmncell.data.dataset import record_to_segments
from lmncell.data.readers import read_record
from lmncell.data.records import Record
from lmncell.data.soc import (
    capacity_from_discharge,
    coulomb_count,
    current_scaled_to_counters,
    ocv_from_slow_tests,
)
from lmncell.evaluation.evaluate import evaluate_model, evaluate_records
from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline
from lmncell.evaluation.interpret import (
    DEPLETION_HEADS,
    MIN_VALIDITY_SHOWN,
    depletion_shown,
    local_model_table,
)
from lmncell.evaluation.observe import observer_figure, observer_runs, soc_metrics
from lmncell.identification.train import train_files
from lmncell.report.html import Report
from lmncell.report.jsontext import json_text
from lmncell.report.readme import drift_sentence
from lmncell.runtime.model import LmnModel, load_model, write_text_whole
from lmncell.scenarios.drive import load_vehicle, plot_cycle, run_cycle
from lmncell.scenarios.traces import data_dir

A123 = "a123_plett"
TRAIN = ["A123_DYN_10_N15_s1.csv.gz", "A123_DYN_30_N05_s1.csv.gz", "A123_DYN_45_P05_s1.csv.gz",
         "A123_DYN_50_P45_s1.csv.gz"]
OCV_TESTS = ["A123_OCV_P25_S1.csv.gz", "A123_OCV_P25_S3.csv.gz"]   # C/30 down and up, 25 °C
SHOWN_TRAINING = "A123_DYN_45_P05_s1.csv.gz"   # the training record drawn in the report (5 °C)
VALIDATE = "A123_DYN_50_P25_s1.csv.gz"
CHARGE_25C = "A123_DYN_50_P25_s3.csv.gz"   # the same test's CC/CV charge from empty (25 °C)
EMPTY_25C = "A123_DYN_50_P25_s2.csv.gz"
OBSERVER_START, OBSERVER_GUESS = 0.6, 0.3


def _say(msg: str) -> None:
    print(f"[demo] {msg}", flush=True)


def ocv_figure(out: Path) -> tuple[Path, float]:
    """Fig. 1: charge and discharge OCV branches of the 25 °C C/30 test."""
    from lmncell.report.plots import plt, save_figure

    d = data_dir() / A123 / "ocv"
    s1, s2, s3 = (read_record(d / f"A123_OCV_P25_S{k}.csv.gz") for k in (1, 2, 3))
    cap = capacity_from_discharge(s1, s2)
    curve = ocv_from_slow_tests(s1, s3, cap)
    fig, ax = plt.subplots(figsize=(8, 4.5), constrained_layout=True)
    ax.plot(100 * curve.soc, curve.discharge_v, label="discharge (C/30)")
    ax.plot(100 * curve.soc, curve.charge_v, label="charge (C/30)")
    ax.plot(100 * curve.soc, curve.mean_v, "k--", lw=0.8, label="mean")
    ax.set(xlabel="SoC / %", ylabel="voltage / V", ylim=(3.0, 3.5),
           title="A123 LFP: OCV hysteresis at 25 °C")
    ax.legend()
    path = out / "fig01_ocv_hysteresis.png"
    save_figure(fig, path)
    mid = (curve.soc > 0.2) & (curve.soc < 0.8)
    return path, float(2e3 * np.median(curve.hysteresis_v[mid]))


def run_demo(out: Path) -> Path:
    """Train, evaluate, build the FMU, drive it, check it, write the report; returns its path."""
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    dyn = data_dir() / A123 / "dyn"
    rep = Report("LMNCell demo: a local model network of an A123 LFP cell", out)
    val_rec, empty = read_record(dyn / VALIDATE), read_record(dyn / EMPTY_25C)
    capacity = capacity_from_discharge(val_rec, empty)
    _say(f"capacity from the 25 °C full discharge (s1 + s2): {capacity:.4f} Ah")
    _data_section(rep, dyn, capacity, out)
    model_path = _train(dyn, capacity, out)
    model = load_model(model_path)
    _identification_section(rep, model, out)
    val = _accuracy_section(rep, model, dyn, out)[-1]       # the unseen record's row
    drift = (val["soc_drift_pct"], *_counter_current_figures(model, val_rec))
    rep.text(drift_sentence(*drift))
    _charge_section(rep, model, dyn / CHARGE_25C, out)
    soc_figures, outside_figures = _observer_section(rep, model, val_rec, capacity, out)
    fmu, check = _fmu_section(rep, model_path, dyn / VALIDATE, out)
    cycles = _cycles_section(rep, fmu, out)
    headline = {
        "local_models": model.n_local_models,
        "validation_record": val["record"],
        "validation_rmse_mv": {k: v["rmse_mv"] for k, v in val.items() if isinstance(v, dict)},
        "validation_window_rmse_mv": {k: v["window_rmse_mv"] for k, v in val.items()
                                      if isinstance(v, dict)},
        "validation_soc_drift_pct": drift[0],
        "validation_counter_current_factor": drift[1],
        "validation_rmse_mv_counter_current": drift[2],
        "fmu_max_dv_v": check["max_dv_v"], "cycles": cycles,
        "soc_rmse_pct_from_0_6_with_0_3": soc_figures,
        "soc_outside_3sigma_pct": outside_figures,
        "seconds": time.perf_counter() - t0,
    }
    write_text_whole(out / "summary.json", json_text(headline))
    return _finish(rep, headline, model_path, fmu)


def _data_section(rep: Report, dyn: Path, capacity: float, out: Path) -> None:
    """The data: what was trained and validated on, the OCV hysteresis, one training record."""
    from lmncell.report import plots

    rep.section("Data")
    rep.text("A123 26650 LFP cell, dynamic tests of G. L. Plett (Battery Management Systems, "
             "Vol. I, 2015; ESC toolbox data). Training: the tests at −15, −5, 5 and 45 °C "
             "with the 25 °C C/30 OCV test; "
             "validation: the 25 °C test, which the training never saw. Current > 0 charges; "
             f"capacity {capacity:.4f} Ah from the 25 °C discharge to 2.0 V (s1 + s2).")
    fig1, hyst_mv = ocv_figure(out)
    rep.figure(fig1, f"Fig. 1 — the OCV of LFP depends on the direction of the current: the "
                     f"charge branch lies {hyst_mv:.0f} mV above the discharge branch between "
                     "20 and 80 % SoC (median). Whether the model carries a hysteresis state is "
                     "decided in the identification (below).")
    train_rec = read_record(dyn / SHOWN_TRAINING)
    soc_train = coulomb_count(train_rec, 1.0, capacity)
    rep.figure(plots.record_figure(train_rec, out / "fig06_training_record.png", soc_train),
               "Fig. 6 — one training record (5 °C): repeated UDDS-derived blocks with rests "
               f"walk the cell from full to {100 * float(soc_train.min()):.0f} % SoC "
               f"(coulomb-counted with {capacity:.3f} Ah).")


def _train(dyn: Path, capacity: float, out: Path) -> Path:
    """Train the LMN and its baselines on the training records; returns the model file."""
    _say("training the LMN and the baselines (ARX, 2RC, 2RC with hysteresis) …")
    model_path = out / "a123_lmn.json"
    ocv = [str(dyn.parent / "ocv" / f) for f in OCV_TESTS]
    train_files([dyn / f for f in TRAIN], model_path, capacity_ah=capacity, soc0=1.0,
                baselines=True, progress=lambda m: _say(m), ocv_tests=ocv)
    return model_path


def _identification_section(rep: Report, model: LmnModel, out: Path) -> None:
    """What the identification chose: hysteresis, temperature, M, validities, local models."""
    from lmncell.report import plots

    tr = model.extra["training"]
    info = tr["info"]
    gamma = info.get("hysteresis_gamma")
    rep.section("Identification")
    rep.text("Hysteresis: " + ("off — the OCV pre-fit with a hysteresis state did not cut its "
                               "error by 3 %, so the model has none: its training records only "
                               "discharge, and the local models' offsets carry the discharge "
                               "branch (Fig. 1; the charge record below shows what that misses)."
                               if gamma is None else
                               f"on, rate γ = {gamma:g} (chosen by the OCV pre-fit)."))
    rep.text(f"Temperature: Arrhenius gain E = {info.get('arrhenius_k')} K on the current "
             f"regressors; temperature terms of degree {info.get('temperature_terms', 0)} "
             "(every local model's gains and offset also vary with dT = (T − 25 °C)/10 K), "
             "which interpolate between the training temperatures.")
    rep.figure(plots.curve_figure(tr["curve"], out / "fig_local_models_curve.png",
                                  model.n_local_models),
               "Error against the number of local models (each sample weighted as in the "
               "fit): the free-run validation error"
               + (", the geometric mean of each training temperature's,"
                  if info.get("stop") == "validation_level_score_mv" else "")
               + f" chose M = {model.n_local_models}. "
               + _refinement_text(info.get("output_error")))
    rep.figure(plots.validity_figure(model, out / "fig_validity.png"),
               "Validity functions over SoC (temperature at the middle of the trained range): "
               "where each local linear model is in charge.")
    _local_model_table(rep, model)


def _refinement_text(refinement: dict | None) -> str:
    """One sentence on the output-error refinement (training RMSE before and after)."""
    if refinement is None:
        return "No output-error refinement was run."
    if refinement["accepted"]:
        return ("Then all local models were refined on the free-run (output) error: "
                f"training RMSE {refinement['train_rmse_before_mv']:.2f} → "
                f"{refinement['train_rmse_after_mv']:.2f} mV.")
    return ("The output-error refinement of all local models was tried and not kept "
            f"(training RMSE {refinement['train_rmse_before_mv']:.2f} → "
            f"{refinement['train_rmse_after_mv']:.2f} mV, not better).")


def _local_model_table(rep: Report, model: LmnModel) -> None:
    """The local models at the reference temperature, as `lmncell explain` prints them."""
    table = [{**row, **{key: depletion_shown(row, key) for key in DEPLETION_HEADS
                        if key in row}}
             for row in local_model_table(model, model.reference_temperature_c)]
    cols = [("local_model", "LM", ""), *[(v, v, ".2f") for v in model.partition_variables],
            ("r0_mohm", "R0 / mΩ", ".1f"), ("r_static_mohm", "R static / mΩ", ".1f")]
    ladder = "rc_mohm_by_tau_s" in table[0]
    if ladder:
        for row in table:
            rc = [(k, v) for k, v in row["rc_mohm_by_tau_s"].items() if k != "0"]
            row["rc_text"] = ", ".join(f"{k} s: {v:.1f}" for k, v in rc)
        cols.append(("rc_text", "RC elements: R / mΩ at τ", ""))
    elif any(row["time_constants_s"] for row in table):
        cols.append(("time_constants_s", "time constants / s", ".1f"))
    optional = [("hysteresis_mv", "hysteresis H / mV", ".1f"),
                ("r_depletion_mohm", "depletion R_d at SoC 0.1 / mΩ", ".2f"),
                ("r_depletion_at_soc_mohm", "R_d at its SoC / mΩ", ".2f"),
                ("r_depletion_fast_mohm", "fast depletion R_d2 at SoC 0.1 / mΩ", ".2f"),
                ("r_depletion_fast_at_soc_mohm", "R_d2 at its SoC / mΩ", ".2f"),
                ("ocv_offset_mv", "OCV offset / mV", ".1f")]
    cols += [c for c in optional if c[0] in table[0]]
    ref = f"{model.reference_temperature_c:g}"
    rep.table(table, cols, f"Local models (`lmncell explain MODEL --temperature {ref}` prints "
                           "the same; without --temperature it states each at its own "
                           "temperature centre): operating "
                           "point (validity-weighted centre), instantaneous resistance R0, "
                           "static resistance (R0 plus all RC elements), the RC elements at the "
                           "model's fixed time constants (the filters of the structure), the "
                           "depletion resistance R_d (its regressor grows as (0.1/SoC)⁴ near "
                           "empty: the collapse before cut-off; at SoC 0.1, – where the local "
                           f"model has under {100 * MIN_VALIDITY_SHOWN:g} % validity there, and at "
                           "its own SoC, which a steady current sees there beside R static) "
                           "and the local OCV offset, at the "
                           f"reference temperature ({ref} °C)"
              + (" (resistances × the Arrhenius factor elsewhere)" if model.arrhenius_k else "")
              + ". " + ("Identified as RC ladders: every R, R_d and the hysteresis voltage are "
                        "constrained ≥ 0 (setting local_model_form). " if ladder else "")
              + "SoC as a fraction, temperature in °C. Current > 0 charges, so a resistance is "
                "u − OCV per ampere.")


def _accuracy_section(rep: Report, model: LmnModel, dyn: Path, out: Path) -> list[dict]:
    """Free-run fits and the error table on the training records and the unseen one; returns
    evaluate_model's rows (the unseen record last)."""
    from lmncell.report import plots

    _say("evaluating free-run on the training records and on the unseen 25 °C record …")
    traces, rows = evaluate_model(model, [dyn / f for f in TRAIN] + [dyn / VALIDATE], soc0=1.0)
    for t in traces[:-1]:
        if t.segment.name.startswith(SHOWN_TRAINING.split(".")[0]):
            rep.figure(plots.fit_figure(t, out / "fig07_08_training_fit.png",
                                        f"training record {t.segment.name}"),
                       "Fig. 7/8 — measured and simulated (free-run) voltage on a training "
                       "record, a zoom around the largest current, and the error.")
    rep.figure(plots.fit_figure(traces[-1], out / "fig09_10_validation_fit.png",
                                f"validation record {traces[-1].segment.name} (25 °C, unseen)"),
               "Fig. 9/10 — the unseen 25 °C record simulated free-run from full charge: "
               "the LMN against the baselines.")
    rep.section("Accuracy (free-run, mV)")
    flat = []
    for r, t in zip(rows, traces, strict=True):
        role = "validation (unseen)" if r["record"].startswith(VALIDATE) else "training"
        temp = t.segment.temperature_c
        for name, m in r.items():
            if isinstance(m, dict):
                figures = {k: "–" if v is None else v for k, v in m.items()}
                flat.append({"record": r["record"], "data": role,
                             "temperature": "–" if temp is None else float(np.median(temp)),
                             "model": name, **figures})
    rep.table(flat, [("record", "record", ""), ("data", "data", ""),
                     ("temperature", "T / °C", ".0f"), ("model", "model", ""),
                     ("rmse_mv", "RMSE whole record", ".2f"),
                     ("window_rmse_mv", "RMSE 20–80 % SoC", ".2f"),
                     ("low_soc_rmse_mv", "RMSE below 10 % SoC", ".2f"),
                     ("high_soc_rmse_mv", "RMSE above 90 % SoC", ".2f"), ("mae_mv", "MAE", ".2f"),
                     ("max_mv", "max", ".1f")],
              "Free-run voltage error (mV) of the LMN and the baselines fitted on the same "
              "data, over the whole record (down to the end of discharge), inside the 20–80 % "
              "SoC window and at each end of the SoC range alone (– where a record does not "
              "reach it).")
    return rows


def _counter_current_figures(model: LmnModel, record: Record) -> tuple[float, dict[str, float]]:
    """The factor on the unseen record's logged current that meets the tester's counters, and
    each model's whole-record RMSE (mV) driven by the current so scaled (its SoC drift is in
    the record's evaluate row, soc_drift_pct)."""
    scaled, factor = current_scaled_to_counters(record)
    _, rows = evaluate_records(model, [(scaled, 1.0)])
    return factor, {k: v["rmse_mv"] for k, v in rows[0].items() if isinstance(v, dict)}


def _fmu_section(rep: Report, model_path: Path, record: Path, out: Path) -> tuple[Path, dict]:
    """Build the pythonfmu FMU (and the native one where a C compiler exists), check both
    against the pipeline on the unseen record; returns the pythonfmu FMU and its check."""
    _say("building the FMU …")
    from lmncell.fmu.pythonfmu_build import build_fmu

    fmu = build_fmu(model_path, out / "A123_LMNCell.fmu")
    check = compare_fmu_with_pipeline(model_path, fmu, record, soc0=1.0)
    _say(f"FMU vs pipeline on {check['record']}: max |Δu| = {check['max_dv_v']:.2e} V, "
         f"max |ΔSoC| = {check['max_dsoc']:.2e}")
    rep.section("FMU")
    rep.figure(_agreement_figure(check, out / "fig_fmu_vs_pipeline.png"),
               f"The FMU driven by fmpy with the 25 °C record's current against the pipeline: "
               f"largest difference {check['max_dv_v']:.1e} V in voltage and "
               f"{check['max_dsoc']:.1e} in SoC over {check['steps']} steps, i.e. "
               "floating-point round-off (the lower panel's scale is logarithmic; the tests "
               "require 1e-9 V).")
    native_note = _native(model_path, out, record)
    if native_note:
        rep.text(native_note)
    return fmu, check


def _cycles_section(rep: Report, fmu: Path, out: Path) -> dict:
    """WLTC and US06 through the FMU in the default vehicle; returns each cycle's figures."""
    vehicle = load_vehicle()
    cycles = {}
    for cyc in ("wltc", "us06"):
        _say(f"driving the FMU through {cyc.upper()} …")
        res = run_cycle(fmu, cyc, vehicle, repeat=1, soc0=0.8, temperature_c=25.0)
        cycles[cyc] = res.figures
        oor = res.figures["out_of_range_steps"]
        rep.figure(plot_cycle(res, out / f"fig_cycle_{cyc}.png"),
                   f"{cyc.upper()} through the FMU ({vehicle.name}, {vehicle.n_series}s"
                   f"{vehicle.n_parallel}p, 25 °C): {res.figures['pack_energy_kwh']:.2f} kWh, "
                   f"minimum cell voltage {res.figures['voltage_min_v']:.3f} V, SoC "
                   f"{100 * res.figures['soc_start']:.0f} → "
                   f"{100 * res.figures['soc_end']:.1f} %; "
                   + (f"{oor} steps left the trained range (red dots)." if oor else
                      "every step within the trained range."))
    return cycles


def _finish(rep: Report, headline: dict, model_path: Path, fmu: Path) -> Path:
    """The report's run note and lead summary, written; the headline printed."""
    whole, window = headline["validation_rmse_mv"], headline["validation_window_rmse_mv"]
    soc_figures = headline["soc_rmse_pct_from_0_6_with_0_3"]
    rep.section("Run")
    rep.text(f"Made by `lmncell demo` in {headline['seconds']:.0f} s; model file "
             f"{model_path.name}, FMU {fmu.name}, figures in this folder, numbers in "
             "summary.json.")
    rep.lead("Summary", "Unseen 25 °C record, free-run voltage RMSE over the whole record / "
             "inside 20–80 % SoC: " + "; ".join(
                 f"{k} {whole[k]:.2f} / {v:.2f} mV" for k, v in window.items())
             + ". SoC observers from a wrong start (RMSE after 10 min): "
             + ", ".join(f"{k} {v:.2f} %" for k, v in soc_figures.items())
             + f". FMU = pipeline within {headline['fmu_max_dv_v']:.1e} V.")
    path = rep.write()
    _say(f"report: {path.resolve()}")
    _say("unseen 25 °C record, free-run RMSE whole record / 20–80 % SoC: "
         + ", ".join(f"{k} {whole[k]:.2f} / {v:.2f} mV" for k, v in window.items())
         + f"; FMU = pipeline within {headline['fmu_max_dv_v']:.1e} V; "
           f"{headline['seconds']:.0f} s")
    return path


def _charge_section(rep: Report, model: LmnModel, path: Path, out: Path) -> None:
    """The discharge-trained model on the 25 °C charge record from empty (not trained)."""
    from lmncell.report import plots

    traces, rows = evaluate_model(model, [path], soc0=0.0)
    lmn = rows[0]["lmn"]
    rep.figure(plots.fit_figure(traces[0], out / "fig_charge_record.png",
                                f"charge record {traces[0].segment.name} (25 °C, from empty)"),
               "The same 25 °C test's charge from empty (CC/CV, not trained), free-run: "
               f"{lmn['window_rmse_mv']:.2f} mV in the 20–80 % SoC window, "
               f"{lmn['rmse_mv']:.2f} mV over the whole record. The training records only "
               "discharge, so the model knows the discharge side of the OCV (Fig. 1) alone. "
               "Trained with charge records beside the discharges (at one temperature at "
               "least, `--soc0` per file for records that start empty), the LMN follows the "
               "charge branch too: `examples/charge_and_discharge.py` measures it, leaving "
               "one test temperature out.")


def _observer_section(rep: Report, model: LmnModel, record: Record, capacity: float,
                      out: Path) -> tuple[dict, dict]:
    """SoC estimation on the unseen record: the three observers and coulomb counting started
    under load where the true SoC first reaches OBSERVER_START with the guess OBSERVER_GUESS.
    Returns the SoC RMSE after 10 minutes (%) of each, and the observers' share of samples
    whose truth lies outside their ±3σ band (%)."""
    _say("SoC observers (EKF, fuzzy, IMM) on the unseen 25 °C record from a wrong start …")
    seg = record_to_segments(record, model.sample_time_s, 1.0, capacity,
                             current_delay_s=model.current_delay_s)[0]
    runs = observer_runs(model, seg, ["ekf", "fuzzy", "imm"], OBSERVER_GUESS, OBSERVER_START)
    rows = [{"observer": r.name, **soc_metrics(r)} for r in runs]
    rep.section("SoC estimation")
    rep.figure(observer_figure(runs, out / "fig_soc_observers.png"),
               f"SoC observers on the unseen 25 °C record, started under load where the true "
               f"SoC first reaches {OBSERVER_START:.0%} with the estimate {OBSERVER_GUESS:.0%}: "
               "estimate with ±3σ band and error. The flat LFP plateau (about 30–90 % SoC) "
               "shows SoC only through the hysteresis-sized voltage differences; the "
               "observers correct where the OCV is steep and coulomb-count in between.")
    rep.table(rows, [("observer", "observer", ""), ("rmse_pct", "RMSE / %", ".2f"),
                     ("mae_pct", "MAE / %", ".2f"), ("max_pct", "max / %", ".1f"),
                     ("time_to_2pct_s", "within 2 % after / s", ".0f"),
                     ("outside_3sigma_share", "outside ±3σ (share)", ".2f"),
                     ("median_3sigma_pct", "median 3σ / %", ".1f")],
              "SoC error after the first 10 minutes against the reference (the tester's "
              "counters from the true start); coulomb counting from the same wrong start is "
              "the baseline; — in 'within 2 % after': still outside 2 % at the record's end.")
    figures = {r["observer"]: r["rmse_pct"] for r in rows}
    outside = {r["observer"]: 100 * r["outside_3sigma_share"] for r in rows
               if r["observer"] != "coulomb"}
    _say("SoC RMSE after 10 min: " + ", ".join(f"{k} {v:.2f} %" for k, v in figures.items())
         + "; outside ±3σ: " + ", ".join(f"{k} {v:.1f} %" for k, v in outside.items()))
    return figures, outside


def _native(model_path: Path, out: Path, record: Path) -> str:
    """Build the native FMU where a C compiler exists and check it against the pipeline."""
    from lmncell.fmu.native_build import NativeBuildError, build_native_fmu

    _say("building the native FMU (generated C) …")
    try:
        fmu = build_native_fmu(model_path, out / "A123_LMNCell_native.fmu")
    except NativeBuildError as exc:
        _say(f"native FMU skipped: {exc}")
        return f"Native FMU not built here: {exc}"
    check = compare_fmu_with_pipeline(model_path, fmu, record, soc0=1.0)
    _say(f"native FMU vs pipeline: max |Δu| = {check['max_dv_v']:.2e} V")
    return (f"The native FMU {fmu.name} (generated C, no Python needed by the importer) agrees "
            f"with the pipeline within {check['max_dv_v']:.1e} V and {check['max_dsoc']:.1e} "
            f"in SoC over the same {check['steps']} steps.")


def _agreement_figure(check: dict, path: Path) -> Path:
    from lmncell.report.plots import plt, save_figure

    t = (check["time_s"] - check["time_s"][0]) / 3600
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True, constrained_layout=True)
    ax[0].plot(t, check["pipeline_voltage_v"], "k", lw=0.8, label="pipeline")
    ax[0].plot(t, check["fmu_voltage_v"], "r:", lw=1.0, label="FMU (fmpy)")
    ax[0].set(ylabel="voltage / V")
    ax[0].legend()
    diff = np.abs(check["fmu_voltage_v"] - check["pipeline_voltage_v"])
    ax[1].semilogy(t, np.maximum(diff, 1e-18), ".", ms=1.5)
    ax[1].axhline(1e-9, color="r", ls="--", lw=0.8, label="tolerance of the tests, 1e-9 V")
    ax[1].set(ylabel="|FMU − pipeline| / V", xlabel="time / h", ylim=(1e-18, 1e-6))
    ax[1].legend(loc="upper right", fontsize=8)
    return save_figure(fig, path)
