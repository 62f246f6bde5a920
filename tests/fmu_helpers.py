"""Driving an FMU instance step by step with fmpy's FMU2Slave (tests and benchmarks)."""

from __future__ import annotations

from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave


class Instance:
    """An instantiated, initialised co-simulation FMU with name-based access."""

    def __init__(self, fmu: str | Path, name: str = "inst", start: dict | None = None,
                 unzipped: str | None = None, logger=None) -> None:
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
            self.slave.setReal([self.vr[k]], [float(v)])
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
