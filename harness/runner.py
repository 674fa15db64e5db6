"""Run scenarios on the RailCar FMU with fmpy: extract once, step in a closed loop, record.

The runner always steps with the scenario's communication step (no silent coarsening), checks
the run reaches its stop time, keeps the FMU's log, and raises ``RunError`` with that log
when a call fails. Value references are looked up by name, so that the pythonfmu FMU and its
native twin (same names and value references, harness.fmus) are driven by the same code;
``FmuRunner.kind`` says which one runs, and every RunResult records it.
"""
from __future__ import annotations

import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import pythonfmu  # noqa: F401  (import before loading a pythonfmu FMU: the FMU reuses it)
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy import calloc, free

from .driver import PhaseDriver
from .scenario import Scenario

INPUTS = ("traction_force_demand", "brake_force_demand", "wind_speed", "car.payload")


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


@dataclass
class RunResult:
    """Recorded outputs of one run: ``signals[name]`` is an array over ``time`` [s]."""
    scenario: Scenario
    time: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str]
    log: list[str] = field(default_factory=list)
    inputs: dict[str, np.ndarray] = field(default_factory=dict)   # held over [t_k, t_k+1]
    fmu: str = ""                  # which FMU ran: "native" or "python" (FmuRunner.kind); "" no FMU

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        return self.signals[name]


def _int32(name: str, value: int) -> int:
    """An fmi2Integer value: ctypes would wrap a value outside 32 bits silently (seed 2**32 + 1 ran
    as seed 1); refused instead, with the range (harness.scenario.integer_range)."""
    from .scenario import integer_range
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
        from .fmus import is_native
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

    def replay(self, log_data, parameters: dict, what: str = "replay"):
        """Run RailCarEstimator over a measured log (see harness.replay); returns (time, signals).

        Row k's measurements and forces drive doStep(t_k, t_k+1 - t_k); the outputs after it
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
                    fmu.doStep(currentCommunicationPoint=float(t[k]), communicationStepSize=float(t[k + 1] - t[k]))
                except Exception as e:
                    raise RunError(f"{what}: doStep at t = {t[k]:.3f} s (row {k + 2}) failed: {e}", log) from None
                rows.append(fmu.getReal(out_vr))
        finally:
            _finish(fmu)
        arr = np.array(rows).reshape(len(rows), len(outputs))
        return {n: arr[:, j] for j, n in enumerate(outputs)}, log

    def run(self, scenario: Scenario, outputs: list[str] | None = None) -> RunResult:
        """Run ``scenario`` to its end and return every output (or ``outputs``) over time."""
        outputs = list(outputs or self.outputs)
        real_out = [n for n in outputs if self.vars[n].type == "Real"]
        int_out = [n for n in outputs if self.vars[n].type == "Integer"]
        real_vr = [self.vr(n) for n in real_out]
        int_vr = [self.vr(n) for n in int_out]
        in_vr = [self.vr(n) for n in INPUTS]
        speed_i, pos_i = real_out.index("car.speed"), real_out.index("car.position")

        h = scenario.step_s
        n_max = int(round(scenario.duration_s / h))
        log: list[str] = []
        fmu = self.start(scenario.parameters, scenario.duration_s, log, scenario.name)
        rows_t, rows_r, rows_i = [], [], []
        try:
            driver = PhaseDriver(scenario.phases, scenario.parameter("car.mass"),
                                 scenario.parameter("car.traction_force_max"),
                                 scenario.parameter("car.brake_force_max")) if scenario.phases else None
            payload = 0.0
            finished = False
            rows_in = []
            r = fmu.getReal(real_vr)
            rows_t.append(0.0), rows_r.append(r), rows_i.append(fmu.getInteger(int_vr))
            for k in range(n_max):
                t = k * h
                if driver is not None:
                    traction, brake, dm = driver.demands(t, r[speed_i], r[pos_i])
                    payload += dm
                    if driver.finished and scenario.stop_after_last_phase:
                        finished = True
                        break
                else:
                    traction, brake = scenario.time_table.at(t)
                u = [traction, brake, scenario.wind_at(t), payload]
                rows_in.append(u)
                fmu.setReal(in_vr, u)
                try:
                    fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
                except Exception as e:
                    raise RunError(f"{scenario.name}: doStep at t = {t:.3f} s failed: {e}", log) from None
                r = fmu.getReal(real_vr)
                rows_t.append((k + 1) * h), rows_r.append(r), rows_i.append(fmu.getInteger(int_vr))
        finally:
            _finish(fmu)
        time = np.array(rows_t)
        if not finished and not math.isclose(time[-1], n_max * h, rel_tol=1e-12, abs_tol=1e-9):
            raise RunError(f"{scenario.name}: run ended at {time[-1]} s, not at {n_max * h} s", log)
        r_arr = np.array(rows_r).reshape(len(rows_t), len(real_out))
        i_arr = np.array(rows_i).reshape(len(rows_t), len(int_out))
        signals = {n: r_arr[:, j] for j, n in enumerate(real_out)}
        signals.update({n: i_arr[:, j] for j, n in enumerate(int_out)})
        units = {n: self.units.get(n, "") for n in outputs}
        u_arr = np.array(rows_in + rows_in[-1:] if rows_in else [[0.0] * len(INPUTS)]).reshape(-1, len(INPUTS))
        inputs = {n: u_arr[:, j] for j, n in enumerate(INPUTS)}
        return RunResult(scenario, time, signals, units, log, inputs, fmu=self.kind)
