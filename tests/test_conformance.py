"""FMI conformance of both FMUs (issue 18): call sequences run in child processes (a crash
fails the test), the model description's InitialUnknowns, the documentation per flavour."""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import subprocess
import sys
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmpy import read_model_description
from lmncell.runtime.cosim import STOP_TOLERANCE

from tests.conformance_sequences import MODES
from tests.conftest import ROOT, c_compiler_or_skip
from tests.fmu_helpers import fmu_reports

WARNING, ERROR, DISCARD = 1, 3, 2


def _run(fmu, sequence: str) -> dict:
    proc = subprocess.run([sys.executable, "-m", "tests.conformance_sequences", str(fmu),
                           sequence], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"the host died ({proc.returncode}): {proc.stderr[-2000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


@functools.cache
def _run_once(fmu: Path, sequence: str) -> dict:
    """_run's result, kept for the session: the sequences that one test checks on each FMU and
    another compares between the two FMUs run once per FMU."""
    return _run(fmu, sequence)


def _memory_errors_in_the_fmu(fmu, sequence: str) -> list[str]:
    """Valgrind's reports (memcheck) whose stack passes through the FMU's binary, for one call
    sequence and the host's exit; glibc's own false positives (dl-load) are left out."""
    proc = subprocess.run(["valgrind", "--num-callers=40", sys.executable, "-m",
                           "tests.conformance_sequences", str(fmu), sequence], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"the host died ({proc.returncode}): {proc.stderr[-2000:]}"
    return fmu_reports(proc.stderr)


def test_outputs_in_initialization_mode_are_the_initial_outputs(fmu) -> None:
    res = _run(fmu, "init_mode_outputs")
    assert res["before"] == pytest.approx(res["after"], abs=1e-12)


def test_initial_unknowns_name_their_dependencies(fmu) -> None:
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    names = [sv.get("name") for sv in root.iter("ScalarVariable")]
    deps = {names[int(u.get("index")) - 1]: {names[int(i) - 1] for i in
                                             u.get("dependencies").split()}
            for u in root.find("ModelStructure/InitialUnknowns")}
    start = {"cell_temperature_start", "use_cell_temperature_start"}
    assert deps["voltage"] == {"soc0", "temperature", "temperature_is_cell", *start}
    assert deps["soc"] == {"soc0"} and deps["soc_std"] == {"observer"}
    assert deps["cell_temperature"] == {"temperature", "temperature_is_cell", *start}
    outputs = {names[int(u.get("index")) - 1] for u in root.find("ModelStructure/Outputs")}
    assert outputs == set(deps)


def test_pythonfmu_fmu_carries_the_patched_wrapper(quick_fmu) -> None:
    """The linux64 binary is LMNCell's build of the wrapper (a C++ compiler is present here),
    and the model description and documentation say so."""
    from lmncell.fmu.pythonfmu_build import PATCHED

    with zipfile.ZipFile(quick_fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
        doc = z.read("documentation/index.html").decode()
    assert PATCHED in root.get("generationTool") and "returns fmi2Error" in doc


def _guid(fmu: Path) -> str:
    with zipfile.ZipFile(fmu) as z:
        return ET.fromstring(z.read("modelDescription.xml")).get("guid")


def test_the_guid_is_the_models_fingerprint(quick_model, quick_fmu, stock_fmu,
                                            native_fmu) -> None:
    """Every build of one model's pythonfmu FMU has the same GUID, a name-based UUID of the
    model file's hash, as the native FMU's is (pythonfmu's own is time-based: a new GUID at
    each build); the two flavours differ."""
    from lmncell.fmu.interface import fmu_guid
    from lmncell.fmu.pythonfmu_build import model_hash

    guid = fmu_guid("pythonfmu", model_hash(quick_model))
    assert _guid(quick_fmu) == _guid(stock_fmu) == guid != _guid(native_fmu)
    assert uuid.UUID(guid).version == 5 == uuid.UUID(_guid(native_fmu)).version


@pytest.mark.slow
def test_source_date_epoch_makes_the_pythonfmu_build_reproducible(quick_model, tmp_path,
                                                                  monkeypatch) -> None:
    """With SOURCE_DATE_EPOCH set, two pythonfmu builds of one model are byte-identical: the
    members and generationDateAndTime carry that time, the GUID is the model's fingerprint
    and the patched wrapper compiles to the same bytes."""
    from lmncell.fmu.pythonfmu_build import build_fmu

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    first, second = (build_fmu(quick_model, tmp_path / f"{k}.fmu") for k in "ab")
    assert first.read_bytes() == second.read_bytes()
    with zipfile.ZipFile(first) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    assert root.get("generationDateAndTime") == "2023-11-14T22:13:20Z"


@pytest.fixture(scope="module")
def stock_fmu(quick_model, tmp_path_factory):
    """The pythonfmu FMU built where no C++ compiler is found: it keeps pythonfmu's wrapper."""
    from lmncell.fmu import native_build
    from lmncell.fmu import pythonfmu_build as pb

    found = native_build.compiler
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(native_build, "compiler", lambda lang: None if lang == "c++" else found(lang))
        with pytest.warns(UserWarning, match="no C\\+\\+ compiler"):   # printed as the CLI's
            return pb.build_fmu(quick_model, tmp_path_factory.mktemp("stock") / "stock.fmu")


def test_without_a_cxx_compiler_the_fmu_keeps_pythonfmus_wrapper(stock_fmu) -> None:
    """No C++ compiler where the FMU is built: a warning, pythonfmu's own binary (named in the
    model description), and the slave's fallback: ordinary errors logged and ignored, no crash."""
    from lmncell.fmu.pythonfmu_build import STOCK, native_host_hint

    with zipfile.ZipFile(stock_fmu) as z:
        assert STOCK in ET.fromstring(z.read("modelDescription.xml")).get("generationTool")
    assert "Python hosts only" in native_host_hint(stock_fmu)
    res = _run(stock_fmu, "ordinary_errors")
    assert res["soc0_after"] == 0.8 and res["steps_after"] == 0 and res["finite"]
    assert max(res["unknown_get"]) < ERROR and res["bad_param_exit"] < ERROR


def test_without_compilers_build_fmu_warns_as_the_command_line_does(quick_model, tmp_path,
                                                                    monkeypatch, capsys) -> None:
    """A machine without gcc and g++ (a fresh one may have none): the warning that the FMU
    keeps pythonfmu's wrapper is the command line's, without Python's file, line and source."""
    from lmncell.cli import main
    from lmncell.fmu import native_build

    monkeypatch.setattr(native_build, "compiler", lambda _lang: None)   # no gcc, no ziglang
    assert main(["build-fmu", str(quick_model), "--out", str(tmp_path / "c.fmu")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("lmncell build-fmu: warning: the pythonfmu FMU keeps PythonFMU")
    assert ("no C++ compiler (g++ or c++) and no C compiler (gcc or cc) found: install gcc and "
            "g++, or pip install ziglang") in err
    assert "pythonfmu_build.py" not in err


def test_pythonfmus_own_wrapper_survives_damaged_fmu_states(stock_fmu) -> None:
    """Under pythonfmu's own wrapper (the win64 binary, or linux64 built without C++) an
    exception in fmi2DeSerializeFMUstate is fatal and frees the instance, so the host's next call
    crashes: bytes that are no JSON state read as a state that fmi2SetFMUstate refuses (logged,
    the call ignored), and every damaged state leaves the instance as it was."""
    res = _run(stock_fmu, "damaged_states")
    twin = res.pop("twin_next")
    assert {"not JSON", "not a JSON object", "JSON nested too deeply"} <= set(res)
    for label, got in res.items():
        assert got["read"] < ERROR and len(got["log"]) == 1, (label, got)
        assert got["log"][0].startswith("fmi2SetFMUstate: ") and "nothing was" in got["log"][0]
        assert "(FMU state: " not in got["log"][0]            # said once, not twice
        assert got["kept"] and got["next_step"] == 0 and got["next"] == twin, (label, got)


def test_pythonfmus_own_wrapper_survives_random_call_sequences(stock_fmu) -> None:
    """Random calls (some serialised states damaged on the way) under pythonfmu's own wrapper,
    where any exception out of the slave frees the instance and the next call crashes the host:
    the slave never raises there. The wrapper's own faults are left out (RandomHost)."""
    res = _run(stock_fmu, "random_calls_stock")
    assert res["calls"] > 600
    assert res["findings"] == []


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="valgrind is not installed")
def test_pythonfmus_own_wrapper_leaves_the_heap_intact_at_exit(stock_fmu) -> None:
    """pythonfmu 0.7.0's wrapper releases its interpreter state twice when the host exits with the
    library loaded (heap corruption, now and then an abort); the slave's exit hook prevents it."""
    assert _memory_errors_in_the_fmu(stock_fmu, "ordinary_errors") == []


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="valgrind is not installed")
def test_no_memory_errors_in_either_fmu(fmu) -> None:
    assert _memory_errors_in_the_fmu(fmu, "ordinary_errors") == []


def test_the_patched_wrapper_is_only_built_for_linux64(monkeypatch, tmp_path) -> None:
    """On another platform no linux64 binary is compiled there (it would replace pythonfmu's
    with a binary of the wrong format)."""
    from lmncell.fmu import pythonfmu_build as pb

    monkeypatch.setattr(pb.sys, "platform", "darwin")
    with pytest.raises(pb.WrapperBuildError, match="linux64 only"):
        pb.compile_wrapper("{guid}", tmp_path)


@pytest.fixture(scope="module")
def temperature_terms_fmus(tmp_path_factory) -> list[Path]:
    """Both FMUs of a small model with quadratic temperature terms (forced; the shipped records
    lie near 25 °C), where the voltage at an absurd temperature is not finite."""
    c_compiler_or_skip()
    from lmncell.api import build_fmu
    from lmncell.identification.train import train_files

    from tests.conftest import PAN_HPPC, PAN_HWFET

    tmp = tmp_path_factory.mktemp("tterms")
    path = tmp / "t.json"
    train_files([PAN_HWFET, PAN_HPPC], path, capacity_ah=2.85, soc0=1.0,
                progress=lambda _m: None, max_local_models=2, oe_max_iterations=2,
                hysteresis="off", temperature_terms=2, temperature_scaling=3000.0)
    return [build_fmu(path, tmp / "t.fmu"), build_fmu(path, tmp / "t_native.fmu", native=True)]


def test_a_temperature_no_step_takes_leaves_the_start_outputs_finite(
        temperature_terms_fmus) -> None:
    for fmu in temperature_terms_fmus:
        res = _run(fmu, "temperature_outside_range_at_start")
        for key in ("init", "after_exit", "after_step", "after_25"):
            assert all(math.isfinite(x) for x in res[key]), (fmu.name, key, res[key])
        assert res["init"] == res["after_exit"] == res["after_step"], fmu.name
        assert res["exit"] == 0 and res["step"] == ERROR and res["step_25"] == 0, fmu.name
        assert res["after_25"][1] < res["after_step"][1]      # the step at 25 °C discharged


def test_state_machine(fmu) -> None:
    res = _run(fmu, "state_machine")
    assert res["first_step"] == 0 and res["right_point"] == 0
    assert res["wrong_point"] == ERROR
    assert res["tiny_step"] == 0 and res["after_tiny"] == 0      # a tiny step counts
    assert res["step_after_terminate"] == ERROR
    assert res["exit_without_enter"] == ERROR


ALLOWED = {   # FMI 2.0 co-simulation: the modes each call may be made in (LMNCell also lets
    # fmi2Terminate end an instance left in initialization mode by bad parameters)
    "setupExperiment": {"instantiated"}, "enterInitializationMode": {"instantiated"},
    "exitInitializationMode": {"initialization mode"},
    "terminate": {"initialization mode", "step mode"}, "doStep": {"step mode"},
    "setReal current": {"instantiated", "initialization mode", "step mode"},
    **{f"get{kind}": {"initialization mode", "step mode", "terminated"} for kind in (
        "Real voltage", "Integer observer", "Boolean out_of_range", "String none")},
    "reset": {"instantiated", "initialization mode", "step mode", "terminated"}}


def test_each_call_is_taken_only_in_its_modes(fmu) -> None:
    """Every call of the co-simulation state machine in every mode: OK where FMI 2.0 allows
    it, fmi2Error elsewhere (the pythonfmu FMU took setupExperiment and
    enterInitializationMode in step mode, restarting the run, setReal and terminate after
    terminate, and a NaN start time that made every later step fail; both FMUs answered
    getters before fmi2EnterInitializationMode)."""
    res = _run_once(fmu, "mode_rules")
    for call, modes in ALLOWED.items():
        for mode in MODES:
            assert res[f"{call} in {mode}"] == (0 if mode in modes else ERROR), (call, mode)
    assert res["setupExperiment at nan"] == res["setupExperiment at inf"] == ERROR
    assert res["restore after terminate"] == res["step after restore"] == 0
    assert res["restore uninitialised"] == 0 and res["step after restore uninitialised"] == ERROR


def test_no_step_ends_past_a_defined_stop_time(fmu) -> None:
    """FMI 2.0 (fmi2SetupExperiment): "if the environment tries to compute past stopTime the
    FMU has to return fmi2Error" (both FMUs ignored stopTime)."""
    res = _run(fmu, "stop_time")
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert f"by more than {STOP_TOLERANCE:.0e} of it".replace("e-0", "e-") in readme   # 1e-8
    assert res["setup_stop_-1.0"] == res["setup_stop_nan"] == ERROR
    assert res["setup"] == 0 and res["grid"] == [0, 0, 0]
    assert res["past"] == ERROR and res["unchanged"]
    assert res["after_reset"] == 0


def test_physically_impossible_inputs_are_refused(fmu) -> None:
    res = _run(fmu, "impossible_inputs")
    assert res["huge_current"] == ERROR
    assert res["below_zero_kelvin"] == ERROR
    assert res["nan_current"] == ERROR                   # row 9: the same status from both
    assert res["after_huge"] == res["before"] and res["after_cold"] == res["before"]
    assert res["after_nan"] == res["before"]
    assert res["endless_step"] == ERROR and res["after_endless"] == res["before"]
    assert res["still_steps"] == 0 and res["finite"]


def test_both_fmus_log_the_same_messages(quick_fmu, native_fmu) -> None:
    """A host's log reads the same whichever FMU it runs: the same words (ASCII, without the
    instance's name, which the FMI logger passes beside the message), the same statuses and
    outputs. Before, the pythonfmu FMU wrote °C and … where the native one wrote degC and ..,
    and left out the time of a refused step's inputs. A temperature in K given as °C is
    refused as such (both took 298.15 °C, and −273 °C overflowed the pythonfmu FMU's
    arithmetic after its SoC had moved)."""
    py, native = (_run(f, "logged_messages") for f in (quick_fmu, native_fmu))
    assert py == native, "\n".join(f"{a}\n{b}\n" for a, b in zip(py["messages"],
                                                                   native["messages"],
                                                                   strict=False) if a != b)
    text = "\n".join(native["messages"])
    assert text.isascii() and "NAME" not in text
    expected = ["fmi2DoStep is not allowed in instantiated",
                "parameter 'capacity' = 1e-300: expected a cell's capacity within "
                "0.0001...100000 Ah; not initialised",
                "parameter 'soc0' = 1.5: expected a fraction within 0..1; not initialised",
                "t = 0 s: input 'temperature' = 298.15 degC: expected -60..100 degC (degC, not "
                "K); the step was not taken",
                "t = 0 s: temperature 60.7 degC outside the trained",
                "t = 1 s: input 'current' = nan: expected a finite number; the step was not",
                "t = 1.5 s: communication step size -1 s: expected > 0 s",
                "fmi2DoStep: currentCommunicationPoint 6.75 s is not the FMU's time 1.75 s",
                "fmi2DoStep is not allowed in terminated"]
    assert all(e in text for e in expected), text
    assert native["statuses"].count(0) == 4 and all(math.isfinite(x) for x in native["outputs"])


def test_a_cell_start_temperature_is_checked_and_read_back_alike(quick_fmu, native_fmu) -> None:
    """use_cell_temperature_start with cell_temperature_start 150 °C and NaN is refused at
    exitInitializationMode (the outputs until then those of a rested start), 40 °C is the
    cell temperature in Initialization Mode and after it, fixed once initialised, and refused
    where the temperature input is the cell's (temperature_is_cell): both FMUs alike."""
    py, native = (_run(f, "cell_start_parameters") for f in (quick_fmu, native_fmu))
    assert py == native
    assert native["statuses"] == [ERROR, ERROR, 0, 0, ERROR, ERROR]
    rested, _, warm, after_init, after_step = native["cell_temperature"]
    assert abs(rested - 25.0) < 2.0 and warm == after_init == 40.0 and after_step < 40.0
    assert native["read_back"] == [40.0, True]
    text = "\n".join(native["messages"])
    assert ("parameter 'cell_temperature_start' = 150: expected a cell temperature within "
            "-60...100 degC; not initialised" in text)
    assert ("parameter 'use_cell_temperature_start' = true: temperature_is_cell = true, so "
            "the temperature input is the cell temperature" in text)


def test_refused_gets_and_sets_read_alike_and_set_nothing(quick_fmu, native_fmu) -> None:
    """Each refused get or set: fmi2Error from both FMUs, the same words naming the variable,
    the value given and, for a parameter set after initialisation, the value kept; nothing of
    a refused set call is set, not even its settable values (the native FMU used to set those
    before the refused one, and named a fixed parameter by its value reference only)."""
    py, native = (_run(f, "access_refusals") for f in (quick_fmu, native_fmu))
    assert py == native, "\n".join(f"{a}\n{b}\n" for a, b in zip(py["messages"],
                                                                   native["messages"],
                                                                   strict=False) if a != b)
    assert native["statuses"] == [ERROR] * 13 and native["steps_after"] == 0
    before_init, after_init = native["read_back"][0], native["read_back"][4]
    assert all(r == before_init for r in native["read_back"][:4])
    assert all(r == after_init for r in native["read_back"][4:])
    assert after_init[:3] == [-1.0, 0.7, 2.5]
    expected = [
        "fmi2SetReal: 'voltage' is an output and cannot be set; 3.3 was not set (nothing of "
        "this call was set)",
        "fmi2SetInteger: value reference 0 ('current') is not an Integer; 1 was not set",
        "fmi2SetBoolean: value reference 9 ('observer') is not a Boolean; true was not set",
        "fmi2SetReal: no variable with value reference 999; 0.30000000000000004 was not set "
        "(nothing of this call was set)",
        "fmi2SetReal: parameter 'soc0' is fixed after initialisation (value kept: 0.7); 0.2 was "
        "not set (nothing of this call was set)",
        "fmi2SetReal: parameter 'soc0' is fixed after initialisation (value kept: 0.7); 1e-300 "
        "was not set; 2 more values refused (nothing of this call was set)",
        "fmi2SetInteger: parameter 'observer' is fixed after initialisation (value kept: 0); 2 "
        "was not set",
        "fmi2SetBoolean: parameter 'temperature_is_cell' is fixed after initialisation (value "
        "kept: false); true was not set; 1 more value refused",
        "fmi2GetReal: no variable with value reference 999 [",
        "fmi2GetInteger: value reference 7 ('soc0') is not an Integer [",
        "fmi2GetBoolean: value reference 0 ('current') is not a Boolean [",
        "fmi2GetString: value reference 3: this FMU has no String variables [",
        "fmi2SetString: value reference 3: this FMU has no String variables; nothing was set"]
    text = "\n".join(native["messages"])
    assert all(e in text for e in expected), [e for e in expected if e not in text]
    refused_values = native["messages"][-len(native["values_refused"]):]
    assert len(native["messages"]) == 13 + len(native["values_refused"])
    assert set(native["values_refused"]) == {ERROR}
    assert "(value kept: 0.7); 40 was not set" in refused_values[0]
    assert "(value kept: 0.7); 2.5e+06 was not set" in refused_values[2]


def test_debug_logging_follows_its_categories_and_refuses_null_ones(quick_fmu,
                                                                    native_fmu) -> None:
    """fmi2SetDebugLogging turns on the categories it names (all where it names none), in both
    FMUs alike: before, the native FMU turned warnings on whatever the list, and a NULL array
    or entry terminated a host of the pythonfmu FMU (std::string from NULL). Now both refuse
    the NULLs with a message and keep their logging as it was."""
    py, native = (_run(f, "debug_logging_categories") for f in (quick_fmu, native_fmu))
    assert py == native
    blocks, label = {}, None
    for entry in native["messages"]:
        if entry.startswith("["):
            label = entry
            blocks[label] = []
        else:
            blocks[label].append(entry)
    warned = {k for k, v in blocks.items() if any("outside the trained" in m for m in v)}
    assert warned == {"[all]", "[warnings]", "[logAll]", "[unknown and warnings]",
                      "[after the NULLs]"}, blocks
    nulls = blocks["[warnings off]"]
    assert len(nulls) == 2 and all("is NULL; logging left as it was" in m for m in nulls)
    assert native["statuses"][-3:] == [ERROR, ERROR, 0] and math.isfinite(native["voltage"])
    # an undeclared category: ignored with fmi2Warning and a message naming it, whether or
    # not warnings are on; the declared ones in the same call still apply
    undeclared = [m for m in native["messages"] if "'noSuchCategory' is not declared" in m]
    # the list the message names is the one modelDescription.xml declares
    declared = ", ".join(c.name for c in read_model_description(native_fmu).logCategories)
    assert len(undeclared) == 2 and all(f"declares {declared} [" in m for m in undeclared)
    calls = [native["statuses"][3 * k] for k in range(8)]
    assert calls == [0, 0, 0, 0, WARNING, 0, WARNING, 0], native["statuses"]


def test_both_fmus_declare_the_same_log_categories(quick_fmu, native_fmu) -> None:
    """fmi2SetDebugLogging accepts the categories modelDescription.xml declares and warns of
    any other, in both FMUs alike: so both must declare the same ones."""
    py, native = (read_model_description(f).logCategories for f in (quick_fmu, native_fmu))
    assert [c.name for c in py] == [c.name for c in native] == [
        "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal", "logAll"]


def test_observers_stay_finite_from_full_charge(fmu) -> None:
    for observer, res in _run(fmu, "observers_at_full").items():
        assert res == {"worst_status": 0, "finite": True}, observer


def test_ordinary_errors_never_crash_and_change_nothing(fmu) -> None:
    res = _run(fmu, "ordinary_errors")
    assert res["soc0_after"] == 0.8                      # the fixed parameter kept its value
    assert res["steps_after"] == 0 and res["finite"]
    assert res["step_uninitialised"] == ERROR
    assert res["unknown_get"] == [ERROR] * 6
    assert res["set_output"] == res["set_fixed"] == res["set_observer"] == ERROR
    assert res["wrong_type"] == ERROR and res["bad_param_exit"] == ERROR


def _needs_resources(fmu: Path) -> bool:
    """The pythonfmu FMU loads its model from the resources folder; the native FMU has it
    compiled in and ignores fmuResourceLocation."""
    return "native C" not in read_model_description(str(fmu)).generationTool


def test_wrong_guid_fmu_type_or_resources_are_refused(fmu) -> None:
    res = _run(fmu, "wrong_guid_or_type")
    assert res["right"] == "instantiated"
    assert res["wrong_guid"] == res["model_exchange"] == "refused"
    assert res["empty_name"] == res["no_callbacks"] == "refused"      # FMI 2.0 requires both
    without = "refused" if _needs_resources(fmu) else "instantiated"
    assert res["no_resources"] == res["missing_resources"] == without


def test_every_file_uri_form_of_the_resources_folder_is_taken(fmu) -> None:
    """FMI 2.0 asks an FMU to take file URIs with and without the authority; a host unpacks it
    where it likes (a space, ü, # or % in the folder's name, all percent-encoded in the URI).
    pythonfmu's wrapper decoded only %20 and took file:/p as a relative path."""
    res = _run(fmu, "resource_locations")
    voltages = [res[k] for k in ("fmpy", "no_authority", "localhost", "upper_scheme",
                                 "trailing_slash", "bare_path")]
    assert all(isinstance(v, float) and math.isfinite(v) for v in voltages), res
    assert voltages == pytest.approx([voltages[0]] * len(voltages), abs=1e-12)
    wrong = "refused" if _needs_resources(fmu) else "instantiated"
    assert {res[k] for k in ("other_host", "http", "relative", "bad_escape")} == {wrong}, res


def test_null_arrays_and_pointers_are_refused_and_logged(fmu) -> None:
    """A NULL array (nvr > 0) or a NULL pointer where the FMU would read or write is the host's
    mistake: fmi2Error and one message that names the call and the argument, nothing read or
    set, and the instance steps on. Each get and set crashed the host before (SIGSEGV), and
    the pythonfmu FMU's state calls and status inquiries too."""
    res = _run_once(fmu, "null_pointers")
    calls = {key: got for key, got in res.items() if key.startswith("fmi2")}
    assert len(calls) == 18
    for key, got in calls.items():
        assert got["status"] == ERROR, (key, got)
        assert len(got["log"]) == 1 and got["log"][0].startswith(key.split()[0] + ": "), key
        assert "NULL" in got["log"][0], key
    assert calls["fmi2SetReal (vr NULL)"]["log"][0].startswith(
        "fmi2SetReal: nvr = 1 but vr is NULL; nothing was set")
    assert calls["fmi2GetReal (value NULL)"]["log"][0].startswith(
        "fmi2GetReal: nvr = 1 but value is NULL; nothing was read")
    assert res["step_after"] == 0 and res["finite_after"]


def test_status_inquiries_answer_as_fmi_asks(fmu) -> None:
    """fmi2LastSuccessfulTime is the end of the last completed step (the start time before the
    first; restored with the FMU state), fmi2Terminated false; every other kind is fmi2Discard
    with a message, as FMI 2.0 asks for a status the FMU cannot give (the pythonfmu FMU gave
    fmi2Error for fmi2GetStatus and NaN as the last successful time before a step)."""
    res = _run_once(fmu, "status_inquiries")
    assert res["last_time"] == [[0, 0.0], [0, 5.0], [0, 7.0], [0, 7.0], [0, 6.0]]
    assert res["refused_step"] == ERROR
    answered = {"fmi2GetRealStatus 2": 6.0, "fmi2GetBooleanStatus 3": 0.0}
    for key, got in res["kinds"].items():
        if key in answered:
            assert got == {"status": 0, "value": answered[key], "log": []}, key
        else:
            assert got["status"] == DISCARD and len(got["log"]) == 1, key
            assert got["log"][0].startswith(key.split()[0] + ": no fmi2"), key


def test_fmu_states_are_reused_freed_and_checked(fmu) -> None:
    """A host that saves the state at every step into the same FMUstate (FMI 2.0 lets the FMU
    reuse it) does not make the FMU grow: pythonfmu's wrapper leaked each replaced state (about
    1.3 kB per call, 23 MB over 18,000). fmi2FreeFMUstate empties the host's pointer and takes
    an empty one; a freed state or a foreign pointer is refused with a message, never read (the
    pythonfmu FMU crashed on a freed one), and the instance steps on."""
    res = _run_once(fmu, "state_reuse")
    assert res["rss_2000"] - res["rss_200"] < 1000, res       # kB over 1,800 reused saves
    assert res["reuse_statuses"] == [0] and res["free"] == res["free_empty"] == 0
    assert res["freed_pointer_emptied"]
    for label in ("freed", "zeros"):
        for call in ("fmi2SetFMUstate", "fmi2SerializedFMUstateSize", "fmi2GetFMUstate",
                     "fmi2FreeFMUstate"):
            got = res[f"{call} {label}"]
            assert got["status"] == ERROR and len(got["log"]) == 1, (call, label, got)
            assert got["log"][0].startswith(f"{call}: the FMU state is not one of this "
                                            "instance's"), (call, label, got)
    assert res["step_after"] == 0


def test_a_damaged_fmu_state_is_refused_and_changes_nothing(fmu) -> None:
    """A serialised state damaged before it is read back (the pythonfmu FMU's JSON: a NaN time,
    a part missing, parts of the wrong shape or kind, a NaN voltage; the native FMU's bytes:
    0xFF after the magic number) is refused with fmi2Error and a message, by
    fmi2DeSerializeFMUstate or by fmi2SetFMUstate, and the instance keeps its outputs and time:
    its next step gives the voltage of an undamaged twin. The pythonfmu FMU took the inputs,
    time and parameters of a state whose engine part it then failed to read."""
    res = _run(fmu, "damaged_states")
    twin = res.pop("twin_next")
    assert len(res) >= 1
    for label, got in res.items():
        assert ERROR in (got["read"], got["set"]), (label, got)
        assert len(got["log"]) == 1 and "nothing was" in got["log"][0], (label, got)
        assert got["kept"] and got["next_step"] == 0 and got["next"] == twin, (label, got)


def test_both_fmus_answer_null_pointers_status_inquiries_modes_and_states_alike(quick_fmu,
                                                                  native_fmu) -> None:
    for sequence in ("null_pointers", "status_inquiries", "mode_rules", "state_reuse"):
        ours, theirs = (_without_memory(_run_once(f, sequence))
                        for f in (quick_fmu, native_fmu))
        assert ours == theirs, sequence


def _without_memory(res: dict) -> dict:
    """A sequence's result without the resident-memory figures (each process its own)."""
    return {key: value for key, value in res.items() if not key.startswith("rss_")}


def test_a_refused_resource_location_is_named_in_the_log(quick_fmu) -> None:
    """The refusal says which location and why, through the host's logger."""
    res = _run(quick_fmu, "logged_resource_refusals")
    assert "fmuResourceLocation 'file://elsewhere.example/x/resources': the host " \
           "'elsewhere.example' is not this machine" in res["other_host"]
    assert "'%' at character 3 of the path is not followed by two hexadecimal digits" \
           in res["bad_escape"]
    assert "only file URIs are supported" in res["http"]


def test_memory_does_not_grow_over_instantiations(fmu) -> None:
    """Row 7: 2,000 instantiate … free cycles; resident memory from cycle 200 to 2,000 grows by
    less than 2 MB (pythonfmu's own wrapper: 8.5 MB, leaked in findClass and the log buffer; the
    native FMU under the same fmpy host: 0.5 MB, fmpy's own)."""
    rss = _run(fmu, "instantiate_many")
    assert rss["2000"] - rss["200"] < 2048, rss


def test_documentation_says_what_each_flavour_needs(quick_fmu, native_fmu) -> None:
    def doc(path) -> str:
        with zipfile.ZipFile(path) as z:
            return z.read("documentation/index.html").decode()

    assert "with numpy on the importing side" in doc(quick_fmu)
    assert "LMNCELL_LIBPYTHON" in doc(quick_fmu)
    assert "no Python needed" in doc(native_fmu) and "PythonFMU" not in doc(native_fmu)
    for path in (quick_fmu, native_fmu):       # the limits beyond which both refuse a step
        text = " ".join(doc(path).split())
        assert "more than 10,000,000 model steps" in text and "beyond 1000 C" in text
        assert "a temperature outside -60…100 °C (°C, not K" in text


def test_random_call_sequences_never_crash_or_return_nan_with_ok(fmu) -> None:
    res = _run(fmu, "random_calls")
    assert res["calls"] > 300
    assert res["findings"] == []


@pytest.mark.slow
def test_many_random_call_sequences(fmu) -> None:
    res = _run(fmu, "random_calls_long")
    assert res["calls"] > 5000
    assert res["findings"] == []


FMUCHECK = os.environ.get("LMNCELL_FMUCHECK") or shutil.which("fmuCheck.linux64")


def _fmu_check(fmu, tmp_path, name: str) -> list[list[float]]:
    """Run the FMI Compliance Checker on an FMU through 600 s of a varying current and ambient
    temperature (its own input file); returns the output rows after asserting a clean log."""
    inp = tmp_path / "input.csv"
    inp.write_text('"time","current","temperature"\n' + "".join(
        f"{k},{-2.0 * math.sin(k / 30) - 0.5},{25 + 5 * math.sin(k / 200)}\n"
        for k in range(0, 601, 5)))
    out, log = tmp_path / f"{name}.csv", tmp_path / f"{name}.log"
    proc = subprocess.run([FMUCHECK, "-h", "1", "-s", "600", "-i", str(inp), "-o", str(out),
                           "-e", str(log), str(fmu)], capture_output=True, text=True,
                          timeout=600)
    text = log.read_text()
    assert proc.returncode == 0 and "\t0 Warning(s)" in text and "\t0 Error(s)" in text, text
    return [[float(x) for x in line.split(",")] for line in out.read_text().splitlines()[1:]]


FMIL = os.environ.get("LMNCELL_FMIL")      # an FMI Library install: its include/ and lib/


def _fmil_outputs(host: Path, fmu: Path) -> list[float]:
    """tests/native/fmil_check.c's run of an FMU: the outputs at 600 s, after asserting that
    FMIL found nothing wrong in its model description and every call returned fmi2OK."""
    proc = subprocess.run([str(host), str(fmu)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "XML problems 0, calls not OK 0" in proc.stdout, (
        proc.stdout[-3000:] + proc.stderr[-2000:])
    return [float(x) for x in proc.stdout.splitlines()[-1].split()[1:]]


@pytest.mark.skipif(FMIL is None, reason="the FMI Library is not installed (LMNCELL_FMIL=the "
                    "prefix of a build of modelon-community/fmi-library)")
def test_the_fmi_library_parses_and_runs_both_fmus_alike(quick_model, quick_fmu, native_fmu,
                                                         tmp_path) -> None:
    """FMIL (the parser and loader under PyFMI and the FMI Compliance Checker) reports no
    warning or error on either model description, and its C API runs both FMUs through 600 s
    of a varying current to the same outputs as the FMU engine (CellCosim)."""
    from lmncell.runtime.cosim import CellCosim, Parameters
    from lmncell.runtime.model import load_model

    c_compiler_or_skip()
    host = tmp_path / "fmil_check"
    subprocess.run(["gcc", "-std=c99", "-O1", f"-I{FMIL}/include",
                    str(ROOT / "tests" / "native" / "fmil_check.c"), "-o", str(host),
                    f"-L{FMIL}/lib", "-lfmilib_shared", f"-Wl,-rpath,{FMIL}/lib"], check=True)
    py, native = (_fmil_outputs(host, f) for f in (quick_fmu, native_fmu))
    model = load_model(quick_model)
    soc0 = next(float(v.start) for v in read_model_description(native_fmu).modelVariables
                if v.name == "soc0")
    engine = CellCosim(model, Parameters(soc0, model.capacity_ah))
    engine.reset(25.0)
    steps = round(600.0 / model.sample_time_s)
    for k in range(steps):
        phase = int(k * model.sample_time_s / 20.0) % 3
        engine.advance(model.sample_time_s, (-6.0, 0.0, 2.0)[phase], 25.0)
    expected = [engine.voltage_v, engine.soc, engine.cell_temperature_c]
    assert py == pytest.approx(expected, abs=1e-9) and native == pytest.approx(expected, abs=1e-9)


@pytest.mark.skipif(FMUCHECK is None, reason="the FMI Compliance Checker is not installed "
                    "(fmuCheck.linux64 on PATH, or LMNCELL_FMUCHECK=its path)")
def test_the_fmi_compliance_checker_passes_both_fmus_alike(quick_fmu, native_fmu,
                                                           tmp_path) -> None:
    """modelica-tools/FMUComplianceChecker (a C host on FMI Library) checks the model description
    and runs each FMU (the pythonfmu one loading the building Python itself). Both give the same
    outputs."""
    py, native = (_fmu_check(f, tmp_path, n) for f, n in ((quick_fmu, "py"), (native_fmu, "c")))
    assert len(py) == len(native) > 500
    assert abs(np.array(py) - np.array(native)).max() < 1e-9
