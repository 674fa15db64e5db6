"""Where the FMUs are, building them (in a subprocess) when missing or stale, and which kind runs.

Two kinds of FMU run the same model (docs/using_fmus.md): the pythonfmu FMUs ``DIST/RailCar.fmu``,
``DIST/RailCarEstimator.fmu`` (every option) and the native ones ``DIST/native/RailCarNative.fmu``,
``DIST/native/RailCarEstimatorNative.fmu`` (the C core: bit-identical outputs, no Python, but
``est.method`` 1-3, ``est.physical`` 1 and ``est.sigma2_method`` 1 are refused at initialisation).
``--fmu`` picks one (``choose``): ``python``, ``native``, or ``auto`` (the default): the native FMU
when the C core covers every parameter set the command will run, else the pythonfmu FMU. The
choice is always printed (``FmuChoice.line``) and recorded in what the command writes.
"""
from __future__ import annotations

import importlib.util
import platform
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree as ET

from harness.textio import InputError

ROOT = Path(__file__).resolve().parents[2]
DIST = ROOT / "dist"
NAMES = ("RailCar", "RailCarEstimator")
NATIVE_NAMES = {"RailCar": "RailCarNative", "RailCarEstimator": "RailCarEstimatorNative"}  # build.py's
KINDS = ("auto", "native", "python")
DEFAULT_KIND = "auto"


class BuildError(RuntimeError):
    """build.py failed: the FMUs could not be built (exit code 1, with build.py's output)."""


def _build_module():
    spec = importlib.util.spec_from_file_location("_railcar_build", ROOT / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _description(path: Path) -> bytes | None:
    try:
        with zipfile.ZipFile(path) as z:
            return z.read("modelDescription.xml")
    except (OSError, KeyError, zipfile.BadZipFile):
        return None


def fmu_guid(path: Path) -> str | None:
    xml = _description(path)
    try:
        return None if xml is None else ET.fromstring(xml).get("guid")
    except ET.ParseError:
        return None


def native_path(name: str, dist: Path = DIST) -> Path:
    """DIST/native/<name>Native.fmu: the native FMI 2 twin of DIST/<name>.fmu."""
    return Path(dist) / "native" / f"{NATIVE_NAMES[name]}.fmu"


def is_stale(name: str, dist: Path = DIST) -> bool:
    """True if dist/<name>.fmu is missing or was built from other sources."""
    return fmu_guid(Path(dist) / f"{name}.fmu") != _build_module().source_guid(name)


def native_is_stale(name: str, dist: Path = DIST) -> bool:
    """True if DIST/native/<name>Native.fmu is missing or was not built from DIST/<name>.fmu and
    the current C sources (its GUID is fmu_src.native.native_guid of both)."""
    xml = _description(Path(dist) / f"{name}.fmu")
    if xml is None:
        return True
    from fmu_src import native
    spec = {s.fmu: s for s in native.SPECS}[name]
    return fmu_guid(native_path(name, dist)) != native.native_guid(xml, spec)


def native_buildable() -> bool:
    """build.py builds the native FMUs only on linux x86-64 with a C compiler."""
    return (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")
            and _build_module().find_compiler() is not None)


def ensure_built(dist: Path = DIST, force: bool = False, quiet: bool = False,
                 native: bool = True) -> dict[str, Path]:
    """Build every FMU (build.py, in a subprocess) unless they are present and current; returns
    the pythonfmu FMUs' paths by name (``native_path`` gives their native twins). A missing or
    stale native FMI 2 FMU counts too when ``native`` (and build.py can build it here)."""
    dist = Path(dist)
    if dist.exists() and not dist.is_dir():
        raise InputError(f"--dist {dist}: exists and is not a folder")
    stale = force or any(is_stale(n, dist) for n in NAMES)
    if not stale and native and any(native_is_stale(n, dist) for n in NAMES) and native_buildable():
        stale = True
    if stale:
        if not quiet:
            print(f"building FMUs into {dist} ...", flush=True)
        proc = subprocess.run([sys.executable, str(ROOT / "build.py"), "--dest", str(dist)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"build.py failed:\n{proc.stdout}\n{proc.stderr}")
        if not quiet:
            print(proc.stdout.strip(), flush=True)
    return {n: dist / f"{n}.fmu" for n in NAMES}


# ------------------------------------------------------------------------------ which kind runs

UNCOVERED_OPTIONS = ("est.method", "est.physical", "est.sigma2_method")


def uncovered(model: str, parameters: dict) -> str | None:
    """Why the native ``model`` FMU would refuse these parameter values (None: the C core covers
    them). Decided by models.compiled (not_covered), the rule the C core is built to; the reason
    names the parameters and values. Unset parameters take the FMU's start values."""
    from fmu_src.adapter import chain_config, estimator_settings
    from fmu_src.variables import RAILCAR, variables_for
    from models.compiled import estimator_not_covered, not_covered
    v = {x.name: x.start for x in variables_for(model) if x.causality == "parameter"}
    v.update(parameters)
    try:
        why = not_covered(chain_config(v)) if model == RAILCAR else estimator_not_covered(*estimator_settings(v)[:2])
    except (ValueError, TypeError, KeyError):
        return None               # a bad value: either FMU refuses it at initialisation, with one message
    if why is None:
        return None
    named = [f"{n} = {v[n]}" for n in UNCOVERED_OPTIONS if n in v and v[n] != 0]
    return ", ".join(named) or why


@dataclass(frozen=True)
class FmuChoice:
    kind: str            # "native" or "python": what runs
    path: Path
    asked: str           # the --fmu value: auto, native or python
    why: str

    def describe(self) -> str:
        """'native /…/RailCarNative.fmu (--fmu auto: why)': for reports."""
        return f"{self.kind} {self.path} (--fmu {self.asked}: {self.why})"

    def line(self) -> str:
        """What the command prints before it runs anything."""
        return f"fmu: {self.describe()}"


def choose(asked: str, model: str, dist: Path, parameter_sets) -> FmuChoice:
    """The FMU of ``model`` to run for ``parameter_sets`` ((label, parameters) pairs: a scenario,
    or every run of a sweep). ``auto``: the native FMU unless one set is not covered by the C
    core or the native FMU is missing (then the pythonfmu FMU, saying why). ``native`` runs the
    native FMU even so: it refuses an uncovered option at initialisation, naming it."""
    if asked not in KINDS:
        raise InputError(f"--fmu {asked}: expected one of {', '.join(KINDS)}")
    dist = Path(dist)
    python, native = dist / f"{model}.fmu", native_path(model, dist)
    if asked == "python":
        return FmuChoice("python", python, asked, "the pythonfmu FMU, as asked")
    gap = next(((label, why) for label, params in parameter_sets
                if (why := uncovered(model, params)) is not None), None)
    if asked == "native":
        if not native.is_file():
            raise BuildError(f"--fmu native: {native} is missing (build.py builds it with a C compiler on "
                             f"linux x86-64); --fmu python runs the pythonfmu FMU")
        return FmuChoice("native", native, asked, "as asked" + (
            f"; it refuses {gap[1]} ({gap[0]}) at initialisation" if gap else ""))
    if gap is not None:
        return FmuChoice("python", python, asked, f"{gap[0]} sets {gap[1]}, which the C core does not cover")
    if not native.is_file():
        return FmuChoice("python", python, asked, f"no native FMU: {native} is missing (build.py builds it "
                         f"with a C compiler on linux x86-64)")
    return FmuChoice("native", native, asked, "the C core covers the parameters, bit-identical to the "
                     "pythonfmu FMU")


def select(asked: str, model: str, dist, rebuild: bool, parameter_sets) -> FmuChoice:
    """ensure_built (natives included unless --fmu python), then ``choose``."""
    dist = Path(dist) if dist else DIST
    ensure_built(dist, force=rebuild, native=asked != "python")
    return choose(asked, model, dist, parameter_sets)


def is_native(model_description) -> bool:
    """An FMU that needs no execution tool is a native one (fmu_src/native.py sets it false;
    pythonfmu sets it true)."""
    return not model_description.coSimulation.needsExecutionTool
