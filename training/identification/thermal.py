"""Identification of the lumped thermal model (lmncell.runtime.thermal) from records that carry
a measured cell (case) temperature beside a known ambient (chamber) temperature.

The heat of each step is i·(u − OCV(SoC)) with the measured voltage and the model's OCV at the
reference SoC; R (K/W), τ (s) and the rested offset (K) minimise the free-run temperature error
of all such segments, each started at its measured temperature (a record may start warmer than
its chamber) and driven by its ambient temperature as logged where that varies (a chamber
still settling: the Panasonic 25 °C Cycle 1 record starts at 23 °C and reaches 25 °C after half
an hour; taken as 25 °C throughout, the fit without the US06 record gave R = 10.0 K/W and
τ = 802 s, with the log 8.5 K/W and 557 s, and the held-out US06 cell temperature 0.89 → 0.54 K
RMSE), else its set point. At run time the temperature the LMN sees at step k is the state at
the start of the step, T(k−1); it is compared here with the measured mean over step k.
"""

from __future__ import annotations

import numpy as np
from lmncell.data.dataset import Segment, record_name
from lmncell.data.records import present
from lmncell.runtime.model import LmnModel
from lmncell.runtime.thermal import ThermalModel, rested_temperature
from scipy.optimize import least_squares
from scipy.signal import lfilter

MIN_RISE_K = 1.0      # records whose temperature rises less above ambient say nothing of heating


def predicted_temperature(params: ThermalModel, heat: np.ndarray, ambient_c: float | np.ndarray,
                          start_c: float, ts: float) -> np.ndarray:
    """T(k−1) for k = 0…n−1 (the temperature each step is taken at), from T(−1) = start_c; the
    ambient one temperature or one per step, step k's as lmncell.runtime.thermal.
    next_temperature takes it: T(k) = a·T(k−1) + (1 − a)·(T_amb(k) + offset) + R·(1 − a)·q(k)."""
    a = np.exp(-ts / params.time_constant_s)
    drive = (1.0 - a) * (rested_temperature(params, ambient_c)
                         + params.resistance_k_per_w * heat)
    x, _ = lfilter([1.0], [1.0, -a], drive, zi=[a * start_c])
    return np.concatenate([[start_c], x[:-1]])


def step_heat(model: LmnModel, seg: Segment) -> np.ndarray:
    """i·(u − OCV(SoC)) per step (W) with the measured voltage."""
    return seg.current_a * (seg.voltage_v - model.ocv(seg.soc_ref))


def _no_thermal_reason(segs: list[Segment]) -> str:
    """Why there is no thermal model, naming the records whose ambient is unknown."""
    reason = (f"no record has a measured cell temperature that rises {MIN_RISE_K} K above a "
              "known ambient temperature")
    unknown = sorted({record_name(s.name) for s in segs
                      if s.temperature_kind == "measured" and s.ambient_c is None})
    if unknown:
        reason += (f"; {', '.join(unknown[:3])}{' …' if len(unknown) > 3 else ''} log a cell "
                   "temperature and no chamber temperature beside it (give it in the file name, "
                   "such as …_25degC…; or, in your own CSV, map the chamber's column as "
                   "ambient=COL)")
    return reason


def fit_thermal(model: LmnModel, segs: list[Segment]) -> tuple[ThermalModel | None, dict]:
    """The thermal model and a summary (RMSE in K, the segments used), or None and the reason."""
    usable = [s for s in segs if s.ambient_c is not None and s.temperature_c is not None
              and float(np.max(s.temperature_c - s.ambient_temperature())) >= MIN_RISE_K]
    if not usable:
        return None, {"used": False, "reason": _no_thermal_reason(segs)}
    ts = model.sample_time_s
    heats = [step_heat(model, s) for s in usable]
    measured = [(present(s.ambient_temperature(), "ambient"),
                 present(s.temperature_c, "cell temperature"))
                for s in usable]

    def unpack(x: np.ndarray) -> ThermalModel:
        return ThermalModel(float(np.exp(x[0])), float(np.exp(x[1])), float(x[2]))

    def residuals(x: np.ndarray) -> np.ndarray:
        p = unpack(x)
        return np.concatenate([predicted_temperature(p, q, ambient, float(cell[0]), ts) - cell
                               for (ambient, cell), q in zip(measured, heats, strict=True)])

    x0 = np.array([np.log(5.0), np.log(1000.0), 0.0])
    lower = np.array([np.log(0.05), np.log(10.0 * ts), -5.0])
    upper = np.array([np.log(200.0), np.log(1e6), 5.0])
    sol = least_squares(residuals, x0, method="trf", x_scale=np.array([1.0, 1.0, 1.0]),
                        bounds=(lower, upper))
    params = unpack(sol.x)
    rmse = float(np.sqrt(np.mean(sol.fun ** 2)))
    return params, {"used": True, "rmse_k": rmse, "segments": [s.name for s in usable],
                    "heat_capacity_j_per_k": params.heat_capacity_j_per_k,
                    "at_bound": parameters_at_bound(sol.x, lower, upper)}


THERMAL_PARAMETERS = ("resistance_k_per_w", "time_constant_s", "offset_k")


def parameters_at_bound(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> list[str]:
    """The names of the fitted parameters that ended on a bound of their search range (then
    the records did not determine them: e.g. one short record that never reaches its thermal
    steady state)."""
    tol = 1e-6 * np.maximum(1.0, upper - lower)
    return [name for name, v, lo, hi, t in zip(THERMAL_PARAMETERS, x, lower, upper, tol,
                                               strict=True)
            if v - lo <= t or hi - v <= t]
