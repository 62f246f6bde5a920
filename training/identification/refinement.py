"""Final output-error refinement: every local model (and the OCV knots) by Levenberg–Marquardt
on the free-run simulation error, sensitivities propagated through the output feedback, with
a Huber loss (iteratively reweighted least squares where there is no output feedback), and
where slow OCV tests fix the OCV a ridge that pulls each local OCV offset towards 0
(TrainConfig.offset_ridge) and, for records at three or more temperatures, OCV knots anchored
to the test's (TrainConfig.ocv_refinement)."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from lmncell.config import OCV_REFINE_LEVELS, OCV_REFINE_SOC_MIN, OCV_TEST_ANCHOR, TrainConfig
from lmncell.data.dataset import Segment
from lmncell.identification.ladder import Ladder, lsi
from lmncell.identification.ocvfit import SMOOTHNESS, hat_basis, second_difference
from lmncell.identification.prefit import temperature_levels
from lmncell.identification.tree import Design, _lags, freerun_rmse, stabilise
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import fixed_point, initial_hysteresis, recursion
from scipy.optimize import least_squares, lsq_linear

Progress = Callable[[str], None]


@dataclass
class _Solution:
    x: np.ndarray
    cost: float
    nfev: int
    status: int


def _sensitivity(A: np.ndarray, G: np.ndarray) -> np.ndarray:
    """S(k) = G(k) + Σ_l A(k,l)·S(k−l), S(k<0) = 0: ∂ŷ/∂params through the feedback."""
    n, na = A.shape
    S = np.empty_like(G)
    for k in range(n):
        row = G[k].copy()
        for l in range(1, na + 1):
            if k - l >= 0:
                row += A[k, l - 1] * S[k - l]
        S[k] = row
    return S


def refine_output_error(model: LmnModel, segs: list[Segment], design: Design,
                        cfg: TrainConfig, progress: Progress) -> tuple[LmnModel, dict]:
    """Levenberg–Marquardt on the free-run error of all segments (θ of every local model and,
    where refines_ocv says so, the OCV knots)."""
    M, p = model.theta.shape
    na = model.output_lags
    with_ocv = refines_ocv(model, segs, cfg)
    knots = model.ocv_soc
    K = knots.size if with_ocv else 0
    w_all = [np.sqrt(design.w_fit[a:b] + design.w_val[a:b]) for a, b in design.bounds]
    Phis = [model.validities(ex.z, ex.direction) for ex in design.exo]
    Bs = [hat_basis(ex.soc, knots) for ex in design.exo] if with_ocv else []
    h0s = [initial_hysteresis(s.soc0) for s in segs]
    t0s = [25.0 if s.temperature_c is None else float(s.temperature_c[0]) for s in segs]
    theta0 = model.theta.copy()
    n_total = float(sum(float(np.sum(w * w)) for w in w_all))
    lam_ocv = np.sqrt(SMOOTHNESS * n_total) * 1e-3
    D2 = second_difference(K) if K >= 3 else np.zeros((0, K))
    ridge = 1e-3
    rho = offset_ridge_of(cfg, model)
    off_col, off_lam = _offset_ridge(model, Phis, w_all, rho)
    cache: dict = {}

    ocv0 = model.ocv_v.copy()
    lam_anchor = ocv_anchor(knots, n_total, bool(cfg.ocv_tests))
    tri = np.tril(np.ones((K, K)))
    # the penalty rows below the residuals are linear in x: their Jacobian is built once
    j_pen = [np.hstack([np.sqrt(ridge) * np.eye(M * p), np.zeros((M * p, K))])]
    if off_col is not None:
        j_off = np.zeros((M, M * p + K))
        j_off[np.arange(M), np.arange(M) * p + off_col] = off_lam
        j_pen.append(j_off)
    if with_ocv and D2.shape[0]:
        j_pen.append(np.hstack([np.zeros((D2.shape[0], M * p)), lam_ocv * D2 @ tri]))
    if with_ocv:
        j_pen.append(np.hstack([np.zeros((K, M * p)), lam_anchor[:, None] * tri]))
    j_penalty = np.vstack(j_pen)

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # OCV knots as a start value plus non-negative increments (OCV rises with SoC)
        return x[: M * p].reshape(M, p), (np.cumsum(x[M * p:]) if with_ocv else model.ocv_v)

    def evaluate(x: np.ndarray):
        key = x.tobytes()
        if key in cache:
            return cache[key]
        theta, ocv_v = unpack(x)
        m = copy.copy(model)
        m.theta, m.ocv_v = theta, ocv_v.copy()
        res, jac = [], []
        for seg, ex, Phi, sw, h0, t0, k in zip(segs, design.exo, Phis, w_all, h0s, t0s,
                                               range(len(segs)), strict=True):
            A = Phi @ theta[:, :na]
            b = np.sum(Phi * (ex.x @ theta[:, na:].T), axis=1)
            y0 = fixed_point(m, seg.soc0, t0, h0)
            y = recursion(A, b, [y0] * na)
            u = y + m.ocv(ex.soc) if m.relative_ocv else y
            r = sw * (seg.voltage_v - u)
            if not np.isfinite(r).all():
                r = np.where(np.isfinite(r), r, 1e3)
            res.append(r)
            ylag = _lags(np.concatenate([[y0], y]), na)[1:]    # y(k−l), y0 before the start
            Xs = np.hstack([ylag, ex.x])
            G = (Phi[:, :, None] * Xs[:, None, :]).reshape(y.size, M * p)
            S = _sensitivity(A, G)
            J = -sw[:, None] * S
            if with_ocv:
                J = np.hstack([J, -sw[:, None] * (Bs[k] @ tri)])
            jac.append(J)
        x_extra = [np.sqrt(ridge) * (theta - theta0).ravel()]    # rows in j_penalty's order
        if off_col is not None:
            x_extra.append(off_lam * theta[:, off_col])
        if with_ocv and D2.shape[0]:
            x_extra.append(lam_ocv * D2 @ ocv_v)
        if with_ocv:
            x_extra.append(lam_anchor * (ocv_v - ocv0))
        out = (np.concatenate(res + x_extra), np.vstack([*jac, j_penalty]))
        cache.clear()
        cache[key] = out
        return out

    incr0 = np.concatenate([[ocv0[0]], np.maximum(np.diff(ocv0), 0.0)]) if with_ocv else []
    x0 = np.concatenate([model.theta.ravel(), incr0])
    lower = np.full(x0.size, -np.inf)
    if with_ocv:
        lower[M * p + 1:] = 0.0
    r0 = evaluate(x0)[0]
    n_res = int(sum(w.size for w in w_all))
    t_start = time.perf_counter()
    upper = np.full(x0.size, np.inf)
    if na == 0:
        # no output feedback: the free-run error is affine in the parameters; (iteratively
        # reweighted) bounded linear least squares gives the exact optimum (under the RC-ladder
        # constraints where the local models are ladders)
        r_0, J_0 = evaluate(x0)
        if with_ocv:
            on_theta = _ladder_constraints(design.ladder, M, p, np.full(x0.size, -np.inf))
            sol = _solve_in_knot_values(J_0, J_0 @ x0 - r_0, n_res, cfg, on_theta, M * p, ocv0)
        else:
            sol = _robust_linear_solve(J_0, J_0 @ x0 - r_0, n_res, (lower, upper), cfg,
                                       _ladder_constraints(design.ladder, M, p, lower))
        sol.cost = float(0.5 * np.sum(evaluate(sol.x)[0] ** 2))
    else:
        robust = {}
        if cfg.robust_loss == "huber":
            robust = {"loss": "huber",
                      "f_scale": HUBER_K * max(_robust_scale(r0[:n_res]), 1e-6)}
        with np.errstate(over="ignore", invalid="ignore"):
            sol = least_squares(lambda x: evaluate(x)[0], x0, jac=lambda x: evaluate(x)[1],
                                bounds=(lower, upper), method="trf",
                                x_scale="jac", max_nfev=cfg.oe_max_iterations,
                                ftol=1e-8, xtol=1e-10, gtol=1e-10, **robust)
    theta, ocv_v = unpack(sol.x)
    theta = np.vstack([stabilise(t, na, cfg.max_pole) for t in theta])
    out = copy.copy(model)
    out.theta, out.ocv_v = theta, np.array(ocv_v, dtype=float)
    before = freerun_rmse(model, segs, design, "fit")
    after = freerun_rmse(out, segs, design, "fit")
    accepted = bool(np.isfinite(after) and after < before)
    info = {"initial_cost": float(0.5 * r0 @ r0), "final_cost": float(sol.cost),
            "evaluations": int(sol.nfev), "seconds": time.perf_counter() - t_start,
            "status": int(sol.status), "train_rmse_before_mv": 1e3 * before,
            "train_rmse_after_mv": 1e3 * after, "accepted": accepted,
            "offset_ridge": rho if off_col is not None else 0.0, "ocv_refined": with_ocv}
    progress(f"  output-error refinement: free-run training RMSE {1e3 * before:.2f} → "
             f"{1e3 * after:.2f} mV in {sol.nfev} evaluations"
             + (f", offsets pulled towards 0 (ρ = {info['offset_ridge']:g})"
                if info["offset_ridge"] else "")
             + (f", the test's OCV refined above SoC {OCV_REFINE_SOC_MIN:g}"
                if with_ocv and cfg.ocv_tests else "")
             + ("" if accepted else " (not better: kept the model before refinement)"))
    return (out if accepted else model), info


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
    solution in x."""
    K = ocv0.size
    n = n_theta + K
    to_x = np.eye(n)                                 # x = to_x·z + shift
    to_x[n_theta:, n_theta:] = np.eye(K) - np.eye(K, k=-1)
    shift = np.concatenate([np.zeros(n_theta), to_x[n_theta:, n_theta:] @ ocv0])
    Jz = J @ to_x
    bz = b - J @ shift
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

    def solve(weights: np.ndarray):
        if constraints is not None:
            Jw = J * weights[:, None]
            x = lsi(J.T @ Jw, Jw.T @ b, *constraints)
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
