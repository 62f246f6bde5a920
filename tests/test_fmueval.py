"""`lmncell evaluate CELL.fmu`: an FMU driven by fmpy through measured records, scored like the
model file it was built from."""

from __future__ import annotations

import json
import re

import lmncell
import numpy as np
import pytest
from lmncell.cli import main
from lmncell.data.dataset import record_to_segments
from lmncell.data.readers import read_record
from lmncell.evaluation.evaluate import evaluate_model, simulate_segment
from lmncell.evaluation.fmueval import communication_points, evaluate_fmu
from lmncell.runtime.cosim import held_delayed_currents
from lmncell.runtime.model import load_model

from tests.conftest import PAN_US06


def quiet(_message: str) -> None:
    """A progress callback that prints nothing."""


@pytest.mark.parametrize("ambient", [False, True])
@pytest.mark.parametrize("which", ["quick_fmu", "native_fmu"])
def test_fmu_through_the_samples_scores_as_its_model_file(quick_model, which, ambient,
                                                          request) -> None:
    """The 10 Hz US06 record through the FMU's own stepping (current delay, thermal model with
    ambient) gives the pipeline's voltages and figures."""
    fmu = request.getfixturevalue(which)
    model = load_model(quick_model)
    assert model.current_delay_s > 0 and (not ambient or model.thermal is not None)
    traces, rows = evaluate_fmu(fmu, [PAN_US06], 1.0, ambient=ambient, progress=quiet)
    ref_traces, ref_rows = evaluate_model(model, [PAN_US06], 1.0, ambient=ambient)
    assert len(traces) == len(ref_traces) == 1
    dv = np.abs(traces[0].voltage["fmu"] - ref_traces[0].voltage["lmn"])
    assert dv.max() < 1e-9
    assert np.abs(traces[0].soc_model - ref_traces[0].soc_model).max() < 1e-12
    for key in ("rmse_mv", "window_rmse_mv", "low_soc_rmse_mv", "high_soc_rmse_mv"):
        assert rows[0]["fmu"][key] == pytest.approx(ref_rows[0]["lmn"][key], abs=1e-6)
    assert rows[0]["temperature_input"] == ("ambient" if ambient else "cell")
    assert rows[0]["steps"] == len(ref_traces[0].segment)


def test_an_fmu_row_names_what_left_the_trained_region(fmu, capsys) -> None:
    """The US06 record goes beyond the quick model's records (its current, its 32.9 °C): the
    row and the printed line quote the FMU's first warning, not only a count of steps."""
    _, rows = evaluate_fmu(fmu, [PAN_US06], 1.0, progress=quiet)
    first = rows[0]["out_of_range_first"]
    assert rows[0]["out_of_range_steps"] > 0 and "outside the trained" in first
    assert "lmncell-evaluate" not in first and "status" not in first
    assert main(["evaluate", str(fmu), str(PAN_US06), "--soc0", "1"]) == 0
    assert f"; its first warning: {first}" in capsys.readouterr().out


def test_fmu_at_model_steps_gets_the_held_delayed_current(quick_model, native_fmu) -> None:
    """Stepped at Ts with the mean current over each step, the FMU computes what a delayed
    model takes from such steps, and that differs from what the current did within them."""
    model = load_model(quick_model)
    seg = record_to_segments(read_record(PAN_US06), 1.0, 1.0, 2.85)[0]
    held = seg.current_a.copy()
    held[:] = held_delayed_currents(seg.current_a.tolist(), 1.0, model.current_delay_s)
    seg.current_a = held
    expected = simulate_segment(model, seg).voltage_v
    traces, rows = evaluate_fmu(native_fmu, [PAN_US06], 1.0, at_model_steps=True,
                                progress=quiet)
    assert np.abs(traces[0].voltage["fmu"] - expected).max() < 1e-9
    through, _ = evaluate_fmu(native_fmu, [PAN_US06], 1.0, progress=quiet)
    assert np.abs(through[0].voltage["fmu"] - expected).max() > 1e-3
    assert rows[0]["driven"] == "model_steps"
    assert rows[0]["out_of_range_steps"] > 0           # its first warning too (was None)
    assert "outside the trained" in rows[0]["out_of_range_first"]


def test_communication_points_hold_every_sample_and_every_model_step_end() -> None:
    t = np.array([0.0, 0.35, 0.7, 1.0 - 1e-12, 1.4, 2.05, 2.6])
    points = communication_points(t, 1.0, 2)
    assert points.tolist() == [0.35, 0.7, 1.0, 1.4, 2.0]


def test_cli_evaluates_an_fmu_and_its_observer_and_refuses_what_it_cannot(
        quick_fmu, quick_model, tmp_path, capsys) -> None:
    trace = tmp_path / "t.csv"
    assert main(["evaluate", str(quick_fmu), str(PAN_US06), "--json", "--trace", str(trace),
                 "--plot", str(tmp_path / "plots")]) == 0
    out = capsys.readouterr().out
    rows = json.loads(out[out.index("["):])
    assert rows[0]["fmu"]["window_rmse_mv"] < 30 and rows[0]["driven"] == "samples"
    assert trace.read_text().startswith("time_s,current_a,voltage_measured_v,voltage_model_v")
    assert len(list((tmp_path / "plots").glob("fmu_*.png"))) == 1
    fake = tmp_path / "fake.fmu"
    fake.write_text("not a zip archive")
    assert main(["evaluate", str(fake), str(PAN_US06)]) == 2
    assert "fake.fmu: not a readable FMU" in capsys.readouterr().err
    assert main(["evaluate", str(quick_fmu), str(PAN_US06), "--observer", "ekf",
                 "--soc0-est", "0.5", "--plot", str(tmp_path / "soc")]) == 0
    assert re.search(r"ekf +SoC RMSE +\d+\.\d\d %", capsys.readouterr().out)
    assert len(list((tmp_path / "soc").glob("fmu_soc_ekf_*.png"))) == 1
    assert main(["evaluate", str(quick_fmu), str(PAN_US06), "--observer", "ekf",
                 "--soc0-est", "0.5", "--at-model-steps"]) == 2
    assert "--at-model-steps with --observer" in capsys.readouterr().err
    assert main(["evaluate", str(quick_model), str(PAN_US06), "--at-model-steps"]) == 2
    assert "--at-model-steps steps an FMU" in capsys.readouterr().err


def test_api_evaluates_an_fmu_like_its_model_file(quick_model, native_fmu) -> None:
    fmu_rows = lmncell.evaluate(native_fmu, [PAN_US06], 1.0, ambient=True)
    model_rows = lmncell.evaluate(quick_model, [PAN_US06], 1.0, ambient=True)
    assert fmu_rows[0]["fmu"]["rmse_mv"] == pytest.approx(model_rows[0]["lmn"]["rmse_mv"],
                                                         abs=1e-6)
    assert fmu_rows[0]["temperature_input"] == model_rows[0]["temperature_input"] == "ambient"


@pytest.mark.parametrize("kind", ["ekf", "fuzzy", "imm"])
def test_fmu_observer_scores_as_the_model_files_observer(quick_model, native_fmu, kind,
                                                         capsys) -> None:
    """The FMU's own observer, given the measured voltage through the record's samples and
    started wrong under load, estimates the SoC as `evaluate MODEL --observer` does."""
    from lmncell.evaluation.fmueval import evaluate_fmu_observer_files
    from lmncell.evaluation.observe import evaluate_observer_files

    fmu_rows = evaluate_fmu_observer_files(native_fmu, [PAN_US06], kind, 1.0, 0.4, 0.7,
                                           progress=quiet)
    ref_rows = evaluate_observer_files(quick_model, [PAN_US06], kind, 1.0, 0.4, 0.7)
    capsys.readouterr()
    assert fmu_rows[0]["start_soc_true"] == ref_rows[0]["start_soc_true"]
    for name in (kind, "coulomb"):
        for key in ("rmse_pct", "max_pct", "median_3sigma_pct", "outside_3sigma_share"):
            assert fmu_rows[0][name][key] == pytest.approx(ref_rows[0][name][key], abs=1e-3)
    assert fmu_rows[0][kind]["rmse_pct"] < fmu_rows[0]["coulomb"]["rmse_pct"]


def test_fmu_is_also_scored_at_the_records_own_samples(native_fmu, tmp_path) -> None:
    """A record sampled faster than Ts (US06, 10 Hz) is also scored sample by sample
    ("fmu_samples"): the FMU's voltage at each sample time (between model steps the step in
    progress) against the voltage logged there. At the samples that end a model step that is
    the step's output; the figures cover every sample of the segment. A record sampled at Ts
    gets no such row (it would repeat the model steps')."""
    from fmpy import extract
    from lmncell.data.dataset import record_parts
    from lmncell.evaluation.fmueval import (
        at_step_ends,
        drive_at_samples,
        read_fmu_info,
        sample_metrics,
    )
    from lmncell.evaluation.metrics import record_metrics

    from tests.conftest import A123_S1

    _, rows = evaluate_fmu(native_fmu, [PAN_US06], 1.0, progress=quiet)
    raw = rows[0]["fmu_samples"]
    info = read_fmu_info(native_fmu)
    part, seg = record_parts(read_record(PAN_US06), info.step_s, 1.0, info.capacity_ah)[0]
    t = part.time_s - part.time_s[0]
    inside = (t > 0) & (t <= len(seg) * info.step_s + 1e-9)
    assert raw["samples"] == int(inside.sum()) > 5 * len(seg)
    run = drive_at_samples(info, extract(str(native_fmu), str(tmp_path / "fmu")), part, seg,
                           False)
    assert np.array_equal(run.point_voltage_v[at_step_ends(run.points_s, info.step_s)],
                          run.voltage_v)
    at = np.searchsorted(run.points_s, t[inside] - 1e-9 * info.step_s)
    assert np.allclose(run.points_s[at], t[inside], rtol=0, atol=1e-9 * info.step_s)
    soc = np.interp(t[inside], info.step_s * np.arange(1, len(seg) + 1), seg.soc_ref)
    expected = record_metrics(part.voltage_v[inside], run.point_voltage_v[at], soc)
    assert sample_metrics(part, seg, run, info.step_s) == expected
    assert raw["rmse_mv"] == pytest.approx(expected["rmse_mv"])
    assert raw["rmse_mv"] != pytest.approx(rows[0]["fmu"]["rmse_mv"], rel=1e-3)
    _, a123_rows = evaluate_fmu(native_fmu, [A123_S1], 1.0, progress=quiet)
    assert "fmu_samples" not in a123_rows[0]


def test_rows_and_captions_say_which_temperature_drove_the_run(quick_model, native_fmu, tmp_path,
                                                               monkeypatch) -> None:
    """A record without a cell temperature (Plett's A123 files) is driven by its chamber set
    point: rows say "chamber" and captions name it, where both said "the measured cell
    temperature"; a record with one says "cell"."""
    from lmncell.evaluation.evaluate import evaluate_files, temperature_input
    from lmncell.evaluation.fmueval import evaluate_fmu_files
    from lmncell.report import plots

    from tests.conftest import A123_S1

    a123 = record_to_segments(read_record(A123_S1), 1.0, 1.0, 2.0307)[0]
    pan = record_to_segments(read_record(PAN_US06), 1.0, 1.0, 2.85)[0]
    assert (a123.temperature_kind, pan.temperature_kind) == ("chamber", "measured")
    assert [temperature_input(s, False) for s in (a123, pan)] == ["chamber", "cell"]
    assert temperature_input(a123, True) == "ambient"
    titles: list[str] = []
    real = plots.fit_figure
    monkeypatch.setattr(plots, "fit_figure", lambda trace, path, title="", **kw: (
        titles.append(title), real(trace, path, title, **kw))[1])
    with pytest.warns(UserWarning):             # the Panasonic model outside its range
        rows = evaluate_files(quick_model, [A123_S1], 1.0, tmp_path / "m", as_json=True,
                              progress=lambda _m: None)
        fmu_rows = evaluate_fmu_files(native_fmu, [A123_S1], 1.0, tmp_path / "f",
                                      as_json=True, progress=lambda _m: None)
    assert rows[0]["temperature_input"] == fmu_rows[0]["temperature_input"] == "chamber"
    assert len(titles) == 2 and all("the chamber temperature 25 °C (the record has no cell "
                                    "temperature; the thermal model computing the cell's where "
                                    "the model has one)" in t for t in titles)
    assert "LMN RMSE whole record" in titles[0] and "in free run from SoC 1" in titles[0]


def test_a_record_without_a_cell_temperature_is_driven_as_the_fmu_takes_its_input_by_default(
        quick_model, native_fmu, tmp_path) -> None:
    """A record without a measured cell temperature (a CSV of current and voltage only) is
    driven with 25 °C as the ambient, the model's thermal model warming the cell as the FMU
    does with its default temperature_is_cell = false: the same voltages as --ambient, in the
    pipeline and the FMU. Before, 25 °C was taken as the cell's own temperature, a cell that
    never warms (on this model's US06 run the cell reaches 3 K above it)."""
    from lmncell.evaluation.evaluate import evaluate_records
    from lmncell.runtime.step import simulate

    model = load_model(quick_model)
    assert model.thermal is not None
    us06 = read_record(PAN_US06)
    path = tmp_path / "us06_no_temperature.csv"
    path.write_text("t,i,u\n" + "".join(f"{t},{i},{u}\n" for t, i, u in zip(
        us06.time_s, us06.current_a, us06.voltage_v, strict=True)))
    columns = {"time": "t", "current": "i", "voltage": "u"}
    rec = read_record(path, columns=columns)
    assert rec.temperature_c is None and rec.meta.segment_starts == [0]
    runs = [evaluate_records(model, [(rec, 1.0)], ambient=ambient) for ambient in (False, True)]
    (trace, *_), rows = runs[0]
    assert np.array_equal(trace.voltage["lmn"], runs[1][0][0].voltage["lmn"])
    assert rows[0]["temperature_input"] == "none"
    assert trace.cell_temperature_c is not None and trace.cell_temperature_c.max() > 27.0
    cold = simulate(model, trace.segment.current_a, np.full(len(trace.segment), 25.0),
                    trace.segment.soc0)
    assert np.sqrt(np.mean((cold.voltage_v - trace.voltage["lmn"]) ** 2)) > 1e-3
    fmu = [evaluate_fmu(native_fmu, [path], 1.0, ambient, read_options={"columns": columns},
                        progress=lambda _m: None)[1][0]["fmu"]["rmse_mv"]
           for ambient in (False, True)]
    assert fmu[0] == fmu[1] == pytest.approx(rows[0]["lmn"]["rmse_mv"], abs=1e-6)
