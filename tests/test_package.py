"""The package a newcomer installs: one import name, the Python API, own CSV data through the
command line, clear errors for files that are not data."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from lmncell.cli import build_parser, main, read_options
from lmncell.data.readers import read_record, write_bdf

from tests.conftest import A123_S1, PAN_US06

HEADER = "Zeit [s];Strom [mA];Spannung [V];Zelltemp [°C]\n"


def _user_csv(path: Path, time_s, current_a, voltage_v, temp_c) -> Path:
    """A cycler export as some testers write it: made-up column names, ';' separators, decimal
    commas, current in mA and discharge counted positive."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(HEADER)
        for t, i, u, c in zip(time_s, current_a, voltage_v, temp_c, strict=True):
            cells = [repr(float(t)), repr(float(-1000.0 * i)), repr(float(u)), repr(float(c))]
            fh.write(";".join(x.replace(".", ",") for x in cells) + "\n")
    return path


@pytest.fixture()
def user_data(tmp_path):
    rng = np.random.default_rng(3)
    n = 600
    t = np.arange(n) * 1.0
    i = np.round(rng.uniform(-3, 2, n), 3)            # A, > 0 charges (what LMNCell uses)
    u = np.round(3.6 + 0.02 * i + 0.001 * np.cumsum(i) / n, 6)
    c = np.round(25 + 0.004 * t, 3)
    csv_path = _user_csv(tmp_path / "my cycler export.csv", t, i, u, c)
    from lmncell.data.records import Record, RecordMeta

    ref = Record(t, i, u, RecordMeta(source="ref", fmt="bdf", sign_note="none",
                                     sample_time_s=1.0), temperature_c=c)
    bdf = write_bdf(ref, tmp_path / "same.bdf.csv")
    return csv_path, bdf


CLI_OPTIONS = ["--columns", "time=Zeit [s],current=Strom [mA],voltage=Spannung [V],"
               "temperature=Zelltemp [°C]", "--delimiter", ";", "--decimal", ",",
               "--current-unit", "mA", "--discharge-positive"]


def test_own_csv_through_the_cli_equals_the_bdf_record(user_data, capsys) -> None:
    csv_path, bdf = user_data
    args = build_parser().parse_args(["inspect", str(csv_path), *CLI_OPTIONS])
    mine, ref = read_record(csv_path, **read_options(args)), read_record(bdf)
    for name in ("time_s", "current_a", "voltage_v", "temperature_c"):
        np.testing.assert_allclose(getattr(mine, name), getattr(ref, name), rtol=1e-12,
                                   atol=1e-12, err_msg=name)
    assert main(["inspect", str(csv_path), *CLI_OPTIONS]) == 0
    mine_txt = capsys.readouterr().out
    assert main(["inspect", str(bdf)]) == 0
    ref_txt = capsys.readouterr().out

    def figures(text: str) -> list[str]:       # all but the file name and the sign note
        return [ln.split("; sign:")[0] for ln in text.splitlines()[1:]]

    assert figures(mine_txt) == figures(ref_txt)
    assert "current negated (file: discharge > 0)" in mine_txt


def test_own_csv_trains_and_evaluates_from_the_cli(user_data, tmp_path, capsys) -> None:
    csv_path, _ = user_data
    model = tmp_path / "m.json"
    assert main(["train", str(csv_path), *CLI_OPTIONS, "--out", str(model), "--capacity", "2",
                 "--soc0", "0.5", "--set", "max_local_models=1",
                 "--set", "hysteresis=off"]) == 0
    assert main(["evaluate", str(model), str(csv_path), *CLI_OPTIONS, "--soc0", "0.5",
                 "--json"]) == 0
    assert '"rmse_mv"' in capsys.readouterr().out


def test_reader_options_without_columns_and_bad_settings_are_refused(user_data, capsys):
    csv_path, _ = user_data
    assert main(["inspect", str(csv_path), "--decimal", ","]) == 2
    assert "--decimal needs --columns" in capsys.readouterr().err
    assert main(["inspect", str(csv_path), "--decimal", ",", "--time-unit", "ms"]) == 2
    assert "--time-unit, --decimal need --columns" in capsys.readouterr().err
    assert main(["inspect", str(csv_path)]) == 2
    assert "--columns time=COL" in capsys.readouterr().err
    assert main(["train", str(csv_path), *CLI_OPTIONS, "--out", "x.json",
                 "--set", "no_such_setting=1"]) == 2
    assert "unknown setting(s) ['no_such_setting']" in capsys.readouterr().err
    assert main(["inspect", str(csv_path), "--columns", "time=Zeit [s],current=Strom [mA],"
                 "voltage=Spannung [V]", "--delimiter", ";"]) == 2
    err = capsys.readouterr().err
    # the decimal comma not given (the time column, which may be text, is read after the rest)
    assert ("'Strom [mA]' line 2: '2572,0' is not a number (a decimal comma? give the decimal "
            "mark: --decimal ',' or decimal=',')") in err


def test_files_that_are_not_data_give_clear_errors(tmp_path, capsys) -> None:
    binary = tmp_path / "scope.csv"
    binary.write_bytes(bytes(range(256)) * 8)
    assert main(["inspect", str(binary)]) == 2
    assert "scope.csv: not a text file" in capsys.readouterr().err
    assert main(["inspect", str(tmp_path)]) == 2
    assert (f"{tmp_path}: is a directory; expected a data file (give the files inside it: "
            f"{tmp_path}/*.csv (1 file))") in capsys.readouterr().err
    (tmp_path / "runs").mkdir()
    (tmp_path / "b.mat").write_bytes(b"x")
    (tmp_path / "c.mat").write_bytes(b"x")
    assert main(["inspect", str(tmp_path)]) == 2
    assert (f"(give the files inside it: {tmp_path}/*.mat (2 files), {tmp_path}/*.csv (1 file); "
            "its folders: runs/)") in capsys.readouterr().err
    assert main(["inspect", str(tmp_path / "absent.csv")]) == 2
    assert "absent.csv: no such file" in capsys.readouterr().err
    if os.geteuid() != 0:                       # root reads files whatever their mode
        locked = tmp_path / "locked.csv"
        locked.write_text("a,b\n1,2\n")
        locked.chmod(0)
        assert main(["inspect", str(locked)]) == 2
        assert "cannot be opened" in capsys.readouterr().err


def test_messages_print_plain_numbers(tmp_path, capsys) -> None:
    bad = tmp_path / "back.bdf.csv"
    bad.write_text("Test Time / s,Voltage / V,Current / A\n0,3.6,0\n2,3.6,0\n1,3.6,0\n")
    assert main(["inspect", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "2.0 s then 1.0 s" in err and "np.float64" not in err


def test_bare_command_prints_help_and_version(capsys) -> None:
    assert main([]) == 0
    assert "usage: lmncell" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and "lmncell 0." in capsys.readouterr().out


def test_one_package_installed_not_generic_names(tmp_path) -> None:
    """After `pip install`, `import lmncell` works from anywhere and no generic top-level
    name (training, fmu_src) is importable."""
    code = ("import importlib.util, lmncell; "
            "print([n for n in ('training', 'fmu_src', 'lmncell_build') "
            "if importlib.util.find_spec(n)])")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_package_type_checks(tmp_path) -> None:
    """mypy finds no type error in the installed package lmncell. It is checked under that name,
    laid out from the repository's folders as pyproject.toml maps them (training/ is lmncell,
    fmu_src/ lmncell.runtime, build/ lmncell.fmu), so that every import between them resolves."""
    pytest.importorskip("mypy", reason="mypy is one of the dev dependencies")
    root = Path(__file__).resolve().parent.parent
    folders = tomllib.loads((root / "pyproject.toml").read_text())[
        "tool"]["setuptools"]["package-dir"]
    package = tmp_path / "lmncell"
    package.mkdir()
    for entry in sorted((root / folders["lmncell"]).iterdir()):
        if entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry)
    for name, folder in folders.items():
        if name != "lmncell":
            (package / name.split(".")[1]).symlink_to(root / folder)
    res = subprocess.run([sys.executable, "-m", "mypy", "--config-file",
                          str(root / "pyproject.toml"), "--cache-dir", str(tmp_path / "cache"),
                          "-p", "lmncell"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "no issues found in" in res.stdout


def test_python_api_end_to_end(tmp_path) -> None:
    import lmncell

    rec = lmncell.read_record(PAN_US06)
    model = lmncell.train([PAN_US06], tmp_path / "m.json", capacity_ah=2.85,
                          progress=lambda _m: None, max_local_models=1, hysteresis="off")
    assert lmncell.load_model(tmp_path / "m.json").n_local_models == model.n_local_models
    assert model.sample_time_s == 0.1                      # the 10 Hz record's interval
    current = np.full(6000, -2.85)                         # 1C discharge for 10 minutes
    sim = lmncell.simulate(model, current, temperature_c=25.0, soc0=1.0)
    assert sim.voltage_v.shape == sim.soc.shape == (6000,)
    assert np.isclose(sim.soc[-1], 1.0 - 600 / 3600 * model.efficiency_discharge, atol=2e-3)
    assert np.all(np.diff(sim.voltage_v[5:]) < 1e-3)       # the voltage falls under load
    rows = lmncell.evaluate(model, [PAN_US06])
    assert rows[0]["lmn"]["rmse_mv"] > 0 and "window_rmse_mv" in rows[0]["lmn"]
    with pytest.raises(lmncell.api.DataError, match="soc0"):
        lmncell.simulate(model, current, soc0=1.5)
    assert rec.current_a.size > 0
    fmu = lmncell.build_fmu(tmp_path / "m.json", tmp_path / "m.fmu")
    assert fmu.stat().st_size > 1000


def test_api_simulate_is_the_fmus_engine_stepped_at_ts(quick_model) -> None:
    """lmncell.simulate takes the profile as the FMU stepped at Ts with it does: the quick
    model's current delay included (8 mV apart at a current step before)."""
    import lmncell
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = lmncell.load_model(quick_model)
    assert model.current_delay_s > 0
    current = np.r_[np.full(60, -2.85), np.zeros(60), np.full(60, 1.0)]
    sim = lmncell.simulate(model, current, temperature_c=25.0, soc0=0.9)
    engine = CellCosim(model, Parameters(0.9, model.capacity_ah, temperature_is_cell=True))
    engine.reset(25.0)
    for k, i in enumerate(current):
        engine.advance(model.sample_time_s, float(i), 25.0)
        assert engine.voltage_v == pytest.approx(sim.voltage_v[k], abs=1e-9), k
        assert engine.soc == pytest.approx(sim.soc[k], abs=1e-12), k


def test_api_simulate_from_the_ambient_is_the_fmus_default(quick_model) -> None:
    """ambient_c drives the thermal model, as the FMU with temperature_is_cell = false: the
    same voltages and cell temperatures; temperature_c and ambient_c together are refused."""
    import lmncell
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = lmncell.load_model(quick_model)
    assert model.thermal is not None and model.current_delay_s > 0
    current = np.r_[np.full(900, -3.0), np.zeros(300)]
    sim = lmncell.simulate(model, current, soc0=0.9, ambient_c=25.0)
    engine = CellCosim(model, Parameters(0.9, model.capacity_ah))
    engine.reset(25.0)
    for k, i in enumerate(current):
        engine.advance(model.sample_time_s, float(i), 25.0)
        assert engine.voltage_v == pytest.approx(sim.voltage_v[k], abs=1e-9), k
        assert engine.cell_temperature_c == pytest.approx(sim.cell_temperature_c[k], abs=1e-9)
    assert sim.cell_temperature_c.max() > 26.0              # the cell warmed above the ambient
    plain = lmncell.simulate(model, current, soc0=0.9)      # as the FMU with its start values
    assert np.array_equal(plain.voltage_v, sim.voltage_v)
    assert np.array_equal(plain.cell_temperature_c, sim.cell_temperature_c)
    with pytest.raises(lmncell.api.DataError, match="temperature_c .* and ambient_c given"):
        lmncell.simulate(model, current, temperature_c=25.0, ambient_c=20.0)
    with pytest.raises(lmncell.api.DataError, match=r"ambient_c must lie within .*an ambient"):
        lmncell.simulate(model, current, ambient_c=293.15)


def test_api_takes_one_ocv_test_file_on_its_own(monkeypatch, tmp_path) -> None:
    """lmncell.train(..., ocv_tests="c20.mat") passes that one file, not its characters."""
    import lmncell
    import lmncell.identification.train as train_module

    seen: dict = {}

    def fake_train_files(paths, out, *args, **kwargs):
        seen.update(kwargs)
        return "model", None

    monkeypatch.setattr(train_module, "train_files", fake_train_files)
    for given in ("c20.mat", tmp_path / "c20.mat"):
        assert lmncell.train([PAN_US06], tmp_path / "m.json", ocv_tests=given) == "model"
        assert seen["ocv_tests"] == [str(given)]


def test_api_takes_one_data_file_on_its_own(monkeypatch, tmp_path, quick_model) -> None:
    """lmncell.train("cycle.mat", ...) and lmncell.evaluate(model, "cycle.mat") take that one
    file, not its characters (which read '/' as a file); a list that holds something other
    than paths is named."""
    import lmncell
    import lmncell.identification.train as train_module
    from lmncell.data.records import DataError

    seen: list = []
    monkeypatch.setattr(train_module, "train_files",
                        lambda paths, out, *a, **k: (seen.append(paths), ("model", None))[1])
    for given in (str(PAN_US06), Path(PAN_US06)):
        assert lmncell.train(given, tmp_path / "m.json") == "model"
        assert seen[-1] == [given]
    one = lmncell.evaluate(quick_model, str(PAN_US06), soc0=1.0)
    assert one == lmncell.evaluate(quick_model, [PAN_US06], soc0=1.0)
    with pytest.raises(DataError, match=r"evaluate: paths holds 3; expected data files' paths"):
        lmncell.evaluate(quick_model, [PAN_US06, 3])
    with pytest.raises(DataError, match=r"train: paths is 3\.0; expected a data file's path"):
        lmncell.train(3.0, tmp_path / "m.json")
    with pytest.raises(DataError, match=r"evaluate: no data files given"):   # [] before
        lmncell.evaluate(quick_model, [])


def test_api_sweep_takes_one_value_per_axis_on_its_own(native_fmu) -> None:
    """lmncell.sweep(fmu, cycles="wltc", ambient_c=25.0, soc0=0.9) is one scenario, as with
    lists of one ("wltc" was read letter by letter, 25.0 raised TypeError)."""
    import lmncell

    one = lmncell.sweep(native_fmu, cycles="us06", ambient_c=25.0, soc0=0.9, workers=1,
                        progress=False)
    listed = lmncell.sweep(native_fmu, cycles=["us06"], ambient_c=[25.0], soc0=[0.9],
                           workers=1, progress=False)
    cols = [c for c in one.columns if c != "wall_s"]
    assert len(one) == 1 and one[cols].equals(listed[cols])


def test_api_simulate_starts_a_cell_warmer_than_its_ambient(quick_model) -> None:
    """cell_temperature_start_c: the cell starts at it and cools towards its ambient, as the
    FMU's engine with that start; the same figures with or without ambient_c's default."""
    import lmncell
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = lmncell.load_model(quick_model)
    current = np.full(600, -2.0)
    sim = lmncell.simulate(model, current, soc0=0.9, cell_temperature_start_c=40.0)
    engine = CellCosim(model, Parameters(0.9, model.capacity_ah, cell_temperature_start_c=40.0))
    engine.reset(25.0)
    assert engine.cell_temperature_c == 40.0
    for k, i in enumerate(current):
        engine.advance(model.sample_time_s, float(i), 25.0)
        assert engine.voltage_v == pytest.approx(sim.voltage_v[k], abs=1e-9), k
    assert 25.0 < sim.cell_temperature_c[-1] < sim.cell_temperature_c[0] < 40.0
    rested = lmncell.simulate(model, current, soc0=0.9, ambient_c=25.0)
    assert np.max(np.abs(rested.voltage_v - sim.voltage_v)) > 1e-3


def test_api_refuses_a_model_file_it_could_not_write_before_training(tmp_path) -> None:
    import lmncell
    from lmncell.config import ConfigError

    with pytest.raises(ConfigError, match="the folder .*missing.* does not exist"):
        lmncell.train(["not read.csv"], tmp_path / "missing" / "m.json")
    with pytest.raises(ConfigError, match="is a folder"):
        lmncell.train(["not read.csv"], tmp_path)


@pytest.mark.parametrize("kwargs, message", [
    ({"current_a": np.zeros((3, 2))}, r"current_a has shape \(3, 2\); expected a non-empty 1-D"),
    ({"current_a": "abc"}, "current_a is 'abc'; expected numbers"),
    ({"current_a": [0.0, float("nan")]}, "current_a has 1 NaN or infinite value.*index 1"),
    ({"temperature_c": np.zeros(3)}, "temperature_c has 3 values for 5 current steps"),
    ({"temperature_c": 298.15}, r"within -60…100 °C \(a cell temperature in °C, not K\)"),
    ({"temperature_c": "warm"}, "temperature_c is 'warm'"),
    ({"capacity_ah": 0}, r"capacity_ah = 0; expected a finite number > 0 \(Ah"),
    ({"capacity_ah": float("nan")}, "capacity_ah = nan; expected a finite number > 0"),
    # numpy dropped the imaginary parts (a ComplexWarning), the load function's TypeError
    ({"current_a": np.full(5, -1.0 + 0.5j)}, "current_a holds complex numbers; expected real"),
    ({"model": None}, "simulate: model is None; expected an LmnModel or a model file's path"),
    ({"cell_temperature_start_c": 150.0}, "cell_temperature_start_c = 150.0; expected a cell "
                                          "temperature within -60…100 °C"),
    ({"cell_temperature_start_c": 30.0, "temperature_c": 25.0},
     "cell_temperature_start_c given with temperature_c"),
])
def test_api_simulate_names_what_is_wrong_with_its_inputs(quick_model, kwargs, message) -> None:
    import lmncell

    args = {"model": quick_model, "current_a": np.full(5, -1.0), **kwargs}
    with pytest.raises(lmncell.api.DataError, match=message):
        lmncell.simulate(args.pop("model"), args.pop("current_a"), **args)


def test_api_builds_an_fmu_of_a_loaded_model_as_of_its_file(quick_model, tmp_path) -> None:
    """build_fmu takes the LmnModel that load_model, train and simulate use (a TypeError
    before); its FMU ships the same model file."""
    import zipfile

    import lmncell

    a = lmncell.build_fmu(quick_model, tmp_path / "a.fmu")
    b = lmncell.build_fmu(lmncell.load_model(quick_model), tmp_path / "b.fmu")
    assert (zipfile.ZipFile(a).read("resources/model.json")
            == zipfile.ZipFile(b).read("resources/model.json"))
    with pytest.raises(lmncell.api.DataError, match="build_fmu: model_path is 3; expected"):
        lmncell.build_fmu(3, tmp_path / "c.fmu")


def test_api_reads_a123(tmp_path) -> None:
    import lmncell

    rec = lmncell.read_record(A123_S1)
    assert rec.meta.fmt == "plett" and rec.current_a.min() < 0


def test_api_simulate_warns_where_it_leaves_the_trained_range(quick_model) -> None:
    """A discharge past empty, or a current and temperature beyond the training data, gives a
    UserWarning that names the variable, the values reached and the trained range (the model
    still extrapolates: the values are not clamped); inside the range there is none."""
    import warnings

    import lmncell

    model = lmncell.load_model(quick_model)
    lo, hi = model.limits["soc"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lmncell.simulate(model, np.full(600, -2.85), temperature_c=25.0, soc0=1.0)
    with pytest.warns(UserWarning, match=r"simulate: SoC -0\.\d+…1\.000 leaves the trained "
                      rf"{lo:.3f}…{hi:.3f} first at step \d+ \(below 0 the cell is past empty\)"):
        sim = lmncell.simulate(model, np.full(4000, -2.85), temperature_c=25.0, soc0=1.0)
    assert sim.soc[-1] < 0                                 # not clamped
    with pytest.warns(UserWarning, match=r"simulate: current -40\.00…-40\.00 A exceeds"):
        lmncell.simulate(model, np.full(10, -40.0), temperature_c=25.0, soc0=1.0)


EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_every_example_without_its_arguments_prints_its_usage(script: Path) -> None:
    """An example run without its arguments says what it needs (two used to end in a
    TypeError traceback from main(*sys.argv[1:]))."""
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith("usage: ") and "Traceback" not in out.stderr


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_every_example_argument_says_what_it_is(script: Path, monkeypatch) -> None:
    """`-h` explains every argument (four examples listed bare names such as capacity_ah)."""
    import argparse
    import runpy

    actions: list[argparse.Action] = []

    def capture(parser: argparse.ArgumentParser, *_args, **_kw):
        actions.extend(parser._actions)
        raise SystemExit(0)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    monkeypatch.setattr(sys, "argv", [str(script)])
    with pytest.raises(SystemExit):
        runpy.run_path(str(script), run_name="__main__")
    assert actions and [a.dest for a in actions if not a.help] == []


THIS_FILE = str(Path(__file__).resolve())    # an existing file, for the record arguments


@pytest.mark.parametrize(("script", "args", "expected"), [
    ("leave_one_out.py", ["x", THIS_FILE], "'x': expected a cell capacity in Ah within "
     "0.0001…100000 or 'auto'"),
    ("observer_leave_one_out.py", ["auto", THIS_FILE], "'auto': expected a cell capacity"),
    ("observer_leave_one_out.py", ["2.85", THIS_FILE, "--soc0-est", "nan"],
     "argument --soc0-est: 'nan': expected a SoC fraction within 0…1"),
    ("observer_leave_one_out.py", ["2.85", THIS_FILE, "--start-soc", "1.5"],
     "argument --start-soc: '1.5': expected a SoC fraction within 0…1"),
    ("leave_one_out.py", ["2.85", THIS_FILE, "--plot", "no-such-folder/loo.png"],
     "argument --plot: 'no-such-folder/loo.png': the folder 'no-such-folder' does not exist"),
    ("observer_leave_one_out.py", ["2.85", THIS_FILE, "--plot", "obs.txt"],
     "argument --plot: 'obs.txt': a figure's file name ends in one of"),
    ("leave_one_out.py", ["2.85", "no-such.csv"],
     "argument records: 'no-such.csv': no such file; expected a file"),
    ("observer_leave_one_out.py", ["2.85", THIS_FILE, "--ocv-tests", "tests"],
     "argument --ocv-tests: 'tests': is a folder; expected a file"),
])
def test_the_leave_one_out_examples_refuse_bad_arguments_before_training(
        script: str, args: list[str], expected: str) -> None:
    """Their capacity, SoCs, input files and figure file are checked as the commands check them,
    before any training (a NaN start estimate used to run every fold and print NaN bands, a
    missing held-out record or a figure in a missing folder failed only after a training)."""
    root = Path(__file__).resolve().parents[1]              # where "tests" is a folder
    out = subprocess.run([sys.executable, str(root / "examples" / script), *args], cwd=root,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert expected in out.stderr and "Traceback" not in out.stderr


def test_the_oldest_constraints_pin_the_declared_floors() -> None:
    """tests/oldest-constraints.txt pins exactly the floors (>=) of pyproject.toml's dependencies,
    so that installing with it checks the oldest releases pip may choose on a user's machine."""
    from packaging.requirements import Requirement
    from packaging.version import Version

    root = Path(__file__).resolve().parent.parent
    declared = [Requirement(r) for r in
                tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]]
    floors = {r.name: Version(s.version) for r in declared for s in r.specifier
              if s.operator == ">="}
    lines = (root / "tests" / "oldest-constraints.txt").read_text().splitlines()
    pins = {}
    for line in lines:
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[name.strip()] = Version(version)
    assert floors and pins == floors


def test_a_wheel_ships_the_data_and_finds_them(tmp_path, monkeypatch) -> None:
    """`pip install .` (not -e) or a wheel: the drive cycles that `lmncell simulate --cycle`
    and the sweep read, and the demo's measurements, travel in the package (lmncell/datasets,
    with their README, licences and citation), and data_dir() finds them there. Before, such an
    install looked for site-packages/data and `simulate --cycle us06` failed."""
    import importlib.util
    import zipfile

    root = Path(__file__).resolve().parent.parent
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True,
                             check=True).stdout.decode().split("\0")
    if not tracked or not tracked[0]:
        pytest.skip("not a git clone: the tracked files are unknown")
    src = tmp_path / "src"
    for name in filter(None, tracked):
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        (src / name).write_bytes((root / name).read_bytes())
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                    str(tmp_path / "wheel"), str(src)], check=True, capture_output=True,
                   timeout=600)
    (wheel,) = (tmp_path / "wheel").glob("lmncell-*.whl")
    with zipfile.ZipFile(wheel) as z:
        shipped = set(z.namelist())
        z.extractall(tmp_path / "site")
    data = sorted(n[len("data/"):] for n in tracked if n.startswith("data/"))
    assert data and {f"lmncell/datasets/{n}" for n in data} <= shipped
    traces = tmp_path / "site" / "lmncell" / "scenarios" / "traces.py"
    spec = importlib.util.spec_from_file_location("installed_traces", traces)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "installed_traces", module)   # for its dataclasses
    spec.loader.exec_module(module)
    assert module.data_dir() == tmp_path / "site" / "lmncell" / "datasets"
    assert (module.data_dir() / "drive_cycles" / module.CYCLES["us06"]).is_file()
