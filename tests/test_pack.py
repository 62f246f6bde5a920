"""The vectorised runtime and packs (issue 20): many cells at once equal the per-cell step,
parallel cells share the current by their impedance."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from lmncell.data.records import DataError
from lmncell.runtime.cosim import CellCosim, Parameters, held_delayed_currents
from lmncell.runtime.model import load_model
from lmncell.runtime.step import CellStepper, CellThermal
from lmncell.runtime.vector import VectorCells
from lmncell.scenarios.pack import Pack, PackSpec, drive_pack, parse_pack, parse_spread


@pytest.mark.parametrize("temperature_is_cell", [True, False])
@pytest.mark.parametrize("fixture, core", [("quick_model", False), ("a123_model", False),
                                           ("quick_model", True)])
def test_vectorised_step_equals_the_per_cell_step(request, fixture, core,
                                                  temperature_is_cell) -> None:
    model = load_model(request.getfixturevalue(fixture))
    if core:    # a core rise k·LP_τ(i²) on the temperature that g(T) and Eτ take
        model = dataclasses.replace(model, arrhenius_k=3000.0, core_rise_k_per_a2=0.05,
                                    core_rise_tau_s=60.0)
    soc0 = np.array([1.0, 0.7, 0.3, 0.95])
    cap = model.capacity_ah * np.array([1.0, 0.9, 1.05, 1.1])
    cells = VectorCells(model, soc0, capacity_ah=cap, temperature_c=20.0,
                        temperature_is_cell=temperature_is_cell)
    offset = model.thermal.offset_k if model.thermal and not temperature_is_cell else 0.0
    single = [CellStepper(model, s, c, 20.0 + offset) for s, c in zip(soc0, cap, strict=True)]
    thermal = [CellThermal(model, temperature_is_cell) for _ in single]
    rng = np.random.default_rng(0)
    currents = rng.uniform(-6, 3, (2000, 4))
    taken = np.array([held_delayed_currents(c.tolist(), model.sample_time_s,
                                            model.current_delay_s) for c in currents.T]).T
    assert model.current_delay_s > 0 or fixture == "a123_model"    # the delay is exercised
    for k, (i, i_taken) in enumerate(zip(currents, taken, strict=True)):
        t = 20.0 + 5 * np.sin(k / 300)
        u = cells.step(i, t)
        for j, (c, th) in enumerate(zip(single, thermal, strict=True)):
            assert c.step(i_taken[j], th.cell_temperature(t)) == pytest.approx(u[j], abs=1e-12)
            th.update(t, i_taken[j], c)
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


@pytest.mark.parametrize("temperature_is_cell", [True, False])
def test_a_vectorised_cell_is_the_fmus_engine(quick_model, temperature_is_cell) -> None:
    """Each cell's voltage and out_of_range after a step are the FMU engine's for the same
    inputs (its current delay included): a current beyond the trained one, a hot ambient, and
    the SoC run out."""
    model = load_model(quick_model)
    cells = VectorCells(model, 0.9, n=1, temperature_c=25.0,
                        temperature_is_cell=temperature_is_cell)
    fmu = CellCosim(model, Parameters(0.9, model.capacity_ah,
                                      temperature_is_cell=temperature_is_cell))
    fmu.reset(25.0)
    flags = []
    for k in range(2400):
        i = -40.0 if 100 <= k < 110 else -3.0
        t = 45.0 if 500 <= k < 900 else 25.0
        cells.step(np.array([i]), t)
        fmu.advance(model.sample_time_s, i, t)
        assert cells.out_of_range[0] == fmu.out_of_range, k
        assert cells.voltage_v[0] == pytest.approx(fmu.voltage_v, abs=1e-9), k
        flags.append(fmu.out_of_range)
    assert 0 < sum(flags) < len(flags)


def test_a_vectorised_cell_from_a_start_temperature_is_the_fmus_engine(quick_model,
                                                                      a123_model) -> None:
    """cell_temperature_start_c: a cell that starts at 40 °C in a 10 °C ambient steps as the
    FMU engine with use_cell_temperature_start, and cools; refused as the FMU refuses it."""
    model = load_model(quick_model)
    cells = VectorCells(model, 0.9, n=2, temperature_c=10.0, temperature_is_cell=False,
                        cell_temperature_start_c=40.0)
    fmu = CellCosim(model, Parameters(0.9, model.capacity_ah, cell_temperature_start_c=40.0))
    fmu.reset(10.0)
    assert cells.voltage_v[0] == pytest.approx(fmu.voltage_v, abs=1e-12)
    for k in range(1500):
        i = -8.0 if k % 200 < 120 else 0.0
        cells.step(np.array([i, i]), 10.0)
        fmu.advance(model.sample_time_s, i, 10.0)
        assert cells.voltage_v[1] == pytest.approx(fmu.voltage_v, abs=1e-9), k
        assert cells.cell_temperature_c[1] == pytest.approx(fmu.cell_temperature_c, abs=1e-9), k
    assert 10.0 < cells.cell_temperature_c[0] < 39.0
    with pytest.raises(ValueError, match="'cell_temperature_start' = 150: expected a cell "):
        VectorCells(model, 0.9, n=1, temperature_is_cell=False, cell_temperature_start_c=150.0)
    with pytest.raises(ValueError, match="this model has no thermal model"):
        VectorCells(load_model(a123_model), 0.9, n=1, temperature_is_cell=False,
                    cell_temperature_start_c=30.0)


def test_a_cell_that_is_not_passive_does_not_take_the_groups_current(quick_model) -> None:
    """Where the model's dU/dI of a cell falls to 0 or below (a model far beyond its data),
    an equal-voltage share would send kiloamperes round the group: the share then takes a
    floor of a tenth of the start's resistance, and the step counts as out of range."""
    model = load_model(quick_model)
    pack = Pack(model, PackSpec(1, 3), soc0=0.8, ambient_c=25.0)
    assert pack.resistance_floor_ohm > 1e-4
    peek = pack.cells.peek

    def not_passive(current_a, temperature_c):     # cell 0: dU/dI = −3 mΩ
        u = peek(current_a, temperature_c)
        u[0] = 3.6 - 0.003 * current_a[0]
        return u

    pack.cells.peek = not_passive
    i = pack.share(-6.0)
    assert pack.floored and i.sum() == pytest.approx(-6.0, abs=1e-12)
    assert np.abs(i).max() < 100.0 * 6.0          # bounded (the 1 µΩ of before: ~10⁴ A)
    pack.cells.peek = peek
    pack.share(-6.0)
    assert not pack.floored


def test_a_pack_counts_its_steps_outside_the_trained_region(quick_model) -> None:
    model = load_model(quick_model)
    power = np.full(600, 100.0)                      # W: 12 cells at about 2 A each
    at = {amb: drive_pack(model, PackSpec(4, 3, 0.02, 0.05, 1), power, amb, 0.9, 2.5)
          for amb in (25.0, 60.0)}
    assert at[25.0]["out_of_range_steps"] == 0
    assert at[60.0]["out_of_range_steps"] == at[60.0]["steps"] == 600


@pytest.mark.parametrize("text", ["96x3", "0s3p", "s3p", ""])
def test_bad_pack_text(text) -> None:
    with pytest.raises(DataError, match="--pack"):
        parse_pack(text)


@pytest.mark.parametrize("text", ["mass=0.1", "capacity=big", "resistance=0.9",
                                  "capacity=0.02,capacity=0.03"])
def test_bad_spread_text(text) -> None:
    with pytest.raises(DataError, match="--spread"):
        parse_spread(text)


@pytest.mark.parametrize("pack, cells, vehicle_pack, source", [
    ("100000s100000p", None, None, "--pack: 10000000000 cells"),
    (None, 2_000_000, None, "--cells: 2000000 cells"),
    (None, None, (10000, 1000), "the [pack] of the vehicle "),
])
def test_a_pack_too_large_to_simulate_is_refused(tmp_path, pack, cells, vehicle_pack,
                                                 source) -> None:
    """100000s100000p was accepted and ran a worker out of memory (about 0.7 kB a cell)."""
    from importlib import resources

    from lmncell.scenarios.sweep import scenarios

    vehicles = [None]
    if vehicle_pack:
        text = resources.files("lmncell.scenarios").joinpath("vehicles/compact_ev.toml")
        path = tmp_path / "v.toml"
        path.write_text(text.read_text().replace("n_series = 100", f"n_series = {vehicle_pack[0]}")
                        .replace("n_parallel = 40", f"n_parallel = {vehicle_pack[1]}"))
        vehicles = [str(path)]
    with pytest.raises(DataError, match=re.escape(f"sweep: {source}") + r".*more than 1000000"):
        scenarios(["wltc"], [25.0], [0.9], vehicles, 1, pack,
                  "capacity=0.01" if vehicle_pack else None, 0, cells)
    assert scenarios(["wltc"], [25.0], [0.9], [None], 1, "1000s1000p")[0].pack.n_series == 1000
