"""Which columns of an unknown table's header look like time, current, voltage, temperature, the
ambient beside it, a net charge counter and the current's direction: the reader's options that
would read it, proposed in the unknown-format error. Only proposed, never applied: the sign of
the current and the columns are the user's to confirm."""

from __future__ import annotations

import re
import shlex

DELIMITERS = ((",", None), (";", "';'"), ("\t", "tab"))   # (delimiter, its --delimiter value)
DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+$")
TIME_NAMES = {"time", "t", "test time", "total time", "elapsed time", "run time",
              "relative time", "time s", "testtime", "seconds",
              "test",                                  # Maccor's "Test (Sec)"
              "~time"}                                 # BaSyTec's "~Time[h]"
# the clocks that run through a whole test, preferred over a plain "Time" beside them (Neware's
# "Time" is the step's, its "Total Time" the test's)
RUNNING_TIME_NAMES = {"test time", "total time", "elapsed time", "run time", "testtime", "test",
                      "~time"}                        # BaSyTec's "~Time[h]" beside its clock "Time"
CURRENT_NAMES = {"current", "i", "curr", "cell current", "battery current", "amps", "amp",
                 "current a", "i a"}
VOLTAGE_NAMES = {"voltage", "u", "v", "volt", "volts", "cell voltage", "battery voltage",
                 "terminal voltage", "ecell", "e cell", "u cell", "ucell", "v cell", "vcell"}
CELL_WORDS = ("cell", "battery", "surface", "case", "t1")   # a cell's, not the chamber's
AMBIENT_WORDS = ("ambient", "amb", "chamber", "environment", "env", "room", "air")
# a net charge counter's names (a cycler's per-step "Capacity" or separate charge and discharge
# counters are not proposed); "Q" only with a charge unit, such as 'Q [mAh]'
# a column of the current's direction beside its magnitude (Maccor's "State": C, D, R)
STATE_NAMES = {"state", "md"}
NET_CHARGE_NAMES = {"ah", "net ah", "q qo", "(q qo)", "ahaccu", "ah accu", "net charge",
                    "net capacity", "charge counter"}


def suggested_options(header: str, first_row: str | None) -> str | None:
    """The CLI options that read a table with this header line (and this first data row, which
    tells a decimal comma), e.g. "--columns 'time=Time [s],current=I [mA],voltage=U [V]'
    --delimiter ';' --decimal ,"; None where the time, current or voltage column is missing
    or not the only candidate."""
    sep, shown = max(DELIMITERS, key=lambda d: header.count(d[0]))
    names = [n.strip().strip('"').strip() for n in header.split(sep)]
    cells = [] if first_row is None else [c.strip().strip('"') for c in first_row.split(sep)]
    picks = _picks(names)
    if picks is None or any("," in n or "=" in n for n in picks.values()):
        return None                                   # not expressible as --columns
    if "state" in picks and not _is_word(dict(zip(names, cells, strict=False)).get(
            picks["state"], "")):                     # a numeric state (BaSyTec's) is no direction
        del picks["state"]
    options = ["--columns " + shlex.quote(",".join(f"{k}={v}" for k, v in picks.items()))]
    if shown is not None:
        options.append(f"--delimiter {shown}")
    if sep != "," and any(DECIMAL_COMMA.match(c) for c in cells):
        options.append("--decimal ,")
    return " ".join(options)


def _is_word(cell: str) -> bool:
    """Whether a cell is a word such as a state column's C, D, R or CC_DChg (not a number)."""
    return bool(re.fullmatch(r"[A-Za-z][A-Za-z _\-]*", cell.strip()))


def _picks(names: list[str]) -> dict[str, str] | None:
    """{quantity: column name} for time, current, voltage (each the only candidate, else None),
    temperature (where one column, or one cell temperature among several, names it),
    ambient (beside that, one chamber temperature: AMBIENT_WORDS), charge (one net charge
    counter: is_net_charge) and state (one column of the current's direction: STATE_NAMES;
    suggested_options keeps it only where the first data row holds a word there)."""
    bases = {name: _base(name) for name in names}
    picks: dict[str, str] = {}
    for what, exact, word in (("time", TIME_NAMES, "time"), ("current", CURRENT_NAMES, "current"),
                              ("voltage", VOLTAGE_NAMES, "voltage")):
        found = ([n for n, b in bases.items() if b in exact]
                 or [n for n, b in bases.items() if word in b.split()
                     and not ({"step", "cycle", "date", "limit", "set"} & set(b.split()))])
        if len(found) > 1:                             # 'time' before 't', 'voltage' before 'v'
            found = [n for n in found if len(bases[n]) > 1]
        if len(found) > 1 and what == "time":          # the test's clock before a step's
            found = [n for n in found if bases[n] in RUNNING_TIME_NAMES] or found
        if len(found) != 1:
            return None
        picks[what] = found[0]
    temps = [n for n, b in bases.items() if n not in picks.values()
             and ("temp" in b or b.startswith("t ") or b in ("t1", "tcell")
                  or _is_ambient(b))]
    cells = [n for n in temps if any(w in bases[n] for w in CELL_WORDS)]
    chosen = temps if len(temps) == 1 else cells
    if len(chosen) == 1:
        picks["temperature"] = chosen[0]
        ambient = [n for n in temps if n != chosen[0] and _is_ambient(bases[n])]
        if len(ambient) == 1:
            picks["ambient"] = ambient[0]
    charges = [n for n in names if n not in picks.values() and is_net_charge(n)]
    if len(charges) == 1:
        picks["charge"] = charges[0]
    states = [n for n, b in bases.items() if b in STATE_NAMES]
    if len(states) == 1:
        picks["state"] = states[0]
    return picks


def is_net_charge(name: str) -> bool:
    """Whether a column names a net charge counter: NET_CHARGE_NAMES, or 'Q' with a charge
    unit ('Q [mAh]')."""
    from lmncell.data.readers import UNIT_WORDS, split_unit

    base = _base(name)
    return base in NET_CHARGE_NAMES or (
        base == "q" and split_unit(name)[1].lower() in UNIT_WORDS["charge"])


def _is_ambient(base: str) -> bool:
    """Whether a column's base name (_base) names a chamber's temperature: 'T_ambient',
    'Chamber Temp', 'Tamb'."""
    words = {w[1:] if w.startswith("t") and w[1:] in AMBIENT_WORDS else w for w in base.split()}
    return bool(words & set(AMBIENT_WORDS))


def _base(name: str) -> str:
    """A column name without its unit (lmncell.data.readers.split_unit), in lower case, with
    '_', '-' and '.' as spaces: 'Test_Time(s)' → 'test time'."""
    from lmncell.data.readers import split_unit

    return " ".join(re.sub(r"[_\-.]", " ", split_unit(name)[0]).lower().split())
