"""FMI 2.0 call sequences for tests/test_conformance.py, each run in a child process so that a
crash of the host is a test failure, not the end of the run:

    python -m tests.conformance_sequences FMU SEQUENCE    → prints one JSON object

Each sequence returns the statuses (0 OK … 4 fatal) and values the test then checks.
"""

from __future__ import annotations

import json
import math
import sys

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from tests.fmu_helpers import Instance

OK = 0


def _status(call) -> int:
    """The FMI status of a call (0 when it returned OK or warning-free)."""
    try:
        call()
        return OK
    except FMICallException as exc:
        return int(exc.status)


def _raw(fmu: str, logging: bool = True):
    md = read_model_description(fmu)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="raw")
    slave.instantiate(loggingOn=logging)
    return slave, {v.name: v.valueReference for v in md.modelVariables}


def init_mode_outputs(fmu: str) -> dict:
    """Row 2: outputs read in Initialization Mode equal those right after it."""
    slave, vr = _raw(fmu)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["soc0"], vr["temperature"]], [0.55, 31.0])
    names = ["voltage", "soc", "soc_std", "cell_temperature"]
    before = slave.getReal([vr[n] for n in names])
    slave.exitInitializationMode()
    after = slave.getReal([vr[n] for n in names])
    slave.terminate()
    slave.freeInstance()
    return {"before": before, "after": after}


def state_machine(fmu: str) -> dict:
    """Row 4: calls out of order and a communication point that is not the FMU's time."""
    out = {}
    slave, _ = _raw(fmu)
    out["exit_without_enter"] = _status(slave.exitInitializationMode)
    slave.freeInstance()
    inst = Instance(fmu)
    out["first_step"] = _status(lambda: inst.slave.doStep(0.0, 1.0))
    out["wrong_point"] = _status(lambda: inst.slave.doStep(5.0, 1.0))
    out["right_point"] = _status(lambda: inst.slave.doStep(1.0, 1.0))
    out["tiny_step"] = _status(lambda: inst.slave.doStep(2.0, 1e-12))
    out["after_tiny"] = _status(lambda: inst.slave.doStep(2.0 + 1e-12, 1.0))
    inst.slave.terminate()
    out["step_after_terminate"] = _status(lambda: inst.slave.doStep(3.0 + 1e-12, 1.0))
    inst.slave.freeInstance()
    return out


def impossible_inputs(fmu: str) -> dict:
    """Row 5: a finite but absurd current and a temperature below absolute zero are refused;
    the outputs stay finite and unchanged."""
    inst = Instance(fmu)
    inst.step(-2.0)
    before = inst.get("voltage", "soc")
    out = {"huge_current": _status(lambda: inst.step(1e308)), "after_huge": inst.get(
        "voltage", "soc")}
    out["below_zero_kelvin"] = _status(lambda: inst.step(-1.0, temperature=-300.0))
    out["after_cold"] = inst.get("voltage", "soc")
    out["nan_current"] = _status(lambda: inst.step(math.nan))
    out["after_nan"] = inst.get("voltage", "soc")
    out["before"] = before
    out["still_steps"] = _status(lambda: inst.step(-1.0))
    out["finite"] = all(math.isfinite(x) for x in inst.get("voltage", "soc", "soc_std"))
    inst.free()
    return out


def observers_at_full(fmu: str) -> dict:
    """Issue 19: each observer from SoC 1.0 with a ±2 A square wave that starts by charging,
    the FMU's own voltage fed back as the measurement, then contradictory measurements."""
    out = {}
    for observer in (1, 2, 3):
        inst = Instance(fmu, start={"soc0": 1.0}, observer=observer)
        worst, finite = OK, True
        v = inst.get("voltage")[0]
        for k in range(600):
            i = 2.0 if (k // 30) % 2 == 0 else -2.0
            meas = v if k < 300 else (0.5 if k % 2 else 4.9)
            inst.slave.setReal([inst.vr["voltage_measured"]], [meas])
            worst = max(worst, _status(lambda i=i, inst=inst: inst.step(i)))
            v, soc, sd = inst.get("voltage", "soc", "soc_std")
            finite = finite and all(math.isfinite(x) for x in (v, soc, sd)) and 0 <= soc <= 1
        out[str(observer)] = {"worst_status": worst, "finite": finite}
        inst.free()
    return out


def ordinary_errors(fmu: str) -> dict:
    """Row 1 and 7: unknown references, wrong types, outputs and fixed parameters set after
    initialisation, bad parameters at exitInitializationMode: no crash, nothing changed."""
    out = {}
    inst = Instance(fmu, start={"soc0": 0.8})
    inst.step(-1.0)
    out["unknown_get"] = [_status(lambda: inst.slave.getReal([999])) for _ in range(6)]
    out["set_output"] = _status(lambda: inst.slave.setReal([inst.vr["voltage"]], [1.0]))
    out["set_fixed"] = _status(lambda: inst.slave.setReal([inst.vr["soc0"]], [0.2]))
    out["soc0_after"] = inst.get("soc0")[0]
    out["set_observer"] = _status(lambda: inst.slave.setInteger([inst.vr["observer"]], [2]))
    out["wrong_type"] = _status(lambda: inst.slave.setInteger([inst.vr["current"]], [1]))
    out["steps_after"] = _status(lambda: inst.step(-1.0))
    out["finite"] = all(math.isfinite(x) for x in inst.get("voltage", "soc"))
    inst.free()
    slave, vr = _raw(fmu)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr["soc0"]], [2.0])
    out["bad_param_exit"] = _status(slave.exitInitializationMode)
    out["step_uninitialised"] = _status(lambda: slave.doStep(0.0, 1.0))
    slave.freeInstance()
    return out


def wrong_guid_or_type(fmu: str) -> dict:
    """Row 7: fmi2Instantiate with another FMU's GUID, as Model Exchange, with an empty or a
    missing resource location is refused (NULL); the right GUID instantiates."""
    import pathlib
    from ctypes import byref

    from fmpy.fmi2 import defaultCallbacks, fmi2CoSimulation, fmi2ModelExchange

    class Raw(FMU2Slave):
        """fmpy's slave with a chosen FMU type and resource location for fmi2Instantiate."""

        fmu_type, uri = fmi2CoSimulation, None

        def instantiate(self, visible=False, callbacks=None, loggingOn=False):
            self.callbacks = defaultCallbacks
            uri = (pathlib.Path(self.unzipDirectory, "resources").as_uri() if self.uri is None
                   else self.uri)
            self.component = self.fmi2Instantiate(self.instanceName.encode(), self.fmu_type,
                                                  self.guid.encode(), uri.encode(),
                                                  byref(self.callbacks), visible, loggingOn)
            if self.component is None:
                raise RuntimeError("Failed to instantiate model")

    class AsModelExchange(Raw):
        fmu_type = fmi2ModelExchange

    class NoResources(Raw):
        uri = ""

    class MissingResources(Raw):
        uri = "file:///nonexistent/lmncell/resources"

    md = read_model_description(fmu)
    out = {}
    for key, guid, cls in (("wrong_guid", "{00000000-0000-0000-0000-000000000000}", FMU2Slave),
                           ("model_exchange", md.guid, AsModelExchange),
                           ("no_resources", md.guid, NoResources),
                           ("missing_resources", md.guid, MissingResources),
                           ("right", md.guid, FMU2Slave)):
        slave = cls(guid=guid, unzipDirectory=extract(fmu),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=key)
        try:
            slave.instantiate(loggingOn=False)
        except Exception:
            out[key] = "refused"
            continue
        out[key] = "instantiated"
        slave.freeInstance()
    return out


def _rss_kb() -> int:
    """Resident set size of this process (kB, Linux)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4


def instantiate_many(fmu: str, cycles: int = 2000) -> dict:
    """Row 7: memory over many instantiate/setup/initialise/step/free cycles (kB of resident
    memory after the first 200 cycles and after all)."""
    md = read_model_description(fmu)
    where = extract(fmu)
    rss = {}
    for k in range(cycles):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=where,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"i{k}")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slave.doStep(0.0, 1.0)
        slave.terminate()
        slave.freeInstance()
        if k + 1 in (200, cycles):
            rss[str(k + 1)] = _rss_kb()
    return rss


SEQUENCES = {f.__name__: f for f in (init_mode_outputs, state_machine, impossible_inputs,
                                      observers_at_full, ordinary_errors, wrong_guid_or_type,
                                      instantiate_many)}

if __name__ == "__main__":
    print(json.dumps(SEQUENCES[sys.argv[2]](sys.argv[1])))
