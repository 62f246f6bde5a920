"""The tree of the local model network while it grows: the model skeleton, the regression
design (stacked one-step data of all segments), local weighted least squares with pole
stabilisation, the root local models and the one-step and free-run errors of a stage."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from lmncell.config import TrainConfig
from lmncell.data.dataset import Segment
from lmncell.identification.ladder import Ladder
from lmncell.runtime.model import Depletion, LmnModel
from lmncell.runtime.step import ExoSeries, exo_series, initial_hysteresis, simulate_exo


def skeleton(cfg: TrainConfig, capacity_ah: float, ocv_soc: np.ndarray, ocv_v: np.ndarray,
             gamma: float | None, center: np.ndarray, scale: np.ndarray,
             temperature_terms: int = 0) -> LmnModel:
    """A model with the configured structure, one local model of zeros and no split."""
    d = len(cfg.partition)
    current_sign = cfg.pre_partition == "current_sign"
    roots = ([("charge", ("leaf", 0)), ("discharge", ("leaf", 1))] if current_sign
             else [("all", ("leaf", 0))])
    core_k = float(cfg.core_rise_k_per_a2) if cfg.core_rise_k_per_a2 != "auto" else 0.0
    m = LmnModel(
        sample_time_s=cfg.sample_time_s, capacity_ah=capacity_ah, ocv_soc=ocv_soc, ocv_v=ocv_v,
        output_lags=cfg.output_lags, current_terms=cfg.current_terms,
        filters=cfg.filter_pairs(), hysteresis_gamma=gamma,
        ocv_input=cfg.ocv_input, soc_input=cfg.soc_input, offset=True,
        relative_ocv=cfg.output == "relative_ocv", partition_variables=list(cfg.partition),
        partition_center=center, partition_scale=scale, roots=roots,
        node_weights=np.zeros((0, d + 1)), node_children=[],
        theta=np.zeros((len(roots), 1)), gating_mode=cfg.pre_partition,
        rest_current_a=cfg.rest_current_a, temperature_terms=temperature_terms,
        activation_t0_k=float(cfg.activation_t0_k) if cfg.activation_t0_k != "auto" else 0.0,
        core_rise_k_per_a2=core_k, core_rise_tau_s=float(cfg.core_rise_tau_s) if core_k else 0.0,
        depletion=(Depletion(cfg.depletion_time_constant_s(), float(cfg.depletion_power),
                             fast_tau_s=cfg.depletion_fast_time_constant_s())
                   if cfg.depletion_power else None))
    m.theta = np.zeros((len(roots), len(m.columns())))
    m._build_paths()
    return m


@dataclass
class Tree:
    """The growing tree: roots, nodes (weights, children) and one θ row per leaf."""

    roots: list[tuple[str, tuple[str, int]]]
    weights: list[np.ndarray]
    children: list[tuple[tuple[str, int], tuple[str, int]]]
    theta: np.ndarray

    def apply(self, base: LmnModel) -> LmnModel:
        m = copy.copy(base)
        m.roots = list(self.roots)
        d = base.partition_center.size
        m.node_weights = (np.vstack(self.weights) if self.weights
                          else np.zeros((0, d + 1)))
        m.node_children = list(self.children)
        m.theta = self.theta.copy()
        m._build_paths()
        return m

    def split(self, leaf: int, psi: np.ndarray, theta_a: np.ndarray,
              theta_b: np.ndarray) -> Tree:
        """Leaf `leaf` becomes a node whose first child is `leaf` (φ) and second a new leaf."""
        new_leaf = self.theta.shape[0]
        node = len(self.weights)

        def swap(ref: tuple[str, int]) -> tuple[str, int]:
            return ("node", node) if ref == ("leaf", leaf) else ref

        t = Tree([(g, swap(c)) for g, c in self.roots], [*self.weights, psi.copy()],
                 [(swap(a), swap(b)) for a, b in self.children], self.theta.copy())
        t.children.append((("leaf", leaf), ("leaf", new_leaf)))
        t.theta[leaf] = theta_a
        t.theta = np.vstack([t.theta, theta_b])
        return t


@dataclass
class Design:
    """Stacked one-step regression data of all segments, plus per-segment simulation data."""

    X: np.ndarray            # (N, p): measured output lags, then exogenous regressors
    y: np.ndarray            # (N,) target: u − OCV(SoC) or u
    Z: np.ndarray            # (N, d) normalised partition inputs
    D: np.ndarray            # (N,) direction codes
    w_fit: np.ndarray        # (N,) one-step fit weights (validation and first lags at 0)
    w_val: np.ndarray        # (N,) validation weights
    exo: list[ExoSeries] = field(default_factory=list)
    bounds: list[tuple[int, int]] = field(default_factory=list)
    ladder: Ladder | None = None   # local models as RC ladders with R ≥ 0 (ladder.py), or free

    def fit(self, X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """One local model by weighted least squares, in the ladder's bounds if there is one."""
        return wls(X, y, w) if self.ladder is None else self.ladder.solve(X, y, w)


def _target(model: LmnModel, seg: Segment, soc: np.ndarray) -> np.ndarray:
    return seg.voltage_v - model.ocv(soc) if model.relative_ocv else seg.voltage_v.copy()


def _lags(y: np.ndarray, na: int) -> np.ndarray:
    L = np.empty((y.size, na))
    for l in range(1, na + 1):
        L[:l, l - 1] = y[0]
        L[l:, l - 1] = y[:-l]
    return L


def build_design(model: LmnModel, segs: list[Segment], val_masks: list[np.ndarray],
                 ladder: Ladder | None = None) -> Design:
    Xs, ys, Zs, Ds, wf, wv, exos, bounds = [], [], [], [], [], [], [], []
    start = 0
    for seg, vmask in zip(segs, val_masks, strict=True):
        ex = exo_series(model, seg.current_a, seg.temperature_c, seg.soc0,
                        h0=initial_hysteresis(seg.soc0))
        y = _target(model, seg, ex.soc)
        Xs.append(np.hstack([_lags(y, model.output_lags), ex.x]))
        ys.append(y)
        Zs.append(ex.z)
        Ds.append(ex.direction)
        w = seg.weight * ~vmask
        w[: model.output_lags] = 0.0
        wf.append(w)
        wv.append(seg.weight * vmask)
        exos.append(ex)
        bounds.append((start, start + len(seg)))
        start += len(seg)
    return Design(np.vstack(Xs), np.concatenate(ys), np.vstack(Zs), np.concatenate(Ds),
                  np.concatenate(wf), np.concatenate(wv), exos, bounds, ladder)


# ----- local least squares and stability -------------------------------------------------
def wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares with a tiny relative ridge (for rank-deficient leaves)."""
    Xw = X * w[:, None]
    G = X.T @ Xw
    ridge = 1e-9 * (np.trace(G) / G.shape[0] + 1e-12)
    return np.linalg.solve(G + ridge * np.eye(G.shape[0]), Xw.T @ y)


def poles(theta: np.ndarray, na: int) -> np.ndarray:
    """Roots of z^na − a1·z^(na−1) − … − a_na of a local model."""
    if na == 0:
        return np.zeros(0)
    return np.roots(np.concatenate([[1.0], -theta[:na]]))


def stabilise(theta: np.ndarray, na: int, max_pole: float, X: np.ndarray | None = None,
              y: np.ndarray | None = None, w: np.ndarray | None = None) -> np.ndarray:
    """Pull poles beyond max_pole radially inside; refit the other parameters if data given."""
    p = poles(theta, na)
    if p.size == 0 or np.abs(p).max() <= max_pole:
        return theta
    scale = np.minimum(1.0, max_pole / np.maximum(np.abs(p), 1e-300))
    a = -np.real(np.poly(p * scale))[1:]
    out = theta.copy()
    out[:na] = a
    if X is not None and y is not None and w is not None and w.sum() > 0:
        out[na:] = wls(X[:, na:], y - X[:, :na] @ a, w)
    return out


def freerun_squares(model: LmnModel, segs: list[Segment], design: Design,
                    which: str = "val", only: list[int] | None = None) -> np.ndarray:
    """Per segment, the weighted sum of squared free-run errors (V²) and the sum of the weights
    over validation ('val') or fit ('fit') samples, shape (len(segs), 2): zeros for segments
    not in `only` (all by default) or without such samples; the first segment whose simulation
    is not finite gets inf and the rest are not simulated."""
    out = np.zeros((len(segs), 2))
    for k, (seg, ex, (a, b)) in enumerate(zip(segs, design.exo, design.bounds, strict=True)):
        if only is not None and k not in only:
            continue
        w = (design.w_val if which == "val" else design.w_fit)[a:b]
        if w.sum() == 0:
            continue
        sim = simulate_exo(model, ex, seg.soc0, initial_hysteresis(seg.soc0),
                           seg.start_temperature())
        err = seg.voltage_v - sim.voltage_v
        if not np.isfinite(err).all():
            out[k] = np.inf
            return out
        out[k] = float(np.sum(w * err * err)), float(w.sum())
    return out


def rmse_of_squares(squares: np.ndarray) -> float:
    """The RMSE (V) of freerun_squares rows: inf where one is not finite, NaN without samples."""
    num, den = np.asarray(squares, dtype=float).reshape(-1, 2).sum(axis=0)
    if not np.isfinite(num + den):
        return float("inf")
    return float(np.sqrt(num / den)) if den else float("nan")


def freerun_rmse(model: LmnModel, segs: list[Segment], design: Design,
                 which: str = "val", only: list[int] | None = None) -> float:
    """Weighted free-run RMSE (V) over validation ('val') or fit ('fit') samples, of the
    segments whose indices are in `only` (all by default)."""
    return rmse_of_squares(freerun_squares(model, segs, design, which, only))


def one_step(model: LmnModel, design: Design) -> tuple[np.ndarray, np.ndarray]:
    Phi = model.validities(design.Z, design.D)
    return Phi, np.sum(Phi * (design.X @ model.theta.T), axis=1)


def root_tree(base: LmnModel, design: Design, cfg: TrainConfig) -> Tree:
    """The start of the construction: one local model per root (one, or charge and
    discharge), each by weighted least squares over its gate, poles kept inside max_pole."""
    w = design.w_fit
    weights = [w * _gate_weight(design, g) for g in base.leaf_gates[:len(base.roots)]]
    return Tree(list(base.roots), [], [], fit_leaves(design, weights, cfg))


def fit_leaves(design: Design, weights: list[np.ndarray], cfg: TrainConfig) -> np.ndarray:
    """One local model per sample-weight vector (θ rows): weighted least squares (in the
    ladder's bounds if any), poles kept inside max_pole."""
    X, y = design.X, design.y
    return np.vstack([stabilise(design.fit(X, y, wj), cfg.output_lags, cfg.max_pole, X, y, wj)
                      for wj in weights])


def _gate_weight(design: Design, gate: str) -> np.ndarray:
    if gate == "all":
        return np.ones_like(design.y)
    code = 1 if gate == "charge" else 2
    return np.asarray(code == design.D, dtype=float)
