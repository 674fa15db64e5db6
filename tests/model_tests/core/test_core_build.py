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

ROOT = Path(__file__).resolve().parents[3]
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


# ----------------------------------------------- no fused multiply-add, whatever the flags

FMA = ("vfmadd", "vfmsub", "vfnmadd", "vfnmsub")
"""x86-64 FMA3 mnemonics; -mfma lets GCC emit them on this machine whatever its CPU."""
CONTRACTING = ["-std=gnu99", "-O3", "-mfma", "-fPIC", "-I", str(ROOT / "models" / "core")]
"""What a user's source-FMU build may do: GNU mode (fmpy's compile: gnu99 or the default gnu17,
where GCC's default is -ffp-contract=fast) on a target with FMA."""
GLUE_SOURCES = sorted((ROOT / "fmu_src" / "c").glob("*.c"))


def fused_instructions(source: Path, tmp_path: Path, extra: list[str] = ()) -> int:
    obj = tmp_path / (source.stem + ".o")
    subprocess.run([GCC, *CONTRACTING, *extra, "-c", str(source), "-o", str(obj)], check=True,
                   capture_output=True, text=True, timeout=120)
    asm = subprocess.run(["objdump", "-d", str(obj)], check=True, capture_output=True, text=True).stdout
    return sum(asm.count(m) for m in FMA)


def test_every_source_turns_contraction_off_itself(tmp_path):
    """rc_fp_contract.h comes first in every .c file of the core, and with GCC's contracting
    defaults no source of the core or the native glue (which computes nothing a fused
    multiply-add could change) compiles to a fused multiply-add: bit-identity with Python does
    not depend on the -ffp-contract=off a source-FMU user may not pass."""
    from fmu_src.build.toolchain import C_DIR, fmi_headers
    sources = CORE_SOURCES + [s for s in GLUE_SOURCES if s.name != "pyslave.c"]
    missing = [s.name for s in CORE_SOURCES if '#include "rc_fp_contract.h"' not in s.read_text()]
    assert not missing, f"without rc_fp_contract.h: {missing}"
    fused = {s.name: n for s in sources
             if (n := fused_instructions(s, tmp_path, ["-I", str(C_DIR), "-I", str(fmi_headers())]))}
    assert not fused, f"fused multiply-adds: {fused}"


def test_the_fma_check_sees_a_source_without_the_guard(tmp_path):
    """The control: ident.c without its include contracts hundreds of a * b + c."""
    copy = tmp_path / "ident_unguarded.c"
    copy.write_text((ROOT / "models" / "core" / "ident.c").read_text().replace('#include "rc_fp_contract.h"', ""))
    assert fused_instructions(copy, tmp_path) > 50
