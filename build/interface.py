"""What both LMNCell FMUs declare alike: the initial unknowns' dependencies, and the archive's
file name.

In Initialization Mode an output already shows what exitInitializationMode will give; these are
the variables that value is computed from (ModelStructure/InitialUnknowns). During stepping the
outputs are computed in fmi2DoStep (the last completed model step's, or the voltage's preview of
the step in progress): no input set between steps reaches them directly, so the Outputs list no
dependencies.
"""

from __future__ import annotations

import os
import uuid
import zipfile
from datetime import UTC, datetime
from pathlib import Path

from lmncell.config import ConfigError
from lmncell.runtime.thermal import CELL_TEMPERATURE_RANGE_C

ZIP_EPOCH_S = 315532800   # 1980-01-01T00:00:00Z, the earliest date a zip member can carry

INITIAL_DEPENDENCIES: dict[str, tuple[str, ...]] = {
    # OCV(soc0) plus the network's rest output at soc0 and the starting cell temperature
    "voltage": ("temperature", "soc0", "temperature_is_cell", "cell_temperature_start",
                "use_cell_temperature_start"),
    "soc": ("soc0",),
    "soc_std": ("observer",),
    "out_of_range": (),
    "cell_temperature": ("temperature", "temperature_is_cell", "cell_temperature_start",
                         "use_cell_temperature_start"),
}


INPUT_BOUNDS: dict[str, tuple[float, float]] = {
    # the Real min and max both FMUs declare for an input: the range outside which a step
    # with it is refused (fmi2Error); hosts that check min and max catch it before the call
    "temperature": CELL_TEMPERATURE_RANGE_C,
}


def dependency_indices(output: str, names: list[str]) -> str:
    """The `dependencies` attribute of an output: 1-based indices of its initial dependencies
    among the model variables `names` (in their order)."""
    return " ".join(str(names.index(n) + 1) for n in INITIAL_DEPENDENCIES[output])


def fmu_guid(flavour: str, model_hash: str) -> str:
    """An FMU's GUID: a fingerprint of its flavour ("native" or "pythonfmu") and its model file
    (the file's hash), as the FMI standard suggests, so that one model gives the same GUID in
    every build of a flavour (pythonfmu's own is time-based, new at each build)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"lmncell-{flavour}:{model_hash}"))


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


def build_time() -> datetime | None:
    """The time set by SOURCE_DATE_EPOCH (seconds since 1970 UTC; reproducible-builds.org), which
    both builders then give every archive member and the pythonfmu FMU its
    generationDateAndTime, so that two builds of one model are byte-identical; None where it is
    not set (then the members carry the time of the build). ConfigError naming it where it is not
    a whole number of seconds from 1980 on."""
    text = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not text:
        return None
    try:
        seconds = int(text)
    except ValueError:
        seconds = -1
    if seconds < ZIP_EPOCH_S:
        raise ConfigError(f"SOURCE_DATE_EPOCH = {text!r}: expected a whole number of seconds "
                          f"since 1970 (UTC), at least {ZIP_EPOCH_S} (1980, the zip format's "
                          "earliest date)")
    return datetime.fromtimestamp(seconds, tz=UTC)


def zip_entry(name: str, when: datetime | None) -> zipfile.ZipInfo:
    """An archive member's header: deflated, readable by all (-rw-r--r--; the shared libraries
    under binaries/ also executable, -rwxr-xr-x), dated `when` (UTC) or, where it is None, now
    (local time, as zipfile dates members)."""
    stamp = when.astimezone(UTC) if when is not None else datetime.now()
    info = zipfile.ZipInfo(name, date_time=stamp.timetuple()[:6])
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = (0o755 if name.startswith("binaries/") else 0o644) << 16
    return info
