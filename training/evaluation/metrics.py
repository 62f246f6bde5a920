"""Error figures of a free-run simulation against measurements (mV)."""

from __future__ import annotations

import numpy as np

WINDOW = (0.2, 0.8)


def error_stats(err_v: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """RMSE, MAE and max |error| in mV (over mask where given); None where no sample."""
    e = err_v if mask is None else err_v[mask]
    if e.size == 0:
        return {"rmse_mv": None, "mae_mv": None, "max_mv": None, "samples": 0}
    return {"rmse_mv": 1e3 * float(np.sqrt(np.mean(e * e))),
            "mae_mv": 1e3 * float(np.mean(np.abs(e))),
            "max_mv": 1e3 * float(np.max(np.abs(e))), "samples": int(e.size)}


def record_metrics(measured_v: np.ndarray, model_v: np.ndarray, soc: np.ndarray,
                   window: tuple[float, float] = WINDOW) -> dict:
    """Whole-record figures and the same over the SoC window (soc is the reference SoC)."""
    err = model_v - measured_v
    inside = (soc >= window[0]) & (soc <= window[1])
    whole = error_stats(err)
    win = error_stats(err, inside)
    return {**whole, **{f"window_{k}": v for k, v in win.items()},
            "window": list(window)}


def pooled(metrics: list[dict], prefix: str = "") -> float:
    """RMSE (mV) pooled over records, weighted by their sample counts."""
    num = sum(m[f"{prefix}rmse_mv"] ** 2 * m[f"{prefix}samples"] for m in metrics
              if m[f"{prefix}samples"])
    den = sum(m[f"{prefix}samples"] for m in metrics)
    return float(np.sqrt(num / den)) if den else float("nan")
