"""Where does a discharge record really end? The SoC at the end of each dynamic test that a slow
discharge to empty follows (Plett's A123 tests: s1 at the test temperature, then s2 at 25 °C down
to 2.0 V), as a model driven by the logged current counts it, against the charge s2 still took.

Usage:
    python examples/end_of_discharge_soc.py CAPACITY_AH S1_FILE... [--ocv-tests FILE [FILE]]
        [--rest-s S]

Example (the A123 tests of ../shared/data, their 25 °C C/30 OCV test):
    A=../shared/data/a123_plett
    python examples/end_of_discharge_soc.py 2.0307 $A/dyn/A123_DYN_*_s1.csv \\
        --ocv-tests $A/ocv/A123_OCV_P25_S1.csv $A/ocv/A123_OCV_P25_S3.csv

Each S1_FILE's s2 (the same name with _s2) must lie beside it. Per test, with s1 starting full:
- "logged": SoC at s1's end by its logged current, as an FMU driven by that current counts it
  from SoC0 = 1 (%); "counters": by the tester's Ah counters (%);
- "left": the charge s2 still discharged to the cut-off, in % of CAPACITY_AH: the SoC the cell
  had at s1's end;
- "error": logged − left (percentage points): how far from the cell's SoC a model driven by
  the logged current enters the collapse before the cut-off (> 0: it thinks the cell fuller);
- with --ocv-tests: the OCV's slope at "left" (mV per % SoC) and error × slope (mV), what that
  SoC error alone costs at rest near empty;
- the voltage REST_S (default 300) after s1's last loaded sample, and at s2's first load after
  its soak: how far from rest the cell still was when s1 ended.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lmncell.cli import capacity_argument, number_argument, run_script
from lmncell.data.readers import read_record
from lmncell.data.records import DataError, Record
from lmncell.data.soc import REST_CURRENT_A, coulomb_count, discharged_ah
from lmncell.identification.ocvfit import measured_ocv
from lmncell.identification.prefit import ocv_slope

OCV_POINTS = 2001       # SoC grid of the OCV's slope (0.05 % steps)


@dataclass
class EndOfTest:
    """One test's end: SoC (%) by the logged current, by the counters (None without), the
    charge left in % of the capacity, and the voltages (V) REST_S after the cut-off and at the
    end of s2's soak."""

    name: str
    logged_pct: float
    counters_pct: float | None
    left_pct: float
    v_after_rest: float
    v_soaked: float

    @property
    def error_pp(self) -> float:
        return self.logged_pct - self.left_pct


def s2_path(s1: Path) -> Path:
    """The s2 file beside an s1 file (A123_DYN_50_P25_s1.csv → …_s2.csv)."""
    if "_s1." not in s1.name:
        raise DataError(f"{s1}: expected a file name with '_s1.' (Plett's dynamic test script 1)")
    s2 = s1.with_name(s1.name.replace("_s1.", "_s2."))
    if not s2.exists():
        raise DataError(f"{s1}: its slow discharge to empty {s2.name} is not beside it")
    return s2


def voltage_after_load(rec: Record, rest_s: float) -> float:
    """The voltage rest_s after the record's last loaded sample (its last voltage if it ends
    sooner)."""
    loaded = np.flatnonzero(np.abs(rec.current_a) > REST_CURRENT_A)
    if loaded.size == 0:
        raise DataError(f"{rec.meta.source}: no loaded sample (|current| > {REST_CURRENT_A} A)")
    t_end = rec.time_s[loaded[-1]] + rest_s
    return float(np.interp(min(t_end, rec.time_s[-1]), rec.time_s, rec.voltage_v))


def voltage_before_load(rec: Record) -> float:
    """The voltage just before the record's first loaded sample (after its soak)."""
    loaded = np.flatnonzero(np.abs(rec.current_a) > REST_CURRENT_A)
    return float(rec.voltage_v[max(int(loaded[0]) - 1, 0)] if loaded.size else rec.voltage_v[-1])


def end_of_test(s1_file: Path, capacity_ah: float, rest_s: float) -> EndOfTest:
    """The end of one s1 test, from it and its s2."""
    s1, s2 = read_record(s1_file), read_record(s2_path(s1_file))
    logged = coulomb_count(s1, 1.0, capacity_ah, use_counters=False)[-1]
    counters = coulomb_count(s1, 1.0, capacity_ah)[-1] if s1.charge_ah is not None else None
    return EndOfTest(s1.name, 100 * logged, None if counters is None else 100 * counters,
                     100 * discharged_ah(s2) / capacity_ah, voltage_after_load(s1, rest_s),
                     voltage_before_load(s2))


def mean_ocv(ocv_tests: list[str], capacity_ah: float) -> tuple[np.ndarray, np.ndarray]:
    """The OCV tests' mean branch (V) on OCV_POINTS SoC from 0 to 1: (SoC, OCV)."""
    soc = np.linspace(0.0, 1.0, OCV_POINTS)
    return soc, measured_ocv(ocv_tests, capacity_ah, soc)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capacity_ah", type=capacity_argument, help="the cell's capacity (Ah)")
    ap.add_argument("s1_files", nargs="+", type=Path,
                    help="Plett's A123 s1 records, each with its s2 beside it")
    ap.add_argument("--ocv-tests", nargs="*", default=[],
                    help="slow OCV tests: also print the OCV's slope and what the SoC error "
                    "costs at rest (mV)")
    ap.add_argument("--rest-s", type=number_argument(float, lambda v: v >= 0, "s ≥ 0"),
                    default=300.0, metavar="S",
                    help="read the voltage S seconds after s1's last loaded sample (default: "
                    "300)")
    a = ap.parse_args()
    ocv = mean_ocv(a.ocv_tests, a.capacity_ah) if a.ocv_tests else None
    ends = [end_of_test(f, a.capacity_ah, a.rest_s) for f in a.s1_files]
    print(f"SoC at the end of s1 (%), from full, capacity {a.capacity_ah:g} Ah; voltage "
          f"{a.rest_s:g} s after s1's cut-off and after s2's soak (V)")
    print(f"{'test':28s} {'logged':>7s} {'counters':>8s} {'left':>6s} {'error':>6s}"
          + ("  slope mV/%  error mV" if ocv is not None else "") + "   V rest   V soaked")
    for e in ends:
        counters = "-" if e.counters_pct is None else f"{e.counters_pct:.2f}"
        cells = (f"{e.name:28s} {e.logged_pct:7.2f} {counters:>8s} {e.left_pct:6.2f} "
                 f"{e.error_pp:+6.2f}")
        if ocv is not None:        # V per unit SoC = 10 mV per % SoC
            slope = 10.0 * float(ocv_slope(*ocv, np.array([e.left_pct / 100]))[0])
            cells += f"  {slope:10.1f}  {e.error_pp * slope:+8.0f}"
        print(f"{cells}   {e.v_after_rest:6.3f}   {e.v_soaked:7.3f}")
    errors = np.array([e.error_pp for e in ends])
    print(f"error (logged − left) over {len(ends)} test(s): mean {errors.mean():+.2f}, RMS "
          f"{np.sqrt(np.mean(errors ** 2)):.2f} percentage points")


if __name__ == "__main__":
    run_script(main, __file__)
