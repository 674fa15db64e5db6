"""The native RailCar FMU for FMI 3.0 (fmu_src/build/native_fmi3.py + fmu_src/c/fmi3_glue.c): the same
backend (fmu_src/c/native_railcar.c) and C core as the FMI 2 native FMU behind the FMI 3 glue,
run through fmpy's FMU3Slave and compared bit for bit with the native FMI 2 FMU (itself compared
with the pythonfmu RailCar.fmu in tests/fmu_tests/test_native_fmu.py) on every library scenario; level_run
is compared with the pythonfmu FMU here too.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import zipfile
from dataclasses import replace
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

from conftest import DISCARD, ERROR, OK, ROOT, FmuFile, LogMessage, Slave
from fmu_src.build import native, native_fmi3, toolchain
from fmu_src.variables import RAILCAR, variables_for
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario

SCENARIOS = tuple(sorted(p.stem for p in (ROOT / "scenarios" / "library").glob("*.toml")))
"""Every library scenario: FMI 3 against FMI 2 (itself bit-identical to pythonfmu on all of them)."""
INPUTS = ("traction_force_demand", "brake_force_demand", "wind_speed", "car.payload")


@pytest.fixture(scope="module")
def fmu3(native_fmus) -> Path:
    return native_fmus["RailCarNative3"]


@pytest.fixture(scope="module")
def fmu2(native_fmus) -> Path:
    return native_fmus["RailCarNative"]


class Fmi3AsFmi2:
    """An FMU3Slave under the FMU2Slave method names harness.run.runner.FmuRunner calls."""

    def __init__(self, fmu: FMU3Slave):
        self.fmu = fmu
        self.start_time, self.stop_time = 0.0, None

    def setupExperiment(self, startTime=0.0, stopTime=None, tolerance=None):
        self.start_time, self.stop_time = startTime, stopTime

    def enterInitializationMode(self):
        self.fmu.enterInitializationMode(startTime=self.start_time, stopTime=self.stop_time)

    def exitInitializationMode(self):
        self.fmu.exitInitializationMode()

    def getReal(self, vr):
        return self.fmu.getFloat64(vr)

    def setReal(self, vr, values):
        self.fmu.setFloat64(vr, values)

    def getInteger(self, vr):
        return self.fmu.getInt32(vr)

    def setInteger(self, vr, values):
        self.fmu.setInt32(vr, values)

    def getString(self, vr):
        return self.fmu.getString(vr)

    def setString(self, vr, values):
        self.fmu.setString(vr, values)

    def doStep(self, currentCommunicationPoint, communicationStepSize):
        out = self.fmu.doStep(currentCommunicationPoint, communicationStepSize)
        assert out == (False, False, False, currentCommunicationPoint + communicationStepSize)
        return out

    def reset(self):
        self.fmu.reset()

    def terminate(self):
        self.fmu.terminate()

    def freeInstance(self):
        self.fmu.freeInstance()


class _Fmi2Typed:
    """A model variable seen with its FMI 2 type name (Float64 -> Real, Int32 -> Integer)."""

    def __init__(self, var):
        self._var = var
        self.type = {"Float64": "Real", "Int32": "Integer"}.get(var.type, var.type)

    def __getattr__(self, name):
        return getattr(self._var, name)


class _Md3:
    """An FMI 3 model description with FMI 2 type names and without "time", as the FMI 2
    drivers read it."""

    def __init__(self, md):
        self._md = md
        self.modelVariables = [_Fmi2Typed(v) for v in md.modelVariables
                               if v.causality != "independent"]

    def __getattr__(self, name):
        return getattr(self._md, name)


class Slave3(Slave):
    """conftest.Slave on an FMI 3 co-simulation FMU (FMU3Slave, logging on; ``fmu``'s description
    as _Md3 gives it); ``adapter`` makes the FMI 2 face the drivers call."""

    @staticmethod
    def adapter(fmu3: FMU3Slave, fmu: FmuFile) -> "Fmi3AsFmi2":
        return Fmi3AsFmi2(fmu3)

    def __init__(self, fmu: FmuFile, instance_name: str = "instance", logging_on: bool = True):
        self.fmu_file = fmu
        self.messages: list[LogMessage] = []

        def logger(_env, status, category, message):
            self.messages.append(LogMessage(
                int(status), category.decode("utf-8", "replace") if category else None,
                message.decode("utf-8", "replace") if message else ""))

        self._callbacks = logger
        fmu3 = FMU3Slave(guid=fmu.md.guid, unzipDirectory=fmu.unzipdir,
                         modelIdentifier=fmu.md.coSimulation.modelIdentifier,
                         instanceName=instance_name)
        fmu3.instantiate(loggingOn=logging_on, logMessage=logger)
        self.fmu = self.adapter(fmu3, fmu)
        self.fatal = False
        self.freed = False
        self.time = 0.0


class Fmi3Runner(FmuRunner):
    """harness.run.runner.FmuRunner on an FMI 3 co-simulation FMU (logging on, as for FMI 2)."""

    def __init__(self, fmu_path):
        super().__init__(fmu_path)
        self.vars = {n: _Fmi2Typed(v) for n, v in self.vars.items()}

    def _new_instance(self, sink, instance_name: str):
        def logger(_env, status, category, message):
            text = message.decode(errors="replace") if message else ""
            sink().append(f"[{status}] {category.decode(errors='replace') if category else ''}: "
                          f"{text}")

        fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                        modelIdentifier=self.md.coSimulation.modelIdentifier,
                        instanceName=instance_name)
        fmu.instantiate(loggingOn=True, logMessage=logger)
        return Fmi3AsFmi2(fmu)


@pytest.fixture(scope="module")
def runners(built_fmus, fmu2, fmu3):
    rs = FmuRunner(built_fmus["RailCar"]), FmuRunner(fmu2), Fmi3Runner(fmu3)
    yield rs
    for r in rs:
        r.close()


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def not_debug(log: list[str]) -> list[str]:
    """Warnings and worse (the debug messages name the FMI version's functions)."""
    return [m for m in log if not m.startswith("[0]")]


# ------------------------------------------------------------------------------ the package

def test_validates_and_describes_railcar_in_fmi3(fmu3, fmu2):
    assert validate_fmu(str(fmu3)) == []
    md3, md2 = read_model_description(str(fmu3)), read_model_description(str(fmu2))
    assert md3.fmiVersion == "3.0" and md3.coSimulation.modelIdentifier == "RailCar"
    assert md3.guid != md2.guid
    table = variables_for(RAILCAR)
    v3 = md3.modelVariables
    assert [v.name for v in v3] == [v.name for v in md2.modelVariables] + ["time"]
    assert v3[-1].causality == "independent" and v3[-1].valueReference == len(table)
    fmi3_type = {"Real": "Float64", "Integer": "Int32", "String": "String"}
    for a, b, var in zip(v3, md2.modelVariables, table):
        assert (a.valueReference, a.causality, a.variability, a.description) == (
            b.valueReference, b.causality, b.variability, b.description), a.name
        assert a.type == fmi3_type[var.type]
        if var.causality == "output":
            assert a.initial == "calculated" and a.start is None
        else:
            conv = {"Real": float, "Integer": int, "String": str}[var.type]
            assert a.start is not None and conv(a.start) == conv(b.start) == var.start, a.name
        if var.type == "Real":
            assert a.unit == b.unit == var.unit
            assert (a.min, a.max) == (b.min, b.max)
    units = {u.name for u in md3.unitDefinitions}
    assert {v.unit for v in table if v.unit and v.type == "Real"} <= units
    outputs = [v.valueReference for v in v3 if v.causality == "output"]
    assert [u.variable.valueReference for u in md3.outputs] == outputs
    assert [u.variable.valueReference for u in md3.initialUnknowns] == outputs


def test_binary_and_sources(fmu3, tmp_path):
    with zipfile.ZipFile(fmu3) as z:
        names = z.namelist()
        z.extractall(tmp_path / "fmu")
    so = tmp_path / "fmu" / "binaries" / "x86_64-linux" / "RailCar.so"
    assert so.is_file() and not [n for n in names if "linux64" in n]
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(so)], capture_output=True,
                               text=True, check=True).stdout
    assert not [ln for ln in undefined.splitlines() if ln.split()[-1].startswith(("Py", "_Py"))]
    assert "python" not in subprocess.run(["ldd", str(so)], capture_output=True,
                                          text=True).stdout.lower()
    defined = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True,
                             text=True, check=True).stdout.split()
    for fn in ("fmi3InstantiateCoSimulation", "fmi3DoStep", "fmi3GetFloat64", "fmi3SetString",
               "fmi3EnterInitializationMode", "fmi3Reset", "fmi3FreeInstance", "fmi3GetVersion"):
        assert fn in defined, fn
    assert not [s for s in defined if s.startswith(("fmi2", "glue_", "model_", "rc_"))]
    assert not [n for n in names if n.endswith(".py")]
    # sources/ builds flat as buildDescription.xml says, with only the FMI 3 headers added
    build = ET.parse(tmp_path / "fmu" / "sources" / "buildDescription.xml").getroot()
    assert build.get("fmiVersion") == "3.0"
    listed = [f.get("name") for f in build.iter("SourceFile")]
    assert set(listed) == {p.name for p in native_fmi3.c_sources()}
    fmi3 = tmp_path / "fmi3"
    fmi3.mkdir()
    for h in ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"):
        shutil.copy(native_fmi3.fmi_headers() / h, fmi3)
    src = tmp_path / "fmu" / "sources"
    cmd = [*toolchain.find_compiler(), "-std=c99", "-O2", "-ffp-contract=off", "-fPIC",
           "-shared", "-pthread", "-Wl,--no-undefined", "-I", str(src), "-I", str(fmi3),
           *[str(src / f) for f in listed], "-o", str(tmp_path / "flat.so"), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# ---------------------------------------------------------------- bit for bit with FMI 2

@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_bit_identical_to_the_fmi2_fmus(runners, name):
    py, c2, c3 = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml")
    results = [c2.run(scenario), c3.run(scenario)]
    if name == "level_run":
        results.append(py.run(scenario))
    a = results[0]
    for b in results[1:]:
        assert np.array_equal(bits(a.time), bits(b.time))
        assert a.signals.keys() == b.signals.keys()
        for sig in a.signals:
            diff = np.flatnonzero(bits(a.signals[sig]) != bits(b.signals[sig]))
            assert diff.size == 0, (f"{name}: {sig} differs first at row {diff[0]}: "
                                    f"{a.signals[sig][diff[0]]!r} vs {b.signals[sig][diff[0]]!r}")
        assert not_debug(a.log) == not_debug(b.log)
    assert len(a.time) > 100


SLOPE_LS_CASES = [
    ("ato_speed_noise", {"est.method": 2}),
    ("ato_speed_noise", {"est.method": 2, "est.slope_window": 6}),
    ("coasting_rusich_row3", {"est.method": 2, "est.slope_window": 6, "est.physical": 1}),
    ("ato_speed_noise", {"est.method": 2, "est.sigma2_method": 1}),
]
"""est.method 2 (LS on Sidorenko's slopes): the default window, a non-default one (it must reach
the core, after the flat configuration), with est.physical 1's projection and with
est.sigma2_method 1's likelihood bank."""


@pytest.mark.parametrize("name,option", SLOPE_LS_CASES)
def test_slope_ls_bit_identical_to_the_fmi2_fmus(runners, name, option):
    """est.method 2 in the FMI 3 FMU: every output bit for bit the native FMI 2 FMU's and the
    pythonfmu FMU's."""
    py, c2, c3 = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml")
    scenario = replace(scenario, parameters={**scenario.parameters, **option})
    a = c3.run(scenario)
    for b in (c2.run(scenario), py.run(scenario)):
        assert np.array_equal(bits(a.time), bits(b.time))
        for sig in a.signals:
            diff = np.flatnonzero(bits(a.signals[sig]) != bits(b.signals[sig]))
            assert diff.size == 0, f"{name} {option}: {sig} differs first at row {diff[0]}"
    assert np.isfinite(a.signals["est.mass"]).any()


def test_slope_window_reaches_the_fmi3_core(runners):
    """The control for the comparison above: est.slope_window 6 and 10 give different
    estimates in the FMI 3 FMU."""
    _, _, c3 = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / "ato_speed_noise.toml")
    mass = [c3.run(replace(scenario, parameters={**scenario.parameters, "est.method": 2,
                                                 "est.slope_window": w})).signals["est.mass"]
            for w in (6, 10)]
    assert not np.array_equal(bits(mass[0]), bits(mass[1]))


def _drive(runner, parameters: dict, inputs, times, step: float = 0.1):
    """Outputs after initialisation and after every step (bit patterns), statuses, the log."""
    log: list[str] = []
    fmu = runner._new_instance(lambda: log, "drive")
    real = [n for n in runner.outputs if runner.vars[n].type == "Real"]
    vr_real, vr_in = [runner.vr(n) for n in real], [runner.vr(n) for n in INPUTS]
    try:
        runner.initialise(fmu, parameters, 100.0, log, "drive")
        rows, statuses = [list(bits(fmu.getReal(vr_real)))], []
        for k, t in enumerate(times):
            fmu.setReal(vr_in, inputs(k))
            try:
                fmu.doStep(currentCommunicationPoint=t, communicationStepSize=step)
                statuses.append(OK)
            except FMICallException as e:
                statuses.append(e.status)
            rows.append(list(bits(fmu.getReal(vr_real))))
    finally:
        fmu.terminate()
        fmu.freeInstance()
    return rows, statuses, not_debug(log)


def test_nan_traction_is_discarded_with_the_message_and_the_instance_goes_on(runners):
    """Step 50 (t = 5.0) has a NaN traction: discarded, logged, nothing changed; step 51 retries
    t = 5.0 with a good input and the run goes on as the FMI 2 FMU's does."""
    _, c2, c3 = runners

    def inputs(k):
        return [float("nan") if k == 50 else 20e3, 0.0, 0.0, 0.0]

    times = [0.1 * k for k in range(51)] + [0.1 * (k - 1) for k in range(51, 120)]
    a = _drive(c2, {"seed": 5}, inputs, times)
    b = _drive(c3, {"seed": 5}, inputs, times)
    assert b[1][50] == DISCARD and b[1].count(DISCARD) == 1 and b[1] == a[1]
    assert b[0][51] == b[0][50]                  # the discarded step changed nothing
    assert a[0] == b[0]
    discards = [m for m in b[2] if m.startswith(f"[{DISCARD}]")]
    assert len(discards) == 1 and "step discarded: " in discards[0]
    assert "traction_force_demand" in discards[0]
    assert b[2] == a[2]


@pytest.mark.parametrize("parameters, named", [
    ({"car.mass": -1.0}, "car.mass"),
    ({"sensor.speed_std_rel": -0.1}, "sensor.speed_std_rel"),
    ({"track.grade_profile": "no/such/file.csv"}, "track.grade_profile"),
])
def test_bad_parameter_fails_initialisation_with_the_message(runners, parameters, named):
    _, c2, c3 = runners
    texts = []
    for runner in (c2, c3):
        log: list[str] = []
        fmu = runner._new_instance(lambda: log, "bad")
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        runner.set_parameters(fmu, parameters)
        with pytest.raises(FMICallException) as e:
            fmu.exitInitializationMode()
        assert e.value.status == ERROR
        errors = [m for m in log if m.startswith(f"[{ERROR}]")]
        assert errors, log
        fmi = "fmi3" if runner is c3 else "fmi2"      # each standard's own function name
        assert f"{fmi}ExitInitializationMode: initialisation failed: " in errors[0], errors[0]
        texts.append(errors[0].split("initialisation failed: ", 1)[1]
                     .replace(str(Path(runner.unzipdir).resolve()), "<FMU>"))
        # the instance is still usable: reset, then a good initialisation and a step
        fmu.reset()
        runner.initialise(fmu, {}, 1.0, log, "good")
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.1)
        fmu.terminate()
        fmu.freeInstance()
    assert named in texts[1]
    assert texts[0] == texts[1]


@pytest.mark.parametrize("kind", [0, 4])
def test_relative_speed_noise_bit_identical_to_fmi2_and_pythonfmu(runners, kind):
    """sensor.speed_std_rel 2 %: the sensor's noise and the filter's R_v relative to the speed;
    FMI 3 == FMI 2 == the pythonfmu RailCar, every Real output after every step; and it is
    not ignored (rel = 0 gives other outputs)."""
    py, c2, c3 = runners

    def inputs(k):
        return [30e3 if k < 300 else 0.0, 0.0 if k < 500 else 20e3, 0.0, 0.0]

    times = [0.1 * k for k in range(700)]
    params = {"seed": 6, "sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.02, "filter.kind": kind}
    a, b, c = (_drive(r, params, inputs, times) for r in (c3, c2, py))
    assert a[1] == b[1] == c[1] == [OK] * len(times)
    assert a[0] == b[0] == c[0]
    assert a[2] == b[2]
    d = _drive(c3, {**params, "sensor.speed_std_rel": 0.0}, inputs, times)
    assert d[0][-1] != a[0][-1]


def test_the_comparison_sees_a_difference(runners):
    _, c2, c3 = runners

    def inputs(k):
        return [20e3, 0.0, 0.0, 0.0]

    times = [0.1 * k for k in range(20)]
    a, b = _drive(c2, {"seed": 1}, inputs, times), _drive(c3, {"seed": 2}, inputs, times)
    assert a[0][-1] != b[0][-1]


COVARIANCES = ("est.cov_A0_A1", "est.cov_A0_A2", "est.cov_A1_A2")


def test_covariance_outputs_bit_identical_to_fmi2_and_seen_to_the_ulp(runners):
    """est.cov_* (appended to the table; FMI 3's time moved after them) are among the compared
    Reals, identified (not 0) by the end, FMI 3 == FMI 2; one ulp off in any is a difference."""
    _, c2, c3 = runners

    def inputs(k):
        return [30e3 if k < 300 else 0.0, 0.0 if k < 450 else 20e3, 0.0, 0.0]

    times = [0.1 * k for k in range(600)]
    a, b = _drive(c2, {"seed": 5}, inputs, times), _drive(c3, {"seed": 5}, inputs, times)
    real = [n for n in c3.outputs if c3.vars[n].type == "Real"]
    assert real[-5:-2] == list(COVARIANCES)
    assert a[1] == b[1] == [OK] * len(times) and a[0] == b[0]
    for name in COVARIANCES:
        k = real.index(name)
        x = float(np.int64(b[0][-1][k]).view(np.float64))
        assert x != 0.0 and math.isfinite(x), name
        off = list(b[0][-1])
        off[k] = int(bits([math.nextafter(x, math.copysign(math.inf, x))])[0])
        assert a[0][-1] != off, name


FORCE_MEANS = ("car.traction_force_mean", "car.brake_force_mean")


def test_force_mean_outputs_bit_identical_to_fmi2_and_seen_to_the_ulp(runners):
    """car.*_force_mean (appended to the table last; FMI 3's time after them) are among the
    compared Reals, 0 before the first step, the demands' means later, FMI 3 == FMI 2; one ulp
    off in either is a difference."""
    _, c2, c3 = runners

    def inputs(k):
        return [25e3 if k < 100 else 0.0, 0.0 if k < 150 else 20e3, 0.0, 0.0]

    times = [0.1 * k for k in range(200)]
    a, b = _drive(c2, {"seed": 5}, inputs, times), _drive(c3, {"seed": 5}, inputs, times)
    real = [n for n in c3.outputs if c3.vars[n].type == "Real"]
    assert real[-2:] == list(FORCE_MEANS)
    assert a[1] == b[1] == [OK] * len(times) and a[0] == b[0]
    for name, row in (("car.traction_force_mean", 50), ("car.brake_force_mean", -1)):
        k = real.index(name)
        assert float(np.int64(b[0][0][k]).view(np.float64)) == 0.0, name
        x = float(np.int64(b[0][row][k]).view(np.float64))
        assert x > 1e3 and math.isfinite(x), name
        off = list(b[0][row])
        off[k] = int(bits([math.nextafter(x, math.inf)])[0])
        assert a[0][row] != off, name
