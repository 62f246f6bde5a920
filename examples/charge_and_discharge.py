"""Charge records in the training: does the LMN then follow the charge branch of an LFP cell
(hysteresis), and what does it do to the discharge? Leave-one-temperature-out on Plett's A123
tests: per held-out test temperature, one model trained on the other tests' discharge records
(s1) alone and one trained on them plus the charge records (s3, which Plett's procedure runs at
25 °C and which start empty), both judged free-run on the held-out test's discharge (s1) and
charge (s3) records.

Usage:
    python examples/charge_and_discharge.py CAPACITY_AH DYN_DIR [--temperatures N15,N05,P05,P25,P45]
        [--hold-out P05,P25] [--plot DIR]

Example (../shared/data):
    python examples/charge_and_discharge.py 2.0307 ../shared/data/a123_plett/dyn --plot charge

Prints RMSE over the 20–80 % SoC window / the whole record (mV) and the hysteresis rate the
training chose; --plot writes, per fold, the held-out charge record with both models.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from lmncell.cli import capacity_argument, output_folder_argument, run_script
from lmncell.data.records import DataError
from lmncell.evaluation.evaluate import Trace, evaluate_model
from lmncell.evaluation.metrics import pooled
from lmncell.identification.train import train_files
from lmncell.runtime.model import LmnModel


def test_file(dyn: Path, temperature: str, script: str) -> Path:
    """The A123 dynamic-test file of one test temperature (e.g. P05) and script (s1, s3)."""
    found = sorted(dyn.glob(f"A123_DYN_*_{temperature}_{script}.csv*"))
    if not found:
        raise DataError(f"{dyn}: no A123_DYN_*_{temperature}_{script}.csv[.gz]: expected "
                        "Plett's dynamic-test files (s1 discharge, s3 charge)")
    return found[0]


def judged(model: LmnModel, path: Path, soc0: float) -> tuple[float, float, list[Trace]]:
    """Free-run RMSE (mV) over the 20–80 % window and the whole record, and the traces."""
    traces, rows = evaluate_model(model, [path], soc0=soc0)
    per = [r["lmn"] for r in rows]
    return pooled(per, "window_"), pooled(per), traces


def plot_fold(held: str, traces: dict[str, list[Trace]], out: Path) -> Path:
    from lmncell.report.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(9, 4.5))
    first = next(iter(traces.values()))
    for t in first:
        ax.plot(t.segment.time_s / 3600, t.segment.voltage_v, "k", lw=0.8)
    for name, ts in traces.items():
        for k, t in enumerate(ts):
            ax.plot(t.segment.time_s / 3600, t.voltage["lmn"], lw=0.8,
                    label=name if k == 0 else None)
    ax.set_xlabel("time / h")
    ax.set_ylabel("terminal voltage / V")
    ax.set_title(f"held-out charge record of the {held} test (25 °C, from empty); black: "
                 "measured", fontsize=9)
    ax.legend(fontsize=8)
    path = out / f"charge_{held}.png"
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capacity_ah", type=capacity_argument, help="the cell's capacity (Ah)")
    ap.add_argument("dyn_dir", type=Path,
                    help="the folder of Plett's A123 dynamic tests (A123_DYN_*_s1/s3.csv[.gz])")
    ap.add_argument("--temperatures", default="N15,N05,P05,P25,P45",
                    help="comma list of the test temperatures in the file names to train on "
                    "(default: N15,N05,P05,P25,P45)")
    ap.add_argument("--hold-out", default="P05,P25",
                    help="comma list of those held out, one fold each (default: P05,P25)")
    ap.add_argument("--plot", type=output_folder_argument, metavar="DIR",
                    help="write each fold's held-out charge record with both models here")
    a = ap.parse_args()
    temps = a.temperatures.split(",")
    plot_dir = Path(a.plot) if a.plot else None
    if plot_dir:
        plot_dir.mkdir(parents=True, exist_ok=True)
    for held in a.hold_out.split(","):
        if held not in temps:
            raise DataError(f"--hold-out {held}: not among --temperatures {a.temperatures}")
    with tempfile.TemporaryDirectory(prefix="lmncell-charge-") as tmp:
        for held in a.hold_out.split(","):
            traces = held_out_fold(a.dyn_dir, held, [t for t in temps if t != held],
                                   a.capacity_ah, Path(tmp) / "model.json")
            if plot_dir:
                print(f"  wrote {plot_fold(held, traces, plot_dir)}")


def held_out_fold(dyn: Path, held: str, others: list[str], capacity_ah: float,
                  model_file: Path) -> dict[str, list[Trace]]:
    """Train on the other temperatures' s1 records alone and with their s3 records, print
    each model's figures on the held-out temperature's s1 and s3 records, and return each
    model's traces of the held-out charge record."""
    discharges = [test_file(dyn, t, "s1") for t in others]
    charges = [test_file(dyn, t, "s3") for t in others]
    records = {"discharge": test_file(dyn, held, "s1"), "charge": test_file(dyn, held, "s3")}
    traces: dict[str, list[Trace]] = {}
    for name, files, soc0 in (
            ("s1 only", discharges, [1.0] * len(discharges)),
            ("s1 + s3", discharges + charges, [1.0] * len(discharges) + [0.0] * len(charges))):
        model, _ = train_files(files, model_file, capacity_ah=capacity_ah, soc0=soc0,
                               progress=lambda _m: None)
        cells = []
        for kind, path in records.items():
            window, whole, tr = judged(model, path, 1.0 if kind == "discharge" else 0.0)
            cells.append(f"{kind} {window:5.2f} / {whole:5.1f}")
            if kind == "charge":
                traces[f"trained on {name}"] = tr
        gamma = model.hysteresis_gamma
        print(f"held out {held}, trained on {name:7s} (M={model.n_local_models}, hysteresis "
              f"{'off' if gamma is None else f'γ = {gamma:g}'}): " + "  ".join(cells),
              flush=True)
    return traces


if __name__ == "__main__":
    run_script(main, __file__)
