"""Choices made before the tree grows: the OCV pre-fit, the Arrhenius gain E, the hysteresis
rate γ, the degree of the temperature terms and the inverse-variance sample weights."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
from lmncell.config import TrainConfig
from lmncell.data.dataset import Segment
from lmncell.data.records import present
from lmncell.identification.baselines import hysteresis
from lmncell.identification.ladder import Ladder
from lmncell.identification.ocvfit import OcvFit, fit_ocv, measured_ocv
from lmncell.identification.tree import (
    Design,
    build_design,
    freerun_squares,
    rmse_of_squares,
    root_tree,
)
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import arrhenius_gain, initial_hysteresis, lmn_temperatures

HYSTERESIS_CANDIDATES = (10.0, 30.0, 100.0, 300.0)
HYSTERESIS_MIN_GAIN = 0.03   # the pre-fit's relative RMSE gain from γ at which 'auto' keeps it,
HYSTERESIS_TRY_GAIN = 0.01   # and from which it trains with and without γ (_choose_hysteresis).
# Measured gains: NCA (Panasonic 18650PF, C/20 test) 0.29 % at 25 °C, 0.38 % at 25 + 10 °C, but
# 2.0 % in the 25 + 10 °C fold without the 10 °C HWFET record; LFP (A123, 25 °C C/30 tests)
# 2.2 % at −5/5/25/45 °C, 4.4 % at −15…45 °C. Kept from 1 %, that NCA fold took γ = 100 and
# its held-out HWFET record went 11.9 → 20.4 mV over the whole record (validation error of
# the network 5.45 mV without γ, 5.95 with it, 26 °C region); the A123 model of −5…45 °C, kept
# from 3 % only, had none (validation 4.23 mV, with γ = 300 4.10 mV). In the A123 folds between
# −15…45 °C (−5/5/25 °C held out) hysteresis is kept; without it they are 3.66/2.51/3.43 mV in
# 20–80 % against 3.33/2.17/2.65, their observers' SoC RMSE (EKF / fuzzy / IMM) 4.79/4.81/4.50
# against 3.64/3.50/3.32 % (hysteresis_terms "polynomial").
SELECTION_R_KNOTS = 6


Progress = Callable[[str], None]


ARRHENIUS_CANDIDATES_K = (1000.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0, 8000.0)


def _temperature_span(segs: list[Segment]) -> float:
    temps = [s.temperature_c for s in segs if s.temperature_c is not None]
    if not temps:
        return 0.0
    t = np.concatenate(temps)
    return float(t.max() - t.min())


CHAMBER_SPAN_K = 2.0   # records whose temperature spans no more: at a constant chamber temperature


TIME_CONSTANT_ACTIVATION_K = 1500.0   # Eτ of time_constant_scaling "auto": Panasonic 25 °C
# leave-one-record-out, measured cell temperature, 20–80 % / whole-record RMSE (mV): off 5.61 /
# 9.66; Eτ 750, 1000, 1500, 2000, 3000 K: 5.35 / 8.98, 5.32 / 8.96, 5.31 / 8.57, 5.29 / 8.72,
# 5.63 / 8.79; −1500 K: 5.83 / 9.74 (the A123 records at constant chamber temperatures, where
# "auto" leaves it off: −5 °C held out 3.06 → 4.00 mV in 20–80 % with 1500 K)


def choose_time_constant_scaling(cfg: TrainConfig, segs: list[Segment],
                                 progress: Progress) -> float | None:
    """Eτ (K) of the filter time constants per the setting (None: off); 'auto' takes
    TIME_CONSTANT_ACTIVATION_K where the temperature varies inside some record by more than
    CHAMBER_SPAN_K (cells warming up under load), else off."""
    setting = cfg.time_constant_scaling
    if isinstance(setting, (int, float)):
        e_tau = float(setting)
    elif setting == "auto" and cells_warm_up(segs):
        e_tau = TIME_CONSTANT_ACTIVATION_K
    else:
        e_tau = None
    progress("  filter time constants: " + ("fixed" if e_tau is None else
                                          f"× exp(Eτ·(1/T − 1/T_ref)), Eτ = {e_tau:g} K"))
    return e_tau


def cells_warm_up(segs: list[Segment]) -> bool:
    """Whether the temperature varies inside some segment by more than CHAMBER_SPAN_K (measured
    cells that warm up under load, not a chamber's set point)."""
    return _within_record_span(segs) > CHAMBER_SPAN_K


def _within_record_span(segs: list[Segment]) -> float:
    """The largest temperature span (K) inside one segment (0 without temperatures)."""
    return max((float(np.ptp(s.temperature_c)) for s in segs if s.temperature_c is not None),
               default=0.0)


def choose_prefit(cfg: TrainConfig, base: LmnModel, segs: list[Segment],
                  masks: list[np.ndarray], progress: Progress, socs: list[np.ndarray],
                  e_k_chosen: tuple[float | None, ...] = ()):
    """Hysteresis γ (or None), a γ to try (or None, _choose_hysteresis), Arrhenius E (or None)
    and the OCV pre-fit, per the settings.

    e_k_chosen: (E,) where an earlier call on the same records and settings (the hysteresis
    setting apart, which E's choice does not read) has chosen E already; () to choose it.

    socs: the coulomb-counted SoC of each segment as the runtime computes it. E and γ are
    chosen with the fit weights (SoC window included), as the network will use them; the OCV
    is then fitted with every sample at its record's weight: the window focuses the local
    models, but the OCV is a property of the whole SoC range (with the window's weights the
    A123 OCV came out 40–90 mV low below 10 % SoC, where the observers read the SoC)."""
    pre = _Prefits(cfg, base, segs, masks, socs)
    if pre.fixed is not None:
        progress(f"  OCV from slow tests {', '.join(Path(p).name for p in cfg.ocv_tests)}: "
                 f"{pre.fixed[0]:.3f} … {pre.fixed[-1]:.3f} V (fixed)")
    if len(pre.groups) > 1:
        progress(f"  E from pre-fits of each of the {len(pre.groups)} temperature levels on "
                 "its own (the temperature regions carry the differences between levels, E "
                 "the warm-up within each)")
    if e_k_chosen:
        e_k = e_k_chosen[0]
        progress(f"  temperature scaling: {'off' if e_k is None else f'E = {e_k:g} K'} "
                 "(chosen above)")
    else:
        e_k = _choose_arrhenius(cfg, segs, pre.selection_fit, progress)
    gamma, trial = _choose_hysteresis(cfg, e_k, pre.fit, progress,
                                      *((pre.score, pre.score_name) if pre.n_levels > 1 else ()))
    return gamma, trial, e_k, pre.fit(gamma, e_k, weights=pre.ocv_weights)


class _Prefits:
    """The linear OCV pre-fits of one training (fit_ocv over every segment), with what they
    share: the fit and OCV weights, the hysteresis series per γ and the measured OCV (fixed,
    where ocv_tests give one)."""

    def __init__(self, cfg: TrainConfig, base: LmnModel, segs: list[Segment],
                 masks: list[np.ndarray], socs: list[np.ndarray]) -> None:
        self.cfg, self.base, self.segs, self.socs = cfg, base, segs, socs
        self.taus = sorted(t for t in set(cfg.filter_time_constants_s()) | {1000.0}
                           if t >= 2 * cfg.sample_time_s)
        self.fit_weights = [s.weight * ~m for s, m in zip(segs, masks, strict=True)]
        self.ocv_weights = [s.record_weight * ~m for s, m in zip(segs, masks, strict=True)]
        self._hyst: dict[float, list[np.ndarray]] = {}
        self._selection: list[np.ndarray] | None = None   # computed on first use ('auto')
        self.fixed = (measured_ocv(cfg.ocv_tests, base.capacity_ah,
                                   np.linspace(0, 1, cfg.ocv_knots))
                      if cfg.ocv_tests else None)
        self.groups = arrhenius_groups(cfg, segs)
        self.levels = segment_levels(segs)
        # the temperatures the model's g(T) takes (the core rise added; None: no temperature)
        self.temperatures = [None if s.temperature_c is None
                             else lmn_temperatures(base, s.current_a, s.temperature_c)
                             for s in segs]

    def hysteresis_series(self, gamma: float) -> list[np.ndarray]:
        """The runtime's hysteresis recursion (lmncell.runtime.step.ExoStepper.update) per
        segment, computed once per γ."""
        if gamma not in self._hyst:
            self._hyst[gamma] = [hysteresis(s.current_a, gamma, self.cfg.sample_time_s,
                                            self.base.capacity_ah, initial_hysteresis(s.soc0))
                                 for s in self.segs]
        return self._hyst[gamma]

    def fit(self, gamma: float | None, e_k: float | None, r_knots: int = 1,
            weights: list[np.ndarray] | None = None) -> OcvFit:
        """The pre-fit with hysteresis γ (None: none), Arrhenius E (None: none), r_knots
        resistance knots over SoC and these sample weights (default: the fit weights)."""
        cfg, segs = self.cfg, self.segs
        gain = [arrhenius_gain(t, e_k, len(s), self.base.reference_temperature_c,
                               self.base.activation_t0_k)
                for s, t in zip(segs, self.temperatures, strict=True)]
        return fit_ocv(self.socs, [s.current_a for s in segs], [s.voltage_v for s in segs],
                       self.fit_weights if weights is None else weights,
                       None if gamma is None else self.hysteresis_series(gamma),
                       cfg.sample_time_s, self.taus, cfg.ocv_knots, gain, self.fixed, r_knots)

    @property
    def n_levels(self) -> int:
        """The number of temperature levels among the segments (segment_levels)."""
        return len(set(self.levels))

    @property
    def score_name(self) -> str:
        """What score gives, in words."""
        return f"geometric mean of the {self.n_levels} temperature levels' RMSE"

    def score(self, fit: OcvFit) -> float:
        """The level_score (V) of the pre-fit's RMSE per temperature level (rmse_by_level), so
        that each level's relative change counts alike; its RMSE without segment_squares."""
        if fit.segment_squares is None:
            return fit.rmse_v
        return level_score(rmse_by_level(fit.segment_squares, self.levels))

    def selection_weights(self) -> list[np.ndarray]:
        """The fit weights times the inverse-variance SoC factors the network will use: E is
        chosen where the linear pre-fit can follow the cell (unweighted, the voltage collapse
        before the cut-off, while the cell is warmest, chose E: Panasonic 25 °C, US06 left
        out, E off, held-out RMSE 13.9 mV in 20–80 % and 31.0 mV whole; with the weights
        E = 2000 K, 10.2 and 22.2 mV). γ keeps the fit weights: the hysteresis of LFP shows
        most where the OCV is steep."""
        if self._selection is None:
            knots = np.linspace(0, 1, self.cfg.ocv_knots)
            table = self.fixed if self.fixed is not None else self.fit(None, None).ocv_v
            self._selection = [w * f for w, f in zip(
                self.fit_weights, soc_reference_factors(self.socs, knots, table, self.cfg),
                strict=True)]
        return self._selection

    def selection_fit(self, gamma: float | None, e_k: float | None,
                      r_knots: int = 1) -> OcvFit:
        """The pre-fit that chooses E: over all segments, or with temperature regions one per
        level (each its own resistances, and its own OCV where no test fixes it), their RMSE
        pooled."""
        weights = self.selection_weights()
        if len(self.groups) < 2:
            return self.fit(gamma, e_k, r_knots, weights=weights)
        fits, masses = [], []
        for group in self.groups:
            w = [wk if k in group else np.zeros_like(wk) for k, wk in enumerate(weights)]
            fits.append(self.fit(gamma, e_k, r_knots, weights=w))
            masses.append(float(sum(float(np.sum(wk)) for wk in w)))
        pooled = np.sqrt(sum(f.rmse_v ** 2 * m for f, m in zip(fits, masses, strict=True))
                         / max(sum(masses), 1e-300))
        # the first level's coefficients stand for the fit; its squares would not
        return dataclasses.replace(fits[0], rmse_v=float(pooled), segment_squares=None)


def arrhenius_groups(cfg: TrainConfig, segs: list[Segment]) -> list[set[int]]:
    """Segment indices per temperature level (segment_levels) where the network holds one set
    of local models per level (uses_temperature_regions); else one group of all segments."""
    if not uses_temperature_regions(cfg, segs):
        return [set(range(len(segs)))]
    levels = segment_levels(segs)
    return [g for g in ({k for k, lv in enumerate(levels) if lv == q}
                        for q in range(max(levels) + 1)) if g]


def uses_temperature_regions(cfg: TrainConfig, segs: list[Segment]) -> bool:
    """Whether the network holds one set of local models per chamber-temperature level
    (lmncell.identification.regions): temperature_regions 'auto', temperature in the (resolved)
    partition, no temperature terms carrying it, and two or more levels."""
    return (cfg.temperature_regions == "auto" and "temperature" in cfg.partition
            and not temperature_degree(cfg, segs) and len(temperature_levels(segs)) >= 2)


def _choose_arrhenius(cfg: TrainConfig, segs: list[Segment], prefit: Callable[..., OcvFit],
                      progress: Progress) -> float | None:
    """Arrhenius E (K) per the setting; 'auto' picks the candidate with the lowest pre-fit
    RMSE once the training temperatures span more than 5 K (chosen before hysteresis: the
    larger effect where temperatures differ)."""
    e_k: float | None = None
    if isinstance(cfg.temperature_scaling, (int, float)):
        e_k = float(cfg.temperature_scaling)
    elif cfg.temperature_scaling == "auto" and _temperature_span(segs) > 5.0:
        # resistances scheduled over SoC, as the LMN's SoC partition will have them: with one
        # resistance for all SoC, the rise of resistance towards empty (while the cell warms up)
        # would decide E instead of the temperature
        best = prefit(None, None, SELECTION_R_KNOTS)
        progress(f"  pre-fit without temperature scaling: RMSE {1e3 * best.rmse_v:.2f} mV")
        for cand in ARRHENIUS_CANDIDATES_K:
            fit = prefit(None, cand, SELECTION_R_KNOTS)
            progress(f"  pre-fit with E = {cand:g} K: RMSE {1e3 * fit.rmse_v:.2f} mV")
            if fit.rmse_v < best.rmse_v:
                e_k, best = cand, fit
        progress(f"  temperature scaling: {'off' if e_k is None else f'E = {e_k:g} K'}")
    return e_k


def _choose_hysteresis(cfg: TrainConfig, e_k: float | None, prefit: Callable[..., OcvFit],
                       progress: Progress, score: Callable[[OcvFit], float] | None = None,
                       what: str = "") -> tuple[float | None, float | None]:
    """Hysteresis rate γ per the setting, and a γ to try: 'auto' keeps the best candidate where
    it cuts the pre-fit RMSE by HYSTERESIS_MIN_GAIN; where it cuts it by HYSTERESIS_TRY_GAIN
    but less, it returns none and that candidate to try (train_lmn then trains with and
    without it and keeps the lower validation error).

    score (records at several temperature levels: the level_score of each level's RMSE, named
    by what): the best candidate by the RMSE is kept where both its RMSE and its score fall by
    HYSTERESIS_MIN_GAIN, tried where either falls by HYSTERESIS_TRY_GAIN. The pooled RMSE
    follows the coldest level, whose error is several times the others': A123 s1 records of
    −25 … 45 °C (−5 °C held out) gain 0.9 % pooled and 3.5 % by level, and had no hysteresis
    where −15 … 45 °C keeps it. By level alone (kept from 3 %, the best by the score), the
    Panasonic 25 + 10 °C fold without the 10 °C HWFET record would keep γ = 100, which its
    trial's validation error turns down (see HYSTERESIS_TRY_GAIN), and the A123 model of
    −5 / 5 / 25 / 45 °C would try γ = 100 instead of 300."""
    if cfg.hysteresis == "off":
        return None, None
    if cfg.hysteresis != "auto":
        return float(cfg.hysteresis), None
    base = prefit(None, e_k)
    best_gamma, best = None, base
    by = score or (lambda f: f.rmse_v)
    for g in HYSTERESIS_CANDIDATES:
        fit = prefit(g, e_k)
        progress(f"  OCV pre-fit with hysteresis γ={g:g}: RMSE {1e3 * fit.rmse_v:.2f} mV "
                 f"(without: {1e3 * base.rmse_v:.2f} mV)"
                 + (f", {what} {1e3 * by(fit):.2f} mV ({1e3 * by(base):.2f})" if score else ""))
        if fit.rmse_v < best.rmse_v:
            best_gamma, best = g, fit
    if best_gamma is None:
        return None, None
    gains = [1 - best.rmse_v / base.rmse_v, 1 - by(best) / by(base)]
    if min(gains) >= HYSTERESIS_MIN_GAIN:
        return best_gamma, None
    if max(gains) >= HYSTERESIS_TRY_GAIN:
        return None, best_gamma
    return None, None


def ocv_slope(ocv_soc: np.ndarray, ocv_v: np.ndarray, soc: np.ndarray) -> np.ndarray:
    """dOCV/dSoC (V per unit SoC) of the piecewise-linear OCV, interpolated between the
    segments' midpoints."""
    return np.interp(soc, 0.5 * (ocv_soc[1:] + ocv_soc[:-1]), np.diff(ocv_v) / np.diff(ocv_soc))


def with_soc_reference_weights(segs: list[Segment], socs: list[np.ndarray],
                               ocv_soc: np.ndarray, ocv_v: np.ndarray,
                               cfg: TrainConfig) -> list[Segment]:
    """The segments with their fit weights multiplied by σ_u²/(σ_u² + (dOCV/dSoC·σ_SoC)²):
    inverse-variance weighting of the voltage target, whose uncertainty from the coulomb-counted
    SoC (σ_SoC = soc_reference_sigma) grows with the OCV slope, i.e. near empty and full.
    socs: each segment's SoC as the model counts it."""
    if cfg.soc_reference_sigma <= 0:
        return segs
    return [dataclasses.replace(seg, weight=seg.weight * f) for seg, f in
            zip(segs, soc_reference_factors(socs, ocv_soc, ocv_v, cfg), strict=True)]


def soc_reference_factors(socs: list[np.ndarray], ocv_soc: np.ndarray, ocv_v: np.ndarray,
                          cfg: TrainConfig) -> list[np.ndarray]:
    """Per segment σ_u²/(σ_u² + (dOCV/dSoC·σ_SoC)²) (all 1 with soc_reference_sigma = 0)."""
    return [1.0 / (1.0 + (ocv_slope(ocv_soc, ocv_v, soc) * cfg.soc_reference_sigma
                          / cfg.model_error_sigma_v) ** 2) for soc in socs]


TEMPERATURE_LEVEL_GAP_K = 7.5


def temperature_levels(segs: list[Segment]) -> list[float]:
    """Distinct training temperatures (°C): the segments' median temperatures, a new level
    wherever one lies TEMPERATURE_LEVEL_GAP_K or more above the previous level."""
    medians = sorted(float(np.median(s.temperature_c)) for s in segs
                     if s.temperature_c is not None)
    levels: list[float] = []
    for t in medians:
        if not levels or t - levels[-1] >= TEMPERATURE_LEVEL_GAP_K:
            levels.append(t)
    return levels


def segment_levels(segs: list[Segment]) -> list[int]:
    """Per segment, the index of the temperature level (temperature_levels, coldest 0) nearest
    its median temperature (0 for a segment without temperature)."""
    levels = temperature_levels(segs)
    return [0 if s.temperature_c is None or not levels
            else int(np.argmin([abs(float(np.median(s.temperature_c)) - t) for t in levels]))
            for s in segs]


def temperature_degree(cfg: TrainConfig, segs: list[Segment]) -> int:
    """The degree of the temperature terms: the setting, or for 'auto' min(2, L − 2) with L
    distinct training temperatures: at least one temperature more than a polynomial through
    them would need, so that they are fitted, not interpolated exactly (0 below three)."""
    if cfg.temperature_terms != "auto":
        return int(cfg.temperature_terms)
    return min(2, max(len(temperature_levels(segs)) - 2, 0))


def level_score(rmse_by_level: np.ndarray) -> float:
    """The criterion over temperature levels: the geometric mean of their RMSEs (V), so that
    each level's relative change counts alike. A level without fit samples (NaN, e.g. all of
    its records weighted 0) is left out; inf where a level diverged or none is left."""
    r = np.asarray(rmse_by_level, dtype=float)
    r = r[~np.isnan(r)]
    if r.size == 0 or not np.isfinite(r).all():
        return float("inf")
    return float(np.exp(np.mean(np.log(np.maximum(r, 1e-12)))))


def rmse_by_level(squares: np.ndarray, levels: list[int]) -> np.ndarray:
    """The RMSE (V) of each temperature level's segments (levels: segment_levels), coldest
    first, from freerun_squares rows."""
    lv = np.asarray(levels)
    return np.array([rmse_of_squares(squares[lv == level]) for level in sorted(set(levels))])


def choose_arrhenius_with_temperature_terms(base: LmnModel, segs: list[Segment],
                                            masks: list[np.ndarray], cfg: TrainConfig,
                                            progress: Progress, ladder: Ladder | None = None
                                            ) -> tuple[float, dict[str, float], Design]:
    """Arrhenius E (K) for records at constant chamber temperatures with temperature terms:
    the candidate whose root model (with those terms, fitted by weighted least squares) has
    the lowest level_score of its training free-run RMSE per temperature level; also each
    candidate's score (mV) by str(E), and the regression design built with the chosen E (for
    the construction that follows).

    There E is seen only between the temperature levels, together with the polynomial terms
    it works with, which the pre-fit (`_choose_arrhenius`) lacks: on the A123
    leave-one-temperature-out folds the pre-fit picked 2000–6000 K where 4000–5000 K
    interpolated best (held-out 20–80 % RMSE 4.15 → 2.77, 9.32 → 4.60, 6.20 → 3.14 mV).
    Per level, not pooled: one level's errors can be far the largest (A123 −25 °C 56–60 mV
    against 9–17 mV at −15 … 25 °C) and a pooled RMSE followed that level alone, to 8000 K,
    where 3000–4000 K interpolated best (−25/−15/5/25 °C, −5 °C held out, 20–80 % / whole
    record: 9.14 / 27.70 → 3.52 / 12.88 mV; −25/−5/5/25 °C, −15 °C held out: 15.69 / 37.99 →
    4.38 / 10.56 mV; the −5/5/25 °C folds of −15 … 45 °C keep 4000 K).
    Where temperature varies inside records (self-heating), the pre-fit's SoC-scheduled
    resistances separate E from the SoC trend and its choice stays."""
    scores: dict[float, float] = {}
    e_k, best = ARRHENIUS_CANDIDATES_K[0], None
    levels = segment_levels(segs)
    for cand in ARRHENIUS_CANDIDATES_K:
        trial = dataclasses.replace(base, arrhenius_k=cand)
        design = build_design(trial, segs, masks, ladder)
        model = root_tree(trial, design, cfg).apply(trial)
        by_level = rmse_by_level(freerun_squares(model, segs, design, "fit"), levels)
        scores[cand] = level_score(by_level)
        progress(f"  root model with temperature terms, E = {cand:g} K: free-run "
                 + ", ".join("–" if np.isnan(r) else f"{1e3 * r:.2f}" for r in by_level)
                 + f" mV by level, geometric mean {1e3 * scores[cand]:.2f} mV")
        if best is None or scores[cand] < scores[e_k]:      # the first of equal minima
            e_k, best = cand, design
    progress(f"  temperature scaling with the temperature terms: E = {e_k:g} K")
    return e_k, {f"{c:g}": 1e3 * v for c, v in scores.items()}, present(best, "the design")
