"""The pythonfmu LMNCell FMU (issue: FMU)."""

from __future__ import annotations

import dataclasses
import math
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from fmpy import extract
from fmpy.validation import validate_fmu
from lmncell.data.dataset import record_to_segments
from lmncell.data.readers import read_record
from lmncell.evaluation.fmucheck import compare_fmu_with_pipeline, run_fmu_on_segment
from lmncell.runtime.cosim import held_delayed_currents
from lmncell.runtime.model import load_model
from lmncell.runtime.step import CellStepper

from tests.conftest import PAN_HWFET, PAN_US06, import_or_skip
from tests.fmu_helpers import (
    Instance,
    assert_state_round_trips,
    fmpy_run,
    libcosim_run,
    refuse_bad_current,
)


def test_fmpy_validate_reports_no_problem(quick_fmu) -> None:
    assert validate_fmu(str(quick_fmu)) == []
    with zipfile.ZipFile(quick_fmu) as z:
        xml = z.read("modelDescription.xml").decode()
        names = z.namelist()
    assert "<InitialUnknowns>" in xml and 'unit="V"' in xml and 'stepSize="1.0"' in xml
    assert 'canGetAndSetFMUstate="true"' in xml and 'canSerializeFMUstate="true"' in xml
    assert "documentation/index.html" in names and "resources/model.json" in names
    assert any(n.startswith("resources/lmncell_rt_") for n in names)
    with zipfile.ZipFile(quick_fmu) as z:
        doc = z.read("documentation/index.html").decode()
    assert f"<li>{PAN_HWFET.name} <small>sha256" in doc        # a training record, no folder
    assert "slow OCV test" not in doc                         # none given


def test_fmu_equals_pipeline_on_a_real_record(quick_model, quick_fmu) -> None:
    res = compare_fmu_with_pipeline(quick_model, quick_fmu, PAN_US06)
    assert res["steps"] > 4000
    assert res["max_dv_v"] <= 1e-9
    assert res["max_dsoc"] <= 1e-12


def test_sub_stepping(quick_model, quick_fmu) -> None:
    model = load_model(quick_model)
    seg = record_to_segments(read_record(PAN_HWFET), 1.0, 1.0, 2.85)[0]
    ref = CellStepper(model, 1.0, temperature_c=float(seg.temperature_c[0]))
    n = 300
    taken = held_delayed_currents(seg.current_a[:n].tolist(), 1.0, model.current_delay_s)
    expect = [ref.step(i, float(t)) for i, t in zip(taken, seg.temperature_c[:n], strict=True)]
    fine = run_fmu_on_segment(quick_fmu, seg, 1.0, step_s=0.1)
    assert np.max(np.abs(fine["voltage"][1:n + 1] - expect)) <= 1e-9
    # an uneven step (2.5 Ts) accumulates exactly: after 2 calls, 5 model steps (the input
    # temperature, 25 °C, taken as the cell's: the model's filters depend on it)
    inst = Instance(quick_fmu, start={"soc0": 1.0, "temperature_is_cell": True})
    try:
        for _ in range(2):
            inst.step(-2.0, h=2.5)
        st = CellStepper(model, 1.0)
        for _ in range(5):
            st.step(-2.0, 25.0)
        assert inst.get("voltage")[0] == pytest.approx(st.voltage_v, abs=1e-12)
    finally:
        inst.free()


def test_nan_input_is_refused_and_host_continues(quick_fmu, capfd) -> None:
    inst = Instance(quick_fmu, start={"soc0": 0.8})
    try:
        inst.step(-1.0)
        before = inst.get("voltage", "soc")
        logs = []
        for bad in (math.nan, math.inf):
            status, log = refuse_bad_current(inst, bad, capfd)
            assert status >= 2       # not OK: fmi2Discard from pythonfmu 0.7
            logs.append(log)
        assert "input 'current' = nan" in logs[0]
        inst.step(-1.0)
        assert inst.get("soc")[0] < before[1]
    finally:
        inst.free()


def test_state_round_trips_exactly(quick_fmu) -> None:
    inst = Instance(quick_fmu, start={"soc0": 0.9})
    try:
        for i in np.linspace(-3, 2, 37):
            inst.step(float(i), h=0.7)
        assert_state_round_trips(inst, np.linspace(2, -5, 50), h=0.7)
    finally:
        inst.free()


def test_reset_and_independent_instances(quick_fmu) -> None:
    d = extract(str(quick_fmu))
    a = Instance(quick_fmu, "a", {"soc0": 0.9}, unzipped=d)
    b = Instance(quick_fmu, "b", {"soc0": 0.5, "capacity": 2.0}, unzipped=d)
    try:
        for _ in range(20):
            a.step(-2.0)
            b.step(1.0)
        assert a.get("soc")[0] == pytest.approx(0.9 - 20 * 2.0 / 3600 / 2.85, abs=1e-12)
        assert b.get("soc")[0] == pytest.approx(0.5 + 20 * 1.0 / 3600 / 2.0, abs=1e-12)
        a.slave.reset()
        a.slave.setupExperiment(startTime=0.0)
        a.slave.enterInitializationMode()
        a.slave.exitInitializationMode()
        assert a.get("soc")[0] == pytest.approx(0.9, abs=1e-12) or a.get("soc")[0] == 1.0
    finally:
        a.free()
        b.free()
        shutil.rmtree(d, ignore_errors=True)


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096 / 2**20


def test_many_instantiations_do_not_leak(quick_fmu) -> None:
    d = extract(str(quick_fmu))
    try:
        for _ in range(50):
            Instance(quick_fmu, unzipped=d).free()
        path_len, rss0 = len(sys.path), _rss_mb()
        for k in range(1000):
            inst = Instance(quick_fmu, f"i{k}", unzipped=d)
            inst.step(-1.0)
            inst.free()
        assert len(sys.path) == path_len
        assert _rss_mb() - rss0 < 5.0
    finally:
        shutil.rmtree(d, ignore_errors=True)


def test_out_of_range_when_the_temperature_leaves_the_trained_range(fmu, quick_model) -> None:
    """The quick model has no temperature in its partition (one chamber temperature), yet its
    Arrhenius gain and thermal model use the temperature: both FMUs raise out_of_range 2 K
    beyond the trained cell temperatures, as README's table says, and lmncell evaluate's
    warning uses the same margins (cosim.trained_bounds)."""
    from lmncell.evaluation.evaluate import warn_outside_training
    from lmncell.runtime.cosim import TEMPERATURE_MARGIN_K

    model = load_model(quick_model)
    lo, hi = model.limits["temperature_c"]
    assert "temperature" not in model.partition_variables
    flags = {}
    for label, temperature in (("inside", 0.5 * (lo + hi)), ("cold", lo - 10.0)):
        inst = Instance(fmu, start={"soc0": 0.9, "temperature_is_cell": True})
        try:
            inst.step(-1.0, temperature=temperature)
            flags[label] = inst.slave.getBoolean([inst.vr["out_of_range"]])[0]
        finally:
            inst.free()
    assert flags == {"inside": False, "cold": True}
    with pytest.warns(UserWarning, match="outside the trained"):
        warn_outside_training(model, "r", np.array([-1.0]),
                              np.array([lo - TEMPERATURE_MARGIN_K - 0.01]))
    assert not warn_outside_training(model, "r", np.array([-1.0]),
                                     np.array([lo - TEMPERATURE_MARGIN_K + 0.01]))


def test_out_of_range_flag(quick_fmu) -> None:
    inst = Instance(quick_fmu, start={"soc0": 0.9})
    try:
        inst.step(-1.0)
        assert not inst.slave.getBoolean([inst.vr["out_of_range"]])[0]
        inst.step(-100.0)
        assert inst.slave.getBoolean([inst.vr["out_of_range"]])[0]
        inst.step(-1.0)
        assert not inst.slave.getBoolean([inst.vr["out_of_range"]])[0]
    finally:
        inst.free()


def test_two_models_in_one_process(quick_model, quick_fmu, tmp_path) -> None:
    """Different models, unique module names: each FMU runs its own code and parameters."""
    from lmncell.fmu.pythonfmu_build import build_fmu

    doc = quick_model.read_text().replace('"sample_time_s": 1.0', '"sample_time_s": 2.0')
    other = tmp_path / "other.json"
    other.write_text(doc)
    fmu2 = build_fmu(other, tmp_path / "other.fmu")
    cell = {"soc0": 0.9, "temperature_is_cell": True}     # stepped at 25 °C, as below
    a, b = Instance(quick_fmu, "a", cell), Instance(fmu2, "b", cell)
    try:
        for _ in range(10):
            a.step(-2.0, h=2.0)
            b.step(-2.0, h=2.0)
        m1, m2 = load_model(quick_model), load_model(other)
        s1, s2 = CellStepper(m1, 0.9), CellStepper(m2, 0.9)
        for _ in range(20):
            s1.step(-2.0, 25.0)
        for _ in range(10):
            s2.step(-2.0, 25.0)
        assert a.get("voltage")[0] == pytest.approx(s1.voltage_v, abs=1e-12)
        assert b.get("voltage")[0] == pytest.approx(s2.voltage_v, abs=1e-12)
    finally:
        a.free()
        b.free()


def test_libcosim_gives_the_same_outputs(quick_fmu) -> None:
    import_or_skip("libcosimpy", "libcosimpy (DNV libcosim) is not installed")
    assert libcosim_run(quick_fmu, 0.8, -2.0, 30) == pytest.approx(fmpy_run(quick_fmu, 0.8, -2.0, 30),
                                                              abs=1e-12)


def test_fmu_manipulation_toolbox_check(quick_fmu) -> None:
    exe = shutil.which("fmutool")
    if exe is None:
        pytest.skip("fmu-manipulation-toolbox (fmutool) is not installed")
    out = subprocess.run([exe, "-input", str(quick_fmu), "-check"], capture_output=True,
                         text=True, timeout=120)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text
    assert "compliant with FMI-2.0" in text and "No semantic error" in text


def test_current_delay_takes_the_window_delta_earlier(quick_model) -> None:
    # the engine given a held current over uneven communication steps takes, at each model
    # step, the current's mean over [t_k − Ts − δ, t_k − δ] (the first current held before 0)
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = load_model(quick_model)
    delay = model.current_delay_s
    assert 0.05 < delay < 0.15                   # estimated from the HWFET record's channels
    rng = np.random.default_rng(11)
    steps = rng.choice([0.05, 0.3, 0.37, 1.0, 2.5], size=60)
    currents = rng.uniform(-4.0, 2.0, size=60)
    starts = np.concatenate([[-np.inf], np.cumsum(steps)[:-1]])
    ends = np.cumsum(steps)                  # piece 0 also covers t < 0

    def charge(a: float, b: float) -> float:   # ∫ i dt over [a, b] of the held input (A·s)
        return float(sum(i * max(0.0, min(b, e) - max(a, s))
                         for s, e, i in zip(starts, ends, currents, strict=True)))

    ref = CellStepper(model, 1.0)
    ref_v = [ref.step(charge(k - delay, k + 1 - delay), 25.0)
             for k in range(int(np.sum(steps)))]
    cosim = CellCosim(model, Parameters(1.0, 2.85, temperature_is_cell=True))   # at 25 °C
    worst = 0.0
    for h, i in zip(steps, currents, strict=True):
        if cosim.advance(float(h), float(i)):        # the last completed model step's
            worst = max(worst, abs(cosim.stepper.voltage_v - ref_v[cosim.steps - 1]))
    assert cosim.steps == len(ref_v) and worst <= 1e-9


def test_a_state_of_another_shape_is_refused_before_anything_changes(quick_model) -> None:
    from lmncell.runtime.cosim import CellCosim, Parameters

    cosim = CellCosim(load_model(quick_model), Parameters(0.8, 2.85))
    for _ in range(5):
        cosim.advance(0.7, -2.0)
    saved = cosim.get_state()
    cosim.advance(1.0, -3.0)
    before = (cosim.voltage_v, cosim.steps, cosim.get_state()["acc"])
    for n in (5, 8):        # the accumulators before the delay, before the preview's current
        with pytest.raises(ValueError, match=f"'acc' holds {n} values, expected 9"):
            cosim.set_state(dict(saved, acc=saved["acc"][:n]))
        assert (cosim.voltage_v, cosim.steps, cosim.get_state()["acc"]) == before
    cosim.set_state(saved)
    assert cosim.steps == 3


def test_a_step_whose_model_fails_is_refused_and_changes_nothing(quick_model,
                                                                   monkeypatch) -> None:
    """Where the model step raises (an overflow) or gives a non-finite voltage, advance()
    restores the state from before the call and raises InputError, as the native FMU restores
    its state (before, the pythonfmu FMU's SoC had moved when 'math range error' came)."""
    from lmncell.runtime import cosim as engine

    cosim = engine.CellCosim(load_model(quick_model), engine.Parameters(0.8, 2.85))
    cosim.advance(1.0, -2.0)
    before = cosim.get_state()

    def overflow(self, *args):
        raise OverflowError("math range error")

    def nan_voltage(self, *args):
        self.voltage_v = math.nan
        return math.nan

    for step in (overflow, nan_voltage):
        monkeypatch.setattr(engine.CellStepper, "step", step)
        for h in (1.0, 0.4, 2.5):           # the one-step path, a partial step, two and a half
            with pytest.raises(engine.InputError, match="the model produced a non-finite output"):
                cosim.advance(h, -2.0)
            assert cosim.get_state() == before
    monkeypatch.undo()
    assert cosim.advance(1.0, -2.0) == 1 and math.isfinite(cosim.voltage_v)


def test_a_step_of_more_model_steps_than_the_limit_is_refused_at_once(quick_model,
                                                                      monkeypatch) -> None:
    """A communication step beyond MAX_STEPS_PER_CALL model steps is refused before anything
    changes (1e300 s used to loop for ever: Ts no longer changes the remaining time); one of
    exactly the limit is taken."""
    from lmncell.runtime import cosim as engine

    model = load_model(quick_model)
    cosim = engine.CellCosim(model, engine.Parameters(0.8, 2.85))
    cosim.advance(0.5, -2.0)
    before = cosim.get_state()
    for h in (1e300, engine.MAX_STEPS_PER_CALL * model.sample_time_s * (1 + 1e-9)):
        with pytest.raises(engine.InputError, match=r"communication step size .* s: more "
                           r"than 10000000 model steps of 1 s; expected at most 1e\+07 s"):
            cosim.advance(h, 0.0)
        assert cosim.get_state() == before
    monkeypatch.setattr(engine, "MAX_STEPS_PER_CALL", 40)
    assert cosim.advance(40 * model.sample_time_s, -1.0) == 40
    with pytest.raises(engine.InputError, match="more than 40 model steps"):
        cosim.advance(40 * model.sample_time_s + 0.5, -1.0)


# a host's sample 1.1e-6 s before a model step end of Ts = 0.1 s: the step that ends the model
# step leaves 8.3e-17 s of rounding over (a 10 Hz record's own times do this)
ROUNDING_POINTS_S = (2.0, 2.099998891657932, 2.1)


def test_a_step_end_within_rounding_gives_the_steps_voltage(quick_model) -> None:
    """Communication points that end a model step up to rounding leave no sliver of a new step
    behind: the output there is the step's voltage, not the preview of the next one. Before,
    8.3e-17 s was left over, the output became the next step previewed, and a Ts = 0.1 s model
    through a 10 Hz record drifted from its pipeline by up to 0.30 V (Panasonic HWFET)."""
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = dataclasses.replace(load_model(quick_model), sample_time_s=0.1, current_delay_s=0.0)
    split, whole = CellCosim(model, Parameters(0.9, 2.85)), CellCosim(model, Parameters(0.9, 2.85))
    t0, t1, t2 = ROUNDING_POINTS_S
    for _ in range(20):                                      # 2 s in whole steps
        split.advance(0.1, -2.0)
        whole.advance(0.1, -2.0)
    split.advance(t1 - t0, -2.0)
    split.advance(t2 - t1, -2.0)
    whole.advance(0.1, -2.0)
    assert split.covered_s == 0.0 and split.preview_v is None
    assert split.voltage_v == pytest.approx(whole.voltage_v, abs=1e-12)
    split.advance(0.05, 1.0)                                  # a new step in progress: a preview
    assert split.covered_s == pytest.approx(0.05) and split.preview_v is not None


def test_between_model_steps_the_voltage_follows_the_latest_input(quick_model) -> None:
    """Communication steps shorter than Ts: the voltage output is the model step in progress
    taken on a copy as if the latest current had been held over all of it (the preview), so it
    follows the current now, not the mean since the step began; the committed steps are those
    of whole-Ts steps with the mean input, to rounding. With a current delay, a step shorter
    than the delay previews the open delayed window's mean. Driven as fmpy drives a 10 Hz
    record (each sample held until the next) and scored against the raw samples of the unseen
    US06 record, the preview cuts the error of holding the last model step to a third, and
    beats a preview with the mean current so far (the rule before)."""
    from lmncell.runtime.cosim import CellCosim, Parameters

    model = load_model(quick_model)
    plain = dataclasses.replace(model, current_delay_s=0.0)
    fine, whole = CellCosim(plain, Parameters(0.9, 2.85)), CellCosim(plain, Parameters(0.9, 2.85))
    for k in range(30):
        current = -3.0 if k % 7 < 4 else 1.0
        for j in range(10):
            now = current + (0.5 if j % 2 else 0.0)       # the input moves within the step
            fine.advance(0.1, now)
            if j < 9:        # mid-step: the step in progress, taken and not kept
                ref = CellStepper(plain, 0.9, 2.85)
                ref.set_state(fine.stepper.get_state())
                assert fine.voltage_v == pytest.approx(
                    ref.step(now, fine.thermal.next_temperature(25.0)), abs=1e-12)
        whole.advance(1.0, current + 0.25)               # the mean of the ten inputs
        assert fine.steps == whole.steps == k + 1
        assert fine.voltage_v == pytest.approx(whole.voltage_v, abs=1e-12)

    delayed = CellCosim(model, Parameters(0.9, 2.85))
    delayed.advance(1.0, -2.0)
    delayed.advance(model.current_delay_s / 2, -4.0)          # shorter than the delay
    # the open delayed window: δ of −2 A carried over, δ/2 of −4 A
    assert delayed.preview_current_a == pytest.approx(-8.0 / 3.0, abs=1e-12)
    delayed.advance(model.current_delay_s, -4.0)              # as long as the delay
    assert delayed.preview_current_a == -4.0

    rec = read_record(PAN_US06)                              # unseen by the model
    t, i, v = rec.time_s - rec.time_s[0], rec.current_a, rec.voltage_v
    keep = np.flatnonzero(np.diff(t) > 0)[:6000]            # 10 minutes of samples
    cosim, mean_so_far = CellCosim(model, Parameters(1.0, 2.85)), []
    now, held = [], []
    for k in keep:
        cosim.advance(float(t[k + 1] - t[k]), float(i[k]))
        now.append(cosim.voltage_v)
        held.append(cosim.stepper.voltage_v)
        mean_so_far.append(_mean_preview(cosim))
    rmse = [float(np.sqrt(np.mean((np.array(x) - v[keep + 1]) ** 2)))
            for x in (now, held, mean_so_far)]
    assert rmse[0] < 0.4 * rmse[1] and rmse[0] < 0.9 * rmse[2], rmse   # 19.4, 65.0, 23.0 mV


def _mean_preview(cosim) -> float:
    """The voltage now by the former preview rule: the step in progress taken with the open
    delayed window's mean current (the quick model has a current delay)."""
    if cosim.covered_s <= 0.0:
        return cosim.stepper.voltage_v
    i = (cosim.delay_charge_as / cosim.delay_covered_s if cosim.delay_covered_s > 0.0
         else cosim.delayed_current_a)
    saved = cosim.stepper.get_state()
    volt = cosim.stepper.step(i, cosim.thermal.next_temperature(cosim.temp_int / cosim.covered_s))
    cosim.stepper.set_state(saved)
    return volt


@pytest.mark.parametrize("native", [False, True])
def test_an_fmu_name_without_the_fmu_extension_is_refused(quick_model, tmp_path,
                                                           native) -> None:
    """FMI 2.0's FMU is a .fmu zip; pythonfmu took any other name for a folder."""
    import lmncell

    with pytest.raises(ValueError, match=r"cell\.zip: an FMU's file name must end in \.fmu"):
        lmncell.build_fmu(quick_model, tmp_path / "cell.zip", native=native)
    assert list(tmp_path.iterdir()) == []


def test_an_older_host_python_is_told_what_to_do(quick_fmu, tmp_path, monkeypatch) -> None:
    """The FMU's slave module checks the host's Python before it imports the runtime: on one
    older than the runtime needs, an ImportError that pythonfmu's wrapper logs, naming both
    versions and the ways out, not an error from inside the runtime (seen on Python 3.9:
    "cannot import name 'TypeGuard' from 'typing'")."""
    import runpy

    with zipfile.ZipFile(quick_fmu) as z:
        module = z.read("resources/slavemodule.txt").decode().strip()
        (tmp_path / "slave.py").write_bytes(z.read(f"resources/{module}.py"))
    monkeypatch.setattr(sys, "version_info", (3, 9, 18, "final", 0))
    with pytest.raises(ImportError, match=r"runs its model on Python 3\.10 or later; this host's "
                       r"Python is .*lmncell build-fmu --native"):
        runpy.run_path(str(tmp_path / "slave.py"))


HOST_WITHOUT_PYTHONFMU = """
import importlib.abc, importlib.machinery, importlib.util, os, sys
import numpy as np
from fmpy import simulate_fmu

INSTALLED = os.path.dirname(importlib.util.find_spec("pythonfmu").origin)


class InstalledPythonfmuRefused(importlib.abc.MetaPathFinder):
    \"\"\"The host's own pythonfmu cannot be imported; a copy elsewhere (the FMU's) can.\"\"\"
    def find_spec(self, name, path, target=None):
        if name.partition(".")[0] != "pythonfmu":
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and (spec.origin or "").startswith(INSTALLED):
            raise ImportError(f"{name}: the host's pythonfmu ({INSTALLED}) is refused")
        return spec


sys.meta_path.insert(0, InstalledPythonfmuRefused())
current = np.array([(0.0, -2.0), (60.0, -2.0)], dtype=[("time", "f8"), ("current", "f8")])
res = simulate_fmu(sys.argv[1], stop_time=60.0, output_interval=1.0, input=current,
                   start_values={"soc0": 0.9})
print(repr(float(res["voltage"][-1])))
"""


def test_a_python_host_needs_numpy_but_not_pythonfmu(quick_fmu, tmp_path) -> None:
    """pythonfmu's Python part travels in the FMU's resources, so a Python host whose own
    pythonfmu cannot be imported runs it and gets the same voltage; the same FMU without that
    copy fails there, so the host's copy is what the refusal keeps out."""
    from fmpy import simulate_fmu

    current = np.array([(0.0, -2.0), (60.0, -2.0)], dtype=[("time", "f8"), ("current", "f8")])
    want = simulate_fmu(str(quick_fmu), stop_time=60.0, output_interval=1.0, input=current,
                        start_values={"soc0": 0.9})["voltage"][-1]
    script = tmp_path / "host.py"
    script.write_text(HOST_WITHOUT_PYTHONFMU)
    run = subprocess.run([sys.executable, str(script), str(quick_fmu)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert float(run.stdout.split()[-1]) == want
    bare = tmp_path / "bare.fmu"
    with zipfile.ZipFile(quick_fmu) as zin, zipfile.ZipFile(bare, "w") as zout:
        for item in zin.infolist():
            if not item.filename.startswith("resources/pythonfmu/"):
                zout.writestr(item, zin.read(item))
    run = subprocess.run([sys.executable, str(script), str(bare)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode != 0 and "the host's pythonfmu" in run.stdout + run.stderr


def test_the_runtime_is_written_for_the_oldest_host_python() -> None:
    """What runs inside the pythonfmu FMU parses as the grammar of the oldest Python the FMU
    admits (MIN_HOST_PYTHON)."""
    import ast

    from lmncell.fmu.pythonfmu_build import MIN_HOST_PYTHON, RUNTIME_DIR

    sources = sorted(RUNTIME_DIR.glob("*.py"))
    assert sources
    for source in sources:
        ast.parse(source.read_text(encoding="utf-8"), str(source), feature_version=MIN_HOST_PYTHON)
