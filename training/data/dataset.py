"""From records to the model-rate segments that training and evaluation step through."""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lmncell.data.records import DataError, Record, present
from lmncell.data.resample import resample_segment
from lmncell.data.soc import REST_CURRENT_A, discharged_ah, reference_soc
from lmncell.runtime.observers import first_crossing
from lmncell.runtime.thermal import DEFAULT_TEMPERATURE_C

SEGMENT_MARK = "#"      # a split record's segments are named RECORD#0, RECORD#1, …


def record_name(segment_name: str) -> str:
    """The name of the record a segment (or a row of it) is part of: 'US06.mat#1' → 'US06.mat'."""
    return segment_name.split(SEGMENT_MARK)[0]


@dataclass
class Segment:
    """One gap-free stretch of a record at the model's sample time.

    Sample k is the step ending at time_s[k]: current_a (A, > 0 charges) and voltage_v (V) are the
    means over the step; soc_ref is the reference SoC at time_s[k]; soc0 the SoC at the start of
    the first step; temperature_c in °C (None if unknown); weight the fit weight of each sample
    (SoC window, record weight and, in training, the SoC-reference weight); record_weight the
    weight of the record it belongs to alone; ambient_c the chamber (ambient) temperature in °C
    where the record has a measured cell temperature beside it (else None), and ambient_trace_c
    that temperature per step where the record logs it and it varies over the segment (a
    chamber still settling; else None: ambient_c throughout); temperature_kind
    what temperature_c is: "measured" (the record's cell temperature), "chamber" (the chamber's,
    as logged or its set point, where the record has no cell temperature) or "none"
    (temperature_c None).
    """

    name: str
    time_s: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray | None
    soc0: float
    soc_ref: np.ndarray
    weight: np.ndarray
    record_weight: float = 1.0
    ambient_c: float | None = None
    temperature_kind: str = "measured"
    ambient_trace_c: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.time_s.size)

    def head(self, steps: int) -> Segment:
        """The segment's first steps: every per-step array cut there (time, current, voltage,
        temperature, SoC, weight, ambient trace), the rest as it is."""
        return dataclasses.replace(self, **{
            f.name: getattr(self, f.name)[:steps] for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)})

    def temperatures(self) -> np.ndarray:
        """The temperature of each step (°C): temperature_c, or DEFAULT_TEMPERATURE_C where the
        segment has none."""
        if self.temperature_c is None:
            return np.full(len(self), DEFAULT_TEMPERATURE_C)
        return self.temperature_c

    def ambient_temperature(self) -> float | np.ndarray | None:
        """The ambient (chamber) temperature beside the measured cell temperature (°C): per
        step where the record logs it varying (ambient_trace_c), else the set point
        (ambient_c; None where the segment has none)."""
        return self.ambient_trace_c if self.ambient_trace_c is not None else self.ambient_c

    def start_temperature(self) -> float:
        """The temperature at the segment's first step (°C), or DEFAULT_TEMPERATURE_C where
        the segment has none."""
        return (DEFAULT_TEMPERATURE_C if self.temperature_c is None
                else float(self.temperature_c[0]))


def rested_mask(rec: Record, min_rest_s: float = 60.0) -> np.ndarray:
    """Samples inside rests (|i| < REST_CURRENT_A) that last at least min_rest_s, and the first
    sample when the record starts at rest (a record that starts rested is rested at its start)."""
    rest = np.abs(rec.current_a) < REST_CURRENT_A
    out = np.zeros_like(rest)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if rec.time_s[b - 1] - rec.time_s[a] >= min_rest_s:
            out[a:b] = True
    out[0] = rest[0]
    return out


def starts_rested_full(rec: Record) -> bool:
    """True where the record starts at rest at its highest rested voltage (within 5 mV)."""
    rested = rested_mask(rec)
    return bool(rested[0] and rec.voltage_v[0] >= rec.voltage_v[rested].max() - 0.005)


START_FULL_MIN_SOC = 0.8   # a record whose rested start voltage an OCV puts below this SoC
#                            does not start full (start_soc)
FULL_START_MAX_ABOVE_OCV_V = 0.2   # a rested full start further above the OCV's top (V) is
#                                    another cell's (the A123 s1 records start 31…72 mV above
#                                    their C/30 tests' mean branch, the Panasonic drive cycles
#                                    within 2 mV of or below their C/20 test's)


def start_soc(rec: Record, soc0: float | None,
              ocv: tuple[np.ndarray, np.ndarray] | None = None,
              ocv_name: str = "the model's OCV") -> float:
    """The given start SoC, or 1.0 for a record that starts rested at full charge. ocv: a
    known OCV (SoC knots, V), named ocv_name in messages; a record that starts rested at its
    top voltage but where that OCV puts the voltage below START_FULL_MIN_SOC (a record that
    starts rested part-way down, and only discharges from there) is refused, not taken as
    full."""
    if soc0 is not None:
        return float(soc0)
    if starts_rested_full(rec):
        if ocv is not None:
            _check_full_start(rec, *ocv, ocv_name)
        return 1.0
    raise DataError(f"{rec.meta.source}: cannot tell the start SoC (the record does not start "
                    "with a rest at its top voltage); give it: --soc0 on the command line, "
                    "soc0= in Python (1.0 for a record that starts fully charged)")


def ocv_soc(voltage_v: float, soc_knots: np.ndarray, ocv_v: np.ndarray) -> float:
    """The SoC (fraction) at which a piecewise linear OCV curve (ocv_v, V, at soc_knots) last
    rises through voltage_v (V): 1 at or above the curve's last value, 0 where it never rises
    through it."""
    s = [float(x) for x in soc_knots]
    v = [float(x) for x in ocv_v]
    if voltage_v >= v[-1]:
        return 1.0
    # walking down from the top knot, the first point at or below voltage_v
    return first_crossing(s[-1], v[-1], voltage_v, s[-2::-1], v[-2::-1], 0.0)


def _check_full_start(rec: Record, soc_knots: np.ndarray, ocv_v: np.ndarray,
                      ocv_name: str) -> None:
    """DataError where the record's rested start voltage lies below START_FULL_MIN_SOC on the
    OCV, or more than FULL_START_MAX_ABOVE_OCV_V above its top."""
    v0, top = float(rec.voltage_v[0]), float(ocv_v[-1])
    if v0 > top + FULL_START_MAX_ABOVE_OCV_V:
        raise DataError(f"{rec.meta.source}: starts rested at {v0:.4g} V, "
                        f"{1e3 * (v0 - top):.0f} mV above the top of {ocv_name} ({top:.4g} V "
                        f"at SoC 1), where a rested full cell lies within "
                        f"{1e3 * FULL_START_MAX_ABOVE_OCV_V:.0f} mV of it: that OCV is not "
                        "this cell's (another cell's OCV test or model?) or does not reach its "
                        "full charge (a model trained only on records below full), or the "
                        "voltage column is not the cell's")
    soc = ocv_soc(v0, soc_knots, ocv_v)
    if soc < START_FULL_MIN_SOC:
        raise DataError(f"{rec.meta.source}: starts rested at {v0:.4g} V, which {ocv_name} "
                        f"puts at SoC {soc:.2f}, not full charge ({float(ocv_v[-1]):.4g} V at "
                        "SoC 1); give the record's start SoC: "
                        "--soc0 on the command line, soc0= in Python (a value from 0 to 1, "
                        f"e.g. {soc:.2f} from that OCV)")


def start_socs(soc0: float | Sequence[float] | None, n: int) -> list[float | None]:
    """One start SoC per record, from None (each record's own, see start_soc), one value for
    every record, or one value per record in the order of the files."""
    if soc0 is None or isinstance(soc0, (int, float)):
        values = [soc0] * n
    else:
        values = list(soc0)
        if len(values) == 1:
            values = values * n
        if len(values) != n:
            raise DataError(f"soc0: {len(values)} start SoC values for {n} data file(s): "
                            "expected one for every file, or one per file in order")
    for v in values:
        if v is not None and not 0.0 <= float(v) <= 1.0:
            raise DataError(f"soc0 = {v!r}: expected a SoC fraction within 0…1")
    return [None if v is None else float(v) for v in values]


def estimate_capacity(records: list[Record],
                      soc0: Sequence[float | None] | None = None) -> float:
    """Largest net discharge (Ah) of the records that start full: a lower bound of capacity.
    soc0: each record's given start SoC (start_socs; None: unknown), 1.0 marks it full; records
    without one start full where they start rested at the top voltage."""
    given = list(soc0) if soc0 is not None else [None] * len(records)
    full = [discharged_ah(r) for r, s in zip(records, given, strict=True)
            if s == 1.0 or (s is None and starts_rested_full(r))]
    if not full or max(full) <= 0:
        raise DataError("cannot estimate the capacity: no record starts full (rested at its "
                        "top voltage, or given as full by --soc0 1 / soc0=1.0) and discharges; "
                        "give the capacity (--capacity / capacity_ah=), or the start SoC of "
                        "records that start full")
    return max(full)


def record_to_segments(rec: Record, sample_time_s: float, soc0: float, capacity_ah: float,
                       soc_window: tuple[float, float] = (0.0, 1.0),
                       outside_weight: float = 1.0,
                       current_delay_s: float = 0.0) -> list[Segment]:
    """Reference SoC by coulomb counting (tester counters where present), then each gap-free
    segment resampled to the model rate (the current δ = current_delay_s late: the input of a
    model with that delay, LmnModel.current_delay_s)."""
    return [seg for _, seg in record_parts(rec, sample_time_s, soc0, capacity_ah, soc_window,
                                           outside_weight, current_delay_s)]


MIN_SEGMENT_STEPS = 10   # a segment shorter than this many model steps is left out


MAX_STEPS_PER_LOG_INTERVAL = 10   # training holds a log's sample over at most this many steps
FAST_LOG_RATIO = 1.5   # the notes speak of a log this many times faster or slower than Ts


def check_sampling_interval(rec: Record, sample_time_s: float) -> None:
    """DataError where training would hold each of a record's samples over more than
    MAX_STEPS_PER_LOG_INTERVAL model steps (its logging interval, the median of its time steps
    within its gap-free segments, that many times the sample time): resampled, such a record is
    mostly its interpolation between samples, which the model would learn instead of the cell,
    and its arrays grow with the ratio (a 1 ms sample time on a 10 Hz log ran out of memory).
    A cycler's constant-current phase logged every 10 s still trains a 1 s model."""
    steps = np.concatenate([np.diff(part.time_s) for part in rec.segments()] or [np.zeros(0)])
    steps = steps[steps > 0]
    interval = float(np.median(steps)) if steps.size else 0.0
    least = interval / MAX_STEPS_PER_LOG_INTERVAL
    if sample_time_s * 1.05 < least:      # a tester's 10 s is 10.015 s (A123 OCV tests)
        raise DataError(f"{rec.meta.source}: logged every {interval:.3g} s (the median time "
                        f"step); a model sample time of {sample_time_s:g} s would hold each "
                        f"sample over {interval / sample_time_s:.3g} model steps, more than "
                        f"{MAX_STEPS_PER_LOG_INTERVAL}: the model would learn the interpolation "
                        "between its samples, not the cell; expected sample_time_s ≥ "
                        f"{least:.3g} s, or a record logged faster")


def record_parts(rec: Record, sample_time_s: float, soc0: float, capacity_ah: float,
                 soc_window: tuple[float, float] = (0.0, 1.0), outside_weight: float = 1.0,
                 current_delay_s: float = 0.0) -> list[tuple[Record, Segment]]:
    """record_to_segments with each segment's gap-free part of the record as measured (its own
    samples, reference SoC and temperature, the chamber set point where none was measured).
    A record logged slower than sample_time_s is held over the steps within each of its
    intervals (evaluation takes any rate; training, check_sampling_interval, at most
    MAX_STEPS_PER_LOG_INTERVAL steps per interval)."""
    rec = rec.with_soc(reference_soc(rec, soc0, capacity_ah))
    chamber = rec.meta.chamber_temp_c
    ambient = (float(chamber) if rec.temperature_c is not None and chamber is not None
               and np.isfinite(chamber) else None)
    kind = "measured" if rec.temperature_c is not None else "none"
    temp = rec.temperature_or_chamber()
    if temp is not None and rec.temperature_c is None:
        rec.temperature_c, kind = temp, "chamber"
    out = []
    for k, part in enumerate(rec.segments()):
        if part.duration_s < MIN_SEGMENT_STEPS * sample_time_s:
            continue
        rs = resample_segment(part, sample_time_s, current_delay_s)
        soc = present(rs.soc_ref, "the segment's reference SoC")
        lo, hi = soc_window
        w = np.where((soc >= lo) & (soc <= hi), 1.0, outside_weight)
        name = (rec.name if len(rec.meta.segment_starts) == 1
                else f"{rec.name}{SEGMENT_MARK}{k}")
        out.append((part, Segment(name, rs.time_s, rs.current_a, rs.voltage_v, rs.temperature_c,
                                  float(present(part.soc_ref, "the record's SoC")[0]), soc, w,
                                  ambient_c=ambient,
                                  temperature_kind=kind,
                                  ambient_trace_c=_varying(part.ambient_c, rs.ambient_c,
                                                           ambient))))
    if not out:
        longest = max((part.duration_s for part in rec.segments()), default=0.0)
        raise DataError(f"{rec.meta.source}: no segment is long enough for the model sample "
                        f"time {sample_time_s:g} s: the longest lasts {longest:g} s, expected "
                        f"at least {MIN_SEGMENT_STEPS * sample_time_s:g} s ({MIN_SEGMENT_STEPS} "
                        "model steps)")
    return out


def _varying(logged: np.ndarray | None, steps: np.ndarray | None, ambient_c: float | None
             ) -> np.ndarray | None:
    """A segment's ambient temperature per step (steps, the step means of the logged samples)
    where it has a set point beside a measured cell temperature and the logged samples vary,
    else None."""
    if logged is None or steps is None or ambient_c is None or float(np.ptp(logged)) == 0.0:
        return None
    return steps


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
