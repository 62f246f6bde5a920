"""Benchmark: microseconds per step of the LMNCell pythonfmu FMU through fmpy at 0.1 s and 1 s
communication steps, beside a trivial pythonfmu FMU built the same way (the floor), instantiate
time, the runtime step alone without FMI, and the observers' runtime cost per step (EKF,
fuzzy, IMM on a synthetic load; EKF and fuzzy also on the shipped US06 record's current,
voltage and cell temperature).

    python tests/benchmarks/bench_fmu.py [MODEL.json]

Without a model file, a model is trained on the shipped Panasonic HWFET record (M ≤ 8).
"""

from __future__ import annotations

import math
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from fmpy import extract

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from lmncell.runtime.model import load_model  # noqa: E402
from lmncell.runtime.step import CellStepper  # noqa: E402

from tests.fmu_helpers import Instance  # noqa: E402

TRIVIAL = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Trivial(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.current = 0.0
        self.temperature = 25.0
        self.voltage = 3.7
        self.soc = 0.5
        self.soc0 = 0.5
        self.register_variable(Real("current", causality=Fmi2Causality.input,
                                    variability=Fmi2Variability.continuous))
        self.register_variable(Real("temperature", causality=Fmi2Causality.input,
                                    variability=Fmi2Variability.continuous))
        self.register_variable(Real("voltage", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.continuous))
        self.register_variable(Real("soc", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.continuous))
        self.register_variable(Real("soc0", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))

    def do_step(self, current_time, step_size):
        return True
'''


def build_trivial(out: Path) -> Path:
    from pythonfmu.builder import FmuBuilder

    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "lmncell_trivial_bench.py"
        script.write_text(TRIVIAL)
        return FmuBuilder.build_FMU(script, dest=out)


def per_step_us(fmus: list[Path], h: float, n: int, repeats: int = 21
                ) -> tuple[list[float], float]:
    """Median µs per communication step of each FMU and the median of the per-round ratio of
    the first to the second: the FMUs run blocks of n steps in turn, so that a slow spell of
    the machine hits both alike."""
    dirs = [extract(str(f)) for f in fmus]
    insts = [Instance(f, start={"soc0": 0.9}, unzipped=d) for f, d in zip(fmus, dirs,
                                                                          strict=True)]
    try:
        runs: list[list[float]] = [[] for _ in fmus]
        for _ in range(repeats):
            for inst, out in zip(insts, runs, strict=True):
                t0 = time.perf_counter()
                for k in range(n):
                    inst.step(3.0 * math.sin(0.05 * k), h)    # zero mean: SoC stays near 0.9
                    inst.get("voltage", "soc")
                out.append(1e6 * (time.perf_counter() - t0) / n)
        ratio = statistics.median(a / b for a, b in zip(runs[0], runs[1], strict=True))
        return [statistics.median(r) for r in runs], ratio
    finally:
        for inst in insts:
            inst.free()
        for d in dirs:
            shutil.rmtree(d, ignore_errors=True)


def instantiate_ms(fmu: Path, n: int = 50) -> float:
    d = extract(str(fmu))
    try:
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            Instance(fmu, unzipped=d).free()
            times.append(time.perf_counter() - t0)
        return 1e3 * statistics.median(times)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def main() -> None:
    from lmncell.fmu.pythonfmu_build import build_fmu
    from lmncell.identification.train import train_files

    out = Path(tempfile.mkdtemp(prefix="lmncell_bench_"))
    if len(sys.argv) > 1:
        model_path = Path(sys.argv[1])
    else:
        model_path = out / "model.json"
        train_files([ROOT / "data/panasonic_18650pf/25degC/drive_cycles/"
                     "03-20-17_05.56_25degC_HWFTa_Pan18650PF.mat"], model_path,
                    capacity_ah=2.85, partition=["soc", "current"], progress=lambda _m: None)
    model = load_model(model_path)
    lmn = build_fmu(model_path, out / "lmn.fmu")
    trivial = build_trivial(out)
    n = 1000
    print(f"model: M = {model.n_local_models}, Ts = {model.sample_time_s} s, "
          f"{len(model.columns())} regressors")
    times = []
    for _ in range(7):
        st = CellStepper(model, 0.9)
        t0 = time.perf_counter()
        for k in range(3000):
            st.step(-1.0 - 0.5 * (k % 7), 25.0)
        times.append((time.perf_counter() - t0) / 3000)
    print(f"runtime step alone (no FMI): {1e6 * statistics.median(times):.2f} µs per model step "
          "(median of 7 runs)")
    for h in (0.1, 1.0):
        (a, b), ratio = per_step_us([lmn, trivial], h, n)
        print(f"through fmpy at h = {h} s (set inputs, doStep, get 2 outputs; medians of 21 "
              f"alternating blocks of {n} steps): LMNCell {a:.1f} µs/step, trivial {b:.1f} "
              f"µs/step, ratio {ratio:.2f} (median of the blocks' ratios)")
    print(f"instantiate + initialise + free: LMNCell {instantiate_ms(lmn):.2f} ms, trivial "
          f"{instantiate_ms(trivial):.2f} ms (median of 50)")
    observers_main(model_path, lmn)
    observers_on_record(model_path, ROOT / "data/panasonic_18650pf/25degC/drive_cycles/"
                        "03-20-17_01.43_25degC_US06_Pan18650PF.mat")
    shutil.rmtree(out, ignore_errors=True)


def observers_main(model_path: Path, fmu: Path, blocks: int = 21, n: int = 500) -> None:
    """Per-step cost of each observer in the runtime (the observers take turns in blocks of n
    steps, medians of the blocks; the EKF/fuzzy ratio is the median of the blocks' ratios) and
    through the FMU (fmpy, h = Ts)."""
    from lmncell.runtime.observers import SocObserver

    model = load_model(model_path)
    kinds = ("ekf", "fuzzy", "imm")
    observers = {kind: SocObserver(model, kind, 0.5) for kind in kinds}
    runtime: dict[str, list[float]] = {kind: [] for kind in kinds}
    for _ in range(blocks):
        for kind, ob in observers.items():
            t0 = time.perf_counter()
            for k in range(n):
                ob.step(-1.0 - 0.5 * (k % 7), 3.7, 25.0)
            runtime[kind].append(1e6 * (time.perf_counter() - t0) / n)
    for code, kind in enumerate(kinds, start=1):
        d = extract(str(fmu))
        inst = Instance(fmu, start={"soc0": 0.5}, unzipped=d, observer=code)
        t0 = time.perf_counter()
        for k in range(2000):
            inst.slave.setReal([inst.vr["voltage_measured"]], [3.7])
            inst.step(-1.0 - 0.5 * (k % 7), model.sample_time_s)
            inst.get("soc", "soc_std")
        fm = 1e6 * (time.perf_counter() - t0) / 2000
        inst.free()
        shutil.rmtree(d, ignore_errors=True)
        print(f"observer {kind:5s}: runtime {statistics.median(runtime[kind]):7.1f} µs/step "
              f"(median of {blocks} blocks of {n} steps), through fmpy {fm:7.1f} µs/step")
    ratio = statistics.median(e / f for e, f in zip(runtime["ekf"], runtime["fuzzy"],
                                                    strict=True))
    fastest = min(runtime["ekf"]) / min(runtime["fuzzy"])
    print(f"runtime EKF / fuzzy: {ratio:.2f} (median of the blocks' ratios), {fastest:.2f} "
          f"(fastest block over fastest block: {min(runtime['ekf']):.1f} / "
          f"{min(runtime['fuzzy']):.1f} µs/step, less touched by the machine's slow spells)")


def observers_on_record(model_path: Path, record: Path, block: int = 500) -> None:
    """EKF and fuzzy observer per step in the runtime on a measured record's current, voltage
    and cell temperature (a temperature that changes from step to step, as a cell's does),
    taking turns in blocks of `block` steps; the ratio is the median of the blocks' ratios."""
    from lmncell.data.dataset import record_to_segments, start_soc
    from lmncell.data.readers import read_record
    from lmncell.runtime.observers import SocObserver

    model = load_model(model_path)
    rec = read_record(record)
    seg = record_to_segments(rec, model.sample_time_s, start_soc(rec, 1.0),
                             model.capacity_ah)[0]
    temperature = (seg.temperature_c.tolist() if seg.temperature_c is not None
                   else [25.0] * len(seg.current_a))
    inputs = list(zip(seg.current_a.tolist(), seg.voltage_v.tolist(), temperature,
                      strict=True))
    observers = {kind: SocObserver(model, kind, 0.9) for kind in ("ekf", "fuzzy")}
    runs: dict[str, list[float]] = {kind: [] for kind in observers}
    for start in range(0, len(inputs) - block + 1, block):
        for kind, ob in observers.items():
            t0 = time.perf_counter()
            for i, v, t in inputs[start:start + block]:
                ob.step(i, v, t)
            runs[kind].append(1e6 * (time.perf_counter() - t0) / block)
    ratio = statistics.median(e / f for e, f in zip(runs["ekf"], runs["fuzzy"], strict=True))
    print(f"on {record.name} ({len(runs['ekf'])} blocks of {block} steps, its cell "
          f"temperature): runtime EKF {statistics.median(runs['ekf']):.1f} µs/step, fuzzy "
          f"{statistics.median(runs['fuzzy']):.1f} µs/step, EKF / fuzzy {ratio:.2f} (median "
          "of the blocks' ratios)")


if __name__ == "__main__":
    main()
