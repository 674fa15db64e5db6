"""Run an SSP system (harness.systems.ssp) in ecos, a third, independent C++ master (PyPI ecospy,
the Ecos platform's Python binding), and return the same table as our master and libcosim.

What ecos 0.7.2 does with one of our packages, read from its source (src/ecos/ssp/ssp.cpp,
simulation.cpp, algorithm/fixed_step_algorithm.cpp) and checked here:

- it reads each component's ssd:ParameterBindings (an .ssv or inline) like libcosim, but gathers
  the sets by their NAME into system-wide sets and applies the one it is told to
  (``init(parameter_set=...)``, the CLI's ``--parameterSet``). Our packages name every set
  harness.systems.ssp.PARAMETER_SET; a package whose sets have several names is refused here (ecos
  would apply one component's values and run the others on their start values);
- it applies the set after fmi2SetupExperiment/EnterInitializationMode (libcosim and our master
  before), then iterates the connections as libcosim does, and steps Jacobi, the components in
  parallel threads;
- it counts time as a double sum: doStep(t, h) gets t_k+1 = t_k + h and h = the step exactly, where
  our master and libcosim give t_k = k step_ns / 1e9 and t_k+1 - t_k. The estimator's filter uses
  the step it is given, so its outputs differ from ours in the last bits (the tests bound it);
- it ignores every status its FMUs return (doStep, set, initialisation): a discarded step or a
  failed initialisation runs on silently. The FMUs' log messages reach ecos's debug log, so the
  run happens with ecos logging at debug level and any Discard, Error or Fatal message (and any
  warning of ecos's own, such as a parameter it found no variable for) is a MasterError here,
  naming the component and where in the run it came;
- it aborts or crashes its process on some failures (an exception in a step; its CLI, a program
  without Python, crashes on a pythonfmu FMU with no message and exit code 139): the run therefore
  happens in a child Python process, and a crash is a MasterError naming the signal;
- it starts its clock at 0 whatever the start time (the start reaches only setupExperiment): a
  package with another start time is refused; so is one with a step order (ecos steps Jacobi);
- FMI 3: it loads our FMI 3 FMUs (fmi4c prints 'Function "fmi3GetVersion" is not provided by this
  FMU', which is wrong and harmless), but reads an FMI 3 String back as "" (its fmi3 get_string
  returns before copying the values): the String parameters of an FMI 3 component are set, and
  the run says (EcosResult.limits) that they could not be read back.

After initialisation every bound parameter (and bound input no connection drives) is read back
through ecos and must have the value in the package (the bits of a Real): that is the check that
ecos applied the parameter sets.
Values are read through ecospy after every step, as doubles (ecos's CSV writer prints 6
decimals); Real, Integer and Boolean outputs are observed (libcosim observes no Boolean).

A String parameter that names a packed profile reaches the FMU as written (relative to the
.ssd), so, as for libcosim, the run happens in a temporary working directory holding the packed
files at their package paths. ecospy needs Debian's libtbb12 (apt-get install libtbb12); both are
optional (the [test] extra), and a missing one is an EcosMissing naming it.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.systems.master import (MasterError, Result, check_outputs, default_outputs, report_failure,
                                    steps_for, time_grid)
from harness.systems.ssp import PARAMETER_SET, LoadedSystem, SspError, split_name, ssp_type, unit_of
from harness.systems.ssp_read import read_ssp, unpack_files

__all__ = ["EcosMissing", "EcosResult", "ecos_unavailable", "run_ecos"]

ECOS_VERSION = "0.7.2"            # the ecospy read and tested (pyproject's [test] extra pins it)
MARK = "@@railcar-ecos "          # the child's markers in the combined log: where the run is
OBSERVABLE = ("Real", "Integer", "Boolean")
TIME_TOLERANCE = 1e-9             # [s] ecos's summed clock against k * step (it drifts ~1e-14 s)
_FMU_LINE = re.compile(r"\[ecos\] \[debug\] \[(?P<instance>[^\]]+)\] (?:fmi2)?"
                       r"(?P<status>OK|Warning|Discard|Error|Fatal|Pending) (?P<message>.*)")
_ECOS_PROBLEM = re.compile(r"\[ecos\] \[(?P<level>warning|warn|error|critical)\] (?P<message>.*)")


class EcosMissing(ImportError):
    """ecospy, or the libtbb12 its library needs, is not installed."""


@dataclass
class EcosResult(Result):
    """harness.systems.master.Result plus what ecos could not do in this run (``limits``, one
    sentence each), and ecos's own clock at each row (``ecos_time`` [s])."""
    limits: list = field(default_factory=list)
    ecos_time: np.ndarray | None = None


def ecos_unavailable() -> str | None:
    """Why ecos cannot run here (ecospy or libtbb12 missing), or None if it can."""
    try:
        import ecospy  # noqa: F401  (loads libecosc.so, which needs libtbb.so.12)
    except ImportError as e:
        return (f"running a system in ecos needs ecospy {ECOS_VERSION} (pip install ecospy=={ECOS_VERSION}, "
                f"or the project's [test] extra): {e}")
    except OSError as e:
        hint = " (install Debian's libtbb12: apt-get install libtbb12)" if "tbb" in str(e) else ""
        return f"ecospy is installed but its library cannot be loaded{hint}: {e}"
    return None


def _require_ecos() -> None:
    why = ecos_unavailable()
    if why:
        raise EcosMissing(why)


def parameter_set_name(system: LoadedSystem) -> str | None:
    """The one name of the components' parameter sets (None: no component binds one); SspError if
    they have several (ecos would apply only one of them)."""
    names = {c: n for c, n in system.parameter_sets.items()}
    if len(set(names.values())) > 1:
        sets = ", ".join(f"{c}: '{n}'" for c, n in names.items())
        raise SspError(f"{system.path}: the components' parameter sets have different names ({sets}); ecos "
                       f"applies one named set to the whole system, so all but one component would run on "
                       f"their start values: rebuild the package (harness.systems.ssp.write_ssp names every "
                       f"set '{PARAMETER_SET}')")
    return next(iter(names.values()), None)


def _check(system: LoadedSystem, outputs: Sequence[str]) -> str | None:
    spec = system.spec
    if spec.step_order:
        raise SspError(f"{system.path}: the system steps its components in an order "
                       f"({' then '.join(spec.step_order)}, Gauss-Seidel); ecos steps them all at once "
                       f"(Jacobi): run it with our master, or build it with --jacobi")
    if spec.start != 0.0:
        raise SspError(f"{system.path}: start time {spec.start!r} s: ecos {ECOS_VERSION} counts its clock "
                       f"from 0 whatever the start time (the start reaches only setupExperiment)")
    for full in outputs:
        typ = ssp_type(system.variable(full))
        if typ not in OBSERVABLE:
            raise SspError(f"{system.path}: output '{full}' is a {typ}; the ecos runner observes "
                           f"{', '.join(OBSERVABLE)} outputs")
    return parameter_set_name(system)


def run_ecos(system: LoadedSystem | str | Path, stop_time: float | None = None,
             n_steps: int | None = None, outputs: Sequence[str] | None = None) -> EcosResult:
    """Run the .ssp in ecos (in a child process) and return ``outputs`` (default every Real,
    Integer and Boolean output) over time, the table of harness.systems.master.run_system.
    SspError for a package ecos would run wrongly, MasterError for a run that failed (an FMU's
    Discard/Error/Fatal, a parameter not applied, a crash), EcosMissing without ecospy/libtbb12."""
    if not isinstance(system, LoadedSystem):
        system = read_ssp(system)
    n = steps_for(system, stop_time, n_steps)
    if outputs is None:
        outputs = [o for o in default_outputs(system) if ssp_type(system.variable(o)) in OBSERVABLE]
    outputs = check_outputs(system, outputs)
    set_name = _check(system, outputs)
    _require_ecos()
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="railcar-ecos-") as tmp:
        # ecos unzips the package below TMPDIR; a crashed process leaves it there: ours
        env = dict(os.environ, TMPDIR=tmp,
                   PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
        out = Path(tmp) / "result.npz"
        request = json.dumps({"n_steps": n, "outputs": outputs, "parameter_set": set_name})
        proc = subprocess.run([sys.executable, "-m", "harness.systems.ecos", str(Path(system.path).resolve()),
                               request, str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, errors="replace", env=env, cwd=tmp)
        log = proc.stdout.splitlines()
        data = dict(np.load(out, allow_pickle=False)) if proc.returncode == 0 and out.is_file() else None
    _raise_for_log(system, log, proc.returncode)
    if data is None:
        raise MasterError(f"{system.spec.name}: ecos's process wrote no result (exit code {proc.returncode})",
                          _tail(log))
    limits = _check_parameters(system, data, log)
    grid = time_grid(system.spec.start, system.spec.step, n)
    ecos_time = data["time"]
    if len(ecos_time) != n + 1 or np.max(np.abs(ecos_time - grid)) > TIME_TOLERANCE:
        raise MasterError(f"{system.spec.name}: ecos's clock {ecos_time[-1]!r} s after {len(ecos_time) - 1} "
                          f"steps, not {grid[-1]!r} s after {n}")
    signals, units = {}, {}
    for j, full in enumerate(outputs):
        typ = ssp_type(system.variable(full))
        signals[full] = data[f"s{j}"].astype({"Real": np.float64, "Integer": np.int64, "Boolean": np.bool_}[typ])
        units[full] = unit_of(system.variable(full))
    return EcosResult(grid, signals, units, "ecos", limits, ecos_time)


# ------------------------------------------------------------------ reading the child's log

def _tail(log: list[str], n: int = 20) -> list[str]:
    """The last ``n`` lines of ecos's log, without our markers and blank lines."""
    return [line for line in log if line.strip() and not line.startswith(MARK)][-n:]


def _components_of(system: LoadedSystem, instance: str) -> list[str]:
    """The components an FMU log line's instance name stands for: ecos names an FMI 3 instance by
    its component, an FMI 2 one (through fmi4c) by the FMU's path in the unpacked package."""
    names = [c.name for c in system.spec.components if c.name == instance]
    return names or [c.name for c in system.spec.components
                     if instance.replace("\\", "/").endswith("/" + str(c.fmu))]


def _raise_for_log(system: LoadedSystem, log: list[str], returncode: int) -> None:
    """MasterError for the first FMU message with status Discard, Error or Fatal, the first
    warning or error of ecos's own, an error the child reported, or a crash."""
    name, where = system.spec.name, "loading the package"
    for k, line in enumerate(log):
        if line.startswith(MARK):
            where = line[len(MARK):]
            continue
        m = _FMU_LINE.search(line)
        if m and m["status"] in ("Discard", "Error", "Fatal"):
            comps = _components_of(system, m["instance"]) or [m["instance"]]
            who = " or ".join(f"'{c}'" for c in comps)
            raise MasterError(f"{name}: component {who}: {m['status'].lower()} {where} in ecos (ecos "
                              f"ignores the status its FMUs return and would have run on): "
                              f"{m['message'].strip()}", _tail(log[:k + 1]))
        m = _ECOS_PROBLEM.search(line)
        if m:
            raise MasterError(f"{name}: ecos {m['level']} {where}: {m['message'].strip()}", _tail(log[:k + 1]))
    if returncode == 0:
        return
    if returncode == 2:
        raise SspError(next((l.removeprefix("error: ") for l in reversed(log) if l.startswith("error: ")),
                            f"{name}: ecos's process refused the package"))
    if returncode < 0:
        try:
            what = f"was killed by {signal.Signals(-returncode).name}"
        except ValueError:
            what = f"was killed by signal {-returncode}"
        raise MasterError(f"{name}: ecos's process {what} {where}", _tail(log))
    last = next((l.removeprefix("error: ") for l in reversed(log) if l.startswith("error: ")), "")
    raise MasterError(f"{name}: ecos's process failed {where} (exit code {returncode})"
                      + (f": {last}" if last else ""), _tail(log))


def _check_parameters(system: LoadedSystem, data: dict, log: list[str]) -> list[str]:
    """Every bound parameter, read back through ecos after initialisation, has its value in the
    package; the limits of that check (FMI 3 Strings) as sentences."""
    read_back = json.loads(str(data["parameters"]))
    driven = {conn.end for conn in system.spec.connections}      # a connection sets these after the set
    limits = []
    for c in system.spec.components:
        fmi3 = system.models[c.name].fmiVersion.startswith("3")
        unread = []
        for pname, want in c.parameters.items():
            if f"{c.name}.{pname}" in driven:
                continue
            got = read_back[c.name].get(pname)
            typ = ssp_type(system.variable(f"{c.name}.{pname}"))
            if typ == "String" and fmi3:
                unread.append(pname)
                continue
            if typ == "Real":
                same = got is not None and np.float64(got).view(np.int64) == np.float64(want).view(np.int64)
            else:
                same = got == want
            if not same:
                raise MasterError(f"{system.spec.name}: ecos did not apply the parameter {c.name}.{pname}: "
                                  f"the package says {want!r}, the FMU has {got!r} after initialisation",
                                  _tail(log))
        if unread:
            limits.append(f"component '{c.name}' (FMI 3): String parameters {', '.join(unread)} set but not "
                          f"read back (ecos {ECOS_VERSION} reads an FMI 3 String as '')")
    return limits


# ------------------------------------------------------------------ in the child process

def _mark(text: str) -> None:
    os.write(1, f"{MARK}{text}\n".encode())        # unbuffered: in order with ecos's own lines


def _getter(sim, typ: str):
    return {"Real": sim.get_real, "Integer": sim.get_integer, "Boolean": sim.get_bool,
            "String": sim.get_string}[typ]


def _child(argv: list[str]) -> int:
    path, request, out = argv
    req = json.loads(request)
    system = read_ssp(path)
    n = int(req["n_steps"])
    spec = system.spec
    from ecospy import EcosSimulation
    from ecospy.lib import EcosLib
    EcosLib.set_log_level("debug")                 # the FMUs' messages come at debug level
    unpack_files(system, Path.cwd())               # packed profiles at their package paths, here
    _mark("loading the package")
    try:
        sim = EcosSimulation(spec.step, ssp_path=str(path))
    except Exception as e:
        print(f"error: ecos could not load {path}: {e}", flush=True)
        return 1
    _mark("in initialisation")
    if not sim.init(spec.start, req["parameter_set"]):
        print(f"error: ecos could not initialise the system: {EcosLib.get_last_error()}", flush=True)
        return 1
    _mark("reading the parameters back after initialisation")
    parameters = {}
    for c in spec.components:
        parameters[c.name] = {}
        for pname in c.parameters:
            typ = ssp_type(system.variable(f"{c.name}.{pname}"))
            parameters[c.name][pname] = _getter(sim, typ)(f"{c.name}::{pname}")
    ids = []
    for full in req["outputs"]:
        comp, var = split_name(full)
        ids.append((f"{comp}::{var}", _getter(sim, ssp_type(system.variable(full)))))
    rows, times = [[get(i) for i, get in ids]], [sim.get_time()]
    for k in range(n):
        _mark(f"at step {k + 1} (t = {times[-1]!r} s)")
        times.append(sim.step(1))
        rows.append([get(i) for i, get in ids])
    _mark("terminating")
    sim.terminate()
    sim.free()
    columns = list(zip(*rows))
    np.savez(out, time=np.array(times, dtype=np.float64), parameters=json.dumps(parameters),
             **{f"s{j}": np.array(col) for j, col in enumerate(columns)})
    return 0


if __name__ == "__main__":
    try:
        sys.exit(_child(sys.argv[1:]))
    except (SspError, MasterError) as e:
        sys.exit(report_failure(e))
