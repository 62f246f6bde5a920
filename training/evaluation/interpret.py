"""What each local model says about the cell: resistances and time constants per regime."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
from lmncell.identification.ladder import (
    coefficient_row,
    filter_to_ladder,
    is_ladder,
    ladder_keys,
)
from lmncell.report.jsontext import json_text
from lmncell.runtime.model import LmnModel
from lmncell.runtime.observers import (
    EKF_ERROR_SCALE_BY_SOC,
    MIN_VOLTAGE_SIGMA_V,
    MODEL_ERROR_FACTOR,
)
from lmncell.runtime.step import arrhenius_gain


def leaf_centres(model: LmnModel, points: int = 21) -> np.ndarray:
    """(M, d) validity-weighted centre of each local model over the trained partition box."""
    d = len(model.partition_variables)
    axes = [np.linspace(-1.0, 1.0, points if d <= 2 else 7)] * d
    grid = np.array(list(itertools.product(*axes)))
    centres = []
    for code in (2, 1):
        Phi = model.validities(grid, np.full(grid.shape[0], code))
        centres.append((Phi.T @ grid) / np.maximum(Phi.sum(axis=0)[:, None], 1e-12))
    gate = np.array([g == "charge" for g in model.leaf_gates])
    z = np.where(gate[:, None], centres[1], centres[0])
    return z * model.partition_scale + model.partition_center


def local_model_table(model: LmnModel, temperature_c: float | None = None) -> list[dict]:
    """Per local model: operating point, instantaneous and static resistance (mΩ), and either
    its RC ladder (feedback-free models: R per time constant, hysteresis and OCV offset in mV,
    at temperature_c, default: the local model's own centre or the reference temperature) or the
    time constants (s) of its real stable poles (ARX models). Current > 0 charges; a resistance
    is (u − OCV)/i."""
    na, cols = model.output_lags, model.columns()
    centres = leaf_centres(model)
    rows = []
    for j, th in enumerate(model.theta):
        point = dict(zip(model.partition_variables, map(float, centres[j]), strict=True))
        row = {"local_model": j + 1, "gate": model.leaf_gates[j], **point}
        if na == 0 and model.filters:
            t = temperature_c if temperature_c is not None else point.get(
                "temperature", model.reference_temperature_c)
            row["temperature_c"] = float(t)
            row.update(ladder_parameters(model, th, float(t)))
            row.update(_depletion_at_soc(model, row))
        else:
            row.update(_arx_row(model, th, cols))
        rows.append(row)
    return rows


def _depletion_at_soc(model: LmnModel, row: dict) -> dict:
    """The depletion resistances at the local model's own SoC (mΩ; R_d·(0.1/SoC)^p, which a
    steady current sees there beside R static), where the model has the regressor and the
    partition the SoC: r_depletion_at_soc_mohm (and r_depletion_fast_at_soc_mohm); and the
    local model's validity at SoC 0.1, its other partition inputs at its centre
    (validity_at_soc_0_1, 0…1: where it is near 0, R_d is a coefficient the local model's
    data never reach)."""
    if model.depletion is None or "soc" not in row:
        return {}
    factor = model.depletion.factor(float(row["soc"]))
    out = {f"{key[:-5]}_at_soc_mohm": _clean(row[key] * factor)
           for key in ("r_depletion_mohm", "r_depletion_fast_mohm") if key in row}
    point = np.array([[0.1 if v == "soc" else float(row[v])
                       for v in model.partition_variables]])
    code = np.array([1 if row["gate"] == "charge" else 2])
    phi = model.validities(model.normalise(point), code)[0, row["local_model"] - 1]
    return {**out, "validity_at_soc_0_1": float(phi)}


# explain's and the report's tables show R_d at SoC 0.1 as "–" for a local model whose
# validity there is below this: no data of its own reach that SoC, and its coefficient,
# scaled up by (SoC/0.1)^p from where it acts, reads tens of Ω
MIN_VALIDITY_SHOWN = 0.01


def depletion_shown(row: dict, key: str) -> float | str:
    """A depletion column of a local_model_table row for display: "–" for the resistance at
    SoC 0.1 of a local model that is not valid there (MIN_VALIDITY_SHOWN)."""
    if key in ("r_depletion_mohm", "r_depletion_fast_mohm") and \
            row.get("validity_at_soc_0_1", 1.0) < MIN_VALIDITY_SHOWN:
        return "–"
    return row[key]


def _arx_row(model: LmnModel, th: np.ndarray, cols: list[str]) -> dict:
    """Resistances, pole time constants and hysteresis of a local model with output feedback."""
    na = model.output_lags
    cur = [k for k, c in enumerate(cols) if c.startswith("i(k")]
    a = th[:na]
    dc = 1.0 - float(a.sum())
    poles = np.roots(np.concatenate([[1.0], -a])) if na else np.zeros(0)
    taus = sorted(float(-model.sample_time_s / np.log(p.real)) for p in poles
                  if abs(p.imag) < 1e-9 and 0 < p.real < 1)
    row = {"r0_mohm": 1e3 * float(th[cur[0]]),
           "r_static_mohm": 1e3 * float(th[cur].sum()) / dc if abs(dc) > 1e-9 else np.inf,
           "time_constants_s": taus,
           "max_pole": float(np.abs(poles).max()) if poles.size else 0.0}
    if "h(k)" in cols:
        g = th[cols.index("h(k)")]
        row["hysteresis_mv"] = 1e3 * float(g) / dc if abs(dc) > 1e-9 else np.inf
    return row


def ladder_parameters(model: LmnModel, theta: np.ndarray, temperature_c: float) -> dict:
    """A feedback-free local model as an RC ladder at a temperature:
    u − OCV = R0·i + Σ_τ R_τ·LP_τ(i) + H·h + R_d·d (+ R_d2·d2) + U_off (+ the current lags'
    small correction; d the depletion regressor, R_d its resistance at SoC 0.1, d2 and R_d2
    the fast one's where the model has it).

    The filter coefficients map onto the ladder by ladder.filter_to_ladder (time constants below
    the sample time join R0, with the current lags); the Arrhenius gain g(T) scales every
    resistance. Returns R0, the RC elements (mΩ by τ in s, key
    "0" = R0 as well), the static resistance R0 + Σ R_τ, H and U_off (mV), R_d and R_d2 (mΩ),
    and whether every R, R_d, R_d2 and H is ≥ 0 (`rc_positive`)."""
    c = {src: float(coefficient_row(model, src, temperature_c) @ theta)
         for src in model._plain_columns()}
    g = float(arrhenius_gain(np.array([temperature_c]), model.arrhenius_k, 1,
                             model.reference_temperature_c, model.activation_t0_k)[0])
    a = filter_to_ladder(list(model.filters), model.sample_time_s)
    gf = np.array([c[f"v{f + 1}(k)"] for f in range(len(model.filters))])
    r0 = sum(v for k, v in c.items() if k.startswith("i(k")) + float(a[0] @ gf)
    rc = dict(zip(ladder_keys(model.filters, model.sample_time_s), (a[1:] @ gf).tolist(),
                  strict=True))
    ladder = {"0": _clean(1e3 * g * r0),
              **{f"{k:g}": _clean(1e3 * g * v) for k, v in sorted(rc.items())}}
    row: dict[str, Any] = {"r0_mohm": ladder["0"], "rc_mohm_by_tau_s": ladder,
           "r_static_mohm": float(sum(ladder.values())),
           "time_constants_s": [float(k) for k in sorted(rc)]}
    if "h(k)" in c:
        row["hysteresis_mv"] = _clean(1e3 * c["h(k)"])
    if "d(k)" in c:
        row["r_depletion_mohm"] = _clean(1e3 * g * c["d(k)"])
    if "d2(k)" in c:
        row["r_depletion_fast_mohm"] = _clean(1e3 * g * c["d2(k)"])
    if "1" in c:
        row["ocv_offset_mv"] = 1e3 * c["1"]
    row["rc_positive"] = bool(min(ladder.values()) >= 0.0 and row.get("hysteresis_mv", 0.0) >= 0.0
                              and row.get("r_depletion_mohm", 0.0) >= 0.0
                              and row.get("r_depletion_fast_mohm", 0.0) >= 0.0)
    return row


# mΩ or mV: |values| below this are round-off of the constrained solver and, with temperature
# terms, of the constraint grid (a quadratic in T held ≥ 0 at 1 K steps dips by < 1 µΩ between)
ROUND_OFF = 1e-3


def _clean(value: float) -> float:
    """The value, or exactly 0.0 where it is round-off around 0 (a constraint at its bound)."""
    return 0.0 if abs(value) < ROUND_OFF else value


DEPLETION_HEADS = {   # explain_text's depletion columns: R_d at SoC 0.1, and at the LM's SoC
    "r_depletion_mohm": "R_dep@0.1", "r_depletion_at_soc_mohm": "R_dep@SoC",
    "r_depletion_fast_mohm": "R_dep2@0.1", "r_depletion_fast_at_soc_mohm": "R_dep2@SoC"}


def explain_text(model: LmnModel, temperature_c: float | None = None) -> str:
    """The table of `lmncell explain`: every local model as the cell it describes."""
    rows = local_model_table(model, temperature_c)
    lines = _explain_head(model, rows)
    part = model.partition_variables
    if "rc_mohm_by_tau_s" in rows[0]:
        head, body = _ladder_table(rows, part)
    else:
        head = ["LM", "gate", *part, "R0", "R static", "time constants/s", "max pole"]
        body = [[str(r["local_model"]), r["gate"], *[f"{r[v]:.2f}" for v in part],
                 f"{r['r0_mohm']:.2f}", f"{r['r_static_mohm']:.2f}",
                 " ".join(f"{t:.1f}" for t in r["time_constants_s"]) or "-",
                 f"{r['max_pole']:.4f}"] for r in rows]
    widths = [max(len(h), *(len(b[k]) for b in body)) for k, h in enumerate(head)]
    lines.append("  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True)))
    lines += ["  ".join(c.rjust(w) for c, w in zip(b, widths, strict=True)) for b in body]
    lines += _training_error_lines(model)
    return "\n".join(lines)


def _explain_head(model: LmnModel, rows: list[dict[str, Any]]) -> list[str]:
    """The lines above explain's table: the model's form, its inputs' effects and units."""
    form = "RC ladder"
    if model.output_lags or not model.filters:
        form = f"ARX with {model.output_lags} output lags (time constants from its poles)"
    elif not is_ladder(model.filters, model.sample_time_s, 0):
        form = "filter terms that are not a chain (RC elements may be negative)"
    lines = [f"{model.n_local_models} local model(s), {form}; partition: "
             f"{', '.join(model.partition_variables)}; hysteresis: "
             + ("off" if model.hysteresis_gamma is None
                else f"γ = {model.hysteresis_gamma:g}")
             + _temperature_text(model)
             + ("" if not model.current_delay_s
                else f"; current delayed by {model.current_delay_s:g} s (the voltage "
                     "channel's lag)"),
             "resistances in mΩ, voltages in mV; current > 0 charges"]
    if model.depletion is not None and "r_depletion_mohm" in rows[0]:
        lines.append(f"R_dep: the depletion resistance R_d·(0.1/SoC)^{model.depletion.power:g}"
                     f" (held below SoC {model.depletion.soc_min:.3g}) that a steady current "
                     "sees beside R static; @0.1 at SoC 0.1 (– for a local model with under "
                     f"{100 * MIN_VALIDITY_SHOWN:g} % validity there: a coefficient its data never "
                     "reach), @SoC at the local model's own")
    return lines


def _ladder_table(rows: list[dict[str, Any]],
                  part: list[str]) -> tuple[list[str], list[list[str]]]:
    """Explain's head and rows for RC-ladder local models: R0, each RC element, R static, …"""
    taus = [k for k in rows[0]["rc_mohm_by_tau_s"] if k != "0"]
    head = (["LM", "gate", *part, "T/°C", "R0"] + [f"R@{t}s" for t in taus]
            + ["R static"] + (["H"] if "hysteresis_mv" in rows[0] else [])
            + [DEPLETION_HEADS[k] for k in DEPLETION_HEADS if k in rows[0]]
            + (["U_off"] if "ocv_offset_mv" in rows[0] else []) + ["R ≥ 0"])
    body = []
    for r in rows:
        cells = [str(r["local_model"]), r["gate"], *[f"{r[v]:.2f}" for v in part],
                 f"{r['temperature_c']:.1f}", f"{r['r0_mohm']:.2f}"]
        cells += [f"{r['rc_mohm_by_tau_s'][t]:.2f}" for t in taus]
        cells.append(f"{r['r_static_mohm']:.2f}")
        if "hysteresis_mv" in r:
            cells.append(f"{r['hysteresis_mv']:.1f}")
        cells += [f"{shown:.2f}" if isinstance(shown := depletion_shown(r, key), float)
                  else shown for key in DEPLETION_HEADS if key in r]
        if "ocv_offset_mv" in r:
            cells.append(f"{r['ocv_offset_mv']:.1f}")
        cells.append("yes" if r["rc_positive"] else "NO")
        body.append(cells)
    return head, body


def _temperature_text(model: LmnModel) -> str:
    """How the resistances and time constants change with temperature, for explain's head."""
    t0 = model.activation_t0_k
    factor = ("exp({}·(1/T − 1/T_ref))" if not t0 else
              "exp({}·c·(1/(T − T0) − 1/(T_ref − T0)))")
    text = ""
    if model.arrhenius_k is not None:
        text += f"; resistances × {factor.format('E')}, E = {model.arrhenius_k:g} K"
    if model.tau_activation_k is not None:
        text += (f"; time constants (at T_ref = {model.reference_temperature_c:g} °C) × "
                 f"{factor.format('Eτ')}, Eτ = {model.tau_activation_k:g} K")
    if text and t0:
        text += (f" (Vogel–Tammann–Fulcher: T0 = {t0:g} K, c = ((T_ref − T0)/T_ref)², T in "
                 "K)")
    return text


def _training_error_lines(model: LmnModel) -> list[str]:
    """The free-run training error's RMS per SoC bin (the model file's
    noise.residual_rms_by_soc) and what the EKF makes of it; none for a model without it."""
    by_soc = model.noise.get("residual_rms_by_soc")
    if not by_soc:
        return []
    bins = ", ".join(f"{soc:.2f}: {1e3 * rms:.1f}"
                     for soc, rms in zip(by_soc["soc"], by_soc["rms_v"], strict=True))
    return [f"free-run training error RMS by SoC (mV) {bins}",
            f"(the EKF's measurement error σ_u(SoC) is {EKF_ERROR_SCALE_BY_SOC:g} × "
            f"{MODEL_ERROR_FACTOR:g} × that, at least {EKF_ERROR_SCALE_BY_SOC:g} × "
            f"{1e3 * MIN_VOLTAGE_SIGMA_V:g} mV)"]


def explain(model_path: str | Path, temperature_c: float | None = None,
            as_json: bool = False) -> str:
    """`lmncell explain MODEL`: the table (or JSON rows) of the model's local models; MODEL a
    model file or an LMNCell FMU (the model it ships: what a supplier's FMU holds)."""
    from lmncell.evaluation.fmueval import model_or_shipped

    model = model_or_shipped(model_path)
    if as_json:
        return json_text(local_model_table(model, temperature_c))
    return explain_text(model, temperature_c)

