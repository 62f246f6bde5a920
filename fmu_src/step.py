"""The one implementation of the LMN step, used by training, evaluation and the FMU.

Step k covers (t_{k−1}, t_k] with t_k − t_{k−1} = Ts. Its input is the current held over the step
(A, > 0 charges) and the temperature (°C); its output the terminal voltage (V) for that step.
Current and filter regressors are multiplied by the Arrhenius gain g(T) where the model has one;
temperature terms repeat the current, filter, hysteresis and offset columns times dT, dT², …
(the hysteresis column times dA, dA², … where the model's hysteresis terms are "arrhenius").
Within a step, in this order: SoC(k) = SoC(k−1) + Ts·η(i)·i/(3600·Cn); the zero-DC-gain filters
v = LP_fast(i) − LP_slow(i) (exact discretisation a = exp(−Ts/τ)); the hysteresis state
h(k) = e·h(k−1) + (1−e)·sgn(i), e = exp(−γ·|i|·Ts/(3600·Cn)) (→ +1 after charge, −1 after
discharge); the pre-partition direction (charge/discharge, kept through rests); the network
ŷ(k) = Σ_j Φ_j(z(k))·x(k)ᵀθ_j; u(k) = ŷ(k) + OCV(SoC(k)) for a relative-OCV model.

At the start of a record the cell is taken as rested: past currents and filter states are 0 and
the output lags sit at the network's fixed point for zero current at SoC0.
"""

from __future__ import annotations

import bisect
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .model import DEPLETION_COLUMNS, LmnModel
from .thermal import (
    DEFAULT_TEMPERATURE_C,
    cell_start_fault,
    heat_w,
    next_temperature,
    rested_temperature,
    step_coefficients,
)

CHARGE, DISCHARGE = 1, 2


def arrhenius_gain(temperature_c: np.ndarray | None, e_k: float | None, n: int,
                   ref_c: float = 25.0, t0_k: float = 0.0) -> np.ndarray:
    """arrhenius_factor for n samples at once (ones without E or T); the step itself takes the
    scalar math.exp version, which costs less per call."""
    if e_k is None or temperature_c is None:
        return np.ones(n)
    t_ref = ref_c + 273.15 - t0_k
    ratio = t_ref / (ref_c + 273.15)
    scale = e_k * (ratio * ratio)
    return np.exp(scale * (1.0 / (temperature_c + 273.15 - t0_k) - 1.0 / t_ref))


def arrhenius_factor(temperature_c: float, e_k: float | None, ref_c: float = 25.0,
                     t0_k: float = 0.0) -> float:
    """exp(E·c·(1/(T − T0) − 1/(T_ref − T0))), c = ((T_ref − T0)/T_ref)², T in K, at one
    temperature (°C; 1 without E): arrhenius_gain's value for one sample, the gain g(T) of the
    current and filter regressors with E, the factor k(T) of every filter time constant with
    Eτ (the relaxation slower when cold). T0 = 0: Arrhenius, exp(E·(1/T − 1/T_ref)); T0 > 0:
    the Vogel–Tammann–Fulcher form of an electrolyte's transport, whose apparent activation
    E·T²/(T − T0)²·c grows towards the cold (E at T_ref, so the slope there is Arrhenius')."""
    if e_k is None:
        return 1.0
    t_ref = ref_c + 273.15 - t0_k
    ratio = t_ref / (ref_c + 273.15)
    scale = e_k * (ratio * ratio)
    return math.exp(scale * (1.0 / (temperature_c + 273.15 - t0_k) - 1.0 / t_ref))


def filter_coefficients(model: LmnModel, temperature_c: float | None = None,
                        taus: list[float] | None = None) -> list[float]:
    """exp(−Ts/(τ·k(T))) of every filter side, in the order of the low-pass states (k(T):
    arrhenius_factor with Eτ; the time constants of the file where T is None or without Eτ);
    taus: model.filter_taus() where the caller keeps it."""
    k = (1.0 if temperature_c is None
         else arrhenius_factor(temperature_c, model.tau_activation_k,
                               model.reference_temperature_c, model.activation_t0_k))
    ts, exp = model.sample_time_s, math.exp
    return [exp(-ts / (tau * k)) for tau in (model.filter_taus() if taus is None else taus)]


def initial_hysteresis(soc0: float) -> float:
    """Default hysteresis state: +1 (just charged) at SoC0 ≥ 0.95, else 0 (unknown history)."""
    return 1.0 if soc0 >= 0.95 else 0.0


@dataclass
class ExoState:
    """State of everything that does not depend on the model output (SoC, filters, h, lags)."""

    soc: float
    lp: list[float]          # [fast_1, slow_1, fast_2, slow_2, …] low-pass states (A)
    h: float
    direction: int
    past_current: list[float]  # i(k−1) … i(k−nb+1)
    core: float = 0.0          # LP_τ(i²) of the core rise (A²; 0 without one)

    def as_list(self) -> list[float]:
        return [self.soc, *self.lp, self.h, float(self.direction), *self.past_current,
                self.core]

    @classmethod
    def from_list(cls, values: list[float], n_filters: int, n_past: int) -> ExoState:
        k = 1 + 2 * n_filters
        return cls(values[0], list(values[1:k]), values[k], int(values[k + 1]),
                   list(values[k + 2:k + 2 + n_past]), values[k + 2 + n_past])


def _without_depletion(soc: float) -> float:
    raise ValueError(f"the model has no depletion regressor (asked at SoC {soc})")


def depletion_factor_function(model: LmnModel) -> Callable[[float], float]:
    """The model's depletion factor as a function of SoC (one that refuses where the model has
    no depletion regressor, whose columns then are never filled)."""
    return model.depletion.factor if model.depletion is not None else _without_depletion


class ExoStepper:
    """Advances ExoState and builds the exogenous regressors and partition inputs of one step."""

    def __init__(self, model: LmnModel, capacity_ah: float | None = None) -> None:
        self.model = model
        self.factor_of_soc = depletion_factor_function(model)
        ts = model.sample_time_s
        self.capacity_ah = float(capacity_ah if capacity_ah is not None else model.capacity_ah)
        self.coef = filter_coefficients(model)      # at T_ref (the file's time constants)
        self._coef_at = (math.nan, self.coef)       # (T, coefficients) of the last step
        self._taus = model.filter_taus()
        self.soc_gain = ts / (3600.0 * self.capacity_ah)
        self.gamma = model.hysteresis_gamma
        self.core_k = model.core_rise_k_per_a2
        self.core_a = core_rise_coefficient(model)
        pv = model.partition_variables     # where each partition input goes in z (or None)
        self._z_index = tuple(pv.index(name) if name in pv else None for name in
                              ("soc", "current", "filtered_current", "temperature"))
        self._temperature_source_cols = model.temperature_source_indices()
        self._in_activation = [model.in_activation_step(c)
                               for c in model.temperature_term_sources()]
        self._any_activation = any(self._in_activation)
        dep = model.depletion
        # the low-pass states of the depletion regressors d (and d2), in column order
        self.depletion_states = [] if dep is None else dep.state_indices(model.filters)
        # the last features' (temperature, g(T)) and (SoC, depletion factor), for the
        # observers' derivatives of the same step
        self.last_gain = (math.nan, 1.0)
        self.last_depletion = (math.nan, 1.0)

    def gain_at(self, temperature_c: float) -> float:
        """temperature_gain, the last features' value where the temperature is theirs."""
        last_t, g = self.last_gain
        return g if temperature_c == last_t else self.temperature_gain(temperature_c)

    def depletion_factor(self, soc: float) -> float:
        """The depletion factor at a SoC, the last features' value where the SoC is theirs."""
        last_soc, factor = self.last_depletion
        return factor if soc == last_soc else self.factor_of_soc(soc)

    def temperature_gain(self, temperature_c: float) -> float:
        """g(T) (arrhenius_factor) on current and filter regressors (1 without E)."""
        m = self.model
        return arrhenius_factor(temperature_c, m.arrhenius_k, m.reference_temperature_c,
                                m.activation_t0_k)

    def initial_state(self, soc0: float, h0: float | None = None) -> ExoState:
        m = self.model
        direction = CHARGE if m.initial_direction == "charge" else DISCHARGE
        return ExoState(float(soc0), [0.0] * (2 * len(m.filters)),
                        initial_hysteresis(soc0) if h0 is None else float(h0), direction,
                        [0.0] * (m.current_terms - 1))

    def eta(self, current_a: float) -> float:
        m = self.model
        return m.efficiency_charge if current_a > 0 else m.efficiency_discharge

    def coefficients_at(self, temperature_c: float | None) -> list[float]:
        """The filter coefficients of a step at the temperature (°C): coef, or with Eτ
        filter_coefficients at T (kept while T stays the same)."""
        if self.model.tau_activation_k is None or temperature_c is None:
            return self.coef
        last_t, coef = self._coef_at
        if temperature_c != last_t:
            coef = filter_coefficients(self.model, temperature_c, self._taus)
            self._coef_at = (temperature_c, coef)
        return coef

    def lmn_temperature(self, s: ExoState, temperature_c: float) -> float:
        """The temperature the step's temperature-dependent parts take (°C): the cell
        temperature plus the core rise k·LP_τ(i²) where the model has one."""
        return temperature_c + self.core_k * s.core if self.core_k else temperature_c

    def update(self, s: ExoState, current_a: float, temperature_c: float) -> None:
        """Advance the state by one step with the current held over it, at the cell
        temperature (°C; with the core rise it sets the filters' time constants where the model
        has Eτ)."""
        i = current_a
        if self.core_k:
            s.core = self.core_a * s.core + (1.0 - self.core_a) * i * i
            temperature_c = self.lmn_temperature(s, temperature_c)
        s.soc += self.soc_gain * self.eta(i) * i
        for k, a in enumerate(self.coefficients_at(temperature_c)):
            s.lp[k] = a * s.lp[k] + (1.0 - a) * i
        if self.gamma is not None:
            e = math.exp(-self.gamma * abs(i) * self.soc_gain)
            s.h = e * s.h + (1.0 - e) * (1.0 if i > 0 else -1.0 if i < 0 else 0.0)
        rest = self.model.rest_current_a
        if i > rest:
            s.direction = CHARGE
        elif i < -rest:
            s.direction = DISCHARGE

    def features(self, s: ExoState, current_a: float, temperature_c: float,
                 x: np.ndarray, z: np.ndarray) -> list[float]:
        """Fill x (exogenous regressors) and z (raw partition inputs) for the step just taken,
        at the cell temperature (°C; the core rise added here); returns each depletion
        regressor's g(T)·LP_τ(i) (its SoC factor apart), in column order (empty without one)."""
        m = self.model
        temperature_c = self.lmn_temperature(s, temperature_c)
        g = 1.0 if m.arrhenius_k is None else self.temperature_gain(temperature_c)
        self.last_gain = (temperature_c, g)
        lp = s.lp
        x[0] = g * current_a
        col = 1
        for past in s.past_current:
            x[col] = g * past
            col += 1
        for k in range(0, 2 * len(m.filters), 2):
            x[col] = g * (lp[k] - lp[k + 1])
            col += 1
        if m.hysteresis_gamma is not None:
            x[col] = s.h
            col += 1
        sources = [g * lp[k] for k in self.depletion_states]
        if sources:
            factor = self.factor_of_soc(s.soc)
            self.last_depletion = (s.soc, factor)
            for source in sources:
                x[col] = source * factor
                col += 1
        if m.ocv_input:
            x[col] = float(m.ocv(s.soc))
            col += 1
        if m.soc_input:
            x[col] = s.soc
            col += 1
        if m.offset:
            x[col] = 1.0
            col += 1
        if m.temperature_terms:
            self._temperature_terms(x, col, temperature_c)
        z_soc, z_current, z_filtered, z_temperature = self._z_index
        if z_soc is not None:
            z[z_soc] = s.soc
        if z_current is not None:
            z[z_current] = current_a
        if z_filtered is not None:
            z[z_filtered] = lp[1] if lp else current_a
        if z_temperature is not None:
            z[z_temperature] = temperature_c
        return sources

    def _temperature_terms(self, x: np.ndarray, col: int, temperature_c: float) -> None:
        """x[col:] = the source columns times dT, dT², … (model.temperature_term_sources; the
        hysteresis regressor times dA, dA², … where its terms are "arrhenius")."""
        m = self.model
        dt = m.temperature_step(temperature_c)
        da = (m.activation_step(temperature_c, self.gain_at(temperature_c))
              if self._any_activation else dt)
        power = power_a = 1.0
        for _ in range(m.temperature_terms):
            power *= dt
            power_a *= da
            for c, in_a in zip(self._temperature_source_cols, self._in_activation, strict=True):
                x[col] = (power_a if in_a else power) * x[c]
                col += 1

    def shift(self, s: ExoState, current_a: float) -> None:
        """After the features of step k: remember i(k) as a past current."""
        if s.past_current:
            s.past_current.pop()
            s.past_current.insert(0, current_a)


@dataclass
class ExoSeries:
    """Exogenous regressors, partition inputs, direction and SoC of a whole record."""

    x: np.ndarray          # (N, p − na)
    z: np.ndarray          # (N, d), normalised
    direction: np.ndarray  # (N,)
    soc: np.ndarray        # (N,)


def core_rise_coefficient(model: LmnModel) -> float:
    """a = exp(−Ts/τ) of the core rise's low-pass state c(k) = a·c(k−1) + (1 − a)·i(k)² (0
    without a core rise); the C takes this very value."""
    if not model.core_rise_k_per_a2:
        return 0.0
    return math.exp(-model.sample_time_s / model.core_rise_tau_s)


def lmn_temperatures(model: LmnModel, current_a: np.ndarray,
                     temperature_c: np.ndarray) -> np.ndarray:
    """The temperature (°C) each step's temperature-dependent parts take over a record of
    steps: the cell temperature plus the core rise k·LP_τ(i²) (ExoStepper.update's recursion,
    the same operations in the same order); the cell temperature itself without one."""
    k = model.core_rise_k_per_a2
    if not k:
        return temperature_c
    a = core_rise_coefficient(model)
    out = np.empty(len(current_a))
    c = 0.0
    for n, (i, t) in enumerate(zip(np.asarray(current_a, dtype=float).tolist(),
                                   np.asarray(temperature_c, dtype=float).tolist(), strict=True)):
        c = a * c + (1.0 - a) * i * i
        out[n] = t + k * c
    return out


def exo_series(model: LmnModel, current_a: np.ndarray, temperature_c: np.ndarray | None,
               soc0: float, capacity_ah: float | None = None, h0: float | None = None,
               soc: np.ndarray | None = None) -> ExoSeries:
    """Run the exogenous part of the step over a whole record (the same code as the step).

    soc: an optional SoC trajectory that replaces coulomb counting (training on a reference).
    """
    stepper = ExoStepper(model, capacity_ah)
    n = current_a.size
    s = stepper.initial_state(soc0, h0)
    X = np.zeros((n, model.n_exo))
    Z = np.zeros((n, len(model.partition_variables)))
    D = np.zeros(n, dtype=np.intp)
    S = np.zeros(n)
    temp = np.full(n, DEFAULT_TEMPERATURE_C) if temperature_c is None else temperature_c
    cur = current_a.tolist()
    tl = temp.tolist()
    for k in range(n):
        stepper.update(s, cur[k], tl[k])
        if soc is not None:
            s.soc = float(soc[k])
        stepper.features(s, cur[k], tl[k], X[k], Z[k])
        stepper.shift(s, cur[k])
        D[k], S[k] = s.direction, s.soc
    return ExoSeries(X, model.normalise(Z), D, S)


def rest_inputs(model: LmnModel, soc0: float, temperature_c: float, h0: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network's inputs at rest (zero current, filters settled) at SoC0: the exogenous
    regressors (1, n_exo), the normalised partition inputs (1, n_z) and the direction (1,),
    as LmnModel.blend takes them."""
    stepper = ExoStepper(model)
    s = stepper.initial_state(soc0, h0)
    x = np.zeros((1, model.n_exo))
    z = np.zeros((1, len(model.partition_variables)))
    stepper.features(s, 0.0, temperature_c, x[0], z[0])
    return x, model.normalise(z), np.array([s.direction])


NO_FIXED_POINT_BELOW = 1e-9   # |1 − ΣA| below which the network at rest has no fixed point


def fixed_point(model: LmnModel, soc0: float, temperature_c: float, h0: float) -> float:
    """Output ŷ of the network at rest (zero current, filters settled) at SoC0; 0 where it has
    no fixed point (|1 − ΣA| ≤ NO_FIXED_POINT_BELOW)."""
    A, b, _ = model.blend(*rest_inputs(model, soc0, temperature_c, h0))
    denom = 1.0 - float(A.sum())
    return float(b[0]) / denom if abs(denom) > NO_FIXED_POINT_BELOW else 0.0


def recursion(A: np.ndarray, b: np.ndarray, y_init: list[float]) -> np.ndarray:
    """Free-run ŷ(k) = Σ_l A(k,l)·ŷ(k−l) + b(k) from initial lags y_init = [ŷ(−1), ŷ(−2), …]."""
    na = A.shape[1]
    if na == 0:
        return b.copy()        # no output feedback: the recursion is the exogenous part
    n = b.size
    y = np.empty(n)
    lags = list(y_init)
    Al = A.tolist()
    bl = b.tolist()
    for k in range(n):
        a = Al[k]
        acc = bl[k]
        for l in range(na):
            acc += a[l] * lags[l]
        y[k] = acc
        if na:
            lags.pop()
            lags.insert(0, acc)
    return y


@dataclass
class SimResult:
    """Free-run simulation of a record: voltage (V), SoC, network output ŷ and validities; and
    where the run was driven by the ambient temperature, the cell temperature (°C) that the
    thermal model computed at the end of each step, as the FMU's output cell_temperature
    (None otherwise)."""

    voltage_v: np.ndarray
    soc: np.ndarray
    y: np.ndarray
    validity: np.ndarray
    cell_temperature_c: np.ndarray | None = None


def simulate_exo(model: LmnModel, ex: ExoSeries, soc0: float, h0: float,
                 temperature0_c: float) -> SimResult:
    """Free-run simulation from precomputed exogenous series (see exo_series)."""
    A, b, Phi = model.blend(ex.x, ex.z, ex.direction)
    y0 = fixed_point(model, soc0, temperature0_c, h0)
    y = recursion(A, b, [y0] * model.output_lags)
    u = y + model.ocv(ex.soc) if model.relative_ocv else y
    return SimResult(np.asarray(u), ex.soc, y, Phi)


def simulate(model: LmnModel, current_a: np.ndarray, temperature_c: np.ndarray | None,
             soc0: float, capacity_ah: float | None = None, h0: float | None = None,
             soc: np.ndarray | None = None) -> SimResult:
    """Free-run (parallel-model) simulation of one record sampled at the model's Ts.

    current_a: current held over each step (A, > 0 charges); temperature_c: °C per step or None
    (then 25 °C); soc0: SoC before the first step; capacity_ah: overrides the model's; h0: initial
    hysteresis state (default initial_hysteresis(soc0)); soc: a SoC trajectory replacing coulomb
    counting.
    """
    if h0 is None:
        h0 = initial_hysteresis(soc0)
    ex = exo_series(model, np.asarray(current_a, dtype=float), temperature_c, soc0, capacity_ah,
                    h0, soc)
    t0 = DEFAULT_TEMPERATURE_C if temperature_c is None else float(temperature_c[0])
    return simulate_exo(model, ex, soc0, h0, t0)


def picker(indices: list[int]) -> Callable[[Sequence[float]], Sequence[float]]:
    """The entries of a sequence at indices, as a tuple (operator.itemgetter, which returns a
    bare value for one index, made to return a tuple for any number of them)."""
    if not indices:
        return lambda values: ()
    pick = operator.itemgetter(*indices)
    return pick if len(indices) != 1 else (lambda values: (pick(values),))


class _OneSample:
    """LmnModel.blend and ocv for one sample in plain Python (the FMU's per-step cost): the
    same validities and blend as the batch path up to floating-point rounding (the partition
    normalisation is folded into each node's weights, sums run in another order), and the OCV
    bit for bit as np.interp. Built for a model that does not change afterwards (a
    stepper's)."""

    def __init__(self, model: LmnModel) -> None:
        weights = model.raw_node_weights()
        order, into, leaf_slots, self.n_slots = tree_plan(model.leaf_paths)
        self.leaves = picker(leaf_slots)        # the leaves' validities from the slots
        self.plan = [(into[node], 1 + 2 * node) for node in order]
        self.plan3 = [(parent, out, out + 1) for parent, out in self.plan]   # (parent, sides)
        node_w = np.array([[weights[node][0], *weights[node][1]] for node in order]
                          ).reshape(len(order), 1 + len(model.partition_variables))
        na = model.output_lags
        theta_exo = model.theta[:, na:]
        # one product gives the nodes' activations and the local models' exogenous parts:
        # [act; θ_exo·x] = [[W, 0], [0, θ_exo]]·[1, z, x]
        self.n_nodes = len(order)
        self.block = np.zeros((self.n_nodes + theta_exo.shape[0], node_w.shape[1]
                               + theta_exo.shape[1]))
        self.block[:self.n_nodes, :node_w.shape[1]] = node_w
        self.block[self.n_nodes:, node_w.shape[1]:] = theta_exo
        # beside: (parent slot, first side's slot, other side's slot, ∂act/∂SoC) of each node
        # in order (none without a SoC partition input), and (0: soc(k), 1: ocv(k), 2: d(k),
        # 3: d2(k); each local model's coefficient) of the SoC regressors the model has
        pv = model.partition_variables
        self.slope_plan = ([(into, out, out + 1, weights[node][1][pv.index("soc")])
                            for (into, out), node in zip(self.plan, order, strict=True)]
                           if "soc" in pv else [])
        exo = model.columns()[na:]
        self.slope_columns = [(which, theta_exo[:, exo.index(name)].tolist())
                              for which, name in enumerate(("soc(k)", "ocv(k)",
                                                            *DEPLETION_COLUMNS))
                              if name in exo]
        self.gates = [GATE_CODES[g] for g in model.leaf_gates]
        self.gated = model.gating_mode == "current_sign"
        self.theta_lags = model.theta[:, :na].tolist()
        self.na = na
        self.ocv_soc = model.ocv_soc.tolist()
        self.ocv_v = model.ocv_v.tolist()

    def ocv(self, soc: float) -> float:
        """np.interp(soc, ocv_soc, ocv_v) for one value: linear, held beyond the ends."""
        return interp_one(soc, self.ocv_soc, self.ocv_v)

    def combine(self, products: list[float], direction: int
                ) -> tuple[list[float], float, Sequence[float], list[float]]:
        """(blended lag coefficients, exogenous part, validities, each local model's exogenous
        part θ_exo,j·x) of one sample from products = block·u,
        u = [1, raw partition inputs, exogenous regressors]: the nodes' activations, then each
        local model's θ_exo,j·x."""
        validity = self.walk(products, direction)
        local = products[self.n_nodes:]
        b = sum(map(operator.mul, validity, local))
        a = [0.0] * self.na
        if self.na:
            for vj, row in zip(validity, self.theta_lags, strict=True):
                for l in range(self.na):
                    a[l] += vj * row[l]
        return a, b, validity, local

    def walk(self, activations: Sequence[float], direction: int
             ) -> Sequence[float]:
        """The validities from the nodes' activations (the first n_nodes entries of
        activations; any further entries are ignored)."""
        v = [1.0] * self.n_slots             # v[0]: a root's validity; then each node's sides
        exp = math.exp
        try:
            for (into, out, other), act in zip(self.plan3, activations, strict=False):
                parent = v[into]             # φ = 1/(1 + e^−act); sides φ·v and v − φ·v
                v[out] = side = parent / (1.0 + exp(-act))
                v[other] = parent - side
        except OverflowError:                # some act < −709.78: again, node by node
            for (into, out, other), act in zip(self.plan3, activations, strict=False):
                parent = v[into]
                try:
                    side = parent / (1.0 + exp(-act))
                except OverflowError:        # φ = 0, as numpy's inf gives
                    side = parent / math.inf
                v[out] = side
                v[other] = parent - side
        return self.leaf_values(v, direction)

    def walk_beside(self, activations: Sequence[float], d_hi: float, d_lo: float,
                    direction: int) -> tuple[Sequence[float], Sequence[float]]:
        """In one pass over the nodes: the validities had the SoC been d_hi above and d_lo
        below the one the activations were computed at (∂act/∂SoC from slope_plan); raises
        OverflowError where a moved activation overflows exp."""
        hi = [1.0] * self.n_slots
        lo = [1.0] * self.n_slots
        exp = math.exp
        for (into, out, other, w), act in zip(self.slope_plan, activations, strict=False):
            parent = hi[into]
            hi[out] = side = parent / (1.0 + exp(-(act + w * d_hi)))
            hi[other] = parent - side
            parent = lo[into]
            lo[out] = side = parent / (1.0 + exp(-(act - w * d_lo)))
            lo[other] = parent - side
        return self.leaf_values(hi, direction), self.leaf_values(lo, direction)

    def leaf_values(self, slots: list[float], direction: int) -> Sequence[float]:
        """Each leaf's validity from the tree slots, 0 where a current-sign gate does not match
        the direction."""
        values = self.leaves(slots)
        if not self.gated:
            return values
        return [0.0 if gate and gate != direction else value
                for value, gate in zip(values, self.gates, strict=True)]


def interp_one(x: float, xs: list[float], ys: list[float]) -> float:
    """np.interp(x, xs, ys) for one value (xs increasing): linear, held beyond the ends, NaN
    for NaN; without numpy's per-call array conversion."""
    if not x > xs[0]:
        return ys[0] if x == x else math.nan
    if x >= xs[-1]:
        return ys[-1]
    j = bisect.bisect_right(xs, x) - 1
    slope = (ys[j + 1] - ys[j]) / (xs[j + 1] - xs[j])
    return slope * (x - xs[j]) + ys[j]


def tree_plan(leaf_paths: list[list[tuple[int, int]]]
              ) -> tuple[list[int], dict[int, int], list[int], int]:
    """How to evaluate a discriminant tree one sample at a time, from each leaf's path
    [(node, side), …] (side 0: φ, side 1: 1 − φ). Slot 0 holds a root's validity (1); node n
    writes φ·v and (1 − φ)·v into slots 1 + 2n and 2 + 2n, v being the value in its parent's
    slot. Returns the nodes in an order that has every parent before its children, each node's
    parent slot, each leaf's slot, and the number of slots."""
    order: list[int] = []
    into: dict[int, int] = {}
    leaf_slots = []
    for path in leaf_paths:
        slot = 0
        for node, side in path:
            if node not in into:
                order.append(node)
                into[node] = slot
            slot = 1 + 2 * node + side
        leaf_slots.append(slot)
    return order, into, leaf_slots, 1 + 2 * max(order, default=-1) + 2


GATE_CODES = {"all": 0, "charge": CHARGE, "discharge": DISCHARGE}


class CellStepper:
    """Step-by-step free-run simulation (the FMU's engine): one call per model sample."""

    def __init__(self, model: LmnModel, soc0: float, capacity_ah: float | None = None,
                 temperature_c: float = DEFAULT_TEMPERATURE_C, h0: float | None = None) -> None:
        self.model = model
        self.exo = ExoStepper(model, capacity_ah)
        h0 = initial_hysteresis(soc0) if h0 is None else h0
        self.state = self.exo.initial_state(soc0, h0)
        y0 = fixed_point(model, soc0, temperature_c, h0)
        self.lags = [y0] * model.output_lags
        self.prev_lags = list(self.lags)
        d = len(model.partition_variables)
        self._u = np.ones(1 + d + model.n_exo)   # [1, raw partition inputs z, regressors x]
        self._z, self._x = self._u[1:1 + d], self._u[1 + d:]
        exo = model.columns()[model.output_lags:]
        pv = model.partition_variables      # where the SoC enters u besides the OCV
        self._soc_entries = [(1 + pv.index("soc"), False)] if "soc" in pv else []
        self._soc_entries += [(1 + d + exo.index(name), name == "ocv(k)")
                              for name in ("ocv(k)", "soc(k)") if name in exo]
        self._depletion_entries = [1 + d + exo.index(c) for c in DEPLETION_COLUMNS if c in exo]
        # the last step's g(T)·LP_τ(i) of each depletion regressor (ExoStepper.features)
        self._depletion_sources = [0.0] * len(self._depletion_entries)
        self.voltage_v = float(model.ocv(soc0)) + y0 if model.relative_ocv else y0
        self.validity: Sequence[float] = [0.0] * model.n_local_models   # Φ of the last step
        self._last_ocv = (math.nan, math.nan)      # (SoC, OCV) of the last step
        self._one = _OneSample(model)
        self._products: list[float] = []     # block·u of the last step (_OneSample)

    @property
    def soc(self) -> float:
        return self.state.soc

    def ocv(self, soc: float) -> float:
        """The model's OCV at one SoC (V), as np.interp gives it (the last step's value again
        when asked at that step's SoC: the FMU's heat term asks for it right after the step)."""
        last_soc, last_ocv = self._last_ocv
        return last_ocv if soc == last_soc else self._one.ocv(soc)

    def step(self, current_a: float, temperature_c: float = DEFAULT_TEMPERATURE_C) -> float:
        """Advance one sample with the current held over it; returns the terminal voltage (V)."""
        m, s, exo = self.model, self.state, self.exo
        exo.update(s, current_a, temperature_c)
        self._depletion_sources = exo.features(s, current_a, temperature_c, self._x, self._z)
        exo.shift(s, current_a)
        one = self._one
        self._products = (one.block @ self._u).tolist()
        a, acc, Phi, _ = one.combine(self._products, s.direction)
        if m.output_lags:
            lags = self.lags
            self.prev_lags = list(lags)
            for l in range(m.output_lags):
                acc += a[l] * lags[l]
            lags.pop()
            lags.insert(0, acc)
        self.validity = Phi
        if m.relative_ocv:
            self._last_ocv = (s.soc, one.ocv(s.soc))
            acc += self._last_ocv[1]
        self.voltage_v = acc
        return self.voltage_v

    def _products_at_socs(self, socs: list[float]) -> tuple[list[list[float]], list[float]]:
        """block·u of the last step with only its SoC entries replaced, one row per SoC, and
        the OCV at each SoC (the depletion regressor from the step's low-pass state as the step
        left it)."""
        one = self._one
        rows = np.empty((len(socs), self._u.size))
        rows[:] = self._u
        ocv = [one.ocv(soc) for soc in socs]
        for index, is_ocv in self._soc_entries:
            rows[:, index] = ocv if is_ocv else socs
        if self._depletion_entries:
            factors = [self.exo.factor_of_soc(soc) for soc in socs]
            for entry, source in zip(self._depletion_entries, self._depletion_sources,
                                     strict=True):
                rows[:, entry] = [source * factor for factor in factors]
        return (rows @ one.block.T).tolist(), ocv

    def voltages_at_socs(self, socs: list[float]) -> list[float]:
        """The last step's terminal voltage (V) had its SoC been each of socs (the first
        entries of outputs_at_socs alone)."""
        rows, ocv = self._products_at_socs(socs)
        return [self._row_output(products, soc_ocv)[0]
                for products, soc_ocv in zip(rows, ocv, strict=True)]

    def beside(self, hi: float, lo: float) -> tuple[float, float]:
        """(u(hi), u(lo)): the last step's terminal voltage (V) had its SoC been hi and lo,
        voltages_at_socs([hi, lo]) up to rounding, from the step's own products in one walk:
        the nodes' activations move by ∂act/∂SoC·ΔSoC, and each local model's exogenous part
        by its SoC regressors' coefficients times their change (soc(k), ocv(k),
        d(k) = g·LP_τ·factor(SoC)). Falls back to voltages_at_socs where a moved activation
        overflows exp, or before the first step."""
        one, soc = self._one, self.state.soc
        if not self._products:
            return self._beside_slowly(hi, lo)
        m, validity = self.model, self.validity
        phi_hi = phi_lo = validity
        if one.slope_plan:
            try:
                phi_hi, phi_lo = one.walk_beside(self._products, hi - soc, soc - lo,
                                                 self.state.direction)
            except OverflowError:
                return self._beside_slowly(hi, lo)
        local = self._products[one.n_nodes:]
        lag_part = self._lag_parts()
        if lag_part:
            local = [x + y for x, y in zip(local, lag_part, strict=True)]
        ocv_hi, ocv_lo = one.ocv(hi), one.ocv(lo)
        mul = operator.mul
        u_hi = sum(map(mul, phi_hi, local))
        u_lo = sum(map(mul, phi_lo, local))
        for which, column in one.slope_columns:
            if which == 0:
                d_hi, d_lo = hi - soc, lo - soc
            elif which == 1:
                ocv0 = self.ocv(soc)
                d_hi, d_lo = ocv_hi - ocv0, ocv_lo - ocv0
            else:
                source, factor = self._depletion_sources[which - 2], self.exo.factor_of_soc
                at = source * self.exo.depletion_factor(soc)
                d_hi, d_lo = source * factor(hi) - at, source * factor(lo) - at
            u_hi += d_hi * sum(map(mul, phi_hi, column))
            u_lo += d_lo * sum(map(mul, phi_lo, column))
        if m.relative_ocv:
            return u_hi + ocv_hi, u_lo + ocv_lo
        return u_hi, u_lo

    def _lag_parts(self) -> list[float]:
        """Each local model's output-lag part θ_lag,j·[ŷ(k−1), …] at the step's lags (empty
        without output lags)."""
        if not self.model.output_lags:
            return []
        return [sum(map(operator.mul, row, self.prev_lags)) for row in self._one.theta_lags]

    def _beside_slowly(self, hi: float, lo: float) -> tuple[float, float]:
        """beside from voltages_at_socs."""
        u_hi, u_lo = self.voltages_at_socs([hi, lo])
        return u_hi, u_lo

    def outputs_at_socs(self, socs: list[float]
                        ) -> list[tuple[float, Sequence[float], list[float]]]:
        """Per SoC: the last step's terminal voltage (V), validities and each local model's
        voltage (V) had its SoC been that one, every other regressor and partition input as
        the step had them: the observers' measurement model at candidate SoCs (at the step's
        own SoC, the step's voltage and validities)."""
        rows, ocv = self._products_at_socs(socs)
        out = []
        for products, soc_ocv in zip(rows, ocv, strict=True):
            u, validity, local, base = self._row_output(products, soc_ocv)
            out.append((u, validity, self._local_voltages(local, base)))
        return out

    def _row_output(self, products: list[float], soc_ocv: float
                    ) -> tuple[float, Sequence[float], list[float], float]:
        """(terminal voltage, validities, local exogenous parts, base) of one row of
        _products_at_socs; base is the OCV added to the network output (0 for an absolute
        output)."""
        m = self.model
        a, b, validity, local = self._one.combine(products, self.state.direction)
        for l in range(m.output_lags):
            b += a[l] * self.prev_lags[l]
        base = soc_ocv if m.relative_ocv else 0.0
        return b + base, validity, local, base

    def local_voltages_at_socs(self, socs: list[float]) -> list[list[float]]:
        """Per SoC each local model's voltage (V), the third entries of outputs_at_socs alone
        (no validities: no walk through the tree)."""
        rows, ocv = self._products_at_socs(socs)
        n = self._one.n_nodes
        relative = self.model.relative_ocv
        return [self._local_voltages(products[n:], soc_ocv if relative else 0.0)
                for products, soc_ocv in zip(rows, ocv, strict=True)]

    def _local_voltages(self, local: list[float], base: float) -> list[float]:
        """Each local model's voltage from its exogenous part θ_exo,j·x: plus its output-lag
        part at the step's lags, plus base (the OCV, or 0 for an absolute output)."""
        if self.model.output_lags:
            lags = self.prev_lags
            local = [x + sum(t * y for t, y in zip(row, lags, strict=True))
                     for x, row in zip(local, self._one.theta_lags, strict=True)]
        return [x + base for x in local]

    def get_state(self) -> list[float]:
        """Everything the next step depends on, as a flat list of floats."""
        return [*self.state.as_list(), *self.lags, self.voltage_v]

    def set_state(self, values: list[float]) -> None:
        """Restore this stepper's own get_state() list (the preview's save, taken back at
        every partial step: unchecked)."""
        m = self.model
        n_exo_state = len(self.state.as_list())     # this model's ExoState layout
        self.state = ExoState.from_list(list(values[:n_exo_state]), len(m.filters),
                                        m.current_terms - 1)
        self.lags = list(values[n_exo_state:n_exo_state + m.output_lags])
        self.voltage_v = float(values[n_exo_state + m.output_lags])

    def load_state(self, values: list) -> None:
        """Restore a get_state() list read from outside (an FMU state a host gave back):
        ValueError, and nothing changed, for one of another length or with a value that is not
        a number."""
        expected = len(self.state.as_list()) + self.model.output_lags + 1
        if len(values) != expected:
            raise ValueError(f"the model state holds {len(values)} values, expected {expected}")
        self.set_state([float(v) for v in values])


class CellThermal:
    """The cell temperature the LMN is stepped with, from the `temperature` input.

    With a thermal model in the model file and temperature_is_cell False, the input is the
    ambient temperature and the cell temperature follows the lumped model (thermal.py) heated
    by the step's i·(u − OCV); otherwise the input is the cell temperature itself. Used by the
    FMU (cosim) and by simulate_ambient, so both step the same way."""

    def __init__(self, model: LmnModel, temperature_is_cell: bool = False,
                 start_c: float | None = None) -> None:
        """start_c: the cell's temperature at the first step (°C), where the thermal model is
        active; None: rested at the first step's input."""
        self.model = model
        self.temperature_is_cell = temperature_is_cell
        self.start_c = start_c
        self.active = model.thermal is not None and not temperature_is_cell
        self._coefficients = (step_coefficients(model.thermal, model.sample_time_s)
                              if model.thermal is not None else None)
        self.temperature_c: float | None = (   # cell temperature at the step's start
            start_c if self.active else None)

    def rested(self, input_c: float) -> float:
        """The temperature of a cell rested at the given `temperature` input (°C); nothing
        changes."""
        return rested_temperature(self.model.thermal, input_c) if self.active else input_c

    def start_fault(self) -> str | None:
        """Why start_c cannot be taken (thermal.cell_start_fault), or None (also without
        one)."""
        if self.start_c is None:
            return None
        return cell_start_fault(self.start_c, self.active, self.temperature_is_cell)

    def start(self, input_c: float) -> float:
        """The cell temperature the first step starts from (°C), given its `temperature`
        input: start_c where given, else rested at the input; nothing changes."""
        return self.rested(input_c) if self.start_c is None else self.start_c

    def next_temperature(self, input_c: float) -> float:
        """The cell temperature the next step takes, given its `temperature` input (the first
        step's: rested at it); nothing changes."""
        if not self.active:
            return input_c
        return self.temperature_c if self.temperature_c is not None else self.rested(input_c)

    def cell_temperature(self, input_c: float) -> float:
        """next_temperature, kept as the cell temperature at the step's start."""
        temperature = self.next_temperature(input_c)
        if self.active:
            self.temperature_c = temperature
        return temperature

    def update(self, input_c: float, current_a: float, stepper: CellStepper) -> None:
        """After a step taken at cell_temperature(input_c): heat the cell for the next one."""
        thermal = self.model.thermal
        if not self.active or thermal is None:       # active: the model has a thermal model
            self.temperature_c = input_c
            return
        start = self.temperature_c
        if start is None:
            start = self.cell_temperature(input_c)
        q = heat_w(current_a, stepper.voltage_v, stepper.ocv(stepper.state.soc))
        self.temperature_c = next_temperature(thermal, start, input_c, q,
                                              self.model.sample_time_s, self._coefficients)


def simulate_ambient(model: LmnModel, current_a: np.ndarray, ambient_c: np.ndarray | float,
                     soc0: float, capacity_ah: float | None = None,
                     h0: float | None = None, cell_temperature_start_c: float | None = None
                     ) -> tuple[SimResult, np.ndarray]:
    """Free-run simulation driven by the ambient temperature: the cell temperature comes from
    the model's thermal model (as in the FMU with temperature_is_cell = false), starting at
    cell_temperature_start_c (°C; None: rested at the first ambient, as the FMU without
    use_cell_temperature_start). Returns the simulation and the cell temperature used at each
    step (°C). Without a thermal model the ambient temperature is taken as the cell
    temperature (and a start temperature is refused, as by the FMU)."""
    current = np.asarray(current_a, dtype=float)
    ambient = np.broadcast_to(np.asarray(ambient_c, dtype=float), current.shape)
    thermal = CellThermal(model, start_c=cell_temperature_start_c)
    fault = thermal.start_fault()
    if fault:
        raise ValueError(fault)
    t_start = thermal.start(float(ambient[0])) if current.size else DEFAULT_TEMPERATURE_C
    stepper = CellStepper(model, soc0, capacity_ah, t_start, h0)
    n = current.size
    u, soc, y = np.empty(n), np.empty(n), np.empty(n)
    cell, cell_end = np.empty(n), np.empty(n)
    phi = np.empty((n, model.n_local_models))
    for k, (i, ta) in enumerate(zip(current.tolist(), ambient.tolist(), strict=True)):
        cell[k] = thermal.cell_temperature(ta)
        u[k] = stepper.step(i, cell[k])
        soc[k] = stepper.soc
        y[k] = u[k] - stepper.ocv(soc[k]) if model.relative_ocv else u[k]
        phi[k] = stepper.validity
        thermal.update(ta, i, stepper)
        cell_end[k] = thermal.temperature_c
    return SimResult(u, soc, y, phi, cell_end), cell
