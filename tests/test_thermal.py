"""The lumped thermal model: identification, the runtime driven by the ambient temperature, and
both FMUs against the pipeline with the ambient and with the measured cell temperature."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from lmncell.config import load_config
from lmncell.data.dataset import Segment
from lmncell.data.records import DataError
from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline
from lmncell.identification.thermal import fit_thermal, predicted_temperature
from lmncell.identification.tree import skeleton
from lmncell.runtime.model import load_model
from lmncell.runtime.step import simulate, simulate_ambient
from lmncell.runtime.thermal import ThermalModel, next_temperature

from tests.conftest import PAN_HWFET, PAN_US06

TRUE = ThermalModel(resistance_k_per_w=4.0, time_constant_s=900.0, offset_k=0.6)


def _ocv_model():
    return skeleton(load_config(), 2.85, np.array([0.0, 1.0]), np.array([3.0, 4.2]), None,
                    np.zeros(1), np.ones(1))


def _synthetic_segment(rng, n: int, ambient: float, start: float) -> Segment:
    """Charge-neutral current blocks of 2…12 A with rests (SoC stays near 0.6), R0 = 30 mΩ, the
    cell temperature from TRUE plus a thermocouple's 0.1 K resolution and 0.05 K noise."""
    levels = rng.uniform(2, 12, n // 40) * np.where(np.arange(n // 40) % 2, 1.0, -1.0)
    levels[rng.random(levels.size) < 0.3] = 0.0                # rests: the cell cools
    blocks = np.repeat(levels, 20)
    current = np.concatenate([blocks, np.zeros(n - blocks.size)])
    soc = 0.6 + np.cumsum(current) / (3600 * 2.85)
    voltage = 3.0 + 1.2 * soc + 0.03 * current
    heat = current * (voltage - (3.0 + 1.2 * soc))
    temp = predicted_temperature(TRUE, heat, ambient, start, 1.0)
    temp = np.round(temp + rng.normal(0, 0.05, n), 1)
    return Segment("synthetic", np.arange(n, dtype=float), current, voltage, temp, 1.0, soc,
                   np.ones(n), ambient_c=ambient)


def test_identification_recovers_known_parameters() -> None:
    rng = np.random.default_rng(7)
    segs = [_synthetic_segment(rng, 6000, 25.0, 25.6), _synthetic_segment(rng, 5000, 10.0, 22.0)]
    fitted, info = fit_thermal(_ocv_model(), segs)
    assert fitted is not None and info["used"] and info["rmse_k"] < 0.08
    assert fitted.resistance_k_per_w == pytest.approx(TRUE.resistance_k_per_w, rel=0.03)
    assert fitted.time_constant_s == pytest.approx(TRUE.time_constant_s, rel=0.05)
    assert fitted.offset_k == pytest.approx(TRUE.offset_k, abs=0.05)
    assert info["at_bound"] == []


def test_identification_follows_a_chamber_that_is_still_settling() -> None:
    """A record whose chamber warms from 22 to 25 °C over its first half hour (the Panasonic
    25 °C Cycle 1): fitted with the logged ambient per step the parameters come back; taken
    at its set point throughout, the chamber's warm-up is read as the cell's own heating and
    they do not."""
    rng = np.random.default_rng(11)
    n = 6000
    ambient = 25.0 - 3.0 * np.exp(-np.arange(n) / 600.0)
    seg = _synthetic_segment(rng, n, 25.0, 22.0)
    heat = seg.current_a * (seg.voltage_v - (3.0 + 1.2 * seg.soc_ref))
    temp = predicted_temperature(TRUE, heat, ambient, 22.0, 1.0)
    seg = dataclasses.replace(seg, temperature_c=np.round(temp + rng.normal(0, 0.05, n), 1),
                              ambient_trace_c=ambient)
    steady = _synthetic_segment(rng, 5000, 10.0, 10.6)
    fitted, info = fit_thermal(_ocv_model(), [seg, steady])
    assert fitted is not None and info["rmse_k"] < 0.08
    assert fitted.resistance_k_per_w == pytest.approx(TRUE.resistance_k_per_w, rel=0.03)
    assert fitted.time_constant_s == pytest.approx(TRUE.time_constant_s, rel=0.05)
    blind, blind_info = fit_thermal(_ocv_model(), [dataclasses.replace(seg, ambient_trace_c=None),
                                                   steady])
    assert blind is not None and blind_info["rmse_k"] > 2 * info["rmse_k"]
    assert abs(blind.time_constant_s / TRUE.time_constant_s - 1) > 0.1


def test_a_varying_ambient_steps_as_the_runtime_does() -> None:
    # the fit's prediction with an ambient per step is the runtime's recursion
    rng = np.random.default_rng(5)
    heat, ambient = rng.uniform(0, 2, 300), 20.0 + rng.uniform(0, 5, 300)
    predicted = predicted_temperature(TRUE, heat, ambient, 21.0, 0.1)
    t, stepped = 21.0, [21.0]
    for q, ta in zip(heat[:-1], ambient[:-1], strict=True):
        t = next_temperature(TRUE, t, ta, q, 0.1)
        stepped.append(t)
    assert predicted == pytest.approx(stepped, abs=1e-10)


def test_parameters_on_a_bound_are_named() -> None:
    from lmncell.identification.thermal import parameters_at_bound

    lower, upper = np.array([-3.0, 2.3, -5.0]), np.array([5.3, 13.8, 5.0])
    assert parameters_at_bound(np.array([1.0, 6.0, 0.2]), lower, upper) == []
    assert parameters_at_bound(np.array([5.3, 6.0, -5.0]), lower, upper) == [
        "resistance_k_per_w", "offset_k"]


def test_an_undetermined_thermal_model_names_what_would_determine_it() -> None:
    # without an OCV test the heat i·(u − OCV) takes the OCV estimated from the records: one
    # Panasonic US06 record so gave R 2.3 K/W and offset +5 K (at its bound), 8.9 K/W and
    # -0.7 K with the C/20 test
    from lmncell.identification.train import _thermal_text

    info = {"rmse_k": 0.8, "segments": ["us06"], "at_bound": ["offset_k"]}
    estimated = _thermal_text(TRUE, info, ocv_measured=False)
    assert "not determined by these records: offset_k" in estimated
    assert "--ocv-tests" in estimated and "warm up and cool down" not in estimated
    assert "warm up and cool down" in _thermal_text(TRUE, info, ocv_measured=True)
    assert "bound" not in _thermal_text(TRUE, {**info, "at_bound": []}, ocv_measured=False)


def test_no_thermal_model_without_a_measured_rise() -> None:
    rng = np.random.default_rng(1)
    seg = _synthetic_segment(rng, 3000, 25.0, 25.6)
    flat = dataclasses.replace(seg, temperature_c=np.full(len(seg), 25.0))
    fitted, info = fit_thermal(_ocv_model(), [flat, dataclasses.replace(seg, ambient_c=None)])
    assert fitted is None and "rises" in info["reason"]
    assert info["reason"].endswith("; synthetic log a cell temperature and no chamber "
                                   "temperature beside it (give it in the file name, such "
                                   "as …_25degC…; or, in your own CSV, map the chamber's "
                                   "column as ambient=COL)")
    assert "beside it" not in fit_thermal(_ocv_model(), [flat])[1]["reason"]


def test_step_recursion_is_the_exact_discretisation() -> None:
    """Constant heat: T approaches ambient + offset + R·q with the time constant τ."""
    t = 25.0 + TRUE.offset_k
    for _ in range(900):
        t = next_temperature(TRUE, t, 25.0, 2.0, 1.0)
    steady = 25.0 + TRUE.offset_k + TRUE.resistance_k_per_w * 2.0
    assert t == pytest.approx(steady - (steady - 25.6) * np.exp(-1.0), rel=1e-12)


def test_trained_model_has_a_thermal_model_and_ambient_runs_use_it(quick_model) -> None:
    model = load_model(quick_model)
    assert model.thermal is not None
    assert model.extra["training"]["thermal"]["rmse_k"] < 1.0
    current = np.full(1200, -5.7)                       # 2C discharge, 20 minutes
    sim, cell = simulate_ambient(model, current, 25.0, 1.0)
    assert cell[0] == pytest.approx(25.0 + model.thermal.offset_k)
    assert np.all(np.diff(cell) > 0) and cell[-1] > cell[0] + 2.0       # the cell warms up
    same = simulate(model, current, cell, 1.0)           # the same temperatures given as cell's
    np.testing.assert_allclose(sim.voltage_v, same.voltage_v, rtol=0, atol=1e-12)
    warm = dataclasses.replace(model, arrhenius_k=4000.0)  # resistance falls as the cell warms
    cold = dataclasses.replace(warm, thermal=None)
    sim_cold, cell_cold = simulate_ambient(cold, current, 25.0, 1.0)
    np.testing.assert_array_equal(cell_cold, 25.0)
    sim_warm, _ = simulate_ambient(warm, current, 25.0, 1.0)
    assert np.max(sim_warm.voltage_v - sim_cold.voltage_v) > 2e-3   # heating lifts the voltage


@pytest.mark.parametrize("ambient", [True, False])
@pytest.mark.parametrize("flavour", ["pythonfmu", "native"])
def test_fmu_reproduces_the_pipeline(quick_model, quick_fmu, native_fmu, flavour,
                                     ambient) -> None:
    """ambient: the chamber temperature as `temperature` (thermal model on); else the measured
    cell temperature with temperature_is_cell = true. Voltage within 1e-9 V."""
    fmu = quick_fmu if flavour == "pythonfmu" else native_fmu
    res = compare_fmu_with_pipeline(quick_model, fmu, PAN_US06, max_steps=2500, ambient=ambient)
    assert res["max_dv_v"] <= 1e-9 and res["max_dsoc"] <= 1e-12
    assert res["max_dtemperature_k"] <= 1e-9
    if ambient:
        assert np.ptp(res["fmu_cell_temperature_c"]) > 1.0   # it did heat up


@pytest.mark.parametrize("flavour", ["pythonfmu", "native"])
def test_a_cell_that_starts_warmer_than_its_ambient(quick_model, quick_fmu, native_fmu,
                                                   flavour) -> None:
    """use_cell_temperature_start: the cell starts at cell_temperature_start (40 °C in the US06
    record's 25 °C chamber) and cools towards its ambient as it works; both FMUs equal the
    pipeline (simulate_ambient with that start) within 1e-9 V and K, and the start shows in the
    voltage against a cell that starts rested."""
    fmu = quick_fmu if flavour == "pythonfmu" else native_fmu
    warm = compare_fmu_with_pipeline(quick_model, fmu, PAN_US06, max_steps=2500, ambient=True,
                                     cell_temperature_start_c=40.0)
    rested = compare_fmu_with_pipeline(quick_model, fmu, PAN_US06, max_steps=2500, ambient=True)
    assert warm["max_dv_v"] <= 1e-9 and warm["max_dtemperature_k"] <= 1e-9
    cell = warm["fmu_cell_temperature_c"]
    assert cell[0] < 40.0 and cell[0] > cell[-1] > rested["fmu_cell_temperature_c"][-1]
    assert np.max(np.abs(warm["fmu_voltage_v"] - rested["fmu_voltage_v"])) > 1e-3


def test_a_cell_start_temperature_needs_the_thermal_model(a123_model, tmp_path) -> None:
    """A model without a thermal model takes the temperature input as the cell's from the first
    step on: a start temperature is refused, by the runtime, the pipeline and the native FMU
    alike, with the same words."""
    import json
    import subprocess
    import sys

    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.runtime.cosim import CellCosim, InputError, Parameters

    from tests.conftest import ROOT, c_compiler_or_skip

    model = load_model(a123_model)
    assert model.thermal is None
    words = ("parameter 'use_cell_temperature_start' = true: this model has no thermal model, "
             "so the temperature input is the cell temperature, from the first step on")
    with pytest.raises(InputError, match=words.replace("(", r"\(")):
        CellCosim(model, Parameters(1.0, 2.2, cell_temperature_start_c=30.0))
    with pytest.raises(ValueError, match="this model has no thermal model"):
        simulate_ambient(model, np.zeros(3), 25.0, 1.0, cell_temperature_start_c=30.0)
    c_compiler_or_skip()
    fmu = build_native_fmu(a123_model, tmp_path / "a123.fmu")
    proc = subprocess.run([sys.executable, "-m", "tests.conformance_sequences", str(fmu),
                           "cell_start_parameters"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["statuses"][:3] == [3, 3, 3]     # fmi2Error whatever the start temperature
    assert sum(words in m for m in res["messages"]) == 3


def test_ambient_evaluation_of_a_held_out_record(quick_model) -> None:
    from lmncell.evaluation.evaluate import evaluate_model

    model = load_model(quick_model)
    _, cell_rows = evaluate_model(model, [PAN_US06])
    _, amb_rows = evaluate_model(model, [PAN_US06], ambient=True)
    assert amb_rows[0]["temperature_input"] == "ambient"
    assert amb_rows[0]["cell_temperature_rmse_k"] < 2.5
    assert cell_rows[0]["lmn"]["rmse_mv"] > 0 and amb_rows[0]["lmn"]["rmse_mv"] > 0
    assert PAN_HWFET.exists()


def test_a_csv_of_ones_own_with_an_ambient_column_gets_the_thermal_model(quick_model,
                                                                        tmp_path) -> None:
    """A user's own CSV that maps the chamber's column as `ambient` beside the cell's
    `temperature` gets the thermal model that the same record in its known format gets; without
    that column there is no ambient, and no thermal model."""
    from lmncell.data.dataset import record_to_segments
    from lmncell.data.readers import read_record

    rec = read_record(PAN_HWFET).slice(0, 15000)     # 25 minutes without a gap in time
    path = tmp_path / "own.csv"
    columns = (rec.time_s, rec.current_a, rec.voltage_v, rec.temperature_c, rec.ambient_c)
    path.write_text("t [s],I [A],U [V],T cell [degC],T chamber [degC]\n" + "".join(
        ",".join(repr(float(v)) for v in row) + "\n" for row in zip(*columns, strict=True)))
    mapping = {"time": "t [s]", "current": "I [A]", "voltage": "U [V]",
               "temperature": "T cell [degC]", "ambient": "T chamber [degC]"}
    model = load_model(quick_model)

    def thermal(record):
        return fit_thermal(model, record_to_segments(record, 1.0, 1.0, 2.85))[0]

    known, own = thermal(rec), thermal(read_record(path, columns=mapping))
    assert known is not None and own is not None     # (the SoC reference of the .mat file
    for name in ("resistance_k_per_w", "time_constant_s", "offset_k"):  # is its Ah counter's)
        assert getattr(own, name) == pytest.approx(getattr(known, name), rel=1e-3), name
    del mapping["ambient"]
    assert thermal(read_record(path, columns=mapping)) is None
    # nor is there an ambient to drive the model by: refused, not the cell's heated twice
    from lmncell.evaluation.evaluate import evaluate_model

    with pytest.raises(DataError, match=r"own.csv: driving the model by the ambient "
                                        r"temperature needs the chamber's .* map it as "
                                        r"ambient=COL"):
        evaluate_model(model, [path], soc0=1.0, read_options={"columns": mapping},
                       ambient=True)
    assert evaluate_model(model, [path], soc0=1.0, read_options={"columns": mapping})[1]
