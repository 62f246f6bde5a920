"""FMU against pipeline: the FMU driven by fmpy with a record's current must reproduce the
pipeline's free-run voltage and SoC, driven by the measured cell temperature
(temperature_is_cell = true) or by the ambient temperature (the FMU's thermal model)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from lmncell.data.dataset import Segment, record_to_segments, start_soc
from lmncell.data.readers import read_record
from lmncell.evaluation.evaluate import ambient_of, model_ocv, simulate_segment
from lmncell.runtime.cosim import held_delayed_currents
from lmncell.runtime.model import load_model
from lmncell.runtime.step import initial_hysteresis, simulate_ambient


def fmu_input(seg: Segment, ts: float, temperature_c: np.ndarray | None = None) -> np.ndarray:
    """fmpy input signal: sample k holds the current of model step k+1 from time k·Ts;
    temperature_c replaces the segment's temperature (e.g. the ambient)."""
    n = len(seg)
    sig = np.zeros(n + 1, dtype=[("time", float), ("current", float), ("temperature", float),
                                 ("voltage_measured", float)])    # 0: not measured
    sig["time"] = ts * np.arange(n + 1)
    sig["current"][:n] = seg.current_a
    sig["current"][n] = seg.current_a[-1]
    temp = temperature_c if temperature_c is not None else seg.temperatures()
    sig["temperature"][:n] = temp
    sig["temperature"][n] = temp[-1]
    return sig


def run_fmu_on_segment(fmu: str | Path, seg: Segment, ts: float, step_s: float | None = None,
                       ambient: bool = False, cell_temperature_start_c: float | None = None
                       ) -> np.ndarray:
    """fmpy result (time, voltage, soc, cell_temperature, out_of_range) of the FMU driven with
    the segment's current and its measured temperature as the cell temperature or (ambient) its
    ambient, the cell then starting at cell_temperature_start_c (°C) where given."""
    from fmpy import simulate_fmu

    n = len(seg)
    signal = fmu_input(seg, ts, ambient_of(seg) if ambient else None)
    start: dict[str, float | bool] = {"soc0": seg.soc0, "temperature_is_cell": not ambient}
    if cell_temperature_start_c is not None:
        start |= {"use_cell_temperature_start": True,
                  "cell_temperature_start": cell_temperature_start_c}
    return simulate_fmu(str(fmu), start_time=0.0, stop_time=n * ts, step_size=step_s or ts,
                        output_interval=ts, input=signal, start_values=start,
                        output=["voltage", "soc", "cell_temperature", "out_of_range"])


def compare_fmu_with_pipeline(model_path: str | Path, fmu: str | Path, record: str | Path,
                              soc0: float | None = None, max_steps: int | None = None,
                              ambient: bool = False,
                              cell_temperature_start_c: float | None = None) -> dict:
    """Largest voltage and SoC differences between the FMU (through fmpy) and the pipeline on
    a record's first segment; ambient: both driven by the ambient temperature only, the cell
    starting at cell_temperature_start_c (°C) where given. The FMU
    gets the segment's step means held over steps of Ts; a model with a current delay delays
    them itself, and the pipeline is given what it then takes (held_delayed_currents)."""
    model = load_model(model_path)
    rec = read_record(record)
    seg = record_to_segments(rec, model.sample_time_s, start_soc(rec, soc0, model_ocv(model)),
                             model.capacity_ah)[0]
    if max_steps is not None and len(seg) > max_steps:
        seg = seg.head(max_steps)
    fmu_seg = seg
    seg = dataclasses.replace(seg, current_a=np.array(held_delayed_currents(
        seg.current_a.tolist(), model.sample_time_s, model.current_delay_s)))
    if ambient:
        sim, cell = simulate_ambient(model, seg.current_a, ambient_of(seg), seg.soc0, None,
                                     initial_hysteresis(seg.soc0), cell_temperature_start_c)
    else:
        sim = simulate_segment(model, seg)
        cell = seg.temperatures()
    res = run_fmu_on_segment(fmu, fmu_seg, model.sample_time_s, ambient=ambient,
                             cell_temperature_start_c=cell_temperature_start_c)
    n = len(seg)
    v, s, t = res["voltage"][1:n + 1], res["soc"][1:n + 1], res["cell_temperature"][1:n + 1]
    return {"record": seg.name, "steps": n, "ambient": ambient,
            "max_dv_v": float(np.max(np.abs(v - sim.voltage_v))),
            "max_dsoc": float(np.max(np.abs(s - sim.soc))),
            # the FMU shows the cell temperature at the end of each step: the next step's
            "max_dtemperature_k": float(np.max(np.abs(t[:-1] - cell[1:]) if ambient
                                               else np.abs(t - cell))),
            "fmu_voltage_v": v, "pipeline_voltage_v": sim.voltage_v, "time_s": seg.time_s,
            "fmu_cell_temperature_c": t}
