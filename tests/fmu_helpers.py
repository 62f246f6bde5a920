"""Driving an FMU instance step by step with fmpy's FMU2Slave (tests and benchmarks)."""

from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

HOST_C = Path(__file__).parent / "native" / "host.c"         # a C host of the native FMU
THREADS_C = Path(__file__).parent / "native" / "threads.c"   # the same, many threads


def compile_host(source: Path, exe: Path, *libs: str) -> Path:
    """A test host from tests/native/ compiled with gcc (skip without it)."""
    from lmncell.fmu.native_build import fmi_headers

    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed")
    subprocess.run(["gcc", "-std=c99", "-O1", f"-I{fmi_headers()}", str(source), "-o", str(exe),
                    "-ldl", *libs], check=True)
    return exe


MODEL_EXCHANGE_ONLY = {f"fmi2{name}" for name in (
    "EnterEventMode", "NewDiscreteStates", "EnterContinuousTimeMode", "CompletedIntegratorStep",
    "SetTime", "SetContinuousStates", "GetDerivatives", "GetEventIndicators",
    "GetContinuousStates", "GetNominalsOfContinuousStates")}


def co_simulation_functions() -> set[str]:
    """Every function of the FMI 2.0 API (fmpy's fmi2Functions.h) that a co-simulation FMU
    exports: the common ones and those for co-simulation."""
    from lmncell.fmu.native_build import fmi_headers

    text = (fmi_headers() / "fmi2Functions.h").read_text()
    return set(re.findall(r"FMI2_Export\s+fmi2\w+TYPE\s+(fmi2\w+);", text)) - MODEL_EXCHANGE_ONLY


def hostile_inputs(n: int, seed: int) -> tuple[list[str], list[str]]:
    """n currents of a noisy square-and-sine drive (A) and measured voltages (V), a tenth of
    each replaced by NaN, ±inf, ±1e308 or nonsense, as text for host.c."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    cur = (-2.0 * np.sin(t / 30.0) - 0.5 + rng.normal(0.0, 1.0, n)).astype(object)
    volts = (3.3 + 0.2 * np.sin(t / 300.0)).astype(object)
    cur[rng.choice(n, n // 10, replace=False)] = rng.choice(
        ["nan", "inf", "-inf", "1e308", "-1e308", "0"], n // 10)
    volts[rng.choice(n, n // 10, replace=False)] = rng.choice(["nan", "0.5", "4.9", "-1"], n // 10)
    return [str(x) for x in cur], [str(x) for x in volts]


def comparable(stdout: str) -> list[str]:
    """host.c's output without its timing and its libpython probe (-1 on Windows)."""
    lines = [ln for ln in stdout.splitlines() if not ln.startswith("us_per_step")]
    return [re.sub(r" libpython -?\d$", "", ln) for ln in lines]


def linux64_reference_run(d: Path, guid: str, observer: int, resource_uri: str
                          ) -> tuple[list[str], subprocess.CompletedProcess]:
    """host.c's arguments for 3000 hostile steps (hostile_inputs, written into d) with an
    observer, and the run of d/host (host.c built for Linux) on d/fmu's linux64 binary with
    them: what another platform's build of the same C is compared with (assert_same_run)."""
    cur, volts = hostile_inputs(3000, observer)
    (d / f"c{observer}.txt").write_text("\n".join(cur))
    (d / f"v{observer}.txt").write_text("\n".join(volts))
    args = [resource_uri, guid, f"c{observer}.txt", "1.0", "0.9", str(observer),
            f"v{observer}.txt"]
    linux = subprocess.run([str(d / "host"), "fmu/binaries/linux64/LMNCell.so", *args],
                           cwd=d, capture_output=True, text=True, timeout=300)
    return args, linux


def assert_same_run(got: str, expected: str, atol: float) -> None:
    """host.c's output got equals expected: every message in order, the steps and refused
    steps, and the final voltage, SoC and σ within atol (the C libraries' exp and log, and
    the compilers' contraction of a·b + c, may differ in the last bits)."""
    want, have = comparable(expected), comparable(got)
    assert re.search(r"steps 3000 errors [1-9]\d+ voltage", want[-1]), want[-1]
    assert any("the step was not taken" in ln for ln in want)   # refusals logged
    assert have[:-1] == want[:-1]                                # every message, in order
    numbers = [[float(x) for x in re.findall(r"-?\d[\d.e+-]*", ln)] for ln in (have[-1], want[-1])]
    assert numbers[0][:2] == numbers[1][:2]                      # steps, refused steps
    assert np.allclose(numbers[0][2:], numbers[1][2:], rtol=0.0, atol=atol), numbers


def cross_built_fmu(model: Path, folder: Path, platform: str) -> Path:
    """The model's native FMU with linux64 and `platform` binaries (the latter cross-compiled
    with zig), in folder; skip without a C compiler (gcc, or zig)."""
    import lmncell

    from tests.conftest import c_compiler_or_skip

    c_compiler_or_skip()
    return lmncell.build_fmu(model, folder / "cell.fmu", native=True,
                             platforms=("linux64", platform))


def unzip_fmu(fmu: Path, d: Path) -> str:
    """Extract an FMU into d; returns its GUID."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(d)
        found = re.search(r'guid="([^"]+)"', z.read("modelDescription.xml").decode())
    assert found, f"{fmu}: no GUID in modelDescription.xml"
    return found.group(1)


class Instance:
    """An instantiated, initialised co-simulation FMU with name-based access."""

    def __init__(self, fmu: str | Path, name: str = "inst", start: dict | None = None,
                 unzipped: str | None = None, logger=None, observer: int = 0) -> None:
        self.md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.dir = unzipped or extract(str(fmu))
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier,
                               instanceName=name)
        kw = {"loggingOn": True}
        if logger is not None:
            kw["callbacks"] = None
        self.slave.instantiate(**kw)
        if logger is not None:
            self.slave.fmi2SetDebugLogging(self.slave.component, True, 0, None)
        self.slave.setupExperiment(startTime=0.0)
        self.slave.enterInitializationMode()
        for k, v in (start or {}).items():
            if isinstance(v, bool):
                self.slave.setBoolean([self.vr[k]], [v])
            else:
                self.slave.setReal([self.vr[k]], [float(v)])
        if observer:
            self.slave.setInteger([self.vr["observer"]], [observer])
        self.slave.exitInitializationMode()
        self.t = 0.0

    def step(self, current: float, h: float = 1.0, temperature: float = 25.0):
        self.slave.setReal([self.vr["current"], self.vr["temperature"]], [current, temperature])
        status = self.slave.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h
        return status

    def get(self, *names: str) -> list[float]:
        return self.slave.getReal([self.vr[n] for n in names])

    def free(self) -> None:
        self.slave.terminate()
        self.slave.freeInstance()


def libcosim_run(fmu: str | Path, soc0: float, current_a: float, seconds: int) -> list[float]:
    """Voltage and SoC after `seconds` 1-s steps at a constant current in DNV libcosim."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_step_size(step_size=int(1e9))
    idx = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="cell"))
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    man = CosimManipulator.create_override()
    ex.add_manipulator(man)
    refs = {(v.name.decode() if isinstance(v.name, bytes) else v.name): v.reference
            for v in ex.slave_variables(idx)}
    ex.real_initial_value(idx, refs["soc0"], soc0)
    man.slave_real_values(idx, [refs["current"]], [current_a])
    ex.simulate_until(int(seconds * 1e9))
    return list(obs.last_real_values(idx, [refs["voltage"], refs["soc"]]))


def fmpy_run(fmu: str | Path, soc0: float, current_a: float, seconds: int) -> list[float]:
    """The same through fmpy."""
    inst = Instance(fmu, start={"soc0": soc0})
    try:
        for _ in range(seconds):
            inst.step(current_a)
        return inst.get("voltage", "soc")
    finally:
        inst.free()


def assert_state_round_trips(inst: Instance, currents, h: float = 1.0, volts=None,
                             outputs: tuple[str, ...] = ("voltage", "soc")) -> list:
    """Save the FMU state (directly and serialized), run on, restore each and run the same
    inputs again: the outputs must be identical. Returns the reference outputs."""
    def run() -> list:
        out = []
        for k, i in enumerate(currents):
            if volts is not None:
                inst.slave.setReal([inst.vr["voltage_measured"]], [float(volts[k])])
            inst.step(float(i), h=h)
            out.append(inst.get(*outputs))
        return out

    state = inst.slave.getFMUstate()
    blob = inst.slave.serializeFMUstate(state)
    t0 = inst.t
    ref = run()
    for restore in (state, inst.slave.deSerializeFMUstate(blob)):
        inst.slave.setFMUstate(restore)
        inst.t = t0
        assert run() == ref
    inst.slave.freeFMUstate(state)
    return ref


def refuse_bad_current(inst: Instance, bad: float, capfd) -> tuple[int, str]:
    """Step with a bad current: the call must fail and leave voltage and SoC as they were.
    Returns the FMI status of the failure and the text the FMU logged meanwhile."""
    import pytest
    from fmpy.fmi1 import FMICallException

    capfd.readouterr()
    before = inst.get("voltage", "soc")
    with pytest.raises(FMICallException) as err:
        inst.step(bad)
    assert inst.get("voltage", "soc") == before   # nothing advanced
    return err.value.status, capfd.readouterr().out


def valgrind_reports(stderr: str) -> list[str]:
    """Valgrind's stderr split into its reports (a report ends at a line with only the pid)."""
    reports, current = [], []
    for line in stderr.splitlines():
        body = line.split("== ", 1)[1] if line.startswith("==") and "== " in line else ""
        if body.strip():
            current.append(body)
        elif current:
            reports.append("\n".join(current))
            current = []
    return reports + (["\n".join(current)] if current else [])


def fmu_reports(stderr: str) -> list[str]:
    """Valgrind's reports whose stack passes through an FMU binary or pythonfmu's exit-time
    finalizePythonInterpreter; glibc's own false positives (dl-load) and valgrind's banner (with
    the host's command line) are left out."""
    return [r for r in valgrind_reports(stderr) if "by 0x" in r or "at 0x" in r
            if "binaries/linux64" in r or "finalizePythonInterpreter" in r]
