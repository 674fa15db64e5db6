"""Where the FMUs are, and building them (in a subprocess) when missing or stale."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .textio import InputError

ROOT = Path(__file__).resolve().parent.parent
DIST = ROOT / "dist"


class BuildError(RuntimeError):
    """build.py failed: the FMUs could not be built (exit code 1, with build.py's output)."""


def _build_module():
    spec = importlib.util.spec_from_file_location("_railcar_build", ROOT / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def fmu_guid(path: Path) -> str | None:
    try:
        with zipfile.ZipFile(path) as z:
            return ET.fromstring(z.read("modelDescription.xml")).get("guid")
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError):
        return None


def is_stale(name: str, dist: Path = DIST) -> bool:
    """True if dist/<name>.fmu is missing or was built from other sources."""
    return fmu_guid(dist / f"{name}.fmu") != _build_module().source_guid(name)


def ensure_built(dist: Path = DIST, force: bool = False, quiet: bool = False) -> dict[str, Path]:
    """Build both FMUs (subprocess) unless they are present and current."""
    names = ("RailCar", "RailCarEstimator")
    dist = Path(dist)
    if dist.exists() and not dist.is_dir():
        raise InputError(f"--dist {dist}: exists and is not a folder")
    if force or any(is_stale(n, dist) for n in names):
        if not quiet:
            print(f"building FMUs into {dist} ...", flush=True)
        proc = subprocess.run([sys.executable, str(ROOT / "build.py"), "--dest", str(dist)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"build.py failed:\n{proc.stdout}\n{proc.stderr}")
        if not quiet:
            print(proc.stdout.strip(), flush=True)
    return {n: dist / f"{n}.fmu" for n in names}
