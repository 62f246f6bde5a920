"""The native FMU's darwin64 binary (`lmncell build-fmu --native --platforms linux64,darwin64`),
cross-compiled with zig: a universal Mach-O library (Intel and Apple silicon, macOS 11 or later)
whose two slices export the whole FMI 2.0 co-simulation API, need nothing beyond macOS's own
libSystem, and, for Apple silicon, which runs no unsigned code, carry an ad-hoc signature whose
page hashes match. No Mac runs here: the checks read the binary, they cannot load it. Where
qemu-aarch64 is installed, the same C built for arm64 (Linux) runs a drive cycle with hostile
inputs as the linux64 binary does."""

from __future__ import annotations

import hashlib
import importlib.util
import shutil
import struct
import subprocess
import sys
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.fmu_helpers import (
    HOST_C,
    assert_same_run,
    co_simulation_functions,
    compile_host,
    cross_built_fmu,
    linux64_reference_run,
    unzip_fmu,
)

LINKED_C = HOST_C.with_name("linked.c")   # host.c's dlopen/dlsym for a static executable

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ziglang") is None,
                                reason="ziglang is not installed (pip install ziglang)")

CPU_X86_64, CPU_ARM64 = 0x01000007, 0x0100000C
MH_DYLIB, PLATFORM_MACOS = 6, 1
LC_SYMTAB, LC_LOAD_DYLIB, LC_ID_DYLIB = 0x2, 0xC, 0xD
LC_CODE_SIGNATURE, LC_BUILD_VERSION = 0x1D, 0x32
LC_LOAD_WEAK_DYLIB, LC_REEXPORT_DYLIB = 0x80000018, 0x8000001F
N_EXT, N_TYPE, N_SECT = 0x01, 0x0E, 0x0E
SHA256 = 2   # the CodeDirectory's hash type


@dataclass
class MachO:
    """What a thin 64-bit Mach-O library says of itself (little-endian)."""

    cputype: int
    filetype: int
    exported: set[str] = field(default_factory=set)
    libraries: list[str] = field(default_factory=list)
    install_name: str = ""
    min_macos: tuple[int, int] = (0, 0)
    signature: tuple[int, int] | None = None   # (offset, size) of the code signature


def _c_string(data: bytes, at: int) -> str:
    return data[at:data.index(b"\0", at)].decode()


def read_macho(data: bytes) -> MachO:
    """The thin Mach-O library in data: its CPU type, file type, the symbols it defines and
    exports (without the leading '_'), the libraries it loads, its install name, its minimum
    macOS and where its code signature lies."""
    magic, cputype, _, filetype, ncmds = struct.unpack_from("<IiIII", data)
    assert magic == 0xFEEDFACF, f"not a thin 64-bit Mach-O (magic {magic:#x})"
    m, at = MachO(cputype, filetype), 32
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<II", data, at)
        if cmd == LC_SYMTAB:
            symoff, nsyms, stroff, _ = struct.unpack_from("<IIII", data, at + 8)
            for k in range(nsyms):
                strx, ntype = struct.unpack_from("<IB", data, symoff + 16 * k)
                if ntype & N_EXT and ntype & N_TYPE == N_SECT:
                    m.exported.add(_c_string(data, stroff + strx).removeprefix("_"))
        elif cmd in (LC_LOAD_DYLIB, LC_LOAD_WEAK_DYLIB, LC_REEXPORT_DYLIB):
            m.libraries.append(_c_string(data, at + struct.unpack_from("<I", data, at + 8)[0]))
        elif cmd == LC_ID_DYLIB:
            m.install_name = _c_string(data, at + struct.unpack_from("<I", data, at + 8)[0])
        elif cmd == LC_BUILD_VERSION:
            platform, minos = struct.unpack_from("<II", data, at + 8)
            assert platform == PLATFORM_MACOS, f"built for platform {platform}, not macOS"
            m.min_macos = (minos >> 16, (minos >> 8) & 0xFF)
        elif cmd == LC_CODE_SIGNATURE:
            m.signature = struct.unpack_from("<II", data, at + 8)
        at += size
    return m


def read_universal(data: bytes) -> dict[int, bytes]:
    """The slices of a Mach-O universal binary by CPU type, each checked to lie at its
    declared alignment, inside the file and apart from the others."""
    magic, count = struct.unpack_from(">II", data)
    assert magic == 0xCAFEBABE, f"not a universal binary (magic {magic:#x})"
    slices, end = {}, 8 + 20 * count
    for k in range(count):
        cputype, _, offset, size, align = struct.unpack_from(">iIIII", data, 8 + 20 * k)
        assert offset % (1 << align) == 0 and offset >= end and offset + size <= len(data)
        slices[cputype], end = data[offset:offset + size], offset + size
    return slices


def signed_pages_match(data: bytes, signature: tuple[int, int]) -> bool:
    """Whether the slice's code signature (a big-endian SuperBlob) holds a SHA-256
    CodeDirectory whose hash of every page of the code matches the slice's bytes, as the
    kernel checks each page it maps on Apple silicon."""
    offset, _ = signature
    magic, _, count = struct.unpack_from(">III", data, offset)
    assert magic == 0xFADE0CC0, f"no embedded signature SuperBlob (magic {magic:#x})"
    for k in range(count):
        slot, blob = struct.unpack_from(">II", data, offset + 12 + 8 * k)
        if slot != 0:   # the CodeDirectory's slot
            continue
        cd = offset + blob
        (cd_magic, _, _, _, hash_offset, _, _, n_code, code_limit, hash_size, hash_type, _,
         page_log2) = struct.unpack_from(">IIIIIIIIIBBBB", data, cd)
        assert cd_magic == 0xFADE0C02 and hash_type == SHA256 and code_limit == offset
        page = 1 << page_log2
        return n_code == -(-code_limit // page) and all(
            hashlib.sha256(data[i * page:min((i + 1) * page, code_limit)]).digest()
            == data[cd + hash_offset + i * hash_size:cd + hash_offset + (i + 1) * hash_size]
            for i in range(n_code))
    raise AssertionError("the signature holds no CodeDirectory")


@pytest.fixture(scope="module")
def mac_fmu(quick_model, tmp_path_factory) -> Path:
    """The quick model's native FMU with linux64 and darwin64 binaries."""
    return cross_built_fmu(quick_model, tmp_path_factory.mktemp("darwin64"), "darwin64")


def test_the_darwin64_binary_is_a_universal_macos_library_with_the_whole_fmi_api(mac_fmu
                                                                                  ) -> None:
    from fmpy import supported_platforms

    with zipfile.ZipFile(mac_fmu) as z:
        dylib = z.read("binaries/darwin64/LMNCell.dylib")
    assert {"linux64", "darwin64"} <= set(supported_platforms(str(mac_fmu)))
    slices = read_universal(dylib)
    assert set(slices) == {CPU_X86_64, CPU_ARM64}
    wanted = co_simulation_functions()
    for cputype, data in slices.items():
        lib = read_macho(data)
        assert lib.cputype == cputype and lib.filetype == MH_DYLIB
        assert len(wanted) > 30 and wanted <= lib.exported, wanted - lib.exported
        assert lib.libraries == ["/usr/lib/libSystem.B.dylib"]
        assert lib.install_name == "@rpath/LMNCell.dylib"   # not the build folder's path
        assert lib.min_macos == (11, 0)
    arm64 = read_macho(slices[CPU_ARM64])
    assert arm64.signature is not None and signed_pages_match(slices[CPU_ARM64], arm64.signature)


def test_the_darwin64_build_is_reproducible(quick_model, tmp_path, monkeypatch) -> None:
    """With SOURCE_DATE_EPOCH set, two builds give the same universal binary, byte for byte
    (no temporary build folder is written into it)."""
    import lmncell

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    first, second = (lmncell.build_fmu(quick_model, tmp_path / f"{k}.fmu", native=True,
                                       platforms=["darwin64"]) for k in "ab")
    assert first.read_bytes() == second.read_bytes()


def test_a_changed_page_no_longer_matches_its_signature(mac_fmu) -> None:
    """The signature check above can fail: one byte of code changed breaks its page's hash."""
    with zipfile.ZipFile(mac_fmu) as z:
        data = read_universal(z.read("binaries/darwin64/LMNCell.dylib"))[CPU_ARM64]
    signature = read_macho(data).signature
    assert signature is not None
    tampered = bytearray(data)
    tampered[signature[0] // 2] ^= 0xFF
    assert not signed_pages_match(bytes(tampered), signature)


def test_universal_binary_joins_thin_slices_and_refuses_anything_else() -> None:
    from lmncell.fmu.interface import NativeBuildError
    from lmncell.fmu.native_build import universal_binary

    thin = {cpu: struct.pack("<IiI", 0xFEEDFACF, cpu, 0x80000003) + bytes(100 + cpu % 7)
            for cpu in (CPU_X86_64, CPU_ARM64)}
    fat = universal_binary(list(thin.values()))
    assert read_universal(fat) == thin
    _, subtype, _, _, _ = struct.unpack_from(">iIIII", fat, 8)
    assert subtype == 3   # the capability bits are not the fat header's
    with pytest.raises(NativeBuildError, match="no 64-bit Mach-O binary"):
        universal_binary([thin[CPU_X86_64], b"MZ" + bytes(100)])


@pytest.fixture(scope="module")
def arm64_hosts(mac_fmu, tmp_path_factory) -> tuple[Path, str]:
    """A folder with the FMU unzipped (fmu/), host.c built for Linux (host) and, with the FMU's
    C linked in, as a static arm64 Linux executable (host_arm64, built with the darwin64
    slices' zig and flags); and the FMU's GUID."""
    from lmncell.fmu.native_build import fmi_headers

    if shutil.which("qemu-aarch64") is None:
        pytest.skip("qemu-aarch64 is not installed (apt install qemu-user)")
    d = tmp_path_factory.mktemp("arm64")
    guid = unzip_fmu(mac_fmu, d / "fmu")
    compile_host(HOST_C, d / "host")
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", "aarch64-linux-musl",
                    "-static", "-std=c99", "-O3", f"-I{fmi_headers()}", f"-I{HOST_C.parent}",
                    f"-I{d / 'fmu' / 'sources'}", str(HOST_C), str(LINKED_C),
                    str(d / "fmu" / "sources" / "lmncell.c"), "-o", str(d / "host_arm64")],
                   check=True, capture_output=True)
    return d, guid


@pytest.mark.parametrize("observer", [0, 1, 2, 3])
def test_under_qemu_the_arm64_build_runs_as_the_linux64_one(arm64_hosts, observer) -> None:
    """The FMU's C built for arm64 (as the Apple silicon slice is, but for Linux) drives 3000
    steps with hostile inputs under qemu-aarch64 (each observer in turn): every logged message
    and the refused steps equal the linux64 binary's, the final voltage, SoC and σ agree within
    1e-10 (clang's contraction of a·b + c into one rounding and musl's exp move the last bits;
    the IMM's σ after 3000 such steps by 1e-11, as much between gcc and clang on x86-64)."""
    d, guid = arm64_hosts
    args, linux = linux64_reference_run(d, guid, observer, "file:///x/")
    arm64 = subprocess.run(["qemu-aarch64", str(d / "host_arm64"), "(linked in)", *args],
                           cwd=d, capture_output=True, text=True, timeout=600)
    assert linux.returncode == 0 and arm64.returncode == 0, arm64.stderr[-2000:]
    assert_same_run(arm64.stdout, linux.stdout, atol=1e-10)
