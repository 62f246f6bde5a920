"""The LMNCell model file: a versioned JSON document, loaded and checked here (numpy + stdlib).

Format ``lmncell-model``, version 9 (versions 1 to 8, which have no ``thermal``, no
``regressors.depletion``, no ``current_delay_s``, no ``regressors.time_constant_activation_k``,
no ``depletion.fast_tau_s``, no ``regressors.hysteresis_terms``, no
``regressors.activation_t0_k`` or no ``regressors.core_rise`` key, are read too).
Keys (units in the names, current > 0 charges, SoC 0…1):

- ``sample_time_s``: the model's fixed sample time Ts (1e-4 … 3600 s).
- ``current_delay_s`` (version 4; absent: 0): δ, 0 ≤ δ < Ts. The model is driven by the current
  δ seconds late: step k takes the mean current over [t_k − Ts − δ, t_k − δ] (before the first
  input, the first input held). It is the lag of a tester's voltage channel behind its current
  channel (Panasonic 18650PF drive cycles: 0.1 s), which the model reproduces so that its
  voltage lines up with such measurements when the current is given finer than Ts.
- ``cell``: ``capacity_ah`` (1e-4 … 1e5), ``efficiency_charge``, ``efficiency_discharge``
  (coulombic, η(i), 0 < η ≤ 1, absent: 1), ``voltage_min_v`` < ``voltage_max_v`` (0 … 10 V),
  ``name`` (a string; no control characters but tab and line breaks).
- ``output``: ``"relative_ocv"`` (local models describe u − OCV(SoC)) or ``"absolute"`` (the
  paper's form: local models describe u itself, OCV carried by their offsets).
- ``ocv``: ``soc`` (increasing, within −1 … 2) and ``voltage_v`` (0 … 10 V) knots, linear
  between them (held beyond the ends).
- ``regressors``: ``output_lags`` na, ``current_terms`` nb (i(k) … i(k−nb+1)), ``filters``: list of
  ``[tau_fast_s, tau_slow_s]`` each giving v = LP_fast(i) − LP_slow(i) (zero DC gain, eq. 19),
  ``hysteresis_gamma`` (null, or γ > 0 of h(k) = e·h(k−1) + (1−e)·sgn(i),
  e = exp(−γ|i|Ts/(3600·Cn))), ``ocv_input``, ``soc_input`` (extra regressors), ``offset``
  (constant 1): true or false (absent: false, false, true),
  ``arrhenius_k`` (null, or E in K, 0…20000: the current and filter regressors are multiplied by
  g(T) = exp(E·(1/(T+273.15) − 1/(T_ref+273.15))), T_ref = ``reference_temperature_c``),
  ``time_constant_activation_k`` (version 5; null or absent: none, or Eτ in K: every filter
  time constant is τ·exp(Eτ·(1/(T+273.15) − 1/(T_ref+273.15))) at the step's temperature T, the
  relaxation slower when cold; the file's time constants are those at T_ref),
  ``activation_t0_k`` (version 8; absent: 0): T0 in K, 0 ≤ T0 ≤ 200, of both: with T0 > 0
  each exp(E·(1/T − 1/T_ref)) above is exp(E·c·(1/(T − T0) − 1/(T_ref − T0))),
  c = ((T_ref − T0)/T_ref)², T in K (the Vogel–Tammann–Fulcher form: the same slope at T_ref,
  an apparent activation that grows towards the cold),
  ``core_rise`` (version 9; null or absent: none, or {``k_per_a2``, ``tau_s``}): the
  temperature that every temperature-dependent part of the step takes (g(T), the time
  constants, the temperature terms, the partition) is T + k·c(k), T the step's cell
  temperature (the ``temperature`` input, or the thermal model's), c(k) = a·c(k−1) +
  (1 − a)·i(k)², a = exp(−Ts/τ), c = 0 at the start (0 ≤ k ≤ 10 K/A², 0 < τ ≤ 1e5 s): the
  core's rise above the case under load, which follows the current's square,
  ``temperature_terms`` (0 by default, or the degree n ≤ 3: the current, filter and hysteresis
  regressors and the offset enter again multiplied by dT, …, dTⁿ, dT = (T − T_ref)/10 K; the
  hysteresis regressor as ``hysteresis_terms`` says),
  ``hysteresis_terms`` (version 7; absent: ``"polynomial"``): the hysteresis regressor's
  temperature terms: none (``"constant"``: each local model's hysteresis voltage H is one
  number), h·dTᵖ (``"polynomial"``) or h·dAᵖ (``"arrhenius"``, needs ``arrhenius_k`` E > 0),
  dA = (1 − g(T))·T_ref²/(E·10 K) with T_ref in K: the Arrhenius gain in the scale of dT
  (dA = dT to first order at T_ref), a hysteresis voltage H(T) that grows towards the cold as
  resistances do,
  ``depletion`` (version 3; null or absent: none, or {``tau_s``, ``power``, ``soc_scale``,
  ``soc_min``, ``fast_tau_s``}: the regressor d(k) = g(T)·LP_τ(i)·(soc_scale/max(SoC,
  soc_min))^power (0 < power ≤ 8; soc_scale, soc_min within 0…1), LP_τ the filters' low-pass
  state of time constant τ = ``tau_s``: a
  polarisation that grows as the cell nears empty, the voltage collapse before cut-off; its
  coefficient is a resistance at SoC = soc_scale, ≥ 0 in an RC-ladder model. ``fast_tau_s``
  (version 6; null or absent: none): a second such regressor d2(k), the same factor times the
  low-pass state LP_τ2(i) of that faster time constant: a collapse that follows the load within
  seconds and recovers as fast at rest).
  The local-model columns are, in order: y(k−1)…y(k−na), i(k)…i(k−nb+1), v_1…v_F, h, d, d2,
  OCV, SoC, 1, then those of the temperature terms ``<column>*dT^1`` … (``h(k)*dA^1`` … for
  ``"arrhenius"`` hysteresis terms; absent ones left out); ``columns`` lists their names.
- ``partition``: ``variables`` (subset of soc, current, filtered_current, temperature),
  ``center`` and ``scale`` (z = (raw − center)/scale).
- ``gating``: ``mode`` ``"none"`` or ``"current_sign"`` (separate charge and discharge trees;
  a rest, |i| ≤ ``rest_current_a``, keeps the tree of the last current above it),
  ``initial_direction``.
- ``tree``: ``roots`` [{``gate``: all|charge|discharge, ``child``: [kind, index]}], ``nodes``
  [{``weights``: [w0, w_1…w_d], ``children``: [[kind, index], [kind, index]]}], kind ``node`` or
  ``leaf``. The first child gets φ = 1/(1+exp(−(w0 + w·z))), the second 1 − φ; a leaf's validity is
  the product along its path (and 0 outside its gate).
- ``local_models``: ``theta`` (M rows of the columns above, each within ±1e9).
- ``limits``: the ranges seen in training (``current_a``, ``soc``, ``temperature_c``,
  ``voltage_v``), each [low, high] finite, low ≤ high.
- ``noise`` (σ and RMS within 0 … 10 V): ``residual_std_v`` of the free-run training error,
  (optional)
  ``residual_std_by_soc`` {``soc``: bin centres, ``std_v``: that error's RMS per bin of the
  reference SoC, never below ``residual_std_v``, times the identification's validation / fit
  free-run RMSE ratio (≥ 1; the error to expect on new data); the observers' SoC-variance
  floor}, (optional) ``residual_rms_by_soc`` {``soc``: the same bin centres,
  ``rms_v``: the free-run training error's RMS per bin, no floor; the EKF's measurement error
  σ_u(SoC)} and
  ``recent_current_rms_a``, the RMS of the training current low-passed over 150 s (observer
  defaults).
- ``observers`` (optional): ``fuzzy``, the fuzzy observer's offline design for the default
  settings: ``q`` (SoC² per step), ``r`` (V²), and per local model ``ocv_slopes_v`` (∂u_j/∂SoC at
  its centre, V), steady-state Kalman ``gains`` (1/V) and ``variances`` (SoC²).
- ``thermal`` (version 2; null or absent: no thermal model): the lumped thermal model of
  thermal.py, ``resistance_k_per_w`` R (K/W), ``time_constant_s`` τ (s), ``offset_k`` (rested
  cell above ambient, K). With it, the FMU's ``temperature`` input is the ambient temperature
  and the model computes the cell temperature (unless ``temperature_is_cell`` is set).
- ``baselines`` (optional) and ``training`` (metadata: the record files ``files`` and OCV tests
  ``ocv_test_files`` by ``name``, without their folder, with their ``sha256``, settings,
  metrics; no wall-clock time, so that the same data and settings give the same file);
  ``description`` (optional, a string as the cell's name: the FMU's description).

Any other key, at the top or in an object above (KNOWN_KEYS), is refused with its name: a
misspelt optional key would otherwise be ignored. The contents of ``baselines`` and
``training`` are not checked.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import numpy as np

from .thermal import CELL_TEMPERATURE_RANGE_C, ThermalModel, is_real_number

FORMAT = "lmncell-model"
DEPLETION_COLUMNS = ("d(k)", "d2(k)")   # the depletion regressors' columns (Depletion)
VERSION = 9
MAX_CORE_RISE_K_PER_A2 = 10.0     # core rise beyond it: 1000 K at 10 A
MAX_CORE_RISE_TAU_S = 1e5
MAX_TAU_ACTIVATION_K = 10000.0    # Eτ beyond it: τ changes by more than e^5 between 0 and 45 °C
MAX_ACTIVATION_T0_K = 200.0       # VTF T0: 13 K below the coldest input taken, −60 °C
MAX_ARRHENIUS_K = 20000.0    # E beyond it (≈ 166 kJ/mol): above any Li-ion activation energy
READABLE_VERSIONS = (1, 2, 3, 4, 5, 6, 7, 8, 9)
HYSTERESIS_TERMS = ("constant", "polynomial", "arrhenius")   # h's temperature terms, if any
PARTITION_VARIABLES = ("soc", "current", "filtered_current", "temperature")
MAX_TEMPERATURE_TERMS = 3
CAPACITY_RANGE_AH = (1e-4, 1e5)        # a cell's capacity (0.1 mAh … 100 kAh)
SAMPLE_TIME_RANGE_S = (1e-4, 3600.0)   # a model's sample time
VOLTAGE_RANGE_V = (0.0, 10.0)          # a cell's voltage (OCV knots, limits)
MAX_DEPLETION_POWER = 8.0              # as training's depletion_power (a step loops p times)
MAX_NOISE_V = 10.0                     # a voltage error's σ or RMS (V)
MAX_THETA = 1e9                        # |θ| beyond it is no cell's (squares overflowed)
LIMIT_KEYS = ("current_a", "soc", "voltage_v", "temperature_c")
TEMPERATURE_STEP_K = 10.0     # dT = (T − T_ref)/TEMPERATURE_STEP_K in the temperature terms
GATES = ("all", "charge", "discharge")
# The keys each object of a model file may hold (the module docstring says what each means); any
# other is refused by _check_known_keys, since a misspelt optional key would be ignored. The
# values of "baselines" and "training" are metadata, read by no model step, and not checked.
KNOWN_KEYS: dict[str, tuple[str, ...]] = {
    "": ("format", "version", "description", "sample_time_s", "current_delay_s", "cell",
         "output", "ocv", "regressors", "partition", "gating", "tree", "local_models", "limits",
         "noise", "observers", "thermal", "baselines", "training"),
    "cell": ("capacity_ah", "efficiency_charge", "efficiency_discharge", "voltage_min_v",
             "voltage_max_v", "name"),
    "ocv": ("soc", "voltage_v"),
    "regressors": ("output_lags", "current_terms", "filters", "hysteresis_gamma", "ocv_input",
                   "soc_input", "offset", "arrhenius_k", "time_constant_activation_k",
                   "activation_t0_k", "core_rise", "reference_temperature_c",
                   "temperature_terms", "hysteresis_terms", "depletion"),
    "partition": ("variables", "center", "scale"),
    "gating": ("mode", "rest_current_a", "initial_direction"),
    "tree": ("roots", "nodes"),
    "tree.roots": ("gate", "child"),
    "tree.nodes": ("weights", "children"),
    "local_models": ("columns", "theta"),
    "limits": LIMIT_KEYS,
    "noise": ("residual_std_v", "residual_std_by_soc", "residual_rms_by_soc",
              "recent_current_rms_a"),
    "noise.residual_std_by_soc": ("soc", "std_v"),
    "noise.residual_rms_by_soc": ("soc", "rms_v"),
    "observers": ("fuzzy",),
    "observers.fuzzy": ("q", "r", "ocv_slopes_v", "gains", "variances"),
}


class ModelFileError(ValueError):
    """A model file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class Depletion:
    """The depletion regressor d(k) = g(T)·LP_τ(i)·factor(SoC) (see the module docstring):
    tau_s (s) picks the filters' low-pass state, factor(SoC) = (soc_scale/max(SoC, soc_min))^power
    (1 at SoC = soc_scale, held below soc_min); with fast_tau_s (s) a second one,
    d2(k) = g(T)·LP_τ2(i)·factor(SoC)."""

    tau_s: float
    power: float
    soc_scale: float = 0.1
    soc_min: float = 0.02
    fast_tau_s: float | None = None    # the second regressor d2(k)'s time constant, or none

    def factor(self, soc: float) -> float:
        """(soc_scale/max(SoC, soc_min))^power for one SoC (an integer power by repeated
        multiplication, as the native FMU does: exact mirror, and no pow() per step)."""
        q = self.soc_scale / max(soc, self.soc_min)
        n = int(self.power)
        if n != self.power:
            return q ** self.power
        out = 1.0
        for _ in range(n):
            out *= q
        return out

    def factors(self, soc: np.ndarray) -> np.ndarray:
        """factor for an array of SoC (the same operations element by element)."""
        q = self.soc_scale / np.maximum(soc, self.soc_min)
        n = int(self.power)
        if n != self.power:
            return np.power(q, self.power)
        out = np.ones_like(q)
        for _ in range(n):
            out = out * q
        return out

    def state_index(self, filters: list[tuple[float, float]], tau_s: float | None = None) -> int:
        """Index of the low-pass state of time constant tau_s (default: the d regressor's)
        among the filters' states [fast_1, slow_1, fast_2, …] (the first that has it)."""
        tau = self.tau_s if tau_s is None else tau_s
        taus = [t for f in filters for t in f]
        if tau not in taus:
            raise ValueError(f"depletion time constant {tau:g} s is none of the filters' time "
                             f"constants {taus}")
        return taus.index(tau)

    def state_indices(self, filters: list[tuple[float, float]]) -> list[int]:
        """The low-pass states of the regressors in column order: [d] or [d, d2]."""
        taus = [self.tau_s] + ([] if self.fast_tau_s is None else [self.fast_tau_s])
        return [self.state_index(filters, tau) for tau in taus]

    def columns(self) -> list[str]:
        """The regressors' column names: DEPLETION_COLUMNS, d2(k) where fast_tau_s is set."""
        return list(DEPLETION_COLUMNS[:1 if self.fast_tau_s is None else 2])

    def to_dict(self) -> dict:
        return {"tau_s": self.tau_s, "power": self.power, "soc_scale": self.soc_scale,
                "soc_min": self.soc_min, "fast_tau_s": self.fast_tau_s}


@dataclass
class LmnModel:
    """Everything the runtime needs to step the network (see the module docstring)."""

    sample_time_s: float
    capacity_ah: float
    ocv_soc: np.ndarray
    ocv_v: np.ndarray
    output_lags: int
    current_terms: int
    filters: list[tuple[float, float]]
    hysteresis_gamma: float | None
    ocv_input: bool
    soc_input: bool
    offset: bool
    relative_ocv: bool
    partition_variables: list[str]
    partition_center: np.ndarray
    partition_scale: np.ndarray
    roots: list[tuple[str, tuple[str, int]]]
    node_weights: np.ndarray            # (n_nodes, 1 + d)
    node_children: list[tuple[tuple[str, int], tuple[str, int]]]
    theta: np.ndarray                   # (M, p)
    efficiency_charge: float = 1.0
    efficiency_discharge: float = 1.0
    gating_mode: str = "none"
    rest_current_a: float = 0.01
    initial_direction: str = "discharge"
    arrhenius_k: float | None = None
    tau_activation_k: float | None = None       # Eτ (K) of the filter time constants
    activation_t0_k: float = 0.0                # VTF T0 (K) of both; 0: Arrhenius
    core_rise_k_per_a2: float = 0.0             # core rise k (K/A²) of k·LP_τ(i²); 0: none
    core_rise_tau_s: float = 0.0                # its time constant τ (s)
    reference_temperature_c: float = 25.0
    temperature_terms: int = 0
    hysteresis_terms: str = "polynomial"        # none, h·dTᵖ or h·dAᵖ (HYSTERESIS_TERMS)
    depletion: Depletion | None = None
    thermal: ThermalModel | None = None
    current_delay_s: float = 0.0
    limits: dict = field(default_factory=dict)
    cell: dict = field(default_factory=dict)
    noise: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)   # baselines, training metadata, observers

    # ----- derived structure -------------------------------------------------------------
    def __post_init__(self) -> None:
        self._build_paths()

    def _build_paths(self) -> None:
        """Per leaf: gate and path of (node, side); index arrays for the vectorised product."""
        m = self.theta.shape[0]
        paths: list[list[tuple[int, int]] | None] = [None] * m
        gates: list[str] = ["all"] * m

        visited: set[int] = set()

        def walk(ref: tuple[str, int], path: list[tuple[int, int]], gate: str) -> None:
            kind, idx = ref
            limit = m if kind == "leaf" else len(self.node_children)
            if not 0 <= idx < limit:
                raise ModelFileError(f"tree: reference [{kind!r}, {idx}] out of range (there "
                                     f"are {limit} {kind}s)")
            if kind == "node":
                if idx in visited:
                    raise ModelFileError(f"tree: node {idx} is reached twice")
                visited.add(idx)
            if kind == "leaf":
                if paths[idx] is not None:
                    raise ModelFileError(f"tree: leaf {idx} is reached twice")
                paths[idx], gates[idx] = path, gate
                return
            for side, child in enumerate(self.node_children[idx]):
                walk(child, [*path, (idx, side)], gate)

        for gate, child in self.roots:
            walk(child, [], gate)
        leaf_paths = [p for p in paths if p is not None]
        if len(leaf_paths) < m:
            missing = [k for k, p in enumerate(paths) if p is None]
            raise ModelFileError(f"tree: local model(s) {missing} belong to no leaf")
        n_nodes = self.node_weights.shape[0]
        depth = max((len(p) for p in leaf_paths), default=0)
        # Index into q = [φ_0…φ_{n−1}, 1−φ_0…1−φ_{n−1}, 1]; padding points at the trailing 1.
        idx = np.full((m, max(depth, 1)), 2 * n_nodes, dtype=np.intp)
        for j, p in enumerate(leaf_paths):
            for k, (node, side) in enumerate(p):
                idx[j, k] = node + side * n_nodes
        self.leaf_paths = leaf_paths
        self.leaf_gates = gates
        self._path_index = idx
        self._gate_code = np.array([GATES.index(g) for g in gates])

    @property
    def n_local_models(self) -> int:
        return int(self.theta.shape[0])

    def filter_taus(self) -> list[float]:
        """Every filter side's time constant (s) at T_ref, in the order of the low-pass
        states: [fast_1, slow_1, fast_2, …]."""
        return [tau for f in self.filters for tau in f]

    @property
    def n_exo(self) -> int:
        return len(self.columns()) - self.output_lags

    def columns(self) -> list[str]:
        """Names of the local-model regressor columns, in order."""
        cols = self._plain_columns()
        for power in range(1, self.temperature_terms + 1):
            cols += [self.temperature_term_name(c, power) for c in self.temperature_term_sources()]
        return cols

    def temperature_term_name(self, source: str, power: int) -> str:
        """The column of a temperature term: ``<source>*dT^p``, or ``h(k)*dA^p`` where the
        hysteresis terms are "arrhenius"."""
        return f"{source}*{'dA' if self.in_activation_step(source) else 'dT'}^{power}"

    def in_activation_step(self, source: str) -> bool:
        """Whether a temperature-term source column enters times powers of dA (the hysteresis
        regressor of "arrhenius" hysteresis terms) rather than of dT."""
        return source == "h(k)" and self.hysteresis_terms == "arrhenius"

    @overload
    def activation_step(self, temperature_c: float, gain: float) -> float: ...

    @overload
    def activation_step(self, temperature_c: np.ndarray,
                        gain: np.ndarray | float) -> np.ndarray: ...

    def activation_step(self, temperature_c: np.ndarray | float,
                        gain: np.ndarray | float) -> np.ndarray | float:
        """dA = (1 − g)·T_ref²/(E·TEMPERATURE_STEP_K) (T_ref in K) of "arrhenius" hysteresis
        terms, from the Arrhenius gain g = g(T) at the temperature (°C) the caller has; dT
        (temperature_step) for "polynomial" ones."""
        if self.hysteresis_terms != "arrhenius":
            return self.temperature_step(temperature_c)
        e_k = self.arrhenius_k
        if e_k is None:
            raise ModelFileError("'arrhenius' hysteresis terms need the Arrhenius E")
        t_ref = self.reference_temperature_c + 273.15
        return (1.0 - gain) * (t_ref * t_ref / (e_k * TEMPERATURE_STEP_K))

    def _plain_columns(self) -> list[str]:
        """The columns without the temperature terms."""
        cols = [f"y(k-{l})" for l in range(1, self.output_lags + 1)]
        cols += ["i(k)" if l == 0 else f"i(k-{l})" for l in range(self.current_terms)]
        cols += [f"v{f + 1}(k)" for f in range(len(self.filters))]
        if self.hysteresis_gamma is not None:
            cols.append("h(k)")
        if self.depletion is not None:
            cols += self.depletion.columns()
        if self.ocv_input:
            cols.append("ocv(k)")
        if self.soc_input:
            cols.append("soc(k)")
        if self.offset:
            cols.append("1")
        return cols

    def temperature_term_sources(self) -> list[str]:
        """Columns that also enter multiplied by dT, dT², … up to ``temperature_terms``
        (dT = (T − T_ref)/TEMPERATURE_STEP_K): the current, filter and hysteresis regressors and
        the offset (resistances, time-constant gains and the OCV offset varying smoothly with
        temperature beyond the Arrhenius gain); not the depletion, OCV and SoC columns, nor the
        hysteresis regressor where its terms are "constant"."""
        left_out = (*DEPLETION_COLUMNS, "ocv(k)", "soc(k)",
                    *(("h(k)",) if self.hysteresis_terms == "constant" else ()))
        return [c for c in self._plain_columns()[self.output_lags:] if c not in left_out]

    @overload
    def temperature_step(self, temperature_c: float) -> float: ...

    @overload
    def temperature_step(self, temperature_c: np.ndarray) -> np.ndarray: ...

    def temperature_step(self, temperature_c: np.ndarray | float) -> np.ndarray | float:
        """dT = (T − T_ref)/TEMPERATURE_STEP_K of the temperature terms at T (°C), one
        temperature or an array of them (activation_step: that of "arrhenius" hysteresis
        terms)."""
        return (temperature_c - self.reference_temperature_c) / TEMPERATURE_STEP_K

    def temperature_source_indices(self) -> list[int]:
        """Positions of temperature_term_sources() among the exogenous columns (those after the
        output lags), as the step fills them."""
        exo = self.columns()[self.output_lags:]
        return [exo.index(c) for c in self.temperature_term_sources()]

    @overload
    def ocv(self, soc: float) -> float: ...

    @overload
    def ocv(self, soc: np.ndarray) -> np.ndarray: ...

    def ocv(self, soc: np.ndarray | float) -> np.ndarray | float:
        """Open-circuit voltage (V) at SoC (fraction), linear between knots, held beyond."""
        return np.interp(soc, self.ocv_soc, self.ocv_v)

    # ----- validity functions and blended local models ----------------------------------
    def validities(self, z: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Φ (N, M) for normalised partition inputs z (N, d) and direction codes (N,) where
        1 = charge, 2 = discharge (the gate of the current-sign pre-partition)."""
        n = z.shape[0]
        n_nodes = self.node_weights.shape[0]
        q = np.ones((n, 2 * n_nodes + 1))
        if n_nodes:
            act = self.node_weights[:, 0] + z @ self.node_weights[:, 1:].T
            with np.errstate(over="ignore"):   # exp overflow → φ = 0 exactly, as intended
                phi = 1.0 / (1.0 + np.exp(-act))
            q[:, :n_nodes] = phi
            q[:, n_nodes:2 * n_nodes] = 1.0 - phi
        Phi = np.prod(q[:, self._path_index], axis=2)
        if self.gating_mode == "current_sign":
            Phi = Phi * ((self._gate_code == 0)[None, :]
                         | (self._gate_code[None, :] == direction[:, None]))
        return Phi

    def blend(self, x_exo: np.ndarray, z: np.ndarray,
              direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For N samples: blended feedback coefficients A (N, na), exogenous part b (N,) and Φ.

        ŷ(k) = Σ_l A(k, l)·y(k−l) + b(k) is the network output (eq. 3 with eq. 2 inside).
        """
        Phi = self.validities(z, direction)
        na = self.output_lags
        A = Phi @ self.theta[:, :na]
        b = np.einsum("nm,nm->n", Phi, x_exo @ self.theta[:, na:].T)
        return A, b, Phi

    def normalise(self, raw: np.ndarray) -> np.ndarray:
        return (raw - self.partition_center) / self.partition_scale

    def raw_node_weights(self) -> list[tuple[float, list[float]]]:
        """Each node's activation over the raw partition inputs z, with the normalisation
        folded in: act = w0 + Σ w_k·(z_k − c_k)/s_k = b + Σ a_k·z_k; per node (b, [a_k…]),
        a_k = w_k/s_k (a_k of the SoC input is ∂act/∂SoC). The one-sample step and the
        native FMU both take these."""
        center = self.partition_center.tolist()
        scale = self.partition_scale.tolist()
        out = []
        for w in self.node_weights.tolist():
            a = [wk / sk for wk, sk in zip(w[1:], scale, strict=True)]
            out.append((w[0] - sum(ak * ck for ak, ck in zip(a, center, strict=True)), a))
        return out


# ----- reading and writing ---------------------------------------------------------------
def _get(doc: dict, key: str, where: str, kind: type | tuple[type, ...]):
    if key not in doc:
        raise ModelFileError(f"{where}: missing key '{key}'")
    val = doc[key]
    if not isinstance(val, kind) or (isinstance(val, bool) and kind is not bool):
        raise ModelFileError(f"{where}: key '{key}' is {type(val).__name__}, expected "
                             f"{getattr(kind, '__name__', kind)}")
    return val


def _array(doc: dict, key: str, where: str, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(_get(doc, key, where, list), dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{where}: key '{key}' is not a numeric array ({exc})") from exc
    if arr.ndim != ndim and not (arr.size == 0 and ndim == 2):
        raise ModelFileError(f"{where}: key '{key}' has {arr.ndim} dimension(s), expected {ndim}")
    if not np.isfinite(arr).all():
        raise ModelFileError(f"{where}: key '{key}' holds NaN or infinite values")
    return arr


def is_cell_capacity(value: float) -> bool:
    """Whether value (Ah) is a finite capacity within CAPACITY_RANGE_AH (the FMUs' 'capacity'
    parameter is refused outside it, as the model file's cell.capacity_ah)."""
    low, high = CAPACITY_RANGE_AH
    return math.isfinite(value) and low <= value <= high


def _real(doc: dict, key: str, where: str, low: float, high: float, default: float | None = None,
          low_open: bool = False) -> float:
    """doc[key] (or default where it is absent and a default is given) as a finite real number
    within low…high (low excluded with low_open), else ModelFileError naming the key, the
    value and the range (a NaN, a string or 1e300 there gave NaN outputs, TypeErrors or
    endless loops)."""
    if key not in doc and default is not None:
        return float(default)
    val = _get(doc, key, where, (int, float))
    if not (math.isfinite(val) and (low < val if low_open else low <= val) and val <= high):
        raise ModelFileError(f"{where}: '{key}' is {val!r}, expected a number within "
                             f"{low:g}{' (excluded)' if low_open else ''}…{high:g}")
    return float(val)


def _flag(doc: dict, key: str, where: str, default: bool) -> bool:
    """doc[key] (default where it is absent) as JSON true or false, else ModelFileError naming
    the key and the value (the string "false" read as a flag would be true)."""
    val = doc.get(key, default)
    if not isinstance(val, bool):
        raise ModelFileError(f"{where}: '{key}' is {val!r}, expected true or false")
    return val


def _ref(val, where: str) -> tuple[str, int]:
    if (not isinstance(val, list) or len(val) != 2 or val[0] not in ("node", "leaf")
            or not isinstance(val[1], int) or isinstance(val[1], bool)):
        raise ModelFileError(f"{where}: expected [\"node\"|\"leaf\", index], got {val!r}")
    return val[0], val[1]


def _thermal(doc: object, source: str) -> ThermalModel | None:
    """The thermal model of a model document, or None (key absent or null)."""
    if doc is None:
        return None
    keys = {"resistance_k_per_w", "time_constant_s", "offset_k"}
    if not isinstance(doc, dict) or set(doc) != keys:
        raise ModelFileError(f"{source}: 'thermal' must be null or an object with exactly the "
                             f"keys {sorted(keys)}, got {doc!r}")
    try:
        return ThermalModel(**{k: doc[k] for k in keys}).check(source)
    except ValueError as exc:
        raise ModelFileError(str(exc)) from None


def _core_rise(doc: object, where: str, version: int) -> dict[str, float]:
    """regressors.core_rise of a model document as LmnModel's two fields (0, 0: none)."""
    if doc is None:
        return {"core_rise_k_per_a2": 0.0, "core_rise_tau_s": 0.0}
    if version < 9:
        raise ModelFileError(f"{where}: 'core_rise' exists from version 9 on; this file says "
                             f"version {version}")
    if not isinstance(doc, dict) or set(doc) != {"k_per_a2", "tau_s"}:
        raise ModelFileError(f"{where}: 'core_rise' must be null or an object with the keys "
                             "'k_per_a2' and 'tau_s'")
    k = _real(doc, "k_per_a2", f"{where}: core_rise", 0.0, MAX_CORE_RISE_K_PER_A2)
    tau = _real(doc, "tau_s", f"{where}: core_rise", 0.0, MAX_CORE_RISE_TAU_S, low_open=True)
    return {"core_rise_k_per_a2": k, "core_rise_tau_s": tau if k else 0.0}


def _depletion(doc: object, filters: list[tuple[float, float]], where: str, version: int
               ) -> Depletion | None:
    """regressors.depletion of a model document, or None (absent or null)."""
    if doc is None:
        return None
    if version < 6 and isinstance(doc, dict) and doc.get("fast_tau_s") is not None:
        raise ModelFileError(f"{where}: 'depletion' has 'fast_tau_s', which model files have "
                             f"from version 6 on; this file says version {version}")
    keys = {"tau_s", "power", "soc_scale", "soc_min"}
    if (not isinstance(doc, dict) or not keys <= set(doc) <= keys | {"fast_tau_s"}
            or not all(is_real_number(doc[k]) and math.isfinite(doc[k]) and doc[k] > 0
                       for k in doc if doc[k] is not None or k != "fast_tau_s")):
        raise ModelFileError(f"{where}: 'depletion' must be null or an object with the keys "
                             f"{sorted(keys)} and optionally 'fast_tau_s' (null: none), each a "
                             f"finite number > 0, got {doc!r}")
    fast = doc.get("fast_tau_s")
    if doc["power"] > MAX_DEPLETION_POWER or doc["soc_min"] > 1.0 or doc["soc_scale"] > 1.0:
        raise ModelFileError(f"{where}: 'depletion' power {doc['power']!r}, soc_scale "
                             f"{doc['soc_scale']!r} and soc_min {doc['soc_min']!r}: expected "
                             f"a power within 0…{MAX_DEPLETION_POWER:g}, soc_scale and soc_min "
                             "within 0…1")
    dep = Depletion(**{k: float(doc[k]) for k in keys},
                    fast_tau_s=None if fast is None else float(fast))
    try:
        dep.state_indices(filters)
    except ValueError as exc:
        raise ModelFileError(f"{where}: {exc}") from None
    return dep


def _noise(doc: object, source: str) -> dict:
    """The 'noise' object; its optional residual_std_by_soc and residual_rms_by_soc checked
    (increasing SoC in 0…1, one finite σ ≥ 0 per SoC)."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: 'noise' must be an object, got {doc!r}")
    for key, values in (("residual_std_by_soc", "std_v"), ("residual_rms_by_soc", "rms_v")):
        by_soc = doc.get(key)
        if by_soc is None:
            continue
        where = f"{source}: noise.{key}"
        if not isinstance(by_soc, dict):
            raise ModelFileError(f"{where} must be an object with 'soc' and '{values}'")
        soc, std = _array(by_soc, "soc", where, 1), _array(by_soc, values, where, 1)
        if (soc.size == 0 or soc.size != std.size or np.any(np.diff(soc) <= 0)
                or soc[0] < 0 or soc[-1] > 1 or np.any(std < 0) or np.any(std > MAX_NOISE_V)):
            raise ModelFileError(f"{where}: expected increasing SoC within 0…1 and one σ within "
                                 f"0…{MAX_NOISE_V:g} V per SoC, got {by_soc!r}")
    for key, high in (("residual_std_v", MAX_NOISE_V), ("recent_current_rms_a", 1e6)):
        _real(doc, key, f"{source}: noise", 0.0, high, 0.0)
    return dict(doc)


def _limits(doc: object, source: str) -> dict:
    """The 'limits' object: each of LIMIT_KEYS present a [low, high] pair of finite numbers,
    low ≤ high (the trained ranges the out-of-range flag and the warnings compare with)."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: 'limits' must be an object, got {doc!r:.60}")
    for key in [k for k in LIMIT_KEYS if k in doc]:      # in LIMIT_KEYS order
        pair = doc[key]
        if not (isinstance(pair, list) and len(pair) == 2
                and all(is_real_number(x) and math.isfinite(x) for x in pair)
                and pair[0] <= pair[1]):
            raise ModelFileError(f"{source}: limits.{key} is {pair!r:.60}, expected [low, high] "
                                 "finite numbers, low ≤ high")
    return dict(doc)


def _check_observers(doc: object, source: str, n_local_models: int) -> None:
    """The 'observers' object: its fuzzy observer's offline design where present (q, r > 0,
    gains, variances and ocv_slopes_v one finite number per local model), which the fuzzy
    observer takes where its q and r are the ones it would design with."""
    if doc is None:
        return
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: 'observers' must be an object, got {doc!r:.60}")
    fuzzy = doc.get("fuzzy")
    if fuzzy is None:
        return
    where = f"{source}: observers.fuzzy"
    if not isinstance(fuzzy, dict):
        raise ModelFileError(f"{where} must be an object, got {fuzzy!r:.60}")
    for key in ("q", "r"):
        _real(fuzzy, key, where, 0.0, 1e6, low_open=True)
    for key in ("gains", "variances", "ocv_slopes_v"):
        if key not in fuzzy:
            continue
        values = _array(fuzzy, key, where, 1)
        low = 0.0 if key == "variances" else -1e6
        if values.size != n_local_models or (values < low).any() or (values > 1e6).any():
            raise ModelFileError(f"{where}: '{key}' is {fuzzy[key]!r:.80}, expected one number "
                                 f"within {low:g}…1e+06 per local model ({n_local_models})")


def model_from_dict(doc: dict, source: str = "<model>") -> LmnModel:
    """Check a model document and build the runtime model; errors name the file and key."""
    ver = _check_format(doc, source)
    _check_known_keys(doc, source)
    ts, delay = _read_timing(doc, source)
    cell = _cell_fields(doc, source)
    output = _get(doc, "output", source, str)
    if output not in ("relative_ocv", "absolute"):
        raise ModelFileError(f"{source}: 'output' is {output!r}, expected 'relative_ocv' or "
                             "'absolute'")
    ocv_soc, ocv_v = _read_ocv(doc, source)
    regressors = _regressor_fields(_get(doc, "regressors", source, dict),
                                   f"{source}: regressors", ver)
    variables, center, scale = _read_partition(doc, source)
    weights, children, roots = _read_tree(doc, source, len(variables))
    lm = _get(doc, "local_models", source, dict)
    model = LmnModel(
        sample_time_s=ts, ocv_soc=ocv_soc, ocv_v=ocv_v, relative_ocv=output == "relative_ocv",
        partition_variables=list(variables), partition_center=center, partition_scale=scale,
        roots=roots, node_weights=weights, node_children=children,
        theta=_read_theta(lm, source), **cell, **regressors, **_gating_fields(doc, source),
        thermal=_thermal(doc.get("thermal"), source), current_delay_s=float(delay),
        limits=_limits(doc.get("limits", {}), source),
        noise=_noise(doc.get("noise", {}), source),
        extra={k: doc[k] for k in ("baselines", "training", "observers", "description")
               if k in doc})
    _check_observers(doc.get("observers"), source, model.n_local_models)
    _check_local_models(model, lm, source)
    return model


def _cell_fields(doc: dict, source: str) -> dict:
    """The LmnModel fields of the document's 'cell': capacity (Ah), coulombic efficiencies and
    the cell's entry itself (its voltage limits and name checked)."""
    cell = _get(doc, "cell", source, dict)
    where = f"{source}: cell"
    fields = {"capacity_ah": _real(cell, "capacity_ah", where, *CAPACITY_RANGE_AH)}
    for k in ("charge", "discharge"):
        fields[f"efficiency_{k}"] = _real(cell, f"efficiency_{k}", where, 0.0, 1.0, 1.0,
                                          low_open=True)
    _check_cell_voltages(cell, where)
    _check_texts(doc, cell, source)
    return {**fields, "cell": dict(cell)}


def _regressor_fields(reg: dict, w: str, ver: int) -> dict:
    """The LmnModel fields of the document's 'regressors' (w: where, for the errors; ver: the
    format's version)."""
    na, nb, filters = _read_structure(reg, w)
    arrhenius, tau_activation, temperature_terms = _read_temperature(reg, w)
    t_low, t_high = CELL_TEMPERATURE_RANGE_C
    return dict(
        output_lags=na, current_terms=nb, filters=filters,
        hysteresis_gamma=_read_hysteresis_gamma(reg, w),
        ocv_input=_flag(reg, "ocv_input", w, False), soc_input=_flag(reg, "soc_input", w, False),
        offset=_flag(reg, "offset", w, True),
        arrhenius_k=None if arrhenius is None else float(arrhenius),
        tau_activation_k=None if tau_activation is None else float(tau_activation),
        activation_t0_k=_real(reg, "activation_t0_k", w, 0.0, MAX_ACTIVATION_T0_K, 0.0),
        **_core_rise(reg.get("core_rise"), w, ver),
        reference_temperature_c=_real(reg, "reference_temperature_c", w, t_low, t_high, 25.0),
        temperature_terms=temperature_terms,
        hysteresis_terms=_read_hysteresis_terms(reg, w, arrhenius, ver),
        depletion=_depletion(reg.get("depletion"), filters, w, ver))


def _read_theta(lm: dict, source: str) -> np.ndarray:
    """local_models.theta: a finite 2-D array within ±MAX_THETA (its shape is checked against
    the columns by _check_local_models)."""
    theta = _array(lm, "theta", f"{source}: local_models", 2)
    if theta.size and np.abs(theta).max() > MAX_THETA:
        raise ModelFileError(f"{source}: local_models.theta holds {np.abs(theta).max():g}, "
                             f"expected coefficients within ±{MAX_THETA:g}")
    return theta


def _gating_fields(doc: dict, source: str) -> dict:
    """The LmnModel fields of the document's 'gating' (absent: one tree for both directions)."""
    gating = _gating(doc.get("gating", {"mode": "none"}), f"{source}: gating")
    return dict(gating_mode=str(gating.get("mode", "none")),
                rest_current_a=_real(gating, "rest_current_a", f"{source}: gating", 0.0, 1e3,
                                     0.01, low_open=True),
                initial_direction=str(gating.get("initial_direction", "discharge")))


def _check_format(doc: dict, source: str) -> int:
    """The document's format and version (returned), refused unless this LMNCell reads them."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: expected a JSON object")
    fmt = doc.get("format")
    if fmt != FORMAT:
        raise ModelFileError(f"{source}: format is {fmt!r}, expected {FORMAT!r}")
    ver = doc.get("version")
    if ver not in READABLE_VERSIONS or isinstance(ver, bool):
        raise ModelFileError(f"{source}: model file version {ver!r}; this LMNCell reads versions "
                             f"{list(READABLE_VERSIONS)} (re-train or convert the model)")
    return ver


def _check_known_keys(doc: dict, source: str) -> None:
    """ModelFileError naming the object and the key where an object of the document holds a
    key that KNOWN_KEYS does not list for it (a misspelt "arrhenius" beside "arrhenius_k" was
    ignored, and the model stepped without its temperature scaling). Objects that are not
    JSON objects are left to the readers, which refuse them by type."""
    def objects(path: str, value: object) -> Iterator[tuple[str, str, dict]]:
        if isinstance(value, dict):
            yield path, path, value
            for key in value:
                child = f"{path}.{key}" if path else key
                if child in KNOWN_KEYS:
                    yield from objects(child, value[key])
        elif isinstance(value, list) and path in ("tree.roots", "tree.nodes"):
            for k, item in enumerate(value):
                if isinstance(item, dict):
                    yield path, f"{path}[{k}]", item

    for kind, where, obj in objects("", doc):
        unknown = [key for key in obj if key not in KNOWN_KEYS[kind]]
        if unknown:
            raise ModelFileError(
                f"{source}{': ' + where if where else ''}: unknown key {unknown[0]!r}; expected "
                f"only {', '.join(KNOWN_KEYS[kind])} (a misspelt key would be ignored)")


def _read_timing(doc: dict, source: str) -> tuple[float, float]:
    """Sample time Ts (s, > 0) and current delay δ (s, 0 ≤ δ < Ts)."""
    ts = _real(doc, "sample_time_s", source, *SAMPLE_TIME_RANGE_S)
    delay = doc.get("current_delay_s", 0.0)
    if not is_real_number(delay) or not 0.0 <= delay < ts:
        raise ModelFileError(f"{source}: 'current_delay_s' is {delay!r}, expected a number "
                             f"0 ≤ δ < sample_time_s = {ts} s")
    return ts, float(delay)


def _read_ocv(doc: dict, source: str) -> tuple[np.ndarray, np.ndarray]:
    """The OCV table: SoC knots (increasing) and voltages (V), of one length ≥ 2."""
    ocv = _get(doc, "ocv", source, dict)
    ocv_soc, ocv_v = _array(ocv, "soc", f"{source}: ocv", 1), _array(ocv, "voltage_v",
                                                                      f"{source}: ocv", 1)
    if ocv_soc.shape != ocv_v.shape or ocv_soc.size < 2 or (np.diff(ocv_soc) <= 0).any():
        raise ModelFileError(f"{source}: ocv.soc and ocv.voltage_v must have the same length "
                             "(≥ 2) and soc must increase")
    low, high = VOLTAGE_RANGE_V
    if ((ocv_v < low) | (ocv_v > high)).any() or ocv_soc[0] < -1.0 or ocv_soc[-1] > 2.0:
        raise ModelFileError(f"{source}: ocv spans SoC {ocv_soc[0]:g}…{ocv_soc[-1]:g} and "
                             f"{ocv_v.min():g}…{ocv_v.max():g} V; expected SoC knots within "
                             f"-1…2 and a cell's voltages within {low:g}…{high:g} V")
    return ocv_soc, ocv_v


def _check_cell_voltages(cell: dict, where: str) -> None:
    """The cell's voltage_min_v and voltage_max_v where given: within VOLTAGE_RANGE_V, the
    minimum below the maximum (drive cycles take their cut-off from them)."""
    given = [_real(cell, k, where, *VOLTAGE_RANGE_V) for k in ("voltage_min_v", "voltage_max_v")
             if k in cell]
    if len(given) == 2 and not given[0] < given[1]:
        raise ModelFileError(f"{where}: voltage_min_v {given[0]:g} V is not below voltage_max_v "
                             f"{given[1]:g} V")


# characters that XML 1.0 does not allow, not even escaped (control characters, surrogates)
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def xml_text(text: str) -> str:
    """text with each character that XML does not allow replaced by U+FFFD (for names taken
    from file names, which may hold control characters or undecodable bytes)."""
    return _NOT_XML.sub("\ufffd", text)


def _check_texts(doc: dict, cell: dict, source: str) -> None:
    """The cell's name and the model's description, where given, are strings of characters
    that XML allows (the FMU builders write them into modelDescription.xml, the FMU's
    documentation and its sources)."""
    for where, holder, key in ((f"{source}: cell", cell, "name"), (source, doc, "description")):
        if key not in holder:
            continue
        text = holder[key]
        if not isinstance(text, str):
            raise ModelFileError(f"{where}: '{key}' is {text!r:.60}, expected a string")
        bad = _NOT_XML.search(text)
        if bad:
            raise ModelFileError(f"{where}: '{key}' holds the character {bad.group()!r} at "
                                 f"position {bad.start()}, expected text that XML allows (no "
                                 "control characters but tab and line breaks)")


def _gating(doc: object, where: str) -> dict:
    """The 'gating' object: mode and initial_direction as strings (checked by the model)."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{where}: expected an object, got {doc!r:.60}")
    direction = doc.get("initial_direction", "discharge")
    if direction not in ("discharge", "charge"):
        raise ModelFileError(f"{where}: 'initial_direction' is {direction!r}, expected "
                             "'discharge' or 'charge'")
    return doc


def _read_structure(reg: dict, where: str) -> tuple[int, int, list[tuple[float, float]]]:
    """Output lags na ≥ 0, current terms nb ≥ 1 and the filters [(τ_fast, τ_slow)] (s)."""
    na = _get(reg, "output_lags", where, int)
    nb = _get(reg, "current_terms", where, int)
    given = _get(reg, "filters", where, list)
    if not all(isinstance(f, list) and all(is_real_number(x) and math.isfinite(x) for x in f)
               for f in given):
        raise ModelFileError(f"{where}: 'filters' is {given!r:.80}, expected a list of "
                             "[tau_fast_s, tau_slow_s] pairs of finite numbers")
    pairs = [tuple(float(x) for x in f) for f in given]
    if na < 0 or nb < 1 or any(len(f) != 2 or not 0 < f[0] < f[1] for f in pairs):
        raise ModelFileError(f"{where}: need output_lags ≥ 0, current_terms ≥ 1 and filters "
                             "[tau_fast_s, tau_slow_s] with 0 < fast < slow")
    return na, nb, [(f[0], f[1]) for f in pairs]


def _read_hysteresis_gamma(reg: dict, where: str) -> float | None:
    """The hysteresis rate γ > 0 (None: no hysteresis state)."""
    gamma = reg.get("hysteresis_gamma")
    if gamma is not None and not (is_real_number(gamma) and math.isfinite(gamma) and gamma > 0):
        raise ModelFileError(f"{where}: 'hysteresis_gamma' is {gamma!r}, expected null or a "
                             "finite number > 0")
    return None if gamma is None else float(gamma)


def _read_temperature(reg: dict, where: str) -> tuple[float | None, float | None, int]:
    """Arrhenius E (K or None), the time constants' Eτ (K or None) and the degree of the
    temperature terms."""
    arrhenius = reg.get("arrhenius_k")
    if arrhenius is not None and not (is_real_number(arrhenius) and math.isfinite(arrhenius)
                                      and 0 <= arrhenius <= MAX_ARRHENIUS_K):
        raise ModelFileError(f"{where}: 'arrhenius_k' is {arrhenius!r}, expected null or a "
                             f"number of K within 0…{MAX_ARRHENIUS_K:g}")
    tau_activation = reg.get("time_constant_activation_k")
    if tau_activation is not None and not (is_real_number(tau_activation)
                                           and math.isfinite(tau_activation)
                                           and 0 <= tau_activation <= MAX_TAU_ACTIVATION_K):
        raise ModelFileError(f"{where}: 'time_constant_activation_k' is {tau_activation!r}, "
                             f"expected null or a number of K within 0…{MAX_TAU_ACTIVATION_K:g}")
    temperature_terms = reg.get("temperature_terms", 0)
    if (not isinstance(temperature_terms, int) or isinstance(temperature_terms, bool)
            or not 0 <= temperature_terms <= MAX_TEMPERATURE_TERMS):
        raise ModelFileError(f"{where}: 'temperature_terms' is {temperature_terms!r}, expected "
                             f"an integer 0…{MAX_TEMPERATURE_TERMS} (the degree in dT)")
    return arrhenius, tau_activation, temperature_terms


def _read_hysteresis_terms(reg: dict, where: str, arrhenius: float | None, version: int
                           ) -> str:
    """The basis of the hysteresis regressor's temperature terms (HYSTERESIS_TERMS)."""
    basis = reg.get("hysteresis_terms", "polynomial")
    if version < 7 and basis != "polynomial":
        raise ModelFileError(f"{where}: 'hysteresis_terms' {basis!r} exists from version 7 on; "
                             f"this file says version {version}")
    if basis not in HYSTERESIS_TERMS:
        raise ModelFileError(f"{where}: 'hysteresis_terms' is {basis!r}, expected one of "
                             f"{', '.join(map(repr, HYSTERESIS_TERMS))}")
    if basis == "arrhenius" and not (arrhenius is not None and arrhenius > 0):
        raise ModelFileError(f"{where}: 'hysteresis_terms' is 'arrhenius' but 'arrhenius_k' is "
                             f"{arrhenius!r}, expected a number of K > 0 (its E)")
    return str(basis)


def _read_partition(doc: dict, source: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Partition variables and their normalisation (centre, scale > 0)."""
    part = _get(doc, "partition", source, dict)
    variables = _get(part, "variables", f"{source}: partition", list)
    bad = [v for v in variables if v not in PARTITION_VARIABLES]
    if bad:
        raise ModelFileError(f"{source}: partition variable(s) {bad} unknown; expected "
                             f"{PARTITION_VARIABLES}")
    center = _array(part, "center", f"{source}: partition", 1)
    scale = _array(part, "scale", f"{source}: partition", 1)
    d = len(variables)
    if center.size != d or scale.size != d or (scale <= 0).any():
        raise ModelFileError(f"{source}: partition center/scale need {d} entries, scale > 0")
    return variables, center, scale


def _read_tree(doc: dict, source: str, d: int
               ) -> tuple[np.ndarray, list[tuple[tuple[str, int], tuple[str, int]]],
                          list[tuple[str, tuple[str, int]]]]:
    """The tree: node weights (nodes, d + 1), each node's two children, the gated roots."""
    tree = _get(doc, "tree", source, dict)
    nodes = _get(tree, "nodes", f"{source}: tree", list)
    try:
        weights = (np.asarray([n.get("weights") for n in nodes], dtype=float) if nodes
                   else np.zeros((0, d + 1)))
    except (TypeError, ValueError, AttributeError) as exc:
        raise ModelFileError(f"{source}: tree node weights are not numeric arrays") from exc
    if weights.ndim != 2 or weights.shape[1] != d + 1 or not np.isfinite(weights).all():
        raise ModelFileError(f"{source}: tree node weights have shape {weights.shape}, "
                             f"expected (nodes, {d + 1}) finite values (bias + one per "
                             "partition variable)")
    children = []
    for k, n in enumerate(nodes):
        ch = n.get("children")
        if not isinstance(ch, list) or len(ch) != 2:
            raise ModelFileError(f"{source}: tree.nodes[{k}].children must be two references")
        children.append((_ref(ch[0], f"{source}: tree.nodes[{k}]"),
                         _ref(ch[1], f"{source}: tree.nodes[{k}]")))
    roots = []
    for k, r in enumerate(_get(tree, "roots", f"{source}: tree", list)):
        if not isinstance(r, dict):
            raise ModelFileError(f"{source}: tree.roots[{k}] is {r!r:.60}, expected an object "
                                 "{\"gate\": …, \"child\": [kind, index]}")
        gate = r.get("gate")
        if gate not in GATES:
            raise ModelFileError(f"{source}: tree.roots[{k}].gate is {gate!r}, expected {GATES}")
        roots.append((gate, _ref(r.get("child"), f"{source}: tree.roots[{k}]")))
    return weights.reshape(len(nodes), d + 1), children, roots


def _check_local_models(model: LmnModel, lm: dict, source: str) -> None:
    """θ's shape and named columns against the regressor definition; the gating mode."""
    theta = model.theta
    p = len(model.columns())
    if theta.ndim != 2 or theta.shape[1] != p:
        raise ModelFileError(f"{source}: local_models.theta has shape {theta.shape}, expected "
                             f"(M, {p}) for columns {model.columns()}")
    if "columns" in lm and lm["columns"] != model.columns():
        raise ModelFileError(f"{source}: local_models.columns {lm['columns']} do not match the "
                             f"regressor definition {model.columns()}")
    if model.gating_mode not in ("none", "current_sign"):
        raise ModelFileError(f"{source}: gating.mode {model.gating_mode!r} unknown")


def model_to_dict(model: LmnModel) -> dict:
    """The JSON document of a model (inverse of model_from_dict)."""
    doc = {
        "format": FORMAT, "version": VERSION,
        "description": model.extra.get("description", "LMNCell local model network cell model"),
        "sample_time_s": model.sample_time_s,
        "current_delay_s": model.current_delay_s,
        "cell": {**model.cell, "capacity_ah": model.capacity_ah,
                 "efficiency_charge": model.efficiency_charge,
                 "efficiency_discharge": model.efficiency_discharge},
        "output": "relative_ocv" if model.relative_ocv else "absolute",
        "ocv": {"soc": model.ocv_soc.tolist(), "voltage_v": model.ocv_v.tolist()},
        "regressors": {"output_lags": model.output_lags, "current_terms": model.current_terms,
                       "filters": [list(f) for f in model.filters],
                       "hysteresis_gamma": model.hysteresis_gamma,
                       "ocv_input": model.ocv_input, "soc_input": model.soc_input,
                       "offset": model.offset, "arrhenius_k": model.arrhenius_k,
                       "time_constant_activation_k": model.tau_activation_k,
                       "activation_t0_k": model.activation_t0_k,
                       "core_rise": (None if not model.core_rise_k_per_a2 else
                                     {"k_per_a2": model.core_rise_k_per_a2,
                                      "tau_s": model.core_rise_tau_s}),
                       "reference_temperature_c": model.reference_temperature_c,
                       "temperature_terms": model.temperature_terms,
                       "hysteresis_terms": model.hysteresis_terms,
                       "depletion": (None if model.depletion is None
                                     else model.depletion.to_dict())},
        "partition": {"variables": model.partition_variables,
                      "center": model.partition_center.tolist(),
                      "scale": model.partition_scale.tolist()},
        "gating": {"mode": model.gating_mode, "rest_current_a": model.rest_current_a,
                   "initial_direction": model.initial_direction},
        "tree": {"roots": [{"gate": g, "child": list(c)} for g, c in model.roots],
                 "nodes": [{"weights": model.node_weights[k].tolist(),
                            "children": [list(c) for c in model.node_children[k]]}
                           for k in range(model.node_weights.shape[0])]},
        "local_models": {"columns": model.columns(), "theta": model.theta.tolist()},
        "limits": model.limits, "noise": model.noise,
        "thermal": None if model.thermal is None else model.thermal.to_dict(),
    }
    for key in ("observers", "baselines", "training"):
        if key in model.extra:
            doc[key] = model.extra[key]
    return doc


MODEL_FILE_EXPECTED = ("expected the JSON model file that `lmncell train` writes (a data "
                       "record is not one: commands take the model first)")


def load_model(path: str | Path) -> LmnModel:
    """Read and check a model file (JSON only; nothing is executed)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ModelFileError(f"{path}: cannot read the model file ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise ModelFileError(f"{path}: not a text (JSON) model file ({exc.reason}); "
                             f"{MODEL_FILE_EXPECTED}") from exc
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path}: not valid JSON ({exc}); {MODEL_FILE_EXPECTED}") from exc
    return model_from_dict(doc, str(path))


def save_model(model: LmnModel, path: str | Path) -> Path:
    """Write the model as JSON; floats are written with repr, so loading is bit-identical.
    Written whole or not at all (replaced_whole): a full disk leaves no truncated model file."""
    path = Path(path)
    return write_text_whole(path, json.dumps(model_to_dict(model), indent=1, allow_nan=False)
                            + "\n")


def write_text_whole(path: str | Path, text: str) -> Path:
    """Write text in UTF-8 to path, whole or not at all (replaced_whole); returns the path."""
    with replaced_whole(path) as part:
        part.write_text(text, encoding="utf-8")
    return Path(path)


@contextmanager
def replaced_whole(path: str | Path) -> Iterator[Path]:
    """A temporary path beside `path` to write a file to; once the block completes, that file
    replaces `path` in one step (os.replace). Where the block raises (a full disk, a read-only
    folder, an error while writing), the temporary file is removed and `path`, if it exists,
    is left as it was: a model or FMU is never left half written for a host to load. A symbolic
    link, or a path that is no regular file (/dev/stdout, a pipe), is given as it is, to be
    written through, as open() would: the link stays, and so does whatever holds the file open."""
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_file()):
        yield path            # written through: a link, a device or pipe (/dev/stdout)
        return
    part = path.with_name(f".{path.name}.{os.getpid()}.part{path.suffix}")
    try:
        yield part
        if path.exists():
            shutil.copymode(path, part)           # the file keeps its permissions
        os.replace(part, path)
    except BaseException as exc:
        with suppress(OSError):   # nothing was written there (e.g. a read-only folder)
            part.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.filename in (None, str(part)):
            exc.filename = str(path)          # the file the user asked for, not the part
        raise

