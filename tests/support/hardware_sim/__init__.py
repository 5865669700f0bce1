"""Simulated haptic hardware at the vendor boundary, for the adapter tests and bench/hardware.py.

- :func:`build_fdsdk`: a C shared library that stands in for the Force Dimension SDK (``libdrd``,
  which also holds the ``dhd`` functions), laid out where ``forcedimension-core`` looks for it
  (``$FDSDK/lib/release/lin-<machine>-gcc/libdrd.so.<version>``);
- :func:`build_libhd`: a C shared library that stands in for OpenHaptics' ``libHD.so`` (its
  servo scheduler is a 1 kHz thread calling the scheduled callbacks);
- :mod:`.haply_pty`: a pseudo-terminal that speaks the Inverse3 / handle serial protocol the way
  ``HaplyHardwareAPI`` does.

The C libraries are compiled here, in the test run, with the system C compiler; without one the
callers skip with :data:`NO_COMPILER`.
"""
from __future__ import annotations

import ctypes
import platform
import re
import shutil
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent
CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
NO_COMPILER = "no C compiler (cc/gcc/clang) on PATH: the simulated vendor library cannot be built"


def compile_shared(sources: list[Path], out: Path, soname: str | None = None) -> Path:
    """Compile C ``sources`` into the shared library ``out`` (raises with the compiler's message)."""
    if CC is None:
        raise RuntimeError(NO_COMPILER)
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [CC, "-shared", "-fPIC", "-O2", "-std=gnu11", "-Wall", "-I", str(HERE), *map(str, sources), "-o", str(out),
           "-lm", "-lpthread"]
    if soname:
        cmd.insert(1, f"-Wl,-soname,{soname}")
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"compiling {out.name} failed:\n{r.stderr}")
    return out


def _binding_symbols(package: str) -> set[str]:
    """Every ``dhd*``/``drd*`` symbol the installed forcedimension-core binds (read from its source)."""
    import importlib.util

    spec = importlib.util.find_spec(package)
    root = Path(spec.origin).parent
    found = set()
    for path in root.rglob("*.py"):
        found.update(re.findall(r"_lib(?:dhd|drd)\.((?:dhd|drd)\w+)", path.read_text()))
    return found


def build_fdsdk(root: Path) -> tuple[Path, Path]:
    """The simulated Force Dimension SDK under ``root``: returns (FDSDK folder, library path).

    Besides ``fdsdk_sim.c`` the library holds one failing stub (``DHD_ERROR_NOT_IMPLEMENTED``)
    for every other symbol the installed binding binds at import, read from its source."""
    sim = HERE / "fdsdk_sim.c"
    defined = set(re.findall(r"^[\w ]+?\**\s*\**((?:dhd|drd)\w+)\s*\(", sim.read_text(), re.M))
    stubs = sorted(_binding_symbols("forcedimension_core") - defined)
    stub_c = root / "fdsdk_stubs.c"
    root.mkdir(parents=True, exist_ok=True)
    stub_c.write_text("int sim_unimplemented(void);\n" + "".join(
        f"int {name}(void) {{ return sim_unimplemented(); }}\n" for name in stubs))
    machine = platform.machine()
    lib = root / "sdk" / "lib" / "release" / f"lin-{machine}-gcc" / "libdrd.so.3.17.0"
    compile_shared([sim, stub_c], lib)
    return root / "sdk", lib


def build_libhd(root: Path) -> Path:
    """The simulated OpenHaptics HD library (soname ``libHD.so``) under ``root``."""
    return compile_shared([HERE / "hd_sim.c"], root / "libHD.so", soname="libHD.so")


def load(lib: Path) -> ctypes.CDLL:
    """The library's handle for the ``sim_*`` hooks (the same copy the binding loaded)."""
    return ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
