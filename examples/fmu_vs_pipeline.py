"""Check an LMNCell FMU against the training pipeline on a real record.

Usage: python examples/fmu_vs_pipeline.py MODEL.json CELL.fmu RECORD [SOC0]
Drives the FMU with fmpy through the record's current (resampled to the model's sample time) and
prints the largest voltage and SoC differences to the pipeline's free-run simulation.
"""

from __future__ import annotations

import sys

from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline


def main(model: str, fmu: str, record: str, soc0: str | None = None) -> None:
    res = compare_fmu_with_pipeline(model, fmu, record, None if soc0 is None else float(soc0))
    print(f"{res['record']}: {res['steps']} steps, max |Δvoltage| = {res['max_dv_v']:.3g} V, "
          f"max |ΔSoC| = {res['max_dsoc']:.3g}")


if __name__ == "__main__":
    main(*sys.argv[1:])
