"""The measured time series every part of LMNCell works on.

Conventions: SI units (s, A, V, Ah, °C); current > 0 charges the cell; SoC is a fraction 0…1.
A record keeps its own time base. Records are never glued together: each starts its own lag
buffers and SoC integration.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from lmncell.runtime.thermal import CELL_TEMPERATURE_RANGE_C

T = TypeVar("T")


class DataError(ValueError):
    """Bad measurement data; the message names the file, the column or row and what was expected."""


def present(value: T | None, what: str) -> T:
    """value, which the caller's earlier steps have set (a RuntimeError naming it otherwise: a
    fault in this package, not in the user's data)."""
    if value is None:
        raise RuntimeError(f"{what} is not set")
    return value


@dataclass
class RecordMeta:
    """Where a record came from and what was done to it on loading."""

    source: str
    fmt: str
    sign_note: str = ""
    sample_time_s: float = float("nan")
    chamber_temp_c: float | None = None
    segment_starts: list[int] = field(default_factory=lambda: [0])
    notes: list[str] = field(default_factory=list)
    pause_starts: list[int] = field(default_factory=list)   # those of segment_starts that
    # begin after a pause which only the wall clock shows (the time column runs on through it)
    file_columns: dict[str, str] = field(default_factory=dict)   # record field (time_s, …) →
    # the file's name for its column, for error messages
    first_line: int | None = None     # the file line of sample 0 where every data row became a
    # sample in order (CSV), for error messages; None: they name samples
    time_origin_s: float = 0.0        # the file's time of sample 0 (time_s counts from it)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class Record:
    """One measured time series.

    time_s: s, strictly increasing. current_a: A, > 0 charges. voltage_v: terminal voltage, V.
    temperature_c: measured cell temperature in °C, or None. ambient_c: the ambient (chamber)
    temperature as logged in °C (beside the cell's: the thermal model's ambient; alone: the
    record's temperature), or None (meta.chamber_temp_c then the set point alone).
    soc_ref: SoC reference (0…1) or None.
    charge_ah: net charge into the cell since the record start from the tester's counters (Ah,
    > 0 charged), or None. meta.segment_starts: indices where a new segment begins after a gap or
    a pause hidden in the time column (the cell state carries over, the lag buffers do not);
    meta.pause_starts: those that begin after a hidden pause.
    """

    time_s: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    meta: RecordMeta
    temperature_c: np.ndarray | None = None
    soc_ref: np.ndarray | None = None
    charge_ah: np.ndarray | None = None
    ambient_c: np.ndarray | None = None

    def __post_init__(self) -> None:
        validate_record(self)

    @property
    def name(self) -> str:
        return self.meta.source.replace("\\", "/").rsplit("/", 1)[-1]

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0]) if len(self) else 0.0

    def temperature_or_chamber(self) -> np.ndarray | None:
        """Measured temperature, else the chamber's as logged, else its set point as a constant,
        else None (°C)."""
        if self.temperature_c is not None:
            return self.temperature_c
        if self.ambient_c is not None:
            return self.ambient_c
        if self.meta.chamber_temp_c is not None:
            return np.full(len(self), float(self.meta.chamber_temp_c))
        return None

    def slice(self, start: int, stop: int, note: str = "") -> Record:
        """Samples start:stop as a new record (counters and SoC kept as they are)."""

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[start:stop].copy()

        starts = [s - start for s in self.meta.segment_starts if start <= s < stop]
        if 0 not in starts:
            starts = [0, *starts]
        pauses = [s - start for s in self.meta.pause_starts if start < s < stop]
        meta = dataclasses.replace(
            self.meta, segment_starts=starts, pause_starts=pauses,
            notes=[*self.meta.notes, note] if note else list(self.meta.notes),
            first_line=None if self.meta.first_line is None else self.meta.first_line + start)
        return Record(self.time_s[start:stop].copy(), self.current_a[start:stop].copy(),
                      self.voltage_v[start:stop].copy(), meta, cut(self.temperature_c),
                      cut(self.soc_ref), cut(self.charge_ah), cut(self.ambient_c))

    def segments(self) -> list[Record]:
        """The record split where meta.segment_starts marks a gap or a hidden pause."""
        bounds = [*sorted(set(self.meta.segment_starts) | {0}), len(self)]
        return [self.slice(a, b, f"segment {k} of {self.name}")
                for k, (a, b) in enumerate(itertools.pairwise(bounds)) if b - a > 1]

    def through_hidden_pauses(self) -> Record:
        """A copy that is not split at pauses which only the wall clock shows: the record as
        a host sees it that drives a model (an FMU) through the time column, where the cell's
        state runs on through such a pause instead of relaxing."""
        if not self.meta.pause_starts:
            return self
        pauses = set(self.meta.pause_starts)
        meta = dataclasses.replace(
            self.meta, segment_starts=[s for s in self.meta.segment_starts if s not in pauses],
            pause_starts=[], notes=[*self.meta.notes, f"{len(pauses)} hidden pause(s) not "
                                   "split: the time column runs on through them"])
        return dataclasses.replace(self, meta=meta)

    def with_soc(self, soc: np.ndarray) -> Record:
        """A copy with soc_ref replaced."""
        return dataclasses.replace(self, soc_ref=np.asarray(soc, dtype=float))


def _column(meta: RecordMeta, name: str) -> str:
    """How an error names a record field: the file's column with the field beside it."""
    file_name = meta.file_columns.get(name)
    return f"column '{name}'" if file_name is None else f"column '{file_name}' ({name})"


def _at(meta: RecordMeta, sample: int) -> str:
    """How an error names a sample: the file's line where samples are its rows, else its
    index."""
    return f"sample {sample}" if meta.first_line is None else f"line {meta.first_line + sample}"


def _check_finite(name: str, values: np.ndarray, meta: RecordMeta) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise DataError(f"{meta.source}: {_column(meta, name)} has {int(bad.sum())} NaN or "
                        f"infinite value(s), first at {_at(meta, row)} (value "
                        f"{float(values[row])!r}); expected finite numbers")


CELL_VOLTAGE_RANGE_V = (0.0, 6.0)           # a record's terminal voltage must lie in it
# and its cell or chamber temperature in CELL_TEMPERATURE_RANGE_C (lmncell.runtime.thermal, where
# the FMUs refuse a `temperature` input outside it too)
SOC_SLACK = 0.05   # a reference SoC this far beyond 0…1 is refused (start SoC or capacity)


def soc_outside(soc: np.ndarray) -> np.ndarray:
    """Indices where a reference SoC leaves 0…1 by more than SOC_SLACK."""
    return np.flatnonzero((soc < -SOC_SLACK) | (soc > 1 + SOC_SLACK))


def is_cell_temperature(values: float | np.ndarray) -> bool:
    """Whether every value is a finite cell temperature in °C within CELL_TEMPERATURE_RANGE_C
    (a value in kelvin is not)."""
    low, high = CELL_TEMPERATURE_RANGE_C
    arr = np.asarray(values, dtype=float)
    return bool(np.all(np.isfinite(arr) & (arr >= low) & (arr <= high)))


def _check_range(name: str, values: np.ndarray, bounds: tuple[float, float], unit: str,
                 expected: str, meta: RecordMeta) -> None:
    """DataError naming the first sample of `values` outside `bounds` (inclusive)."""
    low, high = bounds
    bad = (values < low) | (values > high)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise DataError(f"{meta.source}: {_column(meta, name)} is {float(values[row]):g} {unit} "
                        f"at {_at(meta, row)} ({int(bad.sum())} sample(s) outside "
                        f"{low:g}…{high:g} {unit}); expected {expected}")


def validate_record(rec: Record) -> None:
    """Raise DataError unless the record is complete, finite, strictly increasing in time and
    its voltage and temperature within CELL_VOLTAGE_RANGE_V and CELL_TEMPERATURE_RANGE_C."""
    src = rec.meta.source
    n = rec.time_s.size
    if n == 0:
        raise DataError(f"{src}: the record is empty (no samples)")
    for name in ("time_s", "current_a", "voltage_v", "temperature_c", "soc_ref", "charge_ah",
                 "ambient_c"):
        arr = getattr(rec, name)
        if arr is None:
            continue
        arr = np.asarray(arr, dtype=float)
        object.__setattr__(rec, name, arr)
        if arr.shape != (n,):
            raise DataError(f"{src}: column '{name}' has shape {arr.shape}, expected ({n},) "
                            "like 'time_s'")
        _check_finite(name, arr, rec.meta)
    dt = np.diff(rec.time_s)
    if (dt <= 0).any():
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        kind = "repeated" if dt[row - 1] == 0 else "decreasing (a time reset?)"
        origin = rec.meta.time_origin_s
        raise DataError(f"{src}: {_column(rec.meta, 'time_s')} is {kind} at "
                        f"{_at(rec.meta, row)}: {round(origin + float(rec.time_s[row - 1]), 9)!r} "
                        f"s then {round(origin + float(rec.time_s[row]), 9)!r} s; expected "
                        "strictly increasing time")
    _check_range("voltage_v", rec.voltage_v, CELL_VOLTAGE_RANGE_V, "V",
                 "a cell's terminal voltage in V, not a pack's (a column in mV: "
                 "--voltage-unit mV, voltage_unit='mV')", rec.meta)
    if rec.temperature_c is not None:
        _check_range("temperature_c", rec.temperature_c, CELL_TEMPERATURE_RANGE_C, "°C",
                     "a cell temperature in °C (a column in K: --temperature-unit K, "
                     "temperature_unit='K')", rec.meta)
    if rec.ambient_c is not None:
        _check_range("ambient_c", rec.ambient_c, CELL_TEMPERATURE_RANGE_C, "°C",
                     "an ambient (chamber) temperature in °C", rec.meta)
    if rec.soc_ref is not None:
        outside = soc_outside(rec.soc_ref)
        if outside.size:
            row = int(outside[0])
            raise DataError(f"{src}: 'soc_ref' is {rec.soc_ref[row]:.4f} at row {row}; expected "
                            "a fraction within 0…1 (check start SoC and capacity)")
