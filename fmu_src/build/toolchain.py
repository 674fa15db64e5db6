"""What every FMU build needs from the machine: the project root, a C compiler, fmpy's FMI headers,
and the platforms the native FMUs carry binaries for (``TARGETS``, each with its compiler).

Shared by the pythonfmu FMUs' own FMI 2 binary (``pythonfmu_fmus``), the native FMUs
(``native``, ``native_fmi3``) and the tests and benchmarks that compile C hosts.
"""
from __future__ import annotations

import os
import platform
import shlex
import shutil
import subprocess
import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
"""The project: build.py, fmu_src/, models/, scenarios/."""
C_DIR = ROOT / "fmu_src" / "c"
CORE_DIR = ROOT / "models" / "core"


def find_compiler() -> list[str] | None:
    """$CC, else the compiler Python was built with, else cc/gcc/clang; None if there is none."""
    candidates = [os.environ.get("CC"), sysconfig.get_config_var("CC"), "cc", "gcc", "clang"]
    for cc in candidates:
        cmd = shlex.split(cc) if cc else []
        if cmd and shutil.which(cmd[0]):
            return cmd
    return None


def fmi_headers() -> Path:
    """The FMI 2.0 and 3.0 headers fmpy ships (fmpy/c-code/fmi2Functions.h, fmi3Functions.h ...)."""
    import fmpy
    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise SystemExit(f"FMI 2 headers not found in {folder} (is fmpy installed?)")
    return folder


def is_linux64() -> bool:
    """The one platform whose binaries are built here (linux x86-64)."""
    return sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")


def compile_c(cmd: list[str], what: str) -> None:
    """Run one compiler command; RuntimeError with the command and the compiler's output."""
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling {what} failed:\n{shlex.join(cmd)}\n{proc.stdout}{proc.stderr}")


def warn(message: str) -> None:
    """A warning nobody can miss: framed on stderr, and once more on stdout (the build's log)."""
    bar = "!" * 78
    print(f"{bar}\nWARNING: {message}\n{bar}", file=sys.stderr)
    print(f"WARNING: {message}")


# ------------------------------------------------------------------ the native FMUs' platforms

@dataclass(frozen=True)
class Target:
    """One platform a native FMU carries a binary for."""
    tuple: str                  # FMI 3.0 platform tuple = binaries/ folder of the FMI 3 FMUs
    fmi2_folder: str            # binaries/ folder of the FMI 2 FMUs (FMI 2.0.4 section 2.3)
    compiler: str | None        # cross compiler; None: this machine's own (linux x86-64 only)
    package: str                # the Debian package that provides ``compiler``
    extension: str              # of the shared library
    flags: tuple                # added to native.BASE_FLAGS
    libraries: tuple            # linked after the sources, e.g. ("-lm",)


_POSIX_FLAGS = ("-fPIC", "-fvisibility=hidden", "-pthread")
# FMI 2.0.4 (section 2.3) standardises win64 and linux64 for 64-bit x86 only; "for any other
# platforms the platform tuples defined in the FMI 3.0 Specification ... should be used":
# aarch64 Linux is binaries/aarch64-linux in both versions.
LINUX_X86_64 = Target("x86_64-linux", "linux64", None, "gcc", ".so", _POSIX_FLAGS, ("-lm",))
# -static: libgcc and any helper library go into the DLL, which then needs only what every
# Windows has (KERNEL32.dll, msvcrt.dll); the glue uses no thread library on Windows.
WINDOWS_X86_64 = Target("x86_64-windows", "win64", "x86_64-w64-mingw32-gcc", "mingw-w64", ".dll",
                        ("-static",), ("-lm",))
LINUX_AARCH64 = Target("aarch64-linux", "aarch64-linux", "aarch64-linux-gnu-gcc",
                       "gcc-aarch64-linux-gnu", ".so", _POSIX_FLAGS, ("-lm",))
TARGETS = (LINUX_X86_64, WINDOWS_X86_64, LINUX_AARCH64)


def target_compiler(target: Target) -> list[str] | None:
    """The compiler command for ``target`` on this machine, or None if it has none."""
    if target.compiler is None:
        return find_compiler() if is_linux64() else None
    return [target.compiler] if shutil.which(target.compiler) else None


def missing_compiler(target: Target) -> str:
    """Why ``target`` gets no binary here: the compiler and the package that provides it."""
    if target.compiler is None:
        return (f"{target.tuple}: no C compiler for it on this machine "
                f"({sys.platform} {platform.machine()}; install {target.package} or set CC)")
    return (f"{target.tuple}: {target.compiler} not found "
            f"(apt-get install {target.package})")


def available_targets(report: bool = True) -> list[Target]:
    """The platforms this machine can build native binaries for; each one it cannot is printed
    (``report``), naming the compiler and its package: never skipped silently."""
    found = []
    for target in TARGETS:
        if target_compiler(target) is not None:
            found.append(target)
        elif report:
            print(f"SKIPPED platform {missing_compiler(target)}: the native FMUs carry no "
                  f"{target.tuple} binary")
    return found
