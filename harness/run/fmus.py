"""Where the FMUs are, building them (in a subprocess) when missing or stale, and which kind runs.

Two kinds of FMU run the same model (docs/using_fmus.md): the pythonfmu FMUs ``DIST/RailCar.fmu``,
``DIST/RailCarEstimator.fmu``, ``DIST/AtoController.fmu`` (every option) and the native ones
``DIST/native/RailCarNative.fmu``, ``DIST/native/RailCarEstimatorNative.fmu`` (the C core:
bit-identical outputs, no Python, but ``est.method`` 1 and 3 are refused at initialisation) and
``DIST/native/AtoControllerNative.fmu`` (every AtoController parameter: one span or a line).
``--fmu`` picks one (``choose``): ``python``, ``native``, or ``auto`` (the default): the native FMU
when it covers every parameter set the command will run, else the pythonfmu FMU. The
choice is always printed (``FmuChoice.line``) and recorded in what the command writes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fmu_src.build.dist import (DIST, NAMES, NATIVE_NAMES, BuildError, fmu_guid,  # noqa: F401
                                is_stale, native_buildable, native_path, run_build)
from harness.textio import InputError

KINDS = ("auto", "native", "python")
DEFAULT_KIND = "auto"


def native_is_stale(name: str, dist: Path = DIST) -> bool:
    """fmu_src.build.native.native_is_stale, imported when asked (it imports the models: seconds)."""
    from fmu_src.build.native import native_is_stale as stale
    return stale(name, dist)


def ensure_built(dist: Path = DIST, force: bool = False, quiet: bool = False,
                 native: bool = True) -> dict[str, Path]:
    """Build every FMU (build.py, in a subprocess: fmu_src.build.dist.run_build) unless they are
    present and current; returns the pythonfmu FMUs' paths by name (``native_path`` gives their
    native twins). A missing or stale native FMI 2 FMU counts too when ``native`` (and build.py
    can build it here)."""
    dist = Path(dist)
    if dist.exists() and not dist.is_dir():
        raise InputError(f"--dist {dist}: exists and is not a folder")
    stale = force or any(is_stale(n, dist) for n in NAMES)
    if not stale and native and any(native_is_stale(n, dist) for n in NAMES) and native_buildable():
        stale = True
    if stale:
        if not quiet:
            print(f"building FMUs into {dist} ...", flush=True)
        out = run_build(dist)
        if not quiet:
            print(out.strip(), flush=True)
    return {n: dist / f"{n}.fmu" for n in NAMES}


# ------------------------------------------------------------------------------ which kind runs

COVERED_VALUES = {"est.method": (0, 2)}
"""The values of the estimator options the native FMUs run (models.compiled.NOT_COVERED names the
rest): a refusal names the options set outside them."""


def uncovered(model: str, parameters: dict) -> str | None:
    """Why the native ``model`` FMU would refuse these parameter values (None: it runs them). Decided by models.compiled (not_covered), the rule the C core is built to; the reason
    names the parameters and values. Unset parameters take the FMU's start values. The native
    AtoController runs every parameter set the pythonfmu one runs (a line too: native_ato.c)."""
    from fmu_src.adapter import chain_config, estimator_settings
    from fmu_src.variables import ATO, RAILCAR, variables_for
    if model == ATO:
        return None
    from models.compiled import estimator_not_covered, not_covered
    v = {x.name: x.start for x in variables_for(model) if x.causality == "parameter"}
    v.update(parameters)
    try:
        why = not_covered(chain_config(v)) if model == RAILCAR else estimator_not_covered(*estimator_settings(v)[:2])
    except (ValueError, TypeError, KeyError):
        return None               # a bad value: either FMU refuses it at initialisation, with one message
    if why is None:
        return None
    named = [f"{n} = {v[n]}" for n, ok in COVERED_VALUES.items() if n in v and v[n] not in ok]
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
    or every run of a sweep). ``auto``: the native FMU unless one set is not covered by it
    (``uncovered``) or the native FMU is missing (then the pythonfmu FMU, saying why). ``native`` runs the
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
        return FmuChoice("python", python, asked, f"{gap[0]} sets {gap[1]}, which the native FMU does not cover")
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
    """An FMU that needs no execution tool is a native one (fmu_src/build/native.py sets it
    false; the pythonfmu FMUs have it true)."""
    return not model_description.coSimulation.needsExecutionTool
