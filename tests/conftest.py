"""Shared fixtures: paths to the shipped data, a quickly trained model and its FMU."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data"
SHARED = ROOT.parent / "shared" / "data"
PAN_US06 = DATA / "panasonic_18650pf/25degC/drive_cycles/03-20-17_01.43_25degC_US06_Pan18650PF.mat"
PAN_HWFET = DATA / "panasonic_18650pf/25degC/drive_cycles/03-20-17_05.56_25degC_HWFTa_Pan18650PF.mat"
PAN_HPPC = DATA / "panasonic_18650pf/25degC/hppc/03-11-17_08.47_25degC_5Pulse_HPPC_Pan18650PF.mat"
A123_S1 = DATA / "a123_plett/dyn/A123_DYN_50_P25_s1.csv.gz"
A123_S2 = DATA / "a123_plett/dyn/A123_DYN_50_P25_s2.csv.gz"


def import_or_skip(name: str, reason: str):
    """Import an optional host package or skip the test with a reason. Also catches OSError:
    ecospy raises it at import when its system library (Debian libtbb12) is missing, which
    pytest.importorskip does not catch."""
    import importlib

    try:
        return importlib.import_module(name)
    except (ImportError, OSError) as exc:
        pytest.skip(f"{reason}: {type(exc).__name__}: {exc}")


def shared_or_skip(rel: str = "") -> Path:
    path = SHARED / rel
    if not path.exists():
        pytest.skip(f"needs the full data set at {path} (../shared/data), absent here")
    return path


@pytest.fixture(scope="session")
def quick_model(tmp_path_factory) -> Path:
    """A small LMN trained on the shipped Panasonic HWFET and HPPC records (≤ 3 local models;
    the HPPC rests pin down the OCV). The US06 record stays unseen."""
    from lmncell.identification.train import train_files

    out = tmp_path_factory.mktemp("model") / "pan.json"
    train_files([PAN_HWFET, PAN_HPPC], out, capacity_ah=2.85, soc0=1.0,
                progress=lambda _m: None, max_local_models=3, oe_max_iterations=4,
                hysteresis="off")
    return out


@pytest.fixture(scope="session")
def quick_fmu(quick_model, tmp_path_factory) -> Path:
    from lmncell.fmu.pythonfmu_build import build_fmu

    return build_fmu(quick_model, tmp_path_factory.mktemp("fmu") / "pan.fmu")


@pytest.fixture(scope="session")
def native_fmu(quick_model, tmp_path_factory) -> Path:
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed: the native FMU cannot be compiled here")
    from lmncell.fmu.native_build import build_native_fmu

    return build_native_fmu(quick_model, tmp_path_factory.mktemp("native") / "cell.fmu")


@pytest.fixture(scope="session")
def a123_model(tmp_path_factory) -> Path:
    """A small LMN with the one-state hysteresis, trained on the shipped A123 25 °C dynamic
    record (capacity 2.2 Ah, about the measured one): for observers that estimate h."""
    from lmncell.identification.train import train_files

    out = tmp_path_factory.mktemp("a123") / "a123.json"
    train_files([A123_S1], out, capacity_ah=2.2, soc0=1.0, progress=lambda _m: None,
                max_local_models=2, oe_max_iterations=2)
    return out
