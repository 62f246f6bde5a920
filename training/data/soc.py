"""SoC reference, capacity and open-circuit-voltage curves from measurements.

SoC(t) = SoC0 + ∫ i dτ / (3600·Cn), current > 0 charges, capacity Cn in Ah, SoC a fraction.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from lmncell.data.records import SOC_SLACK, DataError, Record, soc_outside

REST_CURRENT_A = 0.02
SLOW_TEST_MAX_C_RATE = 0.2   # an OCV test's loaded samples run at C/5 or slower (median)


def charge_throughput_ah(rec: Record, use_counters: bool = True) -> np.ndarray:
    """Net charge into the cell since the record start (Ah, > 0 charged).

    Uses the tester's counters where the record has them (they integrate at the tester's own rate);
    otherwise integrates the logged current, held from each sample to the next.
    """
    if use_counters and rec.charge_ah is not None:
        return rec.charge_ah - rec.charge_ah[0]
    return np.cumsum(_held_charge_as(rec)) / 3600.0


def _held_charge_as(rec: Record) -> np.ndarray:
    """The charge (A·s) of each sample interval, the logged current held from each sample to
    the next (0 for the first sample)."""
    dt = np.diff(rec.time_s, prepend=rec.time_s[0])
    held = np.concatenate([[0.0], rec.current_a[:-1]])
    return held * dt


def logged_current_drift_ah(rec: Record) -> float | None:
    """Net charge of the logged current minus the tester's counters' inside the record's
    segments, summed (Ah, > 0: the current counts more charge in), or None without counters:
    the SoC drift of a model driven by the logged current, as an FMU is, from each segment's
    start at the counters' SoC (as evaluation starts them), against the counters' SoC. The
    charge the counters count across a gap between segments is not in it (gap_charge_ah)."""
    if rec.charge_ah is None:
        return None
    return float(sum(charge_throughput_ah(seg, use_counters=False)[-1]
                     - charge_throughput_ah(seg)[-1] for seg in rec.segments()))


def gap_charge_ah(rec: Record) -> float | None:
    """Net charge (Ah, > 0 charged) the tester's counters count across the record's segment
    boundaries, where the log has no samples (a gap) or only the wall clock runs on (a hidden
    pause), or None without counters. A model restarted at each segment's counted SoC is given
    it; a host that drives one FMU through the whole record is not."""
    if rec.charge_ah is None:
        return None
    starts = sorted(set(rec.meta.segment_starts) - {0})
    return float(sum(rec.charge_ah[k] - rec.charge_ah[k - 1] for k in starts))


def current_scaled_to_counters(rec: Record) -> tuple[Record, float]:
    """The record with its logged current times one factor such that its net charge meets the
    tester's counters' by the end, and that factor: a diagnostic of what the drift of the
    logged current (logged_current_drift_ah) costs a model driven by it. DataError without
    counters, or where the record's net charge is under 10 % of its charge throughput (a
    round trip: one factor is then ill-determined)."""
    held = _held_charge_as(rec)
    logged = float(np.cumsum(held)[-1]) / 3600.0      # charge_throughput_ah's, without counters
    throughput = float(np.sum(np.abs(held))) / 3600.0
    if rec.charge_ah is None or not abs(logged) >= 0.1 * throughput > 0:
        raise DataError(f"{rec.meta.source}: cannot scale the current to the tester's counters "
                        "(expected charge counters and a net charge of at least 10 % of the "
                        "charge throughput)")
    factor = float(charge_throughput_ah(rec)[-1]) / logged
    return dataclasses.replace(rec, current_a=rec.current_a * factor), factor


def coulomb_count(rec: Record, soc0: float, capacity_ah: float,
                  use_counters: bool = True) -> np.ndarray:
    """SoC over the record from soc0 (fraction) and capacity (Ah)."""
    if not 0.0 <= soc0 <= 1.0:
        raise DataError(f"{rec.meta.source}: soc0={float(soc0)!r}; expected a fraction within 0…1")
    if not capacity_ah > 0:
        raise DataError(f"{rec.meta.source}: capacity_ah={float(capacity_ah)!r}; expected > 0 Ah")
    return soc0 + charge_throughput_ah(rec, use_counters) / capacity_ah


def reference_soc(rec: Record, soc0: float, capacity_ah: float) -> np.ndarray:
    """coulomb_count as a record's reference SoC: DataError where it leaves 0…1 by more than
    SOC_SLACK, naming where, and the charge the record moves from its start both ways, so that
    the start SoC or the capacity can be put right."""
    soc = coulomb_count(rec, soc0, capacity_ah)
    outside = soc_outside(soc)
    if not outside.size:
        return soc
    charge_ah = (soc - soc0) * capacity_ah
    k = int(outside[0])
    where = (f"line {rec.meta.first_line + k}" if rec.meta.first_line is not None
             else f"sample {k}")
    discharged, charged = max(0.0, -float(charge_ah.min())), max(0.0, float(charge_ah.max()))
    raise DataError(
        f"{rec.meta.source}: counted from SoC {soc0:g} with a capacity of {capacity_ah:g} Ah, the "
        f"SoC reaches {soc[k]:.3f} at {float(rec.time_s[k]):g} s ({where}); expected 0…1. From "
        f"its start the record discharges up to {discharged:.4g} Ah and charges up to "
        f"{charged:.4g} Ah: " + _what_to_check(discharged, charged, capacity_ah,
                                                rec.meta.fmt == "generic"))


def _what_to_check(discharged_ah: float, charged_ah: float, capacity_ah: float,
                   own_columns: bool) -> str:
    """What reference_soc's error asks to check: the start SoC and the capacity; the sign of
    the current where the record charges (nearly) only; where its net charge spans more than
    the capacity (no start SoC fits) the units of a CSV read by its named columns (own_columns)
    or whether a record of a known format is this cell's."""
    check = ("check the start SoC (--soc0, soc0=) and the capacity (the model's, or --capacity, "
             "capacity_ah= when training)")
    if discharged_ah < 0.05 * charged_ah and own_columns:
        check += (", and the sign of the current: the record charges only (a file that counts "
                  "discharge as positive: --discharge-positive, discharge_positive=True; one "
                  "that logs the current's magnitude and its direction in another column: "
                  "--columns …,state=COL)")
    span_ah = discharged_ah + charged_ah
    if span_ah <= capacity_ah * (1.0 + 2.0 * SOC_SLACK):
        return check
    return (f"no start SoC fits a span of {span_ah:.4g} Ah in a cell of {capacity_ah:g} Ah; "
            f"{check}, and " + ("the units of the current (--current-unit A|mA) and of the "
                                "time (--time-unit s|ms|min|h|d)" if own_columns else
                                "whether the record is of this cell"))


def starts_full(rec: Record, v_full: float, tol_v: float = 0.08, rest_s: float = 10.0) -> bool:
    """True where the record starts with a rest at (or near) the top-of-charge voltage v_full."""
    t = rec.time_s - rec.time_s[0]
    head = t <= max(rest_s, float(t[min(1, len(t) - 1)]))
    resting = np.abs(rec.current_a[head]) < REST_CURRENT_A
    return bool(resting.all() and rec.voltage_v[0] >= v_full - tol_v)


def discharged_ah(rec: Record) -> float:
    """Net charge removed over the record (Ah, > 0 for a net discharge)."""
    return float(-charge_throughput_ah(rec)[-1])


def capacity_from_discharge(*records: Record) -> float:
    """Capacity (Ah) from consecutive records that go from full to empty (e.g. A123 s1 then s2)."""
    total = sum(discharged_ah(r) for r in records)
    if total <= 0:
        names = ", ".join(r.name for r in records)
        raise DataError(f"{names}: no net discharge ({total:.4f} Ah); expected records that run "
                        "from full to empty")
    return total


@dataclass
class OcvCurve:
    """OCV over SoC (V over fraction) with the charge and discharge branches and their mean."""

    soc: np.ndarray
    discharge_v: np.ndarray
    charge_v: np.ndarray

    @property
    def mean_v(self) -> np.ndarray:
        return 0.5 * (self.discharge_v + self.charge_v)

    @property
    def hysteresis_v(self) -> np.ndarray:
        """Half the gap between the branches (V)."""
        return 0.5 * (self.charge_v - self.discharge_v)


def _branch(rec: Record, capacity_ah: float, soc0: float, grid: np.ndarray,
            sign: float) -> np.ndarray:
    """Voltage over the SoC grid for the part of a slow test with current of the given sign."""
    soc = coulomb_count(rec, soc0, capacity_ah)
    sel = sign * rec.current_a > REST_CURRENT_A
    what = "charge" if sign > 0 else "discharge"
    if sel.sum() < 10:
        raise DataError(f"{rec.meta.source}: fewer than 10 samples with {what} current; "
                        "expected a slow test")
    rate = float(np.median(np.abs(rec.current_a[sel]))) / capacity_ah
    if rate > SLOW_TEST_MAX_C_RATE:
        raise DataError(f"{rec.meta.source}: its {what} current is {rate:.2f} C (median over "
                        f"its {what} samples, at {capacity_ah:g} Ah); expected a slow OCV test, "
                        f"C/{1 / SLOW_TEST_MAX_C_RATE:g} or slower (C/20, C/30), whose voltage "
                        "is near the OCV")
    s, v = soc[sel], rec.voltage_v[sel]
    order = np.argsort(s, kind="stable")
    s, v = s[order], v[order]
    s_u, idx = np.unique(s, return_index=True)
    return np.interp(grid, s_u, v[idx])


def ocv_from_slow_tests(discharge: Record, charge: Record, capacity_ah: float,
                        points: int = 101) -> OcvCurve:
    """Charge and discharge OCV branches from slow (C/20, C/30) tests; beyond the measured SoC
    range of a branch its last value is held."""
    grid = np.linspace(0.0, 1.0, points)
    return OcvCurve(grid, _branch(discharge, capacity_ah, 1.0, grid, -1.0),
                    _branch(charge, capacity_ah, 0.0, grid, +1.0))


@dataclass
class RoundTripOcv:
    """OCV branches of one slow full → empty → full test, with the current offset removed."""

    curve: OcvCurve
    offset_a: float
    capacity_ah: float


ROUND_TRIP_MIN_SHARE = 0.5   # a one-file OCV test discharges at least this share of the
#                              cell's capacity


def ocv_from_round_trip(rec: Record, points: int = 101,
                        model_capacity_ah: float | None = None) -> RoundTripOcv:
    """OCV branches from one slow test that starts full, discharges to empty and charges back.

    A tester's current offset shows as discharged ≠ charged Ah (Panasonic C/20: 2.997 vs
    2.616 Ah). The offset δ (A, added to every loaded sample) that balances the two is removed;
    SoC then runs 1 → 0 over the corrected discharge and 0 → 1 over the charge, so the curve's
    SoC is a fraction of this test's own capacity (returned, Ah). model_capacity_ah: the cell's
    capacity (Ah), where known; a test that discharges less than ROUND_TRIP_MIN_SHARE of it
    is refused (it does not run from full to empty: a dither, A123 S2)."""
    dt = np.diff(rec.time_s, append=rec.time_s[-1])
    dis, chg = rec.current_a < -REST_CURRENT_A, rec.current_a > REST_CURRENT_A
    if dis.sum() < 10 or chg.sum() < 10:
        raise DataError(f"{rec.meta.source}: expected one slow test with a discharge from full "
                        f"and a charge back to full; found {int(dis.sum())} discharging and "
                        f"{int(chg.sum())} charging sample(s) (|current| > {REST_CURRENT_A:g} A),"
                        " fewer than 10 of one. A discharge test and a charge test in two files "
                        "are given together (--ocv-tests DISCHARGE CHARGE)")
    q_dis = float(-np.sum(rec.current_a[dis] * dt[dis])) / 3600.0
    q_chg = float(np.sum(rec.current_a[chg] * dt[chg])) / 3600.0
    offset = 3600.0 * (q_dis - q_chg) / float(dt[dis].sum() + dt[chg].sum())
    current = rec.current_a + offset * (dis | chg)
    fixed = dataclasses.replace(rec, current_a=current, charge_ah=None, soc_ref=None)
    capacity = q_dis - offset * float(dt[dis].sum()) / 3600.0
    if model_capacity_ah and not capacity >= ROUND_TRIP_MIN_SHARE * model_capacity_ah:
        raise DataError(f"{rec.meta.source}: discharges {capacity:.4g} Ah, "
                        f"{100 * capacity / model_capacity_ah:.2g} % of the capacity "
                        f"{model_capacity_ah:g} Ah; expected one slow test that runs from full "
                        "to empty and back, or two files: a discharge from full and a charge "
                        "from empty")
    grid = np.linspace(0.0, 1.0, points)
    curve = OcvCurve(grid, _branch(fixed, capacity, 1.0, grid, -1.0),
                     _branch(fixed, capacity, 1.0, grid, +1.0))
    return RoundTripOcv(curve, offset, capacity)
