"""Input traces for `lmncell simulate` and `lmncell sweep`: vehicle speed traces (the shipped
drive cycles, or the user's CSV) and cell current profiles (the user's CSV).

A trace file is a CSV with a header (commas, semicolons or tabs between the columns) whose
columns are found by name, case-insensitively, the unit after '_' or in the name's brackets,
parentheses or after a slash ('Time [s]' is time_s, 'Speed (km/h)' speed_kmh); its time rises
in even steps of any length. A
value that is not a finite number, a time that does not rise evenly, or a value outside its
quantity's limits is refused with the file, column, line and value.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lmncell.data.records import DataError

CYCLES = {"udds": "udds.csv", "us06": "us06.csv", "hwfet": "hwfet.csv", "wltc": "wltc_3b.csv"}
MAX_SPEED_MPS = 100.0   # 360 km/h: a faster speed in a trace is a unit mix-up
MAX_GRADE = 0.5         # rise over run: a steeper road in a trace is a unit mix-up (%, degrees)
DELIMITERS = ",;\t"     # the header's first of these that it holds is the delimiter
TIME_COLUMNS = {"cycsecs": (1.0, "s"), "time_s": (1.0, "s"), "time": (1.0, "s"),
                "time_ms": (1e-3, "ms"), "time_min": (60.0, "min"), "time_h": (3600.0, "h")}
UNIT_KEYS = {"km/h": "kmh", "m/s": "mps", "mi/h": "mph", "sec": "s"}   # a name's unit as a key


def data_dir() -> Path:
    """The shipped data folder: the installed package's copy of the clone's `data/`,
    `lmncell/datasets` (`pip install .` or a wheel), else `data/` itself beside the package's
    source folder (an editable install)."""
    package = Path(__file__).resolve().parents[1]
    installed = package / "datasets"
    return installed if installed.is_dir() else package.parent / "data"


@dataclass(frozen=True)
class TraceFormat:
    """What a kind of trace file holds: per quantity its accepted column names (lower case)
    with the factor to SI units and the column's unit; the quantities it must have; limits
    (low, high, note) in SI units; and how `expected` in messages describes it."""

    kind: str
    columns: dict[str, dict[str, tuple[float, str]]]
    required: tuple[str, ...]
    limits: dict[str, tuple[float, float, str]]
    expected: str
    breakpoints: bool = False   # its times may be uneven or repeat (held_on_even_steps)


SPEED_TRACE = TraceFormat(
    "speed trace",
    {"time": TIME_COLUMNS,
     "speed": {"cycmps": (1.0, "m/s"), "speed_mps": (1.0, "m/s"), "speed_kmh": (1 / 3.6, "km/h"),
               "speed_mph": (0.44704, "mph")},
     "grade": {"cycgrade": (1.0, ""), "grade": (1.0, "")}},
    ("time", "speed"),
    {"speed": (0.0, MAX_SPEED_MPS, ""),
     "grade": (-MAX_GRADE, MAX_GRADE, " (rise over run, not % or degrees)")},
    "a CSV with a header: a time column (time_s, or FASTSim's cycSecs), a speed column "
    "(speed_mps, speed_kmh, speed_mph, or cycMps) and optionally the road grade as rise over "
    "run (grade, or cycGrade); a unit may also stand in brackets: 'Speed [km/h]'")

CURRENT_PROFILE = TraceFormat(
    "current profile",
    {"time": TIME_COLUMNS, "current": {"current_a": (1.0, "A"), "current": (1.0, "A"),
                                       "current_ma": (1e-3, "mA"), "i_a": (1.0, "A"),
                                       "i_ma": (1e-3, "mA")}},
    ("time", "current"),
    {},
    "a CSV with a header: a time column (time_s) and a cell current column (current_a or "
    "current_ma; > 0 charges); a unit may also stand in brackets: 'Current [mA]', 'I [A]'",
    breakpoints=True)
MAX_PROFILE_STEPS = 5_000_000   # an uneven profile's even steps (held_on_even_steps) at most


@dataclass(frozen=True)
class TraceColumn:
    """Where a quantity is in a trace file: column index and name, factor to SI, unit."""

    index: int
    name: str
    factor: float
    unit: str


@dataclass(frozen=True, eq=False)
class Trace:
    """A trace's name (how figures, tables and plots call it) and time (s, even steps)."""

    name: str
    time_s: np.ndarray

    @property
    def step_s(self) -> float:
        """The trace's sample step (s)."""
        return float(np.median(np.diff(self.time_s)))


@dataclass(frozen=True, eq=False)
class SpeedTrace(Trace):
    """A vehicle speed trace: speed (m/s, ≥ 0) and road grade (rise over run) at its times;
    named by a shipped cycle's key in CYCLES, or the trace file's name."""

    speed_mps: np.ndarray
    grade: np.ndarray

    @property
    def title(self) -> str:
        """The name in messages and plots: a shipped cycle's upper-case, a file's as it is."""
        return trace_title(self.name)


@dataclass(frozen=True, eq=False)
class CurrentProfile(Trace):
    """A cell current profile: current (A, > 0 charges) at its times (even steps; a file of
    breakpoints is put on them by held_on_even_steps), each value held over its step; named by
    the file's name."""

    current_a: np.ndarray


def trace_title(name: str) -> str:
    """A trace's name in messages and plots: a shipped cycle's upper-case, a file's as it is."""
    return name.upper() if name in CYCLES else name


def load_cycle(cycle: str | Path | SpeedTrace, where: str = "cycle") -> SpeedTrace:
    """A shipped cycle by name (CYCLES), or a speed-trace CSV file (SPEED_TRACE); a SpeedTrace
    is returned as it is. DataError naming the file, line, column and value where a file is
    not such a trace, and `where` (e.g. the option) where it is neither (cycle_problem)."""
    if isinstance(cycle, SpeedTrace):
        return cycle
    if str(cycle) in CYCLES:
        values = read_trace(data_dir() / "drive_cycles" / CYCLES[str(cycle)], SPEED_TRACE)
        name = str(cycle)
    else:
        problem = cycle_problem(cycle)
        if problem:
            raise DataError(f"{where} {str(cycle)!r}: {problem}")
        values, name = read_trace(Path(cycle), SPEED_TRACE), Path(cycle).name
    grade = values.get("grade", np.zeros_like(values["time"]))
    return SpeedTrace(name, values["time"], values["speed"], grade)


def cycle_problem(cycle: str | Path) -> str:
    """Why a cycle argument names neither a shipped cycle nor a file ('' where it does; the
    file's content is read by load_cycle)."""
    if str(cycle) in CYCLES or Path(cycle).is_file():
        return ""
    return (f"neither one of {list(CYCLES)} nor a speed-trace file{_folder(cycle)}; expected "
            f"a cycle name or {SPEED_TRACE.expected}")


def load_current_profile(path: str | Path | CurrentProfile,
                         discharge_positive: bool = False) -> CurrentProfile:
    """A current-profile CSV file (CURRENT_PROFILE; discharge_positive: the file counts
    discharge as positive, and its sign is turned); a CurrentProfile is returned as it is."""
    if isinstance(path, CurrentProfile):
        return path
    if not Path(path).is_file():
        raise DataError(f"{path}: no such file{_folder(path)}; expected "
                        f"{CURRENT_PROFILE.expected}")
    values = read_trace(Path(path), CURRENT_PROFILE)
    sign = -1.0 if discharge_positive else 1.0
    time_s, current_a = held_on_even_steps(values["time"], sign * values["current"], path)
    return CurrentProfile(Path(path).name, time_s, current_a)


def held_on_even_steps(time_s: np.ndarray, values: np.ndarray, path: str | Path
                       ) -> tuple[np.ndarray, np.ndarray]:
    """A profile given at uneven times (a table of breakpoints: each row's value held from its
    time until the next row's; of rows with one time the last holds, the others last no
    time; the last row ends the profile) as the same steps on an even grid whose step
    divides every interval (to 1 µs; halved where it would be the whole profile), each grid
    value held over its step as an even profile's samples are. Even times are returned as
    they are. DataError where the intervals share no step of at least the profile's length /
    MAX_PROFILE_STEPS."""
    step = np.diff(time_s)
    if not uneven_steps(step).size:
        return time_s, values
    micro = np.round(step * 1e6).astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(micro)])
    grid = int(np.gcd.reduce(micro[micro > 0]))
    if grid == offsets[-1]:      # one interval: counted in half µs, the grid is half of it
        offsets = 2 * offsets
    count = int(offsets[-1] // grid)
    span_s = float(time_s[-1] - time_s[0])
    if count > MAX_PROFILE_STEPS:
        raise DataError(f"{path}: its times, {span_s:g} s from first to last row, share no "
                        f"step longer than {span_s / count:g} s ({count} steps; at most "
                        f"{MAX_PROFILE_STEPS} taken); expected times on a coarser grid, e.g. "
                        "rounded to 1 ms")
    starts = np.arange(count, dtype=np.int64) * grid
    row = np.searchsorted(offsets, starts, side="right") - 1     # the last row at or before
    return time_s[0] + starts * (span_s / offsets[-1]), values[row]


def _folder(path: str | Path) -> str:
    return " (it is a folder)" if Path(path).is_dir() else ""


def read_trace(path: Path, fmt: TraceFormat) -> dict[str, np.ndarray]:
    """A trace file's quantities in SI units (fmt: which columns, limits); DataError naming
    the file, column, line and value where it is not such a file. In a file delimited by ';'
    or tabs (a spreadsheet's export where the decimal mark is a comma) a decimal comma is read
    as the decimal mark."""
    from lmncell.data.readers import decimal_number

    rows, delimiter = _rows(path, fmt)
    decimal = "." if delimiter == "," else ","
    columns = _columns(rows[0][1], path, fmt)
    values = {q: np.empty(len(rows) - 1) for q in columns}
    for j, (line, row) in enumerate(rows[1:]):
        for quantity, col in columns.items():
            cell = row[col.index].strip() if col.index < len(row) else ""
            try:
                values[quantity][j] = decimal_number(cell, decimal) * col.factor
            except ValueError:
                raise DataError(f"{path}: column '{col.name}' at line {line}: {cell!r}; expected "
                                "a number") from None
    lines = [line for line, _ in rows[1:]]
    _check_values(values, columns, lines, path, fmt)
    return values


def _rows(path: Path, fmt: TraceFormat) -> tuple[list[tuple[int, list[str]]], str]:
    """The file's non-blank rows with their line numbers (from 1), the header first, and the
    delimiter (DELIMITERS: the first that the header holds)."""
    from lmncell.data.readers import read_text

    try:
        lines = read_text(path).split("\n")
        delimiter = next((d for d in DELIMITERS if d in lines[0]), ",")
        rows = [(n, row) for n, row in enumerate(csv.reader(lines, delimiter=delimiter), start=1)
                if any(cell.strip() for cell in row)]
    except csv.Error as exc:
        raise DataError(f"{path}: cannot read the {fmt.kind} ({exc}); expected "
                        f"{fmt.expected}") from exc
    if not rows:
        raise DataError(f"{path}: empty; expected {fmt.expected}")
    return rows, delimiter


def _columns(header: list[str], path: Path, fmt: TraceFormat) -> dict[str, TraceColumn]:
    """Each quantity's column in a trace file's header."""
    names = [trace_key(h) for h in header]
    found: dict[str, TraceColumn] = {}
    for quantity, accepted in fmt.columns.items():
        hits = [TraceColumn(k, header[k].strip(), *accepted[n]) for k, n in enumerate(names)
                if n in accepted]
        if len(hits) > 1:
            raise DataError(f"{path}: {len(hits)} {quantity} columns "
                            f"{[h.name for h in hits]}; expected one")
        if hits:
            found[quantity] = hits[0]
    missing = [q for q in fmt.required if q not in found]
    if missing:
        raise DataError(f"{path}: no {' and no '.join(missing)} column in the header "
                        f"{[h.strip() for h in header]}; expected {fmt.expected}")
    return found


def trace_key(name: str) -> str:
    """A header name as TraceFormat.columns spells it: lower case, with a unit in brackets,
    parentheses or after a slash (lmncell.data.readers.split_unit) joined by '_':
    'Time [s]' → 'time_s', 'Speed (km/h)' → 'speed_kmh', 'current/mA' → 'current_ma'."""
    from lmncell.data.readers import split_unit

    name = name.strip().lower()
    base, unit = split_unit(name)
    base = base.strip().replace(" ", "_")
    if not (unit and base):
        return name
    return f"{base}_{UNIT_KEYS.get(unit, unit)}"


def uneven_steps(step: np.ndarray) -> np.ndarray:
    """Indices of the time steps (s) that differ from their median by more than 1e-6 of it (all
    of them where the median is not > 0): empty for a trace in even steps."""
    even = float(np.median(step))
    if not even > 0:
        return np.arange(step.size)
    return np.flatnonzero(~(np.abs(step - even) <= 1e-6 * even))


def _check_times(t: np.ndarray, where: str, lines: list[int], breakpoints: bool) -> None:
    """DataError (where: the file and column) where times fall, or, unless the trace is a
    table of breakpoints (which may repeat a time, not all of them one), do not rise in even
    steps."""
    step = np.diff(t)
    even = float(np.median(step))
    falling = np.flatnonzero(~(step >= 0) if breakpoints else ~(step > 0))
    if falling.size:
        k = int(falling[0])
        raise DataError(f"{where} at line {lines[k + 1]}: {t[k]:g} s then {t[k + 1]:g} s; "
                        "expected times " + ("that do not fall" if breakpoints else
                                             "rising in even steps"))
    if breakpoints:
        if not t[-1] > t[0]:
            raise DataError(f"{where} holds {t[0]:g} s on every row; expected times that rise")
        return
    uneven = uneven_steps(step)
    if uneven.size:
        k = int(uneven[0])
        raise DataError(f"{where} at line {lines[k + 1]}: {t[k]:g} s then {t[k + 1]:g} s; "
                        f"expected times rising in even steps (most steps are {even:g} s)")


def _check_values(values: dict[str, np.ndarray], columns: dict[str, TraceColumn],
                  lines: list[int], path: Path, fmt: TraceFormat) -> None:
    """DataError naming the column, line and value where a trace is not finite, its time does
    not rise in even steps, or a quantity leaves fmt's limits."""
    t = values["time"]
    if t.size < 2:
        raise DataError(f"{path}: {t.size} sample(s); expected at least two")
    for quantity, col in columns.items():
        bad = np.flatnonzero(~np.isfinite(values[quantity]))
        if bad.size:
            raise DataError(f"{path}: column '{col.name}' at line {lines[bad[0]]}: "
                            f"{values[quantity][bad[0]] / col.factor:g}; expected a finite "
                            "number")
    _check_times(t, f"{path}: column '{columns['time'].name}'", lines, fmt.breakpoints)
    for quantity, (low, high, note) in fmt.limits.items():
        if quantity not in values:
            continue
        bad = np.flatnonzero((values[quantity] < low) | (values[quantity] > high))
        if bad.size:
            col = columns[quantity]
            raise DataError(f"{path}: column '{col.name}' at line {lines[bad[0]]}: "
                            f"{values[quantity][bad[0]] / col.factor:g}; expected "
                            f"{low / col.factor:g}…{high / col.factor:g} {col.unit}".rstrip()
                            + note)

