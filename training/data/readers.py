"""Readers for cycler files, chosen by content, each converting to charge-positive current.

Formats: ``plett`` (ESC toolbox CSV, discharge positive), ``arbin`` (Arbin CSV export,
discharge negative), ``panasonic`` (Kollmeyer ``.mat`` with struct ``meas``), ``bdf`` (Battery Data
Format CSV, charge positive), ``biologic`` (EC-Lab / BT-Lab ASCII export ``.mpt``, charge
positive) and ``generic`` (CSV with an explicit column mapping). Files may be gzip-compressed
(``.gz``).
"""

from __future__ import annotations

import codecs
import csv
import gzip
import io
import re
import warnings
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import NamedTuple

import numpy as np
from lmncell.data.records import DataError, Record, RecordMeta
from lmncell.data.resample import find_gaps
from lmncell.data.soc import REST_CURRENT_A
from lmncell.runtime.model import FORMAT as MODEL_FORMAT
from lmncell.runtime.model import replaced_whole

FORMATS = ("plett", "arbin", "panasonic", "bdf", "biologic", "generic")
PLETT_COLUMNS = ("time", "step", "current", "voltage", "chgAh", "disAh")
ARBIN_COLUMNS = ("Test_Time(s)", "Current(A)", "Voltage(V)", "Charge_Capacity(Ah)",
                 "Discharge_Capacity(Ah)")
# Arbin MITS Pro writes these names with underscores ("Test_Time(s)") or, in newer exports, with
# spaces ("Test Time (s)"); either is matched (_arbin_key). Its auxiliary temperature channels
# are "Aux_Temperature_1(C)", "Aux_Temperature_1 (C)", "Aux_Temperature(°C)_1", …: channel 1 is
# read as the cell's temperature
ARBIN_TEMPERATURE = re.compile(r"(aux)?temperature(\d*)\(([^)]*)\)(\d*)")
ARBIN_CELSIUS = ("c", "°c", "°", "degc", "℃")
BDF_TIME, BDF_VOLTAGE, BDF_CURRENT = "Test Time / s", "Voltage / V", "Current / A"
BDF_AMBIENT, BDF_T1 = "Ambient Temperature / degC", "Surface Temperature T1 / degC"
BDF_NET_AH, BDF_SOC = "Net Capacity / Ah", "State of Charge / 1"
# A BDF column is headed by its quantity's preferred label (above, as write_bdf writes them) or
# by its machine-readable name (as the Battery Data Alliance's reference files are); T1's
# earlier label "Temperature T1 / degC" is read too
BDF_ALIASES = {BDF_TIME: ("test_time_second",), BDF_VOLTAGE: ("voltage_volt",),
               BDF_CURRENT: ("current_ampere",), BDF_AMBIENT: ("ambient_temperature_celsius",),
               BDF_T1: ("temperature_t1_celsius", "Temperature T1 / degC"),
               BDF_NET_AH: ("net_capacity_ah",), BDF_SOC: ()}
BDF_REQUIRED = (BDF_TIME, BDF_VOLTAGE, BDF_CURRENT)
# BioLogic EC-Lab / BT-Lab ASCII export (.mpt): a first line naming the software, then
# "Nb header lines : N" (N counts every line up to and including the column names), then
# tab-separated rows with the decimal mark of the exporting PC's locale; I > 0 is oxidation at
# the working electrode, i.e. charge where it is the cell's positive terminal
BIOLOGIC_MAGIC = ("EC-Lab ASCII FILE", "BT-Lab ASCII FILE")
BIOLOGIC_TIME = "time/s"
BIOLOGIC_VOLTAGES = ("Ecell/V", "<Ecell>/V", "Ewe-Ece/V", "Ewe/V", "<Ewe>/V")  # preferred first
BIOLOGIC_CURRENTS = {"I/mA": 1e-3, "<I>/mA": 1e-3, "I/A": 1.0, "<I>/A": 1.0}    # → A
BIOLOGIC_CHARGES = {"(Q-Qo)/mA.h": 1e-3, "(Q-Qo)/A.h": 1.0, "(Q-Qo)/C": 1.0 / 3600.0}  # → Ah
BIOLOGIC_TEMPERATURES = ("Temperature/°C", "<Temperature>/°C", "T/°C")
BIOLOGIC_FREQUENCY = "freq/Hz"     # > 0 on the rows of an impedance measurement (EIS)
MAX_PREAMBLE_LINES = 1000  # how far the generic reader looks for the line of the column names
MIN_LOG_STEP_S = 1e-3  # a median time step below this is taken as a time in the wrong unit
GAP_FACTOR = 20.0       # a time step this many times the median step starts a new segment
PAUSE_MIN_S = 60.0      # a wall-clock jump this much beyond the Time column marks a hidden pause


class DataWarning(UserWarning):
    """Data that loads but looks suspicious (units, sign)."""


# Plett's ESC procedure runs these scripts at 25 °C whatever the test temperature in the name:
# the dynamic test's s2 (discharge to the 0 % anchor) and s3 (charge back to full), and the OCV
# test's S2 and S4 (dither to 0 % and to 100 %)
PLETT_25C_SCRIPT = re.compile(r"^A123_(?:DYN_\d+_[NP]\d{2}_s[23]|OCV_[NP]\d{2}_S[24])\.",
                              flags=re.IGNORECASE)


def chamber_temp_from_name(path: str | Path) -> float | None:
    """Chamber temperature (°C) from a file name: A123 ``_N25_``/``_P45_`` (25 °C for the
    scripts that Plett's procedure runs at 25 °C, PLETT_25C_SCRIPT), or ``25degC``, ``-10degC``
    and the Panasonic files' ``n10degC`` (−10 °C) and ``p0degC`` (an ``n`` or ``p`` that
    ends a word, as in ``run10degC``, is no sign)."""
    name = Path(path).name
    if PLETT_25C_SCRIPT.match(name):
        return 25.0
    m = re.search(r"_([NP])(\d{2})(?:_|\.)", name)
    if m:
        return (-1.0 if m.group(1) == "N" else 1.0) * float(m.group(2))
    m = re.search(r"(?:(?<![a-z])([np]))?(-?\d+)\s*deg\s*C", name, flags=re.IGNORECASE)
    if m is None:
        return None
    return -float(m.group(2)) if (m.group(1) or "").lower() == "n" else float(m.group(2))


TEXT_EXPECTED = "expected a CSV text file, a MATLAB .mat file or either gzip-compressed (.gz)"
ZIP_MAGIC = b"PK\x03\x04"
BINARY_KINDS = (       # what a binary file given as data is, by its first bytes
    (ZIP_MAGIC, "a ZIP archive, such as an Excel workbook (.xlsx: save its sheet as CSV) "
                     "or an FMU"),
    (b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1", "an OLE compound file, such as an Excel 97–2003 "
                                           "workbook (.xls: save its sheet as CSV)"),
    (b"\x89HDF\r\n\x1a\n", "an HDF5 file (a MATLAB v7.3 .mat file: save it with "
                           "save(..., '-v7'))"),
    # cyclers' own binary files: their software exports the text that the readers take
    (b"BIO-LOGIC MODULAR FILE", "a BioLogic EC-Lab binary file (.mpr: export it as text, "
                                ".mpt, in EC-Lab)"),
    (b"NEWARE", "a Neware .nda file (export it as CSV in Neware's BTSDA)"),
    (b"\x00\x01\x00\x00Standard Jet DB", "a Microsoft Access database, such as an Arbin .res "
                                        "file (export it as CSV in Arbin's MITS Pro)"),
    (b"\x00\x01\x00\x00Standard ACE DB", "a Microsoft Access database, such as an Arbin .res "
                                        "file (export it as CSV in Arbin's MITS Pro)"),
)
ZIP_KINDS = {".ndax": "a Neware .ndax archive (export it as CSV in Neware's BTSDA)"}
HEAD_BYTES = 1 << 20    # how much of a file detect_format decodes for its first line


def _raw_bytes(path: Path, limit: int | None = None) -> bytes:
    """The file's bytes (gunzipped for .gz), the first `limit` of them where given."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rb") as fh:
        return fh.read(-1 if limit is None else limit)


def text_encoding(raw: bytes, final: bool = True) -> str | None:
    """The encoding of a text file's bytes: UTF-8 (with or without a BOM), UTF-16 (with its
    BOM: Excel's "Unicode text"), else Windows-1252 (older Western exports, µ and ° in
    their headers); None for bytes that are none of them (NUL bytes without a UTF-16 BOM:
    not text). final: raw is the whole file (else its head, which may end inside a character)."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "utf-16"
    if b"\x00" in raw:
        return None
    for encoding in ("utf-8-sig", "cp1252"):
        try:
            codecs.getincrementaldecoder(encoding)().decode(raw, final=final)
            return encoding
        except UnicodeDecodeError:
            continue
    return None


def read_text(path: Path, first_line: bool = False, head: bool = False) -> str:
    """The file's text (or its first line, or its first HEAD_BYTES) in its encoding
    (text_encoding), with a DataError for what is not text."""
    part = first_line or head
    try:
        raw = _raw_bytes(path, HEAD_BYTES if part else None)
    except (gzip.BadGzipFile, EOFError, OSError) as exc:
        raise DataError(f"{path}: cannot be read ({exc}); {TEXT_EXPECTED}") from None
    encoding = text_encoding(raw, final=not part)
    if encoding is None:
        where = raw.find(b"\x00")
        what = next((kind for magic, kind in BINARY_KINDS if raw.startswith(magic)), None)
        if raw.startswith(ZIP_MAGIC):                       # a ZIP archive: which, by its name
            what = ZIP_KINDS.get(Path(str(path).removesuffix(".gz")).suffix.lower(), what)
        what = what or (f"a NUL byte at offset {where}" if where >= 0 else
                        "bytes that are neither UTF-8, UTF-16 nor Windows-1252")
        raise DataError(f"{path}: not a text file ({what}); {TEXT_EXPECTED}")
    try:
        text = codecs.getincrementaldecoder(encoding)().decode(raw, final=not part)
    except UnicodeDecodeError as exc:             # a UTF-16 file cut in a character
        raise DataError(f"{path}: not a text file ({encoding}: {exc.reason} at byte "
                        f"{exc.start}); {TEXT_EXPECTED}") from None
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text.split("\n", 1)[0] if first_line else text


def check_readable(path: str | Path) -> Path:
    """The path, if it names a readable, non-empty file; DataError naming the problem if not."""
    path = Path(path)
    if path.is_dir():
        raise DataError(f"{path}: is a directory; expected a data file ({_folder_contents(path)})")
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if not path.is_file():
        raise DataError(f"{path}: not a regular file; expected a data file")
    try:
        with open(path, "rb") as fh:
            fh.read(1)
    except OSError as exc:
        raise DataError(f"{path}: cannot be opened ({exc.strerror or exc})") from None
    if path.stat().st_size == 0:
        raise DataError(f"{path}: the file is empty")
    return path


def _folder_contents(folder: Path) -> str:
    """What a folder given as a data file holds, as the files to give instead: a shell pattern
    per kind of file ('give the files inside it: DIR/*.mat (4 files)') and its subfolders."""
    counts: dict[str, int] = {}
    subfolders = []
    for f in sorted(folder.iterdir()):
        if f.name.startswith("."):
            continue
        if f.is_dir():
            subfolders.append(f"{f.name}/")
        elif f.is_file():
            kind = "".join(f.suffixes[-2:]) if f.suffix == ".gz" else f.suffix
            counts[kind] = counts.get(kind, 0) + 1
    files = ", ".join(f"{folder}/*{kind} ({n} file{'s' if n > 1 else ''})"
                      for kind, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    inside = f"give the files inside it: {files}" if files else "it holds no file"
    return inside + (f"; its folders: {', '.join(subfolders)}" if subfolders else "")


def _mat_path(path: Path) -> bool:
    return path.name.endswith((".mat", ".mat.gz"))


def detect_format(path: str | Path) -> str:
    """Name of the reader for a file, from its content (header line or MATLAB signature)."""
    return _format_of(check_readable(path))


def _format_of(path: Path) -> str:
    """detect_format for a path already checked by check_readable."""
    if _mat_path(path):
        return "panasonic"
    header = read_text(path, first_line=True).strip()
    if not header:
        raise DataError(f"{path}: the file is empty; expected a header line")
    if header.startswith(BIOLOGIC_MAGIC):
        return "biologic"
    cols = [c.strip() for c in header.split(",")]
    if cols[: len(PLETT_COLUMNS)] == list(PLETT_COLUMNS):
        return "plett"
    if _arbin_names(cols) is not None:
        return "arbin"
    if all(q in _bdf_names(cols) for q in BDF_REQUIRED):
        return "bdf"
    if header.startswith(("{", "[{", "[[")) or header == "[":      # JSON, not a table
        raise DataError(f"{path}: {_json_kind(path)}, not a measurement record; "
                        f"{TEXT_EXPECTED}")
    if _is_speed_trace(cols):
        raise DataError(f"{path}: a vehicle speed trace ({', '.join(cols[:3])}), not a "
                        "measurement record; a model drives it with lmncell simulate CELL.fmu "
                        f"--cycle {path} (or lmncell sweep --cycles)")
    raise DataError(f"{path}: unknown format; header {header[:120]!r} matches none of "
                    f"{list(FORMATS[:5])}. Name your columns: on the command line "
                    "--columns time=COL,current=COL,voltage=COL[,temperature=COL]"
                    "[,ambient=COL][,charge=COL][,state=COL] (with "
                    "--delimiter, --decimal, --current-unit, --time-unit, --voltage-unit, "
                    "--temperature-unit, --charge-unit, --discharge-positive as needed); "
                    "in Python read_record(path, columns={...})"
                    + _suggestion(path))


SUGGESTION_LINES = 100    # how far down a cycler's preamble the header of a proposal may lie


def _suggestion(path: Path) -> str:
    """'. For this header, perhaps: OPTIONS …' for the first of the file's first
    SUGGESTION_LINES lines that names a time, a current and a voltage column
    (lmncell.data.header, with the line under it as its first row), or ''."""
    from lmncell.data.header import suggested_options

    lines = read_text(path, head=True).split("\n", SUGGESTION_LINES + 1)[:SUGGESTION_LINES + 1]
    for k, line in enumerate(lines[:-1]):
        options = suggested_options(line, lines[k + 1])
        if options is not None:
            return (f". For this header (line {k + 1}), perhaps: {options} (check the columns; "
                    "add --discharge-positive where the file counts discharge current as "
                    "positive)")
    return ""


def _is_speed_trace(columns: list[str]) -> bool:
    """Whether a header's columns are those of a vehicle speed trace (lmncell.scenarios.traces:
    a time and a speed column, as `lmncell simulate --cycle` reads them)."""
    from lmncell.scenarios.traces import SPEED_TRACE, trace_key

    names = {trace_key(c) for c in columns}
    return (all(names & set(SPEED_TRACE.columns[q]) for q in SPEED_TRACE.required)
            and not any("volt" in name for name in names))     # a vehicle's log is a record


def _json_kind(path: Path) -> str:
    """What a JSON file given as data seems to be: an LMNCell model file, or some JSON."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if f'"format": "{MODEL_FORMAT}"'.encode() in head:
        return ("an LMNCell model file (give it as the model: lmncell evaluate MODEL.json "
                "DATA...)")
    return "a JSON file"


class CsvColumns(dict):
    """A CSV file's columns by header name (float arrays), and the file line of the first data
    row where the data rows follow each other without blank lines (else None); text: the
    cells as written of the columns asked for (keep_text), lines: each data row's file
    line, and notes: what was left out (a data line that repeats the one before it)."""

    first_line: int | None = None
    text: dict[str, list[str]]
    lines: list[int]
    notes: list[str]


def _read_csv_columns(path: Path, sep: str = ",", decimal: str = ".",
                      required: frozenset[str] | set[str] | None = None,
                      keep_text: frozenset[str] | set[str] = frozenset(),
                      header_line: int = 1, lines: list[str] | None = None,
                      units_row: bool = False,
                      blank_ok: frozenset[str] | set[str] = frozenset()) -> CsvColumns:
    """Every column of a CSV file as float arrays, with the file's line numbers in errors.

    sep: the field delimiter; decimal: the decimal mark ("." or ","); required: columns whose
    every cell must be a number (default: the known formats' numeric columns); keep_text:
    columns whose cells are also kept as written (CsvColumns.text); header_line: the file line
    of the column names (1: the first; the lines before it are skipped); lines: the file's
    lines where the caller has read them already (read_text); units_row: the line after the
    names holds units, not data (skipped); blank_ok: required columns whose empty cells are
    let through as NaN (an auxiliary channel read every few rows)."""
    _check_marks(path, sep, decimal)
    required = _NUMERIC_REQUIRED if required is None else required
    lines = read_text(path).splitlines() if lines is None else lines
    numbered = [(k + 1, ln) for k, ln in enumerate(lines)
                if k + 1 >= header_line and ln.strip()]
    if not numbered:
        raise DataError(f"{path}: the file is empty; expected a header line and data rows")
    header = [c.strip() for c in next(csv.reader([numbered[0][1]], delimiter=sep))]
    numbered = numbered[:1] + numbered[2:] if units_row else numbered
    if len(numbered) < 2:
        raise DataError(f"{path}: the file has a header but no data rows")
    data, notes = _without_repeated_lines(numbered[1:])
    line_of = [k for k, _ in data]
    rows = list(csv.reader([ln for _, ln in data], delimiter=sep, skipinitialspace=True))
    out = CsvColumns()
    out.text, out.lines, out.notes = {}, line_of, notes
    for j, name in enumerate(header):
        if name in keep_text:
            out.text[name] = [row[j].strip() if j < len(row) else "" for row in rows]
        col = np.empty(len(rows))
        for r, row in enumerate(rows):
            try:
                cell = row[j].strip()
                col[r] = decimal_number(cell, decimal)
            except (ValueError, IndexError):
                if j >= len(row):
                    raise DataError(f"{path}: line {line_of[r]} has {len(row)} fields, "
                                    f"expected {len(header)} (column '{name}' missing)"
                                    ) from None
                col[r] = np.nan  # non-numeric cell (date strings etc.): checked where used
                if name in required and not (name in blank_ok and cell == ""):
                    raise DataError(f"{path}: column '{name}' line {line_of[r]}: {row[j]!r} "
                                    f"is not a number{_comma_hint(cell, decimal)}") from None
        out[name] = col
    if line_of[-1] - line_of[0] == len(line_of) - 1:
        out.first_line = line_of[0]
    return out


def _without_repeated_lines(numbered: list[tuple[int, str]]
                            ) -> tuple[list[tuple[int, str]], list[str]]:
    """The data lines (file line, text) without those that repeat the line before them
    character for character (a logger that wrote one sample twice: same time, same values),
    and a note saying how many were left out and where the first was."""
    kept = numbered[:1]
    repeated = []
    for line, text in numbered[1:]:
        if text.strip() == kept[-1][1].strip():
            repeated.append(line)
        else:
            kept.append((line, text))
    if not repeated:
        return numbered, []
    return kept, [f"left out {len(repeated)} data line(s) that repeat the line before them "
                  f"exactly (the same sample logged twice), first line {repeated[0]}"]


def _check_marks(path: Path, sep: str, decimal: str) -> None:
    """DataError unless sep is one character that can delimit fields and decimal is "." or
    ","."""
    if not isinstance(sep, str) or len(sep) != 1 or sep in (decimal, '"') or sep.isalnum():
        raise DataError(f"{path}: delimiter {sep!r}; expected one character other than the "
                        f"decimal mark {decimal!r}, a quote, a letter or a digit")
    if decimal not in (".", ","):
        raise DataError(f"{path}: decimal mark {decimal!r}; expected '.' or ','")


def _comma_hint(cell: str, decimal: str) -> str:
    """A hint where a cell that is not a number reads as one with a decimal comma."""
    if decimal == "." and re.fullmatch(r"[-+]?\d+,\d+(?:[eE][-+]?\d+)?", cell):
        return " (a decimal comma? give the decimal mark: --decimal ',' or decimal=',')"
    return ""


def _csv_meta(cols: CsvColumns, file_times: np.ndarray, /, **names: str) -> dict:
    """The RecordMeta fields that let errors name a CSV record's lines and columns: names maps
    record fields (time_s, current_a, …) to the file's column names; file_times is the file's
    time column, from whose first value the record's time counts."""
    return {"file_columns": names, "first_line": cols.first_line,
            "time_origin_s": float(file_times[0])}


_NUMERIC_REQUIRED = {"time", "current", "voltage", "chgAh", "disAh", *ARBIN_COLUMNS,
                     *BDF_REQUIRED}


def _require(path: Path, cols: Mapping[str, np.ndarray], names: tuple[str, ...],
             sep: str | None = None) -> None:
    """DataError naming the columns missing, with what was found (and, given the delimiter
    the header was split by, a hint where the names read as one joined by another)."""
    missing = [n for n in names if n not in cols]
    if missing:
        raise DataError(f"{path}: missing column(s) {missing}; found {list(cols)}"
                        + ("" if sep is None else _delimiter_hint(list(cols), sep)))


def _delimiter_hint(found: list[str], sep: str) -> str:
    """' (…give the delimiter …)' where a header split by sep holds one of the usual other
    delimiters inside its names (a file delimited by ';' or tabs read with ','), else ''."""
    for other, shown, cli, python in ((";", "';'", "';'", "';'"),
                                      ("\t", "a tab", "tab", "'\\t'"),
                                      (",", "','", "','", "','")):
        if other != sep and any(other in name for name in found):
            return (f" (the names hold {shown}: is that the delimiter? give it: --delimiter "
                    f"{cli} or sep={python})")
    return ""


def _segment_starts_from_gaps(time_s: np.ndarray, current_a: np.ndarray | None = None,
                              charge_ah: np.ndarray | None = None) -> list[int]:
    return [0, *find_gaps(time_s, GAP_FACTOR, current_a, charge_ah).tolist()]


def _meta(path: Path, fmt: str, sign_note: str, time_s: np.ndarray, **kw) -> RecordMeta:
    dt = np.diff(time_s)
    ts = float(np.median(dt)) if dt.size else float("nan")
    return RecordMeta(source=str(path), fmt=fmt, sign_note=sign_note, sample_time_s=ts,
                      chamber_temp_c=chamber_temp_from_name(path), **kw)


def read_plett(path: Path) -> Record:
    """Plett ESC toolbox CSV: ``time, step, current, voltage, chgAh, disAh``; discharge > 0."""
    cols = _read_csv_columns(path, sep=",")
    _require(path, cols, PLETT_COLUMNS)
    t = cols["time"] - cols["time"][0]
    cur = -cols["current"]
    ah, notes = _stitched_counter("chgAh − disAh", cols["time"], cur,
                                  cols["chgAh"] - cols["disAh"])
    return Record(t, cur, cols["voltage"],
                  _meta(path, "plett", "current negated (file: discharge > 0)", cols["time"],
                        segment_starts=_segment_starts_from_gaps(t, cur, ah),
                        notes=[*cols.notes, *notes],
                        **_csv_meta(cols, cols["time"], time_s="time", current_a="current",
                                    voltage_v="voltage", charge_ah="chgAh − disAh")),
                  charge_ah=ah)


def read_arbin(path: Path) -> Record:
    """Arbin CSV export (``Test_Time(s)``, ``Current(A)``, …, or the same names with spaces,
    ``Test Time (s)``); discharge < 0 already. Auxiliary temperature channel 1 (or the only
    temperature column) is the cell's temperature; a channel read every few rows, blank
    between readings, holds each reading until the next (noted), as the BDF reader's does."""
    header = _header_names(path)
    names = _arbin_names(header)
    if names is None:
        raise DataError(f"{path}: missing Arbin column(s); expected {list(ARBIN_COLUMNS)} (or "
                        f"the same names with spaces), found {header}")
    temp_column, notes = _arbin_temperature(header)
    text = {temp_column} if temp_column else set()
    cols = _read_csv_columns(path, required=set(names.values()), keep_text=text,
                             blank_ok=text)
    t, cur = cols[names["Test_Time(s)"]], cols[names["Current(A)"]]
    temp = None
    readings = cols[temp_column][~np.isnan(cols[temp_column])] if temp_column else None
    if readings is not None and not np.any(readings):
        notes.append(f"column '{temp_column}' "
                     + ("reads 0 throughout" if readings.size else "has no reading")
                     + " (no sensor on the channel?): not read as the cell's temperature")
        temp_column = None
    if temp_column is not None:
        temp, more = _held_readings(cols, temp_column, path)
        notes += more
    ah, more = _stitched_counter(      # Arbin's capacities restart at each cycle
        f"{names['Charge_Capacity(Ah)']} − {names['Discharge_Capacity(Ah)']}", t, cur,
        cols[names["Charge_Capacity(Ah)"]] - cols[names["Discharge_Capacity(Ah)"]])
    meta = _meta(path, "arbin", "none (file: charge > 0)", t,
                 segment_starts=_segment_starts_from_gaps(t, cur, ah),
                 notes=[*cols.notes, *notes, *more],
                 **_csv_meta(cols, t, time_s=names["Test_Time(s)"], current_a=names["Current(A)"],
                             voltage_v=names["Voltage(V)"],
                             charge_ah=f"{names['Charge_Capacity(Ah)']} − "
                                       f"{names['Discharge_Capacity(Ah)']}"))
    if temp_column is not None:
        meta.file_columns["temperature_c"] = temp_column
    return Record(t - t[0], cur, cols[names["Voltage(V)"]], meta, temperature_c=temp,
                  charge_ah=ah)


def _header_names(path: Path) -> list[str]:
    """The column names on a comma-separated file's first line, stripped."""
    return [c.strip() for c in next(csv.reader([read_text(path, first_line=True)]))]


def _arbin_key(name: str) -> str:
    """An Arbin column name without spaces and underscores, in lower case: "Test Time (s)" and
    "Test_Time(s)" give one key."""
    return re.sub(r"[\s_]", "", name).lower()


def _arbin_names(header: list[str]) -> dict[str, str] | None:
    """The file's name for each of ARBIN_COLUMNS (in either spelling), or None where one is
    missing."""
    by_key = {_arbin_key(name): name for name in header}
    found = {column: by_key.get(_arbin_key(column)) for column in ARBIN_COLUMNS}
    return None if None in found.values() else {k: v for k, v in found.items() if v}


def _arbin_temperature(header: list[str]) -> tuple[str | None, list[str]]:
    """The column of an Arbin export read as the cell's temperature (auxiliary channel 1, else
    the only temperature column in °C), and notes naming the temperature columns not read."""
    celsius: list[tuple[str, str]] = []
    other: list[tuple[str, str]] = []
    for name in header:
        m = ARBIN_TEMPERATURE.fullmatch(_arbin_key(name))
        if m is not None:
            (celsius if m.group(3) in ARBIN_CELSIUS else other).append(
                (name, m.group(2) or m.group(4)))
    first = [name for name, channel in celsius if channel == "1"]
    chosen = first[0] if first else celsius[0][0] if len(celsius) == 1 else None
    left = [name for name, _ in celsius if name != chosen]
    notes = []
    if left:
        notes.append(f"temperature column(s) {left} not read"
                     + (f": the cell's temperature is '{chosen}' (auxiliary channel 1)"
                        if chosen else ": none is auxiliary channel 1, so none is taken as the "
                        "cell's; name it with --columns …,temperature=COL"))
    if other:
        notes.append(f"temperature column(s) {[name for name, _ in other]} not read: their "
                     "unit is not °C (name one with --columns …,temperature=COL and "
                     "--temperature-unit)")
    return chosen, notes


def chamber_set_point(logged_c: np.ndarray) -> float:
    """The chamber's set point (°C) from its logged temperature: the median of the readings
    (NaN readings left out), which a chamber still settling at the start does not move."""
    return float(np.nanmedian(logged_c))


def _parse_timestamps(stamps: np.ndarray) -> np.ndarray:
    """Wall-clock ``M/D/YYYY h:mm:ss AM`` strings to seconds since the first one."""
    flat = [str(np.ravel(s)[0]) if np.size(s) else "" for s in np.ravel(stamps)]
    cache: dict[str, float] = {}
    out = np.empty(len(flat))
    for k, s in enumerate(flat):
        if s not in cache:
            fmt = "%m/%d/%Y %I:%M:%S %p" if ":" in s else "%m/%d/%Y"  # midnight has no time
            cache[s] = datetime.strptime(s, fmt).timestamp()
        out[k] = cache[s]
    return out - out[0]


def _mat_field(meas: np.ndarray, name: str, path: Path, size: int | None = None) -> np.ndarray:
    """A field of a MATLAB struct as a flat float array of `size` values (any where None), or
    DataError naming the file and field (an IndexError or ValueError before)."""
    try:
        values = np.asarray(meas[name], dtype=float).ravel()
    except (TypeError, ValueError):
        raise DataError(f"{path}: field '{name}' is not numeric; expected one number per "
                        "sample") from None
    if size is not None and values.size != size:
        raise DataError(f"{path}: field '{name}' holds {values.size} value(s) for {size} times "
                        "(field 'Time'); expected one per sample")
    return values


def read_panasonic(path: Path) -> Record:
    """Kollmeyer Panasonic 18650PF ``.mat`` (struct ``meas``); discharge < 0 already.

    Duplicate time stamps are dropped (counted in meta.notes). Gaps in ``Time`` and pauses that only
    ``TimeStamp`` shows start new segments (meta.segment_starts; the pauses also in
    meta.pause_starts); ``Ah`` carries charge across.
    """
    meas = _panasonic_struct(path)
    fields = meas.dtype.names or ()
    t, keep, notes = _panasonic_times(meas, path)

    def field_(name: str) -> np.ndarray:
        return _mat_field(meas, name, path, keep.size)[keep]

    cur = field_("Current")
    ah, more = _stitched_counter("Ah", t, cur, field_("Ah"))
    notes += more
    gaps = set(_segment_starts_from_gaps(t, cur, ah))
    hidden, more = _hidden_pauses(meas, path, t, keep)
    notes += more
    pauses = set(hidden) - gaps
    temp = field_("Battery_Temp_degC") if "Battery_Temp_degC" in fields else None
    if temp is not None and not np.isfinite(temp).all():
        notes.append("Battery_Temp_degC has non-finite samples: temperature not used")
        temp = None
    meta = _meta(path, "panasonic", "none (file: charge > 0)", t,
                 segment_starts=sorted(gaps | pauses), notes=notes, pause_starts=sorted(pauses),
                 file_columns={"time_s": "Time", "current_a": "Current", "voltage_v": "Voltage",
                               "temperature_c": "Battery_Temp_degC", "charge_ah": "Ah"},
                 time_origin_s=float(t[0]) if t.size else 0.0)
    ambient = None
    if "Chamber_Temp_degC" in fields:
        chamber = field_("Chamber_Temp_degC")
        if np.isfinite(chamber).any():
            meta.chamber_temp_c = chamber_set_point(chamber)
        if temp is not None and np.isfinite(chamber).all():
            ambient = chamber        # the chamber as logged beside the cell: the thermal
            meta.file_columns["ambient_c"] = "Chamber_Temp_degC"   # model's ambient
    return Record(t - t[0], cur, field_("Voltage"), meta, temperature_c=temp,
                  charge_ah=ah, ambient_c=ambient)


def _panasonic_struct(path: Path) -> np.ndarray:
    """The struct ``meas`` of a Panasonic ``.mat`` (or ``.mat.gz``) file, with the fields Time,
    Voltage, Current and Ah; DataError naming the file for anything else."""
    import scipy.io

    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rb") as fh:
                mat = scipy.io.loadmat(io.BytesIO(fh.read()))
        else:
            mat = scipy.io.loadmat(str(path))
    except NotImplementedError:     # scipy's answer to a v7.3 (HDF5) file
        raise DataError(f"{path}: a MATLAB v7.3 (HDF5) file, which is not read here; expected "
                        "a v7 or older .mat file (in MATLAB: save(FILE, 'meas', '-v7'))"
                        ) from None
    except Exception as exc:  # scipy raises several types for corrupt files
        raise DataError(f"{path}: not a readable MATLAB file ({exc})") from exc
    if "meas" not in mat:
        raise DataError(f"{path}: no struct 'meas' in the MATLAB file; found "
                        f"{[k for k in mat if not k.startswith('__')]}")
    meas = mat["meas"][0, 0]
    fields = meas.dtype.names or ()
    missing = [f for f in ("Time", "Voltage", "Current", "Ah") if f not in fields]
    if missing:
        raise DataError(f"{path}: struct 'meas' lacks field(s) {missing}; found {list(fields)}")
    return meas


def _panasonic_times(meas: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The field Time (s) without its repeated stamps, the mask of the samples kept and the
    notes saying what was dropped; DataError for an empty, non-finite or decreasing Time."""
    t = _mat_field(meas, "Time", path)
    if t.size == 0:
        raise DataError(f"{path}: field 'Time' is empty; expected one time (s) per sample")
    if not np.isfinite(t).all():
        first = int(np.flatnonzero(~np.isfinite(t))[0])
        raise DataError(f"{path}: field 'Time' holds {int((~np.isfinite(t)).sum())} NaN or "
                        f"infinite value(s), the first at sample {first + 1}; expected finite "
                        "times (s)")
    keep = np.ones(t.size, dtype=bool)
    keep[1:] = np.diff(t) > 0
    notes = []
    if (~keep).any():
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size:
            raise DataError(f"{path}: field 'Time' decreases at sample {int(back[0]) + 1} "
                            f"({float(t[back[0]])!r} s then {float(t[back[0] + 1])!r} s); expected "
                            "increasing time")
        notes.append(f"dropped {int((~keep).sum())} sample(s) with a repeated time stamp")
    return t[keep], keep, notes


def _hidden_pauses(meas: np.ndarray, path: Path, t: np.ndarray, keep: np.ndarray
                   ) -> tuple[list[int], list[str]]:
    """The samples (indices into the kept ones) at which the wall clock ``TimeStamp`` shows a
    pause longer than PAUSE_MIN_S that ``Time`` (t, s) hides, and a note for each; none
    without a TimeStamp field."""
    if "TimeStamp" not in (meas.dtype.names or ()):
        return [], []
    stamps = np.ravel(meas["TimeStamp"])
    if stamps.size != keep.size:
        raise DataError(f"{path}: field 'TimeStamp' holds {stamps.size} value(s) for "
                        f"{keep.size} times; expected one per sample")
    try:
        wall = _parse_timestamps(stamps[keep])
    except ValueError as exc:
        raise DataError(f"{path}: field 'TimeStamp': {exc}; expected wall-clock times "
                        "such as '3/20/2017 5:56:01 AM'") from None
    hidden = np.flatnonzero(np.diff(wall) - np.diff(t) > PAUSE_MIN_S) + 1
    return hidden.tolist(), [f"pause of {wall[k] - wall[k - 1]:.0f} s hidden in 'Time' at "
                             f"sample {k}" for k in hidden]


def read_bdf(path: Path) -> Record:
    """Battery Data Format CSV (``Test Time / s``, ``Voltage / V``, ``Current / A``, …, or the
    machine-readable names ``test_time_second``, ``voltage_volt``, ``current_ampere``, …:
    BDF_ALIASES). A temperature column read every few rows, blank between readings, holds each
    reading until the next (noted), as the generic reader's does. The cell's temperature is
    T1 (``Surface Temperature T1 / degC``); ``Ambient Temperature / degC`` is the record's
    ambient (Record.ambient_c: beside T1 the thermal model's, per step where it varies; alone
    the record's temperature)."""
    header = _header_names(path)
    names = _bdf_names(header)
    missing = [q for q in BDF_REQUIRED if q not in names]
    if missing:
        raise DataError(f"{path}: missing column(s) {missing} (or the machine-readable "
                        f"name(s) {[BDF_ALIASES[q][0] for q in missing]}); found {header}")
    time_c, volt_c, cur_c = (names[q] for q in BDF_REQUIRED)
    t1_c, ambient_c, net_c, soc_c = (names.get(q) for q in (BDF_T1, BDF_AMBIENT, BDF_NET_AH,
                                                             BDF_SOC))
    cols = _read_csv_columns(path, required={time_c, volt_c, cur_c},
                             keep_text={c for c in (t1_c, ambient_c) if c})
    t = cols[time_c]
    temp, notes = _held_readings(cols, t1_c, path) if t1_c else (None, [])
    net_ah = None
    if net_c:
        net_ah, more = _stitched_counter(net_c, t, cols[cur_c], cols[net_c])
        notes += more
    file_columns = {"time_s": time_c, "current_a": cur_c, "voltage_v": volt_c,
                    **{field: c for field, c in (("soc_ref", soc_c), ("charge_ah", net_c),
                                                 ("temperature_c", t1_c)) if c}}
    meta = _meta(path, "bdf", "none (BDF: charge > 0)", t,
                 segment_starts=_segment_starts_from_gaps(t, cols[cur_c], net_ah),
                 file_columns=file_columns, first_line=cols.first_line,
                 notes=[*cols.notes, *notes])
    ambient = None
    if ambient_c:                   # the chamber's: beside the cell's the thermal model's
        ambient, more = _held_readings(cols, ambient_c, path)     # ambient, alone the
        meta.notes.extend(more)                                   # record's temperature
        meta.chamber_temp_c = chamber_set_point(ambient)
        meta.file_columns["ambient_c"] = ambient_c
    return Record(t.copy(), cols[cur_c], cols[volt_c], meta, temperature_c=temp,
                  soc_ref=cols[soc_c] if soc_c else None, charge_ah=net_ah, ambient_c=ambient)


def _bdf_names(header: list[str]) -> dict[str, str]:
    """{preferred label: the file's name for it} for each BDF quantity of BDF_ALIASES whose
    label or machine-readable name is in the header (the label first)."""
    present = set(header)
    names: dict[str, str] = {}
    for label, aliases in BDF_ALIASES.items():
        found = next((n for n in (label, *aliases) if n in present), None)
        if found is not None:
            names[label] = found
    return names


def read_biologic(path: Path) -> Record:
    """BioLogic EC-Lab / BT-Lab ASCII export (``.mpt``): ``time/s``, the cell voltage (the
    first of BIOLOGIC_VOLTAGES present), the current (``I/mA`` or ``<I>/mA``; > 0 charges), and
    where present ``(Q-Qo)/mA.h`` as the charge counter and ``Temperature/°C``.

    The decimal mark is read from the data (a comma where the exporting PC wrote one). Of two
    rows with one time (EC-Lab writes them where a technique or sequence changes) the later is
    kept, and impedance points between the cycling (``freq/Hz`` > 0) are left out; both are
    counted in meta.notes (_biologic_rows)."""
    lines = read_text(path).splitlines()
    header_line = _biologic_header_line(path, lines)
    data = next((ln for ln in lines[header_line:] if ln.strip()), "")
    decimal = "," if re.search(r"\d,\d", data) else "."
    names = [c.strip() for c in lines[header_line - 1].split("\t")]
    voltage = _first_present(path, names, BIOLOGIC_VOLTAGES, "cell voltage")
    current = _first_present(path, names, tuple(BIOLOGIC_CURRENTS), "current")
    _first_present(path, names, (BIOLOGIC_TIME,), "time")
    charge = next((c for c in BIOLOGIC_CHARGES if c in names), None)
    temperature = next((c for c in BIOLOGIC_TEMPERATURES if c in names), None)
    cols = _read_csv_columns(path, sep="\t", decimal=decimal, header_line=header_line,
                             lines=lines, required={BIOLOGIC_TIME, voltage, current,
                                                    *(c for c in (charge, temperature) if c)})
    keep, notes = _biologic_rows(cols)
    if not keep.any():
        raise DataError(f"{path}: no cycling rows ({notes[0]}); expected time, voltage and "
                        "current samples of a charge or discharge")
    notes = [*cols.notes, *notes]
    t = cols[BIOLOGIC_TIME][keep]
    amps = cols[current][keep] * BIOLOGIC_CURRENTS[current]
    net_ah = None
    if charge is not None:
        raw, unit = cols[charge][keep], BIOLOGIC_CHARGES[charge]
        stitched, more = _stitched_counter(charge, t, amps, raw * unit)  # restarts: to 0
        net_ah = stitched - stitched[0] if more else (raw - raw[0]) * unit
        notes += more
    file_columns = {"time_s": BIOLOGIC_TIME, "current_a": current, "voltage_v": voltage,
                    **({"charge_ah": charge} if charge else {}),
                    **({"temperature_c": temperature} if temperature else {})}
    meta = _meta(path, "biologic", "none (EC-Lab: I > 0 charges)", t,
                 segment_starts=_segment_starts_from_gaps(t, amps, net_ah), notes=notes,
                 file_columns=file_columns,
                 first_line=cols.first_line if keep.all() else None,
                 time_origin_s=float(t[0]))
    return Record(t - t[0], amps, cols[voltage][keep], meta,
                  temperature_c=None if temperature is None else cols[temperature][keep],
                  charge_ah=net_ah)


def _biologic_rows(cols: CsvColumns) -> tuple[np.ndarray, list[str]]:
    """Which rows of an EC-Lab export are samples of the cycling, and notes on those that are
    not: impedance points (freq/Hz > 0, whose I and E are the AC measurement's) and the
    earlier of two rows with one time (the later holds the new step's current)."""
    t = cols[BIOLOGIC_TIME]
    keep = ~(cols[BIOLOGIC_FREQUENCY] > 0) if BIOLOGIC_FREQUENCY in cols else np.ones(t.size, bool)
    notes = ([] if keep.all() else [f"dropped {int((~keep).sum())} impedance (EIS) row(s), "
                                    f"those with {BIOLOGIC_FREQUENCY} > 0"])
    rows = np.flatnonzero(keep)
    repeated = rows[:-1][np.diff(t[rows]) == 0]
    if repeated.size:
        keep[repeated] = False
        notes.append(f"dropped {repeated.size} row(s) whose time the next row repeats (kept "
                     "the later)")
    return keep, notes


def _biologic_header_line(path: Path, lines: list[str]) -> int:
    """The file line (1-based) of an EC-Lab export's column names, from its second line
    "Nb header lines : N"."""
    second = lines[1].strip() if len(lines) > 1 else ""
    m = re.fullmatch(r"Nb header lines\s*:\s*(\d+)", second)
    if m is None:
        raise DataError(f"{path}: line 2 is {second[:80]!r}; expected 'Nb header lines : N' "
                        f"after the line {lines[0].strip()!r} (an EC-Lab / BT-Lab ASCII export)")
    n = int(m.group(1))
    if not 3 <= n < len(lines):
        raise DataError(f"{path}: 'Nb header lines : {n}' but the file has {len(lines)} lines; "
                        "expected the column names on line N (3 or more) and data rows after it")
    return n


def _first_present(path: Path, names: list[str], choices: tuple[str, ...], what: str) -> str:
    """The first of choices among a file's column names; DataError naming both if none is."""
    found = next((c for c in choices if c in names), None)
    if found is None:
        raise DataError(f"{path}: no {what} column; expected one of {list(choices)}, found "
                        f"{[n for n in names if n]}")
    return found


GENERIC_KEYS = ("time", "current", "voltage", "temperature", "ambient", "charge", "state")
UNIT_SUFFIX = {"time": "_s", "current": "_a", "voltage": "_v", "temperature": "_c",
               "ambient": "_c", "charge": "_ah", "state": ""}
# A state column gives the direction of a current logged as its magnitude (Maccor's State C, D,
# R; Neware's CC_Chg, CC_DChg, Rest; Digatron's CHA, DCH, PAU): a cell's words (lower case,
# "_" and "-" as spaces) name a charge, a discharge or a rest (its current kept as logged)
DISCHARGE_WORDS = {"d", "dchg", "dischg", "dis", "dch", "discharge", "discharging", "dc"}
CHARGE_WORDS = {"c", "chg", "chrg", "cha", "ch", "charge", "charging"}
REST_WORDS = {"r", "rest", "pau", "pause", "relax", "relaxation", "ocv", "o", "idle"}
KEY_SYNONYMS = {       # how a column-mapping key is often written for one of GENERIC_KEYS
    "t": "time", "test_time": "time", "i": "current", "amps": "current", "v": "voltage",
    "u": "voltage", "volts": "voltage", "temp": "temperature", "t1": "temperature",
    "cell_temperature": "temperature", "chamber": "ambient", "amb": "ambient",
    "ambient_temperature": "ambient", "q": "charge", "ah": "charge", "capacity": "charge",
    "net_charge": "charge", "direction": "state", "status": "state", "mode": "state",
    "md": "state"}
CURRENT_UNITS = {"A": 1.0, "mA": 1e-3}
CHARGE_UNITS = {"Ah": 1.0, "mAh": 1e-3}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0, "d": 86400.0}
VOLTAGE_UNITS = {"V": 1.0, "mV": 1e-3}
TEMPERATURE_UNITS = {"degC": 0.0, "K": -273.15}      # the offset to °C
UNITS = {"time": TIME_UNITS, "current": CURRENT_UNITS, "voltage": VOLTAGE_UNITS,
         "temperature": TEMPERATURE_UNITS, "ambient": TEMPERATURE_UNITS,
         "charge": CHARGE_UNITS}
DEFAULT_UNITS = {"time": "s", "current": "A", "voltage": "V", "temperature": "degC",
                 "ambient": "degC", "charge": "Ah"}
UNIT_OPTION = {"ambient": "temperature"}     # the ambient column's unit option is the cell's
NAME_UNIT = re.compile(r"(?:\[\s*([^\]]+?)\s*\]|\(\s*([^)]+?)\s*\)|/\s*([^/\s]+))\s*$")


def split_unit(name: str) -> tuple[str, str]:
    """A column name's words before the unit it ends in and that unit as written (NAME_UNIT:
    in brackets, parentheses or after a slash): 'Current [mA]' → ('Current', 'mA'),
    'I/mA' → ('I', 'mA'); (name, '') for a name without one."""
    found = NAME_UNIT.search(name)
    if found is None:
        return name, ""
    return name[:found.start()].rstrip(), next(g for g in found.groups() if g)
UNIT_WORDS = {        # how a units row or a column name may write them (lower case)
    "time": {"s": "s", "sec": "s", "ms": "ms", "min": "min", "h": "h", "hr": "h", "d": "d",
             "day": "d", "days": "d"},
    "current": {"a": "A", "ma": "mA"},
    "voltage": {"v": "V", "mv": "mV"},
    "temperature": {"°c": "degC", "degc": "degC", "c": "degC", "℃": "degC", "k": "K"},
}
UNIT_WORDS["ambient"] = UNIT_WORDS["temperature"]
UNIT_WORDS["state"] = {}
UNIT_WORDS["charge"] = {"ah": "Ah", "a.h": "Ah", "a h": "Ah", "mah": "mAh", "ma.h": "mAh",
                        "ma h": "mAh"}
COUNTER_CHECK_AH = 0.002   # Ah: a charge counter's step beyond what the current moves that can
                           # be a restart; the least charge a one-way counter check needs


def read_generic(path: Path, columns: Mapping[str, str], discharge_positive: bool = False,
                 current_scale: float = 1.0, sep: str = ",", decimal: str = ".",
                 current_unit: str | None = None, time_unit: str | None = None,
                 voltage_unit: str | None = None, temperature_unit: str | None = None,
                 charge_unit: str | None = None) -> Record:
    """CSV with an explicit mapping {'time': …, 'current': …, 'voltage': …[, 'temperature']
    [, 'ambient'][, 'charge'][, 'state']} of LMNCell's quantities to the file's column names
    (time in s, or as text that TIME_TEXT_EXPECTED describes; voltage in V, temperatures in °C):
    'temperature' the cell's, 'ambient' the chamber's beside it (Record.ambient_c, the thermal
    model's ambient; mapped alone, it is the record's temperature); 'charge' the tester's net
    charge counter (Ah, running through the record: it decides whether a gap in time lost
    charge, and the SoC reference counts by it; _checked_counter); 'state' a column of words
    that give the direction of a current logged as its magnitude (_state_signs: charge,
    discharge or rest).

    current_unit: "A" or "mA" (or current_scale, a factor to A); time_unit: that of a numeric
    time column, one of TIME_UNITS (default s); voltage_unit: "V" or "mV"; temperature_unit:
    "degC" or "K" (both temperature columns); charge_unit: "Ah" or "mAh"; each unit not given
    is the file's where its column name or a units row under the names gives one
    (_file_units), else the default;
    discharge_positive: the file counts discharge current as positive (it is negated:
    LMNCell's current > 0 charges); sep: the delimiter; decimal: "." or "," (decimal comma).
    The column names are on the first line that holds them all (_line_naming); a units row
    under them is skipped (_units_row)."""
    given = {"time": time_unit, "current": current_unit, "voltage": voltage_unit,
             "temperature": temperature_unit, "ambient": temperature_unit,
             "charge": charge_unit}
    _check_mapping(path, columns, given)
    cols, header_line, units = _generic_columns(path, columns, sep, decimal)
    t, notes = _generic_times(cols, columns["time"], path, decimal)
    text_time = bool(notes)      # a note from _generic_times: the times are text
    notes = [*cols.notes, *notes]
    for col in sorted(_temperature_columns(columns)):
        cols[col], held = _held_readings(cols, col, path)
        notes += held
    given, taken = _with_file_units(
        path, given, _file_units(columns, units, text_time), current_scale)
    if given["current"] is not None:
        current_scale = CURRENT_UNITS[given["current"]]
    if given["time"] is not None and text_time:
        raise DataError(f"{path}: time unit {given['time']!r} for the column '{columns['time']}', "
                        "whose times are text that carries its own unit; expected no time unit")
    t = t * TIME_UNITS[given["time"] or "s"]
    sign = -1.0 if discharge_positive else 1.0
    cur = cols[columns["current"]] * current_scale * sign
    note = "current negated (file: discharge > 0)" if discharge_positive else "none"
    if "state" in columns:
        cur, note = _signed_by_state(path, cols, columns, cur, discharge_positive)
    temp, ambient = (cols[columns[k]] + TEMPERATURE_UNITS[given[k] or "degC"]
                     if k in columns else None for k in ("temperature", "ambient"))
    volts = cols[columns["voltage"]] * VOLTAGE_UNITS[given["voltage"] or "V"]
    # a text time column's messages count s from its first row
    file_times = t - t[0] if text_time else t
    net_ah = None
    if "charge" in columns:
        counter = cols[columns["charge"]] * CHARGE_UNITS[given["charge"] or "Ah"]
        net_ah, more = _checked_counter(path, columns["charge"], file_times, cur, counter * sign)
        notes += more
    notes += _layout_notes(header_line, units, taken)
    meta = _generic_meta(path, columns, cols, (t, file_times, cur, net_ah), note, notes)
    if ambient is not None:
        meta.chamber_temp_c = chamber_set_point(ambient)
    return Record(t - t[0], cur, volts, meta, temperature_c=temp, ambient_c=ambient,
                  charge_ah=net_ah)


def _signed_by_state(path: Path, cols: CsvColumns, columns: Mapping[str, str],
                     current_a: np.ndarray, discharge_positive: bool
                     ) -> tuple[np.ndarray, str]:
    """The current signed by the state column (its magnitude, > 0 on a charge row, < 0 on a
    discharge row, as logged on a rest row) and the sign note; --discharge-positive beside it
    is refused (the state gives the sign)."""
    state = columns["state"]
    if discharge_positive:
        raise DataError(f"{path}: --discharge-positive (discharge_positive=True) with the state "
                        f"column '{state}', which gives the sign of the current; expected one "
                        "or the other")
    signs = _state_signs(path, state, cols.text[state], cols.lines)
    return (np.where(signs == 0, current_a, signs * np.abs(current_a)),
            f"current signed by the column '{state}' (charge > 0, discharge < 0)")


def _state_signs(path: Path, column: str, cells: list[str], lines: list[int]) -> np.ndarray:
    """+1 for each cell of a state column that names a charge (CHARGE_WORDS), −1 for a
    discharge (DISCHARGE_WORDS, looked for first: Neware's "CC_DChg" holds "cc"), 0 for a
    rest (REST_WORDS); a DataError names the first cell that is none of them, with its line."""
    signs = np.empty(len(cells))
    for k, cell in enumerate(cells):
        words = set(re.sub(r"[_\-]", " ", cell.lower()).split())
        if words & DISCHARGE_WORDS:
            signs[k] = -1.0
        elif words & CHARGE_WORDS:
            signs[k] = 1.0
        elif words & REST_WORDS:
            signs[k] = 0.0
        else:
            raise DataError(f"{path}: column '{column}' line {lines[k]}: {cell!r} names no "
                            "charge, discharge or rest; expected a state such as C, D, R "
                            "(Maccor), CC_Chg, CC_DChg, Rest (Neware) or CHA, DCH, PAU "
                            "(Digatron)")
    return signs


def _temperature_columns(columns: Mapping[str, str]) -> set[str]:
    """The file's column names mapped to the cell's and the chamber's temperature."""
    return {columns[k] for k in ("temperature", "ambient") if k in columns}


def _generic_columns(path: Path, columns: Mapping[str, str], sep: str, decimal: str
                     ) -> tuple[CsvColumns, int, UnitsRow | None]:
    """read_generic's columns as read (file units, the time column and the temperature columns
    kept as text where they are), the line that names them and the units row under it (None
    where there is none); a DataError names a mapped column that the file lacks."""
    numeric = set(columns.values()) - {columns["time"], columns.get("state")}
    _check_marks(path, sep, decimal)
    lines = read_text(path).splitlines()
    header_line = _line_naming(lines, set(columns.values()), sep)
    units = _units_row(lines, header_line, numeric, sep, decimal)
    temp_cols = _temperature_columns(columns)
    cols = _read_csv_columns(path, sep=sep, decimal=decimal, required=numeric,
                             keep_text={columns["time"], *temp_cols,
                                        *([columns["state"]] if "state" in columns else [])},
                             header_line=header_line, lines=lines, units_row=units is not None,
                             blank_ok=temp_cols)
    _require(path, cols, tuple(columns.values()), sep)
    return cols, header_line, units


def _generic_meta(path: Path, columns: Mapping[str, str], cols: CsvColumns,
                  series: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None],
                  note: str, notes: list[str]) -> RecordMeta:
    """read_generic's RecordMeta: series are the times (s, as the record keeps them before its
    start is taken off), the times as the file's messages count them (s), the current (A) and
    the net charge counter (Ah, None without one), from which the segments start at gaps in
    time (with a note where no counter tells what a gap lost)."""
    t, file_times, cur, net_ah = series
    starts = _segment_starts_from_gaps(t, cur, net_ah)
    if net_ah is None and len(starts) > 1:
        notes = [*notes, _no_counter_note(len(starts) - 1, list(cols))]
    return _meta(path, "generic", note, t, notes=notes, segment_starts=starts,
                 **_csv_meta(cols, file_times, **{f"{k}{UNIT_SUFFIX[k]}": v
                                                  for k, v in columns.items()}))


def _no_counter_note(gaps: int, names: list[str]) -> str:
    """The note of a generic record split at gaps in time without a charge counter mapped,
    naming the file's net counter column (of its column names) where it has one
    (header.is_net_charge)."""
    from lmncell.data.header import is_net_charge

    found = [n for n in names if n and is_net_charge(n)]
    return (f"split at {gaps} gap(s) in time: without the tester's charge counter the reader "
            "cannot tell whether a gap under load (or one of 10 min or more at rest) lost charge"
            + (f"; the column '{found[0]}' looks like one (charge={found[0]})"
               if len(found) == 1 else "; map it as charge=COL where the file has one"))


def _checked_counter(path: Path, column: str, file_times: np.ndarray, current_a: np.ndarray,
                     counter_ah: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """A user's charge counter column (Ah, in the current's sign) as Record.charge_ah: the net
    charge since the first row, read against the logged current, with notes:

    - a counter that falls while the current charges is negated (the current's sign, which
      --discharge-positive sets, is the one the user chose), read from the steps whose counter
      moves no more than the current can (_counter_reach);
    - restarts are stitched (_stitched_counter);
    - a DataError names the column where it counts less than a fifth of what the current
      charges, or of what it discharges (a discharge-only or charge-only counter).
    """
    regular, held, reach = _counter_reach(file_times, current_a)
    notes: list[str] = []
    step = np.diff(counter_ah)
    normal = regular & (np.abs(step) <= reach)
    if float(np.sum((step * held)[normal])) < 0.0:
        counter_ah = -counter_ah
        notes.append(f"column '{column}' counted charge negative to the current's sign; "
                     "negated (LMNCell's counter rises while the current charges)")
    counter_ah, more = _stitched_counter(column, file_times, current_a, counter_ah,
                                         (regular, held, reach))
    notes += more
    step = np.diff(counter_ah)
    for sign, what in ((1.0, "charges"), (-1.0, "discharges")):
        one_way = regular & (sign * current_a[:-1] > REST_CURRENT_A) & (
            sign * current_a[1:] > REST_CURRENT_A)
        moved = sign * float(np.sum(held[one_way]))
        if moved >= COUNTER_CHECK_AH and sign * float(np.sum(step[one_way])) < 0.2 * moved:
            raise DataError(
                f"{path}: column '{column}' (charge) counts {np.sum(step[one_way]):+.4f} Ah "
                f"over the steps where the current {what} {sign * moved:+.4f} Ah; expected "
                "the tester's net charge counter (charge minus discharge, in Ah or mAh), "
                "not one that counts only one direction; leave the column out otherwise")
    return counter_ah - counter_ah[0], notes


def _counter_reach(file_times: np.ndarray, current_a: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step between rows k and k + 1: whether it is no gap (up to GAP_FACTOR × the median
    step, as find_gaps), the charge of the current held over it (Ah), and the most a charge
    counter can move in it by the current: COUNTER_CHECK_AH plus the larger of its two
    currents held over it (Ah)."""
    dt = np.diff(file_times)
    regular = dt <= GAP_FACTOR * max(float(np.median(dt)), 1e-9) if dt.size else dt > 0
    held = current_a[:-1] * dt / 3600.0
    reach = COUNTER_CHECK_AH + np.maximum(np.abs(current_a[:-1]),
                                          np.abs(current_a[1:])) * dt / 3600.0
    return regular, held, reach


def _stitched_counter(column: str, file_times: np.ndarray, current_a: np.ndarray,
                      counter_ah: np.ndarray,
                      reached: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, list[str]]:
    """A charge counter (Ah, in the current's sign) with its restarts mended, and a note where
    there were any: a step where the counter falls back to about 0 by more than the current can
    move it (both within _counter_reach), as a tester's capacity counters do at each cycle or
    step of a schedule, continues from the count before it plus the current's charge over that
    step. At a step longer than the log's (GAP_FACTOR × its median: a rest logged more slowly,
    or a gap) only a fall that no current of the record, held over the whole step, could have
    made counts as a restart: a cell recharged inside a gap brings a counter of the net charge
    since the start back to about 0 as well, and stays as counted. The counter itself where
    there is none. reached: _counter_reach of these times and currents where the caller has it
    already."""
    regular, held, reach = reached or _counter_reach(file_times, current_a)
    step = np.diff(counter_ah)
    peak = float(np.max(np.abs(current_a))) if current_a.size else 0.0
    beyond_any_current = np.abs(step) > COUNTER_CHECK_AH + peak * np.diff(file_times) / 3600.0
    restarts = np.flatnonzero((regular | beyond_any_current) & (np.abs(step - held) > reach)
                              & (np.abs(counter_ah[1:]) <= reach))
    if not restarts.size:
        return counter_ah, []
    step[restarts] = held[restarts]
    slow = restarts[~regular[restarts]]
    return (np.concatenate([[counter_ah[0]], counter_ah[0] + np.cumsum(step)]),
            [f"column '{column}' restarts from 0 {restarts.size} time(s), the first at "
             f"t = {file_times[restarts[0] + 1]:g} s; each restart continues from the count "
             "before it plus the current's charge over that step"
             + (f" ({slow.size} of them at a step longer than the log's, the first at "
                f"t = {file_times[slow[0] + 1]:g} s after "
                f"{file_times[slow[0] + 1] - file_times[slow[0]]:g} s: the charge over such a "
                "step is the current held over it)" if slow.size else "")])


def _held_readings(cols: CsvColumns, name: str, path: Path) -> tuple[np.ndarray, list[str]]:
    """An auxiliary column logged more slowly than the rest (a thermocouple read every few
    rows, blank between readings; read with blank_ok, so its other cells are numbers): each
    blank cell takes the reading before it (the first reading back to the start), with a
    note saying how many; a column without a reading is a DataError naming it."""
    values = cols[name]
    blank = np.array([cell == "" for cell in cols.text[name]])
    if not blank.any():
        return values, []
    read = np.flatnonzero(~blank)
    if not read.size:
        raise DataError(f"{path}: column '{name}' has no reading (every cell blank); expected "
                        "numbers, or leave the column out (of --columns, or of a BDF file)")
    before = np.maximum(np.searchsorted(read, np.arange(values.size), "right") - 1, 0)
    return values[read[before]], [
        f"column '{name}': {int(blank.sum())} of {values.size} rows blank between readings, "
        "each holding the reading before it"
        + (" (the rows before the first reading hold that one)" if blank[0] else "")]


def _check_mapping(path: Path, columns: Mapping[str, str], units: dict[str, str | None]
                   ) -> None:
    """DataError unless the column mapping names time, current and voltage (and at most
    temperature, ambient, charge and state besides) and every unit given is one of UNITS."""
    unknown = sorted(set(columns) - set(GENERIC_KEYS))
    if unknown:
        meant = "; ".join(f"{k}= is {KEY_SYNONYMS[k.lower()]}=" for k in unknown
                          if k.lower() in KEY_SYNONYMS)
        raise DataError(f"{path}: the column mapping names {unknown}; expected keys among "
                        f"{list(GENERIC_KEYS)}" + (f" ({meant}?)" if meant else ""))
    for key in ("time", "current", "voltage"):
        if key not in columns:
            raise DataError(f"{path}: the column mapping lacks '{key}' (got {dict(columns)}); "
                            "expected time, current and voltage (temperature, ambient, charge and "
                            "state optional)")
    for what, unit in units.items():
        if unit is not None and unit not in UNITS[what]:
            raise DataError(f"{path}: {what} unit {unit!r}; expected one of "
                            f"{list(UNITS[what])}")


def _layout_notes(header_line: int, units: UnitsRow | None,
                  taken: dict[str, tuple[str, str]]) -> list[str]:
    """Notes on how a generic file was read: lines skipped before the column names, a units
    row, and the units taken from the file rather than the defaults."""
    notes = []
    if header_line > 1:
        notes.append(f"column names on line {header_line}: the {header_line - 1} line(s) "
                     "before them skipped")
    if units is not None:
        notes.append(f"line {units.line} read as the columns' units, not data: "
                     f"{units.text!r}")
    if taken:
        notes.append("units from the file: " + ", ".join(
            f"{what} in {unit} ({where})" for what, (unit, where) in taken.items()))
    return notes


def _line_naming(lines: list[str], names: set[str], sep: str) -> int:
    """The file line (1-based) of the first line whose fields hold all the names (a cycler's
    export may put a preamble of settings before its column names); 1 where none does."""
    for k, line in enumerate(lines[:MAX_PREAMBLE_LINES]):
        if names <= {c.strip() for c in next(csv.reader([line], delimiter=sep), [])}:
            return k + 1
    return 1


class UnitsRow(NamedTuple):
    """A units row under a file's column names: its file line, its text and its cells by
    column name."""

    line: int
    text: str
    cells: dict[str, str]


def _units_row(lines: list[str], header_line: int, numeric: set[str], sep: str,
               decimal: str) -> UnitsRow | None:
    """The units row (such as "s;A;V") right after the column names: where none of the
    numeric columns named holds a number there and all of them do in the next line; None
    otherwise."""
    near = [(k + 1, ln) for k, ln in enumerate(lines[header_line - 1:header_line + 9],
                                               header_line - 1) if ln.strip()]
    if len(near) < 3 or not numeric:
        return None
    names = [c.strip() for c in next(csv.reader([near[0][1]], delimiter=sep))]
    cells = [next(csv.reader([ln], delimiter=sep)) for _, ln in near[1:3]]
    where = [names.index(n) for n in numeric if n in names]

    def numbers(row: list[str]) -> list[bool]:
        return [j < len(row) and _is_number(row[j], decimal) for j in where]

    if not where or any(numbers(cells[0])) or not all(numbers(cells[1])):
        return None
    by_name: dict[str, str] = {}
    for name, cell in zip(names, cells[0], strict=False):
        by_name.setdefault(name, cell.strip())     # a repeated name: its first column's
    return UnitsRow(near[1][0], near[1][1].strip(), by_name)


def _file_units(columns: Mapping[str, str], units: UnitsRow | None, text_time: bool
                ) -> dict[str, list[tuple[str, str]]]:
    """The units the file itself gives the mapped columns, each with where: the column name's
    (``Current [mA]``, ``Current (mA)``, ``I/mA``) and the units row's (UNIT_WORDS; a text time
    column's unit is its text's, left out)."""
    found: dict[str, list[tuple[str, str]]] = {}
    for what, column in columns.items():
        word = split_unit(column)[1].lower()
        if word in UNIT_WORDS[what]:
            found.setdefault(what, []).append((UNIT_WORDS[what][word],
                                               f"the column name {column!r}"))
        if units is not None:
            word = units.cells.get(column, "").strip("[]()").strip().lower()
            if word in UNIT_WORDS[what]:
                found.setdefault(what, []).append((UNIT_WORDS[what][word],
                                                   f"the units row (line {units.line})"))
    if text_time:
        found.pop("time", None)
    return found


def _with_file_units(path: Path, given: dict[str, str | None],
                     file_units: dict[str, list[tuple[str, str]]], current_scale: float
                     ) -> tuple[dict[str, str | None], dict[str, tuple[str, str]]]:
    """The units to read with, and those of them taken from the file (with where): an option
    given wins, with a DataWarning where the file says otherwise (a header may be wrong); else
    the file's unit, a DataError where the column name and the units row disagree."""
    out, taken = dict(given), {}
    for what, says in file_units.items():
        mine = given[what]
        if what == "current" and mine is None and current_scale != 1.0:
            mine = next((u for u, f in CURRENT_UNITS.items() if f == current_scale),
                        f"a scale of {current_scale:g}")
        other = [(unit, where) for unit, where in says if unit != (mine or says[0][0])]
        said = " and ".join(f"{where} says {unit}" for unit, where in other)
        if mine is not None:
            if other:
                warnings.warn(f"{path}: the {what} is read in {mine} as the option says, where "
                              f"{said}", DataWarning, stacklevel=4)
            continue
        if other:
            option = UNIT_OPTION.get(what, what)
            raise DataError(f"{path}: {says[0][1]} says the {what} is in {says[0][0]}, {said}; "
                            f"expected them to agree (give the {option} unit: "
                            f"--{option}-unit, {option}_unit=)")
        out[what] = says[0][0]
        if says[0][0] != DEFAULT_UNITS[what]:
            taken[what] = says[0]
    return out, taken


def decimal_number(cell: str, decimal: str) -> float:
    """A cell's number with the decimal mark given ("." or ","); ValueError where it is none."""
    return float(cell.replace(",", ".") if decimal == "," else cell)


def _is_number(cell: str, decimal: str) -> bool:
    try:
        decimal_number(cell.strip(), decimal)
    except ValueError:
        return False
    return True


def _generic_times(cols: CsvColumns, column: str, path: Path, decimal: str
                   ) -> tuple[np.ndarray, list[str]]:
    """The time column in s: numbers, or text (_text_times) with a note saying how it was
    read; DataError where a numeric column has a cell that is not a number."""
    t = cols[column]
    if not np.isnan(t).any():
        return t, []
    cells = cols.text[column]
    if not np.isnan(t[0]):
        k = int(np.flatnonzero(np.isnan(t))[0])
        raise DataError(f"{path}: column '{column}' line {cols.lines[k]}: {cells[k]!r} is not "
                        f"a number like the first row's {cells[0]!r}")
    t, kind = _text_times(cells, cols.lines, path, column, decimal)
    return t, [f"time column '{column}' read as {kind} (first {cells[0]!r})"]


DURATION = re.compile(r"(?:(\d+)[-. ])?(\d+):(\d{1,2}):(\d{1,2}(?:\.\d*)?)")
TIME_TEXT_EXPECTED = ("a number of seconds, a duration h:mm:ss[.f] (hours may exceed 24; a "
                      "day count before it as 'd-', 'd.' or 'd ') or an ISO 8601 date and time "
                      "(2024-03-01 10:00:00[.f], 'T' between them, an offset such as +01:00 "
                      "allowed)")


def _text_times(cells: list[str], lines: list[int], path: Path, column: str,
                decimal: str = ".") -> tuple[np.ndarray, str]:
    """A time column written as durations or ISO date-times (TIME_TEXT_EXPECTED), in s from
    the epoch or the duration's zero (the first cell decides which), and which it was.
    DataError naming the line and the cell where one is neither, or not of the first cell's
    kind."""
    first = cells[0].replace(",", ".") if decimal == "," else cells[0]
    as_duration = DURATION.fullmatch(first) is not None
    kind = "durations h:mm:ss" if as_duration else "ISO 8601 dates and times"
    out = np.empty(len(cells))
    for k, cell in enumerate(cells):
        text = cell.replace(",", ".") if decimal == "," else cell
        value = _duration_s(text) if as_duration else _iso_s(text)
        if value is None:
            raise DataError(f"{path}: column '{column}' line {lines[k]}: {cell!r} is not of "
                            f"the first row's kind ({cells[0]!r}: {kind})"
                            if k else f"{path}: column '{column}' line {lines[k]}: {cell!r} "
                            f"is no time{_comma_hint(cell, decimal)}; expected "
                            f"{TIME_TEXT_EXPECTED}")
        out[k] = value
    return out, kind


def _duration_s(text: str) -> float | None:
    """'[d-]h:mm:ss[.f]' in s, or None."""
    m = DURATION.fullmatch(text)
    if m is None:
        return None
    days, hours, minutes, seconds = m.groups()
    return (int(days or 0) * 86400.0 + int(hours) * 3600.0 + int(minutes) * 60.0
            + float(seconds))


def _iso_s(text: str) -> float | None:
    """An ISO 8601 date and time in s since 1970 (a time without offset is taken as it is:
    no time zone, no daylight-saving shift), or None."""
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        return None
    if stamp.tzinfo is None:
        return (stamp - datetime(1970, 1, 1)).total_seconds()
    return stamp.timestamp()


_READERS = {"plett": read_plett, "arbin": read_arbin, "panasonic": read_panasonic,
            "bdf": read_bdf, "biologic": read_biologic}


def check_plausibility(rec: Record) -> None:
    """Warn (DataWarning) where units or the sign of the current look wrong."""
    src = rec.meta.source
    vmax = float(np.max(np.abs(rec.voltage_v)))
    if vmax > 100:
        warnings.warn(f"{src}: voltage reaches {vmax:.0f}; values look like mV, expected V "
                      "for a single cell", DataWarning, stacklevel=3)
    step = rec.meta.sample_time_s
    if step < MIN_LOG_STEP_S:
        warnings.warn(f"{src}: the time steps by {step:.3g} s (median); a cycler logs every "
                      f"{MIN_LOG_STEP_S:g} s or slower: is the time column in min, h or days "
                      "(a spreadsheet's date numbers)? (--time-unit min|h|d, time_unit=)",
                      DataWarning, stacklevel=3)
    imax = float(np.max(np.abs(rec.current_a)))
    if imax > 500:
        warnings.warn(f"{src}: current reaches {imax:.0f}; values look like mA, expected A "
                      "(--current-unit mA, current_unit='mA')", DataWarning, stacklevel=3)
    di, dv = np.diff(rec.current_a), np.diff(rec.voltage_v)
    steps = np.abs(di) > 0.2 * max(imax, 1e-9)
    if steps.sum() < 5:
        return
    agree = float(np.mean(np.sign(di[steps]) == np.sign(dv[steps])))
    if agree < 0.2:
        warnings.warn(f"{src}: the voltage falls when the current rises in "
                      f"{100 * (1 - agree):.0f} % of current steps; the sign looks "
                      "inverted (expected current > 0 to charge)", DataWarning,
                      stacklevel=3)
    elif agree < 0.8 and float(np.min(rec.current_a)) > -REST_CURRENT_A:
        warnings.warn(f"{src}: the current never goes below 0 (discharge), yet the voltage "
                      f"falls in {100 * (1 - agree):.0f} % of the steps where it rises: a "
                      "current logged as its magnitude, with its direction in another column? "
                      "Map that column as state=COL (Maccor's State: C, D, R); a record that "
                      "only discharges: --discharge-positive", DataWarning, stacklevel=3)


# read_generic's options, which read_record passes on
GENERIC_OPTIONS = ("columns", "discharge_positive", "current_scale", "sep", "decimal",
                   "current_unit", "time_unit", "voltage_unit", "temperature_unit", "charge_unit")


def read_record(path: str | Path, fmt: str | None = None, **generic_kw) -> Record:
    """Read one cycler file into a Record (SI units, current > 0 charges).

    fmt: one of FORMATS, or None to choose by content ("generic" when a column mapping
    `columns` is given). generic_kw go to read_generic (columns, discharge_positive,
    current_unit or current_scale, time_unit, voltage_unit, temperature_unit, charge_unit,
    sep, decimal).
    """
    unknown = sorted(set(generic_kw) - set(GENERIC_OPTIONS))
    if unknown:
        raise TypeError(f"read_record() got unknown option(s) {unknown}; expected some of "
                        f"{list(GENERIC_OPTIONS)} (sep is the CLI's --delimiter)")
    path = check_readable(path)
    columns = generic_kw.get("columns")
    if columns is not None and not isinstance(columns, Mapping):
        raise DataError(f"{path}: columns = {columns!r:.60}; expected a mapping of LMNCell's "
                        "quantities to the file's column names, e.g. {'time': 'Time [s]', "
                        "'current': 'I [A]', 'voltage': 'U [V]'}")
    if fmt is None and generic_kw.get("columns"):
        if _mat_path(path):
            raise DataError(f"{path}: a Panasonic .mat file, which its own reader reads; the "
                            "column mapping (--columns / columns=...) and the other reader "
                            "options are for a CSV: leave them out for this file")
        fmt = "generic"
    if fmt != "generic" and generic_kw:
        raise DataError(f"{path}: reader options {sorted(generic_kw)} need a column mapping "
                        "(--columns / columns=...), which selects the generic CSV reader")
    if fmt is None:
        fmt = _format_of(path)
    if fmt == "generic":
        rec = read_generic(path, **generic_kw)
    elif fmt in _READERS:
        rec = _READERS[fmt](path)
    else:
        raise DataError(f"{path}: unknown format {fmt!r}; expected one of {FORMATS}")
    check_plausibility(rec)
    return rec


def write_bdf(rec: Record, path: str | Path) -> Path:
    """Write a record as Battery Data Format CSV (current > 0 charges), full float precision."""
    path = Path(path)
    names = [BDF_TIME, BDF_VOLTAGE, BDF_CURRENT]
    arrays = [rec.time_s, rec.voltage_v, rec.current_a]
    for name, arr in ((BDF_T1, rec.temperature_c), (BDF_AMBIENT, rec.ambient_c),
                      (BDF_NET_AH, rec.charge_ah), (BDF_SOC, rec.soc_ref)):
        if arr is not None:
            names.append(name)
            arrays.append(arr)
    opener = gzip.open if path.suffix == ".gz" else open
    with replaced_whole(path) as part, opener(part, "wt", encoding="utf-8", newline="") as fh:
        fh.write(",".join(names) + "\n")
        for row in zip(*arrays, strict=True):
            fh.write(",".join(repr(float(v)) for v in row) + "\n")
    return path
