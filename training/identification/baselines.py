"""Classical baselines fitted on the same segments as the LMN.

- ``arx``: one linear local model (the LMN with M = 1), same regressors and refinement.
- ``ecm2rc`` / ``ecm2rc_hyst``: a 2RC equivalent circuit with SoC-dependent R0, R1, R2 (linear
  between SOC_KNOTS), global τ1, τ2, an Arrhenius-like factor exp(β·(25 − T)/10) on every
  resistance, OCV(SoC) knots, and optionally a one-state hysteresis M·h (Plett's form, rate γ);
  fitted with scipy on the free-run voltage error:
  u = OCV(SoC) + R0·i + v1 + v2 [+ M·h], v_m(k) = e_m·v_m(k−1) + R_m·(1 − e_m)·i(k),
  e_m = exp(−Ts/τ_m).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from lmncell.data.dataset import Segment
from lmncell.identification.blas import one_blas_thread
from lmncell.identification.ocvfit import hat_basis, second_difference
from lmncell.runtime.thermal import DEFAULT_TEMPERATURE_C
from scipy.optimize import least_squares
from scipy.signal import lfilter

SOC_KNOTS = np.linspace(0.0, 1.0, 6)
N_R = SOC_KNOTS.size


@dataclass
class Ecm2rc:
    """Parameters of the 2RC baseline (units: Ω, s, V)."""

    ocv_soc: np.ndarray
    ocv_v: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    r2: np.ndarray
    tau1_s: float
    tau2_s: float
    beta: float
    hyst_v: float
    gamma: float | None
    capacity_ah: float
    sample_time_s: float

    def to_dict(self) -> dict:
        return {"kind": "ecm2rc", "ocv_soc": self.ocv_soc.tolist(), "ocv_v": self.ocv_v.tolist(),
                "soc_knots": SOC_KNOTS.tolist(), "r0_ohm": self.r0.tolist(),
                "r1_ohm": self.r1.tolist(), "r2_ohm": self.r2.tolist(),
                "tau1_s": self.tau1_s, "tau2_s": self.tau2_s, "beta": self.beta,
                "hysteresis_v": self.hyst_v, "hysteresis_gamma": self.gamma,
                "capacity_ah": self.capacity_ah, "sample_time_s": self.sample_time_s}

    @classmethod
    def from_dict(cls, d: dict) -> Ecm2rc:
        return cls(np.asarray(d["ocv_soc"]), np.asarray(d["ocv_v"]), np.asarray(d["r0_ohm"]),
                   np.asarray(d["r1_ohm"]), np.asarray(d["r2_ohm"]), float(d["tau1_s"]),
                   float(d["tau2_s"]), float(d["beta"]), float(d["hysteresis_v"]),
                   d["hysteresis_gamma"], float(d["capacity_ah"]), float(d["sample_time_s"]))

    def simulate(self, current_a: np.ndarray, temperature_c: np.ndarray | None,
                 soc: np.ndarray, h0: float, h: np.ndarray | None = None) -> np.ndarray:
        """Free-run terminal voltage (V) for the current held over each step and SoC at its end
        (h: the hysteresis state series, if already computed)."""
        B = hat_basis(soc, SOC_KNOTS)
        T = np.full(soc.size, DEFAULT_TEMPERATURE_C) if temperature_c is None else temperature_c
        f = np.exp(self.beta * (25.0 - T) / 10.0)
        u = np.interp(soc, self.ocv_soc, self.ocv_v) + f * (B @ self.r0) * current_a
        for r, tau in ((self.r1, self.tau1_s), (self.r2, self.tau2_s)):
            e = np.exp(-self.sample_time_s / tau)
            u = u + lfilter([1.0 - e], [1.0, -e], f * (B @ r) * current_a)
        if self.gamma is not None:
            if h is None:
                h = hysteresis(current_a, self.gamma, self.sample_time_s, self.capacity_ah, h0)
            u = u + self.hyst_v * h
        return u


def hysteresis(current_a: np.ndarray, gamma: float, ts: float, capacity_ah: float,
               h0: float) -> np.ndarray:
    """h(k) = e·h(k−1) + (1−e)·sgn(i), e = exp(−γ|i|Ts/(3600·Cn)) (as in lmncell.runtime.step)."""
    e = np.exp(-gamma * np.abs(current_a) * ts / (3600.0 * capacity_ah)).tolist()
    s = np.sign(current_a).tolist()
    h = np.empty(len(e))
    acc = h0
    for k in range(len(e)):
        acc = e[k] * acc + (1.0 - e[k]) * s[k]
        h[k] = acc
    return h


def _unpack(x: np.ndarray, k: int, with_h: bool, gamma: float | None, cap: float, ts: float,
            knots: np.ndarray) -> Ecm2rc:
    o = 0
    ocv = x[o:o + k]
    o += k
    r0, r1, r2 = (np.exp(x[o + j * N_R:o + (j + 1) * N_R]) for j in range(3))
    o += 3 * N_R
    tau1, tau2, beta = np.exp(x[o]), np.exp(x[o + 1]), x[o + 2]
    hyst_v = x[o + 3] if with_h else 0.0
    return Ecm2rc(knots, ocv, r0, r1, r2, float(tau1), float(tau2), float(beta), float(hyst_v),
                  gamma if with_h else None, cap, ts)


LOG_R_SMOOTHNESS = 1e-4   # a factor e between neighbouring resistance knots costs like this
#                           share of the samples being 1 mV off: negligible where the data
#                           determine the knots, and it ties a knot that no sample reaches (a SoC
#                           below every training record) to its neighbour instead of letting it
#                           drift to exp(700) Ω
R_BOUNDS_OHM = (1e-6, 10.0)
TAU_BOUNDS_S = (0.1, 1e5)
BETA_BOUNDS = (-3.0, 3.0)      # exp(β·(25 − T)/10): at most a factor e³ per 10 K
HYSTERESIS_BOUND_V = 0.5


def parameter_bounds(k: int, with_h: bool) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of the fit's x = [OCV knots (V, free), log R0, log R1, log R2
    (Ω, N_R knots each), log τ1, log τ2 (s), β, hysteresis M (V)]: physical ranges that keep
    every simulation finite at any temperature and SoC."""
    lo: list[np.ndarray | list[float]] = [
          np.full(k, -np.inf), np.full(3 * N_R, np.log(R_BOUNDS_OHM[0])),
          np.full(2, np.log(TAU_BOUNDS_S[0])), [BETA_BOUNDS[0]]]
    hi: list[np.ndarray | list[float]] = [
          np.full(k, np.inf), np.full(3 * N_R, np.log(R_BOUNDS_OHM[1])),
          np.full(2, np.log(TAU_BOUNDS_S[1])), [BETA_BOUNDS[1]]]
    if with_h:
        lo.append([-HYSTERESIS_BOUND_V])
        hi.append([HYSTERESIS_BOUND_V])
    return np.concatenate(lo), np.concatenate(hi)


def start_point(ocv_v: np.ndarray, with_h: bool) -> np.ndarray:
    """The fit's start x in parameter_bounds' layout: the OCV knots given, every resistance
    10 mΩ, τ1 10 s, τ2 200 s, β 0 and a hysteresis M of 10 mV."""
    return np.concatenate([ocv_v, np.log(np.full(3 * N_R, 0.01)),
                           [np.log(10.0), np.log(200.0), 0.0], [0.01] if with_h else []])


PROGRESS_EVERY_S = 3.0   # seconds between progress lines of a fit


@one_blas_thread
def fit_ecm2rc(segs: list[Segment], socs: list[np.ndarray], ocv_soc: np.ndarray,
               ocv_v: np.ndarray, capacity_ah: float, ts: float, gamma: float | None,
               h0s: list[float], max_nfev: int = 60,
               progress: Callable[[str], None] | None = None) -> tuple[Ecm2rc, dict]:
    """Least squares on the free-run error over all segments (log-parameterised R and τ);
    progress, if given, gets a line every PROGRESS_EVERY_S seconds."""
    k = ocv_soc.size
    with_h = gamma is not None
    x0 = start_point(ocv_v, with_h)
    lower, upper = parameter_bounds(k, with_h)
    D2 = second_difference(k)
    D1 = np.kron(np.eye(3), np.diff(np.eye(N_R), axis=0))    # neighbouring knots of R0, R1, R2
    w = [np.sqrt(s.weight) for s in segs]
    n = sum(len(s) for s in segs)
    lam = np.sqrt(3e-3 * n) * 1e-3
    lam_r = np.sqrt(LOG_R_SMOOTHNESS * n) * 1e-3
    hs = [None if gamma is None else hysteresis(s.current_a, gamma, ts, capacity_ah, h0)
          for s, h0 in zip(segs, h0s, strict=True)]

    calls, last = [0], [time.perf_counter()]

    def residuals(x: np.ndarray) -> np.ndarray:
        calls[0] += 1
        now = time.perf_counter()
        if progress is not None and now - last[0] >= PROGRESS_EVERY_S:
            last[0] = now
            progress(f"  … {now - t0:.0f} s, {calls[0]} simulations of the records "
                     f"(at most {max_nfev} iterations)")
        m = _unpack(x, k, with_h, gamma, capacity_ah, ts, ocv_soc)
        parts = [sw * (m.simulate(s.current_a, s.temperature_c, soc, h0, h) - s.voltage_v)
                 for s, soc, sw, h0, h in zip(segs, socs, w, h0s, hs, strict=True)]
        r = np.concatenate([*parts, lam * D2 @ m.ocv_v, lam_r * D1 @ x[k:k + 3 * N_R]])
        return np.where(np.isfinite(r), r, 1e3)

    t0 = time.perf_counter()
    with np.errstate(over="ignore", invalid="ignore"):
        sol = least_squares(residuals, x0, bounds=(lower, upper), method="trf", x_scale="jac",
                            max_nfev=max_nfev)
    model = _unpack(sol.x, k, with_h, gamma, capacity_ah, ts, ocv_soc)
    return model, {"seconds": time.perf_counter() - t0, "evaluations": int(sol.nfev),
                   "cost": float(sol.cost)}
