"""The C model core compiles without a single warning.

setup.py builds models._railcar (models/_railcar.c and models/core/*.c) without -Werror, so that
a newer compiler's warning cannot silently drop the optional extension; here the same sources
must pass -Wall -Wextra -Werror: the binding against the Python headers, the core as the plain
C99 it claims to be (-pedantic, no Python.h). Compiled with -O2 and to an object file, not only
-fsyntax-only: some warnings (maybe-uninitialized) come from the optimiser.
"""
from __future__ import annotations

import shutil
import subprocess
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CORE_SOURCES = sorted((ROOT / "models" / "core").glob("*.c"))
GCC = shutil.which("gcc")
WARNINGS = ["-Wall", "-Wextra", "-Werror"]
FLAGS = ["-O2", "-ffp-contract=off", "-fno-fast-math", "-fPIC"]


def compile_c(source: Path, extra: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([GCC, *FLAGS, *WARNINGS, *extra, "-c", str(source),
                           "-o", str(tmp_path / (source.stem + ".o"))],
                          capture_output=True, text=True, timeout=120)


def test_gcc_is_there():
    assert GCC, "gcc is needed to build models._railcar (pip install -e .)"


def test_the_binding_compiles_without_a_warning(tmp_path):
    proc = compile_c(ROOT / "models" / "_railcar.c",
                     ["-std=c99", f"-I{sysconfig.get_paths()['include']}"], tmp_path)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("source", CORE_SOURCES, ids=[p.name for p in CORE_SOURCES])
def test_a_core_source_compiles_as_pedantic_c99_without_a_warning(source, tmp_path):
    assert "Python.h" not in source.read_text(), f"{source.name} includes Python.h"
    proc = compile_c(source, ["-std=c99", "-pedantic"], tmp_path)
    assert proc.returncode == 0, proc.stderr


def test_the_flags_do_refuse_a_warning(tmp_path):
    """The check above can fail: an unused variable and a C99-pedantic violation are errors."""
    bad = tmp_path / "bad.c"
    bad.write_text("int f(void) { int unused; return 0; }\n")
    assert compile_c(bad, ["-std=c99", "-pedantic"], tmp_path).returncode != 0
    bad.write_text("int g(void) { return 0; };\n")          # a stray ';' at file scope: ISO C
    assert compile_c(bad, ["-std=c99", "-pedantic"], tmp_path).returncode != 0
    assert len(CORE_SOURCES) >= 10                           # the glob found the core
