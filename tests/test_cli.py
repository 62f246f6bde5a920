"""The command line end to end on shipped data, and `inspect` on every file of ../shared/data."""

from __future__ import annotations

import csv
import errno
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from lmncell.cli import main
from lmncell.data.records import DataError
from lmncell.evaluation.metrics import pooled, record_metrics
from lmncell.fmu.pythonfmu_build import native_host_environment
from lmncell.runtime.model import Depletion

from tests.conftest import A123_S1, DATA, PAN_HWFET, PAN_US06, SHARED, shared_or_skip


def test_inspect_reads_every_shared_file(capsys) -> None:
    shared_or_skip("a123_plett")
    files = (sorted((SHARED / "a123_plett/dyn").glob("*.csv"))
             + sorted((SHARED / "a123_plett/ocv").glob("*.csv"))
             + sorted((SHARED / "panasonic_18650pf").rglob("*.mat")))
    assert len(files) > 60
    assert main(["inspect", *map(str, files)]) == 0
    out = capsys.readouterr().out
    assert out.count("samples,") == len(files)


def test_inspect_plot_and_bad_file(tmp_path, capsys) -> None:
    assert main(["inspect", str(A123_S1), "--plot", str(tmp_path / "r.png")]) == 0
    assert (tmp_path / "r.png").stat().st_size > 10_000
    out = capsys.readouterr().out
    assert "SoC 12.9 … 100.0 %" in out and "lags the current" not in out    # 1 s, aligned
    # Plett's files carry the tester's Ah counters: the logged current's own integral beside them
    assert re.search(r"the logged current integrates to -\d\.\d{4} Ah\n    \([+-]0\.\d{4} Ah, "
                     r"[+-]\d\.\d\d % of 2\.3 Ah: the SoC drift", out)
    assert main(["inspect", str(PAN_US06)]) == 0
    assert "the voltage channel lags the current by 0.90 sample(s), 0.091 s" in (
        capsys.readouterr().out)
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n1,2\n")
    assert main(["inspect", str(bad)]) == 2
    assert "bad.csv: unknown format" in capsys.readouterr().err


def test_inspect_plot_says_which_capacity_its_soc_counts(tmp_path, monkeypatch) -> None:
    """The SoC panel names the capacity (the nominal 2.3 Ah of the A123 cell unless given),
    whose SoC read 12.9 % at the end of a record that the measured 2.0307 Ah empties."""
    from lmncell.report import plots

    notes: list[str] = []
    real = plots.records_figure
    monkeypatch.setattr(plots, "records_figure", lambda records, path, soc_note="": (
        notes.append(soc_note), real(records, path, soc_note))[1])
    assert main(["inspect", str(A123_S1), "--plot", str(tmp_path / "a.png")]) == 0
    assert main(["inspect", str(A123_S1), "--capacity", "2.0307", "--plot",
                 str(tmp_path / "b.png")]) == 0
    assert notes == ["SoC counted from full with 2.3 Ah (nominal, --capacity to set)",
                     "SoC counted from full with 2.0307 Ah (given)"]


def test_train_evaluate_build_simulate(tmp_path, capsys) -> None:
    model = tmp_path / "m.json"
    assert main(["train", str(PAN_US06), "--out", str(model), "--capacity", "2.85",
                 "--max-local-models", "2", "--partition", "soc,current"]) == 0
    capsys.readouterr()
    trace = tmp_path / "t.csv"
    assert main(["evaluate", str(model), str(PAN_US06), "--json", "--trace", str(trace),
                 "--plot", str(tmp_path / "plots")]) == 0
    out = capsys.readouterr().out
    rows = json.loads(out[out.index("["):])
    assert rows[0]["lmn"]["rmse_mv"] < 30 and "window_rmse_mv" in rows[0]["lmn"]
    # the 25 °C US06 record runs from full to about 9 % SoC: both ends are scored apart
    assert rows[0]["lmn"]["low_soc_samples"] > 0 and rows[0]["lmn"]["high_soc_samples"] > 0
    assert main(["evaluate", str(model), str(PAN_US06)]) == 0
    assert re.search(r"RMSE at SoC 20–80 % \d+\.\d\d mV, below 10 % \d+\.\d\d mV, above "
                     r"90 % \d+\.\d\d mV", capsys.readouterr().out)
    with open(trace) as fh:
        head = next(csv.reader(fh))
    assert head == ["time_s", "current_a", "voltage_measured_v", "voltage_model_v", "soc"]
    assert (tmp_path / "plots" / "validity.png").exists()
    fmu = tmp_path / "c.fmu"
    assert main(["build-fmu", str(model), "--out", str(fmu)]) == 0
    assert ("a native (C/C++) host on Linux runs it" in capsys.readouterr().out) == (
        native_host_environment() is not None)
    for cycle in ("wltc", "udds", "us06", "hwfet"):
        assert main(["simulate", str(fmu), "--cycle", cycle, "--json",
                     "--plot", str(tmp_path / f"{cycle}.png")]) == 0
        out = capsys.readouterr().out
        figures = json.loads(out[out.index("{"):out.rindex("}") + 1])
        assert figures["cycle"] == cycle and figures["distance_km"] > 5
        assert (tmp_path / f"{cycle}.png").exists()
    assert main(["train", str(PAN_US06), "--out", str(model), "--partition", "volts"]) == 2


def test_partition_given_by_set_as_the_help_shows(tmp_path, capsys) -> None:
    """--set 'partition=[…]' (the --set help's own example) reaches the settings like
    --partition does: a bad name is a settings error, a good one is the model's partition."""
    model = tmp_path / "m.json"
    assert main(["train", str(PAN_US06), "--out", str(model), "--soc0", "1",
                 "--set", 'partition=["soc","volts"]']) == 2
    assert "setting 'partition'" in capsys.readouterr().err
    assert main(["train", str(PAN_US06), "--out", str(model), "--soc0", "1", "--capacity",
                 "2.85", "--max-local-models", "1", "--set", 'partition=["soc"]']) == 0
    assert json.loads(model.read_text())["partition"]["variables"] == ["soc"]


def test_record_metrics_score_each_end_of_the_soc_range_apart() -> None:
    """Whole record, 20–80 % window, below 10 % and above 90 % SoC, each over its own samples;
    an end the record does not reach has no figure (None), and pooling skips it."""
    soc = np.arange(100, 4, -1) / 100                     # full to 5 %, 0.01 apart
    err = np.where(soc < 0.1, 0.030, np.where(soc > 0.9, -0.010, 0.002))
    m = record_metrics(np.zeros_like(soc), err, soc)
    assert m["low_soc_samples"] == int(np.sum(soc < 0.1)) == 5
    assert m["low_soc_rmse_mv"] == pytest.approx(30.0) and m["high_soc_max_mv"] == (
        pytest.approx(10.0))
    assert m["window_rmse_mv"] == pytest.approx(2.0) and m["ends"] == [0.1, 0.9]
    assert m["rmse_mv"] == pytest.approx(1e3 * np.sqrt(np.mean(err**2)))
    middle = record_metrics(np.zeros(3), np.full(3, 0.001), np.array([0.3, 0.5, 0.7]))
    assert middle["low_soc_rmse_mv"] is None and middle["low_soc_samples"] == 0
    assert pooled([m, middle], "low_soc_") == pytest.approx(30.0)
    assert np.isnan(pooled([middle], "high_soc_"))


def test_missing_soc0_is_explained(tmp_path, capsys) -> None:
    rec = DATA / "a123_plett/ocv/A123_OCV_P25_S3.csv.gz"   # charge from empty: not full
    assert main(["train", str(rec), "--out", str(tmp_path / "m.json"),
                 "--capacity", "2.0"]) == 2
    assert ("give it: --soc0 on the command line, soc0= in Python (1.0 for a record that "
            "starts fully charged)") in capsys.readouterr().err


def test_a_record_that_starts_rested_part_way_down_is_not_taken_as_full(
        a123_model, tmp_path, capsys) -> None:
    """The A123 OCV test's S2 part starts rested near empty, at its own top voltage, and
    dithers down to 2.0 V from there: without --soc0 it is refused where an OCV tells, by the
    model's OCV in evaluate (model file and FMU) and by the slow tests' in train, with the
    voltage, the SoC the OCV gives it and what to give (before, it was taken as full and
    scored 1.3 V off); with --soc0 it is evaluated."""
    from lmncell.data.dataset import START_FULL_MIN_SOC
    from lmncell.fmu.pythonfmu_build import build_fmu

    fmu = build_fmu(a123_model, tmp_path / "a123.fmu")
    dither = DATA / "a123_plett/ocv/A123_OCV_P25_S2.csv.gz"
    expected = re.compile(r"A123_OCV_P25_S2\.csv\.gz: starts rested at 2\.68 V, which the "
                          r"model's OCV puts at SoC 0\.[01]\d, not full charge \(3\.\d+ V at SoC "
                          r"1\); give the record's start SoC: --soc0 on the command line")
    for model in (a123_model, fmu):
        assert main(["evaluate", str(model), str(dither)]) == 2
        assert expected.search(capsys.readouterr().err)
    ocv = [str(DATA / f"a123_plett/ocv/A123_OCV_P25_{k}.csv.gz") for k in ("S1", "S3")]
    assert main(["train", str(A123_S1), str(dither), "--out", str(tmp_path / "m.json"),
                 "--capacity", "2.2", "--ocv-tests", *ocv]) == 2
    assert ("A123_OCV_P25_S2.csv.gz: starts rested at 2.68 V, which the OCV of the slow tests "
            "(--ocv-tests) puts at SoC 0.0") in capsys.readouterr().err
    assert main(["evaluate", str(a123_model), str(dither), "--soc0", "0.01"]) == 0
    assert "A123_OCV_P25_S2.csv.gz" in capsys.readouterr().out
    readme = " ".join((DATA.parent / "README.md").read_text(encoding="utf-8").split())
    assert f"puts below SoC {START_FULL_MIN_SOC:g}, such as a rest part-way down" in readme


def test_a_record_of_another_cell_than_the_ocv_is_refused(a123_model, tmp_path,
                                                          capsys) -> None:
    """A Panasonic record (rested full at 4.18 V) given the A123 OCV tests or the A123 model
    (OCV top 3.5…3.6 V): refused by name. Training made a 408 mV model of it without a word."""
    ocv = [str(DATA / f"a123_plett/ocv/A123_OCV_P25_{k}.csv.gz") for k in ("S1", "S3")]
    assert main(["train", str(PAN_US06), "--out", str(tmp_path / "m.json"), "--capacity",
                 "2.85", "--ocv-tests", *ocv]) == 2
    expected = re.compile(r"US06_Pan18650PF\.mat: starts rested at 4\.178 V, \d+ mV above the "
                          r"top of (the OCV of the slow tests \(--ocv-tests\)|the model's OCV) "
                          r"\(3\.\d+ V at SoC 1\), where a rested full cell lies within 200 mV "
                          r"of it: that OCV is not this cell's")
    assert expected.search(capsys.readouterr().err)
    assert main(["evaluate", str(a123_model), str(PAN_US06)]) == 2
    assert expected.search(capsys.readouterr().err)
    assert not (tmp_path / "m.json").exists()


def test_ocv_soc_reads_the_last_rise_through_a_voltage() -> None:
    from lmncell.data.dataset import ocv_soc

    soc, volts = np.linspace(0.0, 1.0, 5), np.array([2.5, 3.2, 3.3, 3.3, 3.5])
    assert ocv_soc(2.85, soc, volts) == pytest.approx(0.125)
    assert ocv_soc(3.4, soc, volts) == pytest.approx(0.875)
    assert ocv_soc(3.3, soc, volts) == pytest.approx(0.75)     # the top of the plateau
    assert ocv_soc(2.0, soc, volts) == 0.0 and ocv_soc(3.6, soc, volts) == 1.0


def test_explain_prints_every_local_model_as_a_positive_rc_ladder(quick_model, tmp_path,
                                                                  capsys) -> None:
    assert main(["explain", str(quick_model)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    # the depletion columns are explained: @0.1 is a coefficient, @SoC what the LM's data see
    assert lines[2].startswith("R_dep: the depletion resistance R_d·(0.1/SoC)^4")
    head = 3
    assert "RC ladder" in lines[0] and "R@800s" in lines[head] and "R ≥ 0" in lines[head]
    assert "R_dep@0.1" in lines[head] and "R_dep@SoC" in lines[head]
    doc = json.loads(quick_model.read_text())
    rows = lines[head + 1:head + 1 + len(doc["local_models"]["theta"])]
    assert all(r.split()[-1] == "yes" for r in rows)
    # then the training error by SoC that the EKF's measurement error follows
    rms = doc["noise"]["residual_rms_by_soc"]
    end = head + 1 + len(rows)
    assert lines[end].startswith("free-run training error RMS by SoC (mV) 0.05: "
                                 f"{1e3 * rms['rms_v'][0]:.1f}, 0.15: ")
    assert "σ_u(SoC) is 10 × 3 × that" in lines[end + 1]
    assert len(lines) == end + 2
    assert main(["explain", str(quick_model), "--temperature", "10", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert all(r["temperature_c"] == 10.0 and r["rc_positive"] for r in doc)
    # the depletion resistance also where each local model lies: R_d·(0.1/SoC)^p, what a
    # steady current sees there (R_d at SoC 0.1 read tens of Ω for a local model near full)
    factor = Depletion(**json.loads(quick_model.read_text())["regressors"]["depletion"]).factor
    assert all(r["r_depletion_at_soc_mohm"] == pytest.approx(
        r["r_depletion_mohm"] * factor(r["soc"]), rel=1e-12, abs=1e-3) for r in doc)
    # R_d at SoC 0.1 is shown as "–" exactly for the local models under 1 % valid there
    # (the demo's A123 model near full read 23 Ω there)
    assert all(0.0 <= r["validity_at_soc_0_1"] <= 1.0 for r in doc)
    assert max(r["validity_at_soc_0_1"] for r in doc) > 0.3
    column = lines[head].split().index("R_dep@0.1")
    assert [row.split()[column] == "–" for row in rows] == \
        [r["validity_at_soc_0_1"] < 0.01 for r in doc]
    (tmp_path / "bad.json").write_text("{}")
    assert main(["explain", str(tmp_path / "bad.json")]) == 2
    assert "bad.json" in capsys.readouterr().err


def test_a_depletion_coefficient_out_of_its_local_models_reach_is_not_shown() -> None:
    from lmncell.evaluation.interpret import depletion_shown

    row = {"r_depletion_mohm": 23182.8, "r_depletion_at_soc_mohm": 4.46,
           "r_depletion_fast_mohm": 900.0, "validity_at_soc_0_1": 0.004}
    assert [depletion_shown(row, k) for k in row if k != "validity_at_soc_0_1"] == \
        ["–", 4.46, "–"]
    row["validity_at_soc_0_1"] = 0.02
    assert depletion_shown(row, "r_depletion_mohm") == 23182.8


def test_explain_reads_the_model_an_fmu_ships(quick_model, native_fmu, tmp_path,
                                              capsys) -> None:
    """What a supplier's FMU holds is explained as its model file is (`explain CELL.fmu` read
    the archive as JSON: 'not a text (JSON) model file')."""
    assert main(["explain", str(quick_model), "--json"]) == 0
    from_model = capsys.readouterr().out
    assert main(["explain", str(native_fmu), "--json"]) == 0
    assert capsys.readouterr().out == from_model
    fake = tmp_path / "fake.fmu"
    fake.write_text(quick_model.read_text())
    assert main(["explain", str(fake)]) == 2
    assert "fake.fmu: not a readable FMU" in capsys.readouterr().err


def test_build_fmu_builds_the_model_an_fmu_ships_again(quick_fmu, native_fmu, tmp_path,
                                                      capsys) -> None:
    """A native FMU built from a pythonfmu FMU is the native FMU of its model file: the same
    model description (GUID from the model) and model file (the FMU was read as JSON)."""
    import zipfile

    out = tmp_path / "again.fmu"
    assert main(["build-fmu", str(quick_fmu), "--out", str(out), "--native"]) == 0
    with zipfile.ZipFile(out) as again, zipfile.ZipFile(native_fmu) as first:
        for name in ("modelDescription.xml", "resources/model.json"):
            assert again.read(name) == first.read(name), name
    fake = tmp_path / "fake.fmu"
    fake.write_bytes(b"not a zip")
    assert main(["build-fmu", str(fake), "--out", str(tmp_path / "x.fmu")]) == 2
    assert "fake.fmu: not a readable FMU" in capsys.readouterr().err


def test_leave_one_out_folds_name_what_is_wrong() -> None:
    """The leave-one-out examples' folds: each held-out record beside all the others, with
    their start SoCs, for one pattern or a comma list; a pattern that matches nothing, or a
    single record, is a clear DataError."""
    from lmncell.data.records import DataError
    from lmncell.evaluation.evaluate import (
        fold_words,
        hold_out_clause,
        leave_one_out_folds,
        through_pauses_clause,
    )

    recs = ["d/a_10degC.mat", "d/b_25degC.mat", "d/c_10degC.mat"]
    assert leave_one_out_folds(recs, "10degC", [1.0, 0.0, 0.5]) == [
        ("d/a_10degC.mat", 1.0, ["d/b_25degC.mat", "d/c_10degC.mat"], [0.0, 0.5]),
        ("d/c_10degC.mat", 0.5, ["d/a_10degC.mat", "d/b_25degC.mat"], [1.0, 0.0])]
    assert [f[1] for f in leave_one_out_folds(recs)] == [None, None, None]
    assert [f[0] for f in leave_one_out_folds(recs, "a_, c_,")] == ["d/a_10degC.mat",
                                                                     "d/c_10degC.mat"]
    assert hold_out_clause("a_, c_,") == " whose name contains one of 'a_', 'c_'"
    assert hold_out_clause("10degC") == " whose name contains '10degC'"
    assert hold_out_clause("") == ""
    assert through_pauses_clause(False) == ""
    assert "(the observer runs on through them" in through_pauses_clause(True, "observer")
    with pytest.raises(DataError, match="'P25' is in none of the 3"):
        leave_one_out_folds(recs, "P25")
    with pytest.raises(DataError, match="'P25' is in none of the 3"):
        leave_one_out_folds(recs, "10degC,P25")
    with pytest.raises(DataError, match="at least two different records, got 1"):
        leave_one_out_folds(["d/a.csv"])
    # held out together (leave one temperature out): each trained on the others only
    assert leave_one_out_folds(recs, "10degC", [1.0, 0.0, 0.5], together=True) == [
        ("d/a_10degC.mat", 1.0, ["d/b_25degC.mat"], [0.0]),
        ("d/c_10degC.mat", 0.5, ["d/b_25degC.mat"], [0.0])]
    # a record matched by several groups is held out with each of them
    assert [f[:3:2] for f in leave_one_out_folds(recs, "a_,10degC", together=True)] == [
        ("d/a_10degC.mat", ["d/b_25degC.mat", "d/c_10degC.mat"]),
        ("d/a_10degC.mat", ["d/b_25degC.mat"]), ("d/c_10degC.mat", ["d/b_25degC.mat"])]
    # "A+B" matches either (leave two out); alone it is one record's fold per match
    assert [f[:3:2] for f in leave_one_out_folds(recs, "a_+b_,b_+c_", together=True)] == [
        ("d/a_10degC.mat", ["d/c_10degC.mat"]), ("d/b_25degC.mat", ["d/c_10degC.mat"]),
        ("d/b_25degC.mat", ["d/a_10degC.mat"]), ("d/c_10degC.mat", ["d/a_10degC.mat"])]
    assert [f[0] for f in leave_one_out_folds(recs, "a_+b_, a_")] == ["d/a_10degC.mat",
                                                                      "d/b_25degC.mat"]
    with pytest.raises(DataError, match="'P25' is in none of the 3"):
        leave_one_out_folds(recs, "a_+P25", together=True)
    assert hold_out_clause("a_+b_, c_") == " whose name contains one of ('a_' or 'b_'), 'c_'"
    assert hold_out_clause("a_+ b_+") == " whose name contains 'a_' or 'b_'"
    with pytest.raises(DataError, match="'.mat' is in every record name, so held out "
                                        "together nothing is left to train on"):
        leave_one_out_folds(recs, ".mat", together=True)
    assert fold_words("10degC", True, 3) == (
        "Leave-one-group-out", "the records whose name contains '10degC' held out together, "
        "one group per pattern, the models trained on the records outside the group")
    assert fold_words("", False, 3, "model") == (
        "Leave-one-record-out", "each record held out in turn, the model trained on the "
        "other 2 records")


def test_trained_per_fold_trains_once_per_training_set() -> None:
    """The leave-one-out scripts' trainings: one per fold held out alone, one per group held
    out together, each given the fold's training records and their start SoCs."""
    from lmncell.evaluation.evaluate import leave_one_out_folds, trained_per_fold

    recs = ["d/a_10degC.mat", "d/b_25degC.mat", "d/c_10degC.mat", "d/e_25degC.mat"]
    calls: list[tuple[list[str], list[float | None]]] = []

    def train(records: list[str], socs: list[float | None]) -> int:
        calls.append((records, socs))
        return len(calls)

    socs = [1.0, 0.9, 0.8, 0.7]
    # two groups whose records alternate in the list: the folds come group by group
    both = list(trained_per_fold(leave_one_out_folds(recs, "10degC,25degC", socs,
                                                     together=True), train))
    assert both == [("d/a_10degC.mat", 1.0, 1), ("d/c_10degC.mat", 0.8, 1),
                    ("d/b_25degC.mat", 0.9, 2), ("d/e_25degC.mat", 0.7, 2)]
    assert calls == [(["d/b_25degC.mat", "d/e_25degC.mat"], [0.9, 0.7]),
                     (["d/a_10degC.mat", "d/c_10degC.mat"], [1.0, 0.8])]
    calls.clear()
    grouped = list(trained_per_fold(leave_one_out_folds(recs, "10degC", socs, together=True),
                                    train))
    assert grouped == [("d/a_10degC.mat", 1.0, 1), ("d/c_10degC.mat", 0.8, 1)]
    assert calls == [(["d/b_25degC.mat", "d/e_25degC.mat"], [0.9, 0.7])]
    calls.clear()
    alone = list(trained_per_fold(leave_one_out_folds(recs, "10degC", socs), train))
    assert alone == [("d/a_10degC.mat", 1.0, 1), ("d/c_10degC.mat", 0.8, 2)]
    assert [c[0] for c in calls] == [["d/b_25degC.mat", "d/c_10degC.mat", "d/e_25degC.mat"],
                                     ["d/a_10degC.mat", "d/b_25degC.mat", "d/e_25degC.mat"]]


def test_start_soc_per_file(tmp_path, capsys) -> None:
    """--soc0 takes one value for all files or one per file; a count that fits neither is
    refused with a message that names soc0 and both counts."""
    from lmncell.data.dataset import start_socs
    from lmncell.data.records import DataError

    assert start_socs(None, 2) == [None, None]
    assert start_socs(0.5, 2) == [0.5, 0.5]
    assert start_socs([1.0, 0.0], 2) == [1.0, 0.0]
    assert start_socs([0.3], 3) == [0.3, 0.3, 0.3]
    with pytest.raises(DataError, match="soc0 = 1.5"):
        start_socs([1.0, 1.5], 2)
    out = tmp_path / "m.json"
    assert main(["train", str(PAN_US06), str(PAN_HWFET), "--out", str(out), "--capacity",
                 "2.85", "--soc0", "1,1,0"]) == 2
    err = capsys.readouterr().err
    assert "soc0: 3 start SoC values for 2 data file(s)" in err
    with pytest.raises(SystemExit):
        main(["train", str(PAN_US06), "--out", str(out), "--soc0", "1,x"])
    assert "'x': expected a SoC fraction within 0…1" in capsys.readouterr().err


def test_output_into_a_closed_pipe_is_no_error(quick_model, tmp_path, monkeypatch) -> None:
    # `lmncell explain MODEL | head -1`: the reader stops, the next write breaks the pipe
    sink = open(tmp_path / "sink", "w")    # noqa: SIM115 (closed below)

    class ClosedPipe:
        def write(self, _text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self) -> int:
            return sink.fileno()

    monkeypatch.setattr("sys.stdout", ClosedPipe())
    try:
        assert main(["explain", str(quick_model)]) == 0
    finally:
        sink.close()


def test_folds_figure_draws_every_fold_and_refuses_none(tmp_path) -> None:
    from lmncell.report.plots import folds_figure
    from matplotlib import image

    folds = [("03-20-17_01.43_25degC_US06_Pan18650PF.mat",
              {"cell": {"lmn": (5.9, 10.9), "ecm2rc": (9.2, 21.8)},
               "ambient": {"lmn": (7.3, 11.1), "ecm2rc": (24.9, 36.6)}}),
             ("A123_DYN_50_P25_s1.csv", {"cell": {"lmn": (3.2, 23.6)}})]
    path = folds_figure(folds, tmp_path / "folds.png", "Leave-one-record-out, 2 folds")
    height, width, _ = image.imread(path).shape
    assert height > 500 and width > 600          # two rows of panels: cell and ambient
    with pytest.raises(ValueError, match="no folds"):
        folds_figure([], tmp_path / "none.png", "")


def test_observer_folds_figure_draws_the_folds_and_refuses_none(tmp_path) -> None:
    from lmncell.report.plots import observer_folds_figure
    from matplotlib import image

    folds = [("03-20-17_01.43_25degC_US06_Pan18650PF.mat",
              {"ekf": (0.27, 0.0), "fuzzy": (1.06, 0.0), "imm": (1.35, 0.0)}),
             ("A123_DYN_50_P25_s1.csv", {"ekf": (2.41, 0.0), "imm": (3.6, 0.9)})]
    path = observer_folds_figure(folds, tmp_path / "observers.png", "Observer leave-one-out")
    height, width, _ = image.imread(path).shape
    assert height > 300 and width > 600
    with pytest.raises(ValueError, match="no folds"):
        observer_folds_figure([], tmp_path / "none.png", "")


@pytest.mark.parametrize("argv", [
    ["train", "DATA", "--out", "NODIR/m.json"],
    ["build-fmu", "m.json", "--out", "NODIR/m.fmu"],
    # pythonfmu took another name for a folder and wrote LMNCell.fmu into it
    ["build-fmu", "m.json", "--out", "TMP/m.zip"],
    ["build-fmu", "m.json", "--out", "TMP/m.FMU"],
    ["simulate", "m.json", "--plot", "NODIR/s.png"],
    ["inspect", "DATA", "--plot", "NODIR/r.png"],
    ["evaluate", "m.json", "DATA", "--trace", "NODIR/t.csv"],
    ["design", "--capacity", "2", "--soc-profile", "0.8,0.2", "--out", "NODIR/p.csv"],
    ["train", "DATA", "--out", "TMP"],
    # a folder to write into given as an existing file (the demo raised FileExistsError)
    ["demo", "--out", "FILE"],
    ["evaluate", "m.json", "DATA", "--plot", "FILE"],
    ["sweep", "m.fmu", "--out", "TMP/r.csv", "--plot", "FILE"],
    ["design", "--capacity", "2", "--soc-profile", "0.8,0.2", "--out", "TMP/p.csv",
     "--plot", "FILE"],
])
def test_output_files_in_missing_folders_are_refused_before_any_work(tmp_path, capsys,
                                                                    argv) -> None:
    """A file to write whose folder does not exist (or a folder given as the file), or a
    folder to write into given as a file, is refused when the arguments are read, not after a
    training or a simulation."""
    (tmp_path / "file").write_text("")
    argv = [a.replace("NODIR", str(tmp_path / "missing")).replace("DATA", str(PAN_US06))
            .replace("TMP", str(tmp_path)).replace("FILE", str(tmp_path / "file"))
            for a in argv]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert ("does not exist" in err or "is a folder" in err
            or "is a file; expected a folder" in err
            or "an FMU's file name must end in .fmu" in err) and "argument" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]     # nothing made


def test_temperatures_on_the_command_line_are_cell_temperatures_in_celsius(quick_model,
                                                                          capsys) -> None:
    """298.15 (kelvin) is refused, with the range, before anything is simulated."""
    with pytest.raises(SystemExit):
        main(["explain", str(quick_model), "--temperature", "298.15"])
    assert "a cell temperature in °C within -60…100 (not K)" in capsys.readouterr().err
    with pytest.raises(SystemExit):     # simulate's --ambient is the ambient's, said so
        main(["simulate", str(quick_model), "--ambient", "298.15"])
    assert "--ambient: '298.15': expected an ambient temperature in °C within -60…100 (not K)" in (
        capsys.readouterr().err)


@pytest.mark.parametrize("command", [["simulate"], ["sweep", "--out", "OUT"]])
def test_a_model_file_where_an_fmu_belongs_is_named_not_a_traceback(quick_model, tmp_path,
                                                                   capsys, command) -> None:
    """`lmncell simulate` and `lmncell sweep` take an FMU; given the model's JSON they say so
    (sweep's workers raised a BadZipFile traceback)."""
    argv = [command[0], str(quick_model)] + [str(tmp_path / "r.csv") if c == "OUT" else c
                                             for c in command[1:]]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{quick_model}: not a readable FMU" in err
    assert f"it is a model file; build an FMU of it with `lmncell build-fmu {quick_model}" in err


def test_cli_prints_a_users_warning_as_a_message_not_python_source(quick_model, capsys) -> None:
    """A record beyond the trained range: the command line says so as "lmncell evaluate:
    warning: …" on stderr, without Python's file, line and source; the library still raises the
    UserWarning itself (test_package), and other warnings keep Python's format."""
    import warnings

    from lmncell.cli import user_warnings_as

    assert main(["evaluate", str(quick_model), str(PAN_US06), "--soc0", "1"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"^lmncell evaluate: warning: 03-20-17_01\.43_25degC_US06_Pan18650PF\.mat: "
                     r"current -\d+\.\d\d…\d+\.\d\d A exceeds the trained range", err, re.M)
    assert "UserWarning" not in err and "check_range" not in err and ".py:" not in err
    seen = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda message, category, *_a, **_k: seen.append(category)
        with user_warnings_as("prog"):
            warnings.warn("deprecated thing", DeprecationWarning, stacklevel=1)
            warnings.warn("user thing", UserWarning, stacklevel=1)
    assert seen == [DeprecationWarning]
    assert capsys.readouterr().err == "prog: warning: user thing\n"


def test_ctrl_c_ends_a_command_with_a_message_and_code_130(monkeypatch, capsys) -> None:
    import lmncell.cli as cli

    def interrupted(_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_inspect", interrupted)
    assert cli.main(["inspect", "x.csv"]) == 130
    assert "lmncell inspect: interrupted" in capsys.readouterr().err


def test_out_of_memory_ends_a_command_with_a_message_and_code_2(monkeypatch, capsys) -> None:
    """A MemoryError (data too large for the machine at those settings) is said in a line,
    with what numpy could not allocate, not as a traceback."""
    import lmncell.cli as cli

    def too_big(_args):
        raise MemoryError("Unable to allocate 1.76 GiB for an array with shape (7612046, 31)")

    monkeypatch.setattr(cli, "cmd_inspect", too_big)
    assert cli.main(["inspect", "x.csv"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lmncell inspect: error: out of memory (Unable to allocate 1.76 GiB")
    assert "expected fewer or shorter records, a longer sample time" in err


@pytest.mark.parametrize("command", [
    ["train", "x.csv", "--out", "m.json"], ["inspect", "x.csv"],
    ["design", "--soc-profile", "0.8,0.2", "--out", "p.csv"]])
@pytest.mark.parametrize("capacity", ["1e9", "1e-9", "0"])
def test_a_capacity_no_model_file_holds_is_refused_at_once(capsys, command, capacity) -> None:
    """`train --capacity 1e9` wrote a model that no loader would read (capacity_ah outside
    CAPACITY_RANGE_AH); `design --capacity 1e-9` designed a 0 A programme."""
    with pytest.raises(SystemExit) as info:
        main([*command, "--capacity", capacity])
    assert info.value.code == 2
    assert (f"argument --capacity: '{capacity}': expected a cell capacity in Ah within "
            "0.0001…100000") in capsys.readouterr().err


@pytest.mark.parametrize("capacity", [1e9, -1.0, float("nan"), "two", True])
def test_api_train_refuses_a_capacity_no_model_file_holds(tmp_path, capacity) -> None:
    import lmncell

    with pytest.raises(DataError, match=r"train: capacity_ah = .*; expected None \(estimated "
                                        r"from the records\) or a cell capacity in Ah within"):
        lmncell.train([PAN_HWFET], tmp_path / "m.json", capacity_ah=capacity)


def test_observer_json_is_standard_json_with_null_for_never_settled(quick_model, capsys) -> None:
    """Coulomb counting from a wrong start never comes within 2 %: its time_to_2pct_s was
    printed as the literal Infinity, which standard JSON readers refuse."""
    assert main(["evaluate", str(quick_model), str(PAN_US06), "--soc0", "1", "--observer",
                 "ekf", "--soc0-est", "0.7", "--json"]) == 0
    text = capsys.readouterr().out
    rows = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))
    assert rows[0]["coulomb"]["time_to_2pct_s"] is None
    assert rows[0]["coulomb"]["rmse_pct"] == pytest.approx(30.0, abs=0.5)


def test_json_text_turns_every_non_finite_float_into_null() -> None:
    from lmncell.report.jsontext import json_text

    obj = {"a": float("nan"), "b": [np.float64(np.inf), 1.5, (2, -np.inf)], "c": "x", "d": None}
    assert json.loads(json_text(obj)) == {"a": None, "b": [None, 1.5, [2, None]], "c": "x",
                                          "d": None}


@pytest.mark.parametrize("option, value", [("--voltage-min", "-1"), ("--voltage-max", "inf"),
                                           ("--voltage-max", "1e300")])
def test_design_voltage_limits_outside_a_cells_are_refused(capsys, option, value) -> None:
    """A negative lower limit or an infinite upper one designed a programme against no limit."""
    with pytest.raises(SystemExit) as info:
        main(["design", "--capacity", "2.3", "--soc-profile", "0.8,0.2", "--out", "p.csv",
              option, value])
    assert info.value.code == 2
    assert (f"argument {option}: '{value}': expected a cell voltage in V within 0…10"
            in capsys.readouterr().err)


def test_a_record_logged_every_10_s_is_evaluated_by_a_1_s_model_and_fmu(
        quick_model, quick_fmu, tmp_path, capsys) -> None:
    """The README's check of a 1C discharge logged every 10 s (the Panasonic Dis1C files) was
    refused as 'would learn the interpolation': evaluating is not learning. The model and its
    FMU score such a log alike; training on it at 0.5 s (20 steps per sample) is refused."""
    from lmncell.data.readers import read_record

    rec = read_record(PAN_HWFET)
    keep = np.flatnonzero(np.diff(np.floor(rec.time_s / 10.0), prepend=-1.0) > 0)
    slow = tmp_path / "slow.csv"
    with open(slow, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["t", "I", "U"])
        out.writerows(zip(rec.time_s[keep], rec.current_a[keep], rec.voltage_v[keep],
                          strict=True))
    columns = ["--columns", "time=t,current=I,voltage=U", "--soc0", "1"]
    figures = []
    for model in (quick_model, quick_fmu):
        assert main(["evaluate", str(model), str(slow), *columns, "--json"]) == 0, (
            capsys.readouterr().err)
        out = capsys.readouterr().out
        row = json.loads(out[out.index("["):])[0]
        assert row["logged_every_s"] == pytest.approx(10.0, rel=1e-5)
        figures.append(next(v["rmse_mv"] for v in row.values() if isinstance(v, dict)))
    assert figures[0] < 60 and abs(figures[0] - figures[1]) < 1e-6, figures   # FMU = model
    for model in (quick_model, quick_fmu):                # the table says how it was scored
        assert main(["evaluate", str(model), str(slow), *columns]) == 0
        said = capsys.readouterr()
        assert ("slow.csv: logged every 10 s (median), slower than the model's sample time: it "
                "is scored at the model's steps") in said.out + said.err
    assert main(["train", str(slow), *columns, "--out", str(tmp_path / "m.json"),
                 "--capacity", "2.85", "--set", "sample_time_s=0.5"]) == 2
    assert ("slow.csv: logged every 10 s (the median time step); a model sample time of 0.5 s "
            "would hold each sample over 20 model steps") in capsys.readouterr().err


@pytest.mark.parametrize("native", [False, True], ids=["pythonfmu", "native"])
def test_a_build_that_cannot_write_keeps_the_old_fmu_and_says_why(quick_model, tmp_path,
                                                                  monkeypatch, capsys,
                                                                  native) -> None:
    """A full disk while the FMU is zipped: exit status 2 and the system's reason with the
    FMU's path (no traceback), the FMU of before untouched, no half-written file left."""
    out = tmp_path / "cell.fmu"
    out.write_bytes(b"the FMU of yesterday")
    real, calls = zipfile.ZipFile.writestr, []

    def full_disk(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "writestr", full_disk)
    assert main(["build-fmu", str(quick_model), "--out", str(out),
                 *(["--native"] if native else [])]) == 2
    err = capsys.readouterr().err
    assert f"{out}: No space left on device (OS error 28)" in err, err
    assert "Traceback" not in err and len(calls) > 2
    assert out.read_bytes() == b"the FMU of yesterday"
    assert [p.name for p in tmp_path.iterdir()] == ["cell.fmu"]


def test_a_figure_is_written_whole_and_closed_even_where_writing_fails(tmp_path,
                                                                       monkeypatch) -> None:
    """save_figure: a PNG by the name's suffix, the figure closed; where the disk fills while
    it is written, the picture of before stays, no part is left, and the figure is closed."""
    from lmncell.report.plots import plt, save_figure

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    path = save_figure(fig, tmp_path / "a.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not plt.fignum_exists(fig.number)
    before = path.read_bytes()
    fig, ax = plt.subplots()

    def full_disk(target, **kwargs):
        Path(target).write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(fig, "savefig", full_disk)
    with pytest.raises(OSError) as failed:
        save_figure(fig, path)
    assert failed.value.filename == str(path) and not plt.fignum_exists(fig.number)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["a.png"]


@pytest.mark.parametrize("extra, message", [
    (["--soc0-est", "0.5"], "--soc0-est without --observer: they set up a SoC observer's run"),
    (["--start-soc", "0.6"], "--start-soc without --observer"),
    (["--observer", "ekf"], "--observer needs --soc0-est"),
    (["--observer", "ekf", "--soc0-est", "0.5", "--ambient"],
     "--ambient with --observer: the observer runs on the measured cell temperature"),
])
def test_observer_options_out_of_place_are_refused(quick_model, capsys, extra, message) -> None:
    """An observer's options given without --observer were ignored: the voltage was judged
    and the start guess silently dropped."""
    assert main(["evaluate", str(quick_model), str(PAN_US06), "--soc0", "1", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_output_that_is_not_utf8_is_escaped_not_a_traceback(quick_model) -> None:
    """Output redirected to a file on Windows is cp1252, which has no Ω or τ (ASCII here, which
    has neither them nor ° and …): explain, a command's --help and an error ended in a
    UnicodeEncodeError traceback."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    for args, status in ((["explain", str(quick_model)], 0), (["train", "--help"], 0),
                         (["explain", str(quick_model), "--temperature", "−5"], 2)):
        out = subprocess.run([sys.executable, "-m", "lmncell.cli", *args], capture_output=True,
                             env=env, timeout=120)
        assert out.returncode == status and b"Traceback" not in out.stderr, out.stderr
        assert out.stdout.isascii() and out.stderr.isascii()
        if args[0] == "explain" and status == 0:
            assert b"resistances in m\\u03a9" in out.stdout


def test_train_says_where_ocv_tests_took_the_data_files(tmp_path, capsys) -> None:
    """--ocv-tests before the data files takes them all (argparse): the error says so and how
    to order the arguments, instead of argparse's bare "required: data"."""
    out = str(tmp_path / "m.json")
    assert main(["train", "--out", out, "--ocv-tests", "ocv.csv", str(A123_S1)]) == 2
    err = capsys.readouterr().err
    assert "lmncell train: error: no training data files: --ocv-tests took every file" in err
    assert f"(ocv.csv, {A123_S1})" in err and "end its list with --" in err
    assert main(["train", "--out", out]) == 2
    assert "no training data files given" in capsys.readouterr().err
    assert not Path(out).exists()

