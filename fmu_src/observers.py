"""SoC observers on the LMN (numpy + stdlib): extended Kalman filter, fuzzy observer, IMM.

All three share the LMN step (fmu_src.runtime.CellStepper) and the SoC balance
SoC(k+1) = SoC(k) + Ts·η(i)·i/(3600·Cn) as the prediction. The measurement is the terminal
voltage averaged over the step; the model's prediction for it is the LMN output at the predicted
SoC. The state estimated is SoC; the LMN's other states (filters, hysteresis, output lags) are
propagated deterministically from the current.

- EKF: the gain uses H = ∂u/∂SoC of the whole network at the current operating point (OCV slope,
  local models' SoC inputs and the validity functions' dependence on SoC, by central difference).
- Fuzzy: time-invariant (steady-state) Kalman gains K_j designed offline for each local model at
  its centre, blended online with the validity functions: K = Σ Φ_j·K_j.
- IMM: one filter per local model (its measurement model is that local model alone), mode
  probabilities updated by the innovation likelihoods, Markov mode switching, mixing.

Noise: process q = (σ_i·Ts/(3600·Cn))² + σ_d²·Ts/3600 per step (σ_i: current-sensor error, A;
σ_d: SoC random walk per √hour for capacity and model errors) and measurement r = σ_u²
(σ_u: three times the model's free-run training RMSE unless given). A measurement that is NaN, ≤ 0
(not measured) or more than GATE_V away from the model's voltage range is skipped and counted.
SoC is kept within [0, 1] (the estimate is projected onto the interval after each update).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .model import LmnModel
from .runtime import CellStepper

OBSERVER_NAMES = {0: "none", 1: "ekf", 2: "fuzzy", 3: "imm"}
GATE_V = 0.5
MODEL_ERROR_FACTOR = 3.0
FD_SOC = 1e-4


@dataclass
class ObserverSettings:
    """current_sigma_a: current-sensor error (A); soc_drift_per_sqrt_h: SoC random walk for
    capacity and model errors (fraction per √hour); voltage_sigma_v: measurement and model error
    (V); soc0_sigma: standard deviation of the initial SoC guess; imm_stay: IMM mode persistence."""

    current_sigma_a: float = 0.05
    soc_drift_per_sqrt_h: float = 0.05
    voltage_sigma_v: float | None = None
    soc0_sigma: float = 0.3
    imm_stay: float = 0.95

    @classmethod
    def for_model(cls, model: LmnModel) -> ObserverSettings:
        """Defaults from the model: σ_u = MODEL_ERROR_FACTOR × its free-run training RMSE (the
        error on new data is larger and correlated in time), at least 2 mV."""
        s = cls()
        rmse = float(model.noise.get("residual_std_v", 0.01))
        s.voltage_sigma_v = max(MODEL_ERROR_FACTOR * rmse, 0.002)
        return s


def _clip01(x: float) -> float:
    return min(1.0, max(0.0, x))


@dataclass
class ObserverState:
    soc: float
    var: float
    skipped: int = 0
    mode_soc: list[float] = field(default_factory=list)
    mode_var: list[float] = field(default_factory=list)
    mode_prob: list[float] = field(default_factory=list)


class SocObserver:
    """One observer kind ('ekf', 'fuzzy' or 'imm') around a CellStepper."""

    def __init__(self, model: LmnModel, kind: str, soc0_est: float,
                 capacity_ah: float | None = None, temperature_c: float = 25.0,
                 settings: ObserverSettings | None = None) -> None:
        if kind not in ("ekf", "fuzzy", "imm"):
            raise ValueError(f"observer {kind!r}: expected 'ekf', 'fuzzy' or 'imm'")
        self.model, self.kind = model, kind
        self.settings = settings or ObserverSettings.for_model(model)
        self.stepper = CellStepper(model, soc0_est, capacity_ah, temperature_c)
        cap = capacity_ah or model.capacity_ah
        ts = model.sample_time_s
        self.q = process_variance(self.settings, cap, ts)
        self.r = self.settings.voltage_sigma_v ** 2
        v = model.limits.get("voltage_v", [0.0, 10.0])
        self.v_range = (v[0] - GATE_V, v[1] + GATE_V)
        m = model.n_local_models
        var0 = self.settings.soc0_sigma ** 2
        self.state = ObserverState(soc0_est, var0, 0, [soc0_est] * m, [var0] * m,
                                   [1.0 / m] * m)
        self.fuzzy_gains = fuzzy_gains(model, self.q, self.r) if kind == "fuzzy" else None

    # ----- measurement model ---------------------------------------------------------------
    def _outputs_at(self, soc: float) -> tuple[float, np.ndarray, np.ndarray]:
        """Network voltage, validities and per-local-model voltages at a SoC, for the step just
        predicted (exogenous features and lags as the stepper holds them)."""
        m, st = self.model, self.stepper
        x, z = st._x.copy(), st._z.copy()
        pv = m.partition_variables
        if "soc" in pv:
            z[0, pv.index("soc")] = soc
        cols = m.columns()
        if m.ocv_input:
            x[0, cols.index("ocv(k)") - m.output_lags] = float(m.ocv(soc))
        if m.soc_input:
            x[0, cols.index("soc(k)") - m.output_lags] = soc
        phi = m.validities(m.normalise(z), st._d)[0]
        na = m.output_lags
        lag_part = m.theta[:, :na] @ np.asarray(st.prev_lags) if na else 0.0
        local = x[0] @ m.theta[:, na:].T + lag_part
        ocv = float(m.ocv(soc)) if m.relative_ocv else 0.0
        return ocv + float(phi @ local), phi, ocv + local

    def _slopes(self, soc: float) -> tuple[float, np.ndarray]:
        """∂u/∂SoC of the network and of each local model (central difference)."""
        hi, lo = min(soc + FD_SOC, 1.0), max(soc - FD_SOC, 0.0)
        u_hi, _, loc_hi = self._outputs_at(hi)
        u_lo, _, loc_lo = self._outputs_at(lo)
        return (u_hi - u_lo) / (hi - lo), (loc_hi - loc_lo) / (hi - lo)

    # ----- one step ------------------------------------------------------------------------
    def step(self, current_a: float, voltage_measured_v: float,
             temperature_c: float = 25.0) -> float:
        """Predict with the current held over the step, correct with the mean measured voltage
        over it; returns the SoC estimate."""
        st, s = self.stepper, self.state
        st.step(current_a, temperature_c)
        s.var += self.q
        if self.kind == "imm":
            self._imm_predict(st.soc - s.soc)
        valid = (math.isfinite(voltage_measured_v)
                 and self.v_range[0] <= voltage_measured_v <= self.v_range[1])
        if not valid:
            s.skipped += 1
            s.soc = _clip01(st.soc)
            st.state.soc = s.soc
            return s.soc
        soc = st.soc
        if self.kind == "ekf":
            h = self._slopes(soc)[0]
            innov = voltage_measured_v - self._outputs_at(soc)[0]
            k = s.var * h / (h * h * s.var + self.r)
            soc += k * innov
            s.var = max((1.0 - k * h) * s.var, 1e-12)
        elif self.kind == "fuzzy":
            u, phi, _ = self._outputs_at(soc)
            gains, variances = self.fuzzy_gains
            soc += float(phi @ gains) * (voltage_measured_v - u)
            s.var = float(phi @ variances)
        else:
            soc = self._imm_update(voltage_measured_v)
        s.soc = _clip01(soc)
        st.state.soc = s.soc
        return s.soc

    @property
    def soc_std(self) -> float:
        return math.sqrt(max(self.state.var, 0.0))

    def _imm_predict(self, dsoc: float) -> None:
        s, m = self.state, self.model.n_local_models
        p = self.settings.imm_stay
        trans = np.full((m, m), (1.0 - p) / max(m - 1, 1))
        np.fill_diagonal(trans, p if m > 1 else 1.0)
        mu = np.asarray(s.mode_prob)
        c = trans.T @ mu
        c = np.maximum(c, 1e-300)
        w = (trans * mu[:, None]) / c[None, :]          # w[i, j] = P(from i | to j)
        xs, ps = np.asarray(s.mode_soc), np.asarray(s.mode_var)
        x0 = w.T @ xs
        p0 = np.array([w[:, j] @ (ps + (xs - x0[j]) ** 2) for j in range(m)])
        s.mode_soc = (x0 + dsoc).tolist()
        s.mode_var = (p0 + self.q).tolist()
        s.mode_prob = c.tolist()

    def _imm_update(self, v_meas: float) -> float:
        s = self.state
        xs = np.asarray(s.mode_soc)
        ps = np.asarray(s.mode_var)
        lik = np.empty(xs.size)
        for j in range(xs.size):
            u_j = self._outputs_at(_clip01(xs[j]))[2][j]
            h_j = self._slopes(_clip01(xs[j]))[1][j]
            sj = h_j * h_j * ps[j] + self.r
            k = ps[j] * h_j / sj
            innov = v_meas - u_j
            xs[j] = _clip01(xs[j] + k * innov)
            ps[j] = max((1.0 - k * h_j) * ps[j], 1e-12)
            lik[j] = math.exp(-0.5 * innov * innov / sj) / math.sqrt(2 * math.pi * sj)
        mu = np.asarray(s.mode_prob) * lik
        mu = mu / mu.sum() if mu.sum() > 0 else np.full(xs.size, 1.0 / xs.size)
        s.mode_soc, s.mode_var, s.mode_prob = xs.tolist(), ps.tolist(), mu.tolist()
        x = float(mu @ xs)
        s.var = float(mu @ (ps + (xs - x) ** 2))
        return x

    # ----- state ---------------------------------------------------------------------------
    def get_state(self) -> dict:
        s = self.state
        return {"stepper": self.stepper.get_state(), "soc": s.soc, "var": s.var,
                "skipped": s.skipped, "mode_soc": list(s.mode_soc),
                "mode_var": list(s.mode_var), "mode_prob": list(s.mode_prob)}

    def set_state(self, d: dict) -> None:
        self.stepper.set_state(list(d["stepper"]))
        self.state = ObserverState(float(d["soc"]), float(d["var"]), int(d["skipped"]),
                                   list(d["mode_soc"]), list(d["mode_var"]),
                                   list(d["mode_prob"]))


def fuzzy_gains(model: LmnModel, q: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state Kalman gain and variance of each local model at its centre.

    The offline design stored in the model file (``observers.fuzzy``) is used when it was made
    for the same q and r; otherwise (other settings or capacity) it is designed here the same way.
    """
    stored = model.extra.get("observers", {}).get("fuzzy")
    if (stored and len(stored.get("gains", [])) == model.n_local_models
            and math.isclose(stored.get("q", -1.0), q, rel_tol=1e-12)
            and math.isclose(stored.get("r", -1.0), r, rel_tol=1e-12)):
        return np.asarray(stored["gains"], dtype=float), np.asarray(stored["variances"],
                                                                     dtype=float)
    return design_fuzzy_gains(local_ocv_slopes(model), q, r)


def design_fuzzy_gains(slopes: np.ndarray, q: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """For x(k+1) = x(k) + w, y = c_j·x + v, the predicted variance solves P = P − P²c²/(c²P + r)
    + q, i.e. P = (q + sqrt(q² + 4·q·r/c²))/2; K = P·c/(c²P + r). c_j = ∂u_j/∂SoC at the centre
    (V per unit SoC), q (SoC²) and r (V²) per step."""
    gains, variances = [], []
    for c in np.asarray(slopes, dtype=float).tolist():
        c = c if abs(c) > 1e-6 else 1e-6
        p = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r / (c * c)))
        k = p * c / (c * c * p + r)
        gains.append(k)
        variances.append((1.0 - k * c) * p)
    return np.asarray(gains), np.asarray(variances)


def offline_fuzzy_design(model: LmnModel) -> dict:
    """The fuzzy observer's local Kalman filters for the model file's default settings."""
    settings = ObserverSettings.for_model(model)
    q = process_variance(settings, model.capacity_ah, model.sample_time_s)
    r = float(settings.voltage_sigma_v) ** 2
    slopes = local_ocv_slopes(model)
    gains, variances = design_fuzzy_gains(slopes, q, r)
    return {"q": q, "r": r, "ocv_slopes_v": slopes.tolist(), "gains": gains.tolist(),
            "variances": variances.tolist()}


def process_variance(settings: ObserverSettings, capacity_ah: float, ts: float) -> float:
    """q (SoC² per step) from the current-sensor error and the SoC random walk."""
    return ((settings.current_sigma_a * ts / (3600.0 * capacity_ah)) ** 2
            + settings.soc_drift_per_sqrt_h ** 2 * ts / 3600.0)


def local_ocv_slopes(model: LmnModel) -> np.ndarray:
    """∂u_j/∂SoC of each local model at its validity-weighted SoC centre (V per unit SoC)."""
    grid = np.linspace(0.0, 1.0, 201)
    d = len(model.partition_variables)
    raw = np.tile(model.partition_center, (grid.size, 1))
    if "soc" in model.partition_variables:
        raw[:, model.partition_variables.index("soc")] = grid
    phi = model.validities(model.normalise(raw), np.full(grid.size, 2))
    centres = (phi.T @ grid) / np.maximum(phi.sum(axis=0), 1e-12)
    centres = np.where(phi.sum(axis=0) > 1e-9, centres, 0.5)
    slope = np.gradient(np.asarray(model.ocv(grid), dtype=float), grid)
    out = np.interp(centres, grid, slope)
    cols = model.columns()
    if model.ocv_input:
        out = out * (1.0 + model.theta[:, cols.index("ocv(k)")])
    if model.soc_input:
        out = out + model.theta[:, cols.index("soc(k)")]
    _ = d
    return out
