"""What every FMU build needs from the machine: the project root, a C compiler, fmpy's FMI headers.

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
