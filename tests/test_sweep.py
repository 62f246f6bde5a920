"""Scenario sweeps on Dask (issue 20): rows equal single runs, the table does not depend on the
number of workers, bad option values are refused with the option's name."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from lmncell.cli import main
from lmncell.data.readers import read_record
from lmncell.data.records import DataError

pytest.importorskip("dask.distributed", reason="the sweep extra (dask[distributed]) is absent")
pytest.importorskip("pandas", reason="the sweep extra (pandas) is absent")

from lmncell.scenarios.drive import run_cycle
from lmncell.scenarios.sweep import scenarios, sweep


@pytest.fixture(scope="module")
def cases():
    return scenarios(["us06", "hwfet"], [10.0, 35.0], [0.9], repeat=1)


def test_rows_equal_single_runs_whatever_the_workers(native_fmu, cases, tmp_path,
                                                     monkeypatch) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path))      # the worker processes' temporary folder
    one = sweep(native_fmu, cases, workers=1, progress=False)
    two = sweep(native_fmu, cases, workers=2, progress=False)
    assert not list(tmp_path.glob("lmncell-sweep-*"))   # the workers' FMU copies are removed
    deterministic = [c for c in one.columns if c != "wall_s"]
    assert one[deterministic].equals(two[deterministic])
    assert list(one["cycle"]) == ["us06", "us06", "hwfet", "hwfet"]
    assert list(one["ambient_c"]) == [10.0, 35.0, 10.0, 35.0]
    for sc, (_, row) in zip(cases, one.iterrows(), strict=True):
        single = run_cycle(native_fmu, sc.cycle, sc.vehicle, sc.repeat, sc.soc0,
                           temperature_c=sc.ambient_c).figures
        for key in ("distance_km", "voltage_min_v", "voltage_max_v", "soc_end", "ah_throughput",
                    "cell_energy_wh", "out_of_range_steps", "cell_temperature_max_c"):
            assert row[key] == single[key], key
    warm = one[one["ambient_c"] == 35.0]["cell_temperature_max_c"].to_numpy()
    cold = one[one["ambient_c"] == 10.0]["cell_temperature_max_c"].to_numpy()
    assert (warm > cold + 20).all()                      # the ambient reaches the model
    assert one["cell_temperature_start_c"].isna().all()  # rested at the ambient


@pytest.mark.parametrize("args, message", [
    (["--cycles", "wltc,nedc"], "--cycles 'nedc': neither one of ['udds', 'us06', 'hwfet', "
                                "'wltc'] nor a speed-trace file"),
    (["--soc0", "0.5,1.5"], "--soc0 1.5"),
    (["--ambient", "-300"], "--ambient -300.0"),
    (["--ambient", "298.15"], "--ambient 298.15: expected temperatures in °C within -60…100"),
    (["--ambient", "warm"], "--ambient 'warm'"),
    (["--workers", "0"], "expected a whole number"),
    (["--pack", "96x3"], "--pack '96x3'"),
    (["--pack", "4s2p", "--spread", "capacity=0.5"], "--spread capacity=0.5"),
    (["--cutoff", "-1"], "--cutoff: '-1': expected a cell voltage in V"),
    (["--cutoff", "nan"], "--cutoff: 'nan'"),
    # blanks in the list are dropped, as in the number lists ('' read as the folder '.')
    (["--cycles", " , "], "sweep: --cycles, --ambient and --soc0 each need at least one value"),
    (["--cycles", "us06,,us06"], "--cycles names 'us06' twice"),
])
def test_bad_options_name_the_option(native_fmu, tmp_path, capsys, args, message) -> None:
    code = None
    try:
        code = main(["sweep", str(native_fmu), "--out", str(tmp_path / "r.csv"), *args])
    except SystemExit as exc:            # argparse refuses malformed values itself
        code = exc.code
    assert code == 2
    assert message in capsys.readouterr().err


def test_a_table_name_that_cannot_be_written_is_refused_before_any_run(
        native_fmu, tmp_path, capsys, monkeypatch) -> None:
    """The table's name is checked before the scenarios run (their results were lost when it
    was refused at the end)."""
    import lmncell.scenarios.sweep as sw

    monkeypatch.setattr(sw, "sweep", lambda *_a, **_k: pytest.fail("the sweep ran"))
    assert main(["sweep", str(native_fmu), "--out", str(tmp_path / "r.txt")]) == 2
    assert "r.txt: --out must end in .csv or .parquet" in capsys.readouterr().err


@pytest.mark.parametrize("args, message", [
    (["--cycles", "udds", "--repeat", "100000"],
     "sweep: --repeat 100000: 137000000 steps of 1 s over 100000 × the UDDS cycle, more than "
     "2000000, which would take hours and gigabytes; expected at most 1459 repeats"),
    (["--cycles", "udds", "--repeat", "100000", "--pack", "4s2p"], "--repeat 100000"),
    (["--cycles", "TINY"], "--cycles 'tiny.csv': 0.2 s long, shorter than one step of 1 s"),
])
def test_a_run_too_long_or_too_short_is_refused_before_any_worker_starts(
        native_fmu, tmp_path, capsys, monkeypatch, args, message) -> None:
    """Each scenario's number of steps is checked before the cluster starts: a worker refusing
    it logged a failed task with a traceback before the error."""
    import lmncell.scenarios.sweep as sw

    monkeypatch.setattr(sw, "_local_cluster", lambda *_a: pytest.fail("a cluster started"))
    (tmp_path / "tiny.csv").write_text("time_s,speed_kmh\n0,0\n0.1,10\n")
    args = [str(tmp_path / "tiny.csv") if a == "TINY" else a for a in args]
    assert main(["sweep", str(native_fmu), "--out", str(tmp_path / "r.csv"), *args]) == 2
    assert message in capsys.readouterr().err


def test_a_scheduler_address_that_answers_nothing_is_named(native_fmu, tmp_path,
                                                           capsys) -> None:
    """(It raised a ValueError or, after dask's timeout, an OSError traceback.)"""
    assert main(["sweep", str(native_fmu), "--out", str(tmp_path / "r.csv"), "--scheduler",
                 "nonsense"]) == 2
    assert ("--scheduler 'nonsense': cannot connect to a Dask scheduler there"
            in capsys.readouterr().err)


def test_parquet_without_an_engine_is_refused_before_the_run(tmp_path, monkeypatch) -> None:
    import importlib.util

    from lmncell.scenarios.sweep import check_table_path

    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(DataError, match="writing Parquet needs pyarrow or fastparquet"):
        check_table_path(tmp_path / "r.parquet")
    assert check_table_path(tmp_path / "r.csv") == tmp_path / "r.csv"


def test_a_sweep_without_the_sweep_extra_says_how_to_install_it(native_fmu, tmp_path,
                                                                 capsys, monkeypatch) -> None:
    """A plain `pip install -e .` has no Dask and no pandas: `lmncell sweep` ended in a
    ModuleNotFoundError traceback."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("pandas", "dask") else real(name, *a))
    assert main(["sweep", str(native_fmu), "--out", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert "not installed: dask, pandas; expected the sweep extra: pip install -e '.[sweep]'" in err
    assert "Traceback" not in err and not (tmp_path / "r.csv").exists()
    with pytest.raises(DataError, match="not installed: dask, pandas"):
        sweep(native_fmu, scenarios(["wltc"], [25.0], [0.9]))


def test_cli_writes_table_and_plots(native_fmu, tmp_path, capsys) -> None:
    import pandas as pd

    out = tmp_path / "r.csv"
    assert main(["sweep", str(native_fmu), "--cycles", "us06", "--ambient", "0,25",
                 "--soc0", "0.8", "--workers", "1", "--out", str(out),
                 "--plot", str(tmp_path / "plots")]) == 0
    text = out.read_text().splitlines()
    assert len(text) == 3 and text[0].startswith("cycle,vehicle")
    # numbers as short as reads back exactly (a fixed 17 digits wrote 0.80000000000000004)
    assert text[1].split(",")[3:5] == ["0.0", "0.8"]
    table = sweep(native_fmu, scenarios(["us06"], [0.0, 25.0], [0.8]), workers=1,
                  progress=False)
    back = pd.read_csv(out)
    for column in ("voltage_min_v", "soc_end", "distance_km", "cell_energy_wh"):
        assert (back[column].to_numpy() == table[column].to_numpy()).all(), column
    assert (tmp_path / "plots" / "sweep_voltage_min_v.png").exists()
    assert (tmp_path / "plots" / "sweep_distance_km.png").exists()


def test_pack_scenarios_with_spread(native_fmu) -> None:
    cases = scenarios(["us06"], [25.0], [0.9, 0.5], pack="12s3p",
                      spread="capacity=0.03,resistance=0.1", seed=4)
    one = sweep(native_fmu, cases, workers=1, progress=False)
    two = sweep(native_fmu, cases, workers=2, progress=False)
    cols = [c for c in one.columns if c != "wall_s"]
    assert one[cols].equals(two[cols])
    assert list(one["pack"]) == ["12s3p", "12s3p"]
    assert (one["soc_end_min"] < one["soc_end"]).all()      # the weakest cell is lower
    same = sweep(native_fmu, scenarios(["us06"], [25.0], [0.9], pack="12s3p",
                                       spread="capacity=0.03,resistance=0.1", seed=4),
                 workers=1, progress=False)
    assert same.loc[0, "voltage_min_v"] == one.loc[0, "voltage_min_v"]   # seeded


def test_pythonfmu_fmu_sweeps_too(quick_fmu) -> None:
    cases = scenarios(["us06"], [25.0], [0.9])
    table = sweep(quick_fmu, cases, workers=1, progress=False)
    single = run_cycle(quick_fmu, "us06", cases[0].vehicle, 1, 0.9, temperature_c=25.0).figures
    assert table.loc[0, "voltage_min_v"] == single["voltage_min_v"]
    assert table.loc[0, "soc_end"] == single["soc_end"]


def test_a_sample_string_of_cells_carries_the_cell_current(native_fmu) -> None:
    """--cells N: N cells in series with spread, each with the vehicle pack's cell current;
    without spread every cell is the one cell that the FMU run simulates (its current delay
    included; before, the string took the current undelayed and agreed within 5 mV only)."""
    cases = scenarios(["us06"], [25.0], [0.9], cells=5, spread="capacity=0.0,resistance=0.0")
    string = sweep(native_fmu, cases, workers=1, progress=False)
    single = run_cycle(native_fmu, "us06", cases[0].vehicle, 1, 0.9, temperature_c=25.0)
    assert string.loc[0, "pack"] == "5s1p"
    for figure in ("soc_end", "voltage_min_v", "voltage_max_v", "cell_temperature_max_c"):
        assert string.loc[0, figure] == pytest.approx(single.figures[figure], abs=1e-9), figure
    assert string.loc[0, "distance_km"] == pytest.approx(single.figures["distance_km"])


def test_step_means_keep_the_cycles_energy_at_any_step() -> None:
    """A step inside one 1-s sample holds that sample; a coarser or uneven step takes the mean
    over what it covers (it used to take the sample at its start: UDDS at 100 s steps ended
    the cycle at SoC 85.7 % where 1 s steps end at 87.1 %)."""
    from lmncell.scenarios.drive import step_means

    values = np.array([1.0, 3.0, -2.0, 6.0, 0.5])
    assert step_means(values, 1.0, 1.0, 5).tolist() == values.tolist()
    assert step_means(values, 1.0, 0.25, 20).tolist() == np.repeat(values, 4).tolist()
    assert step_means(values, 1.0, 2.0, 2).tolist() == [2.0, 2.0]
    assert step_means(values, 1.0, 2.5, 2) == pytest.approx([(1 + 3 - 1) / 2.5,
                                                              (-1 + 6 + 0.5) / 2.5])
    assert step_means(values, 1.0, 5.0, 1) == pytest.approx([values.mean()])


def test_coarse_steps_drive_the_same_charge_and_a_step_longer_than_the_cycle_is_refused(
        native_fmu, capsys) -> None:
    fine = run_cycle(native_fmu, "udds", step_s=1.0).figures
    assert fine["unrun_s"] == 0.0
    for h, unrun in ((100.0, 70.0), (1369.0, 1.0)):
        coarse = run_cycle(native_fmu, "udds", step_s=h).figures
        assert coarse["soc_end"] == pytest.approx(fine["soc_end"], abs=1e-3), h   # was 0.014 off
        assert coarse["distance_km"] == pytest.approx(fine["distance_km"], rel=0.03), h
        assert coarse["unrun_s"] == pytest.approx(unrun)    # the end no whole step covers
    assert main(["simulate", str(native_fmu), "--cycle", "udds", "--step", "100"]) == 0
    assert ("note: the last 70 s of the cycle, shorter than one communication step of 100 s, "
            "were not run (--step sets it)") in capsys.readouterr().out
    assert main(["simulate", str(native_fmu), "--cycle", "udds", "--step", "1400"]) == 2
    assert ("communication step 1400 s: longer than the UDDS cycle (1370 s); expected at most "
            "1370 s") in capsys.readouterr().err
    # a step so short that the run would take hours (it ran silently, allocating gigabytes)
    assert main(["simulate", str(native_fmu), "--cycle", "udds", "--step", "1e-6"]) == 2
    assert ("communication step 1e-06 s: 1370000000 steps over the UDDS cycle (1370 s), more than "
            "2000000") in capsys.readouterr().err


def test_a_run_stops_where_the_cell_is_empty(native_fmu) -> None:
    """Repeated US06 from SoC 0.3 at 25 °C empties the cell: the run stops after the first step
    whose voltage is below the cut-off (by default the lowest voltage the model was trained on)
    or whose SoC is below 0, and reports why and when; the figures cover the steps up to there.
    Before, the cell was driven on past empty (SoC −470 %, 515 km, on the demo's A123 FMU)."""
    from lmncell.scenarios.drive import shipped_cutoff_v

    cutoff = shipped_cutoff_v(native_fmu)
    assert 2.0 < cutoff < 3.0                    # the Panasonic training records' lowest voltage
    res = run_cycle(native_fmu, "us06", repeat=10, soc0=0.3, temperature_c=25.0)
    f = res.figures
    assert f["stop"] and f["cutoff_v"] == cutoff
    assert f["stopped_at_s"] == res.time_s[-1] < 10 * 600
    empty = (res.voltage_v < cutoff) | (res.soc < 0.0)
    assert empty[-1] and not empty[:-1].any()
    assert f["voltage_min_v"] == res.voltage_v.min() and f["soc_end"] == res.soc[-1]
    same = run_cycle(native_fmu, "us06", repeat=10, soc0=0.3, temperature_c=25.0,
                     cutoff_v=cutoff).figures
    assert same == f
    # without a cut-off voltage the run goes on until the SoC or the voltage falls below 0
    on = run_cycle(native_fmu, "us06", repeat=10, soc0=0.3, temperature_c=25.0, cutoff_v=0.0)
    beyond = (on.voltage_v < 0.0) | (on.soc < 0.0)
    assert on.figures["stop"] and beyond[-1] and not beyond[:-1].any()
    assert on.time_s.size > res.time_s.size


def test_a_pack_stops_where_its_weakest_cell_is_empty(quick_model) -> None:
    """The vectorised pack stops at the step where its weakest cell crosses the cut-off."""
    from lmncell.runtime.model import load_model
    from lmncell.scenarios.pack import PackSpec, drive_pack

    model = load_model(quick_model)
    spec = PackSpec(2, 1, capacity_spread=0.05, seed=3)
    power = np.full(4000, 2 * 3.6 * 2.85)           # about 1 C per cell for 4000 s
    f = drive_pack(model, spec, power, 25.0, 0.5, cutoff_v=3.0)
    assert "below the cut-off 3.000 V" in f["stop"] and f["voltage_min_v"] < 3.0
    assert f["steps"] < 4000 and f["stopped_at_s"] == f["steps"] * model.sample_time_s
    longer = drive_pack(model, spec, power[: f["steps"] - 1], 25.0, 0.5, cutoff_v=3.0)
    assert longer["stop"] == "" and longer["voltage_min_v"] >= 3.0
    # charging: the run stops where a cell's SoC passes 1, as a single cell's run does
    full = drive_pack(model, spec, -power, 25.0, 0.5)
    assert full["stop"] == "SoC above 100 %" and full["steps"] < 4000


@pytest.mark.parametrize("change, message", [
    (("mass_kg = 1600.0 ", 'mass_kg = "heavy"'), "'mass_kg' = 'heavy'; expected a finite number"),
    (("n_series = 100", "n_series = 100.5"), "'n_series' = 100.5; expected a whole number"),
    (("rolling_resistance = 0.009", "rolling_resistance = nan"),
     "'rolling_resistance' = nan; expected a finite number"),
    (("mass_kg = 1600.0 ", "mass_g = 1600.0 "),
     "unknown key(s) ['mass_g']; missing key(s) ['mass_kg']"),
    (("[pack]", "[battery]"), "no [pack] table"),
    (("[vehicle]", "[vehicle"), "not a TOML file"),
    # physically impossible values drove runs that made energy from nothing
    (("rolling_resistance = 0.009", "rolling_resistance = -0.01"),
     "'rolling_resistance' = -0.01; expected ≥ 0"),
    (("auxiliary_power_w = 500.0", "auxiliary_power_w = -500.0"),
     "'auxiliary_power_w' = -500.0; expected ≥ 0"),
    (("regen_power_limit_w = 40000.0", "regen_power_limit_w = -1.0"),
     "'regen_power_limit_w' = -1.0; expected ≥ 0"),
    (("rotational_inertia_factor = 1.05", "rotational_inertia_factor = 0.5"),
     "'rotational_inertia_factor' = 0.5; expected ≥ 1 (rotating parts add to the mass)"),
    (("air_density_kg_m3 = 1.2", "air_density_kg_m3 = -1.2"),
     "'air_density_kg_m3' = -1.2; expected > 0"),
    (("regen_efficiency = 0.70", "regen_efficiency = 1.5"),
     "'regen_efficiency' = 1.5; expected 0 ≤ η ≤ 1 (0: no regenerative braking)"),
    (("drivetrain_efficiency = 0.90", "drivetrain_efficiency = 0"),
     "'drivetrain_efficiency' = 0; expected 0 < η ≤ 1"),
])
def test_a_vehicle_file_is_checked_key_by_key(tmp_path, change, message) -> None:
    """A string mass raised a TypeError traceback, a string coefficient a numpy one, and a
    pack of 100.5 cells in series was simulated."""
    from importlib import resources

    from lmncell.scenarios.drive import load_vehicle

    text = resources.files("lmncell.scenarios").joinpath("vehicles/compact_ev.toml").read_text()
    assert change[0] in text
    path = tmp_path / "v.toml"
    path.write_text(text.replace(change[0], change[1], 1))
    with pytest.raises(DataError) as err:
        load_vehicle(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)
    assert load_vehicle(None).n_series == 100


def test_a_vehicle_file_without_a_name_takes_the_files(tmp_path) -> None:
    """A vehicle file without `name` was refused as "missing key(s) ['name']"; the name is
    optional, and the file's name stands for it."""
    from importlib import resources

    from lmncell.scenarios.drive import load_vehicle

    text = resources.files("lmncell.scenarios").joinpath("vehicles/compact_ev.toml").read_text()
    path = tmp_path / "my_car.toml"
    path.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith("name")))
    assert load_vehicle(path).name == "my_car"
    assert load_vehicle(None).name == "compact EV (default)"
    # a byte-order mark (Windows editors) is skipped; other bytes than UTF-8 are named
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert load_vehicle(path).mass_kg == load_vehicle(None).mass_kg
    path.write_bytes(text.encode() + b"\n# caf\xe9\n")
    with pytest.raises(DataError, match="my_car.toml: cannot read the vehicle file \\(not UTF-8"):
        load_vehicle(path)


def test_a_vehicle_without_regenerative_braking_is_driven(tmp_path) -> None:
    """regen_efficiency = 0, a car that brakes by friction alone, was refused as "expected
    0 < η ≤ 1"; it now runs, and its pack never charges: the same power as a regen limit of
    0 W, the auxiliaries' at the least."""
    from importlib import resources

    from lmncell.scenarios.drive import load_vehicle, pack_power
    from lmncell.scenarios.traces import load_cycle

    text = resources.files("lmncell.scenarios").joinpath("vehicles/compact_ev.toml").read_text()
    paths = []
    for old, new in (("regen_efficiency = 0.70", "regen_efficiency = 0"),
                     ("regen_power_limit_w = 40000.0", "regen_power_limit_w = 0.0")):
        paths.append(tmp_path / f"{len(paths)}.toml")
        paths[-1].write_text(text.replace(old, new, 1))
    cycle = load_cycle("us06")
    none, limited, default = (pack_power(load_vehicle(p), cycle.speed_mps, cycle.grade,
                                         cycle.step_s) for p in (*paths, None))
    aux = load_vehicle(None).auxiliary_power_w
    assert np.array_equal(none, limited) and none.min() == aux > default.min()


def _write_us06_as(path, header: str, delimiter: str = ",", factor: float = 1.0) -> None:
    """The shipped US06 written as a user's trace: time_s, speed × factor, grade."""
    from lmncell.scenarios.traces import load_cycle

    trace = load_cycle("us06")
    rows = [delimiter.join(header.split(","))]
    rows += [delimiter.join((f"{t + 100.0:g}", repr(float(v) * factor), f"{g:g}"))
             for t, v, g in zip(trace.time_s, trace.speed_mps, trace.grade, strict=True)]
    path.write_text("\n".join(rows) + "\n")


def test_a_speed_trace_file_drives_the_fmu_as_the_shipped_cycle(native_fmu, tmp_path,
                                                                 capsys) -> None:
    """`--cycle FILE.csv` (and `--cycles` of a sweep): the shipped US06 written in km/h with ';'
    between the columns, starting at 100 s, drives the FMU as `--cycle us06` does."""
    shipped = run_cycle(native_fmu, "us06").figures
    path = tmp_path / "my_us06.csv"
    _write_us06_as(path, "Time_s,speed_kmh,grade", ";", 3.6)
    mine = run_cycle(native_fmu, str(path)).figures
    assert mine.pop("cycle") == "my_us06.csv"
    shipped.pop("cycle")
    assert mine.keys() == shipped.keys()
    for key, value in shipped.items():          # km/h to m/s: the last digit may differ
        if isinstance(value, float):
            assert mine[key] == pytest.approx(value, rel=1e-12), key
        else:
            assert mine[key] == value, key
    assert main(["simulate", str(native_fmu), "--cycle", str(path)]) == 0
    assert capsys.readouterr().out.startswith("my_us06.csv x1 at 1.0 s steps: 12.9 km")
    wide = tmp_path / "my_us06_utf16.csv"                 # Excel's "Unicode text"
    wide.write_text(path.read_text(), encoding="utf-16")
    assert run_cycle(native_fmu, str(wide)).figures["soc_end"] == mine["soc_end"]
    units = tmp_path / "units.csv"                # the units in brackets (was: no time column)
    _write_us06_as(units, "Time [s],Speed (km/h),Grade", ",", 3.6)
    assert run_cycle(native_fmu, str(units)).figures["soc_end"] == mine["soc_end"]
    with pytest.raises(DataError, match="units.csv: a vehicle speed trace"):
        read_record(units)
    cases = scenarios([str(path), "us06"], [25.0], [0.9])
    table = sweep(native_fmu, cases, workers=1, progress=False)
    assert list(table["cycle"]) == ["my_us06.csv", "us06"]
    assert table.loc[0, "soc_end"] == pytest.approx(table.loc[1, "soc_end"], rel=1e-12)


@pytest.mark.parametrize("text, message", [
    ("time_s,speed_kmh\n0,0\n\n1,abc\n", "column 'speed_kmh' at line 4: 'abc'; expected a number"),
    ("time_s,speed_kmh\n0,0\n1,1\n3,2\n4,3\n",
     "column 'time_s' at line 4: 1 s then 3 s; expected times rising in even steps"),
    ("time_s,speed_kmh\n0,0\n1,1\n0,2\n", "column 'time_s' at line 4: 1 s then 0 s"),
    ("time_s,speed_mps\n0,0\n1,-1\n", "column 'speed_mps' at line 3: -1; expected 0…100 m/s"),
    ("time_s,speed_kmh\n0,0\n1,400\n", "column 'speed_kmh' at line 3: 400; expected 0…360 km/h"),
    ("time_s,speed_mps,grade\n0,0,0\n1,1,5\n",
     "column 'grade' at line 3: 5; expected -0.5…0.5 (rise over run, not % or degrees)"),
    ("time_s,speed_mph\n0,0\n1,nan\n", "column 'speed_mph' at line 3: nan; expected a finite"),
    ("t,v\n0,0\n1,1\n", "no time and no speed column in the header ['t', 'v']"),
    ("time_s,speed_kmh,speed_mps\n0,0,0\n1,1,1\n", "2 speed columns ['speed_kmh', 'speed_mps']"),
    ("time_s,speed_kmh\n0,0\n", "1 sample(s); expected at least two"),
    ("", "empty; expected a CSV with a header"),
])
def test_a_bad_speed_trace_file_is_named_with_line_column_and_value(
        native_fmu, tmp_path, capsys, text, message) -> None:
    path = tmp_path / "trace.csv"
    path.write_text(text)
    assert main(["simulate", str(native_fmu), "--cycle", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: {message}" in err and "Traceback" not in err
    assert main(["sweep", str(native_fmu), "--cycles", f"us06,{path}", "--out",
                 str(tmp_path / "r.csv")]) == 2
    assert f"{path}: {message}" in capsys.readouterr().err


def test_a_cycle_that_is_neither_a_name_nor_a_file_is_refused(native_fmu, tmp_path,
                                                              capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(native_fmu), "--cycle", "nedc"])
    assert exc.value.code == 2
    assert ("--cycle: 'nedc': neither one of ['udds', 'us06', 'hwfet', 'wltc'] nor a "
            "speed-trace file; expected a cycle name or a CSV") in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["simulate", str(native_fmu), "--cycle", str(tmp_path)])
    assert "nor a speed-trace file (it is a folder)" in capsys.readouterr().err


def test_a_current_profile_drives_the_fmu_as_the_cycle_that_gave_it(native_fmu, tmp_path,
                                                                     capsys) -> None:
    """`lmncell simulate --current FILE.csv`: the cell currents of a US06 run, written as a
    profile (in A, and in mA with discharge positive and ';'), give that run's voltages and
    SoC step for step."""
    from lmncell.scenarios.drive import run_profile

    cycle = run_cycle(native_fmu, "us06", soc0=0.7)
    amps, milli = tmp_path / "us06_current.csv", tmp_path / "us06_ma.csv"
    amps.write_text("time_s,current_a\n" + "".join(
        f"{k},{float(i)!r}\n" for k, i in enumerate(cycle.current_a)))
    milli.write_text("Time_s;Current_mA\n" + "".join(
        f"{k};{-1000 * float(i)!r}\n" for k, i in enumerate(cycle.current_a)))
    minutes = tmp_path / "us06_min.csv"           # units in brackets (was: no time column)
    minutes.write_text("Time [min],Current [mA]\n" + "".join(
        f"{k / 60!r},{1000 * float(i)!r}\n" for k, i in enumerate(cycle.current_a)))
    for res in (run_profile(native_fmu, amps, soc0=0.7),
                run_profile(native_fmu, milli, soc0=0.7, discharge_positive=True),
                run_profile(native_fmu, minutes, soc0=0.7)):
        assert res.speed_mps is None
        assert np.allclose(res.current_a, cycle.current_a, rtol=1e-12, atol=0)
        assert np.allclose(res.voltage_v, cycle.voltage_v, rtol=1e-9, atol=0)
        assert np.allclose(res.soc, cycle.soc, rtol=1e-9, atol=0)
    assert res.figures["ah_throughput"] == pytest.approx(cycle.figures["ah_throughput"])
    plot = tmp_path / "profile.png"
    assert main(["simulate", str(native_fmu), "--current", str(amps), "--soc0", "0.7",
                 "--plot", str(plot)]) == 0
    assert capsys.readouterr().out.startswith("us06_current.csv x1 at 1.0 s steps: 601 s")
    assert plot.stat().st_size > 10_000


def test_a_table_of_breakpoints_drives_the_fmu_as_its_even_steps(native_fmu, tmp_path) -> None:
    """A current profile written as breakpoints (uneven times; a time given twice steps there;
    the last row ends it; the column named just `current`) runs as the same currents written
    out at even steps; times that fall are refused by line."""
    from lmncell.scenarios.drive import run_profile
    from lmncell.scenarios.traces import load_current_profile

    table = tmp_path / "pulses.csv"
    table.write_text("time,current\n0,-3\n20,-3\n20,0\n50,1.5\n57.5,0\n90,0\n")
    prof = load_current_profile(table)
    assert prof.step_s == pytest.approx(2.5) and prof.time_s[-1] == pytest.approx(87.5)
    even = tmp_path / "even.csv"
    amps = [-3.0] * 8 + [0.0] * 12 + [1.5] * 3 + [0.0] * 13
    even.write_text("time_s,current_a\n" + "".join(f"{2.5 * k},{a}\n" for k, a in enumerate(amps)))
    assert np.array_equal(prof.current_a, amps)
    ran, expected = run_profile(native_fmu, table, soc0=0.7), run_profile(native_fmu, even, soc0=0.7)
    assert np.array_equal(ran.voltage_v, expected.voltage_v) and ran.time_s[-1] == 90.0
    back = tmp_path / "back.csv"
    back.write_text("time_s,current_a\n0,-3\n20,-3\n19,0\n")
    with pytest.raises(DataError, match=r"back.csv: column 'time_s' at line 4: 20 s then 19 s; "
                                        r"expected times that do not fall"):
        load_current_profile(back)


def test_a_profile_from_a_spreadsheet_with_a_decimal_comma_reads_as_written(tmp_path) -> None:
    """A profile saved by a spreadsheet where the decimal mark is a comma (';' between the
    fields, "-2,5" in them) was refused cell by cell ("'-2,5'; expected a number"); a file
    delimited by ';' or tabs now reads a decimal comma, and one delimited by commas still
    refuses it."""
    from lmncell.scenarios.traces import load_current_profile, load_cycle

    for sep in (";", "\t"):
        comma = tmp_path / f"comma{len(sep)}.csv"
        comma.write_text(f"time_s{sep}current_a\n0{sep}-2,5\n0,5{sep}1,25\n1{sep}0\n")
        prof = load_current_profile(comma)
        assert np.array_equal(prof.current_a, [-2.5, 1.25, 0.0]) and prof.step_s == 0.5
    speed = tmp_path / "speed.csv"
    speed.write_text("time_s;speed_kmh\n0;0\n1;3,6\n2;7,2\n")
    assert np.allclose(load_cycle(speed).speed_mps, [0.0, 1.0, 2.0])
    cycler = tmp_path / "cycler.csv"                 # a cycler's names: I [A], I/mA
    for name, scale in (("I [A]", 1.0), ("I/mA", 1000.0)):
        cycler.write_text(f"Time [s];{name}\n0;{-2.5 * scale:g}\n1;0\n".replace(".", ","))
        assert np.array_equal(load_current_profile(cycler).current_a, [-2.5, 0.0])
    quoted = tmp_path / "quoted.csv"
    quoted.write_text('time_s,current_a\n0,"-2,5"\n1,0\n')
    with pytest.raises(DataError, match=r"column 'current_a' at line 2: '-2,5'; expected a number"):
        load_current_profile(quoted)


def test_a_charge_profile_stops_at_the_charge_cut_off_or_full(native_fmu, tmp_path,
                                                               capsys) -> None:
    """A 1C charge stops after the first step above the charge cut-off (by default the highest
    voltage of the model's training records) or, without one, with the SoC above 1."""
    from lmncell.scenarios.drive import run_profile, shipped_cutoff_v

    path = tmp_path / "charge.csv"
    path.write_text("time_s,current_a\n" + "".join(f"{k},2.85\n" for k in range(3600)))
    top = shipped_cutoff_v(native_fmu, "voltage_max_v")
    assert 4.1 < top < 4.3                       # the Panasonic training records' highest
    res = run_profile(native_fmu, path, soc0=0.5)
    assert res.figures["stop"].startswith("cell voltage") and res.figures["charge_cutoff_v"] == top
    assert res.voltage_v[-1] > top and (res.voltage_v[:-1] <= top).all()
    full = run_profile(native_fmu, path, soc0=0.5, charge_cutoff_v=0.0)
    assert full.figures["stop"] == "SoC above 100 %"
    assert full.soc[-1] > 1.0 and (full.soc[:-1] <= 1.0).all()
    assert main(["simulate", str(native_fmu), "--current", str(path), "--soc0", "0.5"]) == 0
    assert ("the cell is full (cell voltage" in capsys.readouterr().out)


def test_a_stop_outside_the_trained_range_is_not_called_an_empty_cell(native_fmu,
                                                                        capsys) -> None:
    """A run that crosses the cut-off while the model is outside its trained range (here a
    −40 °C ambient) says so, with the SoC, instead of "the cell is empty", and so does its
    plot's title; inside it, the cell is empty."""
    args = ["simulate", str(native_fmu), "--cycle", "us06", "--soc0", "0.9", "--cutoff", "3.9"]
    assert main([*args, "--ambient", "-40"]) == 0
    out = capsys.readouterr().out
    from lmncell.scenarios.drive import run_cycle, stop_title

    cold = run_cycle(native_fmu, "us06", soc0=0.9, temperature_c=-40.0, cutoff_v=3.9)
    assert re.fullmatch(r" — stopped at the cut-off after \d+ s, outside the trained range",
                        stop_title(cold))
    assert re.search(r"stopped after \d+ s, [\d.]+ km: cell voltage 3\.\d{3} V below the cut-off "
                     r"3\.900 V at SoC 8\d\.\d %, with the model outside its trained range", out)
    assert "the cell is empty" not in out
    assert main([*args, "--ambient", "27"]) == 0
    assert "the cell is empty (cell voltage" in capsys.readouterr().out
    warm = run_cycle(native_fmu, "us06", soc0=0.9, temperature_c=27.0, cutoff_v=3.9)
    assert re.fullmatch(r" — stopped, the cell empty after \d+ s", stop_title(warm))


def test_a_cut_off_beyond_the_model_s_voltages_is_refused(native_fmu, tmp_path, capsys) -> None:
    """A discharge cut-off at or above the highest voltage the model was trained on (or a
    charge cut-off at or below the lowest) would end every run at its first step: simulate
    and sweep refuse it, naming the option and the model's own cut-off. Before, --cutoff 5
    ran and reported "the cell is empty" after 1 s."""
    profile = tmp_path / "p.csv"
    profile.write_text("time_s,current_a\n0,1\n1,1\n2,1\n")
    cases = [(["simulate", str(native_fmu), "--cycle", "wltc", "--cutoff", "5"],
              r"--cutoff 5 V: at or above the highest voltage of the model's training records "
              r"\(4\.\d{3} V\), so every run would stop at its first step; expected a discharge "
              r"cut-off below it \(the model's own: 2\.\d{3} V\)"),
             (["simulate", str(native_fmu), "--current", str(profile), "--charge-cutoff", "2"],
              r"--charge-cutoff 2 V: at or below the lowest voltage of the model's training "
              r"records \(2\.\d{3} V\).* expected a charge cut-off above it"),
             (["sweep", str(native_fmu), "--cycles", "wltc", "--ambient", "25", "--soc0", "0.9",
               "--cutoff", "4.5", "--workers", "1", "--out", str(tmp_path / "r.csv")],
              r"--cutoff 4\.5 V: at or above the highest voltage")]
    for args, message in cases:
        assert main(args) == 2
        out = capsys.readouterr()
        assert re.search(message, out.err) and "scenario(s) on" not in out.out
    assert not (tmp_path / "r.csv").exists()
    assert main(["simulate", str(native_fmu), "--cycle", "wltc", "--cutoff", "3"]) == 0


def test_simulate_says_what_left_the_trained_range(fmu, capsys) -> None:
    """The warning names what the FMU's first out-of-range warning names (before, it said 'see
    the FMU log', which the command never showed): here the ambient 60 °C, beyond the
    temperatures the model was trained at; both FMUs name it alone (the native one listed
    current, SoC, temperature and voltage with an 'or' before), in the same ASCII words (the
    pythonfmu one wrote °C and … before)."""
    from lmncell.scenarios.drive import run_cycle

    res = run_cycle(fmu, "us06", soc0=0.8, temperature_c=60.0)
    first = res.figures["out_of_range_first"]
    assert res.figures["out_of_range_steps"] > 0 and "lmncell-cycle" not in first
    assert re.fullmatch(r"t = 0 s: temperature 60\.\d degC outside the trained "
                        r"\d+\.\d\.\.\d+\.\d degC", first), first
    assert run_cycle(fmu, "us06", soc0=0.8, temperature_c=25.0).figures[
        "out_of_range_first"] is None
    assert main(["simulate", str(fmu), "--cycle", "us06", "--soc0", "0.8", "--ambient",
                 "60"]) == 0
    assert f"; the FMU's first warning: {first}; see the plot" in capsys.readouterr().out


def test_simulate_json_is_json_alone_and_the_plot_is_named(native_fmu, tmp_path,
                                                           capsys) -> None:
    """With --json stdout is the JSON alone (the out-of-range warning went there after it),
    the plot's file is named as written (a name without a suffix gets .png), and a suffix that
    matplotlib cannot write is refused before the run (it raised a traceback after it)."""
    plot = tmp_path / "run"
    assert main(["simulate", str(native_fmu), "--cycle", "us06", "--ambient", "60", "--json",
                 "--plot", str(plot)]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["out_of_range_steps"] > 0
    assert "warning: " in err and f"plot: {plot}.png" in err
    assert (tmp_path / "run.png").exists()
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", str(native_fmu), "--cycle", "us06", "--plot", str(tmp_path / "run.txt")])
    assert exit_info.value.code == 2
    assert "a figure's file name ends in one of" in capsys.readouterr().err
    assert not (tmp_path / "run.txt").exists()


@pytest.mark.parametrize("args, message", [
    (["--current", "p.csv", "--vehicle", "v.toml"], "--vehicle with --current"),
    (["--discharge-positive"], "--discharge-positive is for a --current profile"),
    (["--charge-cutoff", "4.2"], "--charge-cutoff is for a --current profile"),
    (["--current", "nope.csv"], "nope.csv: no such file; expected a CSV with a header: a time "
                                "column (time_s) and a cell current column"),
])
def test_simulate_options_that_do_not_go_together_are_named(native_fmu, capsys, args,
                                                           message) -> None:
    assert main(["simulate", str(native_fmu), *args]) == 2
    assert message in capsys.readouterr().err


def test_a_sweep_says_which_runs_stopped_with_a_cell_full(native_fmu, tmp_path,
                                                          capsys) -> None:
    """Downhill from SoC 0.999 the regeneration fills the cell: that run stops, and the
    summary tells it apart from runs that ended empty."""
    trace = tmp_path / "downhill.csv"
    trace.write_text("time_s,speed_kmh,grade\n" + "".join(f"{k},50,-0.2\n" for k in range(600)))
    out = tmp_path / "r.csv"
    assert main(["sweep", str(native_fmu), "--cycles", str(trace), "--soc0", "0.999,0.5",
                 "--workers", "1", "--out", str(out)]) == 0
    assert ("1 scenario(s) stopped early: 1 with a cell full (columns stop, stopped_at_s)"
            in capsys.readouterr().out)
    header, first = out.read_text().splitlines()[:2]
    assert first.split(",")[header.split(",").index("stop")] == "SoC above 100 %"


def test_a_sweep_warns_of_scenarios_outside_the_trained_range(native_fmu, tmp_path,
                                                            capsys) -> None:
    """The quick model knows the cell near 25 °C: a sweep at 60 °C ambient extrapolates, and
    the summary says which scenarios did; at 25 °C it says nothing."""
    out = tmp_path / "r.csv"
    args = ["sweep", str(native_fmu), "--cycles", "us06", "--soc0", "0.8", "--workers", "1",
            "--out", str(out)]
    assert main([*args, "--ambient", "25"]) == 0
    assert "trained range" not in capsys.readouterr().out
    assert main([*args, "--ambient", "25,60"]) == 0
    assert ("warning: 1 of 2 scenario(s) left the model's trained range (current, SoC, "
            "temperature or its voltage) in some step, at ambient 60 °C (column "
            "out_of_range_steps)" in capsys.readouterr().out)


def test_a_step_the_fmu_refuses_is_named_and_a_sweep_keeps_its_other_rows(native_fmu, quick_fmu,
                                                                          tmp_path,
                                                                          capsys) -> None:
    """A current no cell carries (a pack of one cell in the vehicle) makes the FMU return
    fmi2Error with a logged reason. `simulate` ended in fmpy's FMICallException traceback;
    it now says what the FMU logged. A sweep marks that row and keeps the others."""
    from lmncell.scenarios.drive import FmuStepError, run_profile

    profile = tmp_path / "huge.csv"
    profile.write_text("time_s,current_a\n0,-1e4\n1,-1e4\n2,0\n")
    for fmu in (native_fmu, quick_fmu):
        with pytest.raises(FmuStepError, match=r"the FMU refused the step at t = 0 s with the "
                                               r"cell current -10000 A: .*input 'current' = "
                                               r"-10000(\.0)? A: beyond 1000 C") as err:
            run_profile(fmu, profile)
        assert err.value.t_s == 0.0 and "PyObject_CallMethod" not in str(err.value)
    assert main(["simulate", str(native_fmu), "--current", str(profile)]) == 2
    assert "Traceback" not in capsys.readouterr().err
    tiny = tmp_path / "tiny.toml"
    shipped = (Path(__file__).resolve().parents[1] / "training/scenarios/vehicles/compact_ev.toml")
    tiny.write_text(shipped.read_text().replace("n_series = 100", "n_series = 1")
                    .replace("n_parallel = 40", "n_parallel = 1"))
    downhill = tmp_path / "downhill.csv"        # regeneration of kilowatts into one cell
    downhill.write_text("time_s,speed_kmh,grade\n"
                        + "".join(f"{k},50,-0.2\n" for k in range(60)))
    table = sweep(native_fmu, scenarios([str(downhill)], [25.0], [0.5], [str(tiny), None]),
                  workers=1, progress=False)
    assert table.loc[0, "stop"].startswith("error: the FMU refused the step at t = ")
    assert np.isnan(table.loc[0, "voltage_min_v"]) and table.loc[1, "stop"] == ""
    assert table.loc[1, "voltage_max_v"] > 3.5


def test_other_instances_log_safely_after_a_run_with_the_kept_log(native_fmu, quick_fmu,
                                                                  tmp_path) -> None:
    """fmpy's native logger proxy keeps one Python logger per process, for every instance,
    fmpy's default ones included. A run's logger that was freed afterwards left that pointer
    dangling, and the next instance with fmpy's default callbacks to log an error crashed
    the process (a segmentation fault in the full test run). Run in a subprocess: a crash
    there fails this test instead of the whole session."""
    import subprocess
    import sys

    profile = tmp_path / "huge.csv"
    profile.write_text("time_s,current_a\n0,-1e4\n1,0\n")
    script = f"""
import gc, math, sys
sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
from lmncell.scenarios.drive import FmuStepError, run_profile
for fmu in ({str(native_fmu)!r}, {str(quick_fmu)!r}):
    try:
        run_profile(fmu, {str(profile)!r})
    except FmuStepError:
        pass
gc.collect()
from tests.fmu_helpers import Instance
inst = Instance({str(quick_fmu)!r}, start={{"soc0": 0.8}})
try:
    inst.step(math.nan)
except Exception:
    pass
inst.free()
print("survived")
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "survived" in out.stdout
    assert "input 'current' = nan" in out.stdout        # printed as fmpy's default logger does


def test_workers_that_do_not_start_say_the_usual_cause() -> None:
    """A script that calls lmncell.sweep without the `__main__` guard makes Dask's workers fail
    with "Nanny failed to start"; the error then says what to do."""
    from lmncell.scenarios.sweep import _local_cluster

    class FailingCluster:
        def __init__(self, **_kwargs) -> None:
            raise RuntimeError("Nanny failed to start.")

    with pytest.raises(RuntimeError, match=r"Nanny failed to start\.\)\. A script that calls "
                                           r"lmncell.sweep must call it under `if __name__"):
        _local_cluster(FailingCluster, 1)


def test_a_users_mistake_found_on_a_worker_is_raised_not_logged_as_a_failed_task(
        native_fmu, monkeypatch, caplog) -> None:
    """A DataError inside a scenario's run comes back to sweep, which raises it; the worker
    does not log "Compute Failed" with a traceback ahead of it (as it did where --repeat was
    too large, before check_steps)."""
    import lmncell.scenarios.sweep as sw
    from dask.distributed import Client
    from lmncell.data.records import DataError

    def refused(_fmu_bytes, sc):
        raise DataError(f"the {sc.cycle.title} cycle: refused on the worker")

    monkeypatch.setattr(sw, "run_scenario", refused)
    cases = sw.scenarios(["udds"], [25.0], [0.9])
    with (Client(processes=False, n_workers=1, threads_per_worker=1,
                 dashboard_address=None) as client,
          pytest.raises(DataError, match="the UDDS cycle: refused on the worker")):
        sw.sweep(native_fmu, cases, client=client, progress=False)
    logged = [r.getMessage() for r in caplog.records if r.name.startswith("distributed")]
    assert not [m for m in logged if "Compute Failed" in m], logged


@pytest.mark.parametrize("lists, message", [
    ((["wltc", "udds", "wltc"], [25.0], [0.9]), "--cycles names 'wltc' twice"),
    ((["wltc"], [25.0, 10.0, 25], [0.9]), "--ambient names 25 twice"),
    ((["wltc"], [25.0], [0.9, 0.9]), "--soc0 names 0.9 twice"),
])
def test_a_value_named_twice_in_a_list_is_refused(lists, message) -> None:
    """`sweep --ambient 25,25` ran every scenario twice and counted both in the summaries."""
    from lmncell.scenarios.sweep import scenarios

    with pytest.raises(DataError, match=rf"sweep: {message}; expected each value once"):
        scenarios(*lists)
    assert len(scenarios(["wltc", "udds"], [25.0, 10.0], [0.9, 0.5])) == 8


def test_simulate_starts_a_cell_colder_or_warmer_than_its_ambient(native_fmu, a123_model,
                                                                   tmp_path, capsys) -> None:
    """--cell-temperature-start: the cell starts there and tends towards its ambient (the
    figures and the run line say so); refused by the FMU where the model has no thermal model,
    with the FMU's own words."""
    from lmncell.fmu.native_build import build_native_fmu

    assert main(["simulate", str(native_fmu), "--cycle", "us06", "--ambient", "0",
                 "--cell-temperature-start", "25", "--json"]) == 0
    warm = json.loads(capsys.readouterr().out)
    assert main(["simulate", str(native_fmu), "--cycle", "us06", "--ambient", "0",
                 "--json"]) == 0
    cold = json.loads(capsys.readouterr().out)
    assert warm["cell_temperature_start_c"] == 25.0 and cold["cell_temperature_start_c"] is None
    assert warm["cell_temperature_max_c"] > 20.0 > 5.0 > cold["cell_temperature_max_c"]
    assert warm["cell_energy_wh"] != cold["cell_energy_wh"]
    assert main(["simulate", str(native_fmu), "--cycle", "us06", "--cell-temperature-start",
                 "30"]) == 0
    assert "(from 30 °C at the start)" in capsys.readouterr().out
    no_thermal = build_native_fmu(a123_model, tmp_path / "a123.fmu")
    assert main(["simulate", str(no_thermal), "--cycle", "us06", "--cell-temperature-start",
                 "30"]) == 2
    assert ("the FMU refused its parameters: parameter 'use_cell_temperature_start' = true: "
            "this model has no thermal model") in capsys.readouterr().err


def test_a_sweep_starts_its_cells_colder_or_warmer_than_their_ambient(
        native_fmu, a123_model, tmp_path, capsys) -> None:
    """--cell-temperature-start: each row (one cell through the FMU, or a sample string of cells
    on the vectorised runtime) equals the single run from that start, and the table says the
    start; refused before any worker starts, with the FMU's words, where the FMU would refuse
    it."""
    import lmncell
    import pandas as pd
    from lmncell.fmu.native_build import build_native_fmu

    cases = scenarios(["us06"], [0.0], [0.9], cell_temperature_start_c=25.0)
    table = lmncell.sweep(native_fmu, "us06", 0.0, 0.9, workers=1, progress=False,
                          cell_temperature_start_c=25.0)
    warm = run_cycle(native_fmu, "us06", cases[0].vehicle, 1, 0.9, temperature_c=0.0,
                     cell_temperature_start_c=25.0).figures
    cold = run_cycle(native_fmu, "us06", cases[0].vehicle, 1, 0.9, temperature_c=0.0).figures
    for key in ("voltage_min_v", "soc_end", "cell_energy_wh", "cell_temperature_max_c"):
        assert table.loc[0, key] == warm[key], key
    assert warm["cell_temperature_max_c"] > 20.0 > 5.0 > cold["cell_temperature_max_c"]
    assert table.loc[0, "cell_temperature_start_c"] == 25.0
    string = sweep(native_fmu, scenarios(["us06"], [0.0], [0.9], cells=3,
                                         spread="capacity=0.0,resistance=0.0",
                                         cell_temperature_start_c=25.0),
                   workers=1, progress=False)
    for key in ("voltage_min_v", "soc_end", "cell_temperature_max_c"):
        assert string.loc[0, key] == pytest.approx(warm[key], abs=1e-9), key
    out = tmp_path / "r.csv"
    assert main(["sweep", str(native_fmu), "--cycles", "us06", "--ambient", "0",
                 "--cell-temperature-start", "25", "--workers", "1", "--out", str(out),
                 "--plot", str(tmp_path / "plots")]) == 0
    assert pd.read_csv(out).loc[0, "cell_temperature_start_c"] == 25.0
    assert ", cells from 25 °C at the start" in capsys.readouterr().out
    assert (tmp_path / "plots" / "sweep_soc_end.png").exists()
    no_thermal = build_native_fmu(a123_model, tmp_path / "a123.fmu")
    assert main(["sweep", str(no_thermal), "--cycles", "us06", "--cell-temperature-start", "30",
                 "--workers", "1", "--out", str(tmp_path / "n.csv")]) == 2
    assert (f"sweep: --cell-temperature-start 30: {no_thermal} would refuse it: parameter "
            "'use_cell_temperature_start' = true: this model has no thermal model"
            ) in capsys.readouterr().err
    assert not (tmp_path / "n.csv").exists()
    with pytest.raises(DataError, match=r"--cell-temperature-start 400\.0: expected a "
                                        r"temperature in °C within -60…100"):
        scenarios(["us06"], [0.0], [0.9], cell_temperature_start_c=400.0)
