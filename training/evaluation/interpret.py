"""What each local model says about the cell: resistances and time constants per regime."""

from __future__ import annotations

import itertools

import numpy as np
from lmncell.runtime.model import LmnModel


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


def local_model_table(model: LmnModel) -> list[dict]:
    """Per local model: operating point, instantaneous and static resistance (mΩ), time
    constants (s) of its real stable poles, and the hysteresis gain (mV) where present."""
    na, cols = model.output_lags, model.columns()
    cur = [k for k, c in enumerate(cols) if c.startswith("i(k")]
    centres = leaf_centres(model)
    rows = []
    for j, th in enumerate(model.theta):
        a = th[:na]
        dc = 1.0 - float(a.sum())
        poles = np.roots(np.concatenate([[1.0], -a])) if na else np.zeros(0)
        taus = sorted(float(-model.sample_time_s / np.log(p.real)) for p in poles
                      if abs(p.imag) < 1e-9 and 0 < p.real < 1)
        row = {"local_model": j + 1, "gate": model.leaf_gates[j],
               **{v: float(c) for v, c in zip(model.partition_variables, centres[j],
                                               strict=True)},
               "r0_mohm": 1e3 * float(th[cur[0]]),
               "r_static_mohm": 1e3 * float(th[cur].sum()) / dc if abs(dc) > 1e-9 else np.inf,
               "time_constants_s": taus,
               "max_pole": float(np.abs(poles).max()) if poles.size else 0.0}
        if na == 0 and model.filters:
            row["rc_mohm_by_tau_s"] = rc_ladder(model, th)
            row["r0_mohm"] = row["rc_mohm_by_tau_s"]["0"]   # current lags + sub-Ts filters
        if "h(k)" in cols:
            g = th[cols.index("h(k)")]
            row["hysteresis_mv"] = 1e3 * float(g) / dc if abs(dc) > 1e-9 else np.inf
        rows.append(row)
    return rows


def rc_ladder(model: LmnModel, theta: np.ndarray) -> dict[str, float]:
    """A feedback-free local model as an RC ladder: u − OCV ≈ R0·i + Σ_τ R_τ·LP_τ(i).

    Each filter input v = LP_fast − LP_slow puts +g on its fast and −g on its slow time
    constant; a time constant below the sample time counts as instantaneous (part of R0).
    Returns mΩ per time constant in s ("0" = instantaneous R0, including the current lags)."""
    cols = model.columns()
    ts = model.sample_time_s
    out: dict[float, float] = {0.0: float(sum(theta[k] for k, c in enumerate(cols)
                                               if c.startswith("i(k")))}
    for f, (fast, slow) in enumerate(model.filters):
        g = float(theta[cols.index(f"v{f + 1}(k)")])
        for tau, sign in ((fast, 1.0), (slow, -1.0)):
            key = 0.0 if tau < ts else tau
            out[key] = out.get(key, 0.0) + sign * g
    return {f"{k:g}": 1e3 * v for k, v in sorted(out.items())}
