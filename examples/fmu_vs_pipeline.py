"""Check an LMNCell FMU against the training pipeline on a real record.

Usage: python examples/fmu_vs_pipeline.py MODEL.json CELL.fmu RECORD [SOC0] [--ambient]
Drives the FMU with fmpy through the record's current (resampled to the model's sample time) and
prints the largest voltage and SoC differences to the pipeline's free-run simulation (of the
record's first segment; --ambient: both driven by the ambient temperature only).
"""

from __future__ import annotations

import argparse

from lmncell.cli import run_script, soc_argument
from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("model", help="the model file (JSON) the FMU was built from")
    ap.add_argument("fmu", help="the LMNCell FMU")
    ap.add_argument("record", help="a cycler record (any format lmncell reads)")
    ap.add_argument("soc0", nargs="?", type=soc_argument,
                    help="the record's start SoC (default: as lmncell evaluate finds it)")
    ap.add_argument("--ambient", action="store_true", help="drive both by the ambient "
                    "temperature only (the model's thermal model gives the cell temperature)")
    a = ap.parse_args()
    res = compare_fmu_with_pipeline(a.model, a.fmu, a.record, a.soc0, ambient=a.ambient)
    print(f"{res['record']}: {res['steps']} steps, max |Δvoltage| = {res['max_dv_v']:.3g} V, "
          f"max |ΔSoC| = {res['max_dsoc']:.3g}")


if __name__ == "__main__":
    run_script(main, __file__)
