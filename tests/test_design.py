"""Experiment design (issue: experiment design): every constraint is checked."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from training.cli import main
from training.design import (
    CellSpec,
    CyclerSpec,
    DesignSpec,
    design_programme,
    log_det_information,
    parse_profile,
    predict,
    random_programme,
)
from training.readers import read_record
from training.records import DataError


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
