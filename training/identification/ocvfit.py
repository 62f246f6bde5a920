"""OCV(SoC) and hysteresis pre-fit: a linear, feedback-free cell model solved by least squares.

u(k) = OCV(SoC(k)) + r0·i(k) + Σ_τ g_τ·LP_τ(i)(k) + M·h_γ(k), with OCV piecewise linear over
equally spaced SoC knots and a second-difference smoothness penalty. Because nothing is fed back,
its equation error is its free-run error; it gives the LMN its OCV curve (constrained to rise
with SoC) and chooses the hysteresis rate γ and the Arrhenius temperature gain.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import lsq_linear
from scipy.signal import lfilter

if TYPE_CHECKING:
    from lmncell.data.records import Record

SMOOTHNESS = 3e-3   # penalty weight per knot, relative to the number of samples
HYSTERESIS_MAX_V = 0.2   # |H| of the pre-fit at most (V): a cell's hysteresis is tens of mV


def hat_basis(soc: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(N, K) linear-interpolation basis; SoC outside the knots is held at the end knot."""
    s = np.clip(soc, knots[0], knots[-1])
    k = np.clip(np.searchsorted(knots, s, side="right") - 1, 0, knots.size - 2)
    frac = (s - knots[k]) / (knots[k + 1] - knots[k])
    B = np.zeros((s.size, knots.size))
    rows = np.arange(s.size)
    B[rows, k] = 1.0 - frac
    B[rows, k + 1] += frac
    return B


def second_difference(k: int) -> np.ndarray:
    D = np.zeros((k - 2, k))
    for r in range(k - 2):
        D[r, r:r + 3] = (1.0, -2.0, 1.0)
    return D


def lowpass(current_a: np.ndarray, tau_s: float, ts: float) -> np.ndarray:
    """First-order low-pass with unit DC gain, zero initial state (training-side helper)."""
    a = np.exp(-ts / tau_s)
    return lfilter([1.0 - a], [1.0, -a], current_a)


@dataclass
class OcvFit:
    knots: np.ndarray
    ocv_v: np.ndarray
    rmse_v: float
    coefficients: np.ndarray
    # per segment Σ w·res² (V²) and Σ w, as tree.freerun_squares' rows
    segment_squares: np.ndarray | None = None


def _segment_squares(res: np.ndarray, w: np.ndarray, lengths: list[int]) -> np.ndarray:
    """(S, 2): each segment's weighted squared residuals Σ w·res² (V²) and weight Σ w."""
    bounds = np.cumsum([0, *lengths])
    return np.array([[float(np.sum(w[a:b] * res[a:b] ** 2)), float(np.sum(w[a:b]))]
                     for a, b in pairwise(bounds)])


def fit_ocv(soc: list[np.ndarray], current: list[np.ndarray], voltage: list[np.ndarray],
            weight: list[np.ndarray], hyst: list[np.ndarray] | None, ts: float,
            taus_s: list[float], n_knots: int,
            gain: list[np.ndarray] | None = None,
            fixed_ocv_v: np.ndarray | None = None, r_knots: int = 1) -> OcvFit:
    """Solve the pre-fit over several segments (lists of equal-length arrays per segment);
    gain multiplies the current terms (the Arrhenius gain g(T)); fixed_ocv_v: a measured OCV at
    the knots, then only the other terms are fitted; r_knots > 1 lets each current term's
    resistance vary piecewise-linearly over that many SoC knots."""
    knots = np.linspace(0.0, 1.0, n_knots)
    if fixed_ocv_v is not None:
        return _fit_with_fixed_ocv(soc, current, voltage, weight, hyst, ts, taus_s, knots,
                                   gain, np.asarray(fixed_ocv_v, dtype=float), r_knots)
    X = _design_matrix(soc, current, hyst, gain, ts, taus_s, r_knots, knots)
    y, w = np.concatenate(voltage), np.concatenate(weight)
    sw = np.sqrt(w)
    A = X * sw[:, None]
    b = y * sw
    D = np.zeros((n_knots - 2, X.shape[1]))
    D[:, :n_knots] = second_difference(n_knots)
    lam = SMOOTHNESS * max(float(w.sum()), 1.0)
    coef = _smooth_solve(A, b, D, lam, n_knots)
    if hyst is not None and abs(coef[-1]) > HYSTERESIS_MAX_V:
        # h near a function of SoC (a small γ, records that rarely reverse the current): the
        # OCV and H·h trade volts for volts (OCV 11.7 V at γ = 0.5); H held at the bound
        h_v = float(np.copysign(HYSTERESIS_MAX_V, coef[-1]))
        coef = np.append(_smooth_solve(A[:, :-1], b - h_v * A[:, -1], D[:, :-1], lam, n_knots),
                         h_v)
    res = y - X @ coef
    rmse = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1.0)))
    return OcvFit(knots, coef[:n_knots].copy(), rmse, coef,
                  _segment_squares(res, w, [len(i) for i in current]))


def _smooth_solve(A: np.ndarray, b: np.ndarray, D: np.ndarray, lam: float,
                  n_knots: int) -> np.ndarray:
    """min ‖A·x − b‖² + lam·‖D·x‖², the OCV knots (the first n_knots of x) non-decreasing."""
    G = A.T @ A + lam * D.T @ D
    G += 1e-10 * (np.trace(G) / G.shape[0]) * np.eye(A.shape[1])
    coef = np.linalg.solve(G, A.T @ b)
    if np.any(np.diff(coef[:n_knots]) < 0):
        coef = _monotone_solve(A, b, D, lam, n_knots)
    return coef


def _monotone_solve(A: np.ndarray, b: np.ndarray, D: np.ndarray, lam: float,
                    n_knots: int) -> np.ndarray:
    """The same least squares with OCV non-decreasing in SoC: knots c = L·d, d_k ≥ 0 (k ≥ 1)."""
    p = A.shape[1]
    T = np.eye(p)
    T[:n_knots, :n_knots] = np.tril(np.ones((n_knots, n_knots)))
    M = np.empty((A.shape[0] + D.shape[0], p))   # [A·T; √lam·D·T], A·T written in place
    np.matmul(A, T, out=M[:A.shape[0]])
    M[A.shape[0]:] = np.sqrt(lam) * D @ T
    rhs = np.concatenate([b, np.zeros(D.shape[0])])
    # ‖M·x − rhs‖² = ‖R·x − Qᵀ·rhs‖² + const (M = Q·R): the bounded solver then works on p
    # rows instead of one per sample (BVLS refactors its matrix at every step)
    q, r = np.linalg.qr(M)
    lo = np.full(p, -np.inf)
    lo[1:n_knots] = 0.0
    sol = lsq_linear(r, q.T @ rhs, bounds=(lo, np.full(p, np.inf)), method="bvls")
    return T @ sol.x


def _current_columns(soc: np.ndarray, current: np.ndarray, gain: list[np.ndarray] | None,
                     k: int, ts: float, taus_s: list[float], r_knots: int) -> np.ndarray:
    """g·i and g·LP_τ(i) (A), each times the SoC hat functions when r_knots > 1."""
    g = np.ones_like(current) if gain is None else gain[k]
    terms = np.column_stack([g * current] + [g * lowpass(current, tau, ts) for tau in taus_s])
    if r_knots <= 1:
        return terms
    B = hat_basis(soc, np.linspace(0.0, 1.0, r_knots))
    return (terms[:, :, None] * B[:, None, :]).reshape(len(current), -1)


def _design_matrix(soc: list[np.ndarray], current: list[np.ndarray],
                   hyst: list[np.ndarray] | None, gain: list[np.ndarray] | None, ts: float,
                   taus_s: list[float], r_knots: int, knots: np.ndarray | None) -> np.ndarray:
    """The pre-fit's regressors of all segments, one row per sample: the OCV hat functions
    (where knots are given), the current columns and the hysteresis column (where given).
    Written segment by segment into one array (not stacked from per-segment copies: at 300k
    samples and 63 columns each copy is 150 MB)."""
    n_rows = sum(len(i) for i in current)
    X: np.ndarray | None = None
    start = 0
    for k, (s, i) in enumerate(zip(soc, current, strict=True)):
        cols = [_current_columns(s, i, gain, k, ts, taus_s, r_knots)]
        if knots is not None:
            cols.insert(0, hat_basis(s, knots))
        if hyst is not None:
            cols.append(hyst[k][:, None])
        block = np.hstack(cols)
        if X is None:
            X = np.empty((n_rows, block.shape[1]))
        X[start:start + len(i)] = block
        start += len(i)
    if X is None:
        raise ValueError("the pre-fit got no segments")
    return X


def _fit_with_fixed_ocv(soc, current, voltage, weight, hyst, ts, taus_s, knots, gain,
                        ocv_v: np.ndarray, r_knots: int = 1) -> OcvFit:
    X = _design_matrix(soc, current, hyst, gain, ts, taus_s, r_knots, None)
    y = np.concatenate([u - np.interp(s, knots, ocv_v)
                        for s, u in zip(soc, voltage, strict=True)])
    w = np.concatenate(weight)
    sw = np.sqrt(w)
    coef = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]
    res = y - X @ coef
    rmse = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1.0)))
    return OcvFit(knots, ocv_v.copy(), rmse, coef,
                  _segment_squares(res, w, [len(i) for i in current]))


def _read_slow_tests(paths: list) -> list[Record]:
    """The slow OCV tests' records: [the round trip] for one file (full → empty → full), else
    [the discharge from full, the charge from empty] of two files given in either order;
    DataError for two that run the same way or another number of files."""
    from lmncell.data.readers import read_record
    from lmncell.data.records import DataError
    from lmncell.data.soc import charge_throughput_ah

    recs = [read_record(p) for p in paths]
    if len(recs) == 1:
        return recs
    if len(recs) != 2:
        raise DataError(f"ocv_tests: expected one or two files, got {len(recs)}")
    net = [float(charge_throughput_ah(r)[-1]) for r in recs]
    if (net[0] < 0) == (net[1] < 0):
        raise DataError(f"ocv_tests: {recs[0].name} and {recs[1].name} both "
                        f"{'discharge' if net[0] < 0 else 'charge'} (net {net[0]:+.3f} and "
                        f"{net[1]:+.3f} Ah); expected a discharge from full and a charge "
                        "from empty")
    return recs if net[0] < 0 else recs[::-1]


def ocv_test_capacity_ah(paths: list) -> float:
    """The capacity (Ah) that slow OCV tests deliver from full to empty: a round trip's own
    (its current offset balanced out), else the discharge test's discharged charge."""
    from lmncell.data.soc import charge_throughput_ah, ocv_from_round_trip

    tests = _read_slow_tests(paths)
    if len(tests) == 1:
        return ocv_from_round_trip(tests[0]).capacity_ah
    return -float(charge_throughput_ah(tests[0]).min())


def measured_ocv(paths: list, capacity_ah: float, knots: np.ndarray) -> np.ndarray:
    """Mean of the charge and discharge branches of slow tests at the knots (V).

    paths: a discharge test (starts full) and a charge test (starts empty), in either order,
    or one file that holds both (full → empty → full; its current offset is balanced out and
    its SoC is a fraction of its own capacity, see lmncell.data.soc.ocv_from_round_trip)."""
    from lmncell.data.soc import ocv_from_round_trip, ocv_from_slow_tests

    tests = _read_slow_tests(paths)
    curve = (ocv_from_round_trip(tests[0], model_capacity_ah=capacity_ah).curve
             if len(tests) == 1 else ocv_from_slow_tests(tests[0], tests[1], capacity_ah))
    return np.interp(knots, curve.soc, curve.mean_v)
