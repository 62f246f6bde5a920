"""Training settings: documented defaults, TOML loading, checks with clear messages."""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from lmncell.identification.ladder import is_ladder
from lmncell.runtime.model import (
    MAX_ACTIVATION_T0_K,
    MAX_ARRHENIUS_K,
    MAX_CORE_RISE_K_PER_A2,
    MAX_CORE_RISE_TAU_S,
    MAX_TAU_ACTIVATION_K,
    MAX_TEMPERATURE_TERMS,
    PARTITION_VARIABLES,
    Depletion,
    is_real_number,
)

DEPLETION_TAU_S = 150.0    # the depletion regressor's low-pass time constant for "auto" (s)
DEPLETION_FAST_TAU_S = 5.0  # the fast depletion regressor's, where "auto" turns it on (s)
ACTIVATION_T0_K = 170.0    # activation_t0_k 'auto' with temperature regions: a carbonate
                           # electrolyte's Vogel–Tammann–Fulcher T0 (K), chosen before measuring
CORE_RISE_K_PER_A2 = 0.015  # core_rise_k_per_a2 'auto' where the records' cells warm up: the
                           # Panasonic 18650PF's (docs/settings.md, core_rise_k_per_a2)
OFFSET_BOUND_MV = 50.0     # offset_bound_mv 'auto' where slow OCV tests fix the OCV
OFFSET_RIDGE = 0.003       # offset_ridge 'auto' where slow OCV tests fix the OCV
OCV_TEST_ANCHOR = 0.003    # ocv_refinement: 1 mV off the test costs like this share of samples
OCV_REFINE_SOC_MIN = 0.1   # ocv_refinement: the test's OCV knots below this SoC stay as measured
OCV_REFINE_LEVELS = 3      # ocv_refinement 'auto': on for records at this many temperature levels
FILTER_CHAIN_S = (0.01, 5.0, 30.0, 150.0, 800.0, 3000.0)   # filters 'auto': the chain (s)
SUB_SECOND_SPLITS_S = (0.5, 2.0)   # filters 'auto': its first element split here (s) where …
SPLIT_MIN_SAMPLES = 5              # … the split lies at least this many samples Ts from 0
AUTO_SAMPLE_TIME_S = (0.1, 1.0)    # Ts from the records: their logging interval within these (s)
LOCAL_MODELS_PER_REGION = 8  # max_local_models 'auto': per temperature region (×2 with current)


SWITCH_SETTINGS = ("ocv_input", "soc_input", "oblique", "oe_refinement")
COUNT_SETTINGS = {"output_lags": (0, 10), "current_terms": (1, 10), "oe_max_iterations": (1, 10000),
                  "lm_iterations": (0, 1000), "ocv_knots": (3, 1001)}
REAL_SETTINGS = ("sample_time_s", "depletion_power", "validation_fraction", "outside_weight",
                 "soc_reference_sigma", "model_error_sigma_v", "oe_ridge", "max_pole",
                 "rest_current_a")


class ConfigError(ValueError):
    """A training setting that cannot be used; the message names the setting (`setting`, where
    one setting is at fault)."""

    def __init__(self, message: str, setting: str | None = None) -> None:
        super().__init__(message)
        self.setting = setting


class GivenSettings(dict):
    """The settings given (given_settings), with `origins`: the configuration file each
    setting was read from (settings given as arguments or with --set have none)."""

    origins: dict[str, str]


def output_file_problem(path: str | Path) -> str | None:
    """Why `path` cannot be a file to write (its folder does not exist, or it is a folder), or
    None; asked before work whose result would otherwise be lost when it is written."""
    path = Path(path)
    if path.is_dir():
        return "is a folder; expected a file name"
    if not path.parent.is_dir():
        return f"the folder {str(path.parent)!r} does not exist"
    return None


SETTING_CHOICES = {  # the settings with a fixed set of names
    "ocv_refinement": ("auto", "on", "off"),
    "local_model_form": ("auto", "rc_ladder", "free"),
    "output": ("relative_ocv", "absolute"),
    "pre_partition": ("none", "current_sign"),
    "temperature_regions": ("auto", "off"),
    "hysteresis_terms": ("constant", "polynomial", "arrhenius"),
    "region_growth": ("separate", "joint"),
    "stop": ("validation", "aicc"),
    "validation": ("block", "record", "none"),
    "robust_loss": ("huber", "none"),
}


@dataclass
class TrainConfig:
    """Settings of `lmncell train`: what each does and takes ("auto" is resolved from the
    records when training starts). Units are in the names. What was measured to choose each
    default, and the alternatives tried and not kept, is in docs/settings.md.

    Model structure
    sample_time_s: model sample time Ts (s); records are resampled to it (step means); at
    least a tenth of each training record's logging interval (a finer Ts is refused). Not
    given (or "auto"), `lmncell train` and lmncell.train take it from the records: their
    logging interval within AUTO_SAMPLE_TIME_S, 0.1…1 s (lmncell.identification.train.
    auto_sample_time; a 10 Hz log gives 0.1 s, a log of 1 s or slower 1 s), so that a host
    stepping the FMU at Ts with each step's mean current gives it what the log resolves
    (docs/settings.md); a configuration used on its own (train_lmn) keeps 1 s.
    current_delay_s: δ (s, 0 ≤ δ < Ts), the lag of the tester's voltage channel behind its
    current channel, which the model reproduces: the current enters δ late; "auto": estimated
    from the records (lmncell.data.lag; 0 for records sampled at Ts or slower).
    output_lags / current_terms: na past outputs y(k−1) … y(k−na) (0: local models without
    output feedback, which cannot go unstable) and nb currents i(k) … i(k−nb+1).
    filters: [tau_fast_s, tau_slow_s] pairs (s), each a regressor v = LP_fast(i) − LP_slow(i)
    of zero DC gain; "auto": the chain 0.01, 5, 30, 150, 800, 3000 s (relaxation from seconds
    to about an hour), for Ts below 1 s split also at 0.5 and 2 s where that is ≥ 5·Ts.
    hysteresis: "auto" (γ chosen by the OCV pre-fit, kept where it lowers the pre-fit's error
    enough, or where the validation error says so), "off", or γ (1): the state
    h(k) = e·h(k−1) + (1−e)·sgn(i), e = exp(−γ·|i|·Ts/(3600·Cn)), a regressor of every model.
    Where no OCV test fixes the OCV, the pre-fit that estimates it holds the hysteresis voltage
    |H| ≤ 0.2 V (a small γ leaves h a function of SoC that trades volts with the OCV).
    local_model_form: "rc_ladder" (every local model an equivalent circuit: R0, RC elements at
    the filters' time constants and the hysteresis voltage, all ≥ 0, by bounded least squares;
    needs output_lags = 0 and a chain of filters), "free" (the paper's unconstrained ARX), or
    "auto" (rc_ladder wherever the structure allows).
    output: "relative_ocv" (u − OCV(SoC) is modelled) or "absolute" (u itself).
    ocv_input / soc_input: OCV(SoC) or SoC as extra local-model regressors (true/false).
    depletion_power / depletion_tau_s: the depletion regressor d = g(T)·LP_τ(i)·(0.1/SoC)^p
    in every local model (SoC held at 0.02 below): a resistance that grows as the cell nears
    empty, for the voltage collapse before the cut-off. p = depletion_power (0: none); τ one of
    the filters' time constants (s), "auto": the one nearest 150 s on a log scale.
    depletion_fast_tau_s: a second such regressor d2 from LP_τ2(i), τ2 one of the filters'
    time constants (s), for a collapse that follows the load within seconds; 0: none; "auto":
    the one nearest 5 s where the network has temperature regions, else none.
    offset_bound_mv: in an RC ladder, |U_off| ≤ this (mV) for every local model's OCV offset;
    0: free; "auto": 50 mV where ocv_tests fix the OCV, else free (and free for output
    "absolute" or ocv_input, where the offset is not one from the OCV).

    Temperature
    temperature_scaling: an Arrhenius gain g(T) = exp(E·(1/T − 1/T_ref)) on the current and
    filter regressors: "auto" (on where the training temperatures span more than 5 K, E chosen
    by the pre-fits), "off", or E (K).
    time_constant_scaling: filter time constants τ·exp(Eτ·(1/T − 1/T_ref)): "auto" (on, with
    Eτ = 1500 K, where the measured temperature varies inside records by more than 2 K, i.e.
    the cells warm up under load), "off", or Eτ (K, 0…10000).
    activation_t0_k: T0 (K) of both: exp(E·c·(1/(T − T0) − 1/(T_ref − T0))),
    c = ((T_ref − T0)/T_ref)², the Vogel–Tammann–Fulcher form of an electrolyte's transport
    (the slope at T_ref is the Arrhenius one of E; the apparent activation grows towards the
    cold); 0: Arrhenius; "auto": ACTIVATION_T0_K (170 K) where the network has temperature
    regions (two or more chamber temperatures, no temperature terms: E must carry the
    cells' warm-up at each chamber temperature, 10 and 25 °C), else 0 (temperature terms
    carry the curvature; at one chamber temperature the warm-up spans a few K); 0…200 K.
    core_rise_k_per_a2 / core_rise_tau_s: the core's rise above the measured (case)
    temperature under load, k·LP_τ(i²) (K/A², s), added to the temperature that every
    temperature-dependent part of the model takes, in training and in the runtime (0: none);
    "auto": CORE_RISE_K_PER_A2 (0.015 K/A², measured on the Panasonic 18650PF) where the
    temperature varies inside some record by more than 2 K (cells warming up under load, as
    time_constant_scaling's "auto"), else 0; k within 0…10 K/A², τ > 0 s.
    temperature_terms: degree n of temperature terms: the current, filter and offset columns
    (and the hysteresis column as hysteresis_terms says) again times dT … dTⁿ,
    dT = (T − 25 °C)/10 K, so that resistances and OCV offsets vary smoothly with temperature
    and interpolate between training temperatures; "auto": min(2, L − 2) for L ≥ 3 training
    temperatures (records whose median temperatures lie ≥ 7.5 K apart), else 0; or 0…3. With
    temperature terms the partition is not split along temperature.
    hysteresis_terms: the hysteresis column's temperature terms: "constant" (none: one H per
    local model), "polynomial" (h·dT … h·dTⁿ) or "arrhenius" (h·dA … h·dAⁿ, dA the Arrhenius
    gain's step in the scale of dT: H growing towards the cold as the resistances do).
    temperature_regions: "auto" (where temperature is in the partition and no temperature
    terms carry it: one set of local models per chamber-temperature level, split apart by
    fixed sigmoids in the gaps between the levels; lmncell.identification.regions) or "off"
    (the tree may split along temperature anywhere).
    region_growth: with temperature regions, "separate" (each region's local models grow in
    turn, coldest first, each stopped by its own records' validation error) or "joint" (one
    growth over all regions).

    Partition and growth
    partition: partition-space variables, a list of soc, current, filtered_current,
    temperature; "auto": soc and current, plus temperature where the records lie at two or
    more temperatures (soc and temperature where temperature terms carry it).
    pre_partition: "none" or "current_sign" (separate charge and discharge trees).
    oblique: optimise all of a new split's weights (true) or only its own axis (false).
    max_local_models: upper bound on M, or "auto": 8 per training temperature where the local
    models differ by temperature (regions, or splits along it), else 8; twice that where the
    partition has the current.
    lm_iterations: Levenberg–Marquardt iterations on each new split's sigmoid weights (0: the
    best orthogonal split as the search found it).
    stop: "validation" (M with the lowest free-run validation error; at several temperature
    levels the geometric mean of each level's) or "aicc" (M with the lowest corrected Akaike
    criterion of the one-step loss).
    validation / validation_fraction: the validation samples of stop: "block"
    (validation_fraction of every record's time, in five blocks centred at 10, 30, 50, 70 and
    90 % of it), "record" (the last record given) or "none" (then stop is "aicc").
    max_pole: largest allowed magnitude of a local model's pole (stability repair; 1).

    Weights
    soc_window / outside_weight: samples whose reference SoC lies outside [lo, hi] get this
    weight in every fit.
    record_weights: one weight ≥ 0 per data file, in the order given (empty: all 1); 0 keeps a
    record for the ranges and plots only.
    soc_reference_sigma / model_error_sigma_v: each sample's weight is also multiplied by
    σ_u²/(σ_u² + (dOCV/dSoC·σ_SoC)²), σ_SoC the uncertainty of the coulomb-counted SoC
    (fraction), σ_u a typical model error (V): where the OCV is steep (near empty and full) a
    small SoC error is a large voltage error, and those samples count less (0: off).
    rest_current_a: a current of at most this magnitude (A) is a rest: the charge/discharge
    direction (pre-partition, gating) stays that of the last current above it.

    Output-error refinement (the last step: all local models at once, in free run)
    oe_refinement: whether to run it (true/false).
    oe_ridge: ρ ≥ 0, pull of each local model's coefficients back to the tree's locally
    weighted fit, ρ·‖θ − θ_tree‖² beside the data's Σ w·e² (e in V).
    offset_ridge: ρ ≥ 0, pull of every local model's OCV offset towards 0, ρ·n_j·U_off² (n_j
    its weighted sample count); "auto": 0.003 where ocv_tests fix the OCV and the model has no
    temperature terms, else 0.
    ocv_refinement: where ocv_tests fix the OCV, whether the refinement moves its knots too
    (anchored to the test's; below SoC 0.1 they stay as measured): "on", "off", or "auto" (on
    for records at three or more temperature levels).
    robust_loss: "huber" (quadratic within 1.345 robust standard deviations of the residual,
    linear beyond) or "none" (least squares).
    oe_max_iterations: the most function evaluations of the refinement's nonlinear least
    squares (models with output lags; without them it is solved directly).

    OCV
    ocv_tests: slow OCV tests (C/5 or slower): a discharge from full and a charge from empty,
    in either order, or one file with both; their mean branch becomes the model's OCV on its
    SoC scale (empty: the OCV is estimated from the data).
    ocv_knots: the OCV's knots, evenly spaced over SoC 0…1 (21: every 5 %), linear between.
    """

    sample_time_s: float = 1.0
    current_delay_s: str | float = "auto"
    output_lags: int = 0
    current_terms: int = 2
    filters: str | list[list[float]] = "auto"
    hysteresis: str | float = "auto"
    temperature_scaling: str | float = "auto"
    time_constant_scaling: str | float = "auto"
    activation_t0_k: str | float = "auto"
    core_rise_k_per_a2: str | float = "auto"
    core_rise_tau_s: float = 120.0
    local_model_form: str = "auto"
    output: str = "relative_ocv"
    ocv_input: bool = False
    depletion_power: float = 4.0
    offset_bound_mv: float | str = "auto"
    offset_ridge: float | str = "auto"
    ocv_refinement: str = "auto"
    depletion_tau_s: float | str = "auto"
    depletion_fast_tau_s: float | str = "auto"
    temperature_terms: str | int = "auto"
    hysteresis_terms: str = "constant"
    soc_input: bool = False
    partition: str | list[str] = "auto"
    pre_partition: str = "none"
    temperature_regions: str = "auto"
    region_growth: str = "separate"
    oblique: bool = True
    max_local_models: int | str = "auto"
    stop: str = "validation"
    validation: str = "block"
    validation_fraction: float = 0.2
    soc_window: list[float] = field(default_factory=lambda: [0.0, 1.0])
    outside_weight: float = 1.0
    soc_reference_sigma: float = 0.003
    model_error_sigma_v: float = 0.005
    oe_refinement: bool = True
    oe_max_iterations: int = 25
    oe_ridge: float = 0.001
    robust_loss: str = "huber"
    lm_iterations: int = 15
    max_pole: float = 0.9995
    ocv_knots: int = 21
    ocv_tests: list[str] = field(default_factory=list)
    rest_current_a: float = 0.01
    record_weights: list[float] = field(default_factory=list)

    def offset_bound_v(self) -> float:
        """The bound on |U_off| (V; 0: none): offset_bound_mv, or for "auto"
        OFFSET_BOUND_MV where slow OCV tests fix the OCV and the offset is one from the OCV
        (output "relative_ocv" without ocv_input), else none (an OCV estimated from dynamic
        records can be off by more, and the offsets carry that error; an absolute output's
        offset is the voltage level itself, and with the OCV as an input its coefficient
        shifts the offset)."""
        if self.offset_bound_mv == "auto":
            from_ocv = self.output == "relative_ocv" and not self.ocv_input
            return 1e-3 * OFFSET_BOUND_MV if self.ocv_tests and from_ocv else 0.0
        return 1e-3 * float(self.offset_bound_mv)

    def offset_ridge_weight(self) -> float:
        """ρ of the refinement's offset ridge: offset_ridge, or for "auto" OFFSET_RIDGE where
        slow OCV tests fix the OCV, else 0."""
        if self.offset_ridge == "auto":
            return OFFSET_RIDGE if self.ocv_tests else 0.0
        return float(self.offset_ridge)

    def depletion_time_constant_s(self) -> float:
        """τ of the depletion regressor: depletion_tau_s, or for "auto" the filters' time
        constant nearest DEPLETION_TAU_S on a log scale (the first of equals)."""
        if self.depletion_tau_s != "auto":
            return float(self.depletion_tau_s)
        return self.nearest_filter_time_constant_s(DEPLETION_TAU_S)

    def filter_pairs(self) -> list[tuple[float, float]]:
        """The filters' [tau_fast_s, tau_slow_s] pairs: as given, or for "auto"
        FILTER_CHAIN_S with its first element split at each SUB_SECOND_SPLITS_S of at least
        SPLIT_MIN_SAMPLES·Ts (none at Ts = 1 s; 0.5 and 2 s at 0.1 s)."""
        if not isinstance(self.filters, str):          # "auto", the one string allowed
            return [(float(a), float(b)) for a, b in self.filters]
        splits = [t for t in SUB_SECOND_SPLITS_S
                  if t >= SPLIT_MIN_SAMPLES * self.sample_time_s]
        chain = [FILTER_CHAIN_S[0], *splits, *FILTER_CHAIN_S[1:]]
        return list(itertools.pairwise(chain))

    def filter_time_constants_s(self) -> list[float]:
        """Every filter's time constants, in order [fast_1, slow_1, fast_2, …] (s)."""
        return [t for f in self.filter_pairs() for t in f]

    def nearest_filter_time_constant_s(self, tau_s: float) -> float:
        """The filters' time constant nearest tau_s on a log scale (the first of equals)."""
        return min(self.filter_time_constants_s(), key=lambda t: abs(math.log(t / tau_s)))

    def depletion_fast_time_constant_s(self) -> float | None:
        """τ2 of the fast depletion regressor, or None (0, no depletion regressor, or "auto"
        not yet resolved by the identification: lmncell.identification.construction)."""
        if not self.depletion_power or self.depletion_fast_tau_s in ("auto", 0):
            return None
        return float(self.depletion_fast_tau_s)

    def check(self) -> TrainConfig:
        """Raise ConfigError for settings that cannot work; return self."""
        self._check_kinds()
        self._check_structure()
        self._check_temperature()
        self._check_offsets()
        self._check_depletion()
        self._check_choices()
        self._check_growth()
        self._check_data()
        return self

    def _bad(self, name: str, why: str) -> ConfigError:
        return ConfigError(f"setting '{name}' = {getattr(self, name)!r}: {why}", name)

    def _check_kinds(self) -> None:
        """The settings that are a plain switch, count or number: true/false, an integer in
        its range (not a bool) or a finite real number (not a bool); the OCV tests a list of
        file names."""
        for name in SWITCH_SETTINGS:
            if not isinstance(getattr(self, name), bool):
                raise self._bad(name, "expected true or false")
        for name, (low, high) in COUNT_SETTINGS.items():
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool)
                    and low <= value <= high):
                raise self._bad(name, f"expected an integer {low}…{high}")
        for name in REAL_SETTINGS:
            value = getattr(self, name)
            if not (is_real_number(value) and math.isfinite(value)):
                raise self._bad(name, "expected a finite number")
        self._check_lists()
        tests = self.ocv_tests
        if not (isinstance(tests, (list, tuple)) and len(tests) <= 2
                and all(isinstance(t, (str, os.PathLike)) for t in tests)):
            raise self._bad("ocv_tests", "expected a list of one or two OCV test files")

    def _check_lists(self) -> None:
        """The list-valued settings are lists (or tuples) of the right shape (their values are
        checked later): filters of pairs, the SoC window of two, the partition and the record
        weights of any length."""
        if not (self.filters == "auto" or (isinstance(self.filters, (list, tuple)) and all(
                isinstance(f, (list, tuple)) and len(f) == 2 and all(is_real_number(x) for x in f)
                for f in self.filters))):
            raise self._bad("filters", "expected 'auto' or a list of [tau_fast_s, tau_slow_s] "
                                       "pairs")
        window = self.soc_window
        if not (isinstance(window, (list, tuple)) and len(window) == 2
                and all(is_real_number(x) for x in window)):
            raise self._bad("soc_window", "expected [low, high]")
        if not (self.partition == "auto" or (isinstance(self.partition, (list, tuple))
                                             and all(isinstance(v, str) for v in self.partition))):
            raise self._bad("partition", f"expected 'auto' or a list of names from "
                            f"{PARTITION_VARIABLES}")
        if not isinstance(self.record_weights, (list, tuple)):
            raise self._bad("record_weights", "expected a list of weights, one per data file")

    def _check_structure(self) -> None:
        """Sample time, delay, lags, filters, RC-ladder form, OCV knots, pole bound."""
        bad = self._bad
        if not self.sample_time_s > 0:
            raise bad("sample_time_s", "expected > 0 s")
        for f in self.filter_pairs():
            if not 0 < f[0] < f[1]:
                raise bad("filters", "expected pairs [tau_fast_s, tau_slow_s], 0 < fast < slow")
        if self.local_model_form == "rc_ladder" and not is_ladder(
                self.filter_pairs(), self.sample_time_s, self.output_lags):
            raise bad("local_model_form", "RC-ladder local models need output_lags = 0 and a "
                      "chain of filters whose time constants at or above sample_time_s are "
                      "shared like [[0.01, 5], [5, 30], [30, 150]]; use 'free' or 'auto'")
        if not 0.9 < self.max_pole < 1:
            raise bad("max_pole", "expected 0.9 < max_pole < 1")
        if not (self.current_delay_s == "auto" or (
                is_real_number(self.current_delay_s)
                and 0.0 <= self.current_delay_s < self.sample_time_s)):
            raise bad("current_delay_s", f"expected 'auto' or 0 ≤ δ < sample_time_s = "
                                         f"{self.sample_time_s} s")

    def _check_temperature(self) -> None:
        """Hysteresis rate, Arrhenius E, the time constants' Eτ, temperature terms."""
        bad = self._bad
        if not (self.hysteresis in ("auto", "off") or (is_real_number(self.hysteresis)
                and 0 < self.hysteresis < math.inf)):
            raise bad("hysteresis", "expected 'auto', 'off' or a finite γ > 0")
        if not (self.temperature_scaling in ("auto", "off")
                or (is_real_number(self.temperature_scaling)
                    and 0 <= self.temperature_scaling <= MAX_ARRHENIUS_K)):
            raise bad("temperature_scaling",
                      f"expected 'auto', 'off' or E in K within 0…{MAX_ARRHENIUS_K:g}")
        if not (self.time_constant_scaling in ("auto", "off")
                or (is_real_number(self.time_constant_scaling)
                    and 0 <= self.time_constant_scaling <= MAX_TAU_ACTIVATION_K)):
            raise bad("time_constant_scaling",
                      f"expected 'auto', 'off' or Eτ in K within 0…{MAX_TAU_ACTIVATION_K:g}")
        if not (self.activation_t0_k == "auto" or (is_real_number(self.activation_t0_k)
                and 0 <= self.activation_t0_k <= MAX_ACTIVATION_T0_K)):
            raise bad("activation_t0_k",
                      f"expected 'auto' or T0 in K within 0…{MAX_ACTIVATION_T0_K:g}")
        if not (self.core_rise_k_per_a2 == "auto" or (is_real_number(self.core_rise_k_per_a2)
                and 0 <= self.core_rise_k_per_a2 <= MAX_CORE_RISE_K_PER_A2)):
            raise bad("core_rise_k_per_a2",
                      f"expected 'auto' or k in K/A² within 0…{MAX_CORE_RISE_K_PER_A2:g}")
        if not (is_real_number(self.core_rise_tau_s)
                and 0 < self.core_rise_tau_s <= MAX_CORE_RISE_TAU_S):
            raise bad("core_rise_tau_s",
                      f"expected τ in s within 0 (excluded)…{MAX_CORE_RISE_TAU_S:g}")
        if not (self.temperature_terms == "auto" or (isinstance(self.temperature_terms, int)
                and not isinstance(self.temperature_terms, bool)
                and 0 <= self.temperature_terms <= MAX_TEMPERATURE_TERMS)):
            raise bad("temperature_terms",
                      f"expected 'auto' or a degree 0…{MAX_TEMPERATURE_TERMS}")

    def _check_offsets(self) -> None:
        """The local OCV offsets' bound and ridge, and the refinement's ridge."""
        bound = self.offset_bound_mv
        if not (bound == "auto" or (is_real_number(bound) and 0 <= bound < 1e4)):
            raise self._bad("offset_bound_mv", "expected 'auto', 0 (unbounded) or a bound in mV")
        if self.output == "absolute" and bound not in ("auto", 0):
            raise self._bad("offset_bound_mv", "bounds each local model's offset from the OCV; "
                            "with output = 'absolute' the offset is the voltage level itself "
                            "(volts): expected 'auto' or 0 (unbounded)")
        ridge = self.offset_ridge
        if not (ridge == "auto" or (is_real_number(ridge) and 0 <= ridge <= 1)):
            raise self._bad("offset_ridge", "expected 'auto' or a weight ρ within 0…1 (0: off)")
        if not (is_real_number(self.oe_ridge) and 0 <= self.oe_ridge < 1e6):
            raise self._bad("oe_ridge", "expected a weight ρ ≥ 0 (V² per unit² of coefficient)")

    def _check_depletion(self) -> None:
        """The depletion regressors' power and time constants (each one of the filters')."""
        bad = self._bad
        if not (is_real_number(self.depletion_power) and 0 <= self.depletion_power <= 8):
            raise bad("depletion_power", "expected 0 (off) … 8")
        if self.depletion_power and not self.filter_pairs():
            raise bad("filters", "the depletion regressor low-passes the current with one of "
                                 "the filters' time constants: expected at least one filter "
                                 "(or set depletion_power = 0)")
        if self.depletion_power and self.depletion_tau_s != "auto":
            if not is_real_number(self.depletion_tau_s):
                raise bad("depletion_tau_s", "expected 'auto' or a time constant in s")
            try:
                Depletion(float(self.depletion_tau_s), 1.0).state_index(
                    self.filter_pairs())
            except ValueError as exc:
                raise bad("depletion_tau_s", f"{exc} (or set depletion_power = 0)") from None
        fast = self.depletion_fast_tau_s
        if fast != "auto" and (not is_real_number(fast) or fast < 0):
            raise bad("depletion_fast_tau_s", "expected 'auto', 0 (none) or a time constant in s")
        if self.depletion_power and fast not in ("auto", 0):
            taus = self.filter_time_constants_s()
            if float(fast) not in taus:
                raise bad("depletion_fast_tau_s", f"expected one of the filters' time constants "
                          f"{taus} (or 0: none)")
            if float(fast) == self.depletion_time_constant_s():
                raise bad("depletion_fast_tau_s", "expected a time constant other than the "
                          f"depletion regressor's {self.depletion_time_constant_s():g} s "
                          f"(depletion_tau_s = {self.depletion_tau_s!r}) (or 0: none)")

    def _check_choices(self) -> None:
        """Every setting with a fixed set of names (SETTING_CHOICES)."""
        for name, allowed in SETTING_CHOICES.items():
            if getattr(self, name) not in allowed:
                names = [f"'{a}'" for a in allowed]
                raise self._bad(name, f"expected {', '.join(names[:-1])} or {names[-1]}")

    def _check_growth(self) -> None:
        """Partition, the bound on M and the validation share."""
        part = self.partition
        if part != "auto" and (isinstance(part, str) or not part or len(set(part)) != len(part)
                               or any(p not in PARTITION_VARIABLES for p in part)):
            raise self._bad("partition", f"expected 'auto' or a list of distinct names from "
                            f"{PARTITION_VARIABLES}")
        if not (self.max_local_models == "auto" or (
                isinstance(self.max_local_models, int)
                and not isinstance(self.max_local_models, bool)
                and 1 <= self.max_local_models <= 64)):
            raise self._bad("max_local_models", "expected 'auto' or an integer 1…64")
        if not 0 < self.validation_fraction < 0.5:
            raise self._bad("validation_fraction", "expected 0 < fraction < 0.5")

    def _check_data(self) -> None:
        """SoC window and weights, the SoC reference's and the model's error σ, record weights."""
        bad = self._bad
        lo, hi = self.soc_window
        if not 0 <= lo < hi <= 1:
            raise bad("soc_window", "expected [low, high] with 0 ≤ low < high ≤ 1")
        if not 0 <= self.soc_reference_sigma < 0.1:
            raise bad("soc_reference_sigma", "expected 0 ≤ σ < 0.1 (a SoC fraction)")
        if not self.model_error_sigma_v > 0:
            raise bad("model_error_sigma_v", "expected > 0 V")
        weights = self.record_weights
        if (any(not (is_real_number(w) and 0 <= w < 1e6) for w in weights)
                or (weights and max(weights) <= 0)):
            raise bad("record_weights", "expected finite weights ≥ 0, one per data file, "
                      "not all 0")
        if not 0 <= self.outside_weight <= 1:
            raise bad("outside_weight", "expected 0…1")
        if not 0 < self.rest_current_a < 10:
            raise bad("rest_current_a", "expected 0 < current < 10 A")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def parse_setting(text: str) -> tuple[str, object]:
    """One `KEY=VALUE` setting from the command line: VALUE as a TOML value (numbers, true,
    false, "strings", [lists]) or, if it is none, as a plain string (auto, off)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. max_local_models=4 or "
                          "'partition=[\"soc\",\"current\"]'")
    try:
        return key, tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return key, value.strip()


def given_settings(path: str | Path | None = None, **overrides) -> GivenSettings:
    """The settings given: a TOML file's [train] table (or its top level), then the overrides
    that are not None; the file is read once here."""
    from_file = {} if path is None else _with_paths_from(Path(path), _toml_table(Path(path)))
    given = {k: v for k, v in overrides.items() if v is not None}
    values = GivenSettings({**from_file, **given})
    values.origins = {k: str(path) for k in from_file if k not in given}
    return values


def _with_paths_from(path: Path, table: dict) -> dict:
    """A TOML file's settings with its relative ocv_tests paths taken from the file's folder
    (as a file that names its neighbours means them), except one found only from the working
    folder, which stays as written."""
    tests = table.get("ocv_tests")
    if not (isinstance(tests, list) and all(isinstance(t, str) for t in tests)):
        return table
    beside = [t if Path(t).is_absolute() or (Path(t).exists()
                                             and not (path.parent / t).exists())
              else str(path.parent / t) for t in tests]
    return {**table, "ocv_tests": beside}


def sample_time_given(values: dict) -> bool:
    """Whether the settings given (given_settings) set sample_time_s to a value, not leave it
    out or "auto" (then training takes it from the records)."""
    return values.get("sample_time_s", "auto") != "auto"


def _toml_table(path: Path) -> dict:
    """The [train] table (or the top level) of a TOML configuration file (UTF-8; a byte-order
    mark, which Windows editors write, is skipped)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the TOML configuration ({exc})") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        json_like = path.suffix.lower() == ".json" or text.lstrip().startswith("{")
        raise ConfigError(f"{path}: cannot read the TOML configuration ({exc})"
                          + ("; a JSON file (such as a model file) is not one: expected "
                             "TOML lines such as max_local_models = 8" if json_like else "")
                          ) from exc
    if "train" not in doc:
        tables = sorted(f"[{k}]" for k, v in doc.items() if isinstance(v, dict))
        if tables:
            raise ConfigError(f"{path}: table(s) {', '.join(tables)} and no [train] table; "
                              "expected the settings in a [train] table (or at the top level)")
        return doc
    beside = sorted(k for k in doc if k != "train")
    if beside or not isinstance(doc["train"], dict):
        raise ConfigError(f"{path}: {beside or ['train = ' + repr(doc['train'])]} beside or "
                          "instead of the [train] table; expected every setting inside [train] "
                          "(or all of them at the top level, without [train])")
    return doc["train"]


def config_from_settings(values: dict, source: str = "configuration") -> TrainConfig:
    """The checked TrainConfig of the settings given (given_settings; source names them in
    errors): defaults where a setting is not given; sample_time_s "auto" is left at its
    default (training takes it from the records where sample_time_given says so)."""
    origins = getattr(values, "origins", {})
    values = {k: v for k, v in values.items()
              if not (k == "sample_time_s" and v == "auto")}
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(values) - names)
    if unknown:
        near = {k: difflib.get_close_matches(k, names, n=1) for k in unknown}
        meant = "; ".join(f"{k!r}: did you mean {m[0]!r}?" for k, m in near.items() if m)
        files = {origins.get(k, "configuration") for k in unknown}
        raise ConfigError(f"{files.pop() if len(files) == 1 else source}: "
                          f"unknown setting(s) {unknown}"
                          + (f" ({meant})" if meant else "") + f"; known: {sorted(names)}")
    try:
        return TrainConfig(**values).check()
    except ConfigError as exc:
        if exc.setting in origins:
            raise ConfigError(f"{origins[exc.setting]}: {exc}", exc.setting) from None
        raise


def load_config(path: str | Path | None = None, **overrides) -> TrainConfig:
    """Defaults, then the [train] table (or top level) of a TOML file, then overrides
    (config_from_settings of given_settings)."""
    return config_from_settings(given_settings(path, **overrides), str(path or "configuration"))
