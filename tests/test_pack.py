"""The vectorised runtime and packs (issue 20): many cells at once equal the per-cell step,
parallel cells share the current by their impedance."""

from __future__ import annotations

import numpy as np
import pytest
from lmncell.data.records import DataError
from lmncell.runtime.model import load_model
from lmncell.runtime.step import CellStepper, CellThermal
from lmncell.runtime.vector import VectorCells
from lmncell.scenarios.pack import Pack, PackSpec, parse_pack, parse_spread


@pytest.mark.parametrize("temperature_is_cell", [True, False])
@pytest.mark.parametrize("fixture", ["quick_model", "a123_model"])
def test_vectorised_step_equals_the_per_cell_step(request, fixture, temperature_is_cell) -> None:
    model = load_model(request.getfixturevalue(fixture))
    soc0 = np.array([1.0, 0.7, 0.3, 0.95])
    cap = model.capacity_ah * np.array([1.0, 0.9, 1.05, 1.1])
    cells = VectorCells(model, soc0, capacity_ah=cap, temperature_c=20.0,
                        temperature_is_cell=temperature_is_cell)
    offset = model.thermal.offset_k if model.thermal and not temperature_is_cell else 0.0
    single = [CellStepper(model, s, c, 20.0 + offset) for s, c in zip(soc0, cap, strict=True)]
    thermal = [CellThermal(model, temperature_is_cell) for _ in single]
    rng = np.random.default_rng(0)
    for k in range(2000):
        i, t = rng.uniform(-6, 3, 4), 20.0 + 5 * np.sin(k / 300)
        u = cells.step(i, t)
        for j, (c, th) in enumerate(zip(single, thermal, strict=True)):
            assert c.step(i[j], th.cell_temperature(t)) == pytest.approx(u[j], abs=1e-12)
            th.update(t, i[j], c)
            assert c.soc == pytest.approx(cells.soc[j], abs=1e-12)


def test_parallel_cells_share_the_current_by_impedance(quick_model) -> None:
    model = load_model(quick_model)
    pack = Pack(model, PackSpec(4, 3, capacity_spread=0.05, resistance_spread=0.2, seed=3),
                soc0=0.9, ambient_c=25.0)
    for _ in range(300):
        pack.step_current(-9.0)
    i = pack.current_a.reshape(4, 3)
    u = pack.cells.voltage_v.reshape(4, 3)
    np.testing.assert_allclose(i.sum(axis=1), -9.0, rtol=0, atol=1e-12)
    assert np.ptp(i, axis=1).max() > 0.05                   # the spread shows in the currents
    assert np.ptp(u, axis=1).max() < 2e-3                   # … and the voltages agree
    r = pack.cells.r.reshape(4, 3)
    g = int(np.argmax(np.ptp(r, axis=1)))
    assert i[g, np.argmax(r[g])] > i[g, np.argmin(r[g])]    # the stiffer cell discharges more


def test_identical_cells_split_evenly_and_equal_one_cell(quick_model) -> None:
    model = load_model(quick_model)
    pack = Pack(model, PackSpec(2, 3), soc0=0.8, ambient_c=25.0)
    one = VectorCells(model, 0.8, n=1, temperature_c=25.0, temperature_is_cell=False)
    for _ in range(200):
        u = pack.step_current(-6.0)
        np.testing.assert_allclose(u, one.step(np.array([-2.0]), 25.0)[0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("text", ["96x3", "0s3p", "s3p", ""])
def test_bad_pack_text(text) -> None:
    with pytest.raises(DataError, match="--pack"):
        parse_pack(text)


@pytest.mark.parametrize("text", ["mass=0.1", "capacity=big", "resistance=0.9"])
def test_bad_spread_text(text) -> None:
    with pytest.raises(DataError, match="--spread"):
        parse_spread(text)
