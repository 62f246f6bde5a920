"""Shared fixtures: paths to the shipped data, a quickly trained model and its FMU."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
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

# Collected first, and with --no-loadscope-reorder (pyproject.toml) handed out first by
# pytest-xdist: test_readme.py's module fixture runs the whole demo (about two minutes); as a
# file with few tests it was otherwise handed out last and kept one worker busy alone at the end.
FIRST_FILES = ("test_readme.py",)


@pytest.fixture(autouse=True, scope="session")
def _temporary_files_under_the_base_temp(tmp_path_factory) -> Iterator[None]:
    """Temporary files of the test process and of the processes it starts (TMPDIR) go under
    pytest's base temp, which pytest prunes (the last three runs are kept), not into the
    system's: the FMUs that fmpy extracts for tests/fmu_helpers.Instance and
    tests/conformance_sequences stay behind (about 140 folders, 84 MB, per run)."""
    folder = str(tmp_path_factory.mktemp("tempfile"))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tempfile, "tempdir", folder)
        mp.setenv("TMPDIR", folder)
        yield


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the FIRST_FILES' tests before the others (a stable sort: the order is otherwise kept)."""
    items.sort(key=lambda item: item.path.name not in FIRST_FILES)


def chamber_cell_segments(n: int, tau_s: float, ocv_per_k: float = 0.0,
                          e_k: float = 4000.0) -> list:
    """Segments of a synthetic cell at constant chamber temperatures −5/5/25/45 °C (capacity
    2 Ah, Ts 1 s, seeded random current levels): u = 3.3 + 0.8·SoC + ocv_per_k·T +
    g(T)·(0.03·i + 0.01·LP_τ(i)), g(T) = exp(E·(1/T − 1/298.15 K))."""
    import numpy as np
    from lmncell.data.dataset import Segment
    from lmncell.identification.ocvfit import lowpass

    rng = np.random.default_rng(3)
    cap, ts = 2.0, 1.0
    segs = []
    for k, t_amb in enumerate((-5.0, 5.0, 25.0, 45.0)):
        i = np.repeat(rng.choice([-3.0, -1.5, -0.5, 0.0, 1.5], size=n // 20), 20)
        soc = 1.0 + np.cumsum(i) * ts / 3600.0 / cap
        g = np.exp(e_k * (1 / (t_amb + 273.15) - 1 / 298.15))
        u = 3.3 + 0.8 * soc + ocv_per_k * t_amb + g * (0.03 * i + 0.01 * lowpass(i, tau_s, ts))
        segs.append(Segment(f"chamber{k}", np.arange(1, n + 1) * ts, i, u, np.full(n, t_amb),
                            1.0, soc, np.ones(n)))
    return segs


def import_or_skip(name: str, reason: str):
    """Import an optional host package or skip the test with a reason. Also catches OSError:
    ecospy raises it at import when its system library (Debian libtbb12) is missing, which
    pytest.importorskip does not catch."""
    import importlib

    try:
        return importlib.import_module(name)
    except (ImportError, OSError) as exc:
        pytest.skip(f"{reason}: {type(exc).__name__}: {exc}")


def c_compiler_or_skip() -> None:
    """Skip the test where no C compiler builds the native FMU here (neither gcc nor ziglang:
    lmncell.fmu.native_build.compiler)."""
    from lmncell.fmu.native_build import compiler

    if compiler("c") is None:
        pytest.skip("no gcc and no ziglang: the native FMU cannot be compiled here")


def shared_or_skip(rel: str = "") -> Path:
    path = SHARED / rel
    if not path.exists():
        pytest.skip(f"needs the full data set at {path} (../shared/data), absent here")
    return path


@pytest.fixture(scope="session")
def quick_model(tmp_path_factory) -> Path:
    """A small LMN trained on the shipped Panasonic HWFET and HPPC records (≤ 3 local models;
    the HPPC rests pin down the OCV; Ts = 1 s, ten times fewer steps than the 0.1 s that
    "auto" takes from these 10 Hz logs). The US06 record stays unseen."""
    from lmncell.identification.train import train_files

    out = tmp_path_factory.mktemp("model") / "pan.json"
    train_files([PAN_HWFET, PAN_HPPC], out, capacity_ah=2.85, soc0=1.0,
                progress=lambda _m: None, max_local_models=3, oe_max_iterations=4,
                hysteresis="off", sample_time_s=1.0)
    return out


@pytest.fixture(scope="session")
def quick_fmu(quick_model, tmp_path_factory) -> Path:
    from lmncell.fmu.pythonfmu_build import build_fmu

    return build_fmu(quick_model, tmp_path_factory.mktemp("fmu") / "pan.fmu")


@pytest.fixture(scope="session")
def native_fmu(quick_model, tmp_path_factory) -> Path:
    from lmncell.fmu.native_build import build_native_fmu

    c_compiler_or_skip()
    return build_native_fmu(quick_model, tmp_path_factory.mktemp("native") / "cell.fmu")


@pytest.fixture(params=["pythonfmu", "native"])
def fmu(request) -> Path:
    """Each FMU flavour of the quick model in turn (only the one in use is built)."""
    return request.getfixturevalue("quick_fmu" if request.param == "pythonfmu" else "native_fmu")


@pytest.fixture(scope="session")
def fast_depletion_model(tmp_path_factory) -> Path:
    """A small LMN with the second, fast depletion regressor d2(k) (τ2 = 5 s), trained on the
    shipped Panasonic HWFET record."""
    from lmncell.identification.train import train_files

    out = tmp_path_factory.mktemp("d2") / "d2.json"
    train_files([PAN_HWFET], out, capacity_ah=2.85, soc0=1.0, progress=lambda _m: None,
                max_local_models=3, oe_max_iterations=2, hysteresis="off",
                depletion_fast_tau_s=5.0, sample_time_s=1.0)   # the 1 s segments of the tests
    return out


@pytest.fixture(scope="session")
def fast_depletion_native_fmu(fast_depletion_model, tmp_path_factory) -> Path:
    c_compiler_or_skip()
    from lmncell.fmu.native_build import build_native_fmu

    return build_native_fmu(fast_depletion_model, tmp_path_factory.mktemp("d2fmu") / "d2.fmu")


@pytest.fixture(scope="session")
def a123_model(tmp_path_factory) -> Path:
    """A small LMN with the one-state hysteresis, trained on the shipped A123 25 °C dynamic
    record (capacity 2.2 Ah, about the measured one): for observers that estimate h."""
    from lmncell.identification.train import train_files

    out = tmp_path_factory.mktemp("a123") / "a123.json"
    train_files([A123_S1], out, capacity_ah=2.2, soc0=1.0, progress=lambda _m: None,
                max_local_models=2, oe_max_iterations=2)
    return out
