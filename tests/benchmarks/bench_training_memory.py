"""Benchmark: peak memory of LMN training against the number of samples, in one run.

    python tests/benchmarks/bench_training_memory.py [--max-samples 1000000]

Data: the shipped Panasonic US06 and HWFET records at Ts = 1 s, repeated as separate segments
to reach 30k, 100k, 300k and 1M samples (bench_identification.segments), trained with the
default settings (train_lmn, load_config()). Each training runs in a fresh process, whose peak
resident set size (ru_maxrss) is read when it ends; "before" is that process's peak after the
imports and the data, so peak − before is what training itself took. Prints bytes per sample:
memory grows linearly with the samples. The largest arrays have a row per sample: the OCV
pre-fit's regressors and the copies its bounded least squares makes (the peak here, without OCV
tests), and the refinement's Jacobian (a column per parameter of all local models and the OCV
knots).
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _peak_kib() -> int:
    """This process's peak resident set size so far (KiB, Linux's ru_maxrss unit)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def train_in_child(n_samples: int) -> tuple[int, int, float, int]:
    """Train on n_samples in this (fresh) process: (peak KiB before training, peak KiB after,
    seconds, local models)."""
    from bench_identification import segments
    from lmncell.config import load_config
    from lmncell.identification.construction import train_lmn

    segs = segments(n_samples)
    cfg = load_config()
    before = _peak_kib()
    t0 = time.perf_counter()
    res = train_lmn(segs, cfg, 2.85)
    return before, _peak_kib(), time.perf_counter() - t0, res.model.n_local_models


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-samples", type=int, default=1_000_000)
    args = ap.parse_args()
    if sys.platform != "linux":
        raise SystemExit("bench_training_memory: reads ru_maxrss in KiB, as Linux reports it")
    print("LMN training peak memory by samples (default settings, a fresh process each)")
    spawn = multiprocessing.get_context("spawn")
    for n in (30_000, 100_000, 300_000, 1_000_000):
        if n > args.max_samples:
            continue
        with ProcessPoolExecutor(max_workers=1, mp_context=spawn) as pool:
            before, peak, seconds, m = pool.submit(train_in_child, n).result()
        grown = (peak - before) * 1024
        print(f"  N={n:>9,d}: peak RSS {peak / 1024:8.0f} MiB, of which training "
              f"{grown / 2**20:7.0f} MiB ({grown / n:6.0f} bytes/sample), {seconds:6.1f} s, "
              f"M = {m}", flush=True)


if __name__ == "__main__":
    main()
