"""Benchmark: the native LMNCell FMU per step in a plain C host and through fmpy, beside the
pythonfmu FMU and the trivial-FMU floors (the same native FMU with the model step left out, and
a trivial pythonfmu FMU).

    python tests/benchmarks/bench_native.py [MODEL.json]

Without a model file, a model is trained on the shipped Panasonic HWFET and HPPC records.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.benchmarks.bench_fmu import build_trivial, per_step_us  # noqa: E402


def host_us(host: Path, fmu: Path, n: int, observer: int, tmp: Path, runs_n: int = 15
            ) -> tuple[float, float]:
    """Median and fastest µs per step of runs_n host runs of n steps (a shared machine's slow
    spells move the median; the fastest run is the machine's own speed)."""
    d = tmp / f"x{observer}{fmu.stem}"
    with zipfile.ZipFile(fmu) as z:
        z.extractall(d)
        guid = re.search(r'guid="([^"]+)"', z.read("modelDescription.xml").decode()).group(1)
    cur = -1.0 - 0.5 * (np.arange(n) % 7)
    (tmp / "c.txt").write_text("\n".join(repr(float(x)) for x in cur))
    (tmp / "v.txt").write_text("\n".join("3.7" for _ in range(n)))
    runs = []
    for _ in range(runs_n):
        out = subprocess.run([str(host), str(d / "binaries/linux64/LMNCell.so"),
                              (d / "resources").as_uri(), guid, str(tmp / "c.txt"), "1.0", "0.9",
                              str(observer), str(tmp / "v.txt")], capture_output=True, text=True,
                             check=True).stdout
        runs.append(float(re.search(r"us_per_step (\S+)", out)[1]))
    return float(np.median(runs)), min(runs)


def main() -> None:
    from lmncell.fmu.native_build import build_native_fmu, fmi_headers
    from lmncell.fmu.pythonfmu_build import build_fmu
    from lmncell.identification.train import train_files

    tmp = Path(tempfile.mkdtemp(prefix="lmncell_native_bench_"))
    if len(sys.argv) > 1:
        model = Path(sys.argv[1])
    else:
        model = tmp / "model.json"
        d = ROOT / "data/panasonic_18650pf/25degC"
        train_files([d / "drive_cycles/03-20-17_05.56_25degC_HWFTa_Pan18650PF.mat",
                     d / "hppc/03-11-17_08.47_25degC_5Pulse_HPPC_Pan18650PF.mat"], model,
                    capacity_ah=2.85, soc0=1.0, partition=["soc", "current"],
                    progress=lambda _m: None)
    from lmncell.runtime.model import load_model

    m = load_model(model)
    print(f"model: M = {m.n_local_models} local models, {len(m.node_weights)} nodes, "
          f"{len(m.columns())} regressors, Ts = {m.sample_time_s} s")
    native = build_native_fmu(model, tmp / "native.fmu")
    floor_fmu = build_native_fmu(model, tmp / "floor.fmu", trivial=True)
    py = build_fmu(model, tmp / "py.fmu")
    py_floor = build_trivial(tmp)
    host = tmp / "host"
    subprocess.run(["gcc", "-std=c99", "-O2", f"-I{fmi_headers()}",
                    str(ROOT / "tests/native/host.c"), "-o", str(host), "-ldl"], check=True)
    n = 200_000
    alone = None
    for obs, name in ((0, "LMN"), (1, "LMN + EKF"), (2, "LMN + fuzzy"), (3, "LMN + IMM")):
        (med, fast), (floor, _) = (host_us(host, native, n, obs, tmp),
                                   host_us(host, floor_fmu, n, obs, tmp))
        alone = med if alone is None else alone
        print(f"C host, {name}: {med:.3f} µs/step ({med / alone:.2f}× the LMN alone), fastest "
              f"run {fast:.3f} (floor {floor:.3f} µs/step; medians of 15 runs × {n} steps, "
              "a measurement at every step)")
    for h in (0.1, 1.0):
        (a, b), ratio = per_step_us([native, floor_fmu], h, 1000)
        (c, e), _ = per_step_us([py, py_floor], h, 1000)
        print(f"fmpy at h = {h} s: native {a:.2f} µs/step, native floor {b:.2f} (ratio "
              f"{ratio:.2f}); pythonfmu {c:.2f}, pythonfmu floor {e:.2f} (medians of 21 "
              "alternating blocks of 1000 steps)")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
