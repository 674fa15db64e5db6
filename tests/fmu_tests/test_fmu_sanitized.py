"""The FMUs' own FMI binary (fmu_src/c) under AddressSanitizer and UndefinedBehaviorSanitizer:
built here with -fsanitize=address,undefined into a copy of the built RailCar.fmu, driven through
a hostile session (tests/fmu_cases/sanitized_session.py) in a Python process that preloads the
sanitizer runtimes. Any report aborts that process. Leak checking is off: the Python interpreter
itself keeps memory to the end."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile

from fmu_src.build import pythonfmu_fmus, toolchain

ROOT = toolchain.ROOT


def test_the_fmi_binary_runs_a_hostile_session_clean_under_sanitizers(built_fmus, tmp_path):
    gcc = shutil.which("gcc")
    assert gcc
    unzipdir = tmp_path / "RailCar"
    with zipfile.ZipFile(built_fmus["RailCar"]) as z:
        z.extractall(unzipdir)
    binary = unzipdir / "binaries" / "linux64" / "RailCar.so"
    flags = [f for f in pythonfmu_fmus.C_FLAGS if f != "-O2"]
    subprocess.run([gcc, *flags, "-O1", "-g", "-fsanitize=address,undefined",
                    "-fno-sanitize-recover=undefined", "-I", sysconfig.get_paths()["include"],
                    "-I", str(toolchain.fmi_headers()), *[str(ROOT / s) for s in pythonfmu_fmus.C_SOURCES],
                    "-o", str(binary)], check=True, capture_output=True, text=True)
    assert b"__asan_" in binary.read_bytes()          # the FMU now carries the instrumented build
    runtimes = [subprocess.run([gcc, f"-print-file-name={lib}"], capture_output=True, text=True,
                               check=True).stdout.strip() for lib in ("libasan.so", "libubsan.so")]
    env = dict(os.environ, LD_PRELOAD=" ".join(runtimes), ASAN_OPTIONS="detect_leaks=0:abort_on_error=1")
    proc = subprocess.run([sys.executable, str(ROOT / "tests" / "fmu_cases" / "sanitized_session.py"),
                           str(unzipdir)], capture_output=True, text=True, env=env, timeout=600)
    report = proc.stderr[-3000:]
    assert proc.returncode == 0, report
    assert proc.stdout.strip().endswith("SANITIZED-SESSION-DONE"), proc.stdout[-500:] + report
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr, report
