"""Leave-one-record-out check of the identification: train on all records but one, simulate the
held-out record free-run, and compare the LMN with its baselines fitted on the same files.

Usage:
    python examples/leave_one_out.py CAPACITY_AH RECORD... [--soc0 1] [--set KEY=JSON ...]
        [--ocv-tests FILE] [--no-baselines]

Example (the four Panasonic 25 °C drive cycles of ../shared/data, the C/20 OCV test):
    P=../shared/data/panasonic_18650pf/25degC
    python examples/leave_one_out.py 2.85 $P/drive_cycles/*.mat \\
        --set 'partition=["soc","current"]' --ocv-tests $P/ocv_and_capacity/*C20_OCV*.mat

Per held-out record (all its segments pooled) it prints the free-run RMSE in mV over the 20–80 %
SoC window and over the whole record, for the LMN and each baseline, and the mean over the folds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from lmncell.evaluation.evaluate import evaluate_model
from lmncell.evaluation.metrics import pooled
from lmncell.identification.train import train_files

MODELS = ("lmn", "arx", "ecm2rc", "ecm2rc_hyst")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capacity_ah", type=float)
    ap.add_argument("records", nargs="+")
    ap.add_argument("--soc0", type=float, default=1.0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=JSON",
                    help="a training setting, e.g. 'partition=[\"soc\",\"current\"]'")
    ap.add_argument("--ocv-tests", nargs="*", default=[])
    ap.add_argument("--no-baselines", action="store_true")
    a = ap.parse_args()
    settings = {k: json.loads(v) for k, v in (s.split("=", 1) for s in a.set)}
    if a.ocv_tests:
        settings["ocv_tests"] = a.ocv_tests
    means: dict[str, list[float]] = {}
    tmp = tempfile.mkdtemp(prefix="lmncell-loo-")
    for held in a.records:
        train = [p for p in a.records if p != held]
        model, _ = train_files(train, Path(tmp) / "model.json",
                               capacity_ah=a.capacity_ah, soc0=a.soc0,
                               baselines=not a.no_baselines, progress=lambda _m: None,
                               **settings)
        _, rows = evaluate_model(model, [held], soc0=a.soc0)
        names = [m for m in MODELS if m in rows[0]]
        cells = []
        for m in names:
            per_segment = [r[m] for r in rows]
            w, whole = pooled(per_segment, "window_"), pooled(per_segment)
            means.setdefault(m, []).append(w)
            cells.append(f"{m} {w:6.2f} / {whole:6.1f}")
        print(f"{Path(held).name[:40]:40s} M={model.n_local_models:2d} E={model.arrhenius_k}  "
              + "  ".join(cells), flush=True)
    print("mean 20–80 % RMSE over the folds (mV): "
          + ", ".join(f"{m} {sum(v) / len(v):.2f}" for m, v in means.items()))


if __name__ == "__main__":
    main()
