"""Benchmark: LMN training against the 2RC baseline fit on the same data, repeated in one run.

    python tests/benchmarks/bench_training_vs_2rc.py [--data DIR] [--ocv-test FILE] [--repeats 5]
        [--sample-time S]

Default data: the four Panasonic 25 °C drive cycles in ../shared/data with the C/20 OCV test, as
the README advises training on them (where ../shared is missing, the two shipped 25 °C cycles
without an OCV test, and the printout says so). Both fits start from the same segments, read and
resampled once, as `lmncell train --baselines` fits them: the LMN with every step of its
identification (OCV pre-fit, tree growth, output-error refinement), the 2RC ECM with the LMN's
OCV given (as `fit_baselines` gives it). Prints each run and the medians and their ratio.
--sample-time sets both models' Ts (default: as `lmncell train` takes it from the records, 0.1 s
for the 10 Hz Panasonic drive cycles; 1 for the models of 1 s).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from lmncell.config import load_config
from lmncell.identification.baselines import fit_ecm2rc
from lmncell.identification.construction import train_lmn
from lmncell.identification.prefit import with_soc_reference_weights
from lmncell.identification.train import (
    load_segments,
    read_training_records,
    with_records_sample_time,
)
from lmncell.runtime.step import exo_series, initial_hysteresis

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared/data/panasonic_18650pf/25degC"
SHIPPED = ROOT / "data/panasonic_18650pf/25degC"
CAPACITY_AH = 2.85


def default_data() -> tuple[list[Path], list[str], str]:
    """The four 25 °C drive cycles and the C/20 OCV test from ../shared, else the shipped two."""
    cycles = sorted((SHARED / "drive_cycles").glob("*.mat"))
    ocv = sorted((SHARED / "ocv_and_capacity").glob("*C20_OCV*.mat"))
    if len(cycles) >= 4 and ocv:
        return cycles, [str(ocv[0])], f"{len(cycles)} Panasonic 25 °C drive cycles, C/20 OCV test"
    shipped = sorted((SHIPPED / "drive_cycles").glob("*.mat"))
    return shipped, [], (f"{len(shipped)} shipped Panasonic 25 °C drive cycles, no OCV test "
                         "(../shared/data not found)")


def time_lmn(segs, cfg) -> tuple[float, object]:
    t0 = time.perf_counter()
    result = train_lmn(segs, cfg, CAPACITY_AH, lambda _m: None)
    return time.perf_counter() - t0, result.model


def time_2rc(segs, cfg, lmn) -> float:
    """The 2RC fit as fit_baselines runs it (no hysteresis), the LMN's OCV given."""
    socs = [exo_series(lmn, s.current_a, s.temperature_c, s.soc0).soc for s in segs]
    weighted = with_soc_reference_weights(segs, socs, lmn.ocv_soc, lmn.ocv_v, cfg)
    t0 = time.perf_counter()
    fit_ecm2rc(weighted, socs, lmn.ocv_soc, lmn.ocv_v, CAPACITY_AH, cfg.sample_time_s, None,
               [initial_hysteresis(s.soc0) for s in segs])
    return time.perf_counter() - t0


def _quiet(_message: str) -> None:
    pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, help="folder of drive-cycle files (.mat)")
    ap.add_argument("--ocv-test", action="append", default=[], help="slow OCV test file(s)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sample-time", type=float, help="Ts of both models (s)")
    a = ap.parse_args()
    if a.data:
        files, ocv, what = sorted(a.data.glob("*.mat")), a.ocv_test, str(a.data)
    else:
        files, ocv, what = default_data()
    cfg = load_config(None, ocv_tests=ocv, sample_time_s=a.sample_time)
    if a.sample_time is None:   # as `lmncell train`: Ts from the records' logging interval
        cfg = with_records_sample_time(cfg, read_training_records(files, cfg, _quiet), _quiet)
    segs, _, _, _ = load_segments(files, cfg, CAPACITY_AH, 1.0, lambda _m: None)
    n = sum(len(s) for s in segs)
    print(f"data: {what}; {len(segs)} segments, {n} samples at Ts = {cfg.sample_time_s} s")
    lmn_s, rc_s = [], []
    for k in range(a.repeats):
        t_lmn, model = time_lmn(segs, cfg)
        t_rc = time_2rc(segs, cfg, model)
        lmn_s.append(t_lmn)
        rc_s.append(t_rc)
        print(f"  run {k + 1}: LMN {t_lmn:.2f} s ({model.n_local_models} local models), "
              f"2RC {t_rc:.2f} s", flush=True)
    lmn_med, rc_med = statistics.median(lmn_s), statistics.median(rc_s)
    print(f"median of {a.repeats}: LMN {lmn_med:.2f} s, 2RC {rc_med:.2f} s, "
          f"LMN / 2RC = {lmn_med / rc_med:.2f}")


if __name__ == "__main__":
    main()
