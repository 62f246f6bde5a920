"""Leave-one-record-out check of the identification: train on all records but one, simulate the
held-out record free-run, and compare the LMN with its baselines fitted on the same files.

Usage:
    python examples/leave_one_out.py CAPACITY_AH RECORD... [--soc0 F[,F...]] [--set KEY=VALUE ...]
        [--ocv-tests FILE] [--no-baselines] [--hold-out PATTERN [--together]]
        [--through-hidden-pauses]
        [--fmu native|pythonfmu [--at-model-steps]] [--plot FILE.png]

Example (the four Panasonic 25 °C drive cycles of ../shared/data, the C/20 OCV test):
    P=../shared/data/panasonic_18650pf/25degC
    python examples/leave_one_out.py 2.85 $P/drive_cycles/*.mat \\
        --set 'partition=["soc","current"]' --ocv-tests $P/ocv_and_capacity/*C20_OCV*.mat

Per held-out record (all its segments pooled) it prints the free-run RMSE in mV over the 20–80 %
SoC window and over the whole record, for the LMN and each baseline (and the LMN's below 10 %
SoC, where the record goes there), driven by the measured cell temperature and, where the
record has one beside a chamber temperature, by the chamber temperature only (the LMN's thermal
model computes the cell temperature), and where the record has the tester's charge counters the
SoC drift of the logged current by the record's end (its net charge minus the counters', in % of
the capacity: a model driven by the current counts its SoC that much off, which near empty
moves the voltage collapse; A123 25 °C: +1.17 %, the SoC ends that much high); then the
means over the folds. --hold-out PATTERN holds out only the records whose name contains
PATTERN (e.g. 10degC: train on all, test each 10 °C record left out in turn), or one of a
comma list (N05,P05,P25: the A123 folds between training temperatures); with --together the
records of each pattern are held out at once and the model is trained on the others
(--hold-out 10degC --together: trained at 25 °C only, tested at 10 °C: leave one temperature
out). A pattern A+B matches a name that contains A or B: --hold-out Cycle_1+US06,Cycle_2+HWFT
--together holds out two records at a time (leave two out, how the figures grow with one
record fewer in training; a record in several patterns is held out with each).
--through-hidden-pauses evaluates the held-out record as a host that drives the FMU through its
time column: pauses that only the wall clock shows (Panasonic 25 °C Cycle 1:
16 h and 3 h) do not split it, and the model's state runs on through them (training still
splits there). --fmu native|pythonfmu also builds each fold's model into that FMU and scores
the held-out record through it, driven by fmpy as `lmncell evaluate CELL.fmu` drives it (through
the record's own samples; with --at-model-steps in steps of Ts with the mean current over each):
the "fmu" figures, which equal the lmn ones unless --at-model-steps; for a record sampled
faster than Ts also "fmu_samples", the FMU's voltage at each of the record's own samples
against the voltage logged then (lmncell evaluate CELL.fmu's row). --plot FILE.png draws the
same figures as bars per held-out record, with a caption naming the split and the settings.
Progress (each training, its time) goes to stderr, the figures to stdout.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from lmncell.api import build_fmu
from lmncell.cli import (
    HOLD_OUT_HELP,
    THROUGH_PAUSES_HELP,
    TOGETHER_HELP,
    capacity_or_auto_argument,
    figure_file_argument,
    input_file_argument,
    run_script,
    soc_list_argument,
)
from lmncell.config import parse_setting
from lmncell.evaluation.evaluate import (
    evaluate_records,
    fold_words,
    leave_one_out_folds,
    read_records,
    through_pauses_clause,
    trained_per_fold,
)
from lmncell.evaluation.fmueval import evaluate_fmu
from lmncell.evaluation.metrics import ENDS, pooled
from lmncell.identification.train import train_files
from lmncell.progress import print_progress_stderr
from lmncell.report.plots import folds_figure
from lmncell.runtime.model import LmnModel

MODELS = ("lmn", "fmu", "fmu_samples", "arx", "ecm2rc", "ecm2rc_hyst")

# per mode ("cell", "ambient"), per model: (20–80 % SoC, whole record) RMSE, mV
Scores = dict[str, dict[str, tuple[float, float]]]
Fold = tuple[str, Scores]          # a held-out record's name and scores


def main() -> None:
    a = _arguments()
    settings = dict(parse_setting(s) for s in a.set)
    if a.ocv_tests:
        settings["ocv_tests"] = a.ocv_tests
    with tempfile.TemporaryDirectory(prefix="lmncell-loo-") as tmp:
        def train(records: list[str], socs: list[float | None]) -> tuple[LmnModel, Path | None]:
            start = time.monotonic()
            print_progress_stderr(f"training on {', '.join(Path(r).name for r in records)} …")
            model, _ = train_files(records, Path(tmp) / "model.json", capacity_ah=a.capacity_ah,
                                   soc0=socs, baselines=not a.no_baselines,
                                   progress=lambda _m: None, **settings)
            fmu = (build_fmu(Path(tmp) / "model.json", Path(tmp) / "model.fmu",
                             native=a.fmu == "native") if a.fmu else None)
            print_progress_stderr(f"  {model.n_local_models} local models in "
                                  f"{time.monotonic() - start:.0f} s; scoring the held-out "
                                  "record")
            return model, fmu

        folds = [(Path(held).name, _scored_fold(a, model, fmu, held, held_soc0))
                 for held, held_soc0, (model, fmu) in trained_per_fold(
                     leave_one_out_folds(a.records, a.hold_out, a.soc0, a.together), train)]
    print("mean over the folds, RMSE 20–80 % SoC / whole record (mV): " + ", ".join(
        f"{m} {sum(w for w, _ in v) / len(v):.2f} / {sum(x for _, x in v) / len(v):.2f}"
        for m, v in _per_model(folds).items()))
    if a.plot:
        print(f"figure: {folds_figure(folds, Path(a.plot), _caption(a, len(folds)))}")


def _arguments() -> argparse.Namespace:
    """The command line, checked."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capacity_ah", type=capacity_or_auto_argument,
                    help="Ah, or 'auto': each fold's training estimates it (with --ocv-tests "
                         "by the free-run error, lmncell.identification.train.fit_capacity)")
    ap.add_argument("records", nargs="+", type=input_file_argument,
                    help="cycler records (any format lmncell reads); each is held out in turn")
    ap.add_argument("--soc0", type=soc_list_argument, default=[1.0],
                    help="start SoC: one for every record or one per record, in order")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a training setting, e.g. 'partition=[\"soc\",\"current\"]'")
    ap.add_argument("--ocv-tests", nargs="*", default=[], type=input_file_argument,
                    help="slow OCV tests for every fold's training (as train --ocv-tests)")
    ap.add_argument("--no-baselines", action="store_true",
                    help="leave out the ARX and 2RC baselines (faster)")
    ap.add_argument("--hold-out", default="", metavar="PATTERN",
                    help=HOLD_OUT_HELP)
    ap.add_argument("--together", action="store_true", help=TOGETHER_HELP)
    ap.add_argument("--through-hidden-pauses", action="store_true",
                    help=THROUGH_PAUSES_HELP)
    ap.add_argument("--fmu", choices=("native", "pythonfmu"),
                    help="also score each held-out record through the fold's model built into "
                    "this FMU, driven by fmpy")
    ap.add_argument("--at-model-steps", action="store_true",
                    help="with --fmu: step the FMU at Ts with the mean current over each step")
    ap.add_argument("--plot", type=figure_file_argument, metavar="FILE.png",
                    help="also draw the results per held-out record")
    a = ap.parse_args()
    if a.at_model_steps and not a.fmu:
        ap.error("--at-model-steps needs --fmu")
    if a.together and not a.hold_out:
        ap.error("--together needs --hold-out PATTERN (the records held out together)")
    return a


def _scored_fold(a: argparse.Namespace, model: LmnModel, fmu: Path | None, held: str,
                 held_soc0: float | None) -> Scores:
    """The held-out record's (20–80 %, whole record) RMSE in mV per mode and model, each
    mode's line printed: driven by the measured cell temperature ("cell") and, where the record
    has one, by the chamber temperature only ("ambient")."""
    held_records = [(rec, start) for _, rec, start in read_records(
        [held], held_soc0, through_hidden_pauses=a.through_hidden_pauses)]
    scores: Scores = {}
    for ambient in (False, True):
        _, rows = evaluate_records(model, held_records, ambient=ambient)
        if ambient and "cell_temperature_rmse_k" not in rows[0]:
            continue                  # no measured cell temperature: one run says it all
        if fmu is not None:
            _add_fmu_rows(a, fmu, held, held_soc0, ambient, rows)
        mode = "ambient" if ambient else "cell"
        scores[mode] = {m: (pooled([r[m] for r in rows], "window_"), pooled([r[m] for r in rows]))
                        for m in MODELS if m in rows[0]}
        print(f"{Path(held).name[:40]:40s} {mode:7s} M={model.n_local_models:2d} "
              f"E={model.arrhenius_k}  " + "  ".join(
                  f"{m} {w:6.2f} / {whole:6.1f}" for m, (w, whole) in scores[mode].items())
              + _extra_words(rows), flush=True)
    return scores


def _add_fmu_rows(a: argparse.Namespace, fmu: Path, held: str, held_soc0: float | None,
                  ambient: bool, rows: list[dict]) -> None:
    """Adds the FMU's figures ("fmu", and "fmu_samples" for a record sampled faster than Ts)
    to the pipeline's rows of the held-out record, one per segment."""
    _, fmu_rows = evaluate_fmu(fmu, [held], held_soc0, ambient,
                               through_hidden_pauses=a.through_hidden_pauses,
                               at_model_steps=a.at_model_steps, progress=lambda _m: None)
    for row, fmu_row in zip(rows, fmu_rows, strict=True):
        row["fmu"] = fmu_row["fmu"]
        if "fmu_samples" in fmu_row:
            row["fmu_samples"] = fmu_row["fmu_samples"]


def _extra_words(rows: list[dict]) -> str:
    """The end of a fold's line: the LMN's RMSE below 10 % SoC (where the record goes there),
    the thermal model's cell temperature RMSE, the logged current's SoC drift."""
    extra = ""
    low = pooled([r["lmn"] for r in rows], "low_soc_")    # NaN: no sample below
    if math.isfinite(low):
        extra += f"  | lmn below {100 * ENDS[0]:.0f} % SoC {low:6.1f}"
    if "cell_temperature_rmse_k" in rows[0]:
        extra += f"  T RMSE {rows[0]['cell_temperature_rmse_k']:.2f} K"
    if "soc_drift_pct" in rows[0]:
        extra += f"  SoC drift {rows[0]['soc_drift_pct']:+.2f} %"
    return extra


def _per_model(folds: list[Fold]) -> dict[str, list[tuple[float, float]]]:
    """Each "model (mode T)"'s (20–80 %, whole record) RMSE over the folds, in fold order."""
    out: dict[str, list[tuple[float, float]]] = {}
    for _, scores in folds:
        for mode, per_model in scores.items():
            for m, pair in per_model.items():
                out.setdefault(f"{m} ({mode} T)", []).append(pair)
    return out


def _caption(a: argparse.Namespace, n_folds: int) -> str:
    """The figure's caption: the split, how each record was driven, the settings."""
    ocv = ", ".join(Path(f).name for f in a.ocv_tests) or "estimated from the records"
    title, words = fold_words(a.hold_out, a.together, len(a.records))
    return (f"{title}, {n_folds} held-out record(s): {words}, with the same data "
            "and settings; free-run RMSE of the held-out record, "
            "driven by the measured cell temperature (cell) and, where the record has "
            "one beside it, by the chamber temperature only (ambient)"
            + through_pauses_clause(a.through_hidden_pauses) + fmu_clause(a)
            + ". Settings: "
            f"{', '.join(a.set) or 'defaults'}; OCV: {ocv}.")


def fmu_clause(a: argparse.Namespace) -> str:
    """The caption's words for the fmu bars (none without --fmu)."""
    if not a.fmu:
        return ""
    how = ("in steps of Ts with the mean current over each" if a.at_model_steps
           else "through the record's own samples, scored at its model steps (fmu_samples, for "
                "a record sampled faster than Ts: at each sample)")
    return f"; fmu: the fold's model as a {a.fmu} FMU, driven by fmpy {how}"


if __name__ == "__main__":
    run_script(main, __file__)
