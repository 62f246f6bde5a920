"""The native (C) LMNCell FMU (issue: native FMU)."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from fmpy.validation import validate_fmu
from lmncell.data.dataset import record_to_segments
from lmncell.data.readers import read_record
from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline
from lmncell.runtime.cosim import held_delayed_currents
from lmncell.runtime.model import load_model
from lmncell.runtime.observers import SocObserver
from lmncell.runtime.step import CellStepper, simulate_ambient

from tests.conftest import A123_S1, PAN_US06, ROOT, c_compiler_or_skip, import_or_skip
from tests.fmu_helpers import (
    HOST_C,
    THREADS_C,
    Instance,
    assert_state_round_trips,
    compile_host,
    fmpy_run,
    fmu_reports,
    libcosim_run,
    refuse_bad_current,
    unzip_fmu,
)


@pytest.fixture(scope="module")
def us06(quick_model):
    return load_model(quick_model), record_to_segments(read_record(PAN_US06), 1.0, 1.0, 2.85)[0]


def test_native_fmu_validates_and_ships_sources(native_fmu) -> None:
    assert validate_fmu(str(native_fmu)) == []
    with zipfile.ZipFile(native_fmu) as z:
        names = set(z.namelist())
    assert {"binaries/linux64/LMNCell.so", "sources/lmncell.c", "sources/lmncell_model.h",
            "sources/buildDescription.xml", "documentation/index.html"} <= names


OLDEST_GLIBC = (2, 17)   # CentOS 7's; RHEL 8 has 2.28, where exp@GLIBC_2.29 failed to load


def _glibc_versions(binary: bytes) -> set[tuple[int, ...]]:
    """The glibc symbol versions an ELF library requires (its version-need names)."""
    return {tuple(int(x) for x in v.split(b".")) for v in re.findall(rb"GLIBC_(2(?:\.\d+)+)",
                                                                     binary)}


def test_the_linux64_binary_loads_where_glibc_is_older(native_fmu, tmp_path) -> None:
    """The native FMU's .so requires no glibc symbol newer than OLDEST_GLIBC (built here on
    glibc 2.36, it required exp@GLIBC_2.29, so no host on glibc 2.28 or older could load it);
    the source's binding of exp, exp2, log, log2 and pow holds for each of them."""
    with zipfile.ZipFile(native_fmu) as z:
        versions = _glibc_versions(z.read("binaries/linux64/LMNCell.so"))
    assert versions and max(versions) <= OLDEST_GLIBC, sorted(versions)
    source = (Path(__file__).parents[1] / "build" / "native" / "lmncell.c").read_text()
    binding = re.search(r"#if defined\(LMNCELL_GLIBC_BASELINE\).*?#endif\n", source, re.DOTALL)
    assert binding, "lmncell.c binds no glibc math symbols"
    probe = tmp_path / "probe.c"
    probe.write_text("#include <math.h>\n" + binding.group(0) + "double f(double x, double y) "
                     "{ return exp(x) + exp2(x) + log(x) + log2(x) + pow(x, y); }\n")
    from lmncell.fmu.native_build import compiler

    subprocess.run([*compiler("c"), "-std=c99", "-O2", "-fPIC", "-shared",
                    "-DLMNCELL_GLIBC_BASELINE", str(probe), "-o",
                    str(tmp_path / "probe.so"), "-lm"], check=True)
    probed = _glibc_versions((tmp_path / "probe.so").read_bytes())
    assert probed and max(probed) <= OLDEST_GLIBC, sorted(probed)


def test_without_a_c_compiler_build_fmu_says_what_to_install(quick_model, tmp_path,
                                                              monkeypatch, capsys) -> None:
    """No gcc and no zig: `lmncell build-fmu --native` ends with the message and exit status 2,
    no traceback (it printed one), and writes no FMU."""
    from lmncell.cli import main
    from lmncell.fmu import native_build

    which = shutil.which
    monkeypatch.setattr(native_build.shutil, "which",
                        lambda name: None if name in ("gcc", "cc") else which(name))
    monkeypatch.setattr(native_build.importlib.util, "find_spec", lambda name: None)
    out = tmp_path / "cell.fmu"
    assert main(["build-fmu", str(quick_model), "--out", str(out), "--native"]) == 2
    err = capsys.readouterr().err
    assert ("build-fmu: error: no C compiler found: install gcc and g++, or pip install "
            "ziglang (a C and C++ compiler from pip), to build the native FMU") in err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.skipif(importlib.util.find_spec("ziglang") is None,
                    reason="ziglang is not installed (pip install ziglang)")
def test_without_gcc_zig_builds_the_native_fmu_and_it_equals_the_pipeline(
        quick_model, tmp_path, monkeypatch) -> None:
    """A machine with Python and pip alone (no gcc: a slim container) built no native FMU; zig
    from the ziglang package compiles it, for glibc 2.17 as gcc's, stripped."""
    from lmncell.fmu import native_build

    monkeypatch.setattr(native_build.shutil, "which", lambda name: None)
    assert native_build.compiler("c")[-3:] == ["-target", "x86_64-linux-gnu.2.17", "-s"]
    fmu = native_build.build_native_fmu(quick_model, tmp_path / "zig.fmu")
    res = compare_fmu_with_pipeline(quick_model, fmu, PAN_US06)
    assert res["steps"] > 4000 and res["max_dv_v"] <= 1e-9


def test_source_date_epoch_makes_the_build_reproducible(quick_model, tmp_path,
                                                        monkeypatch) -> None:
    """With SOURCE_DATE_EPOCH set, two native builds of one model are byte-identical (members
    dated then); a value before 1980 is refused with its name before anything is built."""
    from lmncell.config import ConfigError
    from lmncell.fmu.native_build import build_native_fmu

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    first, second = (build_native_fmu(quick_model, tmp_path / f"{k}.fmu") for k in "ab")
    assert first.read_bytes() == second.read_bytes()
    with zipfile.ZipFile(first) as z:
        assert {i.date_time for i in z.infolist()} == {(2023, 11, 14, 22, 13, 20)}
        assert z.getinfo("binaries/linux64/LMNCell.so").external_attr >> 16 == 0o755
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "12")
    with pytest.raises(ConfigError, match="SOURCE_DATE_EPOCH = '12': expected a whole number"):
        build_native_fmu(quick_model, tmp_path / "c.fmu")
    assert not (tmp_path / "c.fmu").exists()


def test_a_cell_name_cannot_end_the_header_comment(quick_model) -> None:
    """The cell's name goes into a C comment of lmncell_model.h: a "*/" in it used to end the
    comment and the rest of the name failed the build as C."""
    from lmncell.fmu.native_build import model_header

    model = load_model(quick_model)
    model.cell["name"] = "A123 */ int x; /* 26650"
    first = model_header(model, "{guid}").splitlines()[0]
    assert first.startswith("/* ") and first.endswith(" */") and first.count("*/") == 1


def test_same_interface_as_pythonfmu(native_fmu, quick_fmu) -> None:
    from fmpy import read_model_description

    def interface(fmu):
        md = read_model_description(str(fmu))
        return [(v.name, v.valueReference, v.causality, v.unit) for v in md.modelVariables]

    assert interface(native_fmu) == interface(quick_fmu)


def test_native_equals_pipeline_on_a_real_record(quick_model, native_fmu) -> None:
    # the quick model's records warm up under load: its filters' time constants follow the
    # measured cell temperature (Eτ), which the C recomputes whenever the temperature changes
    assert load_model(quick_model).tau_activation_k is not None
    res = compare_fmu_with_pipeline(quick_model, native_fmu, PAN_US06)
    assert res["steps"] > 4000
    assert res["max_dv_v"] <= 1e-9 and res["max_dsoc"] <= 1e-12


def _observer_gap(model, fmu, seg, observer: int, kind: str, start: int, n: int,
                  soc0: float, temperature_c: float = 25.0) -> tuple[float, float, SocObserver]:
    """Largest |Δvoltage|, |ΔSoC| and |Δσ| between the native FMU's observer and the runtime's
    over n steps of a record from sample start, at one cell temperature."""
    ob = SocObserver(model, kind, soc0, temperature_c=temperature_c)
    # 25 °C as the cell temperature, as the runtime observer takes it (with the ambient, the
    # FMU's thermal model would warm the cell, which only the extrapolation factor of σ_m sees
    # in a model without temperature dependence)
    inst = Instance(fmu, start={"soc0": soc0, "temperature_is_cell": True}, observer=observer)
    taken = held_delayed_currents(seg.current_a[start:start + n].tolist(), model.sample_time_s,
                                  model.current_delay_s)      # what the FMU's model takes
    try:
        worst_v = worst_s = worst_sd = 0.0
        for k in range(start, start + n):
            ob.step(taken[k - start], float(seg.voltage_v[k]), temperature_c)
            inst.slave.setReal([inst.vr["voltage_measured"]], [float(seg.voltage_v[k])])
            inst.step(float(seg.current_a[k]), temperature=temperature_c)
            v, s, sd = inst.get("voltage", "soc", "soc_std")
            worst_v = max(worst_v, abs(v - ob.stepper.voltage_v))
            worst_s = max(worst_s, abs(s - ob.state.soc))
            worst_sd = max(worst_sd, abs(sd - ob.soc_std))
    finally:
        inst.free()
    return worst_v, worst_s, worst_sd, ob


@pytest.mark.parametrize("observer, kind", [(1, "ekf"), (2, "fuzzy"), (3, "imm")])
def test_native_observers_equal_the_runtime(native_fmu, us06, observer, kind) -> None:
    model, seg = us06
    n = 1500
    worst_v, worst_s, worst_sd, ob = _observer_gap(model, native_fmu, seg, observer, kind, 0, n,
                                                   0.4)
    # σ = √P₀₀ comes out of O(n²) sums in a different order in C than in numpy: seen 1.3e-12
    # for the EKF (numpy 2.4), hence 1e-9 for σ as in the tests below
    assert worst_v <= 1e-9 and worst_s <= 1e-12 and worst_sd <= 1e-9
    assert abs(ob.state.soc - seg.soc_ref[n - 1]) < 0.05   # corrected from 0.4


@pytest.mark.parametrize("observer, kind", [(1, "ekf"), (3, "imm")])
def test_native_observers_beyond_the_trained_temperatures_equal_the_runtime(
        native_fmu, us06, observer, kind) -> None:
    # there σ_m grows with the distance (SocObserver._extrapolation), in C as in the runtime
    model, seg = us06
    assert model.limits["temperature_c"][1] < 40.0
    worst_v, worst_s, worst_sd, ob = _observer_gap(model, native_fmu, seg, observer, kind, 0,
                                                   300, 0.4, temperature_c=45.0)
    assert ob._extrapolation > 2.0
    assert worst_v <= 1e-9 and worst_s <= 1e-12 and worst_sd <= 1e-9


def test_native_ekf_with_hysteresis_equals_the_runtime(a123_model, tmp_path) -> None:
    # the EKF's state then carries h as well as SoC and the low-pass states
    c_compiler_or_skip()
    from lmncell.fmu.native_build import build_native_fmu

    model = load_model(a123_model)
    fmu = build_native_fmu(a123_model, tmp_path / "a123.fmu")
    seg = record_to_segments(read_record(A123_S1), 1.0, 1.0, 2.2)[0]
    worst_v, worst_s, worst_sd, _ = _observer_gap(model, fmu, seg, 1, "ekf", 0, 3000, 0.7)
    # 1e-9: the EKF's secant is as wide as σ, so the round-off of σ (C loops against numpy
    # sums) feeds back into H; seen: 1e-10 in σ for a few steps, voltage within 1e-15 V
    assert worst_v <= 1e-9 and worst_s <= 1e-9 and worst_sd <= 1e-9


def test_nan_is_an_fmi_error_and_state_round_trips(native_fmu, capfd) -> None:
    inst = Instance(native_fmu, start={"soc0": 0.8})
    try:
        inst.step(-1.0)
        status, log = refuse_bad_current(inst, math.nan, capfd)
        assert status == 3                      # fmi2Error
        assert "input 'current'" in log
        for i in np.linspace(-3, 2, 20):
            inst.step(float(i), h=0.7)
        assert_state_round_trips(inst, np.linspace(2, -4, 30), h=0.7)
    finally:
        inst.free()


def test_many_instances_are_independent(native_fmu) -> None:
    d = extract(str(native_fmu))
    insts = [Instance(native_fmu, f"i{k}", {"soc0": 0.3 + 0.01 * k}, unzipped=d)
             for k in range(50)]
    try:
        for _ in range(10):
            for k, inst in enumerate(insts):
                inst.step(-1.0 - 0.1 * k)
        for k, inst in enumerate(insts):
            expect = 0.3 + 0.01 * k - 10 * (1.0 + 0.1 * k) / 3600 / 2.85
            assert inst.get("soc")[0] == pytest.approx(expect, abs=1e-12)
    finally:
        for inst in insts:
            inst.free()
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    return compile_host(HOST_C, tmp_path_factory.mktemp("host") / "host")


@pytest.fixture(scope="module")
def threads_host(tmp_path_factory) -> Path:
    return compile_host(THREADS_C, tmp_path_factory.mktemp("threads") / "threads", "-lpthread")


def _run_host(host: Path, fmu: Path, currents: np.ndarray, tmp: Path, soc0: float,
              observer: int = 0, volts: np.ndarray | None = None,
              prefix: list[str] | None = None,
              env: dict[str, str] | None = None,
              resources: str | None = None) -> subprocess.CompletedProcess:
    d = tmp / "fmu"
    guid = unzip_fmu(fmu, d)
    (tmp / "cur.txt").write_text("\n".join(repr(float(x)) for x in currents))
    vfile = "-"
    if volts is not None:
        (tmp / "volt.txt").write_text("\n".join(repr(float(x)) for x in volts))
        vfile = str(tmp / "volt.txt")
    cmd = [*(prefix or []), str(host), str(d / "binaries/linux64/LMNCell.so"),
           resources or (d / "resources").as_uri(), guid, str(tmp / "cur.txt"), "1.0", str(soc0),
           str(observer), vfile]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **env} if env else None)


def _parse(out: str) -> dict:
    m = re.search(r"steps (\d+) errors (\d+) voltage (\S+) soc (\S+) soc_std (\S+) libpython "
                  r"(-?\d)", out)
    assert m, out
    return {"steps": int(m[1]), "errors": int(m[2]), "voltage": float(m[3]), "soc": float(m[4]),
            "libpython": int(m[6])}


def test_c_host_runs_a_drive_cycle_without_python(host, native_fmu, us06, tmp_path) -> None:
    model, seg = us06
    res = _parse(_run_host(host, native_fmu, seg.current_a, tmp_path, 1.0).stdout)
    taken = held_delayed_currents(seg.current_a.tolist(), 1.0, model.current_delay_s)
    # the host leaves the FMU's defaults: 25 °C ambient, the cell temperature from the model
    sim, _ = simulate_ambient(model, np.array(taken), 25.0, 1.0)
    assert res["steps"] == len(seg) and res["errors"] == 0
    assert res["voltage"] == pytest.approx(sim.voltage_v[-1], abs=1e-9)
    assert res["soc"] == pytest.approx(sim.soc[-1], abs=1e-12)
    assert res["libpython"] == 0
    with zipfile.ZipFile(native_fmu) as z:
        z.extract("binaries/linux64/LMNCell.so", tmp_path / "ldd")
    ldd = subprocess.run(["ldd", str(tmp_path / "ldd/binaries/linux64/LMNCell.so")],
                         capture_output=True, text=True).stdout
    assert "python" not in ldd.lower()


def test_pythonfmu_fmu_runs_in_a_c_host(host, quick_fmu, us06, tmp_path) -> None:
    """pythonfmu's wrapper leaves Python's symbols to the host; the FMU's entry library loads the
    building Python into a C host without one, so the FMU runs a drive cycle there as the
    pipeline does, and valgrind (where installed) finds nothing in the FMU or at the host's
    exit. With no Python to load, fmi2Instantiate logs what to set and returns NULL."""
    from lmncell.fmu.pythonfmu_build import (
        MIN_HOST_PYTHON_TEXT,
        native_host_environment,
        native_host_hint,
    )

    env = native_host_environment()
    if env is None:
        pytest.skip("this Python has no shared libpython for a C host to load")
    assert env["LD_PRELOAD"] in native_host_hint(quick_fmu)
    model, seg = us06
    cur = seg.current_a[:600]
    valgrind = ["valgrind", "--num-callers=40"] if shutil.which("valgrind") else []
    # a desktop PATH whose first python3 (if any) is the system's, not the building Python
    out = _run_host(host, quick_fmu, cur, tmp_path, 1.0, prefix=valgrind,
                    env={"PYTHONPATH": "", "LD_PRELOAD": "", "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr[-2000:]
    res = _parse(out.stdout)
    taken = held_delayed_currents(cur.tolist(), 1.0, model.current_delay_s)
    sim, _ = simulate_ambient(model, np.array(taken), 25.0, 1.0)
    assert res["steps"] == len(cur) and res["errors"] == 0 and res["libpython"] == 1
    assert res["voltage"] == pytest.approx(sim.voltage_v[-1], abs=1e-9)
    assert fmu_reports(out.stderr) == []
    # a host that maps libpython for itself (RTLD_LOCAL): that one is used, no other is loaded
    private = _run_host(host, quick_fmu, cur[:60], tmp_path, 1.0,
                        env={"HOST_PRIVATE_LIB": env["LD_PRELOAD"],
                             "LMNCELL_LIBPYTHON": str(tmp_path / "libpython3.so")})
    assert _parse(private.stdout)["steps"] == 60, private.stderr[-2000:]
    missing = _run_host(host, quick_fmu, cur, tmp_path, 1.0,
                        env={"LMNCELL_LIBPYTHON": str(tmp_path / "libpython3.so")})
    assert missing.returncode == 2 and "instantiate failed" in missing.stderr
    assert re.search(r"LOG \[host\] 3 \w+: LMNCELL_LIBPYTHON=\S+ cannot be loaded.*native FMU",
                     missing.stdout)
    assert f"needs Python {MIN_HOST_PYTHON_TEXT} or later with numpy:" in missing.stdout
    # a message with '%' in it (here the resource path, %25 decoded) reaches the host's logger
    # as text, as does the refusal of a location that is not a percent-encoded URI
    odd = _run_host(host, quick_fmu, cur, tmp_path, 1.0,
                    resources="file:///nowhere%25s%25s%25s%25n/res")
    assert odd.returncode == 2
    assert "LOG [host] 4 logStatusFatal: [ctor] no slave class found in the resources folder " \
           "'/nowhere%s%s%s%n/res'" in odd.stdout
    raw = _run_host(host, quick_fmu, cur, tmp_path, 1.0, resources="file:///nowhere%s%n/res")
    assert raw.returncode == 2
    assert "LOG [host] 3 logStatusError: fmi2Instantiate: fmuResourceLocation " \
           "'file:///nowhere%s%n/res': '%' at character 9 of the path" in raw.stdout


def test_instances_in_parallel_threads_of_a_c_host(threads_host, fmu, quick_model,
                                                   tmp_path) -> None:
    """Four instances of one FMU stepped at once from four threads of a C host (FMI 2.0 allows
    it): each ends where the pipeline does with its own current, no call fails."""
    d = tmp_path / "fmu"
    guid = unzip_fmu(fmu, d)
    out = subprocess.run([str(threads_host), str(d / "binaries/linux64/LMNCell.so"),
                          (d / "resources").as_uri(), guid, "4"], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = {int(m[1]): (float(m[2]), int(m[3])) for m in re.finditer(
        r"instance (\d+) voltage (\S+) failed (\d+)", out.stdout)}
    assert sorted(rows) == [0, 1, 2, 3], out.stdout[-2000:]
    model = load_model(quick_model)
    for k, (volt, failed) in rows.items():
        taken = held_delayed_currents([-1.0 - 0.5 * k] * 2000, 1.0, model.current_delay_s)
        sim, _ = simulate_ambient(model, np.array(taken), 25.0, 1.0)
        assert failed == 0 and volt == pytest.approx(sim.voltage_v[-1], abs=1e-9)


def test_valgrind_memcheck_100k_steps(host, native_fmu, us06, tmp_path) -> None:
    if shutil.which("valgrind") is None:
        pytest.skip("valgrind is not installed (Debian package valgrind)")
    _, seg = us06
    cur = np.resize(seg.current_a, 100_000) * 0.2
    volts = np.resize(seg.voltage_v, 100_000)
    out = _run_host(host, native_fmu, cur, tmp_path, 0.9, observer=1, volts=volts,
                    prefix=["valgrind", "--leak-check=full", "--error-exitcode=9"])
    assert out.returncode == 0, out.stderr[-2000:]
    assert _parse(out.stdout)["steps"] == 100_000
    assert "ERROR SUMMARY: 0 errors" in out.stderr
    assert "All heap blocks were freed" in out.stderr or "definitely lost: 0 bytes" in out.stderr


def test_native_loads_in_libcosim(native_fmu) -> None:
    import_or_skip("libcosimpy", "libcosimpy (DNV libcosim) is not installed")
    assert libcosim_run(native_fmu, 0.8, -2.0, 30) == pytest.approx(fmpy_run(native_fmu, 0.8, -2.0, 30),
                                                              abs=1e-12)


def test_both_fmus_run_in_the_ecos_host(fmu, quick_model, tmp_path) -> None:
    """DNV's `ecos` command-line host (from the ecospy wheel; needs Debian's libtbb12), a C++
    host without Python: the pythonfmu FMU's entry library loads one."""
    ecospy = import_or_skip("ecospy", "ecospy cannot be loaded (needs Debian libtbb12)")
    # pip may install the wheel's binaries without the executable bit: run a private copy
    bins = tmp_path / "ecos_bin"
    shutil.copytree(Path(ecospy.__file__).parent / "binaries", bins)
    exe = bins / "ecos"
    exe.chmod(0o755)
    probe = subprocess.run([str(exe), "--version"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"the ecos host cannot start here (Debian's libtbb12 missing?): "
                    f"{probe.stderr.strip()[:200]}")
    out = subprocess.run([str(exe), "simulate", "--path", str(fmu), "--stopTime", "30",
                          "--stepSize", "1", "-l", "err"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    rows = (tmp_path / f"{fmu.stem}.csv").read_text().splitlines()
    head = [h.strip() for h in rows[0].split(",")]
    last = [float(x) for x in rows[-1].split(",")]
    volt = last[head.index("instance::voltage[REAL]")]
    st = CellStepper(load_model(quick_model), 1.0)
    for _ in range(30):
        st.step(0.0, 25.0)
    assert volt == pytest.approx(st.voltage_v, abs=2e-6)   # the CSV holds 6 decimals


def test_fmpy_compile_rebuilds_from_the_shipped_sources(native_fmu, quick_model, tmp_path) -> None:
    if shutil.which("cmake") is None:
        pytest.skip("cmake (pulled in by fmpy) is not on PATH")
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("fmpy compile (CMake) needs a C compiler on PATH: gcc is not installed")
    copy = tmp_path / "rebuilt.fmu"
    shutil.copy2(native_fmu, copy)
    out = subprocess.run([sys.executable, "-m", "fmpy", "compile", str(copy)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert validate_fmu(str(copy)) == []
    res = compare_fmu_with_pipeline(quick_model, copy, PAN_US06, max_steps=500)
    assert res["max_dv_v"] <= 1e-9


@pytest.mark.parametrize("hysteresis, hysteresis_terms", [
    ("off", "polynomial"), (30.0, "arrhenius"), (30.0, "constant"), (30.0, "polynomial")])
def test_native_equals_pipeline_with_temperature_terms(tmp_path, hysteresis,
                                                       hysteresis_terms) -> None:
    # a model with quadratic temperature terms (forced: the shipped records are all near 25 °C;
    # the cell warms by several kelvin under load, so dT varies along the record); with
    # hysteresis, its terms in dA, and the EKF's gradient through them
    c_compiler_or_skip()
    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.identification.train import train_files

    from tests.conftest import PAN_HPPC, PAN_HWFET

    path = tmp_path / "t.json"
    train_files([PAN_HWFET, PAN_HPPC], path, capacity_ah=2.85, soc0=1.0,
                progress=lambda _m: None, max_local_models=2, oe_max_iterations=2,
                hysteresis=hysteresis, temperature_terms=2, temperature_scaling=3000.0,
                hysteresis_terms=hysteresis_terms, sample_time_s=1.0)   # the 1 s segment below
    model = load_model(path)
    assert model.temperature_terms == 2 and "i(k)*dT^2" in model.columns()
    assert model.hysteresis_terms == hysteresis_terms
    fmu = build_native_fmu(path, tmp_path / "t.fmu")
    res = compare_fmu_with_pipeline(path, fmu, PAN_US06)
    assert res["steps"] > 4000
    assert res["max_dv_v"] <= 1e-9 and res["max_dsoc"] <= 1e-12
    if hysteresis != "off":
        assert ("h(k)*dA^2" in model.columns()) == (hysteresis_terms == "arrhenius")
        seg = record_to_segments(read_record(PAN_HWFET), 1.0, 1.0, 2.85)[0]
        # at 30 °C, inside the training records' 25.6 … 33 °C (dT, dA ≠ 0 there), from mid
        # record (this two-model fit drives the EKF to SoC 1 from the full start, where the
        # round-off of C and numpy grows past 1e-9 in 1500 steps; at 12 °C, far below the
        # records, it diverged)
        start = 2000
        worst_v, worst_s, worst_sd, _ = _observer_gap(model, fmu, seg, 1, "ekf", start, 1500,
                                                      float(seg.soc_ref[start]) - 0.05,
                                                      temperature_c=30.0)
        assert worst_v <= 1e-9 and worst_s <= 1e-9 and worst_sd <= 1e-9


def test_native_with_the_fast_depletion_regressor_equals_the_runtime(
        fast_depletion_model, fast_depletion_native_fmu) -> None:
    # d2(k) beside d(k): the step, the locals at another SoC and the EKF's gradient in C
    from tests.conftest import PAN_HWFET

    path, fmu = fast_depletion_model, fast_depletion_native_fmu
    model = load_model(path)
    assert model.depletion.fast_tau_s == 5.0 and "d2(k)" in model.columns()
    res = compare_fmu_with_pipeline(path, fmu, PAN_US06)
    assert res["steps"] > 4000 and res["max_dv_v"] <= 1e-9 and res["max_dsoc"] <= 1e-12
    seg = record_to_segments(read_record(PAN_HWFET), 1.0, 1.0, 2.85)[0]
    start = seg.current_a.size - 1500     # the end of discharge: the depletion factor large
    worst_v, worst_s, worst_sd, _ = _observer_gap(model, fmu, seg, 1, "ekf", start, 1500,
                                                  float(seg.soc_ref[start]))
    assert worst_v <= 1e-9 and worst_s <= 1e-9 and worst_sd <= 1e-9


SANITIZER_FLAGS = ["-fsanitize=address,undefined", "-fno-sanitize-recover=undefined",
                   "-fno-omit-frame-pointer", "-g", "-O1"]


@pytest.mark.slow
@pytest.mark.parametrize("observer, fmu_fixture", [
    (0, "native_fmu"), (1, "native_fmu"), (2, "native_fmu"), (3, "native_fmu"),
    (1, "fast_depletion_native_fmu")])
def test_sanitizers_find_nothing_on_hostile_inputs(request, us06, tmp_path, observer,
                                                   fmu_fixture) -> None:
    """The FMU's shipped sources and the C host built with -fsanitize=address,undefined, driven
    through a drive cycle mixed with NaN, ±inf, ±1e308 and zero currents and contradictory or
    NaN voltages, from full and from empty: no sanitizer report, refused steps counted (also a
    model with the fast depletion regressor d2, with the EKF)."""
    from lmncell.fmu.native_build import compile_linux64, fmi_headers

    native_fmu = request.getfixturevalue(fmu_fixture)

    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed")
    san = SANITIZER_FLAGS
    src = tmp_path / "src"
    with zipfile.ZipFile(native_fmu) as z:
        for name in z.namelist():
            if name.startswith("sources/") and not name.endswith("/"):
                (src / Path(name).name).parent.mkdir(parents=True, exist_ok=True)
                (src / Path(name).name).write_bytes(z.read(name))
    so = tmp_path / "LMNCell.so"
    compile_linux64(src, so, san)
    exe = tmp_path / "host_asan"
    subprocess.run(["gcc", "-std=c99", *san, f"-I{fmi_headers()}", str(HOST_C), "-o", str(exe),
                    "-ldl"], check=True)
    _, seg = us06
    rng = np.random.default_rng(observer)
    n = 6000
    cur = np.resize(seg.current_a, n).astype(object)
    volts = np.resize(seg.voltage_v, n).astype(object)
    hostile = rng.choice(n, 300, replace=False)
    cur[hostile] = rng.choice(["nan", "inf", "-inf", "1e308", "-1e308", "0"], hostile.size)
    volts[rng.choice(n, 300, replace=False)] = rng.choice(["nan", "0.5", "4.9", "-1"], 300)
    with zipfile.ZipFile(native_fmu) as z:
        guid = re.search(r'guid="([^"]+)"', z.read("modelDescription.xml").decode()).group(1)
    (tmp_path / "c.txt").write_text("\n".join(map(str, cur)))
    (tmp_path / "v.txt").write_text("\n".join(map(str, volts)))
    env = {**os.environ, "ASAN_OPTIONS": "detect_leaks=1:halt_on_error=1",
           "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1"}
    for soc0 in ("1.0", "0.0"):
        out = subprocess.run([str(exe), str(so), (tmp_path / "res").as_uri(), guid,
                              str(tmp_path / "c.txt"), "1.0", soc0, str(observer),
                              str(tmp_path / "v.txt")], capture_output=True, text=True,
                             env=env, timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        assert "runtime error" not in out.stderr and "AddressSanitizer" not in out.stderr
        res = _parse(out.stdout)
        assert res["steps"] == n and res["errors"] >= 100     # the hostile steps were refused
        assert math.isfinite(res["voltage"]) and math.isfinite(res["soc"])
        if observer:                   # coulomb counting is not clamped; the observers are
            assert 0.0 <= res["soc"] <= 1.0


FUZZ_C = Path(__file__).parent / "native" / "fuzz_calls.c"


def _libfuzzer_clang(tmp_path: Path) -> str | None:
    """A clang that links libFuzzer with the address and undefined-behaviour sanitizers (it
    compiles and links an empty fuzz target), or None."""
    probe = tmp_path / "probe.c"
    probe.write_text("#include <stddef.h>\n#include <stdint.h>\n"
                     "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) "
                     "{ (void)d; (void)n; return 0; }\n")
    for name in ("clang", *(f"clang-{v}" for v in range(20, 13, -1))):
        exe = shutil.which(name)
        if exe and subprocess.run([exe, "-fsanitize=fuzzer,address,undefined", str(probe), "-o",
                                   str(tmp_path / "probe")], capture_output=True).returncode == 0:
            return exe
    return None


@pytest.mark.slow
@pytest.mark.parametrize("model_fixture", ["quick_model", "fast_depletion_model", "a123_model"])
def test_fuzzed_call_sequences_find_nothing(request, tmp_path, model_fixture) -> None:
    """Coverage-guided fuzzing (libFuzzer, tests/native/fuzz_calls.c) of FMI call sequences on
    the native FMU's shipped sources, built with the address and undefined-behaviour
    sanitizers: any value into any input or parameter, steps of any size from any point,
    set-up, initialisation, reset and terminate in any order, FMU states saved, restored, freed
    and read back from serialised bytes partly overwritten. 50 000 seeded runs per model (thermal
    and depletion; the fast depletion regressor; hysteresis); no finding (a sanitizer report,
    a leak, a crash, or a non-finite output after a step that returned OK), and taken steps
    among them, so that the check on the outputs was reached."""
    from lmncell.fmu.native_build import build_native_fmu, fmi_headers

    c_compiler_or_skip()
    clang = _libfuzzer_clang(tmp_path)
    if clang is None:
        pytest.skip("no clang with libFuzzer (apt install clang libclang-rt-dev)")
    fmu = build_native_fmu(request.getfixturevalue(model_fixture), tmp_path / "cell.fmu")
    guid = unzip_fmu(fmu, tmp_path / "fmu")
    src = tmp_path / "fmu" / "sources"
    exe = tmp_path / "fuzz_calls"
    subprocess.run([clang, "-g", "-O1", "-fsanitize=fuzzer,address,undefined",
                    "-fno-sanitize-recover=undefined", "-Wall", "-Wno-unused-function",
                    f"-I{src}", f"-I{fmi_headers()}", f'-DLMNCELL_FUZZ_GUID="{guid}"',
                    str(FUZZ_C), str(src / "lmncell.c"), "-lm", "-o", str(exe)], check=True)
    out = subprocess.run([str(exe), "-seed=1", "-runs=50000", "-max_len=512", "-timeout=60",
                          f"-artifact_prefix={tmp_path}/"], capture_output=True, text=True,
                         cwd=tmp_path, timeout=1200)
    assert out.returncode == 0, out.stderr[-4000:]
    made, taken = map(int, re.search(r"fuzz_calls: (\d+) steps, (\d+) taken",
                                     out.stderr).groups())
    assert taken >= 100 and made > taken, out.stderr[-2000:]


def test_build_description_validates_and_names_libm(native_fmu) -> None:
    from fmpy.model_description import read_build_description

    configs = read_build_description(str(native_fmu), validate=True)   # fmpy's FMI 3 schema
    assert configs and configs[0].sourceFileSets[0].sourceFiles == ["lmncell.c"]
    with zipfile.ZipFile(native_fmu) as z:
        assert '<Library name="m" external="true"' in z.read(
            "sources/buildDescription.xml").decode()


def test_native_ekf_with_the_filtered_current_in_the_partition_equals_the_runtime(
        tmp_path) -> None:
    # the low-pass states then move the validities too: their columns of H are central
    # differences of the whole network, not the blended regressor coefficients
    c_compiler_or_skip()
    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.identification.train import train_files

    from tests.conftest import PAN_HWFET

    out = tmp_path / "fc.json"
    train_files([PAN_HWFET], out, capacity_ah=2.85, soc0=1.0, progress=lambda _m: None,
                partition=["soc", "filtered_current"], max_local_models=3, oe_max_iterations=2,
                hysteresis="off", sample_time_s=1.0)   # the 1 s segment below
    model = load_model(out)
    assert model.n_local_models > 1 and np.any(model.node_weights[:, 2] != 0.0)
    fmu = build_native_fmu(out, tmp_path / "fc.fmu")
    seg = record_to_segments(read_record(PAN_HWFET), 1.0, 1.0, 2.85)[0]
    worst_v, worst_s, worst_sd, _ = _observer_gap(model, fmu, seg, 1, "ekf", 0, 1500, 0.6)
    assert worst_v <= 1e-9 and worst_s <= 1e-9 and worst_sd <= 1e-9


@pytest.mark.parametrize("delay", [True, False])
def test_native_over_uneven_steps_equals_the_runtime(quick_model, native_fmu, tmp_path,
                                                     delay) -> None:
    # the delayed current's window (δ before each model step) accumulates across uneven
    # communication steps the same way in C as in the runtime's engine, and between model
    # steps both give the same preview of the step in progress (with and without the delay)
    import dataclasses

    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.runtime.cosim import CellCosim, Parameters
    from lmncell.runtime.model import save_model

    model = load_model(quick_model)
    assert model.current_delay_s > 0
    if not delay:
        c_compiler_or_skip()
        model = dataclasses.replace(model, current_delay_s=0.0)
        native_fmu = build_native_fmu(save_model(model, tmp_path / "plain.json"),
                                      tmp_path / "plain.fmu")
    rng = np.random.default_rng(7)
    cosim = CellCosim(model, Parameters(0.9, 2.85))
    inst = Instance(native_fmu, start={"soc0": 0.9})
    try:
        worst = 0.0
        for h, i in zip(rng.choice([0.01, 0.05, 0.3, 0.37, 1.0, 2.5], size=400),
                        rng.uniform(-6.0, 3.0, size=400), strict=True):
            cosim.advance(float(h), float(i))
            inst.step(float(i), h=float(h))
            worst = max(worst, abs(inst.get("voltage")[0] - cosim.voltage_v))
        assert inst.get("soc")[0] == pytest.approx(cosim.soc, abs=1e-12)
    finally:
        inst.free()
    assert worst <= 1e-9


def test_native_step_end_within_rounding_equals_the_runtime(quick_model, tmp_path) -> None:
    # C drops the rounding left over at a model step's end as the runtime's engine does: the
    # output there is the step's voltage in both (test_fmu: ROUNDING_POINTS_S)
    import dataclasses

    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.runtime.cosim import CellCosim, Parameters
    from lmncell.runtime.model import save_model

    from tests.test_fmu import ROUNDING_POINTS_S

    c_compiler_or_skip()
    model = dataclasses.replace(load_model(quick_model), sample_time_s=0.1, current_delay_s=0.0)
    fmu = build_native_fmu(save_model(model, tmp_path / "fast.json"), tmp_path / "fast.fmu")
    cosim, whole = CellCosim(model, Parameters(0.9, 2.85)), CellCosim(model, Parameters(0.9, 2.85))
    inst = Instance(fmu, start={"soc0": 0.9})
    t0, t1, t2 = ROUNDING_POINTS_S
    try:
        for _ in range(20):
            cosim.advance(0.1, -2.0)
            whole.advance(0.1, -2.0)
            inst.step(-2.0, h=0.1)
        for h in (t1 - t0, t2 - t1):
            cosim.advance(h, -2.0)
            inst.step(-2.0, h=h)
        whole.advance(0.1, -2.0)
        assert inst.get("voltage")[0] == pytest.approx(cosim.voltage_v, abs=1e-9)
        assert inst.get("voltage")[0] == pytest.approx(whole.voltage_v, abs=1e-9)
    finally:
        inst.free()


def test_out_of_range_when_the_model_voltage_leaves_its_trained_range(quick_model, tmp_path,
                                                                     capfd) -> None:
    """Current, SoC and temperature inside their trained ranges, the model's voltage beyond
    its own by more than 0.1 V: both FMUs raise out_of_range, log one warning naming the
    voltage, and drop the flag when the voltage is back."""
    c_compiler_or_skip()
    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.fmu.pythonfmu_build import build_fmu

    doc = json.loads(quick_model.read_text())
    doc["limits"]["voltage_v"] = [3.95, 4.2]       # −10 A takes the model to about 3.76 V
    narrow = tmp_path / "narrow.json"
    narrow.write_text(json.dumps(doc))
    for fmu in (build_fmu(narrow, tmp_path / "py.fmu"),
                build_native_fmu(narrow, tmp_path / "c.fmu")):
        inst = Instance(fmu, start={"soc0": 0.9})
        try:
            flags = []
            capfd.readouterr()
            for current in (-1.0, -10.0, -10.0, -1.0, -1.0):
                inst.step(current)             # fmpy raises on any status but OK/warning
                flags.append(inst.slave.getBoolean([inst.vr["out_of_range"]])[0])
            assert flags == [False, True, True, False, False], fmu.name
            log = capfd.readouterr().out
            assert log.count("model voltage") == 1 and "3.95" in log, (fmu.name, log)
        finally:
            inst.free()


# the temperature forms the C must mirror, each with the model that differs only in it: T0 > 0
# (the Vogel–Tammann–Fulcher form, as models of two chamber temperatures have it) on both the
# gain g(T) with E and the time constants' k(T) with Eτ; the core rise k·LP_τ(i²) on the
# temperature the step takes, a state the C keeps with the runtime's coefficient
TEMPERATURE_FORMS = {
    "vtf": ({"arrhenius_k": 3000.0, "activation_t0_k": 170.0},
            {"arrhenius_k": 3000.0, "activation_t0_k": 0.0}),
    "core_rise": ({"arrhenius_k": 3000.0, "core_rise_k_per_a2": 0.05, "core_rise_tau_s": 60.0},
                  {"arrhenius_k": 3000.0, "core_rise_k_per_a2": 0.0, "core_rise_tau_s": 0.0}),
}


@pytest.mark.parametrize("ambient", [False, True])
@pytest.mark.parametrize("form", sorted(TEMPERATURE_FORMS))
def test_native_temperature_forms_equal_the_runtime(quick_model, tmp_path, form,
                                                    ambient) -> None:
    # the C takes the model file's parameters and the same operations; driven by the measured
    # cell temperature and by the ambient, which the thermal model warms; the same FMU against
    # the model without the form differs (the file's parameters matter)
    import dataclasses

    from lmncell.fmu.native_build import build_native_fmu
    from lmncell.runtime.model import save_model

    c_compiler_or_skip()
    plain = load_model(quick_model)
    assert plain.tau_activation_k is not None
    with_form, without_form = TEMPERATURE_FORMS[form]
    path = save_model(dataclasses.replace(plain, **with_form), tmp_path / f"{form}.json")
    assert all(getattr(load_model(path), k) == v for k, v in with_form.items())
    fmu = build_native_fmu(path, tmp_path / f"{form}.fmu")
    res = compare_fmu_with_pipeline(path, fmu, PAN_US06, max_steps=2500, ambient=ambient)
    assert res["max_dv_v"] <= 1e-9 and res["max_dsoc"] <= 1e-12
    assert res["max_dtemperature_k"] <= 1e-9
    other = save_model(dataclasses.replace(plain, **without_form), tmp_path / "other.json")
    assert compare_fmu_with_pipeline(other, fmu, PAN_US06, max_steps=2500,
                                     ambient=ambient)["max_dv_v"] > 1e-5


SANITIZED_SEQUENCES = ("random_calls", "ordinary_errors", "impossible_inputs", "null_pointers",
                       "state_reuse", "damaged_states", "observers_at_full", "stop_time",
                       "cell_start_parameters", "access_refusals")


def _sanitizer_environment() -> dict[str, str]:
    """The environment in which a Python host loads an FMU built with gcc's AddressSanitizer and
    UBSan (their runtimes preloaded; leaks left to valgrind's tests), or a skip where gcc has no
    such runtimes or this kernel does not run them (a Python with them preloaded that cannot
    even import fmpy)."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed: the sanitizer build needs it")
    libs = [subprocess.run(["gcc", f"-print-file-name={name}"], capture_output=True,
                           text=True).stdout.strip() for name in ("libasan.so", "libubsan.so")]
    if not all(os.path.isabs(lib) and Path(lib).exists() for lib in libs):
        pytest.skip(f"gcc has no sanitizer runtimes here ({libs})")
    env = {**os.environ, "LD_PRELOAD": " ".join(libs),
           "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",
           "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}
    probe = subprocess.run([sys.executable, "-c", "import numpy, fmpy"], env=env,
                           capture_output=True, text=True, timeout=120)
    if probe.returncode != 0:
        pytest.skip(f"Python does not run with the sanitizers preloaded: {probe.stderr[-500:]}")
    return env


def _instrumented(fmu: Path, tmp_path: Path) -> bool:
    """Whether every linux64 library of the FMU calls the two sanitizers' runtimes."""
    with zipfile.ZipFile(fmu) as z:
        names = [n for n in z.namelist() if n.startswith("binaries/linux64/")]
        found = []
        for name in names:
            lib = tmp_path / Path(name).name
            lib.write_bytes(z.read(name))
            symbols = subprocess.run(["nm", "-D", str(lib)], capture_output=True,
                                     text=True).stdout
            found.append("__asan_report" in symbols and "__ubsan_handle" in symbols)
    return bool(names) and all(found)


def _sanitized_fmu(flavour: str, model: Path, out: Path, monkeypatch) -> Path:
    """The FMU of model (native, or pythonfmu with LMNCell's wrapper) compiled with gcc's
    AddressSanitizer and UBSan."""
    from lmncell.fmu import native_build as nb
    from lmncell.fmu import pythonfmu_build as pb

    monkeypatch.setattr(nb, "compiler", lambda language: ["gcc" if language == "c" else "g++"])
    if flavour == "native":
        plain = nb.compile_linux64
        monkeypatch.setattr(nb, "compile_linux64", lambda src, binary, extra=None: plain(
            src, binary, [*(extra or []), *SANITIZER_FLAGS]))
        fmu = nb.build_native_fmu(model, out)
    else:
        if shutil.which("g++") is None:
            pytest.skip("g++ is not installed: the pythonfmu FMU's wrapper is C++")
        compile_plain = pb._compile
        monkeypatch.setattr(pb, "_compile", lambda cmd: compile_plain(
            [*cmd[:cmd.index("-shared")], *SANITIZER_FLAGS, *cmd[cmd.index("-shared"):]]))
        fmu = pb.build_fmu(model, out)
    assert _instrumented(fmu, out.parent), "the FMU's binaries are not instrumented"
    return fmu


@pytest.mark.parametrize(("flavour", "model_fixture"), [("native", "quick_model"),
                                                        ("native", "fast_depletion_model"),
                                                        ("pythonfmu", "quick_model")])
def test_sanitizers_find_nothing_in_the_fmus(flavour, model_fixture, request, tmp_path,
                                            monkeypatch) -> None:
    """The FMU's binaries built with AddressSanitizer and UBSan (any out-of-bounds access, use
    after free, signed overflow, misaligned or null access aborts the host): the conformance
    call sequences (random calls, wrong calls, NULL pointers, damaged states, …) and a drive
    through the US06 record, whose voltage still equals the pipeline's."""
    env = _sanitizer_environment()
    model = request.getfixturevalue(model_fixture)
    fmu = _sanitized_fmu(flavour, model, tmp_path / "asan.fmu", monkeypatch)
    for sequence in SANITIZED_SEQUENCES:
        _run_sanitized([sys.executable, "-m", "tests.conformance_sequences", str(fmu), sequence],
                       env)
    drive = ("import json, sys; from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline"
             "; print(json.dumps(compare_fmu_with_pipeline(*sys.argv[1:4], max_steps=1500)"
             "['max_dv_v']))")
    out = _run_sanitized([sys.executable, "-c", drive, str(model), str(fmu), str(PAN_US06)], env)
    assert json.loads(out.strip().splitlines()[-1]) < 1e-9     # V: the FMU equals the pipeline


def _run_sanitized(cmd: list[str], env: dict[str, str]) -> str:
    """cmd's standard output; fails where the host died or a sanitizer reported anything."""
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{cmd[-1]}: the host died: {proc.stderr[-3000:]}"
    assert "Sanitizer" not in proc.stderr and "runtime error" not in proc.stderr, proc.stderr
    return proc.stdout
