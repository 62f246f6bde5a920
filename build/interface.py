"""What both LMNCell FMUs declare alike: the initial unknowns' dependencies, and the archive's
file name.

In Initialization Mode an output already shows what exitInitializationMode will give; these are
the variables that value is computed from (ModelStructure/InitialUnknowns). During stepping the
outputs are computed in fmi2DoStep (the last completed model step's, or the voltage's preview of
the step in progress): no input set between steps reaches them directly, so the Outputs list no
dependencies.
"""

from __future__ import annotations

from pathlib import Path

INITIAL_DEPENDENCIES: dict[str, tuple[str, ...]] = {
    # OCV(soc0) plus the network's rest output at soc0 and the starting cell temperature
    "voltage": ("temperature", "soc0", "temperature_is_cell"),
    "soc": ("soc0",),
    "soc_std": ("observer",),
    "out_of_range": (),
    "cell_temperature": ("temperature", "temperature_is_cell"),
}


def dependency_indices(output: str, names: list[str]) -> str:
    """The `dependencies` attribute of an output: 1-based indices of its initial dependencies
    among the model variables `names` (in their order)."""
    return " ".join(str(names.index(n) + 1) for n in INITIAL_DEPENDENCIES[output])


class NativeBuildError(RuntimeError):
    """The C compiler or the FMI headers are missing, or compilation failed (the command line
    prints the message, which says what to install, without a traceback)."""


def fmu_path(out: str | Path) -> Path:
    """The FMU archive's path, which must end in .fmu (FMI 2.0: an FMU is a zip file with that
    extension; pythonfmu took any other name for a folder to put LMNCell.fmu in). ValueError
    naming the path otherwise."""
    path = Path(out)
    if path.suffix != ".fmu":
        raise ValueError(f"{path}: an FMU's file name must end in .fmu")
    return path
