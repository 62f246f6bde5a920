"""Error figures of a free-run simulation against measurements (mV)."""

from __future__ import annotations

import numpy as np

WINDOW = (0.2, 0.8)
ENDS = (0.1, 0.9)     # the ends of the SoC range: below 10 % (the collapse before cut-off)
# and above 90 % (the top of charge), scored apart beside the window and the whole record


def error_stats(err_v: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """RMSE, MAE and max |error| in mV (over mask where given); None where no sample."""
    e = err_v if mask is None else err_v[mask]
    if e.size == 0:
        return {"rmse_mv": None, "mae_mv": None, "max_mv": None, "samples": 0}
    return {"rmse_mv": 1e3 * float(np.sqrt(np.mean(e * e))),
            "mae_mv": 1e3 * float(np.mean(np.abs(e))),
            "max_mv": 1e3 * float(np.max(np.abs(e))), "samples": int(e.size)}


def record_metrics(measured_v: np.ndarray, model_v: np.ndarray, soc: np.ndarray,
                   window: tuple[float, float] = WINDOW,
                   ends: tuple[float, float] = ENDS) -> dict:
    """Whole-record figures, the same over the SoC window (``window_*``) and over each end of
    the SoC range: below ends[0] (``low_soc_*``) and above ends[1] (``high_soc_*``); soc is
    the reference SoC (0…1)."""
    err = model_v - measured_v
    parts = {"window_": (soc >= window[0]) & (soc <= window[1]),
             "low_soc_": soc < ends[0], "high_soc_": soc > ends[1]}
    out = error_stats(err)
    for prefix, mask in parts.items():
        out.update({f"{prefix}{k}": v for k, v in error_stats(err, mask).items()})
    return {**out, "window": list(window), "ends": list(ends)}


def pooled(metrics: list[dict], prefix: str = "") -> float:
    """RMSE (mV) pooled over records, weighted by their sample counts (NaN without samples)."""
    num = sum(m[f"{prefix}rmse_mv"] ** 2 * m[f"{prefix}samples"] for m in metrics
              if m[f"{prefix}samples"])
    den = sum(m[f"{prefix}samples"] for m in metrics)
    return float(np.sqrt(num / den)) if den else float("nan")
