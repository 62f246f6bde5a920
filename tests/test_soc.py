"""SoC, capacity, OCV curves, resampling (issue: foundation)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import A123_S1, A123_S2, DATA, PAN_US06
from training.dataset import starts_rested_full
from training.readers import read_record
from training.resample import resample, resample_segment
from training.soc import capacity_from_discharge, coulomb_count, ocv_from_slow_tests


def test_a123_capacity_and_soc_run_from_full_to_empty() -> None:
    s1, s2 = read_record(A123_S1), read_record(A123_S2)
    cap = capacity_from_discharge(s1, s2)
    assert 1.95 < cap < 2.15
    assert starts_rested_full(s1)
    soc1 = coulomb_count(s1, 1.0, cap)
    assert soc1[0] == 1.0 and 0.0 < soc1[-1] < 0.05
    soc2 = coulomb_count(s2, soc1[-1], cap)
    assert soc2[-1] == pytest.approx(0.0, abs=1e-9)


def test_ocv_branches_show_hysteresis() -> None:
    ocv = DATA / "a123_plett/ocv"
    s1, s2 = read_record(ocv / "A123_OCV_P25_S1.csv.gz"), read_record(ocv / "A123_OCV_P25_S2.csv.gz")
    s3 = read_record(ocv / "A123_OCV_P25_S3.csv.gz")
    cap = capacity_from_discharge(s1, s2)
    curve = ocv_from_slow_tests(s1, s3, cap)
    mid = (curve.soc > 0.2) & (curve.soc < 0.8)
    assert np.all(curve.charge_v[mid] > curve.discharge_v[mid])
    assert 0.005 < np.median(curve.hysteresis_v[mid]) < 0.05   # LFP: about 10–20 mV
    assert np.all(np.diff(curve.mean_v[mid]) > -1e-3)           # OCV rises with SoC


def test_resampling_keeps_charge_and_means() -> None:
    rec = read_record(PAN_US06)
    seg = rec.segments()[0]
    rs = resample_segment(seg, 1.0)
    assert np.allclose(np.diff(rs.time_s), 1.0)
    inside = seg.time_s <= rs.time_s[-1]
    q_raw = np.trapezoid(seg.current_a[inside], seg.time_s[inside]) / 3600
    q_rs = np.sum(rs.current_a) * 1.0 / 3600
    assert q_rs == pytest.approx(q_raw, rel=1e-3)
    assert len(resample(rec, 1.0)) == len(rec.segments())
