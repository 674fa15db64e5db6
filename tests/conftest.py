"""Shared fixtures for the FMU tests: one fresh build per session and a low-level fmpy helper.

Known traps this file works around (measured with pythonfmu 0.7.0 / fmpy 0.3.32):

- ``pythonfmu`` is imported here, before any FMU is loaded into this process.
- An FMU's Python modules (``models``, ``fmu_src``) are cached in ``sys.modules`` by the first
  instance created in a process; a rebuilt FMU loaded later in the same process silently runs
  the *old* code. The FMUs are therefore built once per session, in a subprocess, from the
  current sources, and every test loads those builds (never ``dist/``, which may be stale).
- pythonfmu maps any Python exception in a callback to fmi2Fatal. After fmi2Fatal, FMI 2.0
  forbids any further call on the instance, and pythonfmu 0.7.0 indeed segfaults on
  fmi2Terminate / fmi2FreeInstance of such an instance: :class:`Slave` leaks it instead.
- fmpy ignores ``step_size`` for co-simulation; callers pass ``output_interval`` and check that
  the result's last time is the stop time (on fmi2Discard fmpy silently stops early).
- Value references are always looked up by name from the model description.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (must be imported before any FMU is loaded)

import os
import subprocess
import sys
import threading
from contextlib import contextmanager
from ctypes import byref
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
FMU_NAMES = ("RailCar", "RailCarEstimator", "AtoController")

OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS_LABEL = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}


# ------------------------------------------------------------------------------------ layers

# Every test gets one layer marker, from what it needs (pyproject.toml registers them):
#   unit        pure Python: models/, harness/ computing, docs (the fast layer)
#   core        compiles C (the model core, its shims, the native glue under sanitizers)
#   fmu         loads a built FMU (build.py runs once per session)
#   regression  compares with the references in tests/regression/
# and "slow" on everything but the unit layer, plus the unit tests in SLOW_UNIT (long runs), so
# that `pytest -m "not slow"` is the fast unit layer a developer runs while editing.
FMU_FIXTURES = {"built_fmus", "fmus", "railcar", "estimator", "ato_fmu"}
C_MODULES = ("test_core_", "test_native")
SLOW_UNIT = {"test_cli_errors.py", "test_service_day.py", "test_studies.py", "test_regression_variants.py",
             "test_estimator_methods.py", "test_estimator_refit.py", "test_track_integration.py",
             "test_trajectory.py",     # its plans fixture takes ~9 s
             "test_output_error.py::test_grade_break_is_integrated_by_interval_means",
             "test_output_error.py::test_covariance_matches_errors_under_process_noise",
             "test_coast_ekf.py::test_covariance_matches_errors_and_innovations_are_white",
             "test_robust_estimator.py::test_a_step_longer_than_the_maximum_is_refused_at_once",
             "test_singer.py::test_steady_state_covariance_is_the_dare_solution"}
"""Unit tests over ~1.5 s (measured with --durations), by module or module::test (all its params)."""


def layer_of(item) -> str:
    module = item.path.name
    if module.startswith("test_regression"):
        return "regression"
    if FMU_FIXTURES & set(item.fixturenames):
        return "fmu"
    if module.startswith(C_MODULES):
        return "core"
    return "unit"


def pytest_collection_modifyitems(config, items):
    for item in items:
        layer = layer_of(item)
        item.add_marker(getattr(pytest.mark, layer))
        if (layer != "unit" or item.path.name in SLOW_UNIT
                or f"{item.path.name}::{item.originalname}" in SLOW_UNIT):
            item.add_marker(pytest.mark.slow)


# ------------------------------------------------------------------------------------ building

def build_fmus(dest: Path, native: bool = True) -> dict[str, Path]:
    """Run ``build.py --dest dest`` in a subprocess (fresh interpreter, current sources); without
    ``native`` it skips the native FMUs (``--no-native``: tests of the pythonfmu FMUs alone)."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    flags = [] if native else ["--no-native"]
    # 600 s: a ceiling, not the cost (~1.5 min alone); on a machine shared with other jobs the
    # 18 native compiles (6 FMUs x 3 platforms) have taken over 300 s
    proc = subprocess.run([sys.executable, "build.py", "--dest", str(dest), *flags], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"build.py failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    paths = {name: dest / f"{name}.fmu" for name in FMU_NAMES}
    for p in paths.values():
        assert p.is_file(), f"build.py did not produce {p}:\n{proc.stdout}"
    return paths


@dataclass
class FmuFile:
    """A built FMU: its path, model description, one extraction and name -> variable maps."""
    name: str
    path: Path
    md: object = field(repr=False)
    unzipdir: str = ""

    def __post_init__(self):
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.variables.items()}

    def names(self, causality: str) -> list[str]:
        return [v.name for v in self.md.modelVariables if v.causality == causality]


@pytest.fixture(scope="session")
def built_fmus(tmp_path_factory) -> dict[str, Path]:
    """RailCar.fmu, RailCarEstimator.fmu and AtoController.fmu built once per session from the current sources."""
    return build_fmus(tmp_path_factory.mktemp("build") / "dist")


@pytest.fixture(scope="session")
def native_fmus(built_fmus) -> dict[str, Path]:
    """The six native FMUs build.py put in dist/native/ of that same build (the same sources
    and flags as fmu_src.build.native's and native_fmi3's functions): built once, not once per
    test module."""
    folder = built_fmus["RailCar"].parent / "native"
    paths = {n: folder / f"{n}.fmu" for n in ("RailCarNative", "RailCarEstimatorNative",
                                              "RailCarNative3", "RailCarEstimatorNative3",
                                              "AtoControllerNative", "AtoControllerNative3")}
    for path in paths.values():
        assert path.is_file(), f"build.py did not produce {path}"
    return paths


@pytest.fixture(scope="session")
def fmus(built_fmus, tmp_path_factory) -> dict[str, FmuFile]:
    out = {}
    for name, path in built_fmus.items():
        unzipdir = extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"unzip_{name}")))
        out[name] = FmuFile(name, path, read_model_description(str(path)), unzipdir)
    return out


@pytest.fixture(scope="session")
def railcar(fmus) -> FmuFile:
    return fmus["RailCar"]


@pytest.fixture(scope="session")
def estimator(fmus) -> FmuFile:
    return fmus["RailCarEstimator"]


@pytest.fixture(scope="session")
def ato_fmu(fmus) -> FmuFile:
    return fmus["AtoController"]


# ------------------------------------------------------------------------ low-level stepping

@dataclass
class LogMessage:
    status: int
    category: str | None
    message: str

    def __str__(self):
        return f"[{STATUS_LABEL.get(self.status, self.status)}] {self.message}"


def _make_callbacks(sink: list) -> fmi2CallbackFunctions:
    """FMI callbacks whose logger appends formatted LogMessages to ``sink``."""
    def logger(_env, _instance, status, category, message):
        sink.append(LogMessage(int(status), category.decode("utf-8", "replace") if category else None,
                               message.decode("utf-8", "replace") if message else ""))

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    from fmpy.logging import addLoggerProxy   # formats the variadic message in C
    addLoggerProxy(byref(cb))
    # fmpy's proxy keeps the Python logger in a C global, which every later FMU whose logger is
    # the proxy calls: the logger must live as long as the process (freed with its Slave, a
    # later fmpy.simulate_fmu's log message jumped into freed memory and segfaulted)
    _PROXIED.append((cb, cb.logger))
    return cb


_PROXIED = []   # every logger handed to fmpy's logging proxy (see _make_callbacks)


_LEAKED = []   # instances after fmi2Fatal (FMI forbids freeing them) and their callbacks


class Slave:
    """One co-simulation instance driven through fmpy's FMU2Slave, variables by name.

    ``call(name, *args)`` returns the FMI status (0 ok, 2 discard, 4 fatal, ...) instead of
    raising fmpy's FMICallException, so that tests can assert on it.
    """

    def __init__(self, fmu: FmuFile, instance_name: str = "instance", logging_on: bool = True):
        self.fmu_file = fmu
        self.messages: list[LogMessage] = []
        self._callbacks = _make_callbacks(self.messages)
        self.fmu = FMU2Slave(guid=fmu.md.guid, unzipDirectory=fmu.unzipdir,
                             modelIdentifier=fmu.md.coSimulation.modelIdentifier,
                             instanceName=instance_name)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
        self.fatal = False
        self.freed = False
        self.time = 0.0

    # -- calls with status
    def call(self, function: str, *args) -> int:
        try:
            getattr(self.fmu, function)(*args)
            return OK
        except FMICallException as e:
            if e.status == FATAL:
                self.fatal = True
            return e.status

    def log_text(self) -> str:
        return "\n".join(str(m) for m in self.messages)

    # -- values by name
    def _type(self, name: str) -> str:
        return self.fmu_file.variables[name].type

    def set(self, values: dict) -> None:
        for name, value in values.items():
            vr, typ = [self.fmu_file.vr[name]], self._type(name)
            if typ == "Real":
                self.fmu.setReal(vr, [float(value)])
            elif typ == "Integer":
                self.fmu.setInteger(vr, [int(value)])
            elif typ == "String":
                self.fmu.setString(vr, [str(value)])
            elif typ == "Boolean":
                self.fmu.setBoolean(vr, [bool(value)])
            else:  # pragma: no cover
                raise TypeError(f"{name}: unsupported type {typ}")

    def get(self, name: str):
        vr, typ = [self.fmu_file.vr[name]], self._type(name)
        if typ == "Real":
            return self.fmu.getReal(vr)[0]
        if typ == "Integer":
            return self.fmu.getInteger(vr)[0]
        if typ == "String":
            return self.fmu.getString(vr)[0]
        return self.fmu.getBoolean(vr)[0]

    def get_reals(self, names: list[str]) -> list[float]:
        return list(self.fmu.getReal([self.fmu_file.vr[n] for n in names]))

    # -- life cycle
    def setup(self, parameters: dict | None = None, start_time: float = 0.0) -> None:
        """setupExperiment, enterInitializationMode, parameters/initial inputs (by name)."""
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        self.set(parameters or {})
        self.time = start_time

    def exit_init(self) -> int:
        return self.call("exitInitializationMode")

    def initialize(self, parameters: dict | None = None, start_time: float = 0.0) -> None:
        self.setup(parameters, start_time)
        status = self.exit_init()
        assert status == OK, f"exitInitializationMode -> {STATUS_LABEL[status]}\n{self.log_text()}"

    def do_step(self, current_time: float, step_size: float) -> int:
        return self.call("doStep", current_time, step_size)

    def step_to(self, t_end: float) -> None:
        """One doStep from the current time to ``t_end``; must succeed."""
        status = self.do_step(self.time, t_end - self.time)
        assert status == OK, f"doStep({self.time}, {t_end - self.time}) -> {STATUS_LABEL[status]}\n{self.log_text()}"
        self.time = t_end

    def reset(self) -> int:
        status = self.call("reset")
        self.time = 0.0
        return status

    def close(self) -> None:
        if self.freed:
            return
        self.freed = True
        if self.fatal:       # FMI 2.0: no call after fmi2Fatal (pythonfmu would segfault)
            _LEAKED.append((self.fmu, self._callbacks))
            return
        self.fmu.terminate()
        self.fmu.freeInstance()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def run(fmu: FmuFile, parameters: dict | None, outputs: list[str], step: float, n_steps: int,
        inputs=None, instance_name: str = "run") -> np.ndarray:
    """Run ``n_steps`` communication steps of ``step`` [s] with the low-level API.

    ``inputs(k, t)`` returns a dict of inputs to set before step k (from t = k * step).
    Returns an array of shape (n_steps + 1, 1 + len(outputs)): time, then the outputs, the
    first row at t = 0 after initialisation. Times are k * step (no accumulation).
    """
    rows = []
    with Slave(fmu, instance_name) as s:
        s.initialize(parameters)
        rows.append([0.0] + s.get_reals(outputs))
        for k in range(n_steps):
            t = k * step
            if inputs is not None:
                s.set(inputs(k, t))
            status = s.do_step(t, step)
            assert status == OK, f"doStep({t}, {step}) -> {STATUS_LABEL[status]}\n{s.log_text()}"
            rows.append([(k + 1) * step] + s.get_reals(outputs))
    return np.array(rows)


@pytest.fixture
def slave_factory():
    """Create Slaves that are closed (or, after fmi2Fatal, leaked) at the end of the test."""
    created: list[Slave] = []

    def make(fmu: FmuFile, instance_name: str = "instance", logging_on: bool = True) -> Slave:
        s = Slave(fmu, instance_name, logging_on)
        created.append(s)
        return s

    yield make
    for s in reversed(created):
        s.close()


# ------------------------------------------------------------------------ profile files

@contextmanager
def fifo_released(fifo: Path):
    """While inside, a reader that opens ``fifo`` is let go at once (a writer opens and closes
    it: the reader sees an empty file), so an FMU that opens it hangs no test; the list yielded
    gets True each time that had to happen (the check before opening failed)."""
    stop, opened = threading.Event(), []

    def release():
        while not stop.wait(0.02):
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)   # ENXIO while no one reads
            except OSError:
                continue
            opened.append(True)
            os.close(fd)

    thread = threading.Thread(target=release, daemon=True)
    thread.start()
    try:
        yield opened
    finally:
        stop.set()
        thread.join()
