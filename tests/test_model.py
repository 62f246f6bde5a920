"""LMN runtime and model file (issue: identification)."""

from __future__ import annotations

import errno
import json
import math
import os
import threading
from pathlib import Path

import numpy as np
import pytest
from lmncell.config import load_config
from lmncell.identification.tree import Tree, skeleton
from lmncell.runtime.model import (
    ModelFileError,
    load_model,
    model_from_dict,
    model_to_dict,
    replaced_whole,
    save_model,
    xml_text,
)
from lmncell.runtime.step import CellStepper, simulate
from lmncell.runtime.vector import VectorCells


def random_tree_model(gating: str = "none", n_splits: int = 5, d: int = 3,
                      temperature_terms: int = 0, output_lags: int = 0,
                      fast_depletion: bool = False, hysteresis_terms: str = "polynomial"):
    """A model with a tree of n_splits random oblique splits and random stable local models
    (ARX with output_lags > 0); fast_depletion: with the second depletion regressor d2(k)
    (τ2 = 5 s); hysteresis_terms "arrhenius": with E = 3000 K, the hysteresis column's
    temperature terms in dA."""
    rng = np.random.default_rng(0)
    cfg = load_config(partition=["soc", "current", "temperature"][:d], pre_partition=gating,
                      output_lags=output_lags,
                      local_model_form="free" if output_lags else "auto",
                      depletion_fast_tau_s=5.0 if fast_depletion else 0)
    base = skeleton(cfg, 2.0, np.linspace(0, 1, 5), np.linspace(3.0, 3.4, 5), 50.0,
                    np.zeros(d), np.ones(d), temperature_terms)
    if hysteresis_terms == "arrhenius":
        base.arrhenius_k = 3000.0
    base.hysteresis_terms = hysteresis_terms
    p = len(base.columns())
    theta = rng.normal(0, 0.01, (len(base.roots), p))
    theta[:, :3] = [0.5, 0.2, 0.1]
    tree = Tree(list(base.roots), [], [], theta)
    for _ in range(n_splits):
        leaf = int(rng.integers(tree.theta.shape[0]))
        child = rng.normal(0, 0.01, p)
        child[:3] = [0.6, 0.1, 0.05]
        tree = tree.split(leaf, rng.normal(0, 2, d + 1), tree.theta[leaf], child)
    return tree.apply(base)


@pytest.mark.parametrize("gating", ["none", "current_sign"])
def test_validities_sum_to_one(gating: str) -> None:
    m = random_tree_model(gating)
    rng = np.random.default_rng(1)
    z = rng.normal(0, 3, (2000, 3))
    direction = rng.integers(1, 3, 2000)
    Phi = m.validities(z, direction)
    assert Phi.shape == (2000, m.n_local_models)
    assert np.all(Phi >= 0)
    assert np.allclose(Phi.sum(axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("temperature_terms, fast, hysteresis_terms", [
    (0, False, "polynomial"), (2, False, "polynomial"), (0, True, "polynomial"),
    (2, False, "arrhenius"), (2, False, "constant")])
def test_batch_and_step_paths_agree(temperature_terms: int, fast: bool,
                                    hysteresis_terms: str) -> None:
    m = random_tree_model("current_sign", temperature_terms=temperature_terms,
                          fast_depletion=fast, hysteresis_terms=hysteresis_terms)
    rng = np.random.default_rng(2)
    cur = np.repeat(rng.normal(0, 2, 300), 5)
    temp = 20.0 + 10.0 * np.sin(np.arange(cur.size) / 200.0)
    sim = simulate(m, cur, temp, 0.7)
    st = CellStepper(m, 0.7, temperature_c=float(temp[0]))
    steps = np.array([st.step(i, t) for i, t in zip(cur, temp, strict=True)])
    assert np.max(np.abs(steps - sim.voltage_v)) <= 1e-12
    assert st.soc == pytest.approx(sim.soc[-1], abs=1e-15)


def test_step_path_takes_any_node_numbering() -> None:
    """The one-sample path evaluates parents before children whatever their numbers: a model
    file whose nodes are numbered in reverse (children before parents) steps as the original."""
    m = random_tree_model("current_sign")
    doc = model_to_dict(m)
    nodes = doc["tree"]["nodes"]
    n = len(nodes)

    def renumber(ref: list) -> list:
        return ["node", n - 1 - ref[1]] if ref[0] == "node" else ref

    doc["tree"]["nodes"] = [{"weights": nd["weights"],
                             "children": [renumber(c) for c in nd["children"]]}
                            for nd in reversed(nodes)]
    for root in doc["tree"]["roots"]:
        root["child"] = renumber(root["child"])
    r = model_from_dict(doc)
    rng = np.random.default_rng(3)
    cur = np.repeat(rng.normal(0, 2, 200), 5)
    temp = np.full(cur.size, 20.0)
    a, b = CellStepper(m, 0.6, temperature_c=20.0), CellStepper(r, 0.6, temperature_c=20.0)
    va = [a.step(i, 20.0) for i in cur]
    vb = [b.step(i, 20.0) for i in cur]
    assert np.max(np.abs(np.subtract(va, vb))) <= 1e-12
    assert np.max(np.abs(np.subtract(vb, simulate(r, cur, temp, 0.6).voltage_v))) <= 1e-12


@pytest.mark.parametrize("temperature_terms, fast", [(0, False), (2, False), (0, True)])
def test_outputs_at_other_socs_are_the_batch_model_there(temperature_terms: int,
                                                         fast: bool) -> None:
    """CellStepper.outputs_at_socs (the observers' measurement model) equals the batch path
    (LmnModel.blend on the step's regressors with the SoC replaced), and at the step's own
    SoC the step's voltage and validities; voltages_at_socs and local_voltages_at_socs give
    the same voltages and local voltages."""
    m = random_tree_model("current_sign", temperature_terms=temperature_terms,
                          fast_depletion=fast)
    st = CellStepper(m, 0.7, temperature_c=18.0)
    rng = np.random.default_rng(4)
    for i in rng.normal(0, 2, 40):
        st.step(float(i), 18.0)
    socs = [st.soc, 0.0, 0.31, 0.9, 1.0]
    got = st.outputs_at_socs(socs)
    assert got[0][0] == pytest.approx(st.voltage_v, abs=1e-12)
    assert np.allclose(got[0][1], st.validity, atol=1e-15)
    assert st.voltages_at_socs(socs) == [u for u, _, _ in got]     # the voltages alone
    assert st.local_voltages_at_socs(socs) == [local for _, _, local in got]
    na = m.output_lags
    assert m.depletion is not None             # the SoC enters its regressor d(k) too
    assert m.depletion.columns() == (["d(k)", "d2(k)"] if fast else ["d(k)"])
    d_cols = [m.columns().index(c) - na for c in m.depletion.columns()]
    for soc, (u, phi, local) in zip(socs, got, strict=True):
        z = st._z.copy()
        z[m.partition_variables.index("soc")] = soc
        x = st._x.copy()
        x[d_cols] = st._x[d_cols] / m.depletion.factor(st.soc) * m.depletion.factor(soc)
        A, b, Phi = m.blend(x[None, :], m.normalise(z[None, :]),
                            np.array([st.state.direction]))
        ocv = float(m.ocv(soc))
        assert u == pytest.approx(ocv + float(b[0] + A[0] @ np.asarray(st.prev_lags)),
                                  abs=1e-12)
        assert np.allclose(phi, Phi[0], atol=1e-14)
        expect = ocv + x @ m.theta[:, na:].T + m.theta[:, :na] @ np.asarray(st.prev_lags)
        assert np.allclose(local, expect, atol=1e-12)


def test_temperature_terms_are_the_source_columns_times_powers_of_dt() -> None:
    m = random_tree_model(temperature_terms=2)
    cols = m.columns()
    assert cols[-2 * len(m.temperature_term_sources()):] == (
        [f"{c}*dT^1" for c in m.temperature_term_sources()]
        + [f"{c}*dT^2" for c in m.temperature_term_sources()])
    st = CellStepper(m, 0.5, temperature_c=5.0)
    st.step(-2.0, 5.0)                              # dT = (5 − 25)/10 = −2
    x = st._x
    exo = cols[m.output_lags:]
    for c in m.temperature_term_sources():
        assert x[exo.index(f"{c}*dT^1")] == pytest.approx(-2.0 * x[exo.index(c)])
        assert x[exo.index(f"{c}*dT^2")] == pytest.approx(4.0 * x[exo.index(c)])


def test_arrhenius_hysteresis_terms_are_h_times_powers_of_da(tmp_path) -> None:
    """h(k)·dA, h(k)·dA² with dA = (1 − g(T))·T_ref²/(E·10 K); the other sources in dT; the
    basis survives a round trip and is refused in a version 6 file or without E."""
    m = random_tree_model(temperature_terms=2, hysteresis_terms="arrhenius")
    exo = m.columns()[m.output_lags:]
    assert "h(k)*dA^1" in exo and "h(k)*dA^2" in exo and "h(k)*dT^1" not in exo
    st = CellStepper(m, 0.5, temperature_c=5.0)
    st.step(-2.0, 5.0)
    x = st._x
    g = math.exp(3000.0 * (1.0 / 278.15 - 1.0 / 298.15))
    da = (1.0 - g) * 298.15 ** 2 / 30000.0           # −3.15: further out than dT = −2 when cold
    assert da == pytest.approx(-3.146, abs=1e-3)
    assert x[exo.index("h(k)*dA^1")] == pytest.approx(da * x[exo.index("h(k)")], rel=1e-12)
    assert x[exo.index("h(k)*dA^2")] == pytest.approx(da * da * x[exo.index("h(k)")],
                                                      rel=1e-12)
    assert x[exo.index("1*dT^2")] == pytest.approx(4.0, rel=1e-12)
    path = tmp_path / "a.json"
    save_model(m, path)
    assert load_model(path).hysteresis_terms == "arrhenius"
    doc = json.loads(path.read_text())
    doc["version"] = 6
    with pytest.raises(ModelFileError, match="'hysteresis_terms' 'arrhenius' exists from "
                                             "version 7 on"):
        model_from_dict(doc, "v6")
    doc["version"] = 7
    doc["regressors"]["arrhenius_k"] = None
    with pytest.raises(ModelFileError, match="'arrhenius_k' is None, expected a number of K > 0"):
        model_from_dict(doc, "v7")
    doc["regressors"].update(arrhenius_k=3000.0, hysteresis_terms="cubic")
    with pytest.raises(ModelFileError, match="'hysteresis_terms' is 'cubic', expected one of "
                                             "'constant', 'polynomial', 'arrhenius'"):
        model_from_dict(doc, "v7")


def test_constant_hysteresis_terms_leave_the_hysteresis_column_out_of_the_terms(tmp_path
                                                                                 ) -> None:
    m = random_tree_model(temperature_terms=2, hysteresis_terms="constant")
    assert "h(k)" in m.columns() and "h(k)" not in m.temperature_term_sources()
    assert not any(c.startswith("h(k)*") for c in m.columns())
    assert "1*dT^2" in m.columns()
    path = tmp_path / "c.json"
    save_model(m, path)
    again = load_model(path)
    assert again.hysteresis_terms == "constant" and again.columns() == m.columns()


def test_model_round_trip_is_bit_identical(tmp_path) -> None:
    m = random_tree_model(temperature_terms=2)
    p1, p2 = tmp_path / "a.json", tmp_path / "b.json"
    save_model(m, p1)
    m2 = load_model(p1)
    save_model(m2, p2)
    assert p1.read_bytes() == p2.read_bytes()
    assert np.array_equal(m.theta, m2.theta) and np.array_equal(m.node_weights, m2.node_weights)
    cur = np.sin(np.arange(500) / 20.0)
    assert np.array_equal(simulate(m, cur, None, 0.5).voltage_v,
                          simulate(m2, cur, None, 0.5).voltage_v)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(version=10),
     r"version 10; this LMNCell reads versions \[1, 2, 3, 4, 5, 6, 7, 8, 9\]"),
    (lambda d: d["regressors"].update(core_rise={"k_per_a2": -0.1, "tau_s": 120.0}),
     r"core_rise: 'k_per_a2' is -0.1, expected a number within 0…10"),
    (lambda d: d["regressors"].update(core_rise={"k_per_a2": 0.01, "tau_s": 0.0}),
     r"core_rise: 'tau_s' is 0.0, expected a number within 0 \(excluded\)…100000"),
    (lambda d: d["regressors"].update(core_rise={"k_per_a2": 0.01}),
     r"'core_rise' must be null or an object with the keys 'k_per_a2' and 'tau_s'"),
    (lambda d: d.update(version=8) or d["regressors"].update(
        core_rise={"k_per_a2": 0.01, "tau_s": 120.0}),
     r"'core_rise' exists from version 9 on; this file says version 8"),
    (lambda d: d["regressors"].update(activation_t0_k=250.0),
     r"'activation_t0_k' is 250.0, expected a number within 0…200"),
    (lambda d: d["regressors"].update(activation_t0_k=float("nan")),
     r"'activation_t0_k' is nan"),
    (lambda d: d["regressors"].update(time_constant_activation_k=-5.0),
     r"'time_constant_activation_k' is -5.0, expected null or a number of K within 0…10000"),
    (lambda d: d["regressors"].update(time_constant_activation_k="1500"),
     r"'time_constant_activation_k' is '1500'"),
    (lambda d: d.update(current_delay_s=1.0), r"'current_delay_s' is 1.0, expected a number 0 ≤ δ"),
    (lambda d: d.update(current_delay_s="0.1"), r"'current_delay_s' is '0.1'"),
    (lambda d: d["regressors"].update(depletion={"tau_s": 150.0}), "'depletion' must be null"),
    (lambda d: d["regressors"]["depletion"].update(power=-1.0), "'depletion' must be null"),
    (lambda d: d["regressors"]["depletion"].update(tau_s=7.0),
     "depletion time constant 7 s is none of the filters' time constants"),
    (lambda d: d["regressors"].update(depletion=None), "theta has shape"),
    (lambda d: d.update(version=True), "version True"),
    (lambda d: d.update(thermal={"resistance_k_per_w": 2.0}), "'thermal' must be null"),
    (lambda d: d.update(thermal={"resistance_k_per_w": -2.0, "time_constant_s": 900.0,
                                 "offset_k": 0.0}), "thermal.resistance_k_per_w is -2.0"),
    (lambda d: d.update(thermal={"resistance_k_per_w": 2.0, "time_constant_s": "x",
                                 "offset_k": 0.0}), "thermal.time_constant_s is 'x'"),
    (lambda d: d.update(thermal={"resistance_k_per_w": True, "time_constant_s": 900.0,
                                 "offset_k": 0.0}), "thermal.resistance_k_per_w is True"),
    (lambda d: d.update(format="other"), "format is 'other'"),
    (lambda d: d["local_models"]["theta"][0].pop(), "inhomogeneous|theta"),
    (lambda d: d["local_models"]["theta"].pop(), "belong to no leaf|leaf"),
    (lambda d: d["partition"].update(variables=["soc", "pressure", "temperature"]),
     "'pressure'"),
    (lambda d: d["tree"]["nodes"][0].update(weights=[1.0]), "tree node weights"),
    (lambda d: d.update(sample_time_s=-1), "'sample_time_s' is -1"),
    (lambda d: d["cell"].pop("capacity_ah"), "missing key 'capacity_ah'"),
    (lambda d: d["regressors"].update(temperature_terms=5), "'temperature_terms' is 5"),
    (lambda d: d["regressors"].update(temperature_terms=1), "theta has shape"),
    (lambda d: d.update(noise={"residual_std_by_soc": {"soc": [0.5, 0.2],
                                                       "std_v": [0.01, 0.01]}}),
     "residual_std_by_soc: expected increasing SoC"),
    (lambda d: d.update(noise={"residual_std_by_soc": {"soc": [0.5], "std_v": [-1.0]}}),
     "residual_std_by_soc: expected"),
    (lambda d: d.update(noise={"residual_rms_by_soc": {"soc": [0.5], "rms_v": [0.1, 0.2]}}),
     "residual_rms_by_soc: expected"),
    (lambda d: d.update(noise={"residual_rms_by_soc": {"soc": [0.5]}}), "rms_v"),
    (lambda d: d.update(noise=[1]), "'noise' must be an object"),
    (lambda d: d["regressors"].update(arrhenius_k=True), "'arrhenius_k' is True"),
    (lambda d: d["regressors"].update(arrhenius_k=-3000.0), "'arrhenius_k' is -3000.0"),
    (lambda d: d["regressors"].update(arrhenius_k=1e6), "within 0…20000"),
    (lambda d: d["regressors"].update(hysteresis_gamma="fast"), "'hysteresis_gamma' is 'fast'"),
    (lambda d: d["regressors"].update(hysteresis_gamma=-10.0), "'hysteresis_gamma' is -10.0"),
    (lambda d: d["regressors"].update(hysteresis_gamma=False), "'hysteresis_gamma' is False"),
    # found by mutating every key of a trained model's file (NaN outputs, TypeErrors,
    # OverflowErrors, an endless loop for a depletion power of 1e300)
    (lambda d: d.update(sample_time_s=float("inf")),
     "'sample_time_s' is inf, expected a number within 0.0001…3600"),
    (lambda d: d["cell"].update(capacity_ah=1e-300), "'capacity_ah' is 1e-300"),
    (lambda d: d["cell"].update(efficiency_charge=float("nan")), "'efficiency_charge' is nan"),
    (lambda d: d["cell"].update(efficiency_discharge=None), "'efficiency_discharge' is NoneType"),
    (lambda d: d["cell"].update(voltage_min_v=4.3, voltage_max_v=4.2),
     "voltage_min_v 4.3 V is not below voltage_max_v 4.2 V"),
    (lambda d: d["ocv"].update(voltage_v=[1e300] * len(d["ocv"]["soc"])),
     "expected SoC knots within -1…2 and a cell's voltages within 0…10 V"),
    (lambda d: d["regressors"].update(filters=[[None, 5.0]]), "'filters' is \\[\\[None"),
    (lambda d: d["regressors"].update(filters=[5.0]), "'filters' is \\[5.0\\]"),
    (lambda d: d["regressors"].update(reference_temperature_c=float("nan")),
     "'reference_temperature_c' is nan, expected a number within -60…100"),
    (lambda d: d["regressors"]["depletion"].update(power=1e300), "'depletion' power 1e\\+300"),
    (lambda d: d["regressors"]["depletion"].update(soc_scale=1.5),
     "expected a power within 0…8, soc_scale and soc_min within 0…1"),
    (lambda d: d.update(gating={"mode": "none", "rest_current_a": float("inf")}),
     "'rest_current_a' is inf"),
    (lambda d: d.update(gating={"mode": "none", "initial_direction": "up"}),
     "'initial_direction' is 'up'"),
    # written into the FMUs' modelDescription.xml, documentation and C sources: a number
    # ended the build in an AttributeError, a control character in unreadable XML
    (lambda d: d["cell"].update(name=5), "cell: 'name' is 5, expected a string"),
    (lambda d: d.update(description=["x"]), "'description' is \\['x'\\], expected a string"),
    (lambda d: d["cell"].update(name="A\x07"), "'name' holds the character '\\\\x07' at position 1"),
    (lambda d: d.update(description="b\udcff"), "'description' holds the character '\\\\udcff'"),
    (lambda d: d["tree"]["roots"].__setitem__(0, None),
     "tree.roots\\[0\\] is None, expected an object"),             # was an AttributeError
    (lambda d: d["tree"]["roots"][0].update(child=["leaf", True]), "got \\['leaf', True\\]"),
    # flags read as bool() took the string "false" as true
    (lambda d: d["regressors"].update(offset="false"),
     "regressors: 'offset' is 'false', expected true or false"),
    (lambda d: d["regressors"].update(ocv_input=1), "'ocv_input' is 1, expected true or false"),
    (lambda d: d["regressors"].update(soc_input=None), "'soc_input' is None"),
    (lambda d: d.update(limits={"current_a": 5}), "limits.current_a is 5, expected \\[low, high"),
    (lambda d: d.update(limits={"soc": [1.0, 0.0]}), "limits.soc is \\[1.0, 0.0\\]"),
    (lambda d: d.update(noise={"residual_std_v": float("inf")}), "'residual_std_v' is inf"),
    (lambda d: d.update(noise={"recent_current_rms_a": "x"}), "'recent_current_rms_a' is str"),
    (lambda d: d.update(observers={"fuzzy": {"q": 1e-6, "r": 1e-4, "gains": [1e300]}}),
     "observers.fuzzy: 'gains' is \\[1e\\+300\\], expected one number within"),
    (lambda d: d.update(observers={"fuzzy": {"q": None, "r": 1e-4}}), "key 'q' is NoneType"),
    (lambda d: d["local_models"]["theta"][0].__setitem__(0, 1e300),
     "theta holds 1e\\+300, expected coefficients within ±1e\\+09"),
    # a misspelt key would be ignored: the model would step without what it names
    (lambda d: d.update(thermall=None), "bad.json: unknown key 'thermall'; expected only format"),
    (lambda d: d["regressors"].update(arrhenius=3000.0),
     "regressors: unknown key 'arrhenius'; expected only output_lags, .*arrhenius_k"),
    (lambda d: d["cell"].update(capacity=2.0), "cell: unknown key 'capacity'"),
    (lambda d: d.update(limits={"temperature": [0.0, 40.0]}), "limits: unknown key 'temperature'"),
    (lambda d: d["tree"]["nodes"][0].update(weight=[0.0]), r"tree.nodes\[0\]: unknown key 'weight'"),
    (lambda d: d["tree"]["roots"][0].update(gates="all"), r"tree.roots\[0\]: unknown key 'gates'"),
    (lambda d: d.update(noise={"residual_std_by_soc": {"soc": [0.5], "std": [0.01]}}),
     "noise.residual_std_by_soc: unknown key 'std'; expected only soc, std_v"),
    (lambda d: d.update(observers={"fuzy": {}}), "observers: unknown key 'fuzy'"),
])
def test_bad_model_files_are_refused(tmp_path, edit, message) -> None:
    doc = model_to_dict(random_tree_model())
    edit(doc)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises((ModelFileError, ValueError), match=message):
        load_model(p)


def test_training_and_baselines_metadata_are_not_checked_key_by_key(tmp_path) -> None:
    """The contents of 'training' and 'baselines' are metadata that no model step reads: keys
    of any name load (KNOWN_KEYS covers every other object)."""
    doc = model_to_dict(random_tree_model())
    doc["training"] = {"files": [{"path": "a.csv"}], "anything": 1}
    doc["baselines"] = {"ecm2rc": {"any_key": [1, 2]}}
    p = tmp_path / "meta.json"
    p.write_text(json.dumps(doc))
    assert load_model(p).extra["training"]["anything"] == 1


def test_names_from_file_names_are_made_xml_text(tmp_path) -> None:
    """A cell name made of file names (train._cell_name) keeps what XML allows and replaces the
    rest, so that the model file it goes into loads."""
    assert xml_text("cell of a\x07.csv, b\udcff.csv\tc\n") == "cell of a\ufffd.csv, b\ufffd.csv\tc\n"
    doc = model_to_dict(random_tree_model())
    doc["cell"]["name"] = doc["description"] = xml_text("\x00\x1f\ud800 x \U0001f50b")
    p = tmp_path / "m.json"
    p.write_text(json.dumps(doc))
    assert load_model(p).cell["name"] == "\ufffd\ufffd\ufffd x \U0001f50b"


def test_not_json_is_refused(tmp_path) -> None:
    p = tmp_path / "m.json"
    p.write_bytes(b"\x80\x04pickle?")
    with pytest.raises(ModelFileError, match="m.json: not a text .JSON. model file .* expected "
                                             "the JSON model file that `lmncell train` writes"):
        load_model(p)
    p.write_text("time,current,voltage\n0,0,3.3\n")    # a record given first, as the model
    with pytest.raises(ModelFileError, match="not valid JSON .*a data record is not one"):
        load_model(p)
    with pytest.raises(ModelFileError, match="expected a JSON object"):
        model_from_dict([1, 2], "list")


def test_depletion_regressor_is_the_low_pass_current_times_the_soc_factor() -> None:
    """d(k) = g(T)·LP_τ(i)·(soc_scale/max(SoC, soc_min))^power, τ the filters' 150 s state,
    in the step, the batch path and the vectorised stepper alike."""
    m = random_tree_model(temperature_terms=0)
    dep = m.depletion
    assert (dep.tau_s, dep.power, dep.soc_scale, dep.soc_min) == (150.0, 4.0, 0.1, 0.02)
    col = m.columns().index("d(k)") - m.output_lags
    st = CellStepper(m, 0.1)
    cells = VectorCells(m, 0.1, n=1)
    rng = np.random.default_rng(7)
    cur = rng.normal(-2.0, 1.0, 300)
    lp, a = 0.0, math.exp(-m.sample_time_s / 150.0)
    for i in cur:
        st.step(float(i), 25.0)
        lp = a * lp + (1.0 - a) * float(i)
        expected = lp * (0.1 / max(st.soc, 0.02)) ** 4
        assert st._x[col] == pytest.approx(expected, rel=1e-12, abs=1e-15)
        assert cells.step(np.array([i]), 25.0)[0] == pytest.approx(st.voltage_v, abs=1e-9)
    assert st.soc < 0.02                  # the factor is held below soc_min
    batch = simulate(m, cur, None, 0.1).voltage_v
    assert abs(batch[-1] - st.voltage_v) <= 1e-9


def test_fast_depletion_regressor_is_the_fast_low_pass_current_times_the_same_factor(
        tmp_path) -> None:
    """d2(k) = g(T)·LP_τ2(i)·factor(SoC), τ2 the filters' 5 s state, the column after d(k),
    in the step, the batch path and the vectorised stepper; the model file keeps τ2, a
    version-5 file may not have it, and one without it loads as before."""
    m = random_tree_model(temperature_terms=0, fast_depletion=True)
    assert m.depletion.fast_tau_s == 5.0
    exo = m.columns()[m.output_lags:]
    assert exo.index("d2(k)") == exo.index("d(k)") + 1
    assert "d2(k)" not in m.temperature_term_sources()
    st, cells = CellStepper(m, 0.15), VectorCells(m, 0.15, n=1)
    rng = np.random.default_rng(8)
    cur = rng.normal(-2.0, 1.5, 300)
    slow, fast = 0.0, 0.0
    a_slow, a_fast = math.exp(-m.sample_time_s / 150.0), math.exp(-m.sample_time_s / 5.0)
    for i in cur:
        st.step(float(i), 25.0)
        slow = a_slow * slow + (1.0 - a_slow) * float(i)
        fast = a_fast * fast + (1.0 - a_fast) * float(i)
        factor = (0.1 / max(st.soc, 0.02)) ** 4
        assert st._x[exo.index("d(k)")] == pytest.approx(slow * factor, rel=1e-12, abs=1e-15)
        assert st._x[exo.index("d2(k)")] == pytest.approx(fast * factor, rel=1e-12, abs=1e-15)
        assert cells.step(np.array([i]), 25.0)[0] == pytest.approx(st.voltage_v, abs=1e-9)
    assert abs(simulate(m, cur, None, 0.15).voltage_v[-1] - st.voltage_v) <= 1e-9
    p = tmp_path / "fast.json"
    save_model(m, p)
    assert load_model(p).depletion == m.depletion
    doc = json.loads(p.read_text())
    doc["version"] = 5
    with pytest.raises(ModelFileError, match="'fast_tau_s', which model files have from "
                                             "version 6 on"):
        model_from_dict(doc, "v5")
    old = model_to_dict(random_tree_model())
    old["version"] = 5
    del old["regressors"]["depletion"]["fast_tau_s"]
    assert model_from_dict(old, "v5").depletion.fast_tau_s is None
    doc["version"] = 6
    doc["regressors"]["depletion"]["fast_tau_s"] = 7.0
    with pytest.raises(ModelFileError, match="depletion time constant 7 s is none"):
        model_from_dict(doc, "v6")


def test_version_1_files_without_thermal_model_still_load(tmp_path) -> None:
    doc = model_to_dict(random_tree_model())
    doc["version"] = 1
    del doc["thermal"]
    p = tmp_path / "v1.json"
    p.write_text(json.dumps(doc))
    assert load_model(p).thermal is None


@pytest.mark.parametrize("gating, fast", [("none", False), ("current_sign", False),
                                          ("current_sign", True)])
def test_beside_is_the_voltage_beside_the_step(gating: str, fast: bool) -> None:
    """CellStepper.beside (the EKF's secant voltages from the step's own products in one
    walk) equals voltages_at_socs at SoC ± d, with output lags, the depletion regressor and
    current-sign gates, near SoC 0 and 1 too; with a wrong ∂act/∂SoC sign the two secant
    voltages would swap their validities' moves."""
    m = random_tree_model(gating, output_lags=2, fast_depletion=fast)
    assert m.output_lags == 2 and m.depletion is not None
    st = CellStepper(m, 0.7, temperature_c=18.0)
    rng = np.random.default_rng(6)
    checked = 0
    for i in rng.normal(0, 2, 60):
        st.step(float(i), 18.0)
        for d in (1e-4, 0.02, 0.2, 0.8):
            hi, lo = min(st.soc + d, 1.0), max(st.soc - d, 0.0)
            u_hi, u_lo = st.beside(hi, lo)
            expect_hi, expect_lo = st.voltages_at_socs([hi, lo])
            assert u_hi == pytest.approx(expect_hi, abs=1e-12)
            assert u_lo == pytest.approx(expect_lo, abs=1e-12)
            checked += 1
    assert checked == 240


def test_filter_time_constants_follow_the_temperature() -> None:
    """With Eτ the filters' time constants are τ·exp(Eτ(1/T − 1/T_ref)): the step and the batch
    path (simulate) agree over a temperature that sweeps 0…45 °C, a cold cell relaxes slower
    than a warm one after the same pulse (as without Eτ it does not), the runtime's many-cell
    step agrees, and the model file keeps Eτ."""
    from lmncell.runtime.step import arrhenius_factor, filter_coefficients

    m = random_tree_model()
    m.tau_activation_k = 1500.0
    assert arrhenius_factor(25.0, 1500.0) == 1.0
    assert arrhenius_factor(0.0, 1500.0) == pytest.approx(
        math.exp(1500.0 * (1 / 273.15 - 1 / 298.15)), rel=1e-15)
    assert filter_coefficients(m, 25.0) == filter_coefficients(m)
    rng = np.random.default_rng(7)
    cur = np.repeat(rng.normal(0, 2, 120), 5)
    temp = np.linspace(0.0, 45.0, cur.size)
    st = CellStepper(m, 0.6, temperature_c=0.0)
    stepped = [st.step(float(i), float(t)) for i, t in zip(cur, temp, strict=True)]
    assert np.max(np.abs(simulate(m, cur, temp, 0.6).voltage_v - stepped)) <= 1e-12
    cells = VectorCells(m, 0.6, n=2, temperature_c=0.0)
    for i, t in zip(cur, temp, strict=True):
        many = cells.step(np.full(2, i), t)
    assert np.max(np.abs(many - stepped[-1])) <= 1e-12

    def retained_after_rest(model, t_c: float) -> float:
        """The share of the 800 s filter's low-pass state left after a 300 s rest."""
        s = CellStepper(model, 0.6, temperature_c=t_c)
        for _ in range(60):
            s.step(-5.0, t_c)
        loaded = s.state.lp[-3]
        for _ in range(300):
            s.step(0.0, t_c)
        return s.state.lp[-3] / loaded

    assert retained_after_rest(m, 0.0) > retained_after_rest(m, 40.0) > 0.0
    assert retained_after_rest(m, 25.0) == pytest.approx(math.exp(-300.0 / 800.0), rel=1e-12)
    m.tau_activation_k = None
    assert retained_after_rest(m, 0.0) == retained_after_rest(m, 40.0)
    m.tau_activation_k = 1500.0
    assert model_from_dict(model_to_dict(m)).tau_activation_k == 1500.0


def _leaves(doc: object, path: tuple = ()):
    """(path, value) of every key, list and the first three and last items of each list of a
    model document (its metadata 'training' and 'description' left out)."""
    if isinstance(doc, dict):
        for key, value in doc.items():
            if path or key not in ("training", "description", "format"):
                yield from _leaves(value, (*path, key))
    elif isinstance(doc, list):
        yield path, doc
        for k in sorted({*range(min(3, len(doc))), len(doc) - 1} - {-1}):
            yield from _leaves(doc[k], (*path, k))
    else:
        yield path, doc


def _mutations(value: object):
    """Values a corrupted or hand-edited file may hold instead of `value`."""
    yield from (math.nan, math.inf, -1e300, 1e300, 0, -1, 1e-300, "x", None, [], {}, True)
    if isinstance(value, list) and value:
        yield from (value[:-1], value[::-1])
    if isinstance(value, float) and value:
        yield from (-value, value * 1e6, value * 1e-6)


@pytest.mark.slow
def test_no_edit_of_a_model_file_gives_a_traceback_a_hang_or_nan(quick_model, tmp_path) -> None:
    """Each key of a trained model's file set to each of _mutations: loading refuses it with a
    ModelFileError, or the model simulates (cell temperature, ambient, cold) and its observers
    step with finite outputs. Before, 490 mutations gave TypeErrors, OverflowErrors or NaN,
    and a depletion power of 1e300 never returned."""
    import copy
    import warnings

    from lmncell.runtime.observers import SocObserver

    current = np.concatenate([np.full(60, -2.85), np.zeros(40), np.full(60, 2.0),
                              np.zeros(20), np.full(40, -8.0), np.zeros(10)])
    source = json.loads(quick_model.read_text())
    found = []
    for path, value in list(_leaves(source)):
        for new in _mutations(value):
            doc = copy.deepcopy(source)
            node = doc
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = new
            file = tmp_path / "m.json"
            file.write_text(json.dumps(doc))
            label = f"{'/'.join(map(str, path))} = {new!r:.40}"
            try:
                model = load_model(file)
            except ModelFileError:
                continue
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    runs = [simulate(model, current, np.full(current.size, t), soc0).voltage_v
                            for t, soc0 in ((25.0, 1.0), (-20.0, 0.5))]
                    for kind in ("ekf", "fuzzy", "imm"):
                        obs = SocObserver(model, kind, 0.7)
                        runs.append([obs.step(float(i), 3.6, 25.0) for i in current[:20]])
            except Exception as exc:       # any error is a finding here
                found.append(f"{label}: {type(exc).__name__}: {exc}")
                continue
            if not all(np.isfinite(r).all() for r in runs):
                found.append(f"{label}: non-finite output")
    assert not found, "\n".join(found[:20])


def test_the_vtf_form_has_the_arrhenius_slope_at_the_reference() -> None:
    """activation_t0_k: T0 = 0 is the Arrhenius factor to the bit; with T0 > 0 the factor has
    E's slope at T_ref and an apparent activation d ln k/d(1/T) that grows towards the cold
    (the Vogel–Tammann–Fulcher form), scalar and vector alike."""
    import math

    from lmncell.runtime.step import arrhenius_factor, arrhenius_gain

    temps = np.array([-20.0, 0.0, 10.0, 25.0, 33.0, 45.0])
    old = np.exp(3000.0 * (1.0 / (temps + 273.15) - 1.0 / 298.15))
    assert np.array_equal(arrhenius_gain(temps, 3000.0, temps.size), old)
    assert [arrhenius_factor(float(t), 3000.0) for t in temps] == [
        math.exp(3000.0 * (1.0 / (t + 273.15) - 1.0 / 298.15)) for t in temps]

    def apparent(t: float, t0: float, dt: float = 1e-3) -> float:    # d ln k / d(1/T)
        up, down = arrhenius_factor(t + dt, 3000.0, 25.0, t0), arrhenius_factor(t - dt, 3000.0,
                                                                                 25.0, t0)
        return math.log(up / down) / (1.0 / (t + dt + 273.15) - 1.0 / (t - dt + 273.15))

    assert apparent(25.0, 170.0) == pytest.approx(3000.0, rel=1e-6)
    assert apparent(10.0, 170.0) > 1.1 * 3000.0 > 3000.0 > 1.04 * apparent(33.0, 170.0)
    assert arrhenius_factor(25.0, 3000.0, 25.0, 170.0) == 1.0
    np.testing.assert_allclose(arrhenius_gain(temps, 3000.0, temps.size, 25.0, 170.0),
                               [arrhenius_factor(float(t), 3000.0, 25.0, 170.0) for t in temps],
                               rtol=1e-15)


def test_a_model_file_is_written_whole_or_not_at_all(quick_model, tmp_path, monkeypatch) -> None:
    """save_model writes beside the file and replaces it in one step: a write that fails part
    way (here a full disk after half the text) leaves the file as it was and no part behind,
    and the error names the file asked for, not the part."""
    model = load_model(quick_model)
    path = tmp_path / "cell.json"
    path.write_text("the model of yesterday", encoding="utf-8")
    real = Path.write_text

    def full_disk(self: Path, text: str, *args, **kwargs) -> int:
        real(self, text[: len(text) // 2], *args, **kwargs)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full_disk)
    with pytest.raises(OSError) as failed:
        save_model(model, path)
    assert failed.value.filename == str(path)
    monkeypatch.undo()
    assert path.read_text(encoding="utf-8") == "the model of yesterday"
    assert [p.name for p in tmp_path.iterdir()] == ["cell.json"]
    path.chmod(0o640)
    save_model(model, path)
    assert model_to_dict(load_model(path)) == model_to_dict(model)
    assert [p.name for p in tmp_path.iterdir()] == ["cell.json"]
    assert path.stat().st_mode & 0o777 == 0o640


def test_replaced_whole_keeps_an_error_that_names_another_file(tmp_path) -> None:
    """An error about another file (one being read) keeps its own name."""
    with pytest.raises(FileNotFoundError) as failed, replaced_whole(tmp_path / "x.fmu"):
        (tmp_path / "absent.json").read_text()
    assert failed.value.filename == str(tmp_path / "absent.json")
    assert list(tmp_path.iterdir()) == []


def test_a_model_file_through_a_link_or_into_a_pipe(quick_model, tmp_path) -> None:
    """A link to the model file keeps pointing at it, rewritten; a path that is no regular
    file (a pipe, as /dev/stdout can be) is written to, not replaced by a file."""
    model = load_model(quick_model)
    target, link = tmp_path / "models" / "cell.json", tmp_path / "cell.json"
    target.parent.mkdir()
    target.write_text("old", encoding="utf-8")
    link.symlink_to(target)
    save_model(model, link)
    assert link.is_symlink() and model_to_dict(load_model(target)) == model_to_dict(model)
    assert sorted(p.name for p in target.parent.iterdir()) == ["cell.json"]
    pipe, got = tmp_path / "pipe", []
    os.mkfifo(pipe)
    reader = threading.Thread(target=lambda: got.append(pipe.read_text(encoding="utf-8")))
    reader.start()
    save_model(model, pipe)
    reader.join(timeout=30)
    assert not pipe.is_file() and got == [target.read_text(encoding="utf-8")]
