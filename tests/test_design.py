"""Experiment design (issue: experiment design): every constraint is checked."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from lmncell.cli import main
from lmncell.data.readers import read_record
from lmncell.data.records import DataError
from lmncell.design.optimal import (
    CellSpec,
    CyclerSpec,
    DesignSpec,
    design_programme,
    log_det_information,
    parse_profile,
    predict,
    random_programme,
)


@pytest.fixture(scope="module")
def programme(tmp_path_factory):
    out = tmp_path_factory.mktemp("design") / "P.csv"
    assert main(["design", "--capacity", "2.3", "--soc-profile", "0.8,0.2,0.8",
                 "--max-c-rate", "20", "--duration", "7200", "--out", str(out),
                 "--plot", str(out.parent)]) == 0
    return out


def test_cycler_csv_and_bdf(programme) -> None:
    with open(programme) as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "current_a"]
    t = np.array([float(r[0]) for r in rows[1:]])
    i = np.array([float(r[1]) for r in rows[1:]])
    assert t[0] == 0.0 and np.allclose(np.diff(t), 1.0) and t.size == 7200
    # limits: 20 C of 2.3 Ah, and the 10 s minimum hold time
    assert np.abs(i).max() <= 20 * 2.3 + 1e-9
    changes = np.flatnonzero(np.diff(i) != 0) + 1
    assert np.all(np.diff(np.concatenate([[0], changes])) >= 10)
    # the SoC profile is reached within ±2 % by coulomb counting from 0.8
    soc = 0.8 + np.cumsum(i) / 3600 / 2.3
    assert abs(soc[3599] - 0.2) <= 0.02 and abs(soc[-1] - 0.8) <= 0.02
    assert soc.min() >= 0.2 - 0.02 and soc.max() <= 0.8 + 0.02
    rec = read_record(programme.with_suffix(".bdf.csv"))
    assert np.array_equal(rec.current_a, i)
    # the predicted voltage stays within the cell's limits (2.0 … 3.6 V)
    u, _, _ = predict(CellSpec(capacity_ah=2.3), i, 1.0, 0.8, np.zeros(2))
    assert u.min() >= 2.0 and u.max() <= 3.6
    assert (programme.parent / "fig05_sequence.png").exists()
    assert (programme.parent / "fig06_programme.png").exists()


def test_design_is_deterministic_and_more_informative_than_random() -> None:
    cell, cyc = CellSpec(capacity_ah=2.3), CyclerSpec()
    spec = DesignSpec([0.6, 0.5], duration_s=600, sequence_s=300)
    a = design_programme(cell, cyc, spec, progress=lambda _m: None)
    b = design_programme(cell, cyc, spec, progress=lambda _m: None)
    assert np.array_equal(a.current_a, b.current_a)
    r = random_programme(cell, cyc, spec)
    assert log_det_information(cell, a.current_a, 1.0) > log_det_information(cell, r.current_a,
                                                                             1.0)


def test_bad_design_inputs() -> None:
    with pytest.raises(DataError, match="soc-profile"):
        parse_profile("0.8")
    with pytest.raises(DataError, match="soc-profile"):
        parse_profile("0.8,1.2")
    assert parse_profile("0.8:0.2") == [0.8, 0.2]
    with pytest.raises(DataError, match="above the"):
        design_programme(CellSpec(capacity_ah=2.3, max_c_rate=1.0), CyclerSpec(),
                         DesignSpec([1.0, 0.0], duration_s=600), progress=lambda _m: None)


def test_random_programme_has_the_designs_amplitude_bands_and_limits() -> None:
    cell, cyc = CellSpec(capacity_ah=2.3), CyclerSpec()
    spec = DesignSpec([0.8, 0.2, 0.8], duration_s=7200)
    d = design_programme(cell, cyc, spec, progress=lambda _m: None)
    r = random_programme(cell, cyc, spec, seed=3, kind="aprbs")
    assert r.current_a.size == d.current_a.size
    u, soc, _ = predict(cell, r.current_a, 1.0, 0.8, np.zeros(2))
    assert u.min() >= 2.0 + spec.voltage_margin_v - 1e-9
    assert u.max() <= 3.6 - spec.voltage_margin_v + 1e-9
    assert abs(soc[3599] - 0.2) <= 0.02 and abs(soc[-1] - 0.8) <= 0.02
    # sequence by sequence: at most the designed band, and a spread reduced only where the
    # voltage limit needs it (most sequences use over half of their band, as the design does)
    seq_r, seq_d = r.current_a.reshape(24, 300), d.current_a.reshape(24, 300)
    assert np.all(np.abs(seq_r).max(axis=1) <= np.abs(seq_d).max(axis=1) + 1e-9)
    ratio = np.abs(seq_r).max(axis=1) / np.abs(seq_d).max(axis=1)
    assert np.median(ratio) > 0.5


def test_designed_sequences_use_several_current_levels() -> None:
    cell, cyc = CellSpec(capacity_ah=2.3), CyclerSpec()
    spec = DesignSpec([0.6, 0.5], duration_s=600, sequence_s=300)
    d = design_programme(cell, cyc, spec, progress=lambda _m: None)
    band = np.abs(d.current_a[:300]).max()
    levels = np.unique(np.round(np.abs(d.current_a[:300]) / band, 1))
    assert levels.size >= 4, levels


def test_virtual_ocv_test_gives_the_virtual_cells_ocv(tmp_path) -> None:
    from lmncell.design.optimal import DEFAULT_OCV_SOC, DEFAULT_OCV_V, _virtual_ocv_test
    from lmncell.design.virtual_cell import VirtualCell
    from lmncell.identification.ocvfit import measured_ocv

    path = _virtual_ocv_test(VirtualCell(capacity_ah=2.3), 2.3, tmp_path)
    knots = np.linspace(0.1, 0.9, 9)
    ocv = measured_ocv([str(path)], 2.3, knots)
    assert np.max(np.abs(ocv - np.interp(knots, DEFAULT_OCV_SOC, DEFAULT_OCV_V))) < 0.005


@pytest.mark.slow
def test_virtual_cell_proof_reports_every_programme() -> None:
    from lmncell.design.optimal import compare_on_virtual_cell

    cell, cyc = CellSpec(capacity_ah=2.3), CyclerSpec()
    spec = DesignSpec([0.8, 0.2, 0.8], duration_s=7200)
    d = design_programme(cell, cyc, spec, progress=lambda _m: None)
    out = compare_on_virtual_cell(d, cell, cyc, spec, progress=lambda _m: None, seeds=(1, 2))
    assert set(out["programmes"]) == {"designed", "prbs_seed_1", "prbs_seed_2", "aprbs_seed_1",
                                      "aprbs_seed_2"}
    for row in out["programmes"].values():
        assert 0.5 < row["ev_discharge_4c_rmse_mv"] < 50
    assert out["covariance_det_ratio_prbs_over_designed"] > 1.0
    assert out["covariance_det_ratio_aprbs_over_designed"] > 1.0


@pytest.mark.parametrize("kind", ["prbs", "aprbs"])
def test_random_levels_have_zero_mean_and_unit_peak(kind) -> None:
    from lmncell.design.optimal import random_levels

    z = random_levels(np.random.default_rng(4), 30, kind)
    assert abs(z.mean()) < 1e-12 and np.isclose(np.abs(z).max(), 1.0)
    assert np.unique(np.round(z, 9)).size == (2 if kind == "prbs" else 30)
    with pytest.raises(ValueError, match="expected one of"):
        random_levels(np.random.default_rng(4), 30, "sine")
