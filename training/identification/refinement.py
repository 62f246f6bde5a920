"""Final output-error refinement: every local model (and the OCV knots) by Levenberg–Marquardt on
the free-run simulation error, sensitivities propagated through the output feedback, with a
Huber loss (iteratively reweighted least squares where there is no output feedback), a ridge
towards the tree's local fits (TrainConfig.oe_ridge), and where slow OCV tests fix the OCV a
ridge that pulls each local OCV offset towards 0 (TrainConfig.offset_ridge) and, for records at
three or more temperatures, OCV knots anchored to the test's (TrainConfig.ocv_refinement)."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from lmncell.config import OCV_REFINE_LEVELS, OCV_REFINE_SOC_MIN, OCV_TEST_ANCHOR, TrainConfig
from lmncell.data.dataset import Segment
from lmncell.identification.ladder import InfeasibleError, Ladder, lsi
from lmncell.identification.ocvfit import SMOOTHNESS, hat_basis, second_difference
from lmncell.identification.prefit import temperature_levels
from lmncell.identification.tree import Design, _lags, freerun_rmse, stabilise
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import (
    NO_FIXED_POINT_BELOW,
    fixed_point,
    initial_hysteresis,
    recursion,
    rest_inputs,
)
from scipy.optimize import least_squares, lsq_linear

Progress = Callable[[str], None]


@dataclass
class _Solution:
    x: np.ndarray
    cost: float
    nfev: int
    status: int


def _sensitivity(A: np.ndarray, G: np.ndarray, s_start: np.ndarray) -> None:
    """G becomes S, in place: S(k) = G(k) + Σ_l A(k,l)·S(k−l), S(k<0) = s_start, ∂ŷ/∂params
    through the feedback from the start value's own ∂ŷ0/∂params (_start_sensitivity). Row k
    reads only rows before it, already turned into S."""
    n, na = A.shape
    for k in range(n):
        for l in range(1, na + 1):
            G[k] += A[k, l - 1] * (G[k - l] if k - l >= 0 else s_start)


def _start_sensitivity(m: LmnModel, soc0: float, temperature_c: float, h0: float,
                       y0: float) -> np.ndarray:
    """∂ŷ0/∂θ (M·p,) of the start value ŷ0 = fixed_point(m, …), the network at rest:
    ŷ0 = Σ_l A0_l·ŷ0 + b0, so ∂ŷ0/∂θ_j = Φ0_j·[ŷ0 … ŷ0, x0] / (1 − Σ_l A0_l); 0 where
    fixed_point takes ŷ0 = 0 (no fixed point)."""
    x0, z0, direction = rest_inputs(m, soc0, temperature_c, h0)
    A0, _, Phi0 = m.blend(x0, z0, direction)
    denom = 1.0 - float(A0.sum())
    if abs(denom) <= NO_FIXED_POINT_BELOW:
        return np.zeros(m.theta.size)
    row = np.concatenate([np.full(m.output_lags, y0), x0[0]])
    return (Phi0[0][:, None] * row[None, :]).ravel() / denom


class _FreeRunProblem:
    """The refinement's residuals and Jacobian in x = [θ of every local model, OCV increments]
    (the increments only where refines_ocv): each segment's weighted free-run error, then the
    penalty rows (a ridge towards the start θ, TrainConfig.oe_ridge, the offset ridge, and for
    the OCV its smoothness and its anchor to the start), whose Jacobian is constant and built
    once."""

    def __init__(self, model: LmnModel, segs: list[Segment], design: Design,
                 cfg: TrainConfig) -> None:
        self.model, self.segs, self.design = model, segs, design
        self.M, self.p = model.theta.shape
        self.na = model.output_lags
        self.with_ocv = refines_ocv(model, segs, cfg)
        knots = model.ocv_soc
        self.K = knots.size if self.with_ocv else 0
        self.w_all = [np.sqrt(design.w_fit[a:b] + design.w_val[a:b]) for a, b in design.bounds]
        self.Phis = [model.validities(ex.z, ex.direction) for ex in design.exo]
        self.Bs = [hat_basis(ex.soc, knots) for ex in design.exo] if self.with_ocv else []
        self.h0s = [initial_hysteresis(s.soc0) for s in segs]
        self.t0s = [s.start_temperature() for s in segs]
        self.theta0 = model.theta.copy()
        self.sqrt_ridge = np.sqrt(float(cfg.oe_ridge))
        n_total = float(sum(float(np.sum(w * w)) for w in self.w_all))
        self.lam_ocv = np.sqrt(SMOOTHNESS * n_total) * 1e-3
        self.D2 = second_difference(self.K) if self.K >= 3 else np.zeros((0, self.K))
        self.rho = offset_ridge_of(cfg, model)
        self.off_col, self.off_lam = _offset_ridge(model, self.Phis, self.w_all, self.rho)
        self.ocv0 = model.ocv_v.copy()
        self.lam_anchor = ocv_anchor(knots, n_total, bool(cfg.ocv_tests))
        self.tri = np.tril(np.ones((self.K, self.K)))
        self.j_penalty = self._penalty_jacobian()
        self.n_res = int(sum(w.size for w in self.w_all))
        self._cache: dict = {}

    def _penalty_jacobian(self) -> np.ndarray:
        """The penalty rows' Jacobian (they are linear in x), in residuals' order."""
        M, p, K = self.M, self.p, self.K
        j_pen = [np.hstack([self.sqrt_ridge * np.eye(M * p), np.zeros((M * p, K))])]
        if self.off_col is not None:
            j_off = np.zeros((M, M * p + K))
            j_off[np.arange(M), np.arange(M) * p + self.off_col] = self.off_lam
            j_pen.append(j_off)
        if self.with_ocv and self.D2.shape[0]:
            j_pen.append(np.hstack([np.zeros((self.D2.shape[0], M * p)),
                                    self.lam_ocv * self.D2 @ self.tri]))
        if self.with_ocv:
            j_pen.append(np.hstack([np.zeros((K, M * p)), self.lam_anchor[:, None] * self.tri]))
        return np.vstack(j_pen)

    def start(self) -> np.ndarray:
        """x of the model as identified: its θ and, with the OCV, the OCV's start value and its
        non-negative increments (the OCV rises with SoC)."""
        ocv0 = self.ocv0
        incr0 = (np.concatenate([[ocv0[0]], np.maximum(np.diff(ocv0), 0.0)]) if self.with_ocv
                 else np.zeros(0))
        return np.concatenate([self.model.theta.ravel(), incr0])

    def lower(self) -> np.ndarray:
        """Lower bounds on x: the OCV increments ≥ 0, all else free."""
        lower = np.full(self.M * self.p + self.K, -np.inf)
        if self.with_ocv:
            lower[self.M * self.p + 1:] = 0.0
        return lower

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """θ (M, p) and the OCV knot values of x."""
        n = self.M * self.p
        return x[:n].reshape(self.M, self.p), (np.cumsum(x[n:]) if self.with_ocv
                                               else self.model.ocv_v)

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and Jacobian at x (the last x's kept: least_squares asks for both). The
        Jacobian is written in place, segment by segment, into one array: it has a row per
        sample and a column per parameter, the largest array of training."""
        key = x.tobytes()
        if key in self._cache:
            return self._cache[key]
        self._cache.clear()
        m = self._model_at(x)
        n_x = self.M * self.p + self.K
        jac = np.empty((self.n_res + self.j_penalty.shape[0], n_x))
        res, start = [], 0
        for k in range(len(self.segs)):
            stop = start + self.w_all[k].size
            res.append(self._segment_rows(m, k, jac[start:stop]))
            start = stop
        jac[start:] = self.j_penalty
        out = (np.concatenate(res + self._penalty_values(m.theta, m.ocv_v)), jac)
        self._cache[key] = out
        return out

    def take(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """evaluate(x), the arrays handed over: the cache forgets them, so that the caller may
        overwrite the Jacobian in place instead of copying it."""
        out = self.evaluate(x)
        self._cache.clear()
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """The residuals of evaluate alone, without the Jacobian."""
        m = self._model_at(x)
        res = [self._free_run(m, k)[0] for k in range(len(self.segs))]
        return np.concatenate(res + self._penalty_values(m.theta, m.ocv_v))

    def _model_at(self, x: np.ndarray) -> LmnModel:
        """The model with θ and the OCV knots of x."""
        theta, ocv_v = self.unpack(x)
        m = copy.copy(self.model)
        m.theta, m.ocv_v = theta, ocv_v.copy()
        return m

    def _free_run(self, m: LmnModel, k: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """Segment k's weighted free-run residuals (measured − model), the relative output y,
        its start value y0 and the feedback coefficients A (samples × na)."""
        seg, ex, Phi, sw = self.segs[k], self.design.exo[k], self.Phis[k], self.w_all[k]
        na, theta = self.na, m.theta
        A = Phi @ theta[:, :na]
        b = np.sum(Phi * (ex.x @ theta[:, na:].T), axis=1)
        y0 = fixed_point(m, seg.soc0, self.t0s[k], self.h0s[k])
        y = recursion(A, b, [y0] * na)
        u = y + m.ocv(ex.soc) if m.relative_ocv else y
        r = sw * (seg.voltage_v - u)
        if not np.isfinite(r).all():
            r = np.where(np.isfinite(r), r, 1e3)
        return r, y, y0, A

    def _segment_rows(self, m: LmnModel, k: int, J: np.ndarray) -> np.ndarray:
        """Segment k's weighted free-run residuals, its Jacobian written into J (samples × x),
        the sensitivities propagated through the output feedback."""
        r, y, y0, A = self._free_run(m, k)
        ex, Phi, sw = self.design.exo[k], self.Phis[k], self.w_all[k]
        n, M, p = y.size, self.M, self.p
        if J.shape != (n, M * p + self.K):
            raise ValueError(f"segment {k}: Jacobian rows {J.shape}, expected {n} samples")
        ylag = _lags(np.concatenate([[y0], y]), self.na)[1:]    # y(k−l), y0 before the start
        Xs = np.hstack([ylag, ex.x])
        G = J[:, :M * p]
        G3 = G.reshape(n, M, p)                   # a view: the columns split by local model
        if not np.shares_memory(G3, J):
            raise RuntimeError("the Jacobian's local-model block is not a view")
        np.multiply(Phi[:, :, None], Xs[:, None, :], out=G3)
        if self.na:
            seg = self.segs[k]
            _sensitivity(A, G, _start_sensitivity(m, seg.soc0, self.t0s[k], self.h0s[k], y0))
        G *= -sw[:, None]
        if self.with_ocv:
            np.multiply(-sw[:, None], self.Bs[k] @ self.tri, out=J[:, M * p:])
        return r

    def _penalty_values(self, theta: np.ndarray, ocv_v: np.ndarray) -> list[np.ndarray]:
        """The penalty rows at (θ, OCV), in _penalty_jacobian's order."""
        rows = [self.sqrt_ridge * (theta - self.theta0).ravel()]
        if self.off_col is not None:
            rows.append(self.off_lam * theta[:, self.off_col])
        if self.with_ocv and self.D2.shape[0]:
            rows.append(self.lam_ocv * self.D2 @ ocv_v)
        if self.with_ocv:
            rows.append(self.lam_anchor * (ocv_v - self.ocv0))
        return rows


def refine_output_error(model: LmnModel, segs: list[Segment], design: Design,
                        cfg: TrainConfig, progress: Progress) -> tuple[LmnModel, dict]:
    """Levenberg–Marquardt on the free-run error of all segments (θ of every local model and,
    where refines_ocv says so, the OCV knots); the refined model where it lowers the free-run
    training error, else the model as given, and what was done."""
    prob = _FreeRunProblem(model, segs, design, cfg)
    x0 = prob.start()
    r0 = prob.evaluate(x0)[0]
    t_start = time.perf_counter()
    before = freerun_rmse(model, segs, design, "fit")
    try:
        sol = _solve_refinement(prob, x0, r0, cfg)
    except InfeasibleError:
        # the constrained solver (ladder.lsi) finds no usable solution where the records
        # leave the refinement's parameters unidentified (a record with one current step:
        # its optimum lay 1e8 away, beyond the solver's precision)
        progress("  output-error refinement: its constrained least squares has no usable "
                 "solution on these records (parameters they do not identify); kept the model "
                 "before refinement")
        return model, {"initial_cost": float(0.5 * r0 @ r0), "final_cost": None,
                       "evaluations": 0, "seconds": time.perf_counter() - t_start,
                       "status": -1, "train_rmse_before_mv": 1e3 * before,
                       "train_rmse_after_mv": 1e3 * before, "accepted": False,
                       "offset_ridge": prob.rho if prob.off_col is not None else 0.0,
                       "ocv_refined": prob.with_ocv, "unsolved": True}
    theta, ocv_v = prob.unpack(sol.x)
    out = copy.copy(model)
    out.theta = np.vstack([stabilise(t, prob.na, cfg.max_pole) for t in theta])
    out.ocv_v = np.array(ocv_v, dtype=float)
    after = freerun_rmse(out, segs, design, "fit")
    accepted = bool(np.isfinite(after) and after < before)
    info = {"initial_cost": float(0.5 * r0 @ r0), "final_cost": float(sol.cost),
            "evaluations": int(sol.nfev), "seconds": time.perf_counter() - t_start,
            "status": int(sol.status), "train_rmse_before_mv": 1e3 * before,
            "train_rmse_after_mv": 1e3 * after, "accepted": accepted,
            "offset_ridge": prob.rho if prob.off_col is not None else 0.0,
            "ocv_refined": prob.with_ocv}
    progress(f"  output-error refinement: weighted free-run RMSE on the fit samples "
             f"{1e3 * before:.2f} → "
             f"{1e3 * after:.2f} mV in {sol.nfev} evaluations"
             + (f", offsets pulled towards 0 (ρ = {info['offset_ridge']:g})"
                if info["offset_ridge"] else "")
             + (f", the test's OCV refined above SoC {OCV_REFINE_SOC_MIN:g}"
                if prob.with_ocv and cfg.ocv_tests else "")
             + ("" if accepted else " (not better: kept the model before refinement)"))
    return (out if accepted else model), info


def _solve_refinement(prob: _FreeRunProblem, x0: np.ndarray, r0: np.ndarray,
                      cfg: TrainConfig) -> _Solution:
    """Without output feedback the free-run error is affine in x: (iteratively reweighted)
    bounded linear least squares gives the exact optimum, under the RC-ladder constraints where
    the local models are ladders. With feedback: least_squares (trf, Huber where asked)."""
    M, p, n_res = prob.M, prob.p, prob.n_res
    lower, upper = prob.lower(), np.full(x0.size, np.inf)
    if prob.na == 0:
        r_0, J_0 = prob.take(x0)
        b_0 = J_0 @ x0 - r_0
        ladder = prob.design.ladder
        if prob.with_ocv:
            on_theta = _ladder_constraints(ladder, M, p, np.full(x0.size, -np.inf))
            sol = _solve_in_knot_values(J_0, b_0, n_res, cfg, on_theta, M * p, prob.ocv0)
        else:
            sol = _robust_linear_solve(J_0, b_0, n_res, (lower, upper), cfg,
                                       _ladder_constraints(ladder, M, p, lower))
        sol.cost = float(0.5 * np.sum(prob.residuals(sol.x) ** 2))
        return sol
    robust = {}
    if cfg.robust_loss == "huber":
        robust = {"loss": "huber", "f_scale": HUBER_K * max(_robust_scale(r0[:n_res]), 1e-6)}
    with np.errstate(over="ignore", invalid="ignore"):
        return least_squares(lambda x: prob.evaluate(x)[0], x0,
                             jac=lambda x: prob.evaluate(x)[1],
                             bounds=(lower, upper), method="trf", x_scale="jac",
                             max_nfev=cfg.oe_max_iterations, ftol=1e-8, xtol=1e-10,
                             gtol=1e-10, **robust)


def refines_ocv(model: LmnModel, segs: list[Segment], cfg: TrainConfig) -> bool:
    """Whether the refinement moves the OCV knots too: for a relative-OCV model without OCV
    input, always where the OCV was estimated from the records, and where slow tests fixed it
    as TrainConfig.ocv_refinement says ("auto": records at OCV_REFINE_LEVELS or more
    temperature levels)."""
    if not model.relative_ocv or model.ocv_input:
        return False
    if not cfg.ocv_tests or cfg.ocv_refinement == "on":
        return True
    return (cfg.ocv_refinement == "auto"
            and len(temperature_levels(segs)) >= OCV_REFINE_LEVELS)


def ocv_anchor(knots: np.ndarray, n_total: float, from_tests: bool) -> np.ndarray:
    """√ of the weight (per knot) that pulls each refined OCV knot back to its start value.

    Estimated OCV: 10 mV away from the pre-fit costs like 0.1 % of the samples being 10 mV off,
    a weak anchor. OCV from slow tests: 1 mV away costs like OCV_TEST_ANCHOR of the samples
    being 1 mV off, and the knots below OCV_REFINE_SOC_MIN are held (10⁴ times that weight):
    there the free-run error is the collapse before cut-off, a dynamic error that a static OCV
    correction would only displace onto the rests."""
    if not from_tests:
        return np.full(knots.size, np.sqrt(n_total) * 0.1)
    held = np.where(knots < OCV_REFINE_SOC_MIN - 1e-9, 100.0, 1.0)
    return np.sqrt(OCV_TEST_ANCHOR * n_total) * held


def offset_ridge_of(cfg: TrainConfig, model: LmnModel) -> float:
    """ρ of the offset ridge for this model: the setting, where it is "auto" only for models
    without temperature terms (with them the offset is a polynomial in dT, of which the ridge
    would pull the value at T_ref alone)."""
    if cfg.offset_ridge == "auto" and model.temperature_terms:
        return 0.0
    return cfg.offset_ridge_weight()


def _offset_ridge(model: LmnModel, Phis: list[np.ndarray], sqrt_weights: list[np.ndarray],
                  rho: float) -> tuple[int | None, np.ndarray]:
    """The offset ridge (TrainConfig.offset_ridge): the θ column of the OCV offset U_off and,
    per local model j, √(ρ·n_j) with n_j = Σ_k w_k·Φ_kj its weighted sample count; the
    residual rows √(ρ·n_j)·U_off,j pull each offset towards 0. (None, []) where ρ = 0 or the
    offset is not one from the OCV (an absolute-output model's offset is the voltage level; with
    the OCV as an input the OCV's own coefficient shifts it)."""
    cols = model.columns()
    if rho <= 0.0 or "1" not in cols or not model.relative_ocv or model.ocv_input:
        return None, np.zeros(0)
    mass = sum(Phi.T @ (sw * sw) for Phi, sw in zip(Phis, sqrt_weights, strict=True))
    return cols.index("1"), np.sqrt(rho * np.asarray(mass, dtype=float))


def _ladder_constraints(ladder: Ladder | None, M: int, p: int, lower: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray] | None:
    """G and h of G·x ≥ h for the refinement's x = [θ of every local model, OCV increments]:
    the ladder's C·θ_j ≥ h_ladder for every local model j, and one identity row per finitely
    bounded entry (the OCV increments ≥ 0). None where there is no ladder."""
    if ladder is None:
        return None
    n, c = lower.size, ladder.C.shape[0]
    blocks = np.zeros((M * c, n))
    for j in range(M):
        blocks[j * c:(j + 1) * c, j * p:(j + 1) * p] = ladder.C
    bounded = np.flatnonzero(np.isfinite(lower))
    return (np.vstack([blocks, np.eye(n)[bounded]]),
            np.concatenate([np.tile(ladder.h, M), lower[bounded]]))


def _solve_in_knot_values(J: np.ndarray, b: np.ndarray, n_res: int, cfg: TrainConfig,
                          constraints: tuple[np.ndarray, np.ndarray] | None, n_theta: int,
                          ocv0: np.ndarray) -> _Solution:
    """The linear refinement with the OCV as knot values (ocv0 + Δ) instead of increments.

    x = [θ, increments] keeps the OCV monotone by bounds alone, but its OCV columns are
    cumulative sums of the hat functions: nearly collinear, so the normal equations that the
    RC-ladder solver (lsi) works on lost the solution (A123, anchor 0.002: training RMSE 3.1 →
    8.3 mV). In z = [θ, Δ] they are the local hat functions, and monotonicity becomes the rows
    Δ_k − Δ_(k−1) ≥ −(ocv0_k − ocv0_(k−1)). constraints: (G, h) of G·x ≥ h on θ alone (the
    RC ladder's rows, _ladder_constraints without bounded entries), or None. Returns the
    solution in x. J is overwritten with the Jacobian in z (J·to_x, in place: it is the largest
    array of training, a row per sample)."""
    K = ocv0.size
    n = n_theta + K
    to_x = np.eye(n)                                 # x = to_x·z + shift
    to_x[n_theta:, n_theta:] = np.eye(K) - np.eye(K, k=-1)
    shift = np.concatenate([np.zeros(n_theta), to_x[n_theta:, n_theta:] @ ocv0])
    bz = b - J @ shift
    Jz = _times_to_knot_values(J, n_theta)
    mono = np.zeros((K - 1, n))                      # the OCV rises: increments ≥ 0
    mono[:, n_theta + 1:] += np.eye(K - 1)
    mono[:, n_theta:-1] -= np.eye(K - 1)
    rows, bounds = [mono], [-np.diff(ocv0)]
    if constraints is not None:
        rows.append(constraints[0])
        bounds.append(constraints[1])
    sol = _robust_linear_solve(Jz, bz, n_res, (np.full(n, -np.inf), np.full(n, np.inf)), cfg,
                               (np.vstack(rows), np.concatenate(bounds)))
    sol.x = to_x @ sol.x + shift
    return sol


def _times_to_knot_values(J: np.ndarray, n_theta: int) -> np.ndarray:
    """J·to_x of _solve_in_knot_values, in place: the OCV increments' columns k become
    column k − column k+1 (the last one stays), the θ columns stay. Each entry is the one
    rounded difference that the matrix product forms, so the result is the product's."""
    J[:, n_theta:-1] -= J[:, n_theta + 1:]
    return J


def _downweighted(normal: tuple[np.ndarray, np.ndarray], J: np.ndarray, b: np.ndarray,
                  weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J'·W·J and J'·W·b from the unweighted J'·J and J'·b, less the rows whose weight is
    below 1: the Huber iterations down-weight a minority of rows, so this costs that
    minority's product instead of all rows'."""
    JtJ, Jtb = normal
    low = np.flatnonzero(weights < 1.0)
    if low.size == 0:
        return JtJ, Jtb
    Js = J[low]
    cut = (1.0 - weights[low])[:, None] * Js
    return JtJ - Js.T @ cut, Jtb - cut.T @ b[low]


HUBER_K = 1.345      # Huber threshold in robust standard deviations (95 % efficiency)
IRLS_ITERATIONS = 8


def _robust_scale(r: np.ndarray) -> float:
    """Standard deviation of the bulk of the residuals: 1.4826·median|r| (zero-weight samples,
    whose residuals are exactly 0, are left out)."""
    r = np.abs(r[r != 0.0])
    return float(1.4826 * np.median(r)) if r.size else 0.0


def _robust_linear_solve(J: np.ndarray, b: np.ndarray, n_res: int,
                         bounds: tuple[np.ndarray, np.ndarray], cfg: TrainConfig,
                         constraints: tuple[np.ndarray, np.ndarray] | None = None
                         ) -> _Solution:
    """min Σ ρ(J·x − b) over the first n_res rows (data) plus plain squares of the rest
    (regularisation), ρ = squares ("none") or Huber ("huber", by iteratively reweighted least
    squares with the scale fixed from the unweighted solution). Deterministic.
    constraints: (G, h) of G·x ≥ h (_ladder_constraints), which then replace `bounds`."""
    method = "bvls" if np.isfinite(bounds[0]).any() else "trf"
    normal = (J.T @ J, J.T @ b) if constraints is not None else None

    def solve(weights: np.ndarray):
        if normal is not None and constraints is not None:
            x = lsi(*_downweighted(normal, J, b, weights), *constraints)
            return _Solution(x, 0.0, 1, 0)
        sw = np.sqrt(weights)
        return lsq_linear(J * sw[:, None], b * sw, bounds=bounds, method=method,
                          lsq_solver="exact")

    weights = np.ones(b.size)
    lin = solve(weights)
    if cfg.robust_loss == "huber":
        scale = HUBER_K * max(_robust_scale((J @ lin.x - b)[:n_res]), 1e-6)
        for _ in range(IRLS_ITERATIONS):
            r = np.abs(J[:n_res] @ lin.x - b[:n_res])
            new = np.ones(b.size)
            new[:n_res] = np.minimum(1.0, scale / np.maximum(r, 1e-300))
            if np.max(np.abs(new - weights)) < 1e-3:
                break
            weights = new
            lin = solve(weights)
    return _Solution(lin.x, 0.0, 2, lin.status)
