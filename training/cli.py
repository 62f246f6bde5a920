"""The `lmncell` command line: each sub-command parses its arguments and calls one function."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lmncell.config import ConfigError
from lmncell.data.records import DataError
from lmncell.runtime.model import ModelFileError


def _float01(text: str) -> float:
    v = float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a SoC fraction within 0…1")
    return v


def _positive(text: str) -> float:
    v = float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a value > 0")
    return v


def cmd_inspect(a: argparse.Namespace) -> int:
    from lmncell.data.summary import inspect_files

    inspect_files(a.files, a.plot, a.capacity)
    return 0


def cmd_train(a: argparse.Namespace) -> int:
    from lmncell.identification.train import train_files

    partition = a.partition.split(",") if a.partition else None
    train_files(a.data, a.out, a.capacity, a.soc0, partition, a.baselines, a.config,
                max_local_models=a.max_local_models, ocv_tests=a.ocv_tests)
    return 0


def cmd_evaluate(a: argparse.Namespace) -> int:
    if a.observer:
        from lmncell.evaluation.observe import evaluate_observer_files

        if a.soc0_est is None:
            raise ConfigError("--observer needs --soc0-est (the estimator's start guess)")
        evaluate_observer_files(a.model, a.data, a.observer, a.soc0, a.soc0_est, a.start_soc,
                                a.plot, a.json)
        return 0
    from lmncell.evaluation.evaluate import evaluate_files

    evaluate_files(a.model, a.data, a.soc0, a.plot, a.trace, a.json)
    return 0


def cmd_build_fmu(a: argparse.Namespace) -> int:
    if a.native:
        from lmncell.fmu.native_build import build_native_fmu

        path = build_native_fmu(a.model, a.out)
        print(f"wrote {path}")
        return 0
    from lmncell.fmu.pythonfmu_build import build_fmu

    path = build_fmu(a.model, a.out)
    print(f"wrote {path}")
    return 0


def cmd_simulate(a: argparse.Namespace) -> int:
    from lmncell.scenarios.drive import simulate_cycle_cli

    return simulate_cycle_cli(a)


def cmd_design(a: argparse.Namespace) -> int:
    from lmncell.design.command import run_design

    return run_design(a)


def cmd_demo(a: argparse.Namespace) -> int:
    from lmncell.report.demo import run_demo

    run_demo(Path(a.out))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lmncell", description="Local model network cell models "
                                "from cycler data, exported as FMI 2.0 FMUs. Current > 0 "
                                "charges; SI units; SoC as a fraction.")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("inspect", help="summarise cycler files")
    s.add_argument("files", nargs="+")
    s.add_argument("--plot", metavar="OUT.png")
    s.add_argument("--capacity", type=_positive, help="Ah, for C-rates and SoC")
    s.set_defaults(func=cmd_inspect)

    s = sub.add_parser("train", help="identify an LMN from measurements")
    s.add_argument("data", nargs="+")
    s.add_argument("--out", required=True, metavar="MODEL.json")
    s.add_argument("--capacity", type=_positive, help="Ah (default: from full discharges)")
    s.add_argument("--soc0", type=_float01, help="start SoC of every record (default: 1.0 for "
                   "records that start rested at full charge)")
    s.add_argument("--partition", help="comma list of soc, current, filtered_current, "
                   "temperature")
    s.add_argument("--baselines", action="store_true", help="also fit ARX and 2RC baselines")
    s.add_argument("--config", metavar="FILE.toml")
    s.add_argument("--max-local-models", type=int)
    s.add_argument("--ocv-tests", nargs="+", metavar="FILE", help="slow OCV tests (discharge "
                   "from full, charge from empty; or one file with both): fixes the OCV")
    s.set_defaults(func=cmd_train)

    s = sub.add_parser("evaluate", help="free-run error of a model on records")
    s.add_argument("model")
    s.add_argument("data", nargs="+")
    s.add_argument("--soc0", type=_float01)
    s.add_argument("--json", action="store_true")
    s.add_argument("--plot", metavar="DIR")
    s.add_argument("--trace", metavar="OUT.csv")
    s.add_argument("--observer", choices=["ekf", "fuzzy", "imm"],
                   help="judge a SoC observer instead of the voltage")
    s.add_argument("--soc0-est", type=_float01, help="the observer's start SoC guess")
    s.add_argument("--start-soc", type=_float01, help="start the observer where the reference "
                   "SoC first falls to this value (under load)")
    s.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("build-fmu", help="package a model as an FMI 2.0 co-simulation FMU")
    s.add_argument("model")
    s.add_argument("--out", required=True, metavar="CELL.fmu")
    s.add_argument("--native", action="store_true", help="generated C, no Python needed by the "
                   "importer (linux64 binary built here with gcc, sources included)")
    s.set_defaults(func=cmd_build_fmu)

    s = sub.add_parser("simulate", help="drive an FMU through a vehicle drive cycle with fmpy")
    s.add_argument("fmu")
    s.add_argument("--cycle", choices=["wltc", "udds", "us06", "hwfet"], default="wltc")
    s.add_argument("--vehicle", metavar="FILE.toml")
    s.add_argument("--repeat", type=int, default=1)
    s.add_argument("--soc0", type=_float01, default=0.9)
    s.add_argument("--step", type=_positive, help="communication step in s (default: model Ts)")
    s.add_argument("--plot", metavar="OUT.png")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("design", help="optimal excitation programme for a target SoC profile")
    s.add_argument("--capacity", type=_positive, required=True, help="Ah")
    s.add_argument("--soc-profile", required=True, help="SoC points, e.g. 0.8,0.2,0.8 or 0.8:0.2")
    s.add_argument("--max-c-rate", type=_positive, default=20.0, help="default 20")
    s.add_argument("--max-current", type=_positive, default=100.0, help="cycler limit, A")
    s.add_argument("--voltage-min", type=float, default=None, help="V (default 2.0 or model)")
    s.add_argument("--voltage-max", type=float, default=None, help="V (default 3.6 or model)")
    s.add_argument("--hold", type=_positive, default=10.0, help="minimum hold time, s")
    s.add_argument("--sample-time", type=_positive, default=1.0, help="s")
    s.add_argument("--sequence", type=_positive, default=300.0, help="sequence length, s")
    s.add_argument("--duration", type=_positive, default=7200.0, help="total, s")
    s.add_argument("--r0", type=_positive, default=0.010, help="design model R0, Ω")
    s.add_argument("--model", help="take the OCV and voltage limits from a model file")
    s.add_argument("--plot", metavar="DIR")
    s.add_argument("--compare-virtual", action="store_true", help="prove the design on a "
                   "virtual cell against a random programme")
    s.add_argument("--out", required=True, metavar="P.csv")
    s.set_defaults(func=cmd_design)

    s = sub.add_parser("demo", help="train, evaluate, build the FMU, drive it, write a report")
    s.add_argument("--out", default="lmncell-demo")
    s.set_defaults(func=cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (DataError, ModelFileError, ConfigError, FileNotFoundError) as exc:
        print(f"lmncell {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
