"""Benchmark: LMN training time against samples and local models, free-run throughput (batch and
step by step), and the 2RC baseline fit, all in one run.

    python tests/benchmarks/bench_identification.py [--max-samples 1000000]

Data: the shipped Panasonic US06 and HWFET records at Ts = 1 s, repeated as separate segments
to reach 10k, 100k and 1M samples. Prints medians of repeated timings where cheap.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from lmncell.config import load_config
from lmncell.data.dataset import Segment, record_to_segments
from lmncell.data.readers import read_record
from lmncell.identification.baselines import fit_ecm2rc
from lmncell.identification.construction import train_lmn
from lmncell.runtime.step import CellStepper, simulate

ROOT = Path(__file__).resolve().parents[2]
FILES = [ROOT / "data/panasonic_18650pf/25degC/drive_cycles" / n for n in
         ("03-20-17_01.43_25degC_US06_Pan18650PF.mat", "03-20-17_05.56_25degC_HWFTa_Pan18650PF.mat")]


def segments(n_samples: int) -> list[Segment]:
    base = [s for f in FILES for s in record_to_segments(read_record(f), 1.0, 1.0, 2.85)]
    out, total, k = [], 0, 0
    while total < n_samples:
        s = base[k % len(base)]
        take = min(len(s), n_samples - total)
        out.append(Segment(f"{s.name}#{k}", s.time_s[:take], s.current_a[:take],
                           s.voltage_v[:take], s.temperature_c[:take], s.soc0,
                           s.soc_ref[:take], s.weight[:take]))
        total += take
        k += 1
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-samples", type=int, default=1_000_000)
    args = ap.parse_args()
    print("LMN training time (s) by samples and maximum local models (stop rule off: all M)")
    for n in (10_000, 100_000, 1_000_000):
        if n > args.max_samples:
            continue
        segs = segments(n)
        for m in (1, 4, 8):
            cfg = load_config(max_local_models=m, stop="aicc", validation="none",
                              hysteresis="off", partition=["soc", "current"])
            t0 = time.perf_counter()
            res = train_lmn(segs, cfg, 2.85)
            dt = time.perf_counter() - t0
            print(f"  N={n:>9,d}  M≤{m}: {dt:8.2f} s  ({1e6 * dt / n:.2f} µs/sample, "
                  f"M chosen {res.chosen_m})", flush=True)
        if n == 100_000:
            t0 = time.perf_counter()
            _, info = fit_ecm2rc(segs, [s.soc_ref for s in segs], res.model.ocv_soc,
                                 res.model.ocv_v, 2.85, 1.0, None, [1.0] * len(segs))
            print(f"  N={n:>9,d}  2RC baseline fit: {time.perf_counter() - t0:8.2f} s "
                  f"({info['evaluations']} evaluations)", flush=True)
    segs = segments(20_000)
    model = train_lmn(segs, load_config(max_local_models=8, hysteresis="off",
                                        partition=["soc", "current"]), 2.85).model
    s = max(segs, key=len)
    batch = []
    for _ in range(5):
        t0 = time.perf_counter()
        simulate(model, s.current_a, s.temperature_c, s.soc0)
        batch.append((time.perf_counter() - t0) / len(s))
    st = CellStepper(model, s.soc0)
    cur, temp = s.current_a.tolist(), s.temperature_c.tolist()
    steps = []
    for _ in range(3):
        t0 = time.perf_counter()
        for i, t in zip(cur, temp, strict=True):
            st.step(i, t)
        steps.append((time.perf_counter() - t0) / len(cur))
    print(f"free-run throughput, M={model.n_local_models}: batch "
          f"{1e6 * statistics.median(batch):.2f} µs/step "
          f"({1 / statistics.median(batch):,.0f} steps/s); step by step "
          f"{1e6 * statistics.median(steps):.2f} µs/step; ratio "
          f"{statistics.median(steps) / statistics.median(batch):.1f}")
    _ = np


if __name__ == "__main__":
    main()
