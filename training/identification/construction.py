"""Incremental identification of the local model network (the paper's algorithm, generalised).

1. OCV(SoC) and the hysteresis rate γ from a feedback-free pre-fit (prefit.py, ocvfit.py).
2. Start with one local model fitted by (locally weighted) least squares on the one-step error.
3. Repeat: take the local model with the largest weighted error (eq. 10–12), replace it by a node
   and two children. The split starts deterministically as the best orthogonal split through the
   leaf's weighted median along each partition axis; then the node's weights ψ are optimised by
   Levenberg–Marquardt on the global loss (eq. 10) with the Jacobian of eq. 14–18, the two
   children's parameters re-estimated by locally weighted least squares at every step. All other
   nodes and local models stay as they are.
4. After every split: one-step loss, AICc and free-run RMSE on the validation data are recorded
   (with several temperature levels also the geometric mean of each level's, which then
   decides); the number of local models M is chosen from that curve.
5. Final output-error refinement: all local models (and the OCV knots) by Levenberg–Marquardt on
   the free-run simulation error, with sensitivities propagated through the output feedback.
Local models with a pole outside max_pole are repaired (poles pulled in radially, the rest refit).
Nothing is random: the same data and settings give the same model.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from lmncell.config import (
    ACTIVATION_T0_K,
    CORE_RISE_K_PER_A2,
    DEPLETION_FAST_TAU_S,
    LOCAL_MODELS_PER_REGION,
    ConfigError,
    TrainConfig,
)
from lmncell.data.dataset import Segment
from lmncell.identification.blas import one_blas_thread
from lmncell.identification.ladder import Ladder, ladder_for, ladder_keys
from lmncell.identification.prefit import (
    HYSTERESIS_MIN_GAIN,
    cells_warm_up,
    choose_arrhenius_with_temperature_terms,
    choose_prefit,
    choose_time_constant_scaling,
    level_score,
    rmse_by_level,
    segment_levels,
    temperature_degree,
    temperature_levels,
    uses_temperature_regions,
    with_soc_reference_weights,
)
from lmncell.identification.refinement import refine_output_error
from lmncell.identification.regions import region_boundaries, temperature_region_tree
from lmncell.identification.splitting import optimise_split
from lmncell.identification.tree import (
    Design,
    Tree,
    build_design,
    freerun_rmse,
    freerun_squares,
    one_step,
    rmse_of_squares,
    root_tree,
    skeleton,
)
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import exo_series, lmn_temperatures

VALIDATION_BLOCKS = 5   # validation 'block': time blocks centred at 10, 30, … 90 % of each
#                         record (validation_masks)


Progress = Callable[[str], None]


def _quiet(_msg: str) -> None:
    pass


def aicc(loss: float, n: float, n_params: int) -> float:
    """Corrected Akaike criterion of a least-squares fit (loss = weighted sum of squares)."""
    if n - n_params - 1 <= 0 or loss <= 0:
        return float("inf")
    return n * np.log(loss / n) + 2 * n_params + 2 * n_params * (n_params + 1) / (n - n_params - 1)


@dataclass
class TrainResult:
    model: LmnModel
    curve: list[dict]
    chosen_m: int
    info: dict


def validation_masks(segs: list[Segment], cfg: TrainConfig) -> list[np.ndarray]:
    """Per segment, True on validation samples.

    'block': VALIDATION_BLOCKS evenly spread time blocks that together hold validation_fraction
    of each segment (so every SoC range is validated); 'record': the whole last segment.
    """
    masks = []
    for k, seg in enumerate(segs):
        mask = np.zeros(len(seg), dtype=bool)
        if cfg.validation == "block":
            n = len(seg)
            width = cfg.validation_fraction * n / VALIDATION_BLOCKS
            for b in range(VALIDATION_BLOCKS):
                mid = (b + 0.5) * n / VALIDATION_BLOCKS
                mask[int(mid - width / 2): int(mid + width / 2)] = True
        elif cfg.validation == "record" and k == len(segs) - 1 and len(segs) > 1:
            mask[:] = True
        masks.append(mask)
    return masks


def partition_normalisation(base: LmnModel, segs: list[Segment]
                            ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Centre and half-range of the raw partition inputs, and each segment's SoC series."""
    series = [raw_partition_inputs(base, s) for s in segs]
    raw = np.vstack([z for z, _ in series])
    lo, hi = raw.min(axis=0), raw.max(axis=0)
    center = 0.5 * (lo + hi)
    scale = np.where(hi - lo > 1e-9, 0.5 * (hi - lo), 1.0)
    return center, scale, [soc for _, soc in series]


def raw_partition_inputs(base: LmnModel, seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    """The raw partition inputs z (N, d) and the coulomb-counted SoC (N,) of a segment, bit
    for bit as exo_series gives them (the same products, the SoC summed in the same order),
    without its per-sample loop; exo_series itself where the partition has the filtered
    current (a low-pass state)."""
    if "filtered_current" in base.partition_variables:
        ex = exo_series(base, seg.current_a, seg.temperature_c, seg.soc0)
        return ex.z * base.partition_scale + base.partition_center, ex.soc
    i = np.asarray(seg.current_a, dtype=float)
    gain = base.sample_time_s / (3600.0 * base.capacity_ah)     # ExoStepper.soc_gain
    eta = np.where(i > 0, base.efficiency_charge, base.efficiency_discharge)
    soc = np.add.accumulate(np.concatenate([[float(seg.soc0)], gain * eta * i]))[1:]
    temp = lmn_temperatures(base, i, seg.temperatures())
    columns = {"soc": soc, "current": i, "temperature": temp}
    return np.column_stack([columns[v] for v in base.partition_variables]), soc


def resolve_partition(cfg: TrainConfig, segs: list[Segment], progress: Progress = _quiet
                      ) -> TrainConfig:
    """The settings with partition "auto" replaced: soc and current (the overpotential's
    current dependence, strongest in the collapse before cut-off: local models per load level
    follow it where one linear model per SoC range cannot; see TrainConfig), plus temperature
    where the segments lie at two or more distinct temperatures (temperature_levels); with
    temperature terms soc and temperature (the terms carry the temperature dependence)."""
    if cfg.partition != "auto":
        return cfg
    levels = temperature_levels(segs)
    if len(levels) < 2:
        partition = ["soc", "current"]
    elif temperature_degree(cfg, segs):
        partition = ["soc", "temperature"]
    else:
        partition = ["soc", "current", "temperature"]
    progress(f"  partition (auto): {', '.join(partition)} (training temperatures "
             + (", ".join(f"{t:.0f}" for t in levels) or "none") + " °C)")
    return dataclasses.replace(cfg, partition=partition)


def resolve_fast_depletion(cfg: TrainConfig, segs: list[Segment], progress: Progress = _quiet
                           ) -> TrainConfig:
    """The settings with depletion_fast_tau_s "auto" replaced: the filters' time constant
    nearest DEPLETION_FAST_TAU_S where the network has temperature regions
    (uses_temperature_regions; the partition resolved) and that is not d's own, else 0
    (none). A given value was checked by TrainConfig.check."""
    fast = cfg.depletion_fast_tau_s
    if fast == "auto":
        on = bool(cfg.depletion_power) and uses_temperature_regions(cfg, segs)
        fast = cfg.nearest_filter_time_constant_s(DEPLETION_FAST_TAU_S) if on else 0.0
        if on and fast == cfg.depletion_time_constant_s():
            fast = 0.0              # the filters have no time constant apart from d's
        if fast:
            progress(f"  fast depletion regressor (auto, temperature regions): τ2 = {fast:g} s")
    return dataclasses.replace(cfg, depletion_fast_tau_s=float(fast))


def resolve_activation_t0(cfg: TrainConfig, segs: list[Segment], progress: Progress = _quiet
                          ) -> TrainConfig:
    """The settings with activation_t0_k "auto" replaced: ACTIVATION_T0_K where the network has
    temperature regions (uses_temperature_regions; the partition resolved), else 0 (Arrhenius).
    A given value was checked by TrainConfig.check."""
    t0 = cfg.activation_t0_k
    if t0 == "auto":
        t0 = ACTIVATION_T0_K if uses_temperature_regions(cfg, segs) else 0.0
        if t0:
            progress(f"  temperature scaling in the Vogel–Tammann–Fulcher form (auto, "
                     f"temperature regions): T0 = {t0:g} K")
    return dataclasses.replace(cfg, activation_t0_k=float(t0))


def resolve_core_rise(cfg: TrainConfig, segs: list[Segment], progress: Progress = _quiet
                      ) -> TrainConfig:
    """The settings with core_rise_k_per_a2 "auto" replaced: CORE_RISE_K_PER_A2 where the
    cells warm up inside the records (prefit.cells_warm_up, as time_constant_scaling's "auto"),
    else 0. A given value was checked by TrainConfig.check."""
    k = cfg.core_rise_k_per_a2
    if k == "auto":
        k = CORE_RISE_K_PER_A2 if cells_warm_up(segs) else 0.0
    if k:
        progress(f"  core rise over the measured temperature: {k:g} K/A² · LP(i²), "
                 f"τ = {cfg.core_rise_tau_s:g} s")
    return dataclasses.replace(cfg, core_rise_k_per_a2=float(k))


def resolve_max_local_models(cfg: TrainConfig, segs: list[Segment], temperature_fixed: bool,
                             progress: Progress = _quiet) -> TrainConfig:
    """The settings with max_local_models "auto" replaced: LOCAL_MODELS_PER_REGION per
    distinct training temperature where the local models differ by temperature region
    (temperature in the partition and no temperature terms: regions or splits along
    temperature), else LOCAL_MODELS_PER_REGION, twice that where the partition has the current
    too (the tree then splits along two axes); at most 64."""
    if cfg.max_local_models != "auto":
        return cfg
    regions = 1
    if "temperature" in cfg.partition and not temperature_fixed:
        regions = max(len(temperature_levels(segs)), 1)
    per_region = LOCAL_MODELS_PER_REGION * (2 if "current" in cfg.partition else 1)
    m = min(per_region * regions, 64)
    if m != LOCAL_MODELS_PER_REGION:
        progress(f"  at most {m} local models (auto: {per_region} for each of the {regions} "
                 "training temperature(s)" + (", the partition has the current" if per_region
                                               > LOCAL_MODELS_PER_REGION else "") + ")")
    return dataclasses.replace(cfg, max_local_models=m)


def hysteresis_terms(cfg: TrainConfig, base: LmnModel, progress: Progress) -> str:
    """The hysteresis column's temperature terms (TrainConfig.hysteresis_terms) where the model
    has temperature terms and hysteresis ("arrhenius" also needs an Arrhenius E: without one
    it is said to have no effect), else "polynomial", the model file's default, which then
    adds nothing."""
    if not (base.temperature_terms and base.hysteresis_gamma is not None):
        return "polynomial"
    if cfg.hysteresis_terms == "arrhenius" and not base.arrhenius_k:
        progress("  hysteresis_terms 'arrhenius' has no effect: the model has no Arrhenius E")
        return "polynomial"
    progress(f"  hysteresis temperature terms: {cfg.hysteresis_terms}"
             + (f" (in dA, E = {base.arrhenius_k:g} K)" if cfg.hysteresis_terms == "arrhenius"
                else ""))
    return cfg.hysteresis_terms


@one_blas_thread
def train_lmn(segs: list[Segment], cfg: TrainConfig, capacity_ah: float,
              progress: Progress = _quiet, e_k_chosen: tuple[float | None, ...] = ()
              ) -> TrainResult:
    """Identify an LMN from model-rate segments (see the module docstring)."""
    t_start = time.perf_counter()
    cfg = _resolved_settings(cfg, segs, progress)
    d = len(cfg.partition)
    n_temp = temperature_degree(cfg, segs)
    base = skeleton(cfg, capacity_ah, np.array([0.0, 1.0]), np.array([0.0, 0.0]), None,
                    np.zeros(d), np.ones(d), n_temp)
    center, scale, socs = partition_normalisation(base, segs)
    masks = validation_masks(segs, cfg)
    gamma, trial, e_k, ocv = choose_prefit(cfg, base, segs, masks, progress, socs, e_k_chosen)
    if trial is not None:
        return train_with_and_without_hysteresis(segs, cfg, capacity_ah, trial, progress, e_k)
    progress(f"  hysteresis: {'off' if gamma is None else f'γ = {gamma:g}'}; OCV pre-fit RMSE "
             f"{1e3 * ocv.rmse_v:.2f} mV")
    base = skeleton(cfg, capacity_ah, ocv.knots, ocv.ocv_v, gamma, center, scale, n_temp)
    _complete_base(base, cfg, segs, socs, e_k, progress)
    if n_temp:
        progress(f"  temperature terms of degree {n_temp} (training temperatures "
                 + ", ".join(f"{t:.0f}" for t in temperature_levels(segs)) + " °C)")
    cfg, fixed_axes, boundaries = _temperature_structure(cfg, segs, base, n_temp, progress)
    segs = with_soc_reference_weights(segs, socs, base.ocv_soc, base.ocv_v, cfg)
    design, e_scores = _design_choosing_arrhenius(base, segs, masks, cfg, n_temp, progress)
    stop_stage = "validation" if cfg.stop == "validation" and cfg.validation != "none" else "aicc"
    tree, grower = _grown_tree(base, segs, design, cfg, stop_stage, (fixed_axes, boundaries),
                               progress, t_start)
    key = ("aicc" if stop_stage != "validation" else "validation_level_score_mv"
           if "validation_level_score_mv" in grower.curve[-1] else "validation_freerun_rmse_mv")
    model = tree.apply(base)
    progress(f"  chosen M={model.n_local_models} by {STOP_NAMES[key]}")
    info = {"stop": key, "hysteresis_gamma": gamma, "arrhenius_k": base.arrhenius_k,
            "time_constant_activation_k": base.tau_activation_k,
            "arrhenius_root_freerun_rmse_mv": e_scores,
            "temperature_terms": n_temp,
            "ocv_prefit_rmse_mv": 1e3 * ocv.rmse_v}
    if cfg.oe_refinement:
        model, info["output_error"] = refine_output_error(model, segs, design, cfg, progress)
    info.update(_final_figures(model, segs, design, cfg.oe_refinement,
                               grower.levels if key == "validation_level_score_mv" else None))
    info["seconds"] = time.perf_counter() - t_start
    return TrainResult(model, grower.curve, model.n_local_models, info)


def _resolved_settings(cfg: TrainConfig, segs: list[Segment], progress: Progress
                       ) -> TrainConfig:
    """cfg with its "auto" partition, fast depletion, activation T0 and core rise resolved for
    these segments (each says what it chose through progress)."""
    cfg = resolve_partition(cfg, segs, progress)
    cfg = resolve_fast_depletion(cfg, segs, progress)
    cfg = resolve_activation_t0(cfg, segs, progress)
    return resolve_core_rise(cfg, segs, progress)


def _complete_base(base: LmnModel, cfg: TrainConfig, segs: list[Segment],
                   socs: list[np.ndarray], e_k: float | None, progress: Progress) -> None:
    """Fill in base (the pre-fit's OCV and hysteresis already in it) before the growth: the
    depletion factor held below the data, the pre-fit's Arrhenius E (K), the hysteresis
    column's temperature terms, zero coefficients in the columns these imply, and the time
    constants' activation (K)."""
    hold_depletion_below_the_data(base, socs, progress)
    base.arrhenius_k = e_k
    base.hysteresis_terms = hysteresis_terms(cfg, base, progress)
    base.theta = np.zeros((len(base.roots), len(base.columns())))   # the columns it implies
    base.tau_activation_k = choose_time_constant_scaling(cfg, segs, progress)


def _design_choosing_arrhenius(base: LmnModel, segs: list[Segment], masks: list[np.ndarray],
                               cfg: TrainConfig, n_temp: int, progress: Progress
                               ) -> tuple[Design, dict[str, float]]:
    """The growth's design matrices, and the free-run RMSE (mV) of each Arrhenius E tried by
    name (empty where none is tried). E is chosen here, and set in base, where temperature
    terms carry the temperature, E is "auto" and the pre-fit took one, and the cells do not
    warm up inside the records (their warm-up pins E down in the pre-fit otherwise)."""
    ladder = local_ladder(cfg, base, segs, progress)
    if (n_temp and cfg.temperature_scaling == "auto" and base.arrhenius_k is not None
            and not cells_warm_up(segs)):
        e_k, e_scores, design = choose_arrhenius_with_temperature_terms(base, segs, masks, cfg,
                                                                        progress, ladder)
        base.arrhenius_k = e_k
        return design, e_scores
    return build_design(base, segs, masks, ladder), {}


def _grown_tree(base: LmnModel, segs: list[Segment], design: Design, cfg: TrainConfig,
                stop_stage: str, temperature: tuple[frozenset, list], progress: Progress,
                t_start: float) -> tuple[Tree, Grower]:
    """The tree grown from its root (with the temperature regions' fixed splits where
    _temperature_structure gave boundaries) up to the stage that stop_stage ("validation" or
    "aicc") picks, and the Grower with the curve. temperature: the axes no split may use and
    the regions' boundaries; t_start: perf_counter at the training's start, for progress."""
    fixed_axes, boundaries = temperature
    tree = root_tree(base, design, cfg)
    if boundaries:
        tree = temperature_region_tree(tree, base, design, cfg, boundaries)
    grower = Grower(base, segs, design, cfg, fixed_axes, progress, t_start)
    progress("  growing the tree (RMSE weighted as the fit weights the samples: one-step and "
             "free run on the fit samples, free run on the validation samples)")
    if (boundaries and cfg.region_growth == "separate" and stop_stage == "validation"
            and cfg.validation == "block"):
        return grow_regions_separately(grower, tree), grower
    return grower.grow(tree, stop_stage), grower


def _temperature_structure(cfg: TrainConfig, segs: list[Segment], base: LmnModel, n_temp: int,
                           progress: Progress) -> tuple[TrainConfig, frozenset, list]:
    """How temperature enters the growth: the partition axes no split may use (temperature
    where temperature terms or regions carry it), the resolved max_local_models, and the
    temperature regions' fixed boundaries (empty without regions), placed on base's partition
    temperature."""
    fixed_axes: frozenset = frozenset()
    if n_temp and "temperature" in cfg.partition:
        fixed_axes = frozenset({cfg.partition.index("temperature")})
        progress("  temperature acts through the temperature terms, not through splits: "
                 "sigmoid splits between a few training temperatures interpolate badly")
    cfg = resolve_max_local_models(cfg, segs, bool(fixed_axes), progress)
    boundaries = region_boundaries(segs, base) if uses_temperature_regions(cfg, segs) else []
    if boundaries:
        fixed_axes = frozenset({cfg.partition.index("temperature")})
        progress("  temperature regions: fixed splits at " + ", ".join(
            f"{c:.1f} °C (width {w:.2f} K)" for c, w in boundaries)
                 + "; no other splits along temperature")
    return cfg, fixed_axes, boundaries


def _final_figures(model: LmnModel, segs: list[Segment], design: Design, refined: bool,
                   levels: list | None) -> dict:
    """The final model's free-run RMSE (mV) on the validation samples (the fit samples where
    there are none, validation "none"), after the refinement also on the fit samples, and per
    temperature level where M was chosen per level (levels: the grower's, else None); each
    sample set simulated once."""
    squares: dict[str, np.ndarray] = {}

    def final_squares(which: str) -> np.ndarray:
        if which not in squares:
            squares[which] = freerun_squares(model, segs, design, which)
        return squares[which]

    out: dict = {}
    if refined:
        out["refined_validation_freerun_rmse_mv"] = finite_or_none(
            1e3 * rmse_of_squares(final_squares("val")))
        out["refined_train_freerun_rmse_mv"] = finite_or_none(
            1e3 * rmse_of_squares(final_squares("fit")))
    final = "val" if design.w_val.sum() > 0 else "fit"
    out["final_validation_freerun_rmse_mv"] = finite_or_none(
        1e3 * rmse_of_squares(final_squares(final)))
    if levels is not None:                     # M was chosen per level: so is the final figure
        out["final_validation_level_score_mv"] = finite_or_none(
            1e3 * level_score(rmse_by_level(final_squares(final), levels)))
    return out


def _mv(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def train_with_and_without_hysteresis(segs: list[Segment], cfg: TrainConfig, capacity_ah: float,
                                      gamma: float, progress: Progress,
                                      e_k: float | None = None) -> TrainResult:
    """Where the pre-fit's gain from hysteresis is in doubt (prefit.HYSTERESIS_TRY_GAIN …
    HYSTERESIS_MIN_GAIN): the network trained with γ and without, the one with the lower
    final validation error kept (the first of equals: without). That error is the one that
    chose M: final_validation_level_score_mv where both runs chose M per temperature level,
    else final_validation_freerun_rmse_mv. e_k: the pre-fit's Arrhenius E, already chosen for
    these records (both runs take it rather than choose it again)."""
    progress(f"  hysteresis γ = {gamma:g} lowers the pre-fit's error by less than "
             f"{100 * HYSTERESIS_MIN_GAIN:g} %: training with it and without, the lower "
             "validation error decides")
    runs = [(g, train_lmn(segs, dataclasses.replace(cfg, hysteresis=h), capacity_ah, progress,
                          e_k_chosen=(e_k,)))
            for g, h in ((None, "off"), (gamma, gamma))]
    key = ("final_validation_level_score_mv"
           if all("final_validation_level_score_mv" in r.info for _, r in runs)
           else "final_validation_freerun_rmse_mv")
    errors = [r.info[key] for _, r in runs]
    keep = 1 if errors[1] is not None and (errors[0] is None or errors[1] < errors[0]) else 0
    kept = runs[keep][1]
    by = " (by temperature level, geometric mean)" if key.endswith("level_score_mv") else ""
    progress(f"  hysteresis: {'off' if keep == 0 else f'γ = {gamma:g}'} kept (validation{by} "
             f"{_mv(errors[1])} mV with γ = {gamma:g}, {_mv(errors[0])} mV without)")
    kept.info["hysteresis_trial"] = {"gamma": gamma, "validation_mv_without": errors[0],
                                     "validation_mv_with": errors[1], "by": key}
    kept.info["seconds"] = sum(r.info["seconds"] for _, r in runs)
    return kept


STOP_TOLERANCE = 1.02    # M: the fewest local models within 2 % of the best validation error


STOP_NAMES = {  # how progress names each stop criterion (chosen_stage)
    "aicc": "the lowest AICc",
    "validation_freerun_rmse_mv": "the free-run validation RMSE (the fewest local models "
                                  f"within {100 * (STOP_TOLERANCE - 1):g} % of the lowest)",
    "validation_level_score_mv": "the geometric mean of the temperature levels' free-run "
                                 "validation RMSE (the fewest local models within "
                                 f"{100 * (STOP_TOLERANCE - 1):g} % of the lowest)"}


class Grower:
    """The tree's growth (step 3 of the module docstring): split the worst leaf, record the
    curve (one-step, AICc, free-run training and validation RMSE per stage), pick M."""

    def __init__(self, base: LmnModel, segs: list[Segment], design: Design, cfg: TrainConfig,
                 fixed_axes: frozenset, progress: Progress, t_start: float) -> None:
        self.base, self.segs, self.design, self.cfg = base, segs, design, cfg
        self.fixed_axes, self.progress, self.t_start = fixed_axes, progress, t_start
        self.curve: list[dict] = []
        self.n_eff = float(design.w_fit.sum())
        self.levels = segment_levels(segs)

    def record(self, tree: Tree, stop_stage: str, only: list[int] | None = None,
               label: dict | None = None) -> tuple[float, np.ndarray, np.ndarray]:
        """Append the stage's curve entry (validation over the segments `only`, all by
        default); returns its stop score (validation RMSE or AICc), Φ and the one-step output."""
        model, design = tree.apply(self.base), self.design
        phi, yhat = one_step(model, design)
        e = design.y - yhat
        loss = float(np.sum(design.w_fit * e * e))
        n_par = model.theta.size + (len(self.cfg.partition) + 1) * len(tree.weights)
        val = by_levels = float("nan")
        if stop_stage == "validation":
            squares = freerun_squares(model, self.segs, design, "val", only)
            val = rmse_of_squares(squares)
            if only is None and len(set(self.levels)) > 1:
                by_levels = level_score(rmse_by_level(squares, self.levels))
        fit_fr = freerun_rmse(model, self.segs, design, "fit")
        crit = aicc(loss, self.n_eff, n_par)
        self.curve.append({"local_models": model.n_local_models,
                           "one_step_rmse_mv": 1e3 * float(np.sqrt(loss / self.n_eff)),
                           "aicc": finite_or_none(crit),
                           "train_freerun_rmse_mv": finite_or_none(1e3 * fit_fr),
                           "validation_freerun_rmse_mv": finite_or_none(1e3 * val),
                           **({"validation_level_score_mv": finite_or_none(1e3 * by_levels)}
                              if not np.isnan(by_levels) else {}),
                           **(label or {})})
        where = "" if not label else f" ({label['validation_records']})"
        self.progress(f"  M={model.n_local_models}: one-step "
                      f"{self.curve[-1]['one_step_rmse_mv']:.2f} mV, free-run fit "
                      f"{1e3 * fit_fr:.2f} mV, validation{where} {1e3 * val:.2f} mV"
                      + ("" if np.isnan(by_levels) else
                         f" (by temperature level, geometric mean {1e3 * by_levels:.2f} mV)")
                      + f" ({time.perf_counter() - self.t_start:.1f} s)")
        score = crit if stop_stage != "validation" else val if np.isnan(by_levels) else by_levels
        return (score if np.isfinite(score) else np.inf), phi, yhat

    def split_worst(self, tree: Tree, phi: np.ndarray, yhat: np.ndarray,
                    weight: np.ndarray | None = None, allowed: np.ndarray | None = None
                    ) -> Tree | None:
        """The tree with its worst leaf split (weighted error Σ w·Φ_j·e², w times `weight`
        where given; only leaves where `allowed` is True), the next worst where a leaf cannot
        be split; None where none can."""
        d = self.design
        w = d.w_fit if weight is None else d.w_fit * weight
        e = d.y - yhat
        leaf_err = np.sum(w[:, None] * phi * e[:, None] ** 2, axis=0)
        for j in np.argsort(-leaf_err, kind="stable"):
            if allowed is not None and not allowed[j]:
                continue
            r_rest = d.y - (yhat - phi[:, j] * (d.X @ tree.theta[j]))
            split = optimise_split(d.X, d.y, d.w_fit, d.Z, phi[:, j], r_rest, self.cfg,
                                   self.fixed_axes, d.fit)
            if split is not None:
                return tree.split(int(j), split.psi, split.theta_a, split.theta_b)
        return None

    def grow(self, tree: Tree, stop_stage: str) -> Tree:
        """Split the worst leaf of the whole tree up to max_local_models; the stage M by the
        validation error over all records (or AICc). With records at two or more temperature
        levels that error is level_score of each level's validation RMSE, so that the level
        with the largest errors (A123's −25 °C, say) does not decide M alone."""
        stages, scores = [], []
        while True:
            score, phi, yhat = self.record(tree, stop_stage)
            stages.append(tree)
            scores.append(score)
            if tree.theta.shape[0] >= self.cfg.max_local_models:
                break
            nxt = self.split_worst(tree, phi, yhat)
            if nxt is None:
                self.progress("  no leaf can be split further")
                break
            tree = nxt
        return stages[chosen_stage(scores, stop_stage)]


def chosen_stage(scores: list[float], stop_stage: str) -> int:
    """The stage of the lowest AICc, or the first within STOP_TOLERANCE of the lowest
    validation error (fewer local models where more do not clearly help)."""
    s = np.asarray(scores, dtype=float)
    if stop_stage == "aicc":
        return int(np.argmin(s))
    return int(np.flatnonzero(s <= STOP_TOLERANCE * s.min())[0])


def grow_regions_separately(grower: Grower, tree: Tree) -> Tree:
    """Grow the local models of each temperature region in turn, coldest first: split only
    that region's leaves (the worst by its records' error), up to its share of
    max_local_models, and keep the stage whose validation error over that region's records is
    best (chosen_stage); the next region grows from there. A leaf belongs to the region whose
    records hold most of its validity (regions: the grower's temperature levels)."""
    levels = grower.levels
    design, n_regions = grower.design, max(levels) + 1
    sample_region = np.concatenate([np.full(b - a, levels[k])
                                    for k, (a, b) in enumerate(design.bounds)])
    region_samples = [sample_region == q for q in range(n_regions)]
    share = max(int(grower.cfg.max_local_models) // n_regions, 1)    # resolved: an int
    temps = temperature_levels(grower.segs)
    for r in range(n_regions):
        only = [k for k, lv in enumerate(levels) if lv == r]
        label = {"temperature_region_c": temps[r],
                 "validation_records": f"{temps[r]:.0f} °C records"}
        in_region = region_samples[r].astype(float)
        stages, scores = [], []
        while True:
            score, phi, yhat = grower.record(tree, "validation", only, label)
            stages.append(tree)
            scores.append(score)
            mass = np.stack([phi[m].sum(axis=0) for m in region_samples])
            mine = np.argmax(mass, axis=0) == r
            if int(mine.sum()) >= share:
                break
            nxt = grower.split_worst(tree, phi, yhat, in_region, mine)
            if nxt is None:
                grower.progress(f"  no leaf of the {temps[r]:.0f} °C region can be split further")
                break
            tree = nxt
        pick = chosen_stage(scores, "validation")
        tree = stages[pick]
        grower.progress(f"  {temps[r]:.0f} °C region: {pick} split(s) kept by its records' "
                        "validation error")
    return tree


DEPLETION_HOLD_FRACTION = 0.7   # the depletion factor is held below this share of the lowest
# training SoC: its power law, (0.1/SoC)^4, is extrapolated that far and no further


def hold_depletion_below_the_data(base: LmnModel, socs: list[np.ndarray],
                                  progress: Progress = _quiet) -> None:
    """Set the depletion regressor's soc_min (below it the SoC factor is held) to
    DEPLETION_HOLD_FRACTION of the lowest SoC the training records reach, where that is above
    the default: a model trained on records that end at SoC 0.11 (Panasonic 10 °C drive
    cycles) otherwise raised the factor 16-fold beyond its data on a record that ran on to
    SoC 0.05 (at 25 °C) and its R_d of hundreds of mΩ, which had carried the earlier collapse of
    the cold cell, took the terminal voltage to −2 V. Records that reach deeper hold it below
    all of their samples (Panasonic 25 °C, lowest 0.049: 0.034) or keep the default (A123,
    0.014 … 0.037)."""
    dep = base.depletion
    if dep is None or not socs:
        return
    lowest = min(float(np.min(s)) for s in socs)
    hold = DEPLETION_HOLD_FRACTION * lowest
    if hold > dep.soc_min:
        base.depletion = dataclasses.replace(dep, soc_min=hold)
        progress(f"  depletion factor held below SoC {hold:.3f} ({DEPLETION_HOLD_FRACTION:g} of "
                 f"the lowest training SoC, {lowest:.3f})")


def local_ladder(cfg: TrainConfig, base: LmnModel, segs: list[Segment],
                 progress: Progress = _quiet) -> Ladder | None:
    """The RC-ladder bounds of the local models (ladder.py) where local_model_form asks for
    them ("auto": wherever the structure is a ladder), else None (free local models)."""
    if cfg.local_model_form == "free":
        return None
    temps = [s.temperature_c for s in segs if s.temperature_c is not None]
    t_min = min((float(np.min(t)) for t in temps), default=base.reference_temperature_c)
    t_max = max((float(np.max(t)) for t in temps), default=base.reference_temperature_c)
    ladder = ladder_for(base, t_min, t_max, cfg.offset_bound_v())
    if ladder is None:
        if cfg.local_model_form == "rc_ladder":
            raise ConfigError("setting 'local_model_form' = 'rc_ladder': the local models of "
                              "this structure are not RC ladders (needs output_lags = 0 and a "
                              "chain of filters, see lmncell.identification.ladder)")
        progress("  local models: free (the structure is not an RC ladder)")
        return None
    progress("  local models: RC ladders, R0, R_τ (τ = " + ", ".join(
        f"{t:g}" for t in ladder_keys(base.filters, base.sample_time_s)) + " s)"
             + (", R_d" if base.depletion is not None else "") + " and H ≥ 0"
             + (f" at {t_min:.0f} … {t_max:.0f} °C" if base.temperature_terms else ""))
    return ladder


def finite_or_none(value: float) -> float | None:
    """The value, or None where it is NaN or infinite (not computed, e.g. no validation data):
    the model file is strict JSON."""
    return float(value) if np.isfinite(value) else None
