"""The `lmncell` command line: each sub-command parses its arguments and calls one function."""

from __future__ import annotations

import argparse
import codecs
import os
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lmncell import __version__
from lmncell.config import (
    LOCAL_MODELS_PER_REGION,
    ConfigError,
    output_file_problem,
    parse_setting,
)
from lmncell.data.records import CELL_TEMPERATURE_RANGE_C, DataError, is_cell_temperature
from lmncell.design import DESIGN_METHODS, INFORMATION_KINDS, VIRTUAL_CELLS
from lmncell.fmu.interface import NativeBuildError
from lmncell.progress import Progress, print_progress, print_progress_stderr
from lmncell.runtime.cosim import InputError
from lmncell.runtime.model import (
    CAPACITY_RANGE_AH,
    VOLTAGE_RANGE_V,
    ModelFileError,
    is_cell_capacity,
)
from lmncell.scenarios.drive import CUTOFF_EXPECTED, is_cutoff
from lmncell.scenarios.traces import cycle_problem

USER_ERRORS = (DataError, ModelFileError, ConfigError, InputError, FileNotFoundError,
               IsADirectoryError, PermissionError, NativeBuildError)


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Shows an option's default where it has one (not for flags and unset options)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (action.default not in (None, False, [], argparse.SUPPRESS) and "default" not in text
                and action.option_strings):
            text += " (default: %(default)s)"
        return text


def number_argument(cast: type, ok, expected: str):
    """An argparse type: text → cast(text), refused with `expected` unless ok(value)."""
    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {expected}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {expected}")
        return value
    return parse


def input_file_argument(text: str) -> str:
    """An argparse type for a file to read: refused at once (not after a training) where it
    does not exist or is a folder."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(
            f"{text!r}: {'is a folder' if path.is_dir() else 'no such file'}; expected a file")
    return text


def output_file_argument(text: str) -> str:
    """An argparse type for a file to write: refused at once (not after a training) where its
    folder does not exist or the path is a folder (config.output_file_problem)."""
    problem = output_file_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(f"{text!r}: {problem}")
    return text


def figure_file_argument(text: str) -> str:
    """output_file_argument for a figure: a name without a suffix gets .png (what matplotlib
    writes it as); any other suffix must be a format matplotlib writes (.png, .pdf, .svg, …)."""
    suffix = Path(text).suffix.lower().lstrip(".")
    if not suffix:
        text += ".png"
    else:
        from matplotlib.figure import Figure

        formats = Figure().canvas.get_supported_filetypes()
        if suffix not in formats:
            raise argparse.ArgumentTypeError(
                f"{text!r}: a figure's file name ends in one of "
                f"{', '.join('.' + f for f in sorted(formats))} (.png where it has none)")
    return output_file_argument(text)


def fmu_file_argument(text: str) -> str:
    """output_file_argument for an FMU, whose name the builders accept (fmu.interface.fmu_path:
    it must end in .fmu)."""
    from lmncell.fmu.interface import fmu_path

    try:
        fmu_path(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: an FMU's file name must end in .fmu"
                                         ) from None
    return output_file_argument(text)


def cycle_argument(text: str) -> str:
    """An argparse type for a drive cycle: a shipped cycle's name or a speed-trace file (its
    content is checked when it is read)."""
    problem = cycle_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(f"{text!r}: {problem}")
    return text


def output_folder_argument(text: str) -> str:
    """An argparse type for a folder to write into (made where missing, parents too): refused
    at once (not after the work) where the path exists and is not a folder."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: is a file; expected a folder (it is made "
                                         "where it does not exist)")
    return text


# argparse types the examples share with the commands
soc_argument = number_argument(float, lambda v: 0.0 <= v <= 1.0, "a SoC fraction within 0…1")
capacity_argument = number_argument(
    float, is_cell_capacity, "a cell capacity in Ah within {:g}…{:g}".format(*CAPACITY_RANGE_AH))

_positive = number_argument(float, lambda v: v > 0, "a number > 0")
_cell_voltage = number_argument(
    float, lambda v: VOLTAGE_RANGE_V[0] <= v <= VOLTAGE_RANGE_V[1],
    "a cell voltage in V within {:g}…{:g}".format(*VOLTAGE_RANGE_V))
_positive_int = number_argument(int, lambda v: v >= 1, "a whole number ≥ 1")
_cutoff = number_argument(float, is_cutoff, CUTOFF_EXPECTED)
_temperature = number_argument(
    float, is_cell_temperature,
    "a cell temperature in °C within {:g}…{:g} (not K)".format(*CELL_TEMPERATURE_RANGE_C))
_ambient = number_argument(
    float, is_cell_temperature,
    "an ambient temperature in °C within {:g}…{:g} (not K)".format(*CELL_TEMPERATURE_RANGE_C))


def capacity_or_auto_argument(text: str) -> float | None:
    """capacity_argument, or 'auto' → None (the capacity estimated by the training)."""
    if text == "auto":
        return None
    try:
        return capacity_argument(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} or 'auto' (estimated by the training)"
                                         ) from None


def soc_list_argument(text: str) -> list[float]:
    """An argparse type: F or F,F,… → start SoCs within 0…1 (one for all files, or one per
    file in order)."""
    return [soc_argument(part.strip()) for part in text.split(",")]


def _columns(text: str) -> dict[str, str]:
    """time=COL,current=COL,voltage=COL[,temperature=COL][,ambient=COL][,charge=COL]
    [,state=COL] → {quantity: column name}."""
    out: dict[str, str] = {}
    for part in text.split(","):
        key, sep, col = part.partition("=")
        if not sep or not key.strip() or not col.strip():
            raise argparse.ArgumentTypeError(
                f"{text!r}: expected time=COL,current=COL,voltage=COL[,temperature=COL]"
                f"[,ambient=COL][,charge=COL][,state=COL] "
                f"(item {part!r} is not QUANTITY=COLUMN)")
        out[key.strip()] = col.strip()
    return out


def _delimiter(text: str | None) -> str | None:
    """The delimiter option: one character, or the words tab / \\t for a tab."""
    return "\t" if text in ("tab", "\\t", "TAB") else text


def read_options(a: argparse.Namespace) -> dict[str, Any]:
    """The reader options of the command line, for lmncell.data.readers.read_record."""
    extra = {"discharge_positive": a.discharge_positive or None,
             "current_unit": a.current_unit, "time_unit": a.time_unit,
             "voltage_unit": a.voltage_unit, "temperature_unit": a.temperature_unit,
             "charge_unit": a.charge_unit, "sep": _delimiter(a.delimiter), "decimal": a.decimal}
    given = {k: v for k, v in extra.items() if v is not None}
    if a.columns is None:
        if given:
            flags = {"discharge_positive": "--discharge-positive",
                     "current_unit": "--current-unit", "time_unit": "--time-unit",
                     "voltage_unit": "--voltage-unit", "temperature_unit": "--temperature-unit",
                     "charge_unit": "--charge-unit", "sep": "--delimiter",
                     "decimal": "--decimal"}
            verb = "needs" if len(given) == 1 else "need"
            raise ConfigError(f"{', '.join(flags[k] for k in given)} {verb} --columns "
                              "time=COL,current=COL,voltage=COL (the generic CSV reader); the "
                              "known formats are read without them")
        return {}
    return {"columns": a.columns, **given}


def cmd_inspect(a: argparse.Namespace) -> int:
    from lmncell.data.summary import inspect_files

    inspect_files(a.files, a.plot, a.capacity, read_options(a))
    return 0


def cmd_train(a: argparse.Namespace) -> int:
    from lmncell.identification.train import train_files

    if not a.data:
        raise ConfigError(missing_data_message(a.ocv_tests))
    settings: dict[str, Any] = dict(parse_setting(s) for s in a.set)
    for key, value in (("max_local_models", a.max_local_models), ("ocv_tests", a.ocv_tests),
                       ("partition", a.partition.split(",") if a.partition else None)):
        if value is not None:
            settings[key] = value
    partition = settings.pop("partition", None)
    train_files(a.data, a.out, a.capacity, a.soc0, partition, a.baselines, a.config,
                read_options=read_options(a), **settings)
    return 0


def missing_data_message(ocv_tests: list[str] | None) -> str:
    """What to say where `lmncell train` got no data files: where --ocv-tests came before
    them, it took them all as OCV tests (argparse gives an option of several values every
    name after it)."""
    if ocv_tests and len(ocv_tests) > 1:
        return (f"no training data files: --ocv-tests took every file after it as an OCV test "
                f"({', '.join(ocv_tests)}); give the data files before --ocv-tests (lmncell "
                "train DATA... --out MODEL.json --ocv-tests TEST...) or end its list with --")
    return "no training data files given (lmncell train DATA... --out MODEL.json)"


THROUGH_PAUSES_HELP = ("do not split records at pauses that only the wall clock shows (the "
                       "Panasonic TimeStamp): drive the model through them as a host does that "
                       "feeds the FMU the record's time column (default: split, the next "
                       "segment starts rested)")
HOLD_OUT_HELP = ("hold out only records whose name contains PATTERN, or one of a comma list; "
                 "a pattern A+B matches a name that contains A or B (with --together: "
                 "'Cycle_1+US06,Cycle_1+HWFT' holds out two records at a time)")
TOGETHER_HELP = ("hold out the records of each --hold-out pattern at once, trained on the "
                 "records it does not match (--hold-out 10degC --together: leave one "
                 "temperature out)")


def cmd_evaluate(a: argparse.Namespace) -> int:
    if a.observer:
        from lmncell.evaluation.observe import evaluate_observer_files

        if a.soc0_est is None:
            raise ConfigError("--observer needs --soc0-est (the estimator's start guess)")
        unused = [flag for flag, given in (("--ambient", a.ambient), ("--trace", a.trace),
                                           ("--at-model-steps", a.at_model_steps)) if given]
        if unused:
            raise ConfigError(f"{', '.join(unused)} with --observer: the observer runs on the "
                              "measured cell temperature and voltage, and reports SoC figures "
                              "(--json, --plot); leave out " + ", ".join(unused))
        if a.model.lower().endswith(".fmu"):
            from lmncell.evaluation.fmueval import evaluate_fmu_observer_files

            evaluate_fmu_observer_files(a.model, a.data, a.observer, a.soc0, a.soc0_est,
                                        a.start_soc, a.plot, a.json,
                                        read_options=read_options(a),
                                        through_hidden_pauses=a.through_hidden_pauses,
                                        progress=_progress(a))
            return 0
        evaluate_observer_files(a.model, a.data, a.observer, a.soc0, a.soc0_est, a.start_soc,
                                a.plot, a.json, read_options=read_options(a),
                                through_hidden_pauses=a.through_hidden_pauses)
        return 0
    observer_only = [flag for flag, value in (("--soc0-est", a.soc0_est),
                                              ("--start-soc", a.start_soc)) if value is not None]
    if observer_only:
        raise ConfigError(f"{', '.join(observer_only)} without --observer: they set up a SoC "
                          "observer's run (its start guess, where it starts); give --observer "
                          "ekf|fuzzy|imm to judge one, or leave them out to judge the voltage")
    if a.model.lower().endswith(".fmu"):
        from lmncell.evaluation.fmueval import evaluate_fmu_files

        evaluate_fmu_files(a.model, a.data, a.soc0, a.plot, a.trace, a.json,
                           progress=_progress(a), ambient=a.ambient,
                           read_options=read_options(a),
                           through_hidden_pauses=a.through_hidden_pauses,
                           at_model_steps=a.at_model_steps)
        return 0
    if a.at_model_steps:
        raise ConfigError(f"--at-model-steps steps an FMU (.fmu) at Ts with mean inputs, as a "
                          f"host may; {a.model} is a model file, which is evaluated on the "
                          "record's exact means over each model step")
    from lmncell.evaluation.evaluate import evaluate_files

    evaluate_files(a.model, a.data, a.soc0, a.plot, a.trace, a.json, progress=_progress(a),
                   read_options=read_options(a), ambient=a.ambient,
                   through_hidden_pauses=a.through_hidden_pauses)
    return 0


def _progress(a: argparse.Namespace) -> Progress:
    """Where evaluate's progress lines go: stderr with --json (stdout is the JSON), else
    stdout with the table."""
    return print_progress_stderr if a.json else print_progress


def cmd_explain(a: argparse.Namespace) -> int:
    from lmncell.evaluation.interpret import explain

    print(explain(a.model, a.temperature, a.json))
    return 0


def cmd_build_fmu(a: argparse.Namespace) -> int:
    from lmncell.evaluation.fmueval import model_file_of

    if a.platforms is not None and not a.native:
        raise NativeBuildError("--platforms: the pythonfmu FMU is built for this machine's "
                               "platform only; expected --native with --platforms")
    with model_file_of(a.model) as model:
        if a.native:
            from lmncell.fmu.native_build import build_native_fmu

            path = build_native_fmu(model, a.out, platforms=a.platforms if a.platforms is not None
                                    else ["linux64"], progress=lambda m: print(m, flush=True))
        else:
            from lmncell.fmu.pythonfmu_build import build_fmu, native_host_hint

            path = build_fmu(model, a.out)
            if hint := native_host_hint(path):
                print(hint)
    print(f"wrote {path}")
    return 0


def _stops_summary(stops) -> str:
    """The sweep's line on runs that stopped early (its column `stop`, drive.stop_kind): how
    many with a cell empty, full, or refused by the FMU; '' where none did."""
    from lmncell.scenarios.drive import stop_kind

    kinds = [stop_kind(stop) for stop in stops]
    words = {"empty": "with a cell empty", "full": "with a cell full",
             "error": "refused by the FMU (its message in stop)"}
    counts = [(kinds.count(kind), what) for kind, what in words.items()]
    total = sum(n for n, _ in counts)
    if not total:
        return ""
    return (f"{total} scenario(s) stopped early: "
            + ", ".join(f"{n} {what}" for n, what in counts if n)
            + " (columns stop, stopped_at_s); --cutoff sets the cut-off voltage\n")


def _range_summary(out_of_range_steps, ambient_c) -> str:
    """The sweep's line on scenarios whose FMU flagged out_of_range in some step (the model
    extrapolated its training data): how many, at which ambient temperatures (°C); '' where
    none did."""
    left = [t for n, t in zip(out_of_range_steps, ambient_c, strict=True) if n > 0]
    if not left:
        return ""
    ambients = ", ".join(f"{t:g}" for t in sorted(set(left)))
    return (f"warning: {len(left)} of {len(out_of_range_steps)} scenario(s) left the model's "
            "trained range (current, SoC, temperature or its voltage) in some step, at ambient "
            f"{ambients} °C (column out_of_range_steps): their figures are extrapolated\n")


def cmd_simulate(a: argparse.Namespace) -> int:
    from lmncell.scenarios.drive import simulate_cycle_cli

    if a.current and a.vehicle:
        raise ConfigError("--vehicle with --current: a current profile drives the cell itself, "
                          "no vehicle; give one or the other")
    for option, given in (("--discharge-positive", a.discharge_positive),
                          ("--charge-cutoff", a.charge_cutoff is not None)):
        if given and not a.current:
            raise ConfigError(f"{option} is for a --current profile; a drive cycle's current "
                              "comes from the vehicle model")
    a.cycle = a.cycle or "wltc"
    return simulate_cycle_cli(a)


def _floats(option: str):
    def parse(text: str) -> list[float]:
        try:
            return [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{option} {text!r}: expected comma-separated "
                                             "numbers") from None
    return parse


def cmd_sweep(a: argparse.Namespace) -> int:
    from lmncell.scenarios.sweep import (
        check_sweep,
        check_table_path,
        plot_sweep,
        require_sweep_extra,
        scenarios,
        sweep,
        write_table,
    )

    require_sweep_extra()
    check_table_path(a.out)
    cases = scenarios(a.cycles, a.ambient, a.soc0, a.vehicle or [None], a.repeat,
                      a.pack, a.spread, a.seed, a.cells, a.cutoff, a.cell_temperature_start)
    check_sweep(a.fmu, cases, a.workers)
    print(f"sweep: {len(cases)} scenario(s) on "
          + (f"the scheduler {a.scheduler}" if a.scheduler else
             f"a LocalCluster of {a.workers or 'all'} worker(s)")
          + ("" if a.cell_temperature_start is None else
             f", cells from {a.cell_temperature_start:g} °C at the start"), flush=True)
    table = sweep(a.fmu, cases, a.workers, a.scheduler)
    write_table(table, a.out)
    print(f"wrote {a.out}: {len(table)} rows; minimum cell voltage "
          f"{table['voltage_min_v'].min():.3f} V, end SoC {table['soc_end'].min():.3f}…"
          f"{table['soc_end'].max():.3f}, {table['wall_s'].sum():.1f} s of FMU runs")
    print(_stops_summary(table["stop"]), end="")
    print(_range_summary(table["out_of_range_steps"], table["ambient_c"]), end="")
    if a.plot:
        for f in plot_sweep(table, a.plot):
            print(f"plot: {f}")
    return 0


def cmd_design(a: argparse.Namespace) -> int:
    from lmncell.design.command import run_design

    return run_design(a)


def cmd_demo(a: argparse.Namespace) -> int:
    from lmncell.report.demo import run_demo

    run_demo(Path(a.out))
    return 0


def _add_reader_options(s: argparse.ArgumentParser) -> None:
    g = s.add_argument_group("your own CSV files (generic reader; the known formats — Plett, "
                             "Arbin, Panasonic .mat, BDF, BioLogic .mpt — are recognised "
                             "without these)")
    g.add_argument("--columns", type=_columns, metavar="time=COL,current=COL,voltage=COL"
                   "[,temperature=COL][,ambient=COL][,charge=COL][,state=COL]",
                   help="the file's column names for time (s), current, voltage (V) and "
                   "optionally cell temperature and the ambient (chamber) temperature beside "
                   "it (°C; with both, training identifies a thermal model), the tester's net "
                   "charge counter (Ah, running through the record: a gap in time then splits "
                   "the record only where charge was lost, and the SoC reference counts by "
                   "it), and a column that gives the direction of a current logged as its "
                   "magnitude (Maccor's State C, D, R; Neware's CC_Chg, CC_DChg, Rest)")
    g.add_argument("--discharge-positive", action="store_true", help="the file counts "
                   "discharge current as positive (LMNCell: current > 0 charges)")
    g.add_argument("--current-unit", choices=["A", "mA"], help="unit of the current column "
                   "(default: the file's, from the column name, e.g. 'I [mA]', or a units row "
                   "under the names; else A)")
    g.add_argument("--time-unit", choices=["s", "ms", "min", "h", "d"], help="unit of a numeric "
                   "time column (default: the file's, from the column name or a units row; else s)")
    g.add_argument("--voltage-unit", choices=["V", "mV"], help="unit of the voltage column "
                   "(default: the file's, from the column name or a units row; else V)")
    g.add_argument("--temperature-unit", choices=["degC", "K"], help="unit of the temperature "
                   "columns (default: the file's, from the column name or a units row; else "
                   "degC)")
    g.add_argument("--charge-unit", choices=["Ah", "mAh"], help="unit of the charge counter "
                   "column (default: the file's, from the column name or a units row; else Ah)")
    g.add_argument("--delimiter", metavar="CHAR", help="field delimiter, e.g. ';' or tab "
                   "(default: ',')")
    g.add_argument("--decimal", choices=[".", ","], help="decimal mark (default: '.')")


def build_parser() -> argparse.ArgumentParser:
    fmt: dict[str, Any] = {"formatter_class": _HelpFormatter}
    p = argparse.ArgumentParser(prog="lmncell", description="Local model network cell models "
                                "from cycler data, exported as FMI 2.0 FMUs. Current > 0 "
                                "charges; SI units; SoC as a fraction 0…1.", **fmt)
    p.add_argument("--version", action="version", version=f"lmncell {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for add in (_add_inspect_command,
                _add_train_command,
                _add_evaluate_command,
                _add_explain_command,
                _add_build_fmu_command,
                _add_simulate_command,
                _add_sweep_command,
                _add_design_command,
                _add_demo_command):
        add(sub, fmt)
    return p


def _add_inspect_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell inspect` subcommand."""
    s = sub.add_parser("inspect", help="summarise cycler files (and plot them)", **fmt)
    s.add_argument("files", nargs="+", help="data files (CSV, .mat, BDF; .gz too)")
    s.add_argument("--plot", type=figure_file_argument, metavar="OUT.png",
                   help="one figure of all files")
    s.add_argument("--capacity", type=capacity_argument, help="Ah, for C-rates and SoC "
                   "(default: the discharged charge of a record that starts full)")
    _add_reader_options(s)
    s.set_defaults(func=cmd_inspect)


def _add_train_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell train` subcommand."""
    s = sub.add_parser("train", help="identify an LMN from measurements", **fmt)
    s.add_argument("data", nargs="*", help="training data files")
    s.add_argument("--out", required=True, type=output_file_argument, metavar="MODEL.json",
                   help="model file to write")
    s.add_argument("--capacity", type=capacity_argument, help="Ah from full to the cut-off at "
                   "a slow rate (default: with --ocv-tests, of the largest discharge from full "
                   "among the records and up to 15 %% more, the one whose model follows them "
                   "best; else that largest discharge, a lower bound)")
    s.add_argument("--soc0", type=soc_list_argument, help="start SoC: one value for every "
                   "record, or a comma list with one per data file in order, e.g. 1,1,0 for "
                   "two records that start full and one that starts empty (default: 1.0 for "
                   "records that start rested at full charge)")
    s.add_argument("--partition", help="comma list of soc, current, filtered_current, "
                   "temperature (default: auto = soc and current, plus temperature where the "
                   "records lie at two or more chamber temperatures)")
    s.add_argument("--baselines", action="store_true", help="also fit ARX and 2RC baselines")
    s.add_argument("--config", metavar="FILE.toml", help="training settings ([train] table)")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="any training setting (lmncell.config.TrainConfig), VALUE in TOML "
                   "syntax; repeatable, e.g. --set max_local_models=4 --set "
                   "'partition=[\"soc\",\"current\"]'")
    s.add_argument("--max-local-models", type=_positive_int, help="upper limit of M "
                   f"(default: {LOCAL_MODELS_PER_REGION} per training temperature where the "
                   f"local models differ by temperature, else {LOCAL_MODELS_PER_REGION}; twice "
                   "that where the partition has the current)")
    s.add_argument("--ocv-tests", nargs="+", metavar="FILE", help="slow OCV tests, C/5 or "
                   "slower (a discharge from full and a charge from empty, in either order; or "
                   "one file with both): fixes the OCV")
    _add_reader_options(s)
    s.set_defaults(func=cmd_train)


def _add_evaluate_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell evaluate` subcommand."""
    s = sub.add_parser("evaluate", help="free-run error of a model or an FMU on records",
                       **fmt)
    s.add_argument("model", help="model file (JSON), or an LMNCell FMU (.fmu, pythonfmu or "
                   "native), which fmpy then drives through the records")
    s.add_argument("data", nargs="+", help="data files")
    s.add_argument("--soc0", type=soc_list_argument, help="start SoC: one value for every "
                   "record, or a comma list with one per data file in order (default: 1.0 for "
                   "records that start rested at full charge)")
    s.add_argument("--json", action="store_true", help="print the metrics as JSON")
    s.add_argument("--plot", metavar="DIR", type=output_folder_argument,
                   help="write figures and the local-model table "
                   "(an FMU: one fit figure per record)")
    s.add_argument("--trace", type=output_file_argument, metavar="OUT.csv",
                   help="write time, current, measured and model voltage and SoC per model step")
    s.add_argument("--ambient", action="store_true", help="drive the model with the ambient "
                   "(chamber) temperature only, as a vehicle simulation does: the model's "
                   "thermal model computes the cell temperature (default: the measured cell "
                   "temperature)")
    s.add_argument("--through-hidden-pauses", action="store_true", help=THROUGH_PAUSES_HELP)
    s.add_argument("--at-model-steps", action="store_true", help="with an FMU: step it at its "
                   "sample time Ts with the mean current over each step, as a host that steps "
                   "at Ts does (default: through the record's own samples, so that a model "
                   "with a current delay sees what the current did within each step)")
    s.add_argument("--observer", choices=["ekf", "fuzzy", "imm"],
                   help="judge a SoC observer instead of the voltage")
    s.add_argument("--soc0-est", type=soc_argument, help="the observer's start SoC guess")
    s.add_argument("--start-soc", type=soc_argument, help="start the observer where the "
                   "reference SoC first falls to this value (under load; default: the record's "
                   "start)")
    _add_reader_options(s)
    s.set_defaults(func=cmd_evaluate)


def _add_explain_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell explain` subcommand."""
    s = sub.add_parser("explain", help="every local model as the cell it describes: R0, RC "
                       "elements, hysteresis and OCV offset per operating regime", **fmt)
    s.add_argument("model", help="model file (JSON), or an LMNCell FMU (the model it ships)")
    s.add_argument("--temperature", type=_temperature, metavar="DEGC", help="cell temperature "
                   "at which to state the resistances (default: each local model's centre, or "
                   "the model's reference temperature)")
    s.add_argument("--json", action="store_true", help="print the rows as JSON")
    s.set_defaults(func=cmd_explain)


def _add_build_fmu_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell build-fmu` subcommand."""
    s = sub.add_parser("build-fmu", help="package a model as an FMI 2.0 co-simulation FMU",
                       **fmt)
    s.add_argument("model", help="model file (JSON), or an LMNCell FMU whose model to build "
                   "again (e.g. a native FMU of a pythonfmu one)")
    s.add_argument("--out", required=True, type=fmu_file_argument, metavar="CELL.fmu",
                   help="FMU to write")
    s.add_argument("--native", action="store_true", help="generated C, no Python needed by the "
                   "importer (linux64 binary built here with gcc, or zig where gcc is missing; "
                   "sources included)")
    s.add_argument("--platforms", type=_name_list, metavar="linux64,win64,darwin64",
                   help="with --native: the binaries to put in (default linux64; win64 and "
                   "darwin64, a universal binary for Intel and Apple silicon Macs, are "
                   "cross-compiled with zig: pip install ziglang)")
    s.set_defaults(func=cmd_build_fmu)


def _name_list(text: str) -> list[str]:
    """An argparse type for comma-separated names (--platforms, --cycles), blank entries
    dropped as _floats drops them; the names are checked where they are used."""
    return [name.strip() for name in text.split(",") if name.strip()]


def _add_simulate_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell simulate` subcommand."""
    s = sub.add_parser("simulate", help="drive an FMU through a vehicle drive cycle or a "
                       "current profile with fmpy", **fmt)
    s.add_argument("fmu", help="an LMNCell FMU")
    load = s.add_mutually_exclusive_group()
    load.add_argument("--cycle", type=cycle_argument, metavar="NAME|FILE.csv",
                      help="speed trace: wltc, udds, us06, hwfet, or a CSV file with a time "
                      "column (time_s or cycSecs), a speed column (speed_mps, speed_kmh, "
                      "speed_mph or cycMps) and optionally the road grade as rise over run "
                      "(grade or cycGrade); a unit may stand in brackets: 'Speed [km/h]' "
                      "(default: wltc)")
    load.add_argument("--current", metavar="FILE.csv",
                      help="a cell current profile instead of a drive cycle: a CSV file with a "
                      "time column (time_s) and a current column (current_a or current_ma, or "
                      "'Current [mA]', 'I [A]'; > 0 charges unless --discharge-positive); at "
                      "even steps, or a table of breakpoints: each row's current held until "
                      "the next row's time (a repeated time: a step there), the last row its "
                      "end")
    s.add_argument("--discharge-positive", action="store_true",
                   help="the --current profile counts discharge as positive")
    s.add_argument("--charge-cutoff", type=_cutoff, metavar="V", help="with --current: the "
                   "run stops where the voltage rises above it or the SoC above 1 (default: "
                   "the highest voltage of the model's training records; 0: none, the run "
                   "stops at SoC above 1)")
    s.add_argument("--vehicle", metavar="FILE.toml", help="vehicle and pack (default: the "
                   "built-in compact EV; not with --current)")
    s.add_argument("--repeat", type=_positive_int, default=1, help="cycles back to back")
    s.add_argument("--soc0", type=soc_argument, default=0.9, help="start SoC")
    s.add_argument("--ambient", type=_ambient, default=25.0, help="ambient temperature, "
                   "°C (the model computes the cell temperature where it has a thermal model)")
    s.add_argument("--cell-temperature-start", type=_temperature, metavar="DEGC",
                   help="the cell's temperature at the start, °C, where it is warmer or colder "
                   "than the --ambient it meets (needs the model's thermal model; default: "
                   "rested at the ambient)")
    s.add_argument("--step", type=_positive, help="communication step in s (default: model Ts); "
                   "a step longer than the cycle's or profile's samples holds their mean power or "
                   "current")
    s.add_argument("--cutoff", type=_cutoff, metavar="V", help="discharge cut-off cell voltage: "
                   "the run stops where the voltage falls below it or the SoC below 0 (default: "
                   "the lowest voltage of the model's training records; 0: none, the run stops "
                   "at SoC 0 or a voltage below 0)")
    s.add_argument("--plot", type=figure_file_argument, metavar="OUT.png",
                   help="figure of speed, current, voltage, SoC")
    s.add_argument("--json", action="store_true", help="print the results as JSON")
    s.set_defaults(func=cmd_simulate)


def _add_sweep_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell sweep` subcommand."""
    s = sub.add_parser("sweep", help="many drive-cycle scenarios of an FMU on Dask", **fmt)
    s.add_argument("fmu", help="an LMNCell FMU (pythonfmu or native)")
    s.add_argument("--cycles", type=_name_list, default="wltc", help="comma list of wltc, "
                   "udds, us06, hwfet and speed-trace CSV files (as simulate --cycle takes "
                   "them)")
    s.add_argument("--ambient", type=_floats("--ambient"), default=[25.0],
                   help="comma list of ambient temperatures, °C (default: 25)")
    s.add_argument("--soc0", type=_floats("--soc0"), default=[0.9],
                   help="comma list of start SoC (default: 0.9)")
    s.add_argument("--cell-temperature-start", type=_temperature, metavar="DEGC",
                   help="every run's cells start at this temperature, °C, and tend towards "
                   "their --ambient (needs the model's thermal model; default: rested at the "
                   "ambient)")
    s.add_argument("--vehicle", action="append", metavar="V.toml", help="vehicle file; "
                   "repeatable (default: the built-in compact EV)")
    s.add_argument("--repeat", type=_positive_int, default=1, help="cycles back to back")
    s.add_argument("--pack", metavar="NsNp", help="simulate the whole pack, e.g. 96s3p, with "
                   "the vectorised runtime on the FMU's model (default: one cell through the "
                   "FMU)")
    s.add_argument("--spread", metavar="capacity=F,resistance=F", help="cell-to-cell spread "
                   "(relative standard deviations) of a pack")
    s.add_argument("--cells", type=_positive_int, help="without --pack: a string of N cells "
                   "with the spread, each carrying the vehicle's cell current")
    s.add_argument("--seed", type=int, default=0, help="seed of the spread")
    s.add_argument("--cutoff", type=_cutoff, metavar="V", help="discharge cut-off cell voltage: "
                   "a run stops where a cell's voltage falls below it or its SoC below 0 "
                   "(default: the lowest voltage of the model's training records; 0: none, the "
                   "run stops at SoC 0 or a voltage below 0)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--workers", type=_positive_int, help="LocalCluster worker processes "
                   "(default: one per core)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. "
                   "tcp://10.0.0.5:8786, instead of a LocalCluster")
    s.add_argument("--out", required=True, type=output_file_argument, metavar="RESULTS.csv",
                   help="table to write "
                   "(.csv, or .parquet with pyarrow)")
    s.add_argument("--plot", metavar="DIR", type=output_folder_argument,
                   help="summary figures")
    s.set_defaults(func=cmd_sweep)


def _add_design_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell design` subcommand."""
    s = sub.add_parser("design", help="optimal excitation programme for a target SoC profile",
                       **fmt)
    s.add_argument("--capacity", type=capacity_argument, required=True, help="cell capacity, Ah")
    s.add_argument("--soc-profile", required=True, help="SoC points, e.g. 0.8,0.2,0.8 or 0.8:0.2")
    s.add_argument("--max-c-rate", type=_positive, default=20.0, help="current limit, C")
    s.add_argument("--max-current", type=_positive, default=100.0, help="cycler limit, A")
    s.add_argument("--voltage-min", type=_cell_voltage, default=None, help="V (default: 2.0 or the "
                   "model's)")
    s.add_argument("--voltage-max", type=_cell_voltage, default=None, help="V (default: 3.6 or the "
                   "model's)")
    s.add_argument("--hold", type=_positive, default=10.0,
                   help="the cycler's minimum hold time, s (levels are held for a multiple of "
                   "it: 3 τ of the design model's slowest RC, at most a tenth of a sequence)")
    s.add_argument("--sample-time", type=_positive, default=1.0, help="s")
    s.add_argument("--sequence", type=_positive, default=300.0, help="sequence length, s")
    s.add_argument("--duration", type=_positive, default=7200.0, help="total, s")
    s.add_argument("--r0", type=_positive, help="design model R0, Ω (default: with --model "
                   "its local models' median R0 and RC elements, else 0.01)")
    s.add_argument("--model", help="take the OCV and voltage limits from a model file (or "
                   "the one an LMNCell FMU ships)")
    s.add_argument("--plot", metavar="DIR", type=output_folder_argument,
                   help="write the programme's figures")
    s.add_argument("--method", choices=DESIGN_METHODS, default="spacefill",
                   help="evenly spaced levels in D-optimal order, or free D-optimal levels")
    s.add_argument("--information", choices=INFORMATION_KINDS, default="lmn",
                   help="design for the LMN's regressors or for the RC design model's parameters")
    s.add_argument("--compare-virtual", action="store_true", help="characterise a virtual cell, "
                   "design on it and prove the design against PRBS and APRBS programmes (LMNs "
                   "trained on each, validated in free run on three profiles)")
    s.add_argument("--virtual-cell", choices=VIRTUAL_CELLS, default=None,
                   help="PyBaMM DFN with Prada2013 (the sim extra) or the built-in ECM (default: "
                   "pybamm where installed)")
    s.add_argument("--json", action="store_true", help="print the programme's figures as JSON "
                   "on stdout, with --compare-virtual the proof (progress on stderr)")
    s.add_argument("--out", required=True, type=output_file_argument, metavar="P.csv",
                   help="cycler programme to write")
    s.set_defaults(func=cmd_design)


def _add_demo_command(sub: argparse._SubParsersAction, fmt: dict) -> None:
    """The `lmncell demo` subcommand."""
    s = sub.add_parser("demo", help="train, evaluate, build the FMU, drive it, write a report",
                       **fmt)
    s.add_argument("--out", default="lmncell-demo", type=output_folder_argument,
                   help="output folder")
    s.set_defaults(func=cmd_demo)


@contextmanager
def user_warnings_as(prog: str) -> Iterator[None]:
    """Within the block, a UserWarning (the messages about the user's data and runs: a record
    outside the trained range, values that look like mA) is printed as "PROG: warning: …" on
    stderr, like the errors, without Python's file, line and source; other warnings as usual."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if issubclass(category, UserWarning):
            print(f"{prog}: warning: {message}", file=sys.stderr if file is None else file)
        else:
            default(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def tolerant_output() -> None:
    """Let stdout and stderr write what their encoding cannot hold (γ, τ, Ω, σ in the messages)
    as backslash escapes, not fail with UnicodeEncodeError: output redirected to a file on
    Windows, or PYTHONIOENCODING=ascii, is not UTF-8."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure") and _codec(stream.encoding) != "utf-8":
            stream.reconfigure(errors="backslashreplace")


def _codec(encoding: str | None) -> str | None:
    """The codec's canonical name ("utf-8" for "UTF8", "u8", …), None where it has none."""
    try:
        return codecs.lookup(encoding or "").name
    except LookupError:
        return None


def run_script(main_function: Callable[[], None], script: str) -> None:
    """Run an example script's main(): a user's mistake (USER_ERRORS) ends it with the message
    on stderr and exit status 2, as on the command line, not with a traceback; its warnings are
    printed as the command line's are (user_warnings_as)."""
    name = Path(script).name
    tolerant_output()
    try:
        with user_warnings_as(name):
            main_function()
    except USER_ERRORS as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except MemoryError as exc:
        print(f"{name}: error: {out_of_memory(exc)}", file=sys.stderr)
        sys.exit(2)
    except OSError as exc:
        print(f"{name}: error: {os_refusal(exc)}", file=sys.stderr)
        sys.exit(2)


def os_refusal(exc: OSError) -> str:
    """The message for an operating-system error that USER_ERRORS does not name (a full disk,
    a read-only folder, a failing drive): the file where the system gives it, its reason and
    error number, and what to check."""
    where = f"{exc.filename}: " if exc.filename else ""
    return (f"{where}{exc.strerror or exc} (OS error {exc.errno}): the system refused to read "
            "or write a file; expected free disk space and a writable output folder")


def out_of_memory(exc: MemoryError) -> str:
    """The message for a MemoryError: what numpy could not allocate and what to change."""
    return (f"out of memory ({exc or 'MemoryError'}): the data at these settings need more "
            "memory than this machine has; expected fewer or shorter records, a longer sample "
            "time or a shorter run")


def main(argv: list[str] | None = None) -> int:
    tolerant_output()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        with user_warnings_as(f"lmncell {args.command}"):
            return int(args.func(args) or 0)
    except USER_ERRORS as exc:
        print(f"lmncell {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:
        print(f"lmncell {args.command}: error: {out_of_memory(exc)}", file=sys.stderr)
        return 2
    except BrokenPipeError:         # the output piped into a reader that stopped (| head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:       # Ctrl-C: a message and the shell's code, no traceback
        print(f"\nlmncell {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:          # after BrokenPipeError, one of its kind
        print(f"lmncell {args.command}: error: {os_refusal(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
