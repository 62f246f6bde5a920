"""Readers, records and bad input (issue: foundation)."""

from __future__ import annotations

import dataclasses
import gzip
import json
import re
import shlex
import warnings
from datetime import datetime, timedelta
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.io
from lmncell.cli import main
from lmncell.data.readers import DataWarning, detect_format, read_record, write_bdf
from lmncell.data.records import DataError
from lmncell.evaluation.evaluate import evaluate_model
from lmncell.runtime.model import load_model

from tests.conftest import A123_S1, DATA, PAN_US06, shared_or_skip


def test_every_shipped_file_reads() -> None:
    files = sorted(DATA.rglob("*.csv.gz")) + sorted(DATA.rglob("*.mat"))
    assert len(files) >= 12
    for f in files:
        rec = read_record(f)
        assert len(rec) > 100
        assert np.all(np.diff(rec.time_s) > 0)


def test_plett_sign_and_counters() -> None:
    rec = read_record(A123_S1)
    assert rec.meta.fmt == "plett" and rec.meta.chamber_temp_c == 25.0
    assert "negated" in rec.meta.sign_note
    # the record discharges overall: counters and current agree on the sign
    assert rec.charge_ah[-1] < -1.5
    held = np.sum(rec.current_a[:-1] * np.diff(rec.time_s)) / 3600
    assert held == pytest.approx(rec.charge_ah[-1], rel=0.03)


def test_chamber_temperature_of_the_25c_scripts() -> None:
    """Plett's procedure runs the dynamic test's s2/s3 and the OCV test's S2/S4 at 25 °C,
    whatever test temperature the file name carries; s1 and S1/S3 run at that temperature."""
    rec = read_record(DATA / "a123_plett/dyn/A123_DYN_30_N05_s3.csv.gz")
    assert rec.meta.chamber_temp_c == 25.0
    assert read_record(DATA / "a123_plett/dyn/A123_DYN_30_N05_s1.csv.gz"
                       ).meta.chamber_temp_c == -5.0
    from lmncell.data.readers import chamber_temp_from_name as named

    assert [named(n) for n in ("A123_OCV_N15_S2.csv", "A123_OCV_N15_S3.csv",
                               "A123_OCV_P45_S4.csv.gz", "A123_DYN_10_N25_s2.csv",
                               "03-27-17_09.06_10degC_HWFET_Pan18650PF.mat")] == [
        25.0, -15.0, 25.0, 25.0, 10.0]
    # the Panasonic files below 0 °C are named n10degC, n20degC (read as +10, +20 °C before:
    # a CSV of them evaluated at the wrong ambient); an n that ends a word is no sign
    assert [named(n) for n in ("06-07-17_08.39 n10degC_US06_Pan18650PF.mat",
                               "n20degC_Cycle_1_Pan18650PF.csv", "p0degC_NN_Pan18650PF.csv",
                               "x_-10degC.csv", "run10degC.csv")] == [
        -10.0, -20.0, 0.0, -10.0, 10.0]


def test_arbin_and_panasonic_formats() -> None:
    assert detect_format(DATA / "a123_plett/ocv/A123_OCV_P25_S1.csv.gz") == "arbin"
    rec = read_record(PAN_US06)
    assert rec.meta.fmt == "panasonic" and rec.temperature_c is not None
    assert rec.current_a.min() < -15 and rec.charge_ah[-1] < -2
    assert any("repeated time stamp" in n for n in rec.meta.notes)


def test_reader_options_for_a_file_their_reader_does_not_take_are_named() -> None:
    """A column mapping given for a Panasonic .mat file sent it to the CSV reader, which said
    "not a text file ... expected a CSV text file, a MATLAB .mat file"; reader options without
    a mapping select no reader."""
    with pytest.raises(DataError, match=r"US06_Pan18650PF.mat: a Panasonic .mat file, which its "
                                        r"own reader reads; the column mapping"):
        read_record(PAN_US06, columns={"time": "t", "current": "i", "voltage": "u"})
    with pytest.raises(DataError, match=r"reader options \['current_unit'\] need a column "
                                        r"mapping"):
        read_record(PAN_US06, current_unit="mA")


def test_hppc_gaps_become_segments() -> None:
    rec = read_record(DATA / "panasonic_18650pf/25degC/hppc/"
                      "03-11-17_08.47_25degC_5Pulse_HPPC_Pan18650PF.mat")
    assert len(rec.meta.segment_starts) > 10
    segs = rec.segments()
    assert sum(len(s) for s in segs) <= len(rec)


def test_hidden_pause_is_marked() -> None:
    path = shared_or_skip("panasonic_18650pf/25degC/drive_cycles/"
                          "03-18-17_02.17_25degC_Cycle_1_Pan18650PF.mat")
    rec = read_record(path)
    assert len(rec.meta.segment_starts) == 3
    assert sum("pause" in n for n in rec.meta.notes) == 2


def test_bdf_round_trip_is_identical(tmp_path) -> None:
    rec = read_record(PAN_US06)
    rec = rec.slice(0, 5000)
    rec.soc_ref = 1.0 + rec.charge_ah / 2.85
    path = write_bdf(rec, tmp_path / "r.bdf.csv")
    back = read_record(path)
    assert back.meta.fmt == "bdf"
    for name in ("time_s", "current_a", "voltage_v", "temperature_c", "charge_ah", "soc_ref",
                 "ambient_c"):
        assert np.array_equal(getattr(rec, name), getattr(back, name)), name
    assert back.meta.chamber_temp_c == rec.meta.chamber_temp_c == 25.0


def test_a_bdf_file_headed_by_machine_readable_names_reads_as_its_labels(tmp_path) -> None:
    """The Battery Data Format heads a column with its quantity's preferred label ("Test Time /
    s") or its machine-readable name ("test_time_second"), which the Battery Data Alliance's
    reference files use; such a file was "unknown format". T1's label is now "Surface
    Temperature T1 / degC"; files with the earlier "Temperature T1 / degC" still read."""
    rec = read_record(PAN_US06).slice(0, 300)
    rec.ambient_c = np.full(len(rec), 24.8)
    path = write_bdf(rec, tmp_path / "r.bdf.csv")
    text = path.read_text()
    labels = text.split("\n", 1)[0]
    assert labels == ("Test Time / s,Voltage / V,Current / A,Surface Temperature T1 / degC,"
                      "Ambient Temperature / degC,Net Capacity / Ah")
    machine = ("test_time_second,voltage_volt,current_ampere,temperature_t1_celsius,"
               "ambient_temperature_celsius,net_capacity_ah")
    earlier = labels.replace("Surface Temperature T1", "Temperature T1")
    for k, header in enumerate((machine, earlier)):
        other = tmp_path / f"{k}.bdf.csv"
        other.write_text(text.replace(labels, header, 1))
        assert detect_format(other) == "bdf"
        back = read_record(other)
        for name in ("time_s", "current_a", "voltage_v", "temperature_c", "ambient_c",
                     "charge_ah"):
            assert np.array_equal(getattr(back, name), getattr(read_record(path), name)), name
        assert back.meta.file_columns["time_s"] == header.split(",")[0]
    (tmp_path / "m.bdf.csv").write_text("test_time_second,voltage_volt\n0,3.3\n1,3.3\n")
    with pytest.raises(DataError, match=r"missing column\(s\) \['Current / A'\] \(or the "
                                        r"machine-readable name\(s\) \['current_ampere'\]\)"):
        read_record(tmp_path / "m.bdf.csv", fmt="bdf")


def test_a_bdf_temperature_read_every_few_rows_holds_each_reading(tmp_path) -> None:
    """A BDF file whose thermocouple is read every few rows, blank between readings, was
    refused as NaN; it is read as the generic reader reads such a column (a literal NaN is
    still refused)."""
    path = write_bdf(read_record(PAN_US06).slice(0, 300), tmp_path / "r.bdf.csv")
    lines = path.read_text().splitlines()
    j = lines[0].split(",").index("Surface Temperature T1 / degC")

    def blank(k: int, cell: str = "", column: int = j) -> None:
        cells = lines[k].split(",")
        cells[column] = cell
        lines[k] = ",".join(cells)

    readings = {k: float(lines[k].split(",")[j]) for k in range(1, len(lines))}
    for k in range(1, len(lines)):     # file line k + 1 holds sample k − 1
        if (k - 1) % 10:
            blank(k)
    path.write_text("\n".join(lines) + "\n")
    rec = read_record(path)
    assert rec.temperature_c.tolist() == [readings[1 + 10 * (n // 10)] for n in range(300)]
    assert any("270 of 300 rows blank between readings" in n for n in rec.meta.notes)
    blank(10, "nan")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="NaN or infinite value"):
        read_record(path)
    # the chamber column beside the cell's, read once at row 10: that reading held throughout
    blank(10, repr(readings[10]))
    chamber = lines[0].split(",").index("Ambient Temperature / degC")
    for k in range(1, len(lines)):
        blank(k, "24.5" if k == 10 else "", chamber)
    path.write_text("\n".join(lines) + "\n")
    rec = read_record(path)
    assert rec.temperature_c.tolist() == [readings[1 + 10 * (n // 10)] for n in range(300)]
    assert rec.ambient_c.tolist() == [24.5] * 300 and rec.meta.chamber_temp_c == 24.5


def test_generic_csv_with_mapping_and_sign(tmp_path) -> None:
    p = tmp_path / "g.csv"
    p.write_text("t,I_mA,U\n0,0,3.3\n1,-1000,3.2\n2,-1000,3.19\n3,0,3.25\n")
    rec = read_record(p, fmt="generic", columns={"time": "t", "current": "I_mA", "voltage": "U"},
                      current_scale=1e-3, discharge_positive=True)
    assert rec.current_a.tolist() == [0.0, 1.0, 1.0, 0.0]


GENERIC = {"time": "Time", "current": "I", "voltage": "U"}


def _timed_csv(tmp_path, times: list[str], name: str = "t.csv", sep: str = ","):
    """A generic CSV whose time column holds the given cells, a 1 A discharge throughout."""
    p = tmp_path / name
    p.write_text(f"Time{sep}I{sep}U\n" + "".join(f"{t}{sep}-1{sep}3.{3 + k % 2}\n"
                                                 for k, t in enumerate(times)))
    return p


@pytest.mark.parametrize("times, seconds, kind", [
    ([f"2024-03-01 23:59:{s:04.1f}" for s in (58.0, 58.5, 59.0, 59.5)] + ["2024-03-02 00:00:00"],
     [0.0, 0.5, 1.0, 1.5, 2.0], "ISO 8601"),
    (["2024-03-31T01:59:59+01:00", "2024-03-31T03:00:00+02:00", "2024-03-31T03:00:01+02:00"],
     [0.0, 1.0, 2.0], "ISO 8601"),                    # a daylight-saving change, offsets given
    (["23:59:59", "24:00:00", "24:00:01.5", "100:00:00"], [0.0, 1.0, 2.5, 273601.0],
     "durations"),
    (["0-23:59:59", "1-00:00:00", "1.00:00:02"], [0.0, 1.0, 3.0], "durations"),
])
def test_a_generic_time_column_written_as_text(tmp_path, times, seconds, kind) -> None:
    """Cyclers that write the time as durations (h:mm:ss, hours beyond 24, a day count) or as
    date-times: read to s from the first row, and a note says how (it was refused as 'not a
    number')."""
    rec = read_record(_timed_csv(tmp_path, times), columns=GENERIC)
    assert rec.time_s == pytest.approx(seconds, abs=1e-9)
    assert any(kind in note for note in rec.meta.notes)


def test_a_time_column_as_text_with_a_decimal_comma(tmp_path) -> None:
    p = _timed_csv(tmp_path, ["0:00:00,0", "0:00:00,5", "0:00:01,0"], sep=";")
    rec = read_record(p, columns=GENERIC, sep=";", decimal=",")
    assert rec.time_s.tolist() == [0.0, 0.5, 1.0]
    p = _timed_csv(tmp_path, ["0,5", "1,0"], "seconds.csv", sep=";")   # no decimal given
    with pytest.raises(DataError, match=re.escape(
            "line 2: '0,5' is no time (a decimal comma? give the decimal mark: --decimal ',' "
            "or decimal=',')")):
        read_record(p, columns=GENERIC, sep=";")


@pytest.mark.parametrize("times, message", [
    (["0", "1", "00:00:02"], "column 'Time' line 4: '00:00:02' is not a number like the first "
                             "row's '0'"),
    (["00:00:00", "00:00:01", "2024-01-01 00:00:02"],
     "line 4: '2024-01-01 00:00:02' is not of the first row's kind ('00:00:00': durations"),
    (["abc", "def"], "line 2: 'abc' is no time; expected a number of seconds, a duration "
                     "h:mm:ss[.f]"),
    (["2024-03-01 10:00:00", "2024-03-01 10:00:01", "2024-03-01 10:00:00"],
     "column 'Time' (time_s) is decreasing (a time reset?) at line 4: 1.0 s then 0.0 s"),
])
def test_a_bad_text_time_column_is_named_with_its_line(tmp_path, times, message) -> None:
    with pytest.raises(DataError, match=re.escape(message)):
        read_record(_timed_csv(tmp_path, times), columns=GENERIC)


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "utf-16", "cp1252"])
def test_a_generic_csv_in_the_encodings_cyclers_write(tmp_path, encoding) -> None:
    """UTF-16 with its BOM (Excel's "Unicode text") and Windows-1252 (µ, ° in older Western
    exports) were refused as 'not a text file'."""
    p = tmp_path / f"{encoding}.txt"
    p.write_text("Zeit [s]\tStrom [µA]\tU [V]\tT [°C]\n0\t0\t3,30\t25\n1\t-1000000\t3,20\t25\n"
                 "2\t-1000000\t3,19\t26\n", encoding=encoding)
    rec = read_record(p, columns={"time": "Zeit [s]", "current": "Strom [µA]",
                                  "voltage": "U [V]", "temperature": "T [°C]"},
                      sep="\t", decimal=",", current_scale=1e-6)
    assert rec.current_a.tolist() == [0.0, -1.0, -1.0]
    assert rec.voltage_v.tolist() == [3.3, 3.2, 3.19]
    assert rec.temperature_c.tolist() == [25.0, 25.0, 26.0]


def test_a_utf16_file_cut_inside_a_character_is_named(tmp_path) -> None:
    p = tmp_path / "cut.csv"
    p.write_bytes("t,I,U\n0,0,3.3\n".encode("utf-16") + b"x")
    with pytest.raises(DataError, match="cut.csv: not a text file .utf-16: truncated data"):
        read_record(p, columns={"time": "t", "current": "I", "voltage": "U"})


@pytest.mark.parametrize("unit, factor", [("ms", 1e-3), ("s", 1.0), ("min", 60.0), ("h", 3600.0)])
def test_a_numeric_time_column_in_another_unit(tmp_path, unit, factor) -> None:
    p = tmp_path / "t.csv"
    p.write_text("t,I,U\n0,0,3.3\n100,-1,3.2\n200,-1,3.19\n300,0,3.25\n")
    rec = read_record(p, columns={"time": "t", "current": "I", "voltage": "U"}, time_unit=unit)
    assert rec.time_s == pytest.approx([0.0, 100 * factor, 200 * factor, 300 * factor])


def test_a_time_unit_is_refused_for_text_times_and_where_unknown(tmp_path) -> None:
    p = _timed_csv(tmp_path, ["00:00:00", "00:00:01", "00:00:02"])
    with pytest.raises(DataError, match="time unit 'ms' for the column 'Time', whose times are "
                                        "text that carries its own unit"):
        read_record(p, columns=GENERIC, time_unit="ms")
    with pytest.raises(DataError, match=re.escape("time unit 'days'; expected one of ['s', "
                                                  "'ms', 'min', 'h', 'd']")):
        read_record(p, columns=GENERIC, time_unit="days")


def test_voltage_in_mv_and_temperature_in_kelvin(tmp_path) -> None:
    """Columns in mV and K are read with their units given; without, the range check names
    the option (an mV column could not be read at all)."""
    p = tmp_path / "t.csv"
    p.write_text("t,I,U_mV,T_K\n0,0,3300,298.15\n1,-1,3200,298.65\n2,-1,3190,299.15\n")
    columns = {"time": "t", "current": "I", "voltage": "U_mV", "temperature": "T_K"}
    rec = read_record(p, columns=columns, voltage_unit="mV", temperature_unit="K")
    assert rec.voltage_v == pytest.approx([3.3, 3.2, 3.19])
    assert rec.temperature_c == pytest.approx([25.0, 25.5, 26.0])
    with pytest.raises(DataError, match="a column in mV: --voltage-unit mV, voltage_unit='mV'"):
        read_record(p, columns=columns, temperature_unit="K")
    with pytest.raises(DataError, match="a column in K: --temperature-unit K"):
        read_record(p, columns=columns, voltage_unit="mV")


# ----- bad input: each case names the file and the problem -----------------------------
def _plett(tmp_path, rows: list[str], name: str = "x.csv"):
    p = tmp_path / name
    p.write_text("time, step, current, voltage, chgAh, disAh\n" + "\n".join(rows) + "\n")
    return p


GOOD = [f"{k}, 1, 1.0, 3.3, 0, {k / 3600:.6f}" for k in range(10)]


@pytest.mark.parametrize("case, rows, expected", [
    ("nan", GOOD[:3] + ["3, 1, nan, 3.3, 0, 0"] + GOOD[4:],
     "column 'current' (current_a) has 1 NaN or infinite value(s), first at line 5"),
    ("inf", GOOD[:3] + ["3, 1, 1.0, inf, 0, 0"] + GOOD[4:], "column 'voltage' (voltage_v) has 1 NaN or infinite"),
    ("repeated", GOOD[:3] + ["2, 1, 1.0, 3.31, 0, 0"] + GOOD[4:],
     "column 'time' (time_s) is repeated at line 5: 2.0 s then 2.0 s"),
    ("reset", GOOD[:5] + ["0.5, 1, 1.0, 3.3, 0, 0"] + GOOD[6:],
     "decreasing (a time reset?) at line 7: 4.0 s then 0.5 s"),
    ("text", GOOD[:3] + ["3, 1, abc, 3.3, 0, 0"], "'current' line 5: 'abc' is not a number"),
])
def test_bad_plett_input(tmp_path, case, rows, expected) -> None:
    p = _plett(tmp_path, rows, f"{case}.csv")
    with pytest.raises(DataError) as err:
        read_record(p)
    assert str(p) in str(err.value) and expected in str(err.value)


def test_a_line_logged_twice_is_left_out_with_a_note(tmp_path) -> None:
    """A data line that repeats the one before it exactly (a logger that wrote a sample twice,
    as the Panasonic files' last sample) is left out with a note naming its line, in every
    CSV format; the lines of later errors still name the file's lines where it was the last."""
    twice = read_record(_plett(tmp_path, GOOD[:4] + [GOOD[3]] + GOOD[4:], "twice.csv"))
    assert len(twice) == len(GOOD) and np.all(np.diff(twice.time_s) > 0)
    assert ("left out 1 data line(s) that repeat the line before them exactly (the same sample "
            "logged twice), first line 6") in twice.meta.notes
    assert twice.meta.first_line is None          # the rows after it are one line further on
    last = _plett(tmp_path, GOOD + [GOOD[-1], GOOD[-1]], "last.csv")
    generic = read_record(last, columns={"time": "time", "current": "current",
                                         "voltage": "voltage"})
    assert len(generic) == len(GOOD) and generic.meta.first_line == 2
    assert any("left out 2 data line(s)" in n and "first line 12" in n
               for n in generic.meta.notes)


def test_errors_quote_the_files_own_times_and_lines(tmp_path) -> None:
    """A time column that starts at 100 s is quoted as the file has it (not from 0), at its
    line; where blank lines break the row-to-line count the sample is named instead."""
    later = [f"{100 + k}, 1, 1.0, 3.3, 0, 0" for k in range(4)] + ["101.5, 1, 1.0, 3.3, 0, 0"]
    with pytest.raises(DataError, match=r"at line 6: 103.0 s then 101.5 s"):
        read_record(_plett(tmp_path, later, "later.csv"))
    good = read_record(_plett(tmp_path, GOOD, "good.csv"))
    assert (good.meta.first_line, good.slice(3, 8).meta.first_line) == (2, 5)
    blank = GOOD[:3] + [""] + GOOD[3:5] + ["5, 1, 1.0, 33, 0, 0"]
    with pytest.raises(DataError, match=r"column 'voltage' \(voltage_v\) is 33 V at sample 5 "):
        read_record(_plett(tmp_path, blank, "blank.csv"))


def test_missing_column(tmp_path) -> None:
    p = tmp_path / "m.csv"
    p.write_text("Test Time / s,Voltage / V\n0,3.3\n1,3.3\n")
    with pytest.raises(DataError, match="unknown format"):
        read_record(p)
    with pytest.raises(DataError, match=r"missing column\(s\) \['Current / A'\]"):
        read_record(p, fmt="bdf")


def test_a_json_file_given_as_data_is_named(tmp_path, quick_model) -> None:
    """A model file (or other JSON) given where a record belongs says what it is."""
    with pytest.raises(DataError, match=r"pan.json: an LMNCell model file \(give it as the "
                                        r"model: lmncell evaluate MODEL.json DATA"):
        read_record(quick_model)
    other = tmp_path / "results.json"
    other.write_text('[{"record": "a"}]')
    with pytest.raises(DataError, match="results.json: a JSON file, not a measurement record"):
        read_record(other)


def test_a_temperature_read_every_few_rows_is_held_between_readings(tmp_path) -> None:
    """A thermocouple logged every 10th row, blank between (was refused: "column 'T' line 3:
    '' is not a number"): each blank holds the reading before it, and a note says so; a text
    cell there, or a column with no reading, is still refused with its line."""
    cols = {"time": "t", "current": "I", "voltage": "U", "temperature": "T"}
    rows = [f"{k},-1.0,3.{k % 7},{20 + k // 10 if k % 10 == 3 else ''}" for k in range(40)]
    path = tmp_path / "aux.csv"
    path.write_text("t,I,U,T\n" + "\n".join(rows) + "\n")
    rec = read_record(path, columns=cols)
    np.testing.assert_array_equal(rec.temperature_c[:3], [20.0] * 3)    # the first, back
    np.testing.assert_array_equal(rec.temperature_c[3:13], [20.0] * 10)
    np.testing.assert_array_equal(rec.temperature_c[13:23], [21.0] * 10)
    assert rec.temperature_c[-1] == 23.0
    assert ("column 'T': 36 of 40 rows blank between readings, each holding the reading "
            "before it" in " ".join(rec.meta.notes))
    # a time unit with such a column (was refused: its note was taken for text times)
    ms = read_record(path, columns=cols, time_unit="ms")
    np.testing.assert_array_equal(ms.time_s, rec.time_s * 1e-3)
    path.write_text("t,I,U,T\n" + "\n".join(rows).replace(",20\n", ",n/a\n", 1) + "\n")
    with pytest.raises(DataError, match=r"aux.csv: column 'T' line 5: 'n/a' is not a number"):
        read_record(path, columns=cols)
    path.write_text("t,I,U,T\n0,-1,3.3,\n1,-1,3.3,\n")
    with pytest.raises(DataError, match=r"column 'T' has no reading \(every cell blank\)"):
        read_record(path, columns=cols)


def test_a_speed_trace_given_as_data_is_named(tmp_path) -> None:
    """A vehicle speed trace (the shipped cycles' format, or time_s,speed_kmh) given where a
    record belongs says what it is and where it goes; before: 'unknown format … Name your
    columns'. A vehicle's log with a voltage column stays a record to name columns of."""
    from lmncell.scenarios.traces import data_dir

    shipped = data_dir() / "drive_cycles" / "udds.csv"
    with pytest.raises(DataError, match=r"udds.csv: a vehicle speed trace \(cycSecs, cycMps, "
                                        r"cycGrade\), not a measurement record; a model drives "
                                        r"it with lmncell simulate CELL.fmu --cycle "):
        read_record(shipped)
    own = tmp_path / "route.csv"
    own.write_text("time_s,speed_kmh\n0,0\n1,5\n")
    with pytest.raises(DataError, match="route.csv: a vehicle speed trace"):
        read_record(own)
    log = tmp_path / "log.csv"
    log.write_text("time_s,speed_kmh,pack_voltage_v\n0,0,390\n1,5,389\n")
    with pytest.raises(DataError, match="log.csv: unknown format"):
        read_record(log)


def test_empty_and_unknown_files(tmp_path) -> None:
    empty = tmp_path / "e.csv"
    empty.write_text("")
    with pytest.raises(DataError, match="e.csv: the file is empty"):
        read_record(empty)
    header_only = _plett(tmp_path, [], "h.csv")
    with pytest.raises(DataError, match="header but no data rows"):
        read_record(header_only)
    odd = tmp_path / "odd.csv"
    odd.write_text("a,b\n1,2\n")
    with pytest.raises(DataError, match="odd.csv: unknown format"):
        read_record(odd)
    with pytest.raises(DataError, match="no such file"):
        read_record(tmp_path / "missing.csv")
    bad_mat = tmp_path / "bad.mat"
    bad_mat.write_bytes(b"not a mat file at all" * 10)
    with pytest.raises(DataError, match="bad.mat: not a readable MATLAB file"):
        read_record(bad_mat)


def test_binary_files_given_as_data_are_named(tmp_path) -> None:
    """A workbook, an FMU or a MATLAB v7.3 file given as a record is named as such, with what
    to do; before, the message spoke only of a NUL byte or of an HDF reader to use."""
    import zipfile
    with zipfile.ZipFile(tmp_path / "log.xlsx", "w") as z:
        z.writestr("xl/workbook.xml", "<workbook/>")
    (tmp_path / "log.xls").write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(64))
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 ."
    (tmp_path / "v73.mat").write_bytes(header.ljust(116) + bytes(8) + b"\x00\x02IM"
                                       + bytes(384) + b"\x89HDF\r\n\x1a\n" + bytes(64))
    for name, message in (("log.xlsx", "a ZIP archive, such as an Excel workbook (.xlsx: "
                                       "save its sheet as CSV)"),
                          ("log.xls", "Excel 97–2003 workbook (.xls: save its sheet as CSV)"),
                          ("v73.mat", "a MATLAB v7.3 (HDF5) file, which is not read here")):
        with pytest.raises(DataError, match=re.escape(f"{name}: ") + ".*" + re.escape(message)):
            read_record(tmp_path / name)
    # cyclers' own binary files name the export to make (they spoke of a NUL byte)
    (tmp_path / "run.mpr").write_bytes(b"BIO-LOGIC MODULAR FILE\x1a" + b" " * 25 + bytes(64))
    (tmp_path / "run.nda").write_bytes(b"NEWARE" + bytes(64))
    (tmp_path / "run.res").write_bytes(b"\x00\x01\x00\x00Standard Jet DB\x00" + bytes(64))
    with zipfile.ZipFile(tmp_path / "run.ndax", "w") as z:
        z.writestr("data.ndc", bytes(64))
    for name, message in (("run.mpr", "a BioLogic EC-Lab binary file (.mpr: export it as text, "
                                      ".mpt, in EC-Lab)"),
                          ("run.nda", "a Neware .nda file (export it as CSV in Neware's BTSDA)"),
                          ("run.res", "such as an Arbin .res file (export it as CSV in Arbin's "
                                      "MITS Pro)"),
                          ("run.ndax", "a Neware .ndax archive (export it as CSV in Neware's "
                                       "BTSDA)")):
        with pytest.raises(DataError, match=re.escape(f"{name}: not a text file (") + ".*"
                           + re.escape(message)):
            read_record(tmp_path / name)


def test_gzip_csv_reads(tmp_path) -> None:
    p = tmp_path / "z.csv.gz"
    with gzip.open(p, "wt") as fh:
        fh.write("time, step, current, voltage, chgAh, disAh\n" + "\n".join(GOOD) + "\n")
    assert len(read_record(p)) == 10


def test_milliamp_and_sign_warnings(tmp_path) -> None:
    p = tmp_path / "ma.csv"
    rows = ["Test Time / s,Voltage / V,Current / A"]
    rows += [f"{k},{3.3 + (0.1 if k % 4 < 2 else 0)},{1000 if k % 4 < 2 else 0}"
             for k in range(40)]
    p.write_text("\n".join(rows) + "\n")
    with pytest.warns(DataWarning, match="look like mA"):
        read_record(p)
    q = tmp_path / "sign.csv"
    rows = ["Test Time / s,Voltage / V,Current / A"]
    rows += [f"{k},{3.3 - (0.1 if k % 4 < 2 else 0)},{2 if k % 4 < 2 else 0}" for k in range(40)]
    q.write_text("\n".join(rows) + "\n")
    with pytest.warns(DataWarning, match="sign looks inverted"):
        read_record(q)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_record(A123_S1)  # real data: no warning


def _record_with_hidden_pause(tmp_path, row: int, pause_s: float, n: int = 4000):
    """The shipped US06 record's first n samples, saved again with a wall clock (TimeStamp)
    that jumps by pause_s at `row` while its Time column runs on, as in the Panasonic 25 °C
    Cycle 1 file."""
    meas = scipy.io.loadmat(str(PAN_US06))["meas"][0, 0]
    fields = {k: np.asarray(meas[k])[:n] for k in meas.dtype.names if k != "TimeStamp"}
    t = fields["Time"].ravel()
    start = datetime(2017, 3, 20, 1, 43, 49)
    stamps = np.empty((n, 1), dtype=object)
    for k in range(n):
        wall = start + timedelta(seconds=float(t[k] - t[0]) + (pause_s if k >= row else 0.0))
        stamps[k, 0] = np.array([wall.strftime("%m/%d/%Y %I:%M:%S %p")])
    fields["TimeStamp"] = stamps
    path = tmp_path / "paused_Pan18650PF.mat"
    scipy.io.savemat(str(path), {"meas": fields})
    return path


def test_hidden_pause_splits_unless_driven_through_the_time_column(tmp_path) -> None:
    path = _record_with_hidden_pause(tmp_path, 2500, 3 * 3600.0)
    rec = read_record(path)
    assert len(rec.meta.pause_starts) == 1
    (k,) = rec.meta.pause_starts
    assert 2480 <= k <= 2500 and k in rec.meta.segment_starts           # a few duplicates dropped
    assert len(rec.segments()) == 2
    assert rec.slice(100, len(rec)).meta.pause_starts == [k - 100]
    through = rec.through_hidden_pauses()
    assert through.meta.segment_starts == [0] and through.meta.pause_starts == []
    assert len(through.segments()) == 1 and len(through) == len(rec)
    assert any("not split" in note for note in through.meta.notes)
    assert read_record(PAN_US06).through_hidden_pauses().meta == read_record(PAN_US06).meta


def test_evaluation_through_hidden_pauses_runs_the_model_state_on(tmp_path, quick_model,
                                                                  capsys) -> None:
    model = load_model(quick_model)
    path = _record_with_hidden_pause(tmp_path, 2500, 3 * 3600.0)
    split, rows = evaluate_model(model, [path], soc0=1.0)
    run_on, rows_on = evaluate_model(model, [path], soc0=1.0, through_hidden_pauses=True)
    assert len(split) == len(rows) == 2 and len(run_on) == len(rows_on) == 1
    whole, after = run_on[0], split[1]
    first = len(split[0].segment)
    assert np.array_equal(whole.voltage["lmn"][:first], split[0].voltage["lmn"])
    # after the "pause" (only the stamps jump: the cell ran on) the split model restarts rested
    # at the counted SoC, the run-on one stays polarised and follows the cell
    k = np.searchsorted(whole.segment.time_s, after.segment.time_s - 0.5)[:60]
    assert np.max(np.abs(whole.segment.time_s[k] - after.segment.time_s[:60])) < 0.05
    measured = after.segment.voltage_v[:60]
    run_on_error = np.mean(whole.voltage["lmn"][k] - measured)
    restarted_error = np.mean(after.voltage["lmn"][:60] - measured)
    assert abs(restarted_error) > 5e-3 and abs(run_on_error) < 0.5 * abs(restarted_error)
    assert abs(whole.soc_model[k[0]] - after.soc_model[0]) < 2e-3
    assert [r.get("hidden_pauses_split") for r in rows] == [1, 1]
    assert "hidden_pauses_split" not in rows_on[0]
    for flag, segments in (([], 2), (["--through-hidden-pauses"], 1)):
        capsys.readouterr()
        assert main(["evaluate", str(quick_model), str(path), "--soc0", "1", "--json",
                     *flag]) == 0
        assert len(json.loads(capsys.readouterr().out)) == segments
    assert main(["evaluate", str(quick_model), str(path), "--soc0", "1"]) == 0
    assert "split at 1 pause(s) that only its wall clock shows" in capsys.readouterr().out          # SoC counts on across it


@pytest.mark.parametrize("columns, rows, message", [
    ("t,i,v", ["0,1,3650", "1,1,3640"], r"column 'v' \(voltage_v\) is 3650 V at line 2 \(2 sample\(s\) outside "
                                        r"0…6 V\); expected a cell's terminal voltage in V"),
    ("t,i,v", ["0,1,3.6", "1,1,-0.2"], r"column 'v' \(voltage_v\) is -0.2 V at line 3"),
    ("t,i,v,T", ["0,1,3.6,298.15", "1,1,3.6,298.2"], r"column 'T' \(temperature_c\) is 298.15 °C at line 2 "
                                                      r".*expected a cell temperature in °C"),
])
def test_voltages_and_temperatures_outside_a_cells_range_are_refused(tmp_path, columns, rows,
                                                                     message) -> None:
    """A record in mV, of a pack, or in kelvin is refused with the column, row and value."""
    from lmncell.data.readers import read_record
    from lmncell.data.records import DataError

    p = tmp_path / "r.csv"
    p.write_text(columns + "\n" + "\n".join(rows) + "\n")
    names = columns.split(",")
    mapping = dict(zip(("time", "current", "voltage", "temperature")[:len(names)], names,
                       strict=True))
    with pytest.raises(DataError, match=message):
        read_record(p, columns=mapping)


def test_read_records_options_are_read_generics(tmp_path) -> None:
    """read_record passes its options to read_generic: the two lists agree, and an unknown one
    (the CLI's --delimiter spelt as a keyword) is named with the ones there are."""
    import inspect

    from lmncell.data.readers import GENERIC_OPTIONS, read_generic

    assert list(inspect.signature(read_generic).parameters)[1:] == list(GENERIC_OPTIONS)
    p = tmp_path / "r.csv"
    p.write_text("t;i;v\n0;1;3.3\n1;1;3.3\n")
    with pytest.raises(TypeError, match=r"unknown option\(s\) \['delimiter'\].*sep is the "):
        read_record(p, columns={"time": "t", "current": "i", "voltage": "v"}, delimiter=";")
    assert read_record(p, columns={"time": "t", "current": "i", "voltage": "v"},
                       sep=";").voltage_v.tolist() == [3.3, 3.3]


def _write_eclab(path, rec, decimal: str = ".", repeat_row: int | None = None,
                 magic: str = "EC-Lab ASCII FILE", voltage: str = "Ewe/V",
                 eis_after: int | None = None) -> None:
    """An EC-Lab ASCII export (.mpt) of a record as the software writes one: a preamble whose
    second line counts the header lines, tab-separated rows ending in a tab, I in mA (> 0
    charges), (Q-Qo) in mA.h, Windows-1252 text (µ, ° in the names); with eis_after, three
    impedance points (freq/Hz > 0) after that row, at its time and just after it."""
    names = ["mode", "ox/red", "error", "time/s", "freq/Hz", "control/V/mA", voltage, "I/mA",
             "(Q-Qo)/mA.h", "Temperature/°C", "Capacitance charge/µF", "cycle number"]
    preamble = [magic, "", "Galvanostatic Cycling with Potential Limitation", "",
                "Run on channel : 1 (SN 0001)", "Acquisition started on : 03/01/2024 10:00:00",
                "Electrode surface area : 0.001 cm²"]
    preamble[1] = f"Nb header lines : {len(preamble) + 1}"
    t, i = rec.time_s, rec.current_a
    q_mah = 1000.0 * rec.charge_ah
    rows = []
    for k in range(len(rec)):
        cells = [1, int(i[k] > 0), 0, t[k], 0.0, 0.0, rec.voltage_v[k], 1000.0 * i[k],
                 q_mah[k], 25.0 + 0.001 * k, 0.0, 0]
        rows.append("\t".join(repr(float(c)) if isinstance(c, float) else str(c)
                              for c in cells) + "\t")
        if k == repeat_row:     # EC-Lab's row where the technique changes: one time, new mode
            rows.append("\t".join(["2", *rows[-1].split("\t")[1:]]))
        if k == eis_after:
            for j, freq in enumerate((1e4, 1e2, 1.0)):
                eis = [3, 0, 0, t[k] + 1e-3 * j, freq, 0.0, 3.0, 5.0, q_mah[k], 25.0, 0.0, 0]
                rows.append("\t".join(str(c) for c in eis) + "\t")
    text = "\n".join([*preamble, "\t".join(names) + "\t", *rows]) + "\n"
    if decimal == ",":
        text = "\n".join(ln if k <= len(preamble) else ln.replace(".", ",")
                         for k, ln in enumerate(text.split("\n")))
    path.write_bytes(text.replace("\n", "\r\n").encode("cp1252"))


def test_biologic_export_reads_by_content(tmp_path) -> None:
    rec = read_record(A123_S1).slice(0, 3000)
    for decimal in (".", ","):
        path = tmp_path / f"cell_{decimal == ','}.mpt"
        _write_eclab(path, rec, decimal=decimal, repeat_row=100, eis_after=2000)
        assert detect_format(path) == "biologic"
        back = read_record(path)
        assert back.meta.fmt == "biologic" and len(back) == len(rec)
        assert any("dropped 1 row(s) whose time the next row repeats" in n
                   for n in back.meta.notes)
        assert any("dropped 3 impedance (EIS) row(s)" in n for n in back.meta.notes)
        assert np.allclose(back.time_s, rec.time_s - rec.time_s[0], atol=1e-9)
        assert np.allclose(back.current_a, rec.current_a, atol=1e-12)
        assert np.allclose(back.voltage_v, rec.voltage_v, atol=1e-12)
        assert np.allclose(back.charge_ah, rec.charge_ah - rec.charge_ah[0], atol=1e-12)
        assert back.temperature_c[1] == pytest.approx(25.001)
    # a BT-Lab export of a full cell names its voltage Ecell
    _write_eclab(tmp_path / "bt.mpt", rec, magic="BT-Lab ASCII FILE", voltage="Ecell/V")
    assert np.allclose(read_record(tmp_path / "bt.mpt").voltage_v, rec.voltage_v)
    assert main(["inspect", str(tmp_path / "bt.mpt")]) == 0


@pytest.mark.parametrize(("edit", "message"), [
    (lambda s: s.replace("Nb header lines : 8", "Nb header lines: eight"),
     "line 2 is 'Nb header lines: eight'; expected 'Nb header lines : N'"),
    (lambda s: s.replace("Nb header lines : 8", "Nb header lines : 9000"),
     "'Nb header lines : 9000' but the file has"),
    (lambda s: s.replace("\tEwe/V\t", "\tE/V\t"),
     "no cell voltage column; expected one of ['Ecell/V'"),
    (lambda s: s.replace("\tI/mA\t", "\tcurrent\t"), "no current column"),
])
def test_biologic_export_errors_name_what_is_wrong(tmp_path, edit, message) -> None:
    path = tmp_path / "bad.mpt"
    _write_eclab(path, read_record(A123_S1).slice(0, 50))
    path.write_bytes(edit(path.read_bytes().decode("cp1252")).encode("cp1252"))
    with pytest.raises(DataError, match=re.escape(message)):
        read_record(path)


def test_generic_reader_skips_a_preamble_before_the_column_names(tmp_path, capsys) -> None:
    # a cycler's text export (here Maccor-like, tab-separated) with its settings first
    rows = ["Today's Date\t03/01/2024", "Procedure:\tUDDS.000", "Comment/Barcode:\tcell 7", "",
            "Rec\tTest Time\tCurrent\tVoltage\tTemp 1",
            "1\t0\t0\t3.3\t25.0", "2\t1\t-1.5\t3.2\t25.1", "3\t2\t-1.5\t3.19\t25.2",
            "4\t3\t0\t3.25\t25.2"]
    path = tmp_path / "maccor.txt"
    path.write_text("\n".join(rows) + "\n")
    cols = "time=Test Time,current=Current,voltage=Voltage,temperature=Temp 1"
    rec = read_record(path, columns=dict(c.split("=") for c in cols.split(",")), sep="\t")
    assert rec.current_a.tolist() == [0.0, -1.5, -1.5, 0.0]
    assert rec.temperature_c[-1] == 25.2
    assert any("column names on line 5: the 4 line(s) before them skipped" in n
               for n in rec.meta.notes)
    # errors still name the file's own line
    path.write_text("\n".join([*rows[:7], "3\t2\tx\t3.19\t25.2"]) + "\n")
    assert main(["inspect", str(path), "--columns", cols, "--delimiter", "tab"]) == 2
    assert "column 'Current' line 8: 'x' is not a number" in capsys.readouterr().err


def test_biologic_export_of_impedance_only_is_refused(tmp_path) -> None:
    path = tmp_path / "peis.mpt"
    path.write_text("EC-Lab ASCII FILE\nNb header lines : 3\n"
                    "freq/Hz\ttime/s\tEwe/V\tI/mA\n1000\t0.5\t3.3\t0.1\n100\t1.5\t3.3\t0.1\n")
    with pytest.raises(DataError, match=r"peis.mpt: no cycling rows \(dropped 2 impedance"):
        read_record(path)


@pytest.mark.parametrize("sep", [";;", "", 3])
def test_a_bad_delimiter_is_a_data_error_not_a_traceback(tmp_path, sep) -> None:
    path = tmp_path / "g.csv"
    path.write_text("t,I,U\n0,0,3.3\n1,1,3.4\n")
    with pytest.raises(DataError, match="g.csv: delimiter .*; expected one character"):
        read_record(path, columns={"time": "t", "current": "I", "voltage": "U"}, sep=sep)


@pytest.mark.parametrize("sep, text, hint", [
    (",", "t;I;U\n0;0;3.3\n", r"the names hold ';': is that the delimiter\? give it: "
                              "--delimiter ';' or sep=';'"),
    (",", "t\tI\tU\n0\t0\t3.3\n", "the names hold a tab: .* --delimiter tab or sep='\\\\t'"),
    (";", "t,I,U\n0,0,3.3\n", "the names hold ',': .* --delimiter ',' or sep=','"),
])
def test_names_joined_by_another_delimiter_are_pointed_out(tmp_path, sep, text, hint) -> None:
    """A ';'- or tab-delimited file read with ',' has one column holding all the names: the
    error says which delimiter the names seem to use, and how to give it."""
    path = tmp_path / "g.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=r"missing column\(s\) .*; found .* \(" + hint):
        read_record(path, columns={"time": "t", "current": "I", "voltage": "U"}, sep=sep)


def test_a_column_mapping_that_is_not_one_is_named(tmp_path) -> None:
    path = tmp_path / "g.csv"
    path.write_text("t,I,U\n0,0,3.3\n1,1,3.4\n")
    with pytest.raises(DataError, match=r"g.csv: columns = 'time=t'; expected a mapping"):
        read_record(path, columns="time=t")


def test_generic_reader_skips_a_units_row_after_the_column_names(tmp_path) -> None:
    path = tmp_path / "units.csv"
    path.write_text("Time;Current;Voltage\ns;A;V\n0;0;3,30\n1;-1,5;3,20\n2;0;3,25\n")
    rec = read_record(path, columns={"time": "Time", "current": "Current", "voltage": "Voltage"},
                      sep=";", decimal=",")
    assert rec.current_a.tolist() == [0.0, -1.5, 0.0]
    assert any("line 2 read as the columns' units, not data: 's;A;V'" in n
               for n in rec.meta.notes)
    # the row's units are taken: mA, mV and min read as such, and an option that disagrees
    # with them is refused
    path.write_text("Time;Current;Voltage\n[min];[mA];[mV]\n0;0;3300\n1;-1500;3200\n")
    mapping = {"time": "Time", "current": "Current", "voltage": "Voltage"}
    rec = read_record(path, columns=mapping, sep=";")
    assert rec.time_s.tolist() == [0.0, 60.0] and rec.current_a.tolist() == [0.0, -1.5]
    assert rec.voltage_v == pytest.approx([3.3, 3.2], abs=1e-12)
    assert any(n == "units from the file: time in min (the units row (line 2)), current in mA "
               "(the units row (line 2)), voltage in mV (the units row (line 2))"
               for n in rec.meta.notes)
    assert read_record(path, columns=mapping, sep=";", current_unit="mA").current_a[1] == -1.5
    # an option wins over the file (whose header may be wrong), with a warning
    with pytest.warns(DataWarning, match="values look like mA"), \
            pytest.warns(DataWarning, match=re.escape("the current is read in A as the option "
                                                      "says, where the units row (line 2) says mA")):
        assert read_record(path, columns=mapping, sep=";", current_unit="A").current_a[1] == (
            -1500.0)


def test_generic_reader_takes_units_from_the_column_names(tmp_path) -> None:
    path = tmp_path / "named.csv"
    path.write_text("Time (min),I/mA,Voltage [mV],T [K]\n0,0,3300,298.15\n1,-1500,3200,299.15\n")
    mapping = {"time": "Time (min)", "current": "I/mA", "voltage": "Voltage [mV]",
               "temperature": "T [K]"}
    rec = read_record(path, columns=mapping)
    assert rec.time_s.tolist() == [0.0, 60.0] and rec.current_a.tolist() == [0.0, -1.5]
    assert rec.voltage_v == pytest.approx([3.3, 3.2], abs=1e-12)
    assert rec.temperature_c == pytest.approx([25.0, 26.0], abs=1e-9)
    assert any("current in mA (the column name 'I/mA')" in n for n in rec.meta.notes)
    with pytest.warns(DataWarning, match=re.escape("the time is read in s as the option says, "
                                                   "where the column name 'Time (min)' says min")):
        assert read_record(path, columns=mapping, time_unit="s").time_s.tolist() == [0.0, 1.0]
    # a name and a units row that disagree are refused
    path.write_text("Time,Current [A],Voltage\ns,mA,V\n0,0,3.3\n1,-1500,3.2\n")
    mapping = {"time": "Time", "current": "Current [A]", "voltage": "Voltage"}
    with pytest.raises(DataError, match=re.escape("the column name 'Current [A]' says the "
                                                  "current is in A, the units row (line 2) says mA; "
                                                  "expected them to agree (give the current "
                                                  "unit: --current-unit")):
        read_record(path, columns=mapping)
    with pytest.warns(DataWarning, match="where the column name 'Current .A.' says A"):
        assert read_record(path, columns=mapping, current_unit="mA").current_a[1] == -1.5
    # a row that is not units but bad data is still refused, naming its line
    path.write_text("Time;Current;Voltage\n0;0;3,30\n1;x;3,20\n")
    with pytest.raises(DataError, match="column 'Current' line 3: 'x' is not a number"):
        read_record(path, columns={"time": "Time", "current": "Current", "voltage": "Voltage"},
                    sep=";", decimal=",")


def test_an_unknown_header_gets_the_options_that_read_it(tmp_path, capsys) -> None:
    """A plain table with units in its names, ';'-delimited with decimal commas, was refused
    with the generic "Name your columns" alone; the message now proposes the options for this
    header, and those options read it (with the mA of the name). A header without one clear
    time, current and voltage column gets no proposal."""
    path = tmp_path / "eu.csv"
    path.write_text("Time [s];Current [mA];Voltage [V];T_cell;T_ambient\n"
                    + "".join(f"{k};-{k % 5 * 100},5;3,{300 + k % 7};25,1;24\n"
                              for k in range(30)))
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    proposal = ("--columns 'time=Time [s],current=Current [mA],voltage=Voltage [V],"
                "temperature=T_cell,ambient=T_ambient' --delimiter ';' --decimal ,")
    assert "eu.csv: unknown format; " in err and f"(line 1), perhaps: {proposal} (check" in err
    assert main(["inspect", str(path), *shlex.split(proposal)]) == 0
    out = capsys.readouterr().out
    assert "current -0.401 … -0.001 A" in out and "current in mA" in out, out
    rec = read_record(path, columns={"time": "Time [s]", "current": "Current [mA]",
                                     "voltage": "Voltage [V]", "temperature": "T_cell",
                                     "ambient": "T_ambient"}, sep=";", decimal=",")
    assert rec.current_a[1] == pytest.approx(-0.1005) and rec.temperature_c[0] == 25.1
    assert rec.ambient_c[0] == 24.0
    preamble = tmp_path / "cycler.csv"             # a cycler's settings above the table
    preamble.write_text("Channel: 3\nCell: X-1\n\nt/s,I/A,U/V\n0,-1.0,3.3\n1,-1.0,3.2\n")
    with pytest.raises(DataError, match=r"\(line 4\), perhaps: --columns time=t/s,current=I/A,"
                                        r"voltage=U/V \(check"):
        read_record(preamble)
    assert len(read_record(preamble, columns={"time": "t/s", "current": "I/A",
                                              "voltage": "U/V"})) == 2
    from lmncell.data.header import suggested_options

    assert suggested_options("Time,Current,Voltage,Tcell,Tamb", None) == (
        "--columns time=Time,current=Current,voltage=Voltage,temperature=Tcell,ambient=Tamb")
    assert "ambient" not in suggested_options("Time,Current,Voltage,Temp1,Temp2", None)
    # Neware: "Time" is the step's clock, "Total Time" the test's (two time columns proposed
    # nothing before)
    assert suggested_options("DataPoint,Cycle Index,Step Index,Step Type,Time,Total Time,"
                             "Current(A),Voltage(V),Capacity(Ah),T1(℃)", None) == (
        "--columns 'time=Total Time,current=Current(A),voltage=Voltage(V),temperature=T1(℃)'")
    # BaSyTec: "~Time[h]" is the test's clock, "Time" the time of day (proposed before), and
    # its numeric State is no direction (a Maccor State or Md of words is)
    assert suggested_options(
        "~Time[h];DataSet;Date;Time;Line;U[V];I[A];Ah[Ah];T1[°C];State",
        "0,0000;1;01.01.2024;10:00:00;1;3,5;0,0;0,0;25,0;0") == (
        "--columns 'time=~Time[h],current=I[A],voltage=U[V],temperature=T1[°C],charge=Ah[Ah]' "
        "--delimiter ';' --decimal ,")
    assert suggested_options("Rec,TestTime,StepTime,Current [A],Voltage [V],Md,Temp 1",
                             "1,0,0,0,3.3,R,25").endswith("temperature=Temp 1,state=Md'")
    for header in ("a,b,c\n1,2,3\n", "Time,Current,U1,U2\n0,1,3,3\n"):
        path.write_text(header)
        with pytest.raises(DataError, match="unknown format") as info:
            read_record(path)
        assert "perhaps" not in str(info.value)


@pytest.mark.parametrize("field, edit, message", [
    ("Voltage", lambda a: a[:-10], r"field 'Voltage' holds 3990 value\(s\) for 4000 times "
                                   r"\(field 'Time'\); expected one per sample"),
    ("Current", lambda a: np.full(5, "x"), "field 'Current' is not numeric"),
    ("Time", lambda a: a[:0], r"field 'Time' is empty; expected one time \(s\) per sample"),
    ("Time", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.nan, a),
     "field 'Time' holds 1 NaN or infinite value.*, the first at sample 8"),
    ("TimeStamp", lambda a: a[:3], "field 'TimeStamp' holds 3 value.* for 4000 times"),
    ("Chamber_Temp_degC", lambda a: a + 273.15,
     r"column 'Chamber_Temp_degC' \(ambient_c\) is 298.15 °C at sample 0 \(4000 sample"),
    ("TimeStamp", lambda a: np.array([["not a time"]] * a.size, dtype=object),
     "field 'TimeStamp': .*expected wall-clock times"),
])
def test_a_panasonic_file_with_a_broken_field_is_named(tmp_path, field, edit, message) -> None:
    """A field of the 'meas' struct that is not numeric or not one value per sample gave an
    IndexError or a ValueError traceback (found by editing each field of the shipped file)."""
    meas = scipy.io.loadmat(str(PAN_US06))["meas"][0, 0]
    fields = {k: np.asarray(meas[k])[:4000] for k in meas.dtype.names}
    fields[field] = edit(fields[field])
    path = tmp_path / "broken_Pan18650PF.mat"
    scipy.io.savemat(str(path), {"meas": fields})
    with pytest.raises(DataError, match=rf"broken_Pan18650PF.mat: {message}"):
        read_record(path)


def test_a_settling_chamber_is_the_ambient_of_its_segment(tmp_path) -> None:
    """The Panasonic chamber temperature as logged (Chamber_Temp_degC) rides with the record;
    a segment carries it per step where it varies (the 25 °C Cycle 1 record: 23 … 25 °C in its
    first half hour), and evaluation's ambient runs then take it; a constant log, as in the
    shipped records, leaves the set point. A chamber column with a gap is not used per step."""
    from lmncell.data.dataset import record_parts, record_to_segments
    from lmncell.data.summary import format_summary, summarise
    from lmncell.evaluation.evaluate import ambient_of
    from lmncell.evaluation.fmueval import ambient_at_samples

    meas = scipy.io.loadmat(str(PAN_US06))["meas"][0, 0]
    fields = {k: np.asarray(meas[k])[:4000] for k in meas.dtype.names}
    constant = read_record(PAN_US06)
    assert constant.ambient_c is not None and np.ptp(constant.ambient_c) == 0.0
    (seg,) = record_to_segments(constant.slice(0, 4000), 0.1, 1.0, 2.85)
    assert seg.ambient_trace_c is None and np.all(ambient_of(seg) == 25.0)
    settling = np.linspace(23.0, 25.0, 4000).reshape(fields["Chamber_Temp_degC"].shape)
    fields["Chamber_Temp_degC"] = settling
    path = tmp_path / "settling_Pan18650PF.mat"
    scipy.io.savemat(str(path), {"meas": fields})
    rec = read_record(path)
    assert rec.ambient_c == pytest.approx(settling.ravel())
    assert rec.meta.chamber_temp_c == pytest.approx(24.0, abs=1e-3)
    (seg,) = record_to_segments(rec, 0.1, 1.0, 2.85)
    assert seg.ambient_trace_c is not None and len(seg.ambient_trace_c) == len(seg)
    first = seg.head(100)         # every per-step array cut, the trace included
    assert len(first) == len(first.ambient_trace_c) == len(first.soc_ref) == 100
    assert np.array_equal(first.ambient_trace_c, seg.ambient_trace_c[:100])
    assert ambient_of(seg) == pytest.approx(np.interp(seg.time_s - 0.05, rec.time_s,
                                                      rec.ambient_c), abs=2e-3)
    assert "chamber 24 °C, logged 23.0 … 25.0 °C (the thermal model's ambient)" in (
        format_summary(summarise(rec)))
    # the same record as Battery Data Format: its Ambient Temperature column is that ambient
    bdf = read_record(write_bdf(rec, tmp_path / "settling.bdf.csv"))
    assert bdf.meta.file_columns["ambient_c"] == "Ambient Temperature / degC"
    (same,) = record_to_segments(bdf, 0.1, 1.0, 2.85)
    assert np.array_equal(same.ambient_trace_c, seg.ambient_trace_c)
    assert same.ambient_c == seg.ambient_c
    # without the cell's column the chamber's is the record's temperature, as logged
    alone = dataclasses.replace(rec, temperature_c=None)
    chamber = read_record(write_bdf(alone, tmp_path / "chamber.bdf.csv"))
    assert chamber.temperature_c is None
    assert np.array_equal(chamber.temperature_or_chamber(), rec.ambient_c)
    (own,) = record_to_segments(chamber, 0.1, 1.0, 2.85)
    assert own.temperature_kind == "chamber" and own.ambient_temperature() is None
    assert np.array_equal(own.temperature_c, seg.ambient_trace_c)
    assert np.array_equal(ambient_of(own), seg.ambient_trace_c)
    # and an FMU driven at the record's own samples gets the chamber as logged, either way
    for record in (rec, chamber):
        ((part, first),) = record_parts(record, 0.1, 1.0, 2.85)
        assert np.array_equal(ambient_at_samples(part, first), rec.ambient_c)
    rec.ambient_c = rec.ambient_c + 273.15
    with pytest.raises(DataError, match=r"'Ambient Temperature / degC'.*296\.15.*°C"):
        read_record(write_bdf(rec, tmp_path / "kelvin.bdf.csv"))
    fields["Chamber_Temp_degC"] = np.where(np.arange(4000).reshape(settling.shape) == 9,
                                           np.nan, settling)
    scipy.io.savemat(str(path), {"meas": fields})
    gap = read_record(path)
    assert gap.ambient_c is None and gap.meta.chamber_temp_c == pytest.approx(24.0, abs=1e-3)


def test_a_one_sample_panasonic_file_is_inspected_not_refused(tmp_path, capsys) -> None:
    """The shared Panasonic set holds a one-sample file (03-09-17_15.12_3349_TS002973.mat, a
    tester stub); inspect summarises it and says it is too short, as for a one-row CSV, and
    training refuses it by its current, not by a reader error."""
    from lmncell.cli import main

    meas = scipy.io.loadmat(str(PAN_US06))["meas"][0, 0]
    fields = {k: np.asarray(meas[k])[:1] for k in meas.dtype.names}
    path = tmp_path / "stub_Pan18650PF.mat"
    scipy.io.savemat(str(path), {"meas": fields})
    assert len(read_record(path)) == 1
    assert main(["inspect", str(path)]) == 0
    assert "1 samples, 0.00 h, no sample time (too short to train on or evaluate)" in (
        capsys.readouterr().out)


def _own_csv_with_counter(path, rec, counter_ah, counter_name="Q [mAh]", scale=1e3) -> dict:
    """A record written as a user's ';'-separated, decimal-comma CSV in mA with a charge counter
    column (counter_ah in Ah, written times scale); the mapping that reads it."""
    columns = (rec.time_s, rec.current_a * 1e3, rec.voltage_v, counter_ah * scale)
    path.write_text(f"Time [s];I [mA];U [V];{counter_name}\n" + "".join(
        ";".join(f"{v:.6f}".replace(".", ",") for v in row) + "\n"
        for row in zip(*columns, strict=True)))
    return {"time": "Time [s]", "current": "I [mA]", "voltage": "U [V]",
            "charge": counter_name}


def test_a_csv_charge_counter_keeps_a_gappy_log_in_one_segment(tmp_path, capsys) -> None:
    """A 10 Hz drive cycle whose log lost 4 s under a load of 2.2 A: without a charge counter
    the generic reader cannot tell whether charge was lost there and splits it (two
    segments; the log's own 2-s pauses between schedule steps at −0.07 A, which cannot move
    1 mAh, split nothing); with the tester's net counter mapped as charge=COL it is one
    segment, as the .mat file with its Ah counter is, and the SoC reference counts by the
    counter. The header proposes the column, in mAh from its name."""
    from lmncell.data.soc import charge_throughput_ah

    from tests.conftest import PAN_HWFET

    whole = read_record(PAN_HWFET)
    assert whole.meta.segment_starts == [0] and whole.charge_ah is not None
    keep = np.r_[0:6290, 6330:len(whole)]          # 4 s at −2.18 ± 0.10 A not logged
    rec = dataclasses.replace(whole, **{k: getattr(whole, k)[keep] for k in (
        "time_s", "current_a", "voltage_v", "temperature_c", "charge_ah", "ambient_c")})
    path = tmp_path / "own.csv"
    mapping = _own_csv_with_counter(path, rec, rec.charge_ah)
    without = {k: v for k, v in mapping.items() if k != "charge"}
    split = read_record(path, columns=without, sep=";", decimal=",")
    assert len(split.segments()) == 2 and split.meta.segment_starts[1] == 6290
    assert ("split at 1 gap(s) in time: without the tester's charge counter the reader cannot "
            "tell whether a gap under load (or one of 10 min or more at rest) lost charge; the "
            "column 'Q [mAh]' looks like one (charge=Q [mAh])") in split.meta.notes
    own = read_record(path, columns=mapping, sep=";", decimal=",")
    assert own.meta.segment_starts == [0]
    assert own.charge_ah == pytest.approx(rec.charge_ah, abs=1e-9)
    assert charge_throughput_ah(own)[-1] == pytest.approx(charge_throughput_ah(rec)[-1])
    assert own.meta.file_columns["charge_ah"] == "Q [mAh]"
    assert main(["inspect", str(path)]) == 2
    proposal = ("--columns 'time=Time [s],current=I [mA],voltage=U [V],charge=Q [mAh]' "
                "--delimiter ';' --decimal ,")
    assert proposal in capsys.readouterr().err
    assert main(["inspect", str(path), *shlex.split(proposal)]) == 0
    out = capsys.readouterr().out
    assert "1 segment(s)" in out and "the net charge is the tester's counters'" in out, out
    # in Ah, the option saying so where the name does not
    path.write_text(path.read_text().replace("Q [mAh]", "Q"))
    in_ah = read_record(path, columns={**mapping, "charge": "Q"}, sep=";", decimal=",",
                        charge_unit="mAh")
    assert in_ah.charge_ah == pytest.approx(rec.charge_ah, abs=1e-9)
    # a file that counts discharge positive counts its counter so too: both negated
    flipped = dataclasses.replace(rec, current_a=-rec.current_a)
    mapping = _own_csv_with_counter(path, flipped, -rec.charge_ah)
    back = read_record(path, columns=mapping, sep=";", decimal=",", discharge_positive=True)
    assert back.charge_ah == pytest.approx(rec.charge_ah, abs=1e-9)
    assert not any("negated (LMNCell" in n for n in back.meta.notes)


def test_a_csv_charge_counter_of_another_kind_is_mended_or_refused(tmp_path) -> None:
    """A counter of the opposite sign to the current is negated, and one that restarts from 0
    at each step of the schedule is stitched, each with a note; one that counts discharge only
    where the record also charges is refused naming the column and what the current moves. The
    counters of every shipped record with counters pass unchanged."""
    from lmncell.data.readers import _checked_counter

    from tests.conftest import PAN_HWFET

    rec = read_record(PAN_HWFET).slice(0, 20000)
    path = tmp_path / "own.csv"
    mapping = _own_csv_with_counter(path, rec, -rec.charge_ah)
    own = read_record(path, columns=mapping, sep=";", decimal=",")
    assert own.charge_ah == pytest.approx(rec.charge_ah, abs=1e-9)
    assert any("column 'Q [mAh]' counted charge negative to the current's sign; negated" in n
               for n in own.meta.notes)
    restarted = rec.charge_ah.copy()
    for k in (6000, 12000, 12100):                   # a new step of the schedule starts at 0
        restarted[k:] -= restarted[k - 1]
    _own_csv_with_counter(path, rec, restarted)
    stitched = read_record(path, columns=mapping, sep=";", decimal=",")
    assert stitched.charge_ah == pytest.approx(rec.charge_ah, abs=2e-4)
    t = rec.time_s[6000]
    assert any(f"column 'Q [mAh]' restarts from 0 3 time(s), the first at t = {t:g} s" in n
               for n in stitched.meta.notes), stitched.meta.notes
    _own_csv_with_counter(path, rec, -restarted)          # both: negated, then stitched
    both = read_record(path, columns=mapping, sep=";", decimal=",")
    assert both.charge_ah == pytest.approx(rec.charge_ah, abs=2e-4)
    assert [n.split(";")[0] for n in both.meta.notes[:2]] == [
        "column 'Q [mAh]' counted charge negative to the current's sign",
        f"column 'Q [mAh]' restarts from 0 3 time(s), the first at t = {t:g} s"]
    held = np.concatenate([[0.0], rec.current_a[:-1] * np.diff(rec.time_s) / 3600])
    discharged = np.cumsum(np.minimum(held, 0.0))          # the regeneration not counted
    _own_csv_with_counter(path, rec, discharged)
    with pytest.raises(DataError, match=r"own.csv: column 'Q \[mAh\]' \(charge\) counts "
                                        r"\+0.0000 Ah over the steps where the current charges "
                                        r"\+0.\d+ Ah; expected the tester's net charge counter"):
        read_record(path, columns=mapping, sep=";", decimal=",")
    with pytest.raises(DataError, match=r"charge unit 'Wh'; expected one of \['Ah', 'mAh'\]"):
        read_record(path, columns=mapping, sep=";", decimal=",", charge_unit="Wh")
    for known in (A123_S1, PAN_US06, PAN_HWFET):
        rec = read_record(known)
        counter, notes = _checked_counter(known, "Q", rec.time_s, rec.current_a, rec.charge_ah)
        assert notes == [] and np.array_equal(counter, rec.charge_ah - rec.charge_ah[0])


def test_a_counter_restart_at_a_slow_step_is_stitched_and_a_recharge_in_a_gap_is_kept(
        tmp_path) -> None:
    """A tester that logs a rest more slowly (10 s against 0.1 s) and restarts its counter at
    the rest's first row: before, that step was no regular one and the restart stayed, so the
    record was split there and the counters counted +1 Ah "across the gap", which the SoC
    reference took. A fall to 0 that no current of the record could make over its step is a
    restart; a net counter back at 0 after an hour's gap, in which the cell could have been
    recharged at the record's own current, stays as counted (a gap, two segments)."""
    def record(parts, restart_at=None):
        t, i = [0.0], [0.0]
        for dt, n, amps in parts:
            t += list(t[-1] + dt * np.arange(1, n + 1))
            i += [amps] * n
        t, i = np.array(t), np.array(i)
        counter = np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t)) / 3600])
        logged = counter.copy()
        if restart_at is not None:
            logged[restart_at:] -= logged[restart_at]
        return SimpleNamespace(time_s=t, current_a=i, voltage_v=3.6 + 0.05 * i), counter, logged

    path = tmp_path / "own.csv"
    rec, counter, logged = record([(0.1, 18000, -2.0), (10.0, 30, 0.0), (0.1, 3000, -2.0)],
                                  restart_at=18001)
    mapping = _own_csv_with_counter(path, rec, logged)
    read = read_record(path, columns=mapping, sep=";", decimal=",")
    assert read.charge_ah == pytest.approx(counter, abs=1e-6)
    assert read.meta.segment_starts == [0]
    assert any("restarts from 0 1 time(s), the first at t = 1810 s" in n
               and "1 of them at a step longer than the log's" in n
               for n in read.meta.notes), read.meta.notes
    # an hour without rows, the cell recharged in it: the counter back near 0 stays as counted
    rec, counter, _ = record([(0.1, 6000, -2.0), (3600.0, 1, 0.0), (0.1, 100, 0.0)])
    back = counter.copy()
    back[6001:] = counter[6001:] - counter[6001] - 1e-4
    _own_csv_with_counter(path, rec, back)
    kept = read_record(path, columns=mapping, sep=";", decimal=",")
    assert kept.charge_ah == pytest.approx(back, abs=1e-6)
    assert kept.meta.segment_starts == [0, 6001]
    assert not any("restarts" in n for n in kept.meta.notes), kept.meta.notes


def test_ones_own_csv_with_every_column_trains_the_model_of_the_known_format(tmp_path) -> None:
    """A record written as a user's CSV with its cell and chamber temperatures and the tester's
    charge counter mapped (temperature=, ambient=, charge=) trains, bit for bit, the model that
    the same record in a known format (Battery Data Format, with those columns) trains: the
    generic reader leaves nothing behind. Measured on the full HWFET and US06 .mat records
    against CSVs of them too (November 2026)."""
    from lmncell.identification.train import train_files

    from tests.conftest import PAN_HWFET

    rec = read_record(PAN_HWFET)
    (tmp_path / "bdf").mkdir()
    (tmp_path / "own").mkdir()
    known = write_bdf(rec, tmp_path / "bdf" / "hwfet.csv")     # one name: the model names it
    own = tmp_path / "own" / "hwfet.csv"
    columns = (rec.time_s, rec.current_a, rec.voltage_v, rec.temperature_c, rec.ambient_c,
               rec.charge_ah)
    own.write_text("t [s],I [A],U [V],T cell,T chamber,Ah\n" + "".join(
        ",".join(repr(float(v)) for v in row) + "\n" for row in zip(*columns, strict=True)))
    mapping = {"time": "t [s]", "current": "I [A]", "voltage": "U [V]",
               "temperature": "T cell", "ambient": "T chamber", "charge": "Ah"}
    settings = {"max_local_models": 2, "sample_time_s": 1.0}

    def model(path, **read):
        out = path.with_suffix(".json")
        train_files([path], out, capacity_ah=2.85, soc0=1.0, progress=lambda _m: None,
                    read_options=read, **settings)
        data = json.loads(out.read_text())     # all but the files' paths and the timings
        data["training"] = {k: data["training"][k] for k in ("capacity_ah", "curve",
                                                             "train_metrics", "thermal")}
        return data

    assert model(own, columns=mapping) == model(known)


def test_an_arbin_file_whose_capacities_restart_at_each_cycle_keeps_one_charge_count(
        tmp_path) -> None:
    """Arbin's Charge_Capacity and Discharge_Capacity restart at 0 with each cycle. The net
    counter jumped back there, and the SoC reference with it (a C/30 discharge that restarts
    half way read 1 Ah short at its end, silently); now the restart is stitched, with a note,
    as the generic reader's charge=COL is."""
    path = DATA / "a123_plett/ocv/A123_OCV_P25_S1.csv.gz"
    with gzip.open(path, "rt") as fh:
        lines = fh.read().splitlines()
    names = lines[0].split(",")
    chg, dis, cyc = (names.index(n) for n in ("Charge_Capacity(Ah)", "Discharge_Capacity(Ah)",
                                               "Cycle_Index"))
    half = len(lines) // 2
    at_half = [float(lines[half - 1].split(",")[k]) for k in (chg, dis)]
    rows = [lines[0]]
    for k, line in enumerate(lines[1:], start=1):
        cells = line.split(",")
        if k >= half:                            # the second cycle counts from 0
            cells[cyc] = "2"
            for col, start in zip((chg, dis), at_half, strict=True):
                cells[col] = repr(float(cells[col]) - start)
        rows.append(",".join(cells))
    restarted = tmp_path / "A123_OCV_P25_S1.csv"
    restarted.write_text("\n".join(rows) + "\n")
    original, rec = read_record(path), read_record(restarted)
    assert rec.meta.fmt == "arbin"
    assert rec.charge_ah[-1] == pytest.approx(original.charge_ah[-1], abs=1e-3)
    assert original.charge_ah[-1] < -2.0
    assert any("restarts from 0 1 time(s)" in n for n in rec.meta.notes), rec.meta.notes
    assert not any("restarts" in n for n in original.meta.notes)


def _arbin_with_temperatures(tmp_path, spaces: bool, channels: dict[str, np.ndarray],
                             name: str = "A123_OCV_P25_S1.csv"):
    """The A123 C/30 Arbin export with the given temperature columns added (blank where a
    value is NaN), its names written with spaces (MITS Pro's newer export) or as they are."""
    with gzip.open(DATA / "a123_plett/ocv/A123_OCV_P25_S1.csv.gz", "rt") as fh:
        lines = fh.read().splitlines()
    header = lines[0]
    if spaces:
        header = re.sub(r"_(?=[A-Z])", " ", header).replace("(", " (")
    rows = [",".join([header, *channels])]
    for k, line in enumerate(lines[1:]):
        rows.append(",".join([line, *("" if np.isnan(v[k]) else f"{v[k]:.2f}"
                                      for v in channels.values())]))
    path = tmp_path / name
    path.write_text("\n".join(rows) + "\n")
    return path


def test_an_arbin_export_gives_its_cell_temperature_in_either_spelling(tmp_path) -> None:
    """The Arbin reader knew only the names with underscores and left every temperature column
    out without a word: a MITS Pro export with spaces ("Test Time (s)") was "unknown format",
    and a thermocouple on auxiliary channel 1 never reached the model (no thermal model, the
    chamber's temperature from the file name instead). Now either spelling is Arbin, channel 1
    is the cell's temperature (a channel read every few rows holds its readings), and the
    other channels are named as not read."""
    n = len(read_record(DATA / "a123_plett/ocv/A123_OCV_P25_S1.csv.gz"))
    cell = 25.0 + np.linspace(0.0, 3.0, n)
    cell[1::2] = np.nan                                 # read every other row
    chamber = np.full(n, 24.5)
    records = []
    for spaces, (one, two) in ((True, ("Aux_Temperature_1 (C)", "Aux_Temperature_2 (C)")),
                               (False, ("Aux_Temperature(°C)_1", "Aux_Temperature(°C)_2"))):
        folder = tmp_path / ("spaces" if spaces else "underscores")
        folder.mkdir()
        path = _arbin_with_temperatures(folder, spaces, {two: chamber, one: cell})
        assert detect_format(path) == "arbin"
        rec = read_record(path)
        assert rec.meta.file_columns["temperature_c"] == one
        assert any(f"['{two}'] not read" in note for note in rec.meta.notes), rec.meta.notes
        assert any("blank between readings" in note for note in rec.meta.notes)
        records.append(rec)
    held = np.round(cell[np.arange(n) // 2 * 2], 2)
    for rec in records:
        np.testing.assert_array_equal(rec.temperature_c, held)
    np.testing.assert_array_equal(records[0].voltage_v, records[1].voltage_v)
    np.testing.assert_array_equal(records[0].charge_ah, records[1].charge_ah)
    assert "Test Time (s)" in records[0].meta.file_columns["time_s"]


def test_an_arbin_channel_that_reads_zero_throughout_is_not_a_cell_temperature(
        tmp_path) -> None:
    n = len(read_record(DATA / "a123_plett/ocv/A123_OCV_P25_S1.csv.gz"))
    rec = read_record(_arbin_with_temperatures(tmp_path, False,
                                               {"Aux_Temperature_1(C)": np.zeros(n)}))
    assert rec.temperature_c is None
    assert any("reads 0 throughout" in note for note in rec.meta.notes), rec.meta.notes
    blank = read_record(_arbin_with_temperatures(tmp_path, False,
                                                 {"Aux_Temperature_1(C)": np.full(n, np.nan)},
                                                 name="blank.csv"))
    assert blank.temperature_c is None
    assert any("'Aux_Temperature_1(C)' has no reading" in note for note in blank.meta.notes)
    far = read_record(_arbin_with_temperatures(tmp_path, False,
                                               {"Aux_Temperature_1(F)": np.full(n, 77.0)},
                                               name="f.csv"))
    assert far.temperature_c is None
    assert any("unit is not °C" in note for note in far.meta.notes), far.meta.notes


def _maccor_csv(tmp_path, states: tuple[str, str, str] = ("C", "D", "R"),
                name: str = "maccor.csv") -> tuple:
    """The A123 25 °C record as a Maccor-like export: the current's magnitude in Amps and its
    direction in State (charge, discharge, rest as the words given)."""
    rec = read_record(A123_S1)
    i = np.round(rec.current_a, 4)
    state = np.where(i > 0, states[0], np.where(i < 0, states[1], states[2]))
    rows = ["Rec#,Cyc#,Step,Test (Sec),Step (Sec),Amp-hr,Watt-hr,Amps,Volts,State,ES"]
    rows += [f"{k + 1},0,1,{t:.3f},0,0,0,{abs(c):.4f},{v:.4f},{s},0"
             for k, (t, c, v, s) in enumerate(zip(rec.time_s, i, rec.voltage_v, state,
                                                  strict=True))]
    path = tmp_path / name
    path.write_text("\n".join(rows) + "\n")
    return path, i


MACCOR = {"time": "Test (Sec)", "current": "Amps", "voltage": "Volts"}


@pytest.mark.parametrize("states", [("C", "D", "R"), ("CCCV_Chg", "CC_DChg", "Rest"),
                                    ("CHA", "DCH", "PAU")])
def test_a_current_logged_as_its_magnitude_is_signed_by_its_state_column(tmp_path,
                                                                          states) -> None:
    """Maccor logs the current's magnitude (Amps) and its direction in State. Read by its
    named columns, every discharge was a charge: the record charged 8.7 Ah into a 2.3-Ah cell,
    said nothing while reading, and training's error then asked for --discharge-positive,
    which would have made every charge a discharge. Now state=COL signs the current (Maccor's,
    Neware's and Digatron's words), and a current that never goes below 0 while the voltage
    falls at its rises is warned of."""
    path, signed = _maccor_csv(tmp_path, states)
    rec = read_record(path, columns={**MACCOR, "state": "State"})
    np.testing.assert_array_equal(rec.current_a, signed)
    assert "signed by the column 'State'" in rec.meta.sign_note
    assert rec.current_a.min() < -5 and rec.current_a.max() > 5
    with pytest.warns(DataWarning, match=r"never goes below 0 .* state=COL"):
        read_record(path, columns=MACCOR)


def test_a_state_column_is_refused_where_its_words_or_the_options_do_not_fit(tmp_path) -> None:
    path, _ = _maccor_csv(tmp_path, ("C", "D", "X"))
    with pytest.raises(DataError, match=r"column 'State' line 2: 'X' names no charge, "
                                        r"discharge or rest; expected a state such as C, D, R"):
        read_record(path, columns={**MACCOR, "state": "State"})
    good, _ = _maccor_csv(tmp_path, name="good.csv")
    with pytest.raises(DataError, match=r"--discharge-positive .* with the state column 'State'"):
        read_record(good, columns={**MACCOR, "state": "State"}, discharge_positive=True)
    with pytest.raises(DataError, match=r"perhaps: --columns 'time=Test \(Sec\),current=Amps,"
                                        r"voltage=Volts,state=State'"):
        read_record(good)


def test_a_column_mapping_with_keys_of_its_own_is_refused_with_the_keys_meant(tmp_path) -> None:
    """A mapping key written as many write it (i=, temp=, Status=) was refused with the list of
    keys only, and after the missing 'current' first; now the unknown keys are named first,
    each with the key it stands for where it is a common way of writing one."""
    path = tmp_path / "own.csv"
    path.write_text("t,I,U,T1,State\n0,0,3.3,25,R\n1,-1,3.2,25,D\n")
    with pytest.raises(DataError, match=r"the column mapping names \['Status', 'i', 'temp'\]; "
                                        r"expected keys among \[.*\] \(Status= is state=; i= is "
                                        r"current=; temp= is temperature=\?\)"):
        read_record(path, columns={"time": "t", "i": "I", "voltage": "U", "temp": "T1",
                                   "Status": "State"})
    with pytest.raises(DataError, match=r"the column mapping names \['x'\]; expected keys "
                                        r"among \[[^]]*\]$"):
        read_record(path, columns={"time": "t", "current": "I", "voltage": "U", "x": "T1"})
    with pytest.raises(DataError, match=r"the column mapping lacks 'current'"):
        read_record(path, columns={"time": "t", "voltage": "U"})


def test_a_time_column_in_days_is_warned_of_and_read_with_its_unit(tmp_path) -> None:
    """A time column of a spreadsheet's date numbers (days) was read in s without a word: a
    10-h record of 11.6-µs steps, which training then refused as too short. A median step
    below 1 ms is now warned of, and --time-unit d (time_unit="d") reads it."""
    path = tmp_path / "days.csv"
    t = np.arange(600.0)
    path.write_text("Time,Current,Voltage\n" + "".join(
        f"{45000 + s / 86400:.10f},{-1.0 if s % 120 < 60 else 0.0},{3.3 - 0.01 * (s % 120 < 60)}\n"
        for s in t))
    mapping = {"time": "Time", "current": "Current", "voltage": "Voltage"}
    with pytest.warns(DataWarning, match=r"the time steps by 1.16e-05 s \(median\); .* "
                                         r"\(--time-unit min\|h\|d, time_unit=\)"):
        read_record(path, columns=mapping)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        rec = read_record(path, columns=mapping, time_unit="d")
    np.testing.assert_allclose(rec.time_s, t, atol=2e-5)
