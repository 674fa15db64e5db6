"""Our own fixed-step co-simulation master for an SSP system (harness.systems.ssp), over fmpy.

Jacobi, as libcosim's fixed-step algorithm: every component steps from t to t + h with its
inputs set from the outputs at t, then the outputs are transferred. The calls are libcosim
0.11's, in its order, so that a system gives the same numbers bit for bit in both (docs/systems.md):

1. instantiate every component (logging on);
2. per component: its bound parameters (not its inputs) set, fmi2SetupExperiment(start, no stop
   time, no tolerance), fmi2EnterInitializationMode, the outputs read;
3. as many times as there are components: per component, the pending values set (the first time
   every bound parameter and input, then what the connections carried), the outputs read; then
   every connection carried;
4. per component: the pending values set, fmi2ExitInitializationMode, the outputs read; every
   connection carried. These outputs are the result's first row (time = start);
5. each step k: per component the pending values set, fmi2DoStep(t_k, t_k+1 - t_k), the outputs
   read; every connection carried; a row recorded.

A system with a step order (SystemSpec.step_order, the ORDER_ANNOTATION of the .ssd) steps
Gauss-Seidel instead, in that order, each component's outputs carried as soon as it has stepped:
RailCar <-> AtoController with the order (ato, car) applies the demand the ATO computed from the
outputs at t over [t, t + h], as ``python -m harness run`` does, with no one-step delay.
libcosim has no such algorithm (harness.systems.libcosim refuses such a system). Initialisation
is the same in both.

A profile packed in the .ssp (a String parameter "resources/profiles/...") is unpacked next to
the FMUs and its absolute path is what the FMU gets (harness.systems.ssp_read.unpack_files), so
the run does not depend on the working directory.

Time is counted in integer nanoseconds as libcosim does (step_ns = the step in ns, truncated):
t_k = (start_ns + k step_ns) / 1e9, so doStep gets the same doubles. Values in a set call go
Real, Integer, Boolean, String. Value references are looked up by name in each modelDescription.

A component that returns Discard, Error or Fatal (or whose call raises) stops the run with a
``MasterError`` naming the component, the call, the time and the status, with the component's
log. Every instance is terminated and freed, except one after Fatal (FMI forbids any call, and
pythonfmu would crash): that one is left allocated.
"""
from __future__ import annotations

import csv
import shutil
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.systems.ssp import LoadedSystem, SspError, TYPES, split_name, ssp_type, unit_of
from harness.systems.ssp_read import read_ssp, unpack_files

__all__ = ["MasterError", "Result", "run_system", "time_grid", "plan_reads", "default_outputs",
           "report_failure"]

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
EXIT_FAILED_RUN, EXIT_INVALID_INPUT = 1, 2


def report_failure(e: Exception) -> int:
    """Print a failed system run's error on stderr; its exit code: 2 for a package or
    description that is invalid (SspError), 1 for a run that failed (MasterError)."""
    print(f"error: {e}", file=sys.stderr)
    return EXIT_INVALID_INPUT if isinstance(e, SspError) else EXIT_FAILED_RUN


class MasterError(RuntimeError):
    """A co-simulation that failed; the message names the component, call, time and status."""

    def __init__(self, message: str, log: Sequence[str] = ()):
        super().__init__(message + ("\n" + "\n".join(f"  {m}" for m in list(log)[-20:]) if log else ""))
        self.message, self.log = message, list(log)


@dataclass
class Result:
    """A run: ``time`` [s] and each observed "Component.variable" over it (row 0: after
    initialisation), with its unit."""
    time: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    master: str = ""

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    def header(self) -> list[str]:
        return ["time [s]"] + [f"{n} [{self.units.get(n) or '-'}]" for n in self.signals]

    def write_csv(self, path: str | Path) -> Path:
        """One row per time point; header cells 'name [unit]'; reals written exactly (repr)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.header())
            cols = [self.time] + list(self.signals.values())
            for k in range(len(self.time)):
                w.writerow([repr(float(c[k])) if c.dtype.kind == "f" else str(c[k]) for c in cols])
        return path


# ------------------------------------------------------------------------------ computing

def to_ns(seconds: float) -> int:
    """libcosim's to_duration: the double times 1e9, truncated to integer nanoseconds."""
    return int(float(seconds) * 1e9)


def time_grid(start: float, step: float, n: int) -> np.ndarray:
    """The n + 1 communication points as libcosim passes them: (start_ns + k step_ns) / 1e9."""
    start_ns, step_ns = to_ns(start), to_ns(step)
    return np.array([(start_ns + k * step_ns) / 1e9 for k in range(n + 1)])


def steps_for(system: LoadedSystem, stop_time: float | None, n_steps: int | None) -> int:
    spec = system.spec
    if n_steps is not None:
        if int(n_steps) != n_steps or n_steps < 1:
            raise SspError(f"{system.path}: {n_steps!r} steps: expected an integer >= 1")
        return int(n_steps)
    stop = spec.stop if stop_time is None else stop_time
    if stop is None:
        raise SspError(f"{system.path}: no stop time (ssd:DefaultExperiment stopTime); pass one")
    span_ns, step_ns = to_ns(stop) - to_ns(spec.start), to_ns(spec.step)
    if span_ns <= 0 or span_ns % step_ns:
        raise SspError(f"{system.path}: stop time {stop} s is not start + a whole number of steps "
                       f"of {spec.step} s")
    return span_ns // step_ns


def default_outputs(system: LoadedSystem) -> list[str]:
    """Every output of every component, "Component.variable", in component then FMU order."""
    return [f"{c.name}.{v.name}" for c in system.spec.components
            for v in system.models[c.name].modelVariables
            if v.causality == "output" and ssp_type(v) in TYPES]


def check_outputs(system: LoadedSystem, outputs: Sequence[str]) -> list[str]:
    out = []
    for full in outputs:
        system.variable(full, f"output '{full}'")       # SspError if unknown
        if full in out:
            raise SspError(f"{system.path}: output '{full}' asked for twice")
        out.append(full)
    return out


def plan_reads(system: LoadedSystem, outputs: Sequence[str]) -> dict[str, list[str]]:
    """Per component, the variables read after each call: connection sources and ``outputs``."""
    reads: dict[str, list[str]] = {c.name: [] for c in system.spec.components}
    for full in [c.start for c in system.spec.connections] + list(outputs):
        comp, name = split_name(full)
        if name not in reads[comp]:
            reads[comp].append(name)
    return reads


# --------------------------------------------------------------------------------- the FMUs

class _Instance:
    """One component's FMU instance (FMI 2 or 3 through fmpy), values by SSP type and name."""

    def __init__(self, name: str, md, unzipdir: str):
        self.name, self.md, self.log, self.fatal = name, md, [], False
        self.vars = {v.name: v for v in md.modelVariables}
        self.fmi3 = md.fmiVersion.startswith("3")
        self.api = "fmi3" if self.fmi3 else "fmi2"
        kw = dict(guid=md.guid, unzipDirectory=unzipdir,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave

            def logger(_env, status, category, message):
                self._log(status, category, message)
            self.fmu = FMU3Slave(**kw)
            self.fmu.instantiate(loggingOn=True, logMessage=logger)
        else:
            from fmpy import calloc, free
            from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                                   fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

            def logger(_env, _instance, status, category, message):
                self._log(status, category, message)
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(logger)
            cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            self._callbacks = cb                   # the C side keeps pointers to them
            self.fmu = FMU2Slave(**kw)
            self.fmu.instantiate(callbacks=cb, loggingOn=True)

    def _log(self, status, category, message):
        text = message.decode("utf-8", "replace").replace("%%", "%") if message else ""
        cat = category.decode("utf-8", "replace") if category else ""
        self.log.append(f"[{self.name}] [{STATUS[status] if 0 <= status < 6 else status}] {cat}: {text}")

    def _fn(self, typ: str, verb: str):
        suffix = {"Real": "Float64", "Integer": "Int32"}.get(typ, typ) if self.fmi3 else typ
        return getattr(self.fmu, f"{verb}{suffix}")

    def set(self, values: dict[str, object]) -> None:
        """Set ``values`` by name: Real, then Integer, Boolean, String (libcosim's order)."""
        for typ in TYPES:
            names = [n for n in values if ssp_type(self.vars[n]) == typ]
            if names:
                self._fn(typ, "set")([self.vars[n].valueReference for n in names],
                                     [values[n] for n in names])

    def get(self, names: Sequence[str]) -> dict[str, object]:
        out = {}
        for typ in TYPES:
            sel = [n for n in names if ssp_type(self.vars[n]) == typ]
            if sel:
                values = self._fn(typ, "get")([self.vars[n].valueReference for n in sel])
                if typ == "String":
                    values = [v.decode("utf-8") if isinstance(v, bytes) else v for v in values]
                out.update(zip(sel, values))
        return out

    def do_step(self, t: float, h: float) -> None:
        result = self.fmu.doStep(t, h)
        if self.fmi3 and result[1]:
            raise RuntimeError("the FMU asked to terminate the simulation (terminateSimulation)")

    def setup(self, start: float) -> None:
        if self.fmi3:
            self.fmu.enterInitializationMode(startTime=start)
        else:
            self.fmu.setupExperiment(startTime=start)
            self.fmu.enterInitializationMode()

    def close(self) -> None:
        if self.fatal:
            return                                 # FMI: no call after Fatal
        for call in (self.fmu.terminate, self.fmu.freeInstance):
            try:
                call()
            except Exception:
                pass


class _Run:
    """One run: the instances, the pending values per component, the recorded rows."""

    def __init__(self, system: LoadedSystem, dirs: dict[str, str], outputs: list[str]):
        self.system, self.outputs = system, outputs
        self.reads = plan_reads(system, outputs)
        self.instances: dict[str, _Instance] = {}
        self.pending: dict[str, dict] = {c.name: {} for c in system.spec.components}
        self.values: dict[str, dict] = {c.name: {} for c in system.spec.components}
        self.rows: list[list] = []
        self.t = system.spec.start
        self.dirs = dirs

    def instantiate(self) -> None:
        for c in self.system.spec.components:
            self.instances[c.name] = self._guard(c.name, "instantiate", _Instance, c.name,
                                                 self.system.models[c.name], self.dirs[c.name])

    def _guard(self, comp: str, call: str, fn, *args):
        try:
            return fn(*args)
        except Exception as e:
            inst = self.instances.get(comp)
            status = getattr(e, "status", None)
            if inst is not None and status == 4:
                inst.fatal = True
            label = f"returned {STATUS[status]}" if isinstance(status, int) and 0 <= status < 6 \
                else f"failed ({type(e).__name__}: {e})"
            raise MasterError(f"{self.system.spec.name}: component '{comp}': {call} at t = {self.t!r} s "
                              f"{label}", inst.log if inst else []) from None

    def read(self, comp: str) -> None:
        inst = self.instances[comp]
        self.values[comp] = self._guard(comp, "get", inst.get, self.reads[comp])

    def flush(self, comp: str) -> None:
        inst, pending = self.instances[comp], self.pending[comp]
        if pending:
            self._guard(comp, "set", inst.set, dict(pending))
            pending.clear()

    def transfer(self, source: str | None = None) -> None:
        """Carry every connection (or those from component ``source``) into the pending values."""
        for conn in self.system.spec.connections:
            (sc, sv), (ec, ev) = split_name(conn.start), split_name(conn.end)
            if source is None or sc == source:
                self.pending[ec][ev] = self.values[sc][sv]

    def record(self) -> None:
        row = []
        for full in self.outputs:
            comp, name = split_name(full)
            row.append(self.values[comp][name])
        self.rows.append(row)


def _extract(system: LoadedSystem, root: Path) -> dict[str, str]:
    """Unzip each component's FMU (from the .ssp) into its own folder below ``root``."""
    from fmpy import extract
    dirs = {}
    with zipfile.ZipFile(system.path) as z:
        for c in system.spec.components:
            fmu = root / f"{c.name}.fmu"
            fmu.write_bytes(z.read(str(c.fmu)))
            dirs[c.name] = extract(str(fmu), unzipdir=str(root / c.name))
    return dirs


def _needs_python(system: LoadedSystem) -> bool:
    return any(md.coSimulation.needsExecutionTool for md in system.models.values())


def run_system(system: LoadedSystem | str | Path, stop_time: float | None = None,
               n_steps: int | None = None, outputs: Sequence[str] | None = None,
               unzip_root: str | Path | None = None) -> Result:
    """Run an SSP system (a path, or what harness.systems.ssp_read.read_ssp gave) to ``stop_time`` (or for
    ``n_steps``, or to the file's stopTime) and return ``outputs`` ("Component.variable"; default
    every output) over time."""
    if not isinstance(system, LoadedSystem):
        system = read_ssp(system)
    spec = system.spec
    n = steps_for(system, stop_time, n_steps)
    outputs = check_outputs(system, default_outputs(system) if outputs is None else outputs)
    if _needs_python(system):
        try:
            import pythonfmu  # noqa: F401  (a pythonfmu FMU reuses the process's pythonfmu)
        except ImportError:
            pass
    grid = time_grid(spec.start, spec.step, n)
    tmp = Path(tempfile.mkdtemp(prefix="railcar-ssp-", dir=None if unzip_root is None else str(unzip_root)))
    run = None
    try:
        dirs = _extract(system, tmp)
        system = unpack_files(system, tmp / "files")       # profiles: the FMUs get absolute paths
        run = _Run(system, dirs, outputs)
        run.instantiate()
        _initialise(run, run.system.spec)
        order = spec.step_order or tuple(run.instances)
        run.record()
        for k in range(n):
            t, h = float(grid[k]), float(grid[k + 1] - grid[k])
            run.t = t
            for comp in order:
                run.flush(comp)
                run._guard(comp, "doStep", run.instances[comp].do_step, t, h)
                run.read(comp)
                if spec.step_order:          # Gauss-Seidel: the next component sees it now
                    run.transfer(comp)
            if not spec.step_order:
                run.transfer()
            run.record()
    finally:
        if run is not None:
            for inst in run.instances.values():
                inst.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return _result(system, outputs, grid, run.rows, "harness.systems.master")


def _initialise(run: _Run, spec) -> None:
    """libcosim 0.11's fixed_step_algorithm::initialize, call for call (see the module's text)."""
    inputs = {c.name: {n for n in c.parameters if run.instances[c.name].vars[n].causality == "input"}
              for c in spec.components}
    for c in spec.components:
        inst = run.instances[c.name]
        params = {n: v for n, v in c.parameters.items() if n not in inputs[c.name]}
        if params:
            run._guard(c.name, "set (parameters before setup)", inst.set, params)
        run._guard(c.name, "fmi3EnterInitializationMode" if inst.fmi3 else
                   "fmi2SetupExperiment/EnterInitializationMode", inst.setup, spec.start)
        run.read(c.name)
        run.pending[c.name].update(c.parameters)           # set again in the first iteration
    for _ in range(len(spec.components)):
        for c in spec.components:
            run.flush(c.name)
            run.read(c.name)
        run.transfer()
    for c in spec.components:
        run.flush(c.name)
        inst = run.instances[c.name]
        run._guard(c.name, f"{inst.api}ExitInitializationMode", inst.fmu.exitInitializationMode)
        run.read(c.name)
    run.transfer()


def _result(system: LoadedSystem, outputs: list[str], grid: np.ndarray, rows: list, master: str) -> Result:
    signals, units = {}, {}
    for j, full in enumerate(outputs):
        v = system.variable(full)
        typ = ssp_type(v)
        dtype = {"Real": np.float64, "Integer": np.int64, "Boolean": np.bool_}.get(typ, object)
        signals[full] = np.array([r[j] for r in rows], dtype=dtype)
        units[full] = unit_of(v)
    return Result(np.asarray(grid, dtype=np.float64), signals, units, master)
