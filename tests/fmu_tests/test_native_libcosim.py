"""The native FMI 2 FMUs (RailCarNative.fmu, RailCarEstimatorNative.fmu of the session build)
through libcosim (libcosimpy 0.0.6), against fmpy on the same native FMU and on the pythonfmu
FMU: bit-identical outputs.

libcosim is driven open loop: the inputs the harness's closed-loop driver gave the pythonfmu
RailCar.fmu in a library scenario (RunResult.inputs; the native FMU's fmpy run must produce the
same inputs, which is checked) go in through an override manipulator before each step. Outputs
are read twice: by a last-value observer after every step, and by libcosim's own time-series
observer, whose samples (step number, time point in ns, value) include the initial values; each
sample is compared with the fmpy row of the same time point. libcosim passes doStep the time
t_k = k * step_ns / 1e9 and the step t_k+1 - t_k, fmpy the harness's k * h and h: RailCar snaps
its clocks to its own grids, so this must not show there; the estimator's filter uses the step
size it is given, so its fmpy references get libcosim's arguments.

FMI 3: libcosim 0.0.6 refuses the FMI 3 RailCarNative3.fmu ("Unsupported FMI version"); the
slave pointer libcosimpy hands back is then NULL, unchecked, and adding it to an execution
kills the process with SIGSEGV (checked in a subprocess).
"""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from libcosimpy.CosimEnums import CosimVariableType
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimManipulator import CosimManipulator
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave
from fmpy import read_model_description

from conftest import OK, ROOT
from harness.run.runner import INPUTS, FmuRunner
from harness.run.scenario import load_scenario
from test_native_sources import EST_INPUTS, _estimator_inputs, _replay

STEMS = ("steep_grades", "etcs_noisy_sensors")


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


@pytest.fixture(scope="module", autouse=True)
def quiet_libcosim():
    log_output_level(CosimLogLevel.WARNING)


@pytest.fixture(scope="module")
def native(built_fmus) -> dict:
    d = built_fmus["RailCar"].parent / "native"
    return {n: d / f"{n}.fmu" for n in ("RailCarNative", "RailCarEstimatorNative",
                                        "RailCarNative3")}


@pytest.fixture(scope="module")
def scenarios():
    return {stem: load_scenario(ROOT / "scenarios" / "library" / f"{stem}.toml") for stem in STEMS}


@pytest.fixture(scope="module")
def fmpy_runs(built_fmus, native, scenarios) -> dict:
    """stem -> (pythonfmu RailCar.fmu's run, native RailCarNative.fmu's run), both via fmpy."""
    with FmuRunner(built_fmus["RailCar"]) as py, FmuRunner(native["RailCarNative"]) as c:
        return {stem: (py.run(sc), c.run(sc)) for stem, sc in scenarios.items()}


class LibcosimRun:
    """One FMI 2 FMU in a libcosim execution, inputs overridden before each step."""

    def __init__(self, fmu_path, step_ns: int, parameters: dict, inputs: list[str]):
        self.md = read_model_description(str(fmu_path))
        self.var = {v.name: v for v in self.md.modelVariables}
        self.reals = [v.name for v in self.md.modelVariables
                      if v.causality == "output" and v.type == "Real"]
        self.ints = [v.name for v in self.md.modelVariables
                     if v.causality == "output" and v.type == "Integer"]
        self.step_ns = step_ns
        self.execution = CosimExecution.from_step_size(step_ns)
        self.slave = CosimLocalSlave(fmu_path=str(fmu_path), instance_name="native")
        assert self.slave.ptr(), "libcosim could not load the FMU"
        self.index = self.execution.add_local_slave(self.slave)
        assert self.index >= 0
        self.last = CosimObserver.create_last_value()
        self.series = CosimObserver.create_time_series()
        self.override = CosimManipulator.create_override()
        assert self.execution.add_observer(self.last) and self.execution.add_observer(self.series)
        assert self.execution.add_manipulator(self.override)
        setters = {"Real": self.execution.real_initial_value,
                   "Integer": self.execution.integer_initial_value,
                   "String": self.execution.string_initial_value}
        for name, value in parameters.items():
            v = self.var[name]
            assert setters[v.type](self.index, v.valueReference, value), name
        for name in self.reals:
            assert self.series.start_time_series(self.index, self.var[name].valueReference,
                                                 CosimVariableType.REAL), name
        self.in_vr = [self.var[n].valueReference for n in inputs]

    def run(self, rows) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """Step once per input row: the real outputs' bit patterns and the integer outputs after
        every step (last-value observer), and libcosim's time after every step [ns]."""
        rvr = [self.var[n].valueReference for n in self.reals]
        ivr = [self.var[n].valueReference for n in self.ints]
        reals, ints, times = [], [], []
        for k, row in enumerate(rows):
            assert self.override.slave_real_values(self.index, self.in_vr, [float(x) for x in row])
            assert self.execution.step(), f"libcosim step {k} failed"
            times.append(self.execution.status().current_time)
            reals.append(self.last.last_real_values(self.index, rvr))
            ints.append(self.last.last_integer_values(self.index, ivr))
        return bits(np.array(reals)), np.array(ints, dtype=np.int64), times

    def samples(self, name: str, n: int):
        """libcosim's own record of ``name``: (time points [ns], step numbers, values) for steps
        0..n. (libcosimpy trims a read by the number of zero step numbers it got back, so a read
        from step 0 loses its last sample: step 0 is read alone, then steps 1..n.)"""
        vr = self.var[name].valueReference
        t0, s0, v0 = self.series.time_series_real_samples(self.index, vr, from_step=0,
                                                          sample_count=2)
        t, s, v = self.series.time_series_real_samples(self.index, vr, from_step=1,
                                                       sample_count=n)
        return list(t0) + list(t), list(s0) + list(s), np.array(list(v0) + list(v))

    def close(self):
        del self.execution, self.last, self.series, self.override, self.slave


def _step_ns(scenario) -> int:
    ns = round(scenario.step_s * 1e9)
    assert ns / 1e9 == scenario.step_s
    return ns


# ----------------------------------------------------------------------------- RailCar

@pytest.mark.parametrize("stem", STEMS)
def test_railcar_native_in_libcosim_bit_identical_to_fmpy(native, fmpy_runs, scenarios, stem):
    py, c = fmpy_runs[stem]
    sc = scenarios[stem]
    n = len(c.time) - 1
    assert n > 1000
    # fmpy: the native FMU and the pythonfmu FMU agree, and the closed loop gave both the same
    # inputs, which libcosim replays
    for name in py.signals:
        assert np.array_equal(bits(py.signals[name]), bits(c.signals[name])), name
    for name in INPUTS:
        assert np.array_equal(bits(py.inputs[name]), bits(c.inputs[name])), name
    rows = np.column_stack([c.inputs[name][:n] for name in INPUTS])
    assert np.count_nonzero(rows[:, 0]) > 100 and np.count_nonzero(rows[:, 1]) > 10

    lc = LibcosimRun(native["RailCarNative"], _step_ns(sc), sc.parameters, list(INPUTS))
    try:
        reals, ints, times = lc.run(rows)
        series = {name: lc.samples(name, n) for name in lc.reals}
    finally:
        lc.close()
    step_ns = _step_ns(sc)
    assert times == [(k + 1) * step_ns for k in range(n)]
    for j, name in enumerate(lc.reals):
        diff = np.flatnonzero(reals[:, j] != bits(c.signals[name][1:]))
        assert diff.size == 0, (f"{stem}: {name} (last value) differs from fmpy first after "
                                f"step {diff[0]}")
    for j, name in enumerate(lc.ints):
        assert np.array_equal(ints[:, j], c.signals[name][1:]), name
    # libcosim's own sampling, from the initial values on: the same time points, the same bits
    for name, (t_ns, steps, values) in series.items():
        assert steps == list(range(n + 1)), name
        assert t_ns == [k * step_ns for k in range(n + 1)], name
        diff = np.flatnonzero(bits(values) != bits(c.signals[name]))
        assert diff.size == 0, f"{stem}: {name} (time series) differs first at step {diff[0]}"
    assert len(series) >= 15 and set(lc.reals) | set(lc.ints) == set(c.signals)


def test_the_comparison_sees_one_ulp_of_one_input(native, fmpy_runs, scenarios):
    """The same libcosim run with one traction demand one ulp higher at step 200: identical up
    to that step, different after it."""
    _, c = fmpy_runs["steep_grades"]
    sc = scenarios["steep_grades"]
    n = len(c.time) - 1
    rows = np.column_stack([c.inputs[name][:n] for name in INPUTS])
    assert rows[200, 0] > 0.0
    rows[200, 0] = math.nextafter(rows[200, 0], math.inf)
    lc = LibcosimRun(native["RailCarNative"], _step_ns(sc), sc.parameters, list(INPUTS))
    try:
        reals, _, _ = lc.run(rows)
    finally:
        lc.close()
    want = np.column_stack([bits(c.signals[name][1:]) for name in lc.reals])
    assert np.array_equal(reals[:200], want[:200])
    assert not np.array_equal(reals[200:], want[200:])


# --------------------------------------------------------------------------- the estimator

@pytest.mark.parametrize("stem", STEMS)
def test_estimator_native_in_libcosim_bit_identical_to_fmpy(native, built_fmus, fmpy_runs,
                                                            scenarios, stem, tmp_path):
    """RailCarEstimatorNative fed the pythonfmu RailCar run's measurements and forces: libcosim
    equals fmpy on the same FMU and on the pythonfmu RailCarEstimator.fmu, every output after
    every step (and libcosim's time series from the initial values on).

    fmpy is given libcosim's doStep arguments, t_k = k * step_ns / 1e9 and h_k = t_k+1 - t_k
    (found by trying: k * 0.1, k * step_ns * 1e-9 or h = 0.1 give other bits). The estimator's
    filter takes the step size as the host passes it, so the harness's t_k = k * h (490 of
    etcs_noisy_sensors' 1410 times differ) gives other last bits, in both FMUs alike: checked
    below, that run differs."""
    py_run, _ = fmpy_runs[stem]
    sc = scenarios[stem]
    step_ns = _step_ns(sc)
    rows, harness_times, harness_steps = _estimator_inputs(py_run)
    n = len(rows)
    grid = np.arange(n + 1) * step_ns / 1e9                      # libcosim's doStep times
    times, steps = grid[:-1], np.diff(grid)
    assert np.count_nonzero(times != harness_times) > 100
    md = read_model_description(str(built_fmus["RailCarEstimator"]))
    own = {v.name for v in md.modelVariables if v.causality == "parameter"}
    params = {k: v for k, v in sc.parameters.items() if k in own}
    ref, names, statuses, _ = _replay(native["RailCarEstimatorNative"], tmp_path, params, rows,
                                      times, steps)
    py, py_names, py_statuses, _ = _replay(built_fmus["RailCarEstimator"], tmp_path, params,
                                           rows, times, steps)
    assert statuses == py_statuses == [OK] * n and names == py_names
    assert np.array_equal(ref, py)
    assert not np.array_equal(ref[1], ref[-1])                   # the estimates moved

    lc = LibcosimRun(native["RailCarEstimatorNative"], step_ns, params, list(EST_INPUTS))
    try:
        reals, ints, t = lc.run(rows)
        series = {name: lc.samples(name, n) for name in lc.reals}
    finally:
        lc.close()
    assert lc.reals + lc.ints == names
    got = np.hstack([reals, ints])
    diff = np.argwhere(got != ref[1:])
    assert diff.size == 0, (f"{stem}: {names[diff[0][1]]} differs from fmpy first after step "
                            f"{diff[0][0]}")
    assert t == [(k + 1) * step_ns for k in range(n)]
    for j, name in enumerate(lc.reals):
        t_ns, steps_, values = series[name]
        assert steps_ == list(range(n + 1)) and t_ns == [k * step_ns for k in range(n + 1)], name
        assert np.array_equal(bits(values), ref[:, j]), name
    # the harness's times and step sizes: another run (so the comparison above can fail)
    other, _, _, _ = _replay(native["RailCarEstimatorNative"], tmp_path / "harness_steps", params,
                             rows, harness_times, harness_steps)
    assert not np.array_equal(other, ref)


# ------------------------------------------------------------------------------------ FMI 3

PROBE = """
import sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimSlave import CosimLocalSlave
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy._internal import get_last_error_message
log_output_level(CosimLogLevel.WARNING)
for path in sys.argv[1:]:
    slave = CosimLocalSlave(fmu_path=path, instance_name="probe")
    print(path, bool(slave.ptr()), get_last_error_message(), flush=True)
execution = CosimExecution.from_step_size(100_000_000)
print("index", execution.add_local_slave(slave), flush=True)
"""


def test_libcosim_refuses_fmi3(native):
    """The FMI 2 RailCarNative.fmu loads; RailCarNative3.fmu gives a NULL slave and libcosim's
    message, and adding that slave crashes the process (libcosimpy does not check)."""
    fmu2, fmu3 = native["RailCarNative"], native["RailCarNative3"]
    proc = subprocess.run([sys.executable, "-c", PROBE, str(fmu2), str(fmu3)],
                          capture_output=True, text=True, timeout=60)
    lines = [ln for ln in proc.stdout.splitlines() if not ln.startswith("[")]   # not log lines
    assert lines[0] == f"{fmu2} True ", proc.stdout
    assert lines[1] == (f"{fmu3} False Unsupported feature: Unsupported FMI version for FMU "
                        f"'{fmu3}'"), proc.stdout
    assert len(lines) == 2 and proc.returncode == -11, (proc.returncode, proc.stdout)
