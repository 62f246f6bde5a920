"""Build recipe of the pythonfmu LMNCell FMU (`lmncell build-fmu MODEL.json --out CELL.fmu`).

The FMU's resources hold the model file (`model.json`), a copy of the runtime package
`lmncell.runtime` (`fmu_src/`) renamed `lmncell_rt_<hash>` and a generated slave module
`lmncell_<hash>` (hash: of the model file), so that two LMNCell FMUs in one process each run
their own code. After pythonfmu has written the FMU, the model description is completed with
units, `InitialUnknowns`, a default experiment at the model's sample time, version and
generation tool.

The linux64 binary is pythonfmu 0.7.0's wrapper built from its sources with LMNCell's fixes
(`pythonfmu_wrapper/`, see its README): ordinary call errors return fmi2Error instead of freeing
the instance, a wrong GUID, Model Exchange or a missing resource location is refused, no memory
grows per instantiation, no heap corruption at exit. It sits beside a small C entry library
(`pythonfmu_wrapper/shim.c`) that loads a Python into a host without one (a C/C++ tool), so
that the FMU runs there too. It needs C and C++17 compilers and the Python headers where the
FMU is built; without them the FMU keeps pythonfmu's own binary (with a warning, and the
documentation says so).
"""

from __future__ import annotations

import hashlib
import html
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import warnings
import zipfile
from datetime import datetime
from pathlib import Path
from xml.etree import ElementTree as ET

import lmncell.runtime as runtime_package
from lmncell.fmu.interface import (
    INPUT_BOUNDS,
    build_time,
    dependency_indices,
    fmu_guid,
    fmu_path,
    zip_entry,
)
from lmncell.runtime.cosim import (
    MAX_C_RATE,
    MAX_STEPS_PER_CALL,
    MAX_TEMPERATURE_C,
    MIN_TEMPERATURE_C,
    VOLTAGE_MARGIN_V,
)
from lmncell.runtime.model import LmnModel, load_model, replaced_whole

RUNTIME_DIR = Path(runtime_package.__file__).resolve().parent
# The oldest Python that runs the runtime inside the pythonfmu FMU (zip(strict=...) and
# typing.TypeGuard are 3.10's); checked by the FMU's slave module before it imports the runtime
MIN_HOST_PYTHON = (3, 10)
MIN_HOST_PYTHON_TEXT = ".".join(map(str, MIN_HOST_PYTHON))
WRAPPER_DIR = Path(__file__).resolve().parent / "pythonfmu_wrapper"
WRAPPER_SOURCES = ("fmi2.cpp", "PySlaveInstance.cpp")  # and shim.c, the entry library
PATCHED, STOCK = "LMNCell's build of the PythonFMU 0.7.0 wrapper", "PythonFMU 0.7.0's wrapper"


class WrapperBuildError(RuntimeError):
    """The patched wrapper cannot be compiled here (no C or C++ compiler, or no Python
    headers)."""


def compile_wrapper(guid: str, out: Path, model_identifier: str = "LMNCell") -> list[Path]:
    """Compile the FMU's linux64 libraries into the folder `out` for an FMU with this GUID:
    pythonfmu_wrapper/ as `<model_identifier>_python.so` (C++17, Python's stable ABI from 3.8
    on, the FMI 2.0 headers from fmpy) and the entry library `shim.c` as
    `<model_identifier>.so`, which loads a Python where the host has none and then the
    wrapper; with g++ and gcc, or zig where they are missing (native_build.compiler). Returns
    both paths, the entry library first."""
    from lmncell.fmu.native_build import (
        NO_COMPILER_ADVICE,
        NativeBuildError,
        compiler,
        fmi_headers,
    )

    if not (sys.platform.startswith("linux") and sys.maxsize > 2**32):
        raise WrapperBuildError(f"the patched wrapper is built for linux64 only (this is "
                                f"{sys.platform})")
    cxx, cc = compiler("c++"), compiler("c")
    if cxx is None or cc is None:
        raise WrapperBuildError("no " + " and no ".join(
            what for what, found in (("C++ compiler (g++ or c++)", cxx),
                                     ("C compiler (gcc or cc)", cc)) if found is None)
            + f" found: {NO_COMPILER_ADVICE}")
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").exists():
        raise WrapperBuildError(f"no Python headers ({include / 'Python.h'} is missing)")
    try:
        fmi = fmi_headers()
    except NativeBuildError as exc:
        raise WrapperBuildError(str(exc)) from None
    env = native_host_environment() or {}
    entry, wrapper = out / f"{model_identifier}.so", out / f"{model_identifier}_python.so"
    _compile([*cxx, "-std=c++17", "-O2", "-fPIC", "-shared", "-DPy_LIMITED_API=0x03080000",
              f'-DLMNCELL_GUID="{guid}"', f'-DLMNCELL_SITE_PATHS="{env.get("PYTHONPATH", "")}"',
              f"-I{WRAPPER_DIR}", f"-I{fmi}", f"-I{include}",
              *(str(WRAPPER_DIR / s) for s in WRAPPER_SOURCES), "-o", str(wrapper)])
    _compile([*cc, "-std=c99", "-O2", "-fPIC", "-shared", f"-I{fmi}",
              f'-DLMNCELL_LIBPYTHON_PATH="{env.get("LD_PRELOAD", "")}"',
              f'-DLMNCELL_LIBPYTHON_SONAME="{sysconfig.get_config_var("INSTSONAME") or ""}"',
              f'-DLMNCELL_PYTHON_HOME="{python_home() if env else ""}"',
              f'-DLMNCELL_MIN_PYTHON="{MIN_HOST_PYTHON_TEXT}"',
              f'-DLMNCELL_INNER="{wrapper.name}"', str(WRAPPER_DIR / "shim.c"), "-o", str(entry),
              "-ldl", "-lpthread"])
    return [entry, wrapper]


def _compile(cmd: list[str]) -> None:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise WrapperBuildError(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")


UNITS = {"current": "A", "voltage_measured": "V", "temperature": "degC", "voltage": "V",
         "soc": "1", "soc0": "1", "capacity": "Ah", "soc_std": "1", "cell_temperature": "degC",
         "cell_temperature_start": "degC"}
UNIT_BASE = {"A": {"A": "1"}, "V": {"kg": "1", "m": "2", "s": "-3", "A": "-1"},
             "degC": {"K": "1", "offset": "273.15"}, "Ah": {"s": "1", "A": "1",
                                                             "factor": "3600"}, "1": {}}


def model_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


PYTHON_CHECK = """import sys

if sys.version_info < {need!r}:
    raise ImportError("LMNCell FMU {module_hash} runs its model on Python {need_text} or later; "
                      "this host's Python is " + sys.version.split()[0] + " (" + sys.prefix
                      + "). Give it a newer Python (in a native host LMNCELL_LIBPYTHON), or "
                      "use the model's native FMU (lmncell build-fmu --native): it needs none")
"""


def slave_source(module_hash: str, model: LmnModel) -> str:
    """The FMU's slave module: the host's Python checked first (an older one gets an ImportError
    that says what to do, which pythonfmu's wrapper logs before fmi2Instantiate returns NULL,
    not an error from deep inside the runtime), then the model's class."""
    check = PYTHON_CHECK.format(need=MIN_HOST_PYTHON, need_text=MIN_HOST_PYTHON_TEXT,
                                module_hash=module_hash)
    return (f'"""LMNCell FMU slave (generated for model {module_hash})."""\n\n{check}\n'
            f"from lmncell_rt_{module_hash}.slave import LmnCellSlave, keep_module_dict\n\n"
            "keep_module_dict(globals())  # balances pythonfmu 0.7.0 (see slave.py)\n\n\n"
            "class LMNCell(LmnCellSlave):\n"
            f'    """{model.extra.get("description", "LMNCell model")}."""\n\n'
            f'    description = {model.extra.get("description", "LMNCell model")!r}\n'
            f'    version = "{module_hash}"\n')


FLAVOURS = {
    "pythonfmu": f"Generated by LMNCell with PythonFMU: needs Python {MIN_HOST_PYTHON_TEXT} or "
                 "later with numpy on the importing side (pythonfmu's Python part travels in "
                 "the FMU's resources). A Python host (fmpy, libcosim through libcosimpy) has "
                 "them. In a native (C/C++) host on Linux the FMU's entry "
                 "library loads a Python itself: <code>$LMNCELL_LIBPYTHON</code> if set, else "
                 "the library of the Python that built the FMU, else libpython of its version "
                 "on the system's search path; numpy comes from "
                 "<code>$PYTHONPATH</code> or the building Python's site-packages. Where none "
                 "is found, fmi2Instantiate logs what to set and returns NULL. The native "
                 "flavour needs none of this.",
    "native": "Generated by LMNCell as C (sources/ included; binaries/linux64 built with gcc "
              "or zig, binaries/win64 and binaries/darwin64 (Intel and Apple silicon, macOS 11 or "
              "later), where present, cross-compiled with zig, other platforms with "
              "<code>fmpy compile</code>): no Python needed on the importing side.",
}


WRAPPERS = {
    PATCHED: " Its linux64 binary is LMNCell's build of PythonFMU 0.7.0's wrapper: an ordinary "
             "call error (unknown value reference, wrong type, fixed parameter set after "
             "initialisation, refused step) is logged and returns fmi2Error; a wrong GUID or "
             "Model Exchange is refused. Its win64 binary is PythonFMU's own.",
    STOCK: " Its binaries are PythonFMU 0.7.0's own wrapper: an ordinary call error is logged "
           "and the call ignored (status OK; a refused step returns fmi2Discard), because that "
           "wrapper turns any error into fmi2Fatal and frees the instance.",
}


def _file_name(entry: dict) -> str:
    """A training file's name in a model file's metadata ("name"; model files written before
    December 2026 give its "path")."""
    return entry.get("name") or Path(entry.get("path", "?")).name


def documentation_html(model: LmnModel, model_path: Path, flavour: str = "pythonfmu",
                       wrapper: str = STOCK) -> str:
    """documentation/index.html: cell, data, sample time, accuracy and limits of the model;
    flavour "pythonfmu" or "native" says what the importer needs (and for pythonfmu, which
    wrapper the linux64 binary is)."""
    tr = model.extra.get("training", {})
    files = "".join(f"<li>{html.escape(_file_name(f))}{note} <small>sha256 "
                    f"{f['sha256'][:16]}…</small></li>"
                    for key, note in (("files", ""), ("ocv_test_files", " (slow OCV test)"))
                    for f in tr.get(key, []))
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v[0]:.4g} … {v[1]:.4g}</td></tr>"
                   for k, v in model.limits.items())
    acc = _accuracy_rows(tr.get("train_metrics", []))
    thermal_text = _temperature_input_text(model)
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>LMNCell FMU</title></head>
<body><h1>LMNCell FMU: {html.escape(model.cell.get('name', 'cell'))}</h1>
<p>{html.escape(model.extra.get('description', ''))}. Model file {html.escape(model_path.name)},
sample time Ts = {model.sample_time_s} s, {model.n_local_models} local models over
{', '.join(model.partition_variables)}, capacity {model.capacity_ah:.4f} Ah.</p>
<h2>Interface</h2><ul>
<li><b>current</b> (input, A): held over the communication step, &gt; 0 charges.</li>
<li><b>voltage_measured</b> (input, V): mean measured voltage over the step (observer).</li>
<li><b>temperature</b> (input, degC): {thermal_text}</li>
<li><b>voltage</b> (output, V): model terminal voltage of the last completed model step; between
model steps (communication steps shorter than Ts, no observer) the step in progress previewed as if
the latest current had been held over all of it, so that it follows each input at once.</li>
<li><b>soc</b> (output): state of charge, coulomb-counted or the observer's estimate;
<b>soc_std</b> (output): the observer's standard deviation; <b>out_of_range</b> (output): true
while the inputs leave the trained region or the model's voltage its trained range by more than
{VOLTAGE_MARGIN_V:g} V (the model extrapolates, nothing is clamped).</li>
<li><b>soc0</b>, <b>capacity</b> (Ah), <b>observer</b> (0 none, 1 EKF, 2 fuzzy, 3 IMM):
parameters. The observers compare the model with <b>voltage_measured</b> (0 = no update).</li>
</ul>
<p>Sub-stepping: inputs are integrated over the communication step; each completed Ts is one
model step with the mean inputs over it. A step that is a multiple of Ts gives that many
sub-steps; other steps are accumulated exactly across calls. The outputs hold the last completed
model step (the voltage between model steps: the step in progress previewed). A NaN or
infinite input, a current beyond {MAX_C_RATE:g} C, a temperature outside
{MIN_TEMPERATURE_C:g}…{MAX_TEMPERATURE_C:g} °C (°C, not K: the input's min and max) and a
communication step of more than {MAX_STEPS_PER_CALL:,} model steps are refused with fmi2Error
and a logged message; the step is not taken.</p>
<h2>Training data</h2><ul>{files}</ul>
<h2>Trained region</h2><table border="1"><tr><th>quantity</th><th>range</th></tr>{rows}</table>
<h2>Free-run accuracy on the training records</h2><table border="1"><tr><th>segment</th>
<th>RMSE / mV</th><th>RMSE 20–80 % SoC / mV</th><th>max / mV</th></tr>{acc}</table>
<p>{FLAVOURS[flavour]}{WRAPPERS[wrapper] if flavour == "pythonfmu" else ""}</p>
</body></html>"""


def _accuracy_rows(metrics: list[dict]) -> str:
    """The documentation's rows of free-run accuracy per training segment (mV; – where a figure
    is missing, e.g. no sample in the 20–80 % SoC window)."""
    def num(v: float | None, fmt: str) -> str:
        return "–" if v is None else format(v, fmt)

    return "".join(f"<tr><td>{html.escape(m['segment'])}</td><td>{num(m['rmse_mv'], '.2f')}</td>"
                   f"<td>{num(m['window_rmse_mv'], '.2f')}</td><td>{num(m['max_mv'], '.1f')}"
                   "</td></tr>" for m in metrics)


def _temperature_input_text(model: LmnModel) -> str:
    """What the documentation says the `temperature` input is: the ambient temperature where the
    model has a thermal model, else the cell temperature."""
    th = model.thermal
    if th is None:
        return ("the cell temperature (the model has no thermal model: its training data "
                "had no measured cell temperature); <b>cell_temperature</b> repeats it.")
    return ("the ambient temperature; the model computes the cell temperature with its "
            f"lumped thermal model (R = {th.resistance_k_per_w:.3g} K/W, τ = "
            f"{th.time_constant_s:.0f} s), output <b>cell_temperature</b>. With the "
            "parameter <b>temperature_is_cell</b> = true it is the measured cell "
            "temperature instead. The cell starts rested at the first ambient, or at the "
            "parameter <b>cell_temperature_start</b> (degC) where "
            "<b>use_cell_temperature_start</b> = true (a cell warmer or colder than the air "
            "it meets).")


def _indent(elem: ET.Element) -> None:
    ET.indent(elem, space="  ")


def _element(parent: ET.Element, tag: str) -> ET.Element:
    """parent's child element tag; ValueError where pythonfmu's model description has none."""
    child = parent.find(tag)
    if child is None:
        raise ValueError(f"pythonfmu's modelDescription.xml has no <{tag}> in <{parent.tag}>")
    return child


def patch_model_description(xml_text: str, model: LmnModel, module_hash: str,
                            wrapper: str = STOCK, when: datetime | None = None) -> str:
    """Set the GUID (interface.fmu_guid) and add units, InitialUnknowns, default experiment,
    version and generation tool (which names the wrapper in the linux64 binary); with `when`
    (interface.build_time) also the generation time."""
    from lmncell import __version__

    root = ET.fromstring(xml_text)
    root.set("guid", fmu_guid("pythonfmu", module_hash))
    if when is not None:
        root.set("generationDateAndTime", when.strftime("%Y-%m-%dT%H:%M:%SZ"))
    root.set("generationTool", f"LMNCell {__version__} ({wrapper})")
    root.set("version", module_hash)
    root.set("description", model.extra.get("description", "LMNCell model"))
    variables = _element(root, "ModelVariables")
    _add_units_and_bounds(root, variables)
    ex = root.find("DefaultExperiment")
    if ex is None:
        ex = ET.Element("DefaultExperiment")
        root.insert(list(root).index(variables), ex)
    ex.set("startTime", "0.0")
    ex.set("stopTime", repr(3600.0))
    ex.set("stepSize", repr(float(model.sample_time_s)))
    _set_initial_unknowns(_element(root, "ModelStructure"),
                          [sv.get("name", "") for sv in variables.findall("ScalarVariable")])
    _indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode")


def _add_units_and_bounds(root: ET.Element, variables: ET.Element) -> None:
    """Each Real variable's unit (UNITS) and input bounds (INPUT_BOUNDS), and the
    UnitDefinitions of the units used, inserted where FMI 2.0's element order puts them."""
    used = set()
    for sv in variables.findall("ScalarVariable"):
        name = sv.get("name")
        real = sv.find("Real")
        if real is not None and name in UNITS:
            real.set("unit", UNITS[name])
            used.add(UNITS[name])
        if real is not None and name in INPUT_BOUNDS:
            real.set("min", repr(INPUT_BOUNDS[name][0]))
            real.set("max", repr(INPUT_BOUNDS[name][1]))
    units = ET.Element("UnitDefinitions")
    for unit_name in sorted(used):
        unit = ET.SubElement(units, "Unit", {"name": unit_name})
        if UNIT_BASE[unit_name]:
            ET.SubElement(unit, "BaseUnit", UNIT_BASE[unit_name])
    children = list(root)
    pos = next(k for k, c in enumerate(children) if c.tag in ("LogCategories",
                                                              "DefaultExperiment",
                                                              "ModelVariables"))
    root.insert(pos, units)


def _set_initial_unknowns(structure: ET.Element, names: list[str]) -> None:
    """ModelStructure's InitialUnknowns (each output with the variables it depends on at
    initialisation, dependency_indices) in place of pythonfmu's, and the outputs' empty
    dependencies (no direct feedthrough within a communication step)."""
    outputs = structure.find("Outputs")
    old = structure.find("InitialUnknowns")
    if old is not None:
        structure.remove(old)
    if outputs is None:
        return
    init = ET.SubElement(structure, "InitialUnknowns")
    for u in outputs.findall("Unknown"):
        index = u.get("index", "")
        name = names[int(index) - 1]
        ET.SubElement(init, "Unknown", {"index": index,
                                        "dependencies": dependency_indices(name, names)})
    for u in outputs.findall("Unknown"):
        u.set("dependencies", "")


def _rewrite_members(fmu: Path, members: dict[str, bytes], when: datetime | None = None
                     ) -> None:
    """Replace the contents of the named zip members (same names, same order) and add, at the
    end, those the FMU does not have yet; with `when` (interface.build_time) every member dated
    then, else the existing ones as pythonfmu dated them."""
    with replaced_whole(fmu) as tmp, zipfile.ZipFile(fmu) as zin, \
            zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            header = item if when is None else zip_entry(item.filename, when)
            zout.writestr(header, members.get(item.filename, zin.read(item.filename)))
        for name in sorted(members.keys() - set(zin.namelist())):
            zout.writestr(zip_entry(name, when), members[name])


def native_host_environment() -> dict[str, str] | None:
    """This Python's shared library and the directories holding numpy and pythonfmu, as the
    environment {"LD_PRELOAD": ..., "PYTHONPATH": ...} under which a native (C/C++) host on
    Linux runs a pythonfmu FMU (pythonfmu's wrapper leaves Python's symbols to the host). The
    entry library of LMNCell's pythonfmu FMU has both built in. None where this Python has no
    shared library (a static build) or this is not Linux."""
    import numpy
    import pythonfmu

    libdir, ldlib = sysconfig.get_config_var("LIBDIR"), sysconfig.get_config_var("LDLIBRARY")
    if not (sys.platform.startswith("linux") and sysconfig.get_config_var("Py_ENABLE_SHARED")
            and libdir and ldlib and (Path(libdir) / ldlib).is_file()):
        return None
    paths = dict.fromkeys(str(Path(m.__file__).resolve().parent.parent)
                          for m in (numpy, pythonfmu) if m.__file__)
    return {"LD_PRELOAD": str(Path(libdir) / ldlib), "PYTHONPATH": ":".join(paths)}


def python_home() -> str:
    """This Python's installation as PYTHONHOME reads it: base_prefix[:base_exec_prefix]."""
    return (sys.base_prefix if sys.base_exec_prefix == sys.base_prefix
            else f"{sys.base_prefix}:{sys.base_exec_prefix}")


def native_host_hint(fmu: str | Path) -> str:
    """One line for the user of a pythonfmu FMU built here: what a native (C/C++) host on Linux
    needs to run it ('' for LMNCell's wrapper where this Python has no shared library to
    name)."""
    with zipfile.ZipFile(fmu) as z:
        tool = ET.fromstring(z.read("modelDescription.xml")).get("generationTool", "")
    if PATCHED not in tool:
        return (f"it carries {STOCK}, which needs the host's Python and frees memory twice as a "
                "native host exits: use it in Python hosts only (or build it where gcc and g++, "
                "or pip's ziglang, are installed)")
    env = native_host_environment()
    if env is None:
        return ""
    return (f"a native (C/C++) host on Linux runs it as is on this machine (it loads "
            f"{env['LD_PRELOAD']} and finds numpy in {env['PYTHONPATH']}); "
            "elsewhere set LMNCELL_LIBPYTHON to a libpython3.x.so "
            f"({MIN_HOST_PYTHON_TEXT} or later) and PYTHONPATH to a site-packages with numpy")


def patched_binary(guid: str, model_identifier: str) -> dict[str, bytes]:
    """{zip member: bytes} of the patched linux64 libraries (entry and wrapper), or {} (with a
    warning) where they cannot be built here."""
    with tempfile.TemporaryDirectory(prefix="lmncell_wrapper_") as tmp:
        try:
            paths = compile_wrapper(guid, Path(tmp), model_identifier)
        except WrapperBuildError as exc:
            warnings.warn(f"the pythonfmu FMU keeps {STOCK} (ordinary call errors are logged and "
                          f"ignored, see the README): {exc}", UserWarning, stacklevel=3)
            return {}
        return {f"binaries/linux64/{p.name}": p.read_bytes() for p in paths}


def build_fmu(model_path: str | Path, out: str | Path) -> Path:
    """Write the pythonfmu FMU of a model file; returns its path."""
    model_file, archive = Path(model_path), fmu_path(out)
    model = load_model(model_file)
    when = build_time()       # a bad SOURCE_DATE_EPOCH is refused before the build
    h = model_hash(model_file)
    archive.parent.mkdir(parents=True, exist_ok=True)
    with replaced_whole(archive) as part:    # no half-written FMU where the build fails
        _pythonfmu_archive(model_file, model, h, part)
        _patch_archive(part, model_file, model, h, when)
    return archive


def _pythonfmu_archive(model_file: Path, model: LmnModel, h: str, archive: Path) -> None:
    """pythonfmu's FMU of the model file (its slave class, the runtime package and the model
    file as project files, the documentation), written to archive."""
    from pythonfmu.builder import FmuBuilder

    with tempfile.TemporaryDirectory(prefix="lmncell_fmu_") as tmp:
        stage = Path(tmp)
        pkg = stage / f"lmncell_rt_{h}"
        pkg.mkdir()
        for f in RUNTIME_DIR.glob("*.py"):
            shutil.copy2(f, pkg / f.name)
        shutil.copy2(model_file, stage / "model.json")
        script = stage / f"lmncell_{h}.py"
        script.write_text(slave_source(h, model), encoding="utf-8")
        doc = stage / "documentation"
        doc.mkdir()
        (doc / "index.html").write_text(documentation_html(model, model_file), encoding="utf-8")
        try:
            FmuBuilder.build_FMU(script, dest=archive, project_files=[pkg, stage / "model.json"],
                                 documentation_folder=doc, canGetAndSetFMUstate=True,
                                 canSerializeFMUstate=True)
        finally:
            while str(stage) in sys.path:
                sys.path.remove(str(stage))
            for name in [n for n in sys.modules if n.startswith((f"lmncell_rt_{h}",
                                                                  f"lmncell_{h}"))]:
                del sys.modules[name]


def _patch_archive(archive: Path, model_file: Path, model: LmnModel, h: str,
                   when: datetime | None) -> None:
    """pythonfmu's FMU made LMNCell's: the patched wrapper where it was built, the model
    description and documentation completed, every member dated `when`."""
    with zipfile.ZipFile(archive) as z:
        xml_text = z.read("modelDescription.xml").decode("utf-8")
    root = ET.fromstring(xml_text)
    members = patched_binary(fmu_guid("pythonfmu", h),
                             _element(root, "CoSimulation").get("modelIdentifier", ""))
    wrapper = PATCHED if members else STOCK
    members["modelDescription.xml"] = patch_model_description(xml_text, model, h, wrapper,
                                                              when).encode("utf-8")
    members["documentation/index.html"] = documentation_html(
        model, model_file, "pythonfmu", wrapper).encode("utf-8")
    _rewrite_members(archive, members, when)
