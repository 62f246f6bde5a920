"""SoC observers on the LMN (numpy + stdlib): extended Kalman filter, fuzzy observer, IMM.

All three share the LMN step (lmncell.runtime.step.CellStepper) and the SoC balance
SoC(k+1) = SoC(k) + Ts·η(i)·i/(3600·Cn) as the prediction. The measurement is the terminal
voltage averaged over the step; the model's prediction for it is the LMN output at the predicted
SoC. The fuzzy observer and the IMM estimate SoC only and propagate the LMN's other states
(filters, hysteresis, output lags) deterministically from the current; the EKF estimates the
filter and hysteresis states with SoC.

- EKF: the state is ξ = [SoC, the filters' low-pass states (A; one per distinct time constant,
  lowpass_states: a chain of filters shares them), the hysteresis state h (models with
  hysteresis)], the LMN's dynamic state; the output lags of a model with na > 0 follow the
  network deterministically. The prediction is the runtime's own step, with the Jacobian
  F = diag(1, a_k, e_h); the gain uses H = ∂u/∂ξ of the whole network at the current operating
  point (OCV slope, local models' SoC inputs, the validity functions' dependence on SoC, the
  filter and hysteresis regressors): the SoC column a secant over ±σ_SoC through the step's own
  regressors with the SoC replaced (CellStepper.voltages_at_socs), the other columns from the
  regressors they enter (state_gradient; by central differences through the runtime's
  features() where the filtered current is a partition input).
  The low-pass states start unknown (ObserverSettings.for_model, the default of both FMUs), as
  if the cell had carried a steady unknown current of spread history_current_sigma_a (prior
  σ²·11ᵀ): the EKF then estimates the relaxation under way when it starts under load; a start
  "at rest" (history_current_sigma_a = 0) takes them as known, 0. The fuzzy observer and the
  IMM, which do not estimate them, count the voltage that their remaining spread means in the
  model error of their variance floor.
- Fuzzy: time-invariant (steady-state) Kalman gains K_j designed offline for each local model at
  its centre, blended online with the validity functions: K = Σ Φ_j·K_j.
- IMM: one filter per local model (its measurement model is that local model alone, its
  measurement variance r plus the squared difference between that local model and the whole
  network at the mode's SoC: outside its validity region a local model is no model of the
  cell, and its mode must neither pull SoC nor win the probabilities there), mode
  probabilities updated by the innovation likelihoods, Markov mode switching, mixing.

Noise: process q = (σ_i·Ts/(3600·Cn))² + σ_d²·Ts/3600 per step (σ_i: current-sensor error, A;
σ_d: SoC random walk per √hour for capacity and model errors) and measurement r = σ_u²
(σ_u: three times the model's free-run training RMSE unless given; the EKF takes
EKF_ERROR_SCALE·σ_u: it assimilates every sample as if independent, but the model's error on
new data is correlated over minutes, and with σ_u alone its ±3σ band held the truth only 73 %
of the time on a held-out Panasonic cycle; with 4·σ_u 97 %, SoC RMSE 0.47 → 0.26 %; the IMM's
mode filters take IMM_ERROR_SCALE·σ_u = √2·σ_u for the same reason: with σ_u its mixture
variance collapsed on the flat A123 plateau at −5 °C, held out, and 5.3 % of the samples fell
outside ±3σ; with √2·σ_u 1.7 %, SoC RMSE 5.9 → 6.2 %, measured before the depletion
regressor; with it 6.2 % outside, and 5.5 % with 2·σ_u). Where the model file has the training
error by SoC (noise.residual_rms_by_soc), the EKF's σ_u is a function of its SoC estimate,
σ_u(SoC) = 3·that RMS (at least 2 mV; the IMM's mode filters take it at each mode's SoC, times
IMM_ERROR_SCALE as before: A123 five folds 5.93 → 5.13 %, Panasonic 25 °C 0.72 → 0.75 %,
10 °C held out 1.74 → 1.73 %), scaled by EKF_ERROR_SCALE_BY_SOC = 10 ≈ √(2·τ_c/Ts) for
an error correlated over τ_c ≈ 50 s (the held-out residuals' autocorrelation falls to 1/e after
28–330 s): the whole-record RMSE is dominated by the voltage collapse near empty (A123: 15 mV
overall, 2 mV per bin on the plateau), and as one σ_u it made the EKF distrust the voltage
where the model is good. Leave-one-out, started under load at true 0.6 with 0.3, SoC RMSE
after 10 min, scalar 4·σ_u → 10·σ_u(SoC): A123 (−15, −5, 5, 25, 45 °C held out)
8.92 / 3.50 / 4.90 / 2.61 / 3.08 → 8.22 / 2.52 / 2.65 / 2.41 / 2.84 %; Panasonic 25 °C
0.34 → 0.27 %; 25 + 10 °C, 10 °C held out 0.70 → 0.58 %; at most 0.1 % of the samples outside
±3σ before and after. σ_d defaults to
EKF_DRIFT_PER_SQRT_H for the EKF (it estimates the dynamic state, so the walk only stands for a
capacity error of about 1.5 % at 1/3 C) and SOC_ONLY_DRIFT_PER_SQRT_H for the fuzzy observer and
the IMM, whose SoC also absorbs the error of the hysteresis and filter states they do not
estimate. In the EKF the current-sensor error drives SoC and the low-pass states together
(Q = σ_i²·g·gᵀ, g = [Ts·η/(3600·Cn), 1 − a_k, 0]) and h walks by σ_h per √hour.
Consistency of ±3σ: the EKF's SoC column of H is the secant over ±σ_SoC (at most SPREAD_MAX) and
the curvature over that range is added to r (statistical linearisation); the fuzzy observer's
variance is propagated exactly for its fixed blended gain, (1 − K·c)²·P + K²·r, from σ_SoC0; and
every observer reports at least the SoC variance (σ_m/|∂u/∂SoC|)² (soc_variance_floor), and at
least the square of the spread that σ_m means on the OCV curve around the estimate
(ocv_interval_sigma: the tangent at an estimate on the steep side of the knee near empty says
nothing of the flat side just above it, where the truth may be), because the model's error is
correlated, not white. σ_m is the larger of the model's free-run training RMSE at that SoC and
the RMS of the recent innovations (measured minus predicted voltage, exponentially weighted over
innovation_tau_s): where the cell leaves what the model was trained on (a colder cell's voltage
collapse at a SoC where the training records never went) the model's error is far larger than
in training, and the innovations show it. That floor widens the reported band only and does
not change the gains.
A measurement that is NaN, ≤ 0 (not measured) or more than GATE_V away from the model's voltage
range is skipped and counted. SoC is kept within [0, 1] (the estimate is projected onto the
interval after each update), h within [−1, 1].
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .model import LmnModel
from .step import CellStepper, ExoState, interp_one, picker
from .thermal import DEFAULT_TEMPERATURE_C

OBSERVER_NAMES = {0: "none", 1: "ekf", 2: "fuzzy", 3: "imm"}
GATE_V = 0.5
MODEL_ERROR_FACTOR = 3.0
EKF_ERROR_SCALE = 4.0
EKF_ERROR_SCALE_BY_SOC = 10.0
MIN_VOLTAGE_SIGMA_V = 0.002   # the smallest default σ_u (V)
IMM_ERROR_SCALE = math.sqrt(2.0)
ERROR_SCALE = {"ekf": EKF_ERROR_SCALE, "fuzzy": 1.0, "imm": IMM_ERROR_SCALE}
FD_SOC = 1e-4
FD_CURRENT_A = 1e-3
FD_HYSTERESIS = 1e-4
SPREAD_MAX = 0.2      # largest SoC half-width of the EKF's secant (statistical linearisation)
EKF_DRIFT_PER_SQRT_H = 0.005
SOC_ONLY_DRIFT_PER_SQRT_H = 0.05
HISTORY_FORGOTTEN_A = 1e-9  # the load history's spread below which the fuzzy observer and
                            # the IMM stop counting it (ObserverState.history emptied)
INNOVATION_TAU_S = 300.0   # the window (s) of the innovation RMS that can raise σ_m
EXTRAPOLATION_K = 10.0     # beyond the trained temperatures σ_m grows by 1 per this many K
HYSTERESIS_PRIOR_VAR = (1.0 / 3.0, 0.05)   # h0 unknown (0): uniform on [−1, 1]; h0 = ±1 assumed


@dataclass
class ObserverSettings:
    """current_sigma_a: current-sensor error (A); soc_drift_per_sqrt_h: SoC random walk for
    capacity and model errors (fraction per √hour; None: the kind's default, see the module);
    voltage_sigma_v: measurement and model error (V); soc0_sigma: standard deviation of the
    initial SoC guess; imm_stay: IMM mode persistence; hysteresis_drift_per_sqrt_h: random walk
    of the EKF's hysteresis state (per √hour); history_current_sigma_a: spread of the unknown
    steady current before the start (A), 0 for a start at rest; model_error_v: the model's
    persistent voltage error σ_m (V; its free-run training RMSE by default) and
    model_error_by_soc ([SoC…], [σ_m…]; the model file's noise.residual_std_by_soc by
    default), which set the floor of the reported SoC variance (soc_variance_floor), raised to
    the RMS of the innovations over the last innovation_tau_s (s; 0: not raised);
    voltage_sigma_by_soc ([SoC…], [σ_u…] in V): the EKF's measurement error as a function of
    SoC, used instead of voltage_sigma_v (with EKF_ERROR_SCALE_BY_SOC) where given."""

    current_sigma_a: float = 0.05
    soc_drift_per_sqrt_h: float | None = None
    voltage_sigma_v: float = MIN_VOLTAGE_SIGMA_V
    soc0_sigma: float = 0.3
    imm_stay: float = 0.95
    hysteresis_drift_per_sqrt_h: float = 0.06
    history_current_sigma_a: float = 0.0
    innovation_tau_s: float = INNOVATION_TAU_S
    model_error_v: float = 0.0
    model_error_by_soc: tuple[list[float], list[float]] | None = None
    voltage_sigma_by_soc: tuple[list[float], list[float]] | None = None

    def model_error_at(self, soc: float) -> float:
        """σ_m (V) at a SoC: model_error_by_soc interpolated (held beyond its ends), else
        model_error_v."""
        if self.model_error_by_soc is None:
            return self.model_error_v
        return interp_one(soc, *self.model_error_by_soc)

    def drift(self, kind: str) -> float:
        """The SoC random walk (per √hour) of an observer kind."""
        if self.soc_drift_per_sqrt_h is not None:
            return self.soc_drift_per_sqrt_h
        return EKF_DRIFT_PER_SQRT_H if kind == "ekf" else SOC_ONLY_DRIFT_PER_SQRT_H

    @classmethod
    def for_model(cls, model: LmnModel, at_rest: bool = False) -> ObserverSettings:
        """Defaults from the model: σ_u = MODEL_ERROR_FACTOR × its free-run training RMSE (the
        error on new data is larger and correlated in time), at least 2 mV; the load history
        before the start unknown, of spread the training current's RMS low-passed over 150 s
        (noise.recent_current_rms_a; 0, a start taken as rested, without it), unless at_rest.
        An observer cannot know whether it starts under load: the default serves both (the
        EKF from rest on the four held-out Panasonic 25 °C records 0.73 / 0.32 / 0.13 / 0.23 %
        SoC RMSE either way; started under load on the held-out 10 °C records of the 25 + 10 °C
        model, 1.21 % against 1.63 % with the history taken as rest)."""
        s = cls()
        rmse = float(model.noise.get("residual_std_v", 0.01))
        s.voltage_sigma_v = max(MODEL_ERROR_FACTOR * rmse, MIN_VOLTAGE_SIGMA_V)
        s.model_error_v = rmse
        by_soc = model.noise.get("residual_std_by_soc")
        if by_soc:
            s.model_error_by_soc = ([float(v) for v in by_soc["soc"]],
                                    [float(v) for v in by_soc["std_v"]])
        rms = model.noise.get("residual_rms_by_soc")
        if rms:
            s.voltage_sigma_by_soc = ([float(v) for v in rms["soc"]],
                                      [max(MODEL_ERROR_FACTOR * float(v), MIN_VOLTAGE_SIGMA_V)
                                       for v in rms["rms_v"]])
        if not at_rest:
            s.history_current_sigma_a = float(model.noise.get("recent_current_rms_a", 0.0))
        return s

    def measurement_variance(self, kind: str, soc: float) -> float:
        """r (V²) of the EKF ("ekf") or of an IMM mode filter ("imm") at a SoC estimate:
        (scale·σ_u(SoC))² where voltage_sigma_by_soc is given (scale EKF_ERROR_SCALE_BY_SOC,
        or IMM_ERROR_SCALE), else (scale·voltage_sigma_v)² (EKF_ERROR_SCALE or
        IMM_ERROR_SCALE)."""
        if self.voltage_sigma_by_soc is None:
            return (self.voltage_sigma_v * ERROR_SCALE[kind]) ** 2
        scale = EKF_ERROR_SCALE_BY_SOC if kind == "ekf" else ERROR_SCALE[kind]
        return (scale * interp_one(soc, *self.voltage_sigma_by_soc)) ** 2


def _clip01(x: float) -> float:
    return min(1.0, max(0.0, x))


@dataclass
class ObserverState:
    soc: float
    var: float
    skipped: int = 0
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))   # EKF: P of ξ
    mode_soc: list[float] = field(default_factory=list)
    mode_var: list[float] = field(default_factory=list)
    mode_prob: list[float] = field(default_factory=list)
    var_floor: float = 0.0        # the reported variance's floor (_variance_floor), SoC²
    innovation_ms: float = 0.0    # innovations' exponentially weighted mean square (V²)
    innovation_weight: float = 0.0  # its weights' sum (the average is unbiased from the start)
    history: list[float] = field(default_factory=list)  # fuzzy, IMM: the low-pass states'
    # remaining spread from the unknown load history (A), decaying with their coefficients

    def covariance(self) -> np.ndarray:
        """The EKF's covariance P of ξ (square; empty for the fuzzy observer and the IMM)."""
        return self.cov


class SocObserver:
    """One observer kind ('ekf', 'fuzzy' or 'imm') around a CellStepper."""

    def __init__(self, model: LmnModel, kind: str, soc0_est: float,
                 capacity_ah: float | None = None, temperature_c: float = DEFAULT_TEMPERATURE_C,
                 settings: ObserverSettings | None = None) -> None:
        if kind not in ("ekf", "fuzzy", "imm"):
            raise ValueError(f"observer {kind!r}: expected 'ekf', 'fuzzy' or 'imm'")
        self.model, self.kind = model, kind
        self.settings = settings or ObserverSettings.for_model(model)
        self.stepper = CellStepper(model, soc0_est, capacity_ah, temperature_c)
        cap = capacity_ah or model.capacity_ah
        ts = model.sample_time_s
        self.q = process_variance(self.settings, cap, ts, kind)
        self.r = (self.settings.voltage_sigma_v * ERROR_SCALE[kind]) ** 2
        v = model.limits.get("voltage_v", [0.0, 10.0])
        self.v_range = (v[0] - GATE_V, v[1] + GATE_V)
        m = model.n_local_models
        var0 = self.settings.soc0_sigma ** 2
        self.lowpass_slots, self.lowpass_state = lowpass_states(model)
        coef = [self.stepper.exo.coef[slot] for slot in self.lowpass_slots]
        self._pick_lowpass = picker(self.lowpass_slots)      # EKF's from the stepper's
        self._spread_lowpass = picker(self.lowpass_state)    # and back
        cov = initial_covariance(self.settings, len(self.lowpass_slots),
                                 self.stepper.state.h if model.hysteresis_gamma is not None
                                 else None) if kind == "ekf" else np.zeros((0, 0))
        history = ([self.settings.history_current_sigma_a] * len(self.lowpass_slots)
                   if kind != "ekf" and self.settings.history_current_sigma_a > 0 else [])
        self.state = ObserverState(soc0_est, var0, 0, cov.copy(), [soc0_est] * m,
                                   [var0] * m, [1.0 / m] * m, history=history)
        none = np.zeros(0)        # the other kinds' tables (never read)
        self.fuzzy_gains = fuzzy_gains(model, self.q, self.r) if kind == "fuzzy" else (none, none)
        self.fuzzy_slopes = local_ocv_slopes(model) if kind == "fuzzy" else none
        self.state_columns = state_columns(model)
        self._fd_states = "filtered_current" in model.partition_variables
        exo_cols = model.columns()[model.output_lags:]
        # (column, EKF low-pass slot) of each depletion regressor
        self._depletion = [(exo_cols.index(c), self.lowpass_state[k]) for c, k in zip(
            model.depletion.columns(), self.stepper.exo.depletion_states, strict=True)
                           ] if model.depletion is not None else []
        matrices = gradient_matrices(self.state_columns, model.n_exo)
        self._gradient_powers = len(matrices)
        self._gradient = local_gradients(matrices, model.theta[:, model.output_lags:],
                                         [c for c, _ in self._depletion])
        self._ekf_q: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._lowpass_coef = coef
        self._ekf_fg = (ekf_transition(coef, cov.shape[0]) if kind == "ekf"
                        else (none, none))
        self._step_inputs = (0.0, temperature_c, list(self.stepper.state.past_current))
        self._ocv_knots = (model.ocv_soc.tolist(), model.ocv_v.tolist())
        tau = self.settings.innovation_tau_s
        self._innovation_decay = math.exp(-ts / tau) if tau > 0 else None

    # ----- measurement model ---------------------------------------------------------------
    def _state_vector(self) -> list[float]:
        """ξ = [SoC, low-pass states…, h (with hysteresis)] of the stepper (one low-pass state
        per distinct time constant, lowpass_states)."""
        s = self.stepper.state
        if self.model.hysteresis_gamma is not None:
            return [s.soc, *self._pick_lowpass(s.lp), s.h]
        return [s.soc, *self._pick_lowpass(s.lp)]

    def _stepper_lowpass(self, states: list[float]) -> list[float]:
        """The stepper's low-pass states (one per filter side) from the EKF's (one per
        distinct time constant)."""
        return list(self._spread_lowpass(states))

    def _features_for(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exogenous regressors x (n, p − na) and raw partition inputs z (n, d) of the step just
        predicted, with rows of ξ replacing the stepper's SoC, low-pass states and h (columns
        beyond a row's length keep the stepper's values), from the runtime's own
        ExoStepper.features with the step's current, temperature and past currents."""
        m, st = self.model, self.stepper
        current, temperature, past = self._step_inputs
        n, nlp = states.shape[0], len(self.lowpass_slots)
        x = np.zeros((n, m.n_exo))
        z = np.zeros((n, len(m.partition_variables)))
        base = st.state
        for r in range(n):
            row = states[r]
            lp = (self._stepper_lowpass(row[1:1 + nlp].tolist()) if row.size > 1
                  else list(base.lp))
            h = float(row[1 + nlp]) if row.size > 1 + nlp else base.h
            cand = ExoState(float(row[0]), lp, h, base.direction, past, base.core)
            st.exo.features(cand, current, temperature, x[r], z[r])
        return x, z

    def _outputs_for(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Network voltage (n,), validities (n, M) and per-local-model voltages (n, M) for the
        step just predicted, with rows of ξ replacing the stepper's states (_features_for)."""
        m, st = self.model, self.stepper
        states = np.atleast_2d(states)
        x, z = self._features_for(states)
        n = states.shape[0]
        d = np.full(n, st.state.direction, dtype=np.intp)
        phi = m.validities(m.normalise(z), d)
        na = m.output_lags
        lag_part = m.theta[:, :na] @ np.asarray(st.prev_lags) if na else 0.0
        local = x @ m.theta[:, na:].T + lag_part
        ocv = np.asarray(m.ocv(states[:, 0]), dtype=float) if m.relative_ocv else np.zeros(n)
        return ocv + np.sum(phi * local, axis=1), phi, ocv[:, None] + local

    def _jacobian(self, xi: list[float], soc_spread: float = FD_SOC
                  ) -> tuple[float, np.ndarray, float]:
        """u(ξ), H = ∂u/∂ξ by central differences (SoC kept within [0, 1]) and the curvature
        term δ = (u(SoC + d) + u(SoC − d))/2 − u(SoC): two network evaluations besides the
        step's own, at the step's own SoC one walk through the tree for both
        (CellStepper.beside).

        The SoC difference d of H is soc_spread (at least FD_SOC): with d = σ_SoC the SoC
        column is the secant over ±σ, a statistical linearisation that does not take the OCV
        slope at a wrong estimate for the slope over the whole uncertainty (an EKF started on
        the steep part of an LFP curve otherwise trusts it and collapses its variance before it
        reaches the plateau), and δ² is added to the measurement variance as the linearisation
        error. The same secant sets the variance floor (_variance_floor): the slope over
        ±σ_SoC around the estimate, where the reported band says the truth is.
        The low-pass states and h enter u only through the regressors (unless the filtered
        current is a partition input, then by central differences): their columns are
        ∂x/∂state (state_columns) times the network's blended coefficients at ξ."""
        n, st = len(xi), self.stepper
        clipped = min(max(xi[0], 0.0), 1.0)  # differences around the clipped SoC:
        spread = max(FD_SOC, soc_spread)              # beyond 0 or 1 both sides would clip
        hi, lo = min(clipped + spread, 1.0), max(clipped - spread, 0.0)
        if not self._fd_states:
            if clipped == st.soc:          # the step's own SoC: its voltage and validities
                u0, validity = st.voltage_v, st.validity
                u_hi, u_lo = st.beside(hi, lo)
            else:
                u0, validity, _ = st.outputs_at_socs([clipped])[0]
                u_hi, u_lo = st.voltages_at_socs([hi, lo])
            rest = self._regressor_gradient(validity, clipped)
        else:
            steps = np.full(n - 1, FD_CURRENT_A)
            if self.model.hysteresis_gamma is not None:
                steps[-1] = FD_HYSTERESIS
            rows = np.tile(np.asarray(xi), (3 + 2 * (n - 1), 1))
            rows[:3, 0] = [clipped, hi, lo]
            rows[3:, 0] = clipped
            for k in range(1, n):
                rows[1 + 2 * k, k] += steps[k - 1]
                rows[2 + 2 * k, k] -= steps[k - 1]
            u_all = self._outputs_for(rows)[0]
            u0, u_hi, u_lo = u_all[:3].tolist()
            rest = ((u_all[3::2] - u_all[4::2]) / (2.0 * steps)).tolist()
        h = np.array([(u_hi - u_lo) / (hi - lo), *rest])
        return u0, h, 0.5 * (u_hi + u_lo) - u0

    def _regressor_gradient(self, validity: Sequence[float], soc: float) -> list[float]:
        """∂u/∂state for the states after SoC (low-pass states, h) through the regressors
        they enter, at the validities and SoC given and the step's temperature: state_gradient
        of the blended coefficients, plus the depletion regressor's g·factor(SoC) on its
        low-pass state."""
        _, temperature, _ = self._step_inputs
        exo = self.stepper.exo
        temperature = exo.lmn_temperature(self.stepper.state, temperature)   # as the step's
        gain = exo.gain_at(temperature)
        per_validity = np.dot(validity, self._gradient).tolist()
        out = state_gradient(per_validity, len(self.state_columns), self._gradient_powers, gain,
                             self.model.temperature_step(temperature),
                             self.model.activation_step(temperature, gain))
        if self._depletion:    # d = g·LP_τ·factor(SoC): ∂d/∂LP_τ = g·factor
            factor = gain * exo.depletion_factor(soc)
            tail = per_validity[len(per_validity) - len(self._depletion):]
            for (_, slot), coefficient in zip(self._depletion, tail, strict=True):
                out[slot] += coefficient * factor
        return out

    # ----- one step ------------------------------------------------------------------------
    def step(self, current_a: float, voltage_measured_v: float,
             temperature_c: float = DEFAULT_TEMPERATURE_C) -> float:
        """Predict with the current held over the step, correct with the mean measured voltage
        over it; returns the SoC estimate."""
        st, s = self.stepper, self.state
        self._step_inputs = (current_a, temperature_c, list(st.state.past_current))
        st.step(current_a, temperature_c)
        if s.history:
            s.history = [a * x for a, x in zip(self._lowpass_coef, s.history, strict=True)]
            if max(s.history) < HISTORY_FORGOTTEN_A:
                s.history = []
        if self.kind == "ekf":
            self._ekf_predict(current_a)
        else:
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
        self._track_innovation(voltage_measured_v - st.voltage_v)
        if self.kind == "ekf":
            soc = self._ekf_update(voltage_measured_v)
        elif self.kind == "fuzzy":         # at the step's own SoC: its voltage and validities
            phi = st.validity
            gain = float(np.dot(phi, self.fuzzy_gains[0]))
            soc += gain * (voltage_measured_v - st.voltage_v)
            slope = float(np.dot(phi, self.fuzzy_slopes))
            s.var = fixed_gain_variance(s.var, gain, slope, self.r)
            s.var_floor = self._variance_floor(st.soc, slope)
        else:
            soc = self._imm_update(voltage_measured_v)
        s.soc = _clip01(soc)
        st.state.soc = s.soc
        return s.soc

    def _ekf_predict(self, current_a: float) -> None:
        """P ← F·P·Fᵀ + Q for the step the stepper just took."""
        s, exo = self.state, self.stepper.exo
        p = s.covariance()
        ff, q = self._ekf_f_and_q(exo.eta(current_a))
        if exo.gamma is not None:         # the model's hysteresis rate γ
            f = self._ekf_fg[0].copy()
            f[-1] = math.exp(-exo.gamma * abs(current_a) * exo.soc_gain)
            ff = f[:, None] * f       # np.outer(f, f) without its Python overhead
        p = ff * p + q             # F diagonal: (f_a·f_b)·P_ab keeps a symmetric P symmetric
        s.cov = p
        s.var = float(p[0, 0])

    def _ekf_f_and_q(self, eta: float) -> tuple[np.ndarray, np.ndarray]:
        """F·Fᵀ of the diagonal F (h entry still 1) and Q of the prediction for a step with
        coulombic efficiency eta: Q = σ_i²·G·Gᵀ plus the SoC and hysteresis random walks;
        computed once per eta."""
        cached = self._ekf_q.get(eta)
        if cached is None:
            cfg, exo = self.settings, self.stepper.exo
            f, g = (a.copy() for a in self._ekf_fg)
            g[0] = exo.soc_gain * eta
            q = cfg.current_sigma_a ** 2 * np.outer(g, g)
            q[0, 0] += cfg.drift("ekf") ** 2 * self.model.sample_time_s / 3600.0
            if self.model.hysteresis_gamma is not None:
                q[-1, -1] += (cfg.hysteresis_drift_per_sqrt_h ** 2 * self.model.sample_time_s
                              / 3600.0)
            cached = self._ekf_q[eta] = (f[:, None] * f, q)
        return cached

    def _ekf_update(self, v_meas: float) -> float:
        """Correct ξ with one voltage; writes the low-pass states and h back to
        the stepper and returns the unclipped SoC."""
        s, st = self.state, self.stepper
        xi = self._state_vector()
        soc_prior = min(max(xi[0], 0.0), 1.0)
        p = s.covariance()
        u, h, curvature = self._jacobian(xi, min(math.sqrt(max(s.var, 0.0)),
                                                          SPREAD_MAX))
        r = self.settings.measurement_variance("ekf", soc_prior) + curvature * curvature
        ph = p.dot(h)                              # (.dot: less overhead than @ here)
        inv_s = 1.0 / (float(h.dot(ph)) + r)       # 1/(hᵀPh + r)
        innovation = v_meas - u            # ξ + K·(v − u), K = P·h/s
        xi = [x + k * inv_s * innovation for x, k in zip(xi, ph.tolist(), strict=True)]
        # P − P·h·hᵀ·P/(hᵀPh + r): the Joseph form's value for this optimal gain, in O(n²);
        # (Ph_a·Ph_b)·(1/s) keeps the symmetric P of the prediction symmetric, bit for bit
        outer = np.multiply.outer(ph, ph)
        outer *= inv_s
        p -= outer                  # in place: the prediction made this P, nothing shares it
        s.var_floor = self._variance_floor(soc_prior, float(h[0]))
        s.var = max(float(p[0, 0]), 1e-12)
        st.state.lp = self._stepper_lowpass(xi[1:1 + len(self.lowpass_slots)])
        if self.model.hysteresis_gamma is not None:
            st.state.h = min(1.0, max(-1.0, xi[-1]))
        return xi[0]

    def _track_innovation(self, innovation_v: float) -> None:
        """Update the innovations' exponentially weighted mean square (weights decaying by
        exp(−Ts/innovation_tau_s), normalised by their sum)."""
        decay = self._innovation_decay
        if decay is None:
            return
        s = self.state
        s.innovation_weight = decay * s.innovation_weight + 1.0
        s.innovation_ms += (innovation_v * innovation_v - s.innovation_ms) / s.innovation_weight

    @property
    def _extrapolation(self) -> float:
        """1 + (K beyond the trained temperature range)/EXTRAPOLATION_K at the step's
        temperature (1 inside it, or for a model without a trained range): the training error
        says nothing of the model's error where it extrapolates, which grows with the distance
        (A123 trained at −15…25 °C, run at 45 °C: the EKF's SoC 2.5 % off where its ±3σ
        band had narrowed to 2.2 % on the steep OCV below SoC 0.2)."""
        lo, hi = self.model.limits.get("temperature_c", (-math.inf, math.inf))
        t = self._step_inputs[1]
        return 1.0 + max(0.0, lo - t, t - hi) / EXTRAPOLATION_K

    def _model_error(self, soc: float) -> float:
        """σ_m (V) for the variance floor: the training error at the SoC (times _extrapolation
        beyond the trained temperatures), or the recent
        innovations' RMS where that is larger; for the fuzzy observer and the IMM, which do not
        estimate the low-pass states, combined in quadrature with the voltage that the
        remaining spread of the unknown load history means (∂u/∂LP at the step's validities,
        _regressor_gradient, times ObserverState.history)."""
        trained = self.settings.model_error_at(soc) * self._extrapolation
        error = max(trained, math.sqrt(self.state.innovation_ms))
        history = self.state.history
        if history:
            grad = self._regressor_gradient(self.stepper.validity, soc)
            u_h = float(np.dot(grad[:len(history)], history))
            error = math.sqrt(error * error + u_h * u_h)
        return error

    def _variance_floor(self, soc: float, slope_v: float) -> float:
        """The reported variance's floor at a SoC estimate (SoC²): the model error σ_m over
        slope_v (V per unit SoC: the EKF's secant over ±σ, the fuzzy observer's and the IMM's
        local slopes; soc_variance_floor), and at least the square of ocv_interval_sigma,
        the spread σ_m means on the OCV curve around the estimate (the tangent at an estimate
        on the steep side of the knee is no measure of the flat side where the truth may be)."""
        error = self._model_error(soc)
        return max(soc_variance_floor(error, slope_v),
                   ocv_interval_sigma(soc, error, *self._ocv_knots) ** 2)

    @property
    def soc_std(self) -> float:
        """The reported SoC standard deviation: the filter's own, but at least the floor of
        _variance_floor (which does not feed back into the gains)."""
        return math.sqrt(max(self.state.var, self.state.var_floor, 0.0))

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
        slopes = np.empty(xs.size)
        # each mode at its SoC: the network and its own local model, and that local model's
        # slope by a central difference (local voltages alone, no validities needed)
        socs = [_clip01(x) for x in s.mode_soc]
        his, los = [min(x + FD_SOC, 1.0) for x in socs], [max(x - FD_SOC, 0.0) for x in socs]
        at = self.stepper.outputs_at_socs(socs)
        ends = self.stepper.local_voltages_at_socs(his + los)
        for j in range(xs.size):
            u_net, _, local = at[j]
            u_j = local[j]
            h_j = (ends[j][j] - ends[xs.size + j][j]) / (his[j] - los[j])
            sj = (h_j * h_j * ps[j] + self.settings.measurement_variance("imm", socs[j])
                  + (u_net - u_j) ** 2)
            k = ps[j] * h_j / sj
            innov = v_meas - u_j
            xs[j] = _clip01(xs[j] + k * innov)
            ps[j] = max((1.0 - k * h_j) * ps[j], 1e-12)
            slopes[j] = h_j
            lik[j] = math.exp(-0.5 * innov * innov / sj) / math.sqrt(2 * math.pi * sj)
        mu = np.asarray(s.mode_prob) * lik
        mu = mu / mu.sum() if mu.sum() > 0 else np.full(xs.size, 1.0 / xs.size)
        s.mode_soc, s.mode_var, s.mode_prob = xs.tolist(), ps.tolist(), mu.tolist()
        x = float(mu @ xs)
        s.var = float(mu @ (ps + (xs - x) ** 2))
        s.var_floor = self._variance_floor(x, float(mu @ slopes))
        return x

    # ----- state ---------------------------------------------------------------------------
    def get_state(self) -> dict:
        s = self.state
        return {"stepper": self.stepper.get_state(), "soc": s.soc, "var": s.var,
                "skipped": s.skipped, "cov": s.cov.ravel().tolist(),
                "mode_soc": list(s.mode_soc),
                "mode_var": list(s.mode_var), "mode_prob": list(s.mode_prob),
                "var_floor": s.var_floor, "innovation_ms": s.innovation_ms,
                "innovation_weight": s.innovation_weight, "history": list(s.history)}

    def set_state(self, d: dict) -> None:
        self.stepper.load_state(list(d["stepper"]))
        cov = np.array([float(v) for v in d["cov"]])
        n = self.state.cov.shape[0]         # this observer's: ξ's size for the EKF, else 0
        if cov.size != n * n:
            raise ValueError(f"observer state: cov has {cov.size} entries, expected {n}×{n} "
                             "(the covariance of this observer's state, row by row)")
        history = [float(v) for v in d["history"]]
        if history and len(history) != len(self.lowpass_slots):
            raise ValueError(f"observer state: history has {len(history)} entries, expected "
                             f"0 or {len(self.lowpass_slots)} (one per low-pass state)")
        mode_soc, mode_var, mode_prob = modes = [
            [float(v) for v in d[key]] for key in ("mode_soc", "mode_var", "mode_prob")]
        if any(len(m) != len(self.state.mode_soc) for m in modes):
            raise ValueError(f"observer state: the IMM's modes hold {[len(m) for m in modes]} "
                             f"values, expected {len(self.state.mode_soc)} each")
        self.state = ObserverState(float(d["soc"]), float(d["var"]), int(d["skipped"]),
                                   cov.reshape(n, n), mode_soc, mode_var, mode_prob,
                                   float(d["var_floor"]),
                                   float(d["innovation_ms"]), float(d["innovation_weight"]),
                                   history)


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


def ekf_transition(coef: list[float], n: int) -> tuple[np.ndarray, np.ndarray]:
    """The EKF prediction's F (diagonal) and G of ξ = [SoC, low-pass states…, h] without the
    step's current-dependent entries (G's SoC entry, F's h entry): the low-pass states decay by
    their coefficients a and take 1 − a of the current."""
    f, g = np.ones(n), np.zeros(n)
    f[1:1 + len(coef)] = coef
    g[1:1 + len(coef)] = [1.0 - a for a in coef]
    return f, g


def lowpass_states(model: LmnModel) -> tuple[list[int], list[int]]:
    """The EKF's low-pass states: one per distinct time constant of the filters' states
    [fast_1, slow_1, fast_2, …] (in a chain of filters the slow state of one is the fast state
    of the next: the same recursion of the same current, always equal, which the EKF would
    otherwise carry twice, with a singular covariance). Returns the first filter slot of each
    EKF low-pass state and the EKF low-pass state of each slot."""
    taus = model.filter_taus()
    first: list[int] = []
    state_of: list[int] = []
    for slot, tau in enumerate(taus):
        if tau not in taus[:slot]:
            first.append(slot)
        state_of.append(first.index(taus.index(tau)))
    return first, state_of


def state_columns(model: LmnModel) -> list[list[tuple[int, int, bool, float]]]:
    """Per EKF state after SoC (the low-pass states of lowpass_states, then h): the regressor
    columns it enters linearly, as (exogenous column, power p of dT, times the Arrhenius gain
    g, sign): each filter v_f = g·(lp_fast − lp_slow) it is a side of, and their temperature
    terms v_f·dTᵖ; h and h·dTᵖ."""
    exo = model.columns()[model.output_lags:]
    powers = range(model.temperature_terms + 1)

    def with_terms(col: str, scaled: bool, sign: float) -> list[tuple[int, int, bool, float]]:
        names = [col] + [model.temperature_term_name(col, p) for p in powers if p > 0]
        return [(exo.index(name), p, scaled, sign) for p, name in zip(powers, names,
                                                                       strict=True)
                if name in exo]

    state_of = lowpass_states(model)[1]
    out: list[list[tuple[int, int, bool, float]]] = [[] for _ in set(state_of)]
    for slot, state in enumerate(state_of):
        out[state] += with_terms(f"v{slot // 2 + 1}(k)", True, -1.0 if slot % 2 else 1.0)
    if model.hysteresis_gamma is not None:
        out.append(with_terms("h(k)", False, 1.0))
    return out


def gradient_matrices(columns: list[list[tuple[int, int, bool, float]]], n_exo: int
                      ) -> list[tuple[np.ndarray, np.ndarray]]:
    """state_columns as matrices per power p of dT: (A_p, B_p), the signs of the unscaled and
    of the temperature-gain-scaled regressor columns (rows: states, columns: regressors)."""
    degree = max((p for cols in columns for _, p, _, _ in cols), default=0)
    mats = [(np.zeros((len(columns), n_exo)), np.zeros((len(columns), n_exo)))
            for _ in range(degree + 1)]
    for a, cols in enumerate(columns):
        for col, p, scaled, sign in cols:
            mats[p][1 if scaled else 0][a, col] += sign
    return mats


def local_gradients(matrices: list[tuple[np.ndarray, np.ndarray]], theta_exo: np.ndarray,
                    depletion_columns: list[int]) -> np.ndarray:
    """Per local model (rows) the blocks [θ_j·A_0ᵀ, θ_j·B_0ᵀ, θ_j·A_1ᵀ, …] of gradient_matrices
    (θ_j: its exogenous coefficients), then its coefficient of each depletion regressor the
    model has: the validities times this matrix give state_gradient its terms in one product."""
    blocks = [theta_exo @ m.T for pair in matrices for m in pair]
    blocks += [theta_exo[:, c:c + 1] for c in depletion_columns]
    return np.ascontiguousarray(np.hstack(blocks))


def state_gradient(per_validity: list[float], n: int, powers: int, gain: float,
                   dt: float, da: float) -> list[float]:
    """∂u/∂state for the n states of state_columns: Σ_p (dAᵖ·A_p + dTᵖ·g·B_p)·∂u/∂x,
    p < powers, from per_validity = Φ·local_gradients (Φ: the validities; blocks of n:
    A_0·θᵀΦ, B_0·θᵀΦ, …; θᵀΦ the network's coefficients of the regressors at the operating
    point), g the temperature gain of the scaled (filter) columns; the unscaled columns are the
    hysteresis regressor's, whose terms go in dA (LmnModel.activation_step; dA = dT for
    "polynomial" hysteresis terms)."""
    out = [a + gain * b for a, b in zip(per_validity[:n], per_validity[n:2 * n], strict=True)]
    power, power_a = dt, da
    for p in range(1, powers):
        start = 2 * n * p
        unscaled, scaled = per_validity[start:start + n], per_validity[start + n:start + 2 * n]
        out = [o + power_a * a + power * gain * b for o, a, b in zip(out, unscaled, scaled,
                                                                     strict=True)]
        power *= dt
        power_a *= da
    return out


def ocv_interval_sigma(soc: float, error_v: float, xs: list[float], ys: list[float]) -> float:
    """Half the width of the SoC interval [s_lo, s_hi] around soc whose ends are where the OCV
    (knots xs, ys, linear between) first rises by error_v above OCV(soc) and first falls by
    error_v below it, going up and down from soc (0 or 1 where it never gets that far): the SoC
    spread that a voltage error error_v means on the curve itself. On a straight curve it is
    error_v/slope; where the curve is steep on one side and flat on the other (the knee near
    empty, an LFP plateau's edge) it is far wider than error_v over the local tangent."""
    if not error_v > 0.0:
        return 0.0
    u0 = interp_one(soc, xs, ys)
    j = bisect.bisect_right(xs, soc)
    high = first_crossing(soc, u0, u0 + error_v, xs[j:], ys[j:], 1.0)
    below = bisect.bisect_left(xs, soc)
    low = first_crossing(soc, u0, u0 - error_v, xs[:below][::-1], ys[:below][::-1], 0.0)
    return 0.5 * (high - low)


def first_crossing(x0: float, y0: float, target: float, xs: list[float], ys: list[float],
                    end: float) -> float:
    """Walking from (x0, y0) through the knots (xs, ys) in the order given, the first x where
    the piecewise-linear curve reaches target; end if it never does."""
    rising = target > y0
    for x1, y1 in zip(xs, ys, strict=True):
        if (y1 >= target) if rising else (y1 <= target):
            return x0 + (x1 - x0) * (target - y0) / (y1 - y0)
        x0, y0 = x1, y1
    return end


def soc_variance_floor(model_error_v: float, slope_v: float) -> float:
    """The smallest SoC variance an observer reports: (σ_m/|∂u/∂SoC|)², the SoC error that the
    model's persistent voltage error σ_m causes at the local slope (V per unit SoC). The
    model's error on a record is correlated over minutes, not white as the filters assume, so
    that where the OCV is steep (near empty) their variance would otherwise fall far below
    the error they actually make (A123: ±3σ of 0.4 % around a 1.3 % error). A "consider"
    term: it widens the reported band only; the gains keep the filter's own variance (as a
    floor inside the filter it made the EKF chase the model's error: Panasonic 25 °C
    leave-one-out EKF RMSE 0.22 → 0.66 %). Capped at 1."""
    if model_error_v <= 0.0:
        return 0.0
    return min((model_error_v / max(abs(slope_v), 1e-6)) ** 2, 1.0)


def fixed_gain_variance(var: float, gain: float, slope: float, r: float) -> float:
    """Variance after a correction with a given (not necessarily optimal) gain K of the scalar
    measurement y = c·SoC + v: (1 − K·c)²·P + K²·r (c guarded as in design_fuzzy_gains). From
    the start variance it falls as fast as the gains correct, so that ±3σ stays honest while
    the estimate converges; at the design point it settles at the local steady-state variance."""
    c = slope if abs(slope) > 1e-6 else 1e-6
    return (1.0 - gain * c) ** 2 * var + gain * gain * r


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
    q = process_variance(settings, model.capacity_ah, model.sample_time_s, "fuzzy")
    r = float(settings.voltage_sigma_v) ** 2
    slopes = local_ocv_slopes(model)
    gains, variances = design_fuzzy_gains(slopes, q, r)
    return {"q": q, "r": r, "ocv_slopes_v": slopes.tolist(), "gains": gains.tolist(),
            "variances": variances.tolist()}


def process_variance(settings: ObserverSettings, capacity_ah: float, ts: float,
                     kind: str) -> float:
    """q (SoC² per step) from the current-sensor error and the SoC random walk of the kind."""
    return ((settings.current_sigma_a * ts / (3600.0 * capacity_ah)) ** 2
            + settings.drift(kind) ** 2 * ts / 3600.0)


def initial_covariance(settings: ObserverSettings, n_lowpass: int,
                       h0: float | None) -> np.ndarray:
    """P0 of the EKF's ξ = [SoC, low-pass states, h]: σ_SoC0², a steady unknown current of
    spread history_current_sigma_a before the start (all low-pass states equal: σ²·11ᵀ), and
    HYSTERESIS_PRIOR_VAR for h0 unknown (0) or assumed (±1)."""
    n = 1 + n_lowpass + (0 if h0 is None else 1)
    p = np.zeros((n, n))
    p[0, 0] = settings.soc0_sigma ** 2
    p[1:1 + n_lowpass, 1:1 + n_lowpass] = settings.history_current_sigma_a ** 2
    if h0 is not None:
        p[-1, -1] = HYSTERESIS_PRIOR_VAR[0] if h0 == 0.0 else HYSTERESIS_PRIOR_VAR[1]
    return p


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
