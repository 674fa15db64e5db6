"""A folder of built FMUs (``dist/`` by default): where each FMU is, and whether it is current.

``python build.py --dest DIST`` writes ``DIST/RailCar.fmu``, ``DIST/RailCarEstimator.fmu``,
``DIST/AtoController.fmu`` and, with a C compiler on linux x86-64, the native FMUs into
``DIST/native/``. A pythonfmu FMU is current when its GUID is ``source_guid`` of today's sources;
a native FMI 2 FMU when its GUID is ``native_guid`` of its pythonfmu twin and today's C files.
``run_build`` runs build.py in a subprocess (a fresh interpreter: a process that has loaded an
FMU's modules would build from them); the harness decides when (harness.run.fmus.ensure_built).
"""
from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .toolchain import ROOT, find_compiler, is_linux64

DIST = ROOT / "dist"
# fmu_src.variables' RAILCAR and ESTIMATOR, spelt out: importing the table imports models (seconds),
# and the harness imports this module to ask whether its FMUs are current.
NAMES = ("RailCar", "RailCarEstimator")
"""The FMUs that have a native twin."""
NATIVE_NAMES = {"RailCar": "RailCarNative", "RailCarEstimator": "RailCarEstimatorNative",
                "AtoController": "AtoControllerNative"}


class BuildError(RuntimeError):
    """build.py failed: the FMUs could not be built (exit code 1, with build.py's output)."""


def description_of(path: Path) -> bytes | None:
    """The FMU's modelDescription.xml bytes; None if the file or the entry is not readable."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.read("modelDescription.xml")
    except (OSError, KeyError, zipfile.BadZipFile):
        return None


def fmu_guid(path: Path) -> str | None:
    """The GUID in the FMU's modelDescription.xml; None if there is no readable one."""
    xml = description_of(path)
    try:
        return None if xml is None else ET.fromstring(xml).get("guid")
    except ET.ParseError:
        return None


def native_path(name: str, dist: Path = DIST) -> Path:
    """DIST/native/<name>Native.fmu: the native FMI 2 twin of DIST/<name>.fmu."""
    return Path(dist) / "native" / f"{NATIVE_NAMES[name]}.fmu"


def is_stale(name: str, dist: Path = DIST) -> bool:
    """True if DIST/<name>.fmu is missing or was built from other sources."""
    from .pythonfmu_fmus import source_guid
    return fmu_guid(Path(dist) / f"{name}.fmu") != source_guid(name)


def native_buildable() -> bool:
    """build.py builds the native FMUs only on linux x86-64 with a C compiler."""
    return is_linux64() and find_compiler() is not None


def run_build(dist: Path, native: bool = True) -> str:
    """``build.py --dest dist`` (``--no-native`` unless ``native``) in a subprocess; its output,
    or BuildError with it."""
    cmd = [sys.executable, str(ROOT / "build.py"), "--dest", str(dist), *([] if native else ["--no-native"])]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"build.py failed:\n{proc.stdout}\n{proc.stderr}")
    return proc.stdout


def current_pythonfmu(name: str, dist: Path = DIST) -> Path:
    """DIST/<name>.fmu, built first (every pythonfmu FMU, no native one) if missing or stale."""
    if is_stale(name, dist):
        run_build(Path(dist), native=False)
    return Path(dist) / f"{name}.fmu"
