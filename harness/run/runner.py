"""Run scenarios on the RailCar FMU with fmpy: extract once, step in a closed loop, record.

The closed loop is harness.run.driver.drive, the one the models chain runs too; here the FMU is its
stepper (``FmuStepper``). The runner always steps with the scenario's communication step (no
silent coarsening), checks the run reaches its stop time, keeps the FMU's log, and raises
``RunError`` with that log when a call fails. Value references are looked up by name, so that
the pythonfmu FMU and its native twin (same names and value references, harness.run.fmus) are
driven by the same code; ``FmuRunner.kind`` says which one runs, and every RunResult records it.
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

import pythonfmu  # noqa: F401  (import before loading a pythonfmu FMU: the FMU reuses it)
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy import calloc, free

from harness.run.driver import drive
from harness.run.phases import INPUTS, Driver
from harness.run.result import RunResult
from harness.run.scenario import Scenario, integer_range

__all__ = ["INPUTS", "FmuRunner", "FmuStepper", "InitError", "RunError", "RunResult"]


class RunError(RuntimeError):
    """A run that failed; carries the FMU's log messages."""

    def __init__(self, message: str, log: list[str]):
        super().__init__(message + ("\nFMU log:\n  " + "\n  ".join(log[-20:]) if log else ""))
        self.message = message
        self.log = log


class InitError(RunError):
    """The FMU refused to initialise with the parameters given: invalid input (exit code 2), where a
    RunError after initialisation is a failed run (exit code 1)."""

    @property
    def reason(self) -> str:
        """The FMU's own message (fmu_src.adapter logs "initialisation failed: ..."), else the call's."""
        for line in self.log:               # the first: later ones may hold a traceback
            head, sep, tail = line.partition("initialisation failed: ")
            if sep and tail.strip():
                return tail.strip().splitlines()[0]
        return self.message


def _int32(name: str, value: int) -> int:
    """An fmi2Integer value: ctypes would wrap a value outside 32 bits silently (seed 2**32 + 1 ran
    as seed 1); refused instead, with the range (harness.run.scenario.integer_range)."""
    lo, hi = integer_range(name)
    if not lo <= value <= hi:
        raise ValueError(f"{name}: {value} is outside {lo}..{hi} (a 32-bit fmi2Integer)")
    return value


def _finish(fmu: FMU2Slave) -> None:
    """Terminate and free an instance that initialised (never one after fmi2Fatal)."""
    try:
        fmu.terminate()
    except Exception:
        pass
    try:
        fmu.freeInstance()
    except Exception:
        pass


class FmuRunner:
    """One extracted FMU, reused for many runs (a new instance per run)."""

    def __init__(self, fmu_path: str | Path, unzip_root: str | Path | None = None):
        """``unzip_root``: extract into a new folder below it (default: the system's temporary
        folder); ``close`` removes the extraction."""
        self.fmu_path = Path(fmu_path)
        if not self.fmu_path.is_file():
            raise FileNotFoundError(f"FMU not found: {self.fmu_path} (build it with: python build.py)")
        self.md = read_model_description(str(self.fmu_path))
        self.unzipdir = extract(str(self.fmu_path), unzipdir=tempfile.mkdtemp(
            prefix="railcar-fmu-", dir=str(unzip_root)) if unzip_root is not None else None)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.outputs = [v.name for v in self.md.modelVariables if v.causality == "output"]
        self.units = {v.name: (v.unit or v.declaredType and v.declaredType.unit or "")
                      for v in self.md.modelVariables}
        self._runs = 0

    @property
    def kind(self) -> str:
        """"native" (the C core, no Python: needsExecutionTool false) or "python" (pythonfmu)."""
        from harness.run.fmus import is_native
        return "native" if is_native(self.md) else "python"

    def close(self) -> None:
        shutil.rmtree(self.unzipdir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def vr(self, name: str) -> int:
        try:
            return self.vars[name].valueReference
        except KeyError:
            raise KeyError(f"{self.md.modelName} has no variable '{name}'") from None

    def _instantiate(self, log: list[str]) -> FMU2Slave:
        self._runs += 1
        return self._new_instance(lambda: log, f"{self.md.modelName}_{self._runs}")

    def _new_instance(self, sink, instance_name: str) -> FMU2Slave:
        """Instantiate with logging on; the FMU's messages go to the list ``sink()`` returns."""
        def logger(_env, instance, status, category, message):
            # the message arrives as a printf format without arguments: '%%' stands for '%'
            text = message.decode(errors="replace").replace("%%", "%") if message else ""
            sink().append(f"[{status}] {category.decode(errors='replace') if category else ''}: {text}")

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                        modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        fmu._keep_callbacks = callbacks        # the C side holds pointers to them
        return fmu

    def typed_parameters(self, raw: dict[str, str]) -> dict:
        """Command-line NAME=VALUE strings -> values of the FMU parameters' types.

        A String parameter that names an existing file is made absolute (the FMU resolves
        relative paths against its resources/ folder first)."""
        out = {}
        for name, text in raw.items():
            var = self.vars.get(name)
            if var is None or var.causality != "parameter":
                raise KeyError(f"{self.md.modelName} has no parameter '{name}'")
            try:
                if var.type == "Real":
                    out[name] = float(text)
                elif var.type == "Integer":
                    out[name] = _int32(name, int(text))
                else:
                    out[name] = str(Path(text).resolve()) if text and Path(text).is_file() else text
            except ValueError:
                raise ValueError(f"{name}: '{text}' is not a valid {var.type}") from None
        return out

    def set_parameters(self, fmu: FMU2Slave, parameters: dict) -> None:
        for name, value in parameters.items():
            var = self.vars.get(name)
            if var is None:
                raise KeyError(f"{self.md.modelName} has no parameter '{name}'")
            if var.type == "Real":
                fmu.setReal([var.valueReference], [float(value)])
            elif var.type == "Integer":
                fmu.setInteger([var.valueReference], [_int32(name, int(value))])
            elif var.type == "String":
                fmu.setString([var.valueReference], [str(value)])
            else:
                raise TypeError(f"{name}: unsupported type {var.type}")

    def start(self, parameters: dict, stop_time: float, log: list[str], what: str) -> FMU2Slave:
        """A new instance, initialised with ``parameters``; RunError (with the log) if that fails."""
        return self.initialise(self._instantiate(log), parameters, stop_time, log, what)

    def initialise(self, fmu: FMU2Slave, parameters: dict, stop_time: float, log: list[str],
                   what: str) -> FMU2Slave:
        """Set up and initialise an instantiated (or reset) FMU; RunError if that fails."""
        try:
            fmu.setupExperiment(startTime=0.0, stopTime=stop_time)
            fmu.enterInitializationMode()
            self.set_parameters(fmu, parameters)
            fmu.exitInitializationMode()
        except Exception as e:
            # pythonfmu reports initialisation errors as fmi2Fatal; after Fatal the FMI standard
            # allows no further call on the instance (pythonfmu's freeInstance would segfault),
            # so the instance is deliberately leaked.
            raise InitError(f"{what}: initialisation failed: {e}", log) from None
        return fmu

    def replay(self, log_data, parameters: dict, what: str = "replay", step: float | None = None):
        """Run RailCarEstimator over a measured log (see harness.run.replay); returns (signals, log).

        Row k's measurements and forces drive doStep(t_k, h_k), h_k = ``step`` (a uniform grid's
        step, exactly as RailCar's estimator steps) or else t_k+1 - t_k; the outputs after it
        (estimates for t_k+1) are stored at row k+1.
        """
        outputs = [n for n in self.outputs if self.vars[n].type == "Real"]
        out_vr = [self.vr(n) for n in outputs]
        in_names = ("traction_force", "brake_force", "sensor.speed", "sensor.position")
        in_vr = [self.vr(n) for n in in_names]
        t = log_data.time
        log: list[str] = []
        fmu = self.start(parameters, float(t[-1]), log, what)
        rows = [fmu.getReal(out_vr)]
        try:
            for k in range(len(t) - 1):
                fmu.setReal(in_vr, [float(log_data.columns[n][k]) for n in in_names])
                try:
                    h = step if step is not None else float(t[k + 1] - t[k])
                    fmu.doStep(currentCommunicationPoint=float(t[k]), communicationStepSize=h)
                except Exception as e:
                    raise RunError(f"{what}: doStep at t = {t[k]:.3f} s (row {k + 2}) failed: {e}", log) from None
                rows.append(fmu.getReal(out_vr))
        finally:
            _finish(fmu)
        arr = np.array(rows).reshape(len(rows), len(outputs))
        return {n: arr[:, j] for j, n in enumerate(outputs)}, log

    def run(self, scenario: Scenario, outputs: list[str] | None = None,
            driver: Driver | None = None) -> RunResult:
        """Run ``scenario`` to its end (harness.run.driver.drive, with ``driver`` or the scenario's
        own) and return every output (or ``outputs``) over time."""
        outputs = list(outputs or self.outputs)
        names = ([n for n in outputs if self.vars[n].type == "Real"] +
                 [n for n in outputs if self.vars[n].type == "Integer"])
        driver = scenario.new_driver() if driver is None else driver
        log: list[str] = []
        fmu = self.start(scenario.parameters, scenario.duration_s, log, scenario.name)
        try:
            reads = names + [n for n in getattr(driver, "reads", ()) if n not in names]
            trace = drive(FmuStepper(self, fmu, reads, scenario.name, log), scenario, driver)
        finally:
            _finish(fmu)
        steps = int(round(scenario.duration_s / scenario.step_s))
        if not trace.finished and len(trace.inputs) != steps:
            raise RunError(f"{scenario.name}: run ended after {len(trace.inputs)} steps, not {steps}", log)
        return trace.result(scenario, names, units={n: self.units.get(n, "") for n in outputs}, log=log,
                            fmu=self.kind)


class FmuStepper:
    """An initialised RailCar FMU instance (FMU2Slave, or what FmuRunner.start gives) as a
    harness.run.driver Stepper: the inputs set by value reference (INPUTS), doStep, and the outputs
    ``names`` read back (Real, then Integer), no others. A failed doStep raises RunError with
    the FMU's log."""

    def __init__(self, runner: FmuRunner, fmu, names: Sequence[str], what: str, log: list[str]):
        self.fmu, self.what, self.log = fmu, what, log
        real = [n for n in names if runner.vars[n].type == "Real"]
        ints = [n for n in names if runner.vars[n].type == "Integer"]
        self.names = real + ints
        self.real_vr, self.int_vr = [runner.vr(n) for n in real], [runner.vr(n) for n in ints]
        self.in_vr = [runner.vr(n) for n in INPUTS]

    def outputs(self) -> Mapping[str, float]:
        values = list(self.fmu.getReal(self.real_vr))
        if self.int_vr:
            values += self.fmu.getInteger(self.int_vr)
        return dict(zip(self.names, values))

    def do_step(self, t: float, h: float, inputs: Sequence[float]) -> None:
        self.fmu.setReal(self.in_vr, list(inputs))
        try:
            self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        except Exception as e:
            raise RunError(f"{self.what}: doStep at t = {t:.3f} s failed: {e}", self.log) from None
