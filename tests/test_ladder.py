"""RC-ladder local models: the bounded identification, the explain table, the settings."""

from __future__ import annotations

import numpy as np
import pytest
from lmncell.config import ConfigError, load_config
from lmncell.data.dataset import Segment
from lmncell.evaluation.interpret import explain_text, ladder_parameters, local_model_table
from lmncell.identification import ladder as ladder_module
from lmncell.identification.construction import train_lmn
from lmncell.identification.ladder import (
    constraint_temperatures_c,
    is_ladder,
    ladder_for,
    verified_nnls,
)
from lmncell.identification.ocvfit import lowpass
from lmncell.identification.tree import skeleton, wls

R0, R30, R800 = 0.020, 0.015, 0.025      # Ω: the synthetic cell's R0 and RC elements (τ s)


def _rc_cell(n: int = 20000, seed: int = 5) -> tuple[list[Segment], float]:
    """A 2RC cell with τ = 30 s and 800 s (two of the default ladder's time constants),
    a linear OCV, current steps of random level and length, 0.3 mV measurement noise."""
    rng = np.random.default_rng(seed)
    cap, ts = 2.0, 1.0
    levels = rng.choice([-4.0, -2.0, -1.0, 0.0, 0.0, 1.0, 2.0], size=n // 10)
    lengths = rng.integers(5, 400, size=levels.size)
    i = np.repeat(levels, lengths)[:n]
    i -= np.mean(i) + 0.25                      # net discharge of 0.25 A: SoC 0.9 → ~0.2
    soc = 0.9 + np.cumsum(i) * ts / 3600.0 / cap
    u = (3.3 + 0.8 * soc + R0 * i + R30 * lowpass(i, 30.0, ts) + R800 * lowpass(i, 800.0, ts)
         + 3e-4 * rng.standard_normal(i.size))
    seg = Segment("rc", np.arange(1, i.size + 1) * ts, i, u, None, 0.9, soc, np.ones(i.size))
    return [seg], cap


def test_ladder_recovers_the_rc_elements_of_a_synthetic_cell() -> None:
    segs, cap = _rc_cell()
    cfg = load_config(max_local_models=1, hysteresis="off", temperature_scaling="off")
    model = train_lmn(segs, cfg, cap).model
    row = ladder_parameters(model, model.theta[0], 25.0)
    rc = row["rc_mohm_by_tau_s"]
    assert row["rc_positive"]
    assert rc["0"] == pytest.approx(1e3 * R0, abs=0.3)
    assert rc["30"] == pytest.approx(1e3 * R30, abs=0.3)
    assert rc["800"] == pytest.approx(1e3 * R800, abs=0.5)
    assert rc["5"] + rc["150"] + rc["3000"] < 0.5     # elements the cell does not have: ~0
    assert row["r_static_mohm"] == pytest.approx(1e3 * (R0 + R30 + R800), rel=0.02)


def test_ladder_solution_equals_least_squares_where_that_is_feasible_and_bounds_it_else() -> None:
    cfg = load_config(hysteresis="off", temperature_scaling="off")
    base = skeleton(cfg, 2.0, np.array([0.0, 1.0]), np.array([3.3, 4.1]), None,
                    np.zeros(1), np.ones(1))
    ladder = ladder_for(base)
    assert ladder is not None
    rng = np.random.default_rng(1)
    p = ladder.C.shape[1]
    X = rng.standard_normal((500, p))
    # θ of a ladder with every element positive: R0 = 20, R_τ = 5…25 mΩ
    theta_ok = np.linalg.lstsq(ladder.C, np.linspace(0.02, 0.005, ladder.C.shape[0]),
                               rcond=None)[0]
    w = np.ones(500)
    y = X @ theta_ok
    assert ladder.holds(theta_ok)
    assert np.allclose(ladder.solve(X, y, w), wls(X, y, w), atol=1e-8)
    k = ladder.names.index("R_150s")
    theta_bad = theta_ok - 0.03 * ladder.C[k] / (ladder.C[k] @ ladder.C[k]) * 1.0
    assert ladder.C[k] @ theta_bad < 0                # the unconstrained fit is negative
    theta = ladder.solve(X, X @ theta_bad, w)
    assert ladder.holds(theta, 1e-12)
    assert ladder.C[k] @ theta == pytest.approx(0.0, abs=1e-9)


def _nnls_problem(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A non-negative least-squares problem with unit columns whose optimum has some v = 0."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((40, 25))
    return A / np.linalg.norm(A, axis=0), rng.standard_normal(40)


def _kkt_gap(A: np.ndarray, b: np.ndarray, v: np.ndarray) -> float:
    """How far v is from the NNLS optimum's conditions, g = A'(b − Av) ≤ 0 and v·g = 0."""
    g = A.T @ (b - A @ v)
    return float(max(g.max(), np.abs(v * g).max()))


def test_verified_nnls_returns_the_optimum() -> None:
    for seed in range(5):
        A, b = _nnls_problem(seed)
        v = verified_nnls(A, b)
        assert v.min() >= 0.0 and (v == 0.0).any()
        assert _kkt_gap(A, b, v) < 1e-9


def test_verified_nnls_replaces_an_nnls_answer_that_is_not_optimal(monkeypatch) -> None:
    # SciPy's NNLS can return a point that is not the optimum, with a residual norm that is
    # not the point's (scipy/scipy#25389; seen on an A123 refinement): such an answer is
    # checked against the optimality conditions and solved again
    A, b = _nnls_problem(0)
    best = verified_nnls(A, b)
    wrong = np.where(best > 0.0, 0.5 * best, 0.0)                # feasible, not optimal
    assert _kkt_gap(A, b, wrong) > 1e-3
    monkeypatch.setattr(ladder_module, "nnls", lambda *_a, **_k: (wrong, 0.0))
    v = verified_nnls(A, b)
    assert _kkt_gap(A, b, v) < 1e-9
    np.testing.assert_allclose(A @ v, A @ best, atol=1e-9)


def test_verified_nnls_keeps_the_nnls_answer_where_bvls_fails(monkeypatch) -> None:
    # LAPACK's SVD inside BVLS can fail to converge (an A123 refinement with charge records,
    # 204 × 2638): the training goes on with NNLS's answer, not a LinAlgError traceback
    A, b = _nnls_problem(1)
    best = verified_nnls(A, b)
    near = np.where(best > 0.0, 0.999 * best, 0.0)
    monkeypatch.setattr(ladder_module, "nnls", lambda *_a, **_k: (near, 0.0))

    def no_convergence(*_a, **_k):
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")

    monkeypatch.setattr(ladder_module, "lsq_linear", no_convergence)
    np.testing.assert_array_equal(verified_nnls(A, b), near)


def test_both_depletion_resistances_are_held_non_negative() -> None:
    """With the fast depletion regressor d2(k) the ladder has R_depletion_fast ≥ 0 beside
    R_depletion ≥ 0: a fit whose d2 coefficient comes out negative ends on 0."""
    cfg = load_config(hysteresis="off", temperature_scaling="off", depletion_fast_tau_s=5.0)
    base = skeleton(cfg, 2.0, np.array([0.0, 1.0]), np.array([3.3, 4.1]), None,
                    np.zeros(1), np.ones(1))
    ladder = ladder_for(base)
    assert ladder is not None and ladder.names.count("R_depletion_fast") == 1
    col = base.columns().index("d2(k)")
    row = ladder.C[ladder.names.index("R_depletion_fast")]
    assert row[col] == 1.0 and np.count_nonzero(row) == 1
    rng = np.random.default_rng(2)
    X = rng.standard_normal((400, ladder.C.shape[1]))
    theta = np.linalg.lstsq(ladder.C, np.full(ladder.C.shape[0], 0.01), rcond=None)[0]
    theta[col] = -0.02
    fitted = ladder.solve(X, X @ theta, np.ones(400))
    assert ladder.holds(fitted, 1e-12) and fitted[col] == pytest.approx(0.0, abs=1e-9)


def test_offset_bound_holds_the_local_ocv_offset_within_it() -> None:
    """With offset_bound_v the ladder also bounds |U_off|: a fit whose least-squares offset
    lies within it is unchanged, one beyond it ends on the bound."""
    cfg = load_config(hysteresis="off", temperature_scaling="off")
    base = skeleton(cfg, 2.0, np.array([0.0, 1.0]), np.array([3.3, 4.1]), None,
                    np.zeros(1), np.ones(1))
    ladder = ladder_for(base, offset_bound_v=0.05)
    plain = ladder_for(base)
    assert ladder is not None and plain is not None
    assert ladder.names[-2:] == ["U_off≥−max", "U_off≤max"]
    assert "U_off≤max" not in plain.names
    rng = np.random.default_rng(2)
    p = ladder.C.shape[1]
    X = rng.standard_normal((500, p))
    X[:, base.columns().index("1")] = 1.0
    theta = np.linalg.lstsq(plain.C, np.linspace(0.02, 0.005, plain.C.shape[0]), rcond=None)[0]
    w = np.ones(500)
    col = base.columns().index("1")
    for offset, expected in ((0.02, 0.02), (0.3, 0.05), (-0.3, -0.05)):
        theta[col] = offset
        fit = ladder.solve(X, X @ theta, w)
        assert ladder.holds(fit, 1e-12)
        assert fit[col] == pytest.approx(expected, abs=1e-9)
        assert plain.solve(X, X @ theta, w)[col] == pytest.approx(offset, abs=1e-9)
    with pytest.raises(ConfigError, match="offset_bound_mv"):
        load_config(offset_bound_mv=-1.0)
    # "auto": bounded where slow OCV tests fix the OCV, free where it is estimated
    assert load_config().offset_bound_v() == 0.0
    assert load_config(ocv_tests=["ocv.mat"]).offset_bound_v() == pytest.approx(0.05)
    assert load_config(offset_bound_mv=20).offset_bound_v() == pytest.approx(0.02)


def test_local_models_of_measured_records_are_positive_rc_ladders(tmp_path) -> None:
    """Panasonic HWFET + HPPC (no OCV test: OCV and slow polarisation are confounded, and
    free local models take negative RC elements of hundreds of mΩ there)."""
    from lmncell.identification.train import train_files
    from lmncell.runtime.model import load_model

    from tests.conftest import PAN_HPPC, PAN_HWFET

    kw = dict(capacity_ah=2.85, soc0=1.0, progress=lambda _m: None, max_local_models=3,
              oe_max_iterations=2, hysteresis="off")
    train_files([PAN_HWFET, PAN_HPPC], tmp_path / "rc.json", **kw)
    rows = local_model_table(load_model(tmp_path / "rc.json"))
    assert all(r["rc_positive"] for r in rows)
    assert all(r["r0_mohm"] > 5.0 for r in rows)          # an 18650's R0 is tens of mΩ
    train_files([PAN_HWFET, PAN_HPPC], tmp_path / "free.json", local_model_form="free", **kw)
    free = local_model_table(load_model(tmp_path / "free.json"))
    assert not all(r["rc_positive"] for r in free)        # what the constraint prevents
    text = explain_text(load_model(tmp_path / "rc.json"))
    assert "R@800s" in text and "NO" not in text


def test_ladder_is_positive_at_every_training_temperature_with_temperature_terms() -> None:
    from tests.conftest import chamber_cell_segments

    cap = 2.0
    segs = chamber_cell_segments(5000, 30.0)
    cfg = load_config(max_local_models=2, hysteresis="off", oe_max_iterations=2)
    model = train_lmn(segs, cfg, cap).model
    assert model.temperature_terms >= 1
    for t in (-5.0, 5.0, 25.0, 45.0):
        assert all(r["rc_positive"] for r in local_model_table(model, t)), t


@pytest.mark.parametrize("hysteresis_terms", ["constant", "polynomial", "arrhenius"])
def test_hysteresis_voltage_is_constrained_for_every_basis(hysteresis_terms: str) -> None:
    """H ≥ 0 is a ladder row for every basis of the hysteresis column's temperature terms: one
    row where H is one number ("constant"), one per constraint temperature otherwise; and the
    trained local models keep it."""
    from tests.conftest import chamber_cell_segments

    segs = chamber_cell_segments(5000, 30.0)
    cfg = load_config(max_local_models=2, hysteresis=30.0, oe_max_iterations=2,
                      hysteresis_terms=hysteresis_terms)
    model = train_lmn(segs, cfg, 2.0).model
    assert model.temperature_terms >= 1 and model.hysteresis_terms == hysteresis_terms
    ladder = ladder_for(model, -5.0, 45.0)
    h_rows = [k for k, name in enumerate(ladder.names) if name.startswith("H")]
    assert len(h_rows) == (1 if hysteresis_terms == "constant" else
                           len(constraint_temperatures_c(-5.0, 45.0, model.temperature_terms,
                                                         25.0)))
    h_col = model.columns().index("h(k)")
    assert all(ladder.C[k, h_col] == 1.0 for k in h_rows)
    for t in (-5.0, 5.0, 25.0, 45.0):
        assert all(r["rc_positive"] for r in local_model_table(model, t)), t


def test_ladder_settings() -> None:
    assert is_ladder([[0.01, 5.0], [5.0, 30.0]], 1.0, 0)
    assert not is_ladder([[0.01, 5.0], [5.0, 30.0]], 1.0, 2)      # ARX: free
    assert not is_ladder([[10.0, 100.0]], 1.0, 0)                 # +g at 10 s, −g at 100 s
    with pytest.raises(ConfigError, match="local_model_form"):
        load_config(local_model_form="rc_ladder", output_lags=3)
    with pytest.raises(ConfigError, match="local_model_form"):
        load_config(local_model_form="positive")
    assert load_config(output_lags=3, current_terms=3).local_model_form == "auto"


def test_hysteresis_of_a_synthetic_cell_is_recovered() -> None:
    """A cell with a one-state hysteresis (γ = 30, H = 15 mV: the charge branch 30 mV above
    discharge, as the A123's slow OCV tests show) cycled between charge and discharge: 'auto'
    keeps the hysteresis, chooses γ = 30 and every local model's H is close to 15 mV."""
    rng = np.random.default_rng(9)
    cap, ts, n, gamma, hyst = 2.0, 1.0, 24000, 30.0, 0.015
    blocks = []
    for k in range(n // 2000):                    # alternate net charge and net discharge
        sign = 1.0 if k % 2 else -1.0
        blocks.append(sign * 0.6 + rng.choice([-1.5, -0.5, 0.0, 0.5, 1.5], size=2000))
    i = np.concatenate(blocks)
    i = np.repeat(i[::20], 20)
    soc = 0.5 + np.cumsum(i) * ts / 3600.0 / cap
    h = np.zeros(n)
    state = 0.0
    for k in range(n):
        e = np.exp(-gamma * abs(i[k]) * ts / 3600.0 / cap)
        state = e * state + (1.0 - e) * np.sign(i[k])
        h[k] = state
    u = (3.3 + 0.8 * soc + 0.02 * i + 0.01 * lowpass(i, 30.0, ts) + hyst * h
         + 2e-4 * rng.standard_normal(n))
    seg = Segment("hyst", np.arange(1, n + 1) * ts, i, u, None, 0.5, soc, np.ones(n))
    cfg = load_config(max_local_models=2, temperature_scaling="off", oe_max_iterations=2)
    model = train_lmn([seg], cfg, cap).model
    assert model.hysteresis_gamma == 30.0
    for row in local_model_table(model):
        assert row["hysteresis_mv"] == pytest.approx(1e3 * hyst, abs=1.5)
        assert row["rc_positive"]
