"""The 2RC baseline: fitted within physical bounds, its knots that no sample reaches tied to
their neighbours, so that it stays finite on records that go further than its training data."""

from __future__ import annotations

import numpy as np
from lmncell.data.dataset import Segment
from lmncell.identification.baselines import (
    N_R,
    SOC_KNOTS,
    Ecm2rc,
    fit_ecm2rc,
    parameter_bounds,
    start_point,
)

CAPACITY_AH = 2.0
TS = 1.0


def _true_ecm() -> Ecm2rc:
    ocv_soc = np.linspace(0.0, 1.0, 11)
    return Ecm2rc(ocv_soc, 3.3 + 0.8 * ocv_soc, np.full(N_R, 0.030), np.full(N_R, 0.015),
                  np.full(N_R, 0.020), 20.0, 300.0, 0.3, 0.0, None, CAPACITY_AH, TS)


def _upper_half_segment(ecm: Ecm2rc) -> Segment:
    """A pulsed discharge from SoC 1 to 0.55 at 20…30 °C: no sample below SoC 0.5, so the
    resistance knots at SoC 0 and 0.2 are not determined by the data."""
    rng = np.random.default_rng(3)
    n = 2400
    current = -np.repeat(rng.uniform(0.0, 2.5, n // 30), 30)
    soc = 1.0 + np.cumsum(current) * TS / 3600.0 / CAPACITY_AH
    temperature = np.linspace(20.0, 30.0, n)
    voltage = ecm.simulate(current, temperature, soc, 0.0)
    return Segment("upper half", np.arange(1, n + 1) * TS, current, voltage, temperature, 1.0,
                   soc, np.ones(n))


def test_knots_without_data_follow_their_neighbours_and_stay_finite() -> None:
    truth = _true_ecm()
    seg = _upper_half_segment(truth)
    assert seg.soc_ref.min() > 0.5
    ecm, _ = fit_ecm2rc([seg], [seg.soc_ref], truth.ocv_soc, truth.ocv_v, CAPACITY_AH, TS,
                        None, [0.0])
    # where the data are, the fit finds the cell's resistances
    assert abs(ecm.r0[-1] - 0.030) < 0.003
    # below the data, R0, R1 and R2 take their neighbour's value (not 0 or exp(700) Ω)
    for r in (ecm.r0, ecm.r1, ecm.r2):
        assert SOC_KNOTS[1] < 0.5 and np.allclose(r[:2], r[2], rtol=0.05)
    # a record that runs on to empty in the cold is simulated with finite voltages
    soc = np.linspace(1.0, 0.0, 500)
    u = ecm.simulate(np.full(500, -2.0), np.full(500, -30.0), soc, 0.0)
    assert np.isfinite(u).all()


def test_bounds_hold_the_start_point_and_keep_beta_physical() -> None:
    for with_h in (False, True):
        lo, hi = parameter_bounds(11, with_h)
        x0 = start_point(np.full(11, 3.7), with_h)
        assert lo.size == hi.size == x0.size
        assert np.all(lo < x0) and np.all(x0 < hi)
        beta = 11 + 3 * N_R + 2
        assert lo[beta] >= -3.0 and hi[beta] <= 3.0
