"""Leave-one-record-out check of the SoC observers: train on all records but one, run each
observer on the held-out record from a wrong start under load, report SoC RMSE after the first
10 minutes, the share of samples outside ±3σ (the band's honesty, target ≤ 5 %) and the
median 3σ after 10 minutes (how wide the band is while it holds the truth).

Usage:
    python examples/observer_leave_one_out.py CAPACITY_AH RECORD... [--ocv-tests FILE ...]
        [--hold-out PATTERN [--together]] [--start-soc 0.6] [--soc0-est 0.3] [--soc0 F[,F...]]
        [--set KEY=VALUE ...] [--through-hidden-pauses] [--plot FILE.png]

Example (the four Panasonic 25 °C drive cycles of ../shared/data, the C/20 OCV test):
    P=../shared/data/panasonic_18650pf/25degC
    python examples/observer_leave_one_out.py 2.85 $P/drive_cycles/*.mat \\
        --ocv-tests $P/ocv_and_capacity/*C20_OCV*.mat

The observer starts where the reference SoC first falls to --start-soc (under load, its load
history unknown to it) with the estimate --soc0-est. --hold-out PATTERN holds out only the
records whose name contains PATTERN (e.g. 10degC), or one of a comma list (N05,P05,P25), a
pattern A+B matching a name that contains A or B; --together holds the records of each pattern
out at once, the model trained on the others.
--through-hidden-pauses runs the observers through pauses that only the wall clock shows, as in
an FMU driven through the record's time column (default: the record is split there).
--plot FILE.png draws the RMSE and the share outside ±3σ per held-out record and observer, with
a caption naming the run. Progress (each training, its time) goes to stderr, the figures to
stdout.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from lmncell.cli import (
    HOLD_OUT_HELP,
    THROUGH_PAUSES_HELP,
    TOGETHER_HELP,
    capacity_argument,
    figure_file_argument,
    input_file_argument,
    run_script,
    soc_argument,
    soc_list_argument,
)
from lmncell.config import parse_setting
from lmncell.data.dataset import record_to_segments, start_soc
from lmncell.data.readers import read_record
from lmncell.evaluation.evaluate import (
    fold_words,
    leave_one_out_folds,
    through_pauses_clause,
    trained_per_fold,
)
from lmncell.evaluation.observe import (
    observer_segment,
    run_observer,
    soc_metrics,
    start_index,
)
from lmncell.identification.train import train_files
from lmncell.progress import print_progress_stderr
from lmncell.report.plots import observer_folds_figure
from lmncell.runtime.model import LmnModel, load_model

KINDS = ("ekf", "fuzzy", "imm")


# per observer: (SoC RMSE after the first 10 minutes %, share outside ±3σ %, median 3σ %)
Scores = dict[str, tuple[float, float, float]]


def main() -> None:
    a = _arguments()
    settings = dict(parse_setting(s) for s in a.set)
    if a.ocv_tests:
        settings["ocv_tests"] = a.ocv_tests
    folds: list[tuple[str, Scores]] = []
    with tempfile.TemporaryDirectory() as tmp:
        def train(records: list[str], socs: list[float | None]) -> LmnModel:
            start = time.monotonic()
            print_progress_stderr(f"training on {', '.join(Path(r).name for r in records)} …")
            out = Path(tmp) / "model.json"
            train_files(records, out, a.capacity_ah, socs, progress=lambda _m: None,
                        **settings)
            model = load_model(out)
            print_progress_stderr(f"  {model.n_local_models} local models in "
                                  f"{time.monotonic() - start:.0f} s; running the observers")
            return model

        for held, held_soc0, model in trained_per_fold(
                leave_one_out_folds(a.records, a.hold_out, a.soc0, a.together), train):
            folds.append((Path(held).name, _observed_fold(a, model, held, held_soc0)))
    for kind in KINDS:
        rows = [scores[kind] for _, scores in folds]
        if rows:
            rmse, out3, width = np.mean(rows, axis=0)
            worst = max(r[1] for r in rows)
            print(f"mean over the folds, {kind:5s}: SoC RMSE {rmse:.2f} %, outside ±3σ "
                  f"{out3:.1f} % (worst fold {worst:.1f} %), median 3σ {width:.1f} %")
    if a.plot:
        bars = [(name, {k: (r[0], r[1]) for k, r in scores.items()}) for name, scores in folds]
        print(f"figure: {observer_folds_figure(bars, Path(a.plot), _caption(a, len(folds)))}")


def _arguments() -> argparse.Namespace:
    """The command line, checked."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capacity_ah", type=capacity_argument, help="the cell's capacity (Ah)")
    ap.add_argument("records", nargs="+", type=input_file_argument,
                    help="cycler records (any format lmncell reads); each is held out in turn")
    ap.add_argument("--ocv-tests", nargs="*", default=[], type=input_file_argument,
                    help="slow OCV tests for every fold's training (as train --ocv-tests)")
    ap.add_argument("--hold-out", default="", metavar="PATTERN",
                    help=HOLD_OUT_HELP)
    ap.add_argument("--together", action="store_true", help=TOGETHER_HELP)
    ap.add_argument("--start-soc", type=soc_argument, default=0.6,
                    help="start the observers where the reference SoC first reaches this "
                    "(default: 0.6)")
    ap.add_argument("--soc0-est", type=soc_argument, default=0.3,
                    help="the observers' wrong start guess (default: 0.3)")
    ap.add_argument("--soc0", type=soc_list_argument, default=[1.0],
                    help="start SoC: one for every record or one per record, in order")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a training setting, e.g. 'partition=[\"soc\",\"current\"]'")
    ap.add_argument("--through-hidden-pauses", action="store_true",
                    help=THROUGH_PAUSES_HELP)
    ap.add_argument("--plot", type=figure_file_argument, metavar="FILE.png",
                    help="also draw the results per held-out record")
    a = ap.parse_args()
    if a.together and not a.hold_out:
        ap.error("--together needs --hold-out PATTERN (the records held out together)")
    return a


def _observed_fold(a: argparse.Namespace, model: LmnModel, held: str,
                   held_soc0: float | None) -> Scores:
    """Each observer on the held-out record from --start-soc with the estimate --soc0-est, its
    line printed."""
    rec = read_record(held)
    if a.through_hidden_pauses:
        rec = rec.through_hidden_pauses()
    seg = observer_segment(record_to_segments(rec, model.sample_time_s,
                                              start_soc(rec, held_soc0), a.capacity_ah,
                                              current_delay_s=model.current_delay_s),
                           a.start_soc)
    k0 = start_index(seg, a.start_soc)
    scores: Scores = {}
    for kind in KINDS:
        m = soc_metrics(run_observer(model, seg, kind, a.soc0_est, k0))
        scores[kind] = (m["rmse_pct"], 100 * m["outside_3sigma_share"], m["median_3sigma_pct"])
        print(f"{Path(held).name[:40]:40s} {kind:5s} SoC RMSE {m['rmse_pct']:5.2f} %"
              f"  outside ±3σ {100 * m['outside_3sigma_share']:5.1f} %  median 3σ "
              f"{m['median_3sigma_pct']:5.1f} %", flush=True)
    return scores


def _caption(a: argparse.Namespace, n_folds: int) -> str:
    """The figure's caption: the split, where and how each observer started, the settings."""
    ocv = ", ".join(Path(f).name for f in a.ocv_tests) or "estimated from the records"
    title, words = fold_words(a.hold_out, a.together, len(a.records), "model")
    return (f"Observer {title.lower()}, {n_folds} held-out record(s): {words}; "
            f"each observer started where the reference SoC falls to {a.start_soc:g} "
            f"(under load) with the estimate {a.soc0_est:g}; SoC RMSE after the first "
            "10 minutes, and the share of all its samples whose reference SoC lies "
            "outside the observer's ±3σ band"
            + through_pauses_clause(a.through_hidden_pauses, "observer")
            + f". Settings: {', '.join(a.set) or 'defaults'};"
            f" OCV: {ocv}.")


if __name__ == "__main__":
    run_script(main, __file__)
