"""The native FMU's win64 binary (`lmncell build-fmu --native --platforms linux64,win64`),
cross-compiled with zig: a 64-bit Windows DLL that exports the whole FMI 2.0 co-simulation API
and needs nothing beyond Windows' own libraries, and, where Wine is installed, runs a drive
cycle with hostile inputs exactly as the linux64 binary does.

The tests that build the DLL are marked slow (`python -m pytest -m slow`): on a new machine zig
first builds its Windows C library, 105 s of the default run's 935 test-seconds on two cores
(December 2026). The checks of the build's arguments and messages stay in the default run."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from lmncell.cli import main

from tests.fmu_helpers import (
    HOST_C,
    assert_same_run,
    co_simulation_functions,
    compile_host,
    cross_built_fmu,
    linux64_reference_run,
    unzip_fmu,
)

WINDOWS_LIBRARIES = re.compile(r"(kernel32|api-ms-win-crt-[a-z]+-l1-1-0)\.dll", re.IGNORECASE)

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ziglang") is None,
                                reason="ziglang is not installed (pip install ziglang)")


@pytest.fixture(scope="module")
def both_fmu(quick_model, tmp_path_factory) -> Path:
    """The quick model's native FMU with linux64 and win64 binaries."""
    return cross_built_fmu(quick_model, tmp_path_factory.mktemp("win64"), "win64")


@pytest.mark.slow
def test_the_win64_binary_is_a_windows_dll_with_the_whole_fmi_api(both_fmu) -> None:
    import pefile

    with zipfile.ZipFile(both_fmu) as z:
        names = set(z.namelist())
        dll = pefile.PE(data=z.read("binaries/win64/LMNCell.dll"))
    assert {"binaries/linux64/LMNCell.so", "binaries/win64/LMNCell.dll"} <= names
    assert dll.is_dll() and dll.FILE_HEADER.Machine == 0x8664        # x86-64
    assert dll.OPTIONAL_HEADER.Magic == 0x20B                         # PE32+
    exported = {e.name.decode() for e in dll.DIRECTORY_ENTRY_EXPORT.symbols if e.name}
    wanted = co_simulation_functions()
    assert len(wanted) > 30 and wanted <= exported, wanted - exported
    imported = [i.dll.decode() for i in dll.DIRECTORY_ENTRY_IMPORT]
    assert all(WINDOWS_LIBRARIES.fullmatch(name) for name in imported), imported


def test_platforms_are_checked(quick_model, tmp_path, capsys) -> None:
    """An unknown platform, none, or --platforms without --native: exit 2 and a message."""
    out = str(tmp_path / "x.fmu")
    assert main(["build-fmu", str(quick_model), "--native", "--platforms", "win32",
                 "--out", out]) == 2
    assert ("--platforms: 'win32' is not a platform this build makes; expected one or more of "
            "linux64, win64, darwin64") in capsys.readouterr().err
    assert main(["build-fmu", str(quick_model), "--native", "--platforms", ",", "--out", out]) == 2
    assert "--platforms: none given" in capsys.readouterr().err
    assert main(["build-fmu", str(quick_model), "--platforms", "win64", "--out", out]) == 2
    assert "expected --native with --platforms" in capsys.readouterr().err
    assert not Path(out).exists()
    import lmncell
    from lmncell.fmu.interface import NativeBuildError

    with pytest.raises(NativeBuildError, match="platforms are for native=True"):
        lmncell.build_fmu(quick_model, out, platforms=["win64"])


def test_without_zig_a_win64_build_says_what_to_install(quick_model, tmp_path, monkeypatch,
                                                        capsys) -> None:
    from lmncell.fmu import native_build

    monkeypatch.setattr(native_build.importlib.util, "find_spec", lambda name: None)
    assert main(["build-fmu", str(quick_model), "--native", "--platforms", "linux64,win64",
                 "--out", str(tmp_path / "x.fmu")]) == 2
    assert "pip install ziglang" in capsys.readouterr().err


def test_a_cross_compilation_says_first_that_it_can_take_minutes(tmp_path, monkeypatch) -> None:
    """zig's first build for a target builds its C library (minutes): `build-fmu --native
    --platforms linux64,win64` was silent all that while."""
    from lmncell.fmu import native_build
    from lmncell.fmu.interface import NativeBuildError

    said: list[str] = []
    monkeypatch.setattr(native_build.subprocess, "run",
                        lambda cmd, **_kw: subprocess.CompletedProcess(cmd, 1, "", "stub"))
    with pytest.raises(NativeBuildError, match="zig cc failed"):
        native_build.compile_cross("win64", tmp_path, tmp_path / "LMNCell.dll",
                                   progress=said.append)
    assert said == ["compiling the win64 binary with zig (its first build for a target also "
                    "builds that target's C library: a few minutes)"]


@pytest.fixture(scope="module")
def hosts(both_fmu, tmp_path_factory) -> tuple[Path, str]:
    """A folder with the FMU unzipped (fmu/), host.c built for Linux (host) and for Windows
    (host.exe), and a Wine prefix (wine/, made once for all the runs); and the FMU's GUID."""
    from lmncell.fmu.native_build import fmi_headers

    if shutil.which("wine") is None:
        pytest.skip("Wine is not installed")
    d = tmp_path_factory.mktemp("hosts")
    guid = unzip_fmu(both_fmu, d / "fmu")
    compile_host(HOST_C, d / "host")
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", "x86_64-windows-gnu",
                    "-std=c99", "-O1", f"-I{fmi_headers()}", str(HOST_C), "-o",
                    str(d / "host.exe")], check=True, capture_output=True)
    subprocess.run(["wineboot", "-i"], env=_wine_env(d), capture_output=True, timeout=300)
    return d, guid


def _wine_env(d: Path) -> dict[str, str]:
    return {**os.environ, "WINEDEBUG": "-all", "WINEPREFIX": str(d / "wine")}


@pytest.mark.slow
@pytest.mark.parametrize("observer", [0, 1, 2, 3])
def test_under_wine_the_win64_binary_runs_as_the_linux64_one(hosts, observer) -> None:
    """host.c built for Windows loads the DLL under Wine and drives 3000 steps with hostile
    inputs (each observer in turn): every logged message, the refused steps and the final
    voltage, SoC and σ equal the linux64 binary's driven by host.c built for Linux."""
    d, guid = hosts
    args, linux = linux64_reference_run(d, guid, observer, "file:///C:/")
    windows = subprocess.run(["wine", "host.exe", "fmu/binaries/win64/LMNCell.dll", *args],
                             cwd=d, capture_output=True, text=True, timeout=600,
                             env=_wine_env(d))
    assert linux.returncode == 0 and windows.returncode == 0, windows.stderr[-2000:]
    assert_same_run(windows.stdout.replace("\r\n", "\n"), linux.stdout, atol=1e-12)
