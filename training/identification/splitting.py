"""One split of the tree: the worst leaf becomes a node with a sigmoid validity and two
children. Only the new node's weights ψ (Levenberg–Marquardt) and the two children's parameters
(locally weighted least squares at every step) are optimised; nothing else changes."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from lmncell.config import TrainConfig
from lmncell.identification.tree import stabilise, wls

Fit = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _sigmoid(a: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):        # exp(−a) → inf gives the correct limit 0
        return 1.0 / (1.0 + np.exp(-a))


@dataclass
class SplitResult:
    psi: np.ndarray
    theta_a: np.ndarray
    theta_b: np.ndarray
    loss: float
    loss_history: list[float]


def _split_children(psi: np.ndarray, X: np.ndarray, y: np.ndarray, w: np.ndarray, Pj: np.ndarray,
                    Z1: np.ndarray, r_rest: np.ndarray, na: int, max_pole: float,
                    fit: Fit = wls):
    phi = _sigmoid(Z1 @ psi)
    wa, wb = w * Pj * phi, w * Pj * (1.0 - phi)
    ta = stabilise(fit(X, y, wa), na, max_pole, X, y, wa)
    tb = stabilise(fit(X, y, wb), na, max_pole, X, y, wb)
    ya, yb = X @ ta, X @ tb
    e = r_rest - Pj * (phi * ya + (1.0 - phi) * yb)
    return ta, tb, ya, yb, phi, e, float(np.sum(w * e * e))


def optimise_split(X: np.ndarray, y: np.ndarray, w: np.ndarray, Z: np.ndarray, Pj: np.ndarray,
                   r_rest: np.ndarray, cfg: TrainConfig,
                   fixed_axes: frozenset[int] = frozenset(), fit: Fit = wls
                   ) -> SplitResult | None:
    """Best initial orthogonal split of one leaf, then Levenberg–Marquardt on its weights ψ.
    fixed_axes: partition axes the split may not use (their weights stay 0); fit: the local
    weighted least squares (Design.fit: bounded for RC-ladder local models)."""
    na, max_pole = cfg.output_lags, cfg.max_pole
    sel = Pj > 1e-6 * Pj.max()
    X, y, w, Z, Pj, r_rest = X[sel], y[sel], w[sel], Z[sel], Pj[sel], r_rest[sel]
    Z1 = np.hstack([np.ones((Z.shape[0], 1)), Z])
    wl = w * Pj
    if wl.sum() <= 0:
        return None

    def children(psi: np.ndarray) -> tuple:
        return _split_children(psi, X, y, w, Pj, Z1, r_rest, na, max_pole, fit)

    best = _best_orthogonal_split(Z, wl, fixed_axes, children)
    if best is None:
        return None
    psi, axis, res = best
    free = (np.array([0] + [a + 1 for a in range(Z.shape[1]) if a not in fixed_axes])
            if cfg.oblique else np.array([0, axis + 1]))
    return _levenberg_marquardt(psi, res, free, w, Pj, Z1, cfg.lm_iterations, children)


def _best_orthogonal_split(Z: np.ndarray, wl: np.ndarray, fixed_axes: frozenset[int],
                           children: Callable[[np.ndarray], tuple]
                           ) -> tuple[np.ndarray, int, tuple] | None:
    """The orthogonal split (ψ, its axis, children(ψ)) of least loss among the free axes: each
    at the weighted median of its partition input, its steepness 2 / the weighted spread
    (wl: the samples' weights times the leaf's validity); None where no axis spreads."""
    best = None
    for axis in range(Z.shape[1]):
        if axis in fixed_axes:
            continue
        zc = Z[:, axis]
        order = np.argsort(zc, kind="stable")
        cum = np.cumsum(wl[order])
        median = zc[order][np.searchsorted(cum, 0.5 * cum[-1])]
        spread = float(np.sqrt(np.sum(wl * (zc - np.sum(wl * zc) / wl.sum())**2) / wl.sum()))
        if spread < 1e-6:
            continue
        kappa = 2.0 / spread
        psi = np.zeros(Z.shape[1] + 1)
        psi[0], psi[axis + 1] = -kappa * median, kappa
        res = children(psi)
        if best is None or res[-1] < best[2][-1]:
            best = (psi, axis, res)
    return best


def _levenberg_marquardt(psi: np.ndarray, res: tuple, free: np.ndarray, w: np.ndarray,
                         Pj: np.ndarray, Z1: np.ndarray, iterations: int,
                         children: Callable[[np.ndarray], tuple]) -> SplitResult:
    """Levenberg–Marquardt on the split's weights ψ[free] from ψ (res = children(ψ)): the two
    local models are refitted at each trial ψ, a step is kept where the loss falls, and the
    iterations stop where it falls by less than a millionth."""
    lam, history = 1e-2, [res[-1]]
    ta, tb, ya, yb, phi, e, loss = res
    for _ in range(iterations):
        F = (Pj * (ya - yb) * phi * (1.0 - phi))[:, None] * Z1[:, free]
        H = F.T @ (F * w[:, None])
        g = F.T @ (w * e)
        improved = False
        for _try in range(8):
            step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
            cand = psi.copy()
            cand[free] += step
            new = children(cand)
            if new[-1] < loss:
                psi, (ta, tb, ya, yb, phi, e, loss) = cand, new
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
        history.append(loss)
        if not improved or history[-2] - loss < 1e-6 * history[-2]:
            break
    return SplitResult(psi, ta, tb, loss, history)
