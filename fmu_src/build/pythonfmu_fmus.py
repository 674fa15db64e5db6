"""The pythonfmu FMUs: RailCar.fmu, RailCarEstimator.fmu, AtoController.fmu (FMI 2.0, Python inside).

``build_pythonfmu(fmu, dest, binary)`` runs ``pythonfmu build`` in a subprocess (a Python
process caches the FMU's modules, so building and loading in one process can run stale code),
bundling ``fmu_src/``, ``models/`` and ``scenarios/profiles`` as the FMU's resources. Then the
FMU is rewritten:

- modelDescription.xml is ours (``model_description.fmi2``), with a GUID derived from the
  sources (same sources => same GUID), once pythonfmu's own has been checked against the table;
- the Linux binary pythonfmu ships (``binaries/linux64/<model>.so``) is replaced by ours
  (``compile_binary``: ``fmu_src/c/``, C99, the Python C API, FMI 2 headers from fmpy), which
  reports errors as fmi2Error instead of crashing the host after fmi2Fatal. Without a C
  compiler (or asked to) pythonfmu's binary stays. The win64 DLL is always pythonfmu's;
- ``resources/fmu_src/c/`` is dropped: compiled into the binary, not needed at run time.
"""
from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile
import uuid
import zipfile
from pathlib import Path

from . import model_description
from .toolchain import ROOT, compile_c, find_compiler, fmi_headers, is_linux64, warn

PROJECT_FILES = ["fmu_src", "models", "scenarios/profiles"]
"""Bundled under resources/ (relative to ROOT); the GUID hashes every file in them."""

# Our FMI 2 binary: sources, flags, and the marker string it carries (tests look for it).
C_SOURCES = ["fmu_src/c/fmi2_glue.c", "fmu_src/c/glue_common.c", "fmu_src/c/pyslave.c"]
C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-fPIC", "-shared",
           "-fvisibility=hidden", "-pthread"]
BINARY_MARKER = b"railcar-fmu fmi2 binary 1"
LINUX_BINARY = "binaries/linux64/{model}.so"


def slave_script(fmu: str) -> str:
    """The slave's script, relative to ROOT, as ``pythonfmu build -f`` takes it."""
    return model_description.SLAVE_MODULES[fmu].replace(".", "/") + ".py"


def source_files() -> list[Path]:
    files = []
    for folder in PROJECT_FILES:
        files += [p for p in sorted((ROOT / folder).rglob("*"))
                  if p.is_file() and "__pycache__" not in p.parts]
    return files


def source_guid(fmu: str) -> str:
    """A GUID from the model name, pythonfmu's version and every bundled source file."""
    import pythonfmu
    h = hashlib.sha256(f"{fmu}|pythonfmu {pythonfmu.__version__}".encode())
    for p in source_files():
        h.update(str(p.relative_to(ROOT)).encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def generation_tool() -> str:
    import pythonfmu
    return f"PythonFMU {pythonfmu.__version__}"


def compile_binary(out_dir: Path) -> Path | None:
    """Compile our FMI 2 binary for linux64 into ``out_dir``; None (with a warning) when it
    cannot be built here, so that pythonfmu's binary stays. RuntimeError on a compiler error."""
    if not is_linux64():
        warn(f"our FMI 2 binary is built for linux64 only (this is {sys.platform}/"
             f"{platform.machine()}): the FMUs keep pythonfmu's binary, which crashes the host "
             "after an initialisation error (see README, Limits)")
        return None
    cc = find_compiler()
    if cc is None:
        warn("no C compiler found (set CC or install gcc): the FMUs keep pythonfmu's binary, "
             "which reports errors as fmi2Fatal and crashes the host when such an instance is "
             "freed (see README, Limits)")
        return None
    out = out_dir / "fmi2_python.so"
    compile_c([*cc, *C_FLAGS, "-I", sysconfig.get_paths()["include"], "-I", str(fmi_headers()),
               *[str(ROOT / s) for s in C_SOURCES], "-o", str(out)], "the FMI 2 binary")
    if BINARY_MARKER not in out.read_bytes():
        raise RuntimeError(f"{out}: the compiled binary does not carry its marker {BINARY_MARKER!r}")
    return out


def rewrite_fmu(path: Path, fmu: str, binary: Path | None = None) -> None:
    """Our model description (after checking pythonfmu's); our linux64 binary; no C sources."""
    tmp = path.with_suffix(".tmp")
    linux_binary = LINUX_BINARY.format(model=fmu)
    swapped = False
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            if item.filename.startswith("resources/fmu_src/c/"):
                continue                     # compiled into the binary, not needed at run time
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                model_description.check_pythonfmu_description(data, fmu, f"{path} (pythonfmu)")
                data = model_description.fmi2(fmu, source_guid(fmu), generation_tool())
            elif item.filename == linux_binary and binary is not None:
                data = binary.read_bytes()
                swapped = True
            dst.writestr(item, data)
    if binary is not None and not swapped:
        tmp.unlink()
        raise RuntimeError(f"{path}: pythonfmu wrote no {linux_binary} to replace")
    tmp.replace(path)


def build_pythonfmu(fmu: str, dest: Path, binary: Path | None = None) -> Path:
    """``dest/<fmu>.fmu``: pythonfmu's build (in a subprocess), rewritten (``rewrite_fmu``)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "pythonfmu", "build", "-f", slave_script(fmu), "-d", out,
               *PROJECT_FILES]
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"pythonfmu build of {fmu} failed:\n{proc.stdout}\n{proc.stderr}")
        built = Path(out) / f"{fmu}.fmu"
        dest.mkdir(parents=True, exist_ok=True)
        target = dest / f"{fmu}.fmu"
        target.write_bytes(built.read_bytes())
    rewrite_fmu(target, fmu, binary)
    return target
