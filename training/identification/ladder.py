"""Local models as RC ladders: the identification's constraint that keeps them interpretable.

A feedback-free local model (output_lags = 0) whose filters form a chain (each filter
v = LP_fast(i) − LP_slow(i), every time constant at or above the sample time Ts shared by the
filters exactly as in a ladder) is, term by term, an equivalent circuit:

    u − OCV = R0·i(k) + Σ_l b_l·i(k−l) + Σ_τ R_τ·LP_τ(i) + H·h + R_d·d + U_off

(R0 the instantaneous resistance including the sub-Ts filters and the current lags' sum, R_τ an RC
element of time constant τ, H the hysteresis voltage, R_d the depletion resistance at SoC 0.1 of
the depletion regressor d (model.Depletion; R_d2 of the fast one, d2, likewise), U_off the local
OCV offset). The map from
the regressor coefficients θ to these parameters is linear; with temperature terms (θ then
holds polynomials in dT) it is taken at a grid of temperatures across the training range. The
identification solves its (locally weighted) least-squares problems under C·θ ≥ h: R0, R_τ, H
R_d (R_d2) ≥ 0, and with an offset bound U_max (TrainConfig.offset_bound_mv) |U_off| ≤ U_max, at
every grid temperature (least squares with linear inequality constraints, by the
Lawson–Hanson reduction to a least-distance problem solved by NNLS, its answer checked against
the optimality conditions (verified_nnls): exact, deterministic), so
that the runtime, the model file and the FMUs are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import arrhenius_factor
from scipy.linalg import cho_factor, solve_triangular
from scipy.optimize import lsq_linear, nnls

GRID_STEP_K = 1.0      # spacing of the temperatures where the ladder must hold (degree ≥ 2)
NNLS_KKT_TOL = 1e-9    # largest gradient E'·(t − E·v) an NNLS solution may leave (unit columns)


def ladder_keys(filters: list[tuple[float, float]] | list[list[float]],
                sample_time_s: float) -> list[float]:
    """The RC time constants (s) of a filter chain: every corner at or above Ts (sorted)."""
    return sorted({float(t) for pair in filters for t in pair if t >= sample_time_s})


def is_ladder(filters: list[tuple[float, float]] | list[list[float]], sample_time_s: float,
              output_lags: int) -> bool:
    """True where the local models can be read (and constrained) as RC ladders: no output
    feedback, and as many RC time constants as filters (a chain such as [[0.01, 5], [5, 30]])."""
    if output_lags != 0 or not filters:
        return False
    a = filter_to_ladder(list(filters), sample_time_s)[1:]
    return a.shape[0] == a.shape[1] and np.linalg.matrix_rank(a) == a.shape[0]


def filter_to_ladder(filters: list, sample_time_s: float) -> np.ndarray:
    """(1 + keys, F): how the filter coefficients g add up to the ladder. Each filter
    v = LP_fast − LP_slow puts +g on its fast and −g on its slow time constant; row 0 collects
    those below the sample time (instantaneous: a share of R0), then one row per RC time
    constant of ladder_keys."""
    keys = ladder_keys(filters, sample_time_s)
    a = np.zeros((1 + len(keys), len(filters)))
    for f, (fast, slow) in enumerate(filters):
        for tau, sign in ((float(fast), 1.0), (float(slow), -1.0)):
            a[0 if tau < sample_time_s else 1 + keys.index(tau), f] += sign
    return a


def coefficient_row(model: LmnModel, source: str, temperature_c: float) -> np.ndarray:
    """Row vector over the model's columns: the coefficient of a plain column at a
    temperature, its temperature terms summed in (row @ θ gives the value)."""
    cols = model.columns()
    if model.in_activation_step(source):
        gain = arrhenius_factor(temperature_c, model.arrhenius_k, model.reference_temperature_c,
                                model.activation_t0_k)
        step = model.activation_step(temperature_c, gain)
    else:
        step = model.temperature_step(temperature_c)
    v = np.zeros(len(cols))
    v[cols.index(source)] = 1.0
    for power in range(1, model.temperature_terms + 1):
        name = model.temperature_term_name(source, power)
        if name in cols:
            v[cols.index(name)] = step ** power
    return v


def constraint_temperatures_c(t_min_c: float, t_max_c: float, degree: int,
                              reference_c: float) -> list[float]:
    """Temperatures where every R and H must be ≥ 0: the reference temperature without
    temperature terms, both ends for degree 1 (linear: then everywhere between), else a grid
    across the training range no coarser than GRID_STEP_K (between its points a polynomial of
    degree 2 or 3 can dip below 0 by a negligible amount only)."""
    if degree == 0 or t_max_c - t_min_c < 1e-6:
        return [reference_c]
    if degree == 1:
        return [t_min_c, t_max_c]
    points = max(3, int(np.ceil((t_max_c - t_min_c) / GRID_STEP_K)) + 1)
    return np.linspace(t_min_c, t_max_c, points).tolist()


class InfeasibleError(ArithmeticError):
    """No usable solution: the constraints have none, or (for C·θ ≥ 0, which θ = 0 meets) the
    optimum lies so far beyond the data's reach that the least-distance solve loses it."""


def lsi(H: np.ndarray, c: np.ndarray, C: np.ndarray, h: np.ndarray) -> np.ndarray:
    """min ½·x'Hx − c'x subject to C·x ≥ h (H symmetric positive semi-definite; a relative
    ridge of 1e-9 makes it definite): Lawson & Hanson's reduction of least squares with
    linear inequality constraints to a least-distance problem, solved by NNLS."""
    p = H.shape[0]
    scale = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hs = H / np.outer(scale, scale) + 1e-9 * np.eye(p)
    L = np.tril(cho_factor(Hs, lower=True)[0])              # Hs = L·L'
    f = solve_triangular(L, c / scale, lower=True)          # objective ‖L'·xs − f‖²
    free = solve_triangular(L.T, f, lower=False)
    Cs = C / scale[None, :]
    if C.shape[0] == 0 or np.all(Cs @ free >= h - 1e-12 * (1.0 + np.abs(h))):
        return free / scale
    A = solve_triangular(L, Cs.T, lower=True).T              # Cs·L'^{-1}
    b = h - A @ f
    E = np.vstack([A.T, b[None, :]])
    target = np.zeros(p + 1)
    target[-1] = 1.0
    # NNLS on unit columns (u = v/‖E_i‖ ≥ 0 is the same problem): with columns whose norms
    # span four decades (a depletion regressor near empty beside the others) the unscaled
    # NNLS stopped at a point that broke constraints by up to 0.14 V/A
    with np.errstate(over="ignore", invalid="ignore"):   # an optimum far beyond precision
        norms = np.linalg.norm(E, axis=0)                  # ends in InfeasibleError below
        norms = np.where(norms > 0.0, norms, 1.0)
        v = verified_nnls(E / norms[None, :], target)
        r = E @ (v / norms) - target
    if not abs(r[-1]) > 1e-12:
        raise InfeasibleError("the inequality constraints have no solution")
    z = -r[:p] / r[-1]
    return solve_triangular(L.T, z + f, lower=False) / scale


def verified_nnls(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """min ‖A·v − b‖ over v ≥ 0 (A's columns of unit norm): scipy's NNLS, its answer checked
    against the optimality conditions (g = A'·(b − A·v): no column may still lower the
    residual, g ≤ NNLS_KKT_TOL, and v·|g| ≤ NNLS_KKT_TOL, g = 0 where v > 0), else the
    bounded-variable solver's (where that one stops short too, the one of the two answers with
    the smaller residual; where it fails, LAPACK's SVD not converging on a free subset, NNLS's
    answer as it is). SciPy ≥ 1.15's NNLS can stop at a point that fails them and
    report a residual norm that is not the point's (scipy/scipy#25389): on an A123 refinement
    with 4004 ladder rows, relative perturbations of 1e-15 in its matrix gave residual norms
    0.903 … 1.000 where the optimum is 0.903, and the normal matrix summed in another order a
    refinement step 3.5 % worse on its own fit that broke its constraints by 1e-5."""
    with np.errstate(over="ignore", invalid="ignore"):
        v, _ = nnls(A, b, maxiter=50 * A.shape[1])
        grad = A.T @ (b - A @ v)
    if np.all(np.isfinite(grad)) and max(grad.max(initial=0.0),
                                         np.abs(v * grad).max(initial=0.0)) <= NNLS_KKT_TOL:
        return v
    try:
        bvls = lsq_linear(A, b, bounds=(0.0, np.inf), method="bvls", tol=1e-14).x
    except np.linalg.LinAlgError:
        # an A123 refinement (204 × 2638, s1 + s3 records): NNLS 2.5e-6 off its conditions,
        # 4e-6 above BVLS's residual on a perturbed copy; the training went on from there
        return v
    return bvls if np.linalg.norm(A @ bvls - b) <= np.linalg.norm(A @ v - b) else v


@dataclass(frozen=True)
class Ladder:
    """The constraints C·θ ≥ h of an RC-ladder local model (rows named in `names`; h is 0 but
    for the offset bound's rows, −U_max)."""

    C: np.ndarray
    names: list[str]
    h: np.ndarray

    def solve(self, X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Weighted least squares of y ≈ X·θ under the ladder's constraints; returns θ."""
        Xw = X * w[:, None]
        return lsi(X.T @ Xw, Xw.T @ y, self.C, self.h)

    def holds(self, theta: np.ndarray, tol: float = 1e-9) -> bool:
        """True where θ satisfies the constraints (to tol, V/A or V)."""
        return bool(np.all(self.C @ theta >= self.h - tol))


def ladder_for(model: LmnModel, t_min_c: float = 25.0, t_max_c: float = 25.0,
               offset_bound_v: float = 0.0) -> Ladder | None:
    """The ladder constraints of a model's local models, or None where they are not ladders
    (is_ladder). t_min_c … t_max_c: the training temperature range (for temperature terms);
    offset_bound_v > 0 also bounds |U_off| by it at those temperatures (0: unbounded)."""
    if not is_ladder(model.filters, model.sample_time_s, model.output_lags):
        return None
    n = model.temperature_terms
    temps = constraint_temperatures_c(t_min_c, t_max_c, n, model.reference_temperature_c)
    keys = ladder_keys(model.filters, model.sample_time_s)
    a = filter_to_ladder(list(model.filters), model.sample_time_s)
    sources = model.temperature_term_sources()
    rows: list[np.ndarray] = []
    names: list[str] = []
    for t in temps:
        tag = "" if n == 0 else f"@{t:g}C"
        cur = sum(coefficient_row(model, c, t) for c in sources if c.startswith("i(k"))
        filt = np.array([coefficient_row(model, f"v{f + 1}(k)", t)
                         for f in range(len(model.filters))])
        rows.append(cur + a[0] @ filt)
        names.append(f"R0{tag}")
        for k, tau in enumerate(keys):
            rows.append(a[1 + k] @ filt)
            names.append(f"R_{tau:g}s{tag}")
        if "h(k)" in sources:
            rows.append(coefficient_row(model, "h(k)", t))
            names.append(f"H{tag}")
    if "h(k)" in model.columns() and "h(k)" not in sources:   # "constant" hysteresis terms
        rows.append(coefficient_row(model, "h(k)", model.reference_temperature_c))
        names.append("H")
    if model.depletion is not None:       # no temperature terms: one row each
        for col, name in zip(model.depletion.columns(), ("R_depletion", "R_depletion_fast"),
                             strict=False):
            rows.append(coefficient_row(model, col, model.reference_temperature_c))
            names.append(name)
    h = [0.0] * len(rows)
    if offset_bound_v > 0.0 and "1" in model.columns():
        for t in temps:
            tag = "" if n == 0 else f"@{t:g}C"
            row = coefficient_row(model, "1", t)
            rows += [row, -row]
            names += [f"U_off≥−max{tag}", f"U_off≤max{tag}"]
            h += [-offset_bound_v, -offset_bound_v]
    return Ladder(np.array(rows), names, np.array(h))
