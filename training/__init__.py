"""LMNCell: local model network (LMN) models of Lithium-ion cells identified from cycler data,
exported as FMI 2.0 co-simulation FMUs.

The API (see lmncell.api): read_record, train, load_model, simulate, evaluate, build_fmu, sweep.
Sub-packages: data (readers), identification, evaluation, design (experiment design),
scenarios (drive cycles), report, runtime (what runs inside the FMU), fmu (FMU builders).
"""

__version__ = "0.1.0"

from lmncell.api import (
    LmnModel,
    Record,
    SimResult,
    build_fmu,
    evaluate,
    load_model,
    read_record,
    simulate,
    sweep,
    train,
)

__all__ = ["LmnModel", "Record", "SimResult", "__version__", "build_fmu", "evaluate",
           "load_model", "read_record", "simulate", "sweep", "train"]
