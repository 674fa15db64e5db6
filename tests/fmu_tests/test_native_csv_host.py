"""Our own C FMI host (tests/fmu_cases/csv_host.c: dlopen, FMI 2.0 and FMI 3.0 co-simulation,
inputs from a CSV file, outputs to a CSV file, no Python in its process) runs the native FMUs of
the session build (conftest's built_fmus: <dist>/native/*.fmu) and must reproduce the pythonfmu
FMUs bit for bit:

- RailCar: every library scenario is run closed loop through the pythonfmu RailCar.fmu with
  harness.run.runner.FmuRunner, which records the inputs it actually sent at each step
  (RunResult.inputs, held over [t_k, t_k+1]); those inputs are replayed open loop through the host
  on RailCarNative.fmu (FMI 2) and RailCarNative3.fmu (FMI 3), doStep(k h, h) as the runner did,
  and every output at every communication point must have the runner's float64 bits;
- RailCarEstimator: each of those runs' forces and sensor outputs (as
  tests/fmu_tests/test_native_estimator_fmu.py builds them, over all 12 library scenarios, a superset of its
  six) replayed through RailCarEstimatorNative(.fmu / 3.fmu) in the host (step sizes t_k+1 - t_k,
  the host's variable-step mode) against the pythonfmu RailCarEstimator.fmu driven through fmpy.

Also: the host holds no Python (its ELF needs and symbols, and at run time the dynamic loader's
list of what it loaded); one input one ulp off is seen; a NaN traction is discarded naming the
variable and retried with the last accepted inputs (the host's documented -d hold policy), equal
to the pythonfmu FMU driven through the same calls; bad PARAMS/INPUTS lines, a wrong binary, a
wrong GUID and a bad parameter value are refused with the file and line or the FMU's message.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import DISCARD, OK, ROOT, Slave
from csv_host_cases import (NativeFmu, assert_same, bits, compile_host, run_host, write_inputs,
                            write_params)
from fmu_src.build import native, native_fmi3, toolchain
from fmu_src.variables import ESTIMATOR, variables_for
from harness.run.runner import INPUTS as RAILCAR_INPUTS
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario

LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))
STEMS = [p.stem for p in LIBRARY]
EST_INPUTS = list(native.ESTIMATOR_SPEC.inputs)
EST_PARAMETERS = {v.name for v in variables_for(ESTIMATOR) if v.causality == "parameter"}
# the innovation gate refuses measurements when the sensors are far better than the process
# noise the estimator assumes (as tests/fmu_tests/test_native_fmu.py's gate test): warnings every step
GATE = {"car.process_noise_psd": 1.0, "est.sigma2_initial": 1e-12, "sensor.speed_std": 1e-4,
        "sensor.position_std": 1e-3}


# ------------------------------------------------------------------------------ fixtures

@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    compiler = toolchain.find_compiler()
    assert compiler, "no C compiler"
    return compile_host(compiler, native_fmi3.fmi_headers(),
                        tmp_path_factory.mktemp("csv_host") / "csv_host")


@pytest.fixture(scope="module")
def natives(built_fmus, tmp_path_factory) -> dict:
    """(model, FMI version) -> the session build's native FMU, unpacked."""
    folder = built_fmus["RailCar"].parent / "native"
    out = {}
    for model in ("RailCar", "RailCarEstimator"):
        for version, suffix in ((2, ""), (3, "3")):
            name = f"{model}Native{suffix}"
            fmu = NativeFmu.unpack(folder / f"{name}.fmu", tmp_path_factory.mktemp(name))
            assert fmu.version == version
            out[model, version] = fmu
    return out


class RailCarRuns:
    """Closed-loop pythonfmu RailCar runs of the library scenarios, each run once per module."""

    def __init__(self, fmu_path: Path):
        self.runner = FmuRunner(fmu_path)
        self.cache: dict = {}

    def __call__(self, stem: str, extra: dict | None = None):
        key = (stem, tuple(sorted((extra or {}).items())))
        if key not in self.cache:
            sc = load_scenario(ROOT / "scenarios" / "library" / f"{stem}.toml")
            if extra:
                sc = dataclasses.replace(sc, parameters={**sc.parameters, **extra})
            self.cache[key] = (sc, self.runner.run(sc))
        return self.cache[key]


@pytest.fixture(scope="module")
def railcar_runs(built_fmus):
    runs = RailCarRuns(built_fmus["RailCar"])
    yield runs
    runs.runner.close()


def replay_inputs(sc, ref):
    """The runner's communication points k h and the inputs it sent over each step (exactly)."""
    n = len(ref.time) - 1
    h = sc.step_s
    times = np.array([k * h for k in range(n)])
    # the runner's own time column is (k + 1) h after step k: its first n entries are these
    assert np.array_equal(bits(ref.time[:-1]), bits(times))
    rows = np.column_stack([ref.inputs[name][:n] for name in RAILCAR_INPUTS])
    return times, rows


def warning_texts(log: list[str]) -> list[str]:
    """FmuRunner's log lines "[status] category: text" of Warning status, the text."""
    return [line.split(": ", 1)[1] for line in log if line.startswith("[1] ")]


def drive(fmu_file, parameters: dict, names: list[str], times, steps, rows, outputs: list[str],
          retry_rows=None):
    """The pythonfmu FMU through fmpy (conftest's Slave): outputs after initialisation and after
    every step (doStep(times[k], steps[k]) with rows[k]); a discarded step k is retried once with
    retry_rows[k] (the host's -d hold). Returns (outputs by name, statuses, discard messages)."""
    vr = fmu_file.vr
    in_vr = [vr[n] for n in names]
    reals = [n for n in outputs if fmu_file.variables[n].type == "Real"]
    ints = [n for n in outputs if fmu_file.variables[n].type == "Integer"]
    got_r, got_i, statuses = [], [], []
    with Slave(fmu_file, "reference") as s:
        s.initialize(parameters)
        got_r.append(s.fmu.getReal([vr[n] for n in reals]))
        got_i.append(s.fmu.getInteger([vr[n] for n in ints]))
        for k in range(len(rows)):
            s.fmu.setReal(in_vr, [float(x) for x in rows[k]])
            status = s.do_step(float(times[k]), float(steps[k]))
            statuses.append(status)
            if status == DISCARD and retry_rows is not None:
                s.fmu.setReal(in_vr, [float(x) for x in retry_rows[k]])
                status = s.do_step(float(times[k]), float(steps[k]))
            assert status == OK, s.log_text()
            got_r.append(s.fmu.getReal([vr[n] for n in reals]))
            got_i.append(s.fmu.getInteger([vr[n] for n in ints]))
        discards = [m.message for m in s.messages if m.status == DISCARD]
    r, i = np.array(got_r), np.array(got_i, dtype=np.int64)
    out = {n: r[:, j] for j, n in enumerate(reals)}
    out.update({n: i[:, j] for j, n in enumerate(ints)})
    return {n: out[n] for n in outputs}, statuses, discards


def railcar_case(tmp_path: Path, fmu: NativeFmu, sc, times, rows, name: str = "in"):
    params = write_params(tmp_path / "params.csv", fmu, sc.parameters)
    inputs = write_inputs(tmp_path / f"{name}.csv", fmu, RAILCAR_INPUTS, times, rows)
    return params, inputs


# ---------------------------------------------------------------------- no Python in the host

def test_the_host_holds_no_python(host, natives, railcar_runs, tmp_path):
    """Its ELF needs libc (and libdl) only and imports no Py symbol; at run time (FMI 2 and 3)
    the dynamic loader lists every object it loads (LD_DEBUG=files): the FMU's binary, no
    libpython."""
    dynamic = subprocess.run(["readelf", "-d", str(host)], capture_output=True, text=True,
                             check=True).stdout
    needed = [line.split("[", 1)[1].rstrip("]") for line in dynamic.splitlines()
              if "(NEEDED)" in line]
    assert needed and set(needed) <= {"libc.so.6", "libdl.so.2"}, needed
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(host)], capture_output=True,
                               text=True, check=True).stdout.split()
    assert "dlopen" in " ".join(undefined)
    assert not [s for s in undefined if s.startswith(("Py", "_Py"))]
    ldd = subprocess.run(["ldd", str(host)], capture_output=True, text=True).stdout
    assert "python" not in ldd.lower(), ldd

    sc, ref = railcar_runs("level_run")
    times, rows = replay_inputs(sc, ref)
    for version in (2, 3):
        fmu = natives["RailCar", version]
        params, inputs = railcar_case(tmp_path, fmu, sc, times[:50], rows[:50])
        env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "LD_"))}
        env["LD_DEBUG"] = "files"
        run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", ["car.speed"],
                       step=sc.step_s, env=env)
        assert run.returncode == 0, run.stderr
        loaded = [line.split("file=", 1)[1].split()[0] for line in run.stderr.splitlines()
                  if "file=" in line]
        assert str(fmu.binary) in loaded, loaded
        assert not [f for f in loaded if "python" in f.lower()], loaded
        assert len(run.time) == 51


# ---------------------------------------------------- RailCar: library scenarios bit for bit

@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("stem", STEMS)
def test_library_scenario_replayed_bit_identical(host, natives, railcar_runs, tmp_path, stem,
                                                 version):
    sc, ref = railcar_runs(stem)
    fmu = natives["RailCar", version]
    times, rows = replay_inputs(sc, ref)
    params, inputs = railcar_case(tmp_path, fmu, sc, times, rows)
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", fmu.outputs,
                   step=sc.step_s, stop=sc.duration_s)
    assert run.returncode == 0, run.stderr
    assert np.array_equal(run.status, np.zeros(len(times) + 1))
    # the communication points: the start, then t_k + h (FMI 3: the FMU's lastSuccessfulTime)
    assert np.array_equal(bits(run.time), bits([0.0] + [t + sc.step_s for t in times]))
    assert_same({n: ref.signals[n] for n in fmu.outputs}, run.columns, f"{stem} FMI {version}")
    assert run.messages("Warning") == warning_texts(ref.log) == []


@pytest.mark.parametrize("version", [2, 3])
def test_gate_warnings_reported_as_the_pythonfmu_fmu_logs_them(host, natives, railcar_runs,
                                                               tmp_path, version):
    """Many innovation-gate warnings (OK steps): the outputs and each warning's text as the
    pythonfmu FMU gave them, the status column says OK (the steps returned OK)."""
    sc, ref = railcar_runs("level_run", GATE)
    fmu = natives["RailCar", version]
    times, rows = replay_inputs(sc, ref)
    params, inputs = railcar_case(tmp_path, fmu, sc, times, rows)
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", fmu.outputs,
                   step=sc.step_s, stop=sc.duration_s)
    assert run.returncode == 0, run.stderr
    assert_same({n: ref.signals[n] for n in fmu.outputs}, run.columns, f"gate FMI {version}")
    expected = warning_texts(ref.log)
    assert len(expected) > 10 and "refused by the innovation gate" in expected[0]
    assert run.messages("Warning") == expected
    assert f"{len(expected)} warning(s), 0 discarded step(s), 0 error(s)" in run.stderr
    quiet = run_host(host, fmu, params, inputs, tmp_path / "quiet.csv", fmu.outputs,
                     step=sc.step_s, stop=sc.duration_s, options=("-q",))
    assert quiet.returncode == 0 and quiet.stderr == ""             # -q: no warnings, no summary
    assert_same(run.columns, quiet.columns, "-q")


# ---------------------------------------------- RailCarEstimator: replays bit for bit

class EstimatorCase:
    """A RailCar run's forces and sensor outputs as the estimator's inputs (row k: the
    measurements at t_k and the forces applied over [t_k, t_k+1], as in
    tests/fmu_tests/test_native_estimator_fmu.py), and the pythonfmu estimator's outputs for them."""

    def __init__(self, sc, ref, estimator):
        t, sig = ref.time, ref.signals
        self.rows = np.column_stack([sig["car.traction_force"][1:], sig["car.brake_force"][1:],
                                     sig["sensor.speed"][:-1], sig["sensor.position"][:-1],
                                     sig["sensor.track_speed"][:-1], sig["sensor.track_time"][:-1]])
        self.times, self.steps, self.stop = t[:-1], np.diff(t), float(t[-1])
        self.params = {n: v for n, v in sc.parameters.items() if n in EST_PARAMETERS}
        outputs = [v.name for v in estimator.md.modelVariables if v.causality == "output"]
        self.expected, self.statuses, _ = drive(estimator, self.params, EST_INPUTS, self.times,
                                                self.steps, self.rows, outputs)


@pytest.fixture(scope="module")
def estimator_cases(railcar_runs, estimator):
    cache: dict = {}

    def get(stem: str) -> EstimatorCase:
        if stem not in cache:
            cache[stem] = EstimatorCase(*railcar_runs(stem), estimator)
        return cache[stem]
    return get


def run_estimator(host, fmu: NativeFmu, case: EstimatorCase, tmp_path: Path, rows=None):
    params = write_params(tmp_path / "est_params.csv", fmu, case.params)
    inputs = write_inputs(tmp_path / "est_in.csv", fmu, EST_INPUTS, case.times,
                          case.rows if rows is None else rows)
    return run_host(host, fmu, params, inputs, tmp_path / "est_out.csv", fmu.outputs,
                    stop=case.stop)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("stem", STEMS)
def test_estimator_replay_bit_identical(host, natives, estimator_cases, tmp_path, stem, version):
    case = estimator_cases(stem)
    fmu = natives["RailCarEstimator", version]
    assert list(case.expected) == fmu.outputs
    run = run_estimator(host, fmu, case, tmp_path)
    assert case.statuses == [OK] * len(case.rows)
    assert run.returncode == 0, run.stderr
    assert np.array_equal(run.status, np.zeros(len(case.rows) + 1))
    # variable steps: h_k = t_k+1 - t_k (np.diff's doubles), the last one ending at -e t_end
    assert np.array_equal(bits(run.time), bits([0.0] + list(case.times + case.steps)))
    assert_same(case.expected, run.columns, f"estimator {stem} FMI {version}")
    if stem == "station_day":
        assert run.columns["est.station_stops"][-1] >= 3


# ---------------------------------------------------------- the comparison can fail

def test_one_ulp_on_one_input_is_seen(host, natives, railcar_runs, estimator_cases, tmp_path):
    """One traction demand (RailCar) and one measured speed (estimator) one ulp off: some output
    differs, and the comparison above says so."""
    sc, ref = railcar_runs("level_run")
    times, rows = replay_inputs(sc, ref)
    rows = rows.copy()
    k = 5
    assert rows[k, 0] == 40e3                 # full traction, applied as asked at low speed
    rows[k, 0] = np.nextafter(rows[k, 0], 0.0)
    fmu = natives["RailCar", 2]
    params, inputs = railcar_case(tmp_path, fmu, sc, times, rows)
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", fmu.outputs,
                   step=sc.step_s, stop=sc.duration_s)
    assert run.returncode == 0, run.stderr
    with pytest.raises(AssertionError, match="differs"):
        assert_same({n: ref.signals[n] for n in fmu.outputs}, run.columns, "one ulp")
    # the force applied over that step is the demand, one ulp below the reference's
    applied = run.columns["car.traction_force"][k + 1]
    assert applied == rows[k, 0] < ref.signals["car.traction_force"][k + 1]

    case = estimator_cases("steep_grades")
    est_rows = case.rows.copy()
    est_rows[200, 2] = np.nextafter(est_rows[200, 2], np.inf)
    run = run_estimator(host, natives["RailCarEstimator", 3], case, tmp_path, est_rows)
    assert run.returncode == 0, run.stderr
    with pytest.raises(AssertionError, match="differs"):
        assert_same(case.expected, run.columns, "one ulp")


# ------------------------------------------------------------ bad inputs through the host

@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("bad", [(50,), (0,), (50, 51)], ids=["row50", "row0", "rows50-51"])
def test_nan_traction_is_discarded_and_retried_with_held_inputs(host, natives, railcar_runs,
                                                                railcar, tmp_path, bad, version):
    """NaN traction in rows `bad`: each such step is discarded with the message naming
    traction_force_demand and the file line, and retried over the same interval with the last
    accepted row's inputs (before any row: the FMU's start values, read after initialisation);
    the run goes on with the next row. Exit status 1, status 2 in those rows; the outputs equal a
    clean run whose bad rows hold those inputs, and the pythonfmu FMU driven through the same
    calls (discard, then the retry)."""
    sc, ref = railcar_runs("level_run")
    times, rows = replay_inputs(sc, ref)
    n = 120
    times, rows = times[:n], rows[:n].copy()
    held = rows.copy()
    start_values = [float(railcar.variables[name].start) for name in RAILCAR_INPUTS]
    for k in bad:
        rows[k, 0] = np.nan
        held[k] = held[k - 1] if k > 0 else start_values
    fmu = natives["RailCar", version]
    params, inputs = railcar_case(tmp_path, fmu, sc, times, rows, "nan")
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", fmu.outputs, step=sc.step_s)
    assert run.returncode == 1, run.stderr
    want_status = np.zeros(n + 1)
    want_status[[k + 1 for k in bad]] = 2
    assert np.array_equal(run.status, want_status)
    discards = run.messages("Discard")
    assert len(discards) == len(bad)
    for k, text in zip(bad, discards):
        assert text.startswith("step discarded: ") and "traction_force_demand" in text
        assert f"{inputs}:{k + 2} (t = " in run.stderr          # header is line 1, row k line k+2
        held_from = (f"with the inputs of {inputs}:{bad[0] + 1}" if bad[0] > 0
                     else "with the inputs the FMU had after initialisation")
        assert f"{inputs}:{k + 2} (t = {times[k]:.17g}): retried from" in run.stderr
        assert held_from in run.stderr
    assert f"{len(bad)} discarded step(s), 0 error(s); exit status 1" in run.stderr

    clean_inputs = write_inputs(tmp_path / "held.csv", fmu, RAILCAR_INPUTS, times, held)
    clean = run_host(host, fmu, params, clean_inputs, tmp_path / "clean.csv", fmu.outputs,
                     step=sc.step_s)
    assert clean.returncode == 0, clean.stderr
    assert np.array_equal(bits(run.time), bits(clean.time))
    assert_same(clean.columns, run.columns, "held retry vs clean run")

    expected, statuses, py_discards = drive(railcar, sc.parameters, list(RAILCAR_INPUTS), times,
                                            np.full(n, sc.step_s), rows, fmu.outputs, held)
    assert [k for k, s in enumerate(statuses) if s == DISCARD] == list(bad)
    assert_same(expected, run.columns, "host vs pythonfmu, same calls")
    assert py_discards == discards


def test_discard_policy_stop_ends_the_run(host, natives, railcar_runs, tmp_path):
    sc, ref = railcar_runs("level_run")
    times, rows = replay_inputs(sc, ref)
    rows = rows[:80].copy()
    rows[30, 0] = np.nan
    fmu = natives["RailCar", 3]
    params, inputs = railcar_case(tmp_path, fmu, sc, times[:80], rows)
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", ["car.speed"],
                   step=sc.step_s, options=("-d", "stop"))
    assert run.returncode == 2, run.stderr
    assert len(run.time) == 31                    # the start and rows 0..29
    assert "fmi3DoStep returned Discard: step discarded: traction_force_demand" in run.stderr
    assert f"{inputs}:32 (t = {times[30]:.17g}): stopped (-d stop)" in run.stderr


PARAMS_HEADER = "vr,type,value\n"


@pytest.mark.parametrize("text, line, says", [
    (PARAMS_HEADER + "4,real,34.0\n5,rea,1.0\n", 3,
     'type "rea" is not real, integer, boolean or string'),
    (PARAMS_HEADER + "4,real,34.0x\n", 2, '"34.0x" is not a valid real value'),
    (PARAMS_HEADER + "4,real,1e999\n", 2, '"1e999" is not a valid real value'),
    (PARAMS_HEADER + "\n4,real,34.0\n27,integer,2147483648\n", 4,
     '"2147483648" is not a valid integer value'),
    (PARAMS_HEADER + "r4,real,34.0\n", 2, '"r4" is not a value reference'),
    (PARAMS_HEADER + "4;real;34.0\n", 2, 'expected "vr,type,value"'),
    (PARAMS_HEADER + '43,string,"profiles/a"b.csv"\n', 2, "a quoted string must end the line"),
    ("vr,typ,value\n4,real,34.0\n", 1, 'the header must be "vr,type,value"'),
])
def test_a_bad_params_line_is_refused_naming_file_and_line(host, natives, tmp_path, text, line,
                                                           says):
    fmu = natives["RailCar", 2]
    params = tmp_path / "params.csv"
    params.write_text(text)
    inputs = write_inputs(tmp_path / "in.csv", fmu, RAILCAR_INPUTS, [0.0], [[0.0] * 4])
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", ["car.speed"], step=0.1)
    assert run.returncode == 3
    assert f"csv_host: {params}:{line}: {says}" in run.stderr, run.stderr
    assert not (tmp_path / "out.csv").exists()       # nothing ran: no output file


@pytest.mark.parametrize("text, line, says", [
    ("time [s],0,1\n0,1,2\n0.1,1\n", 3, "2 fields, the header has 3"),
    ("time [s],0,1\n0,1,2\n0.1,1,2,3\n", 3, "4 fields, the header has 3"),
    ("time [s],0,1\n0,1,2\n0,1,2\n", 3, "time 0 does not follow 0 (line 2): times must increase"),
    ("time [s],0,1\n0,1,2\nnan,1,2\n", 3, 'time "nan" is not a finite number'),
    ("time [s],0,1\r\n0,1,2\r\n0.1,1,two\r\n", 3,
     'column 3 (vr 1): "two" is not a valid real value'),
    ("time [s],0,x1\n0,1,2\n", 1, 'column 3: "x1" is not an input value reference'),
    ("time [s],0,0\n0,1,2\n", 1, "value reference 0 in columns 2 and 3"),
    ("t,0\n0,1\n", 1, 'the first column must be "time [s]", not "t"'),
])
def test_a_bad_inputs_line_is_refused_naming_file_and_line(host, natives, tmp_path, text, line,
                                                           says):
    fmu = natives["RailCar", 3]
    params = write_params(tmp_path / "params.csv", fmu, {})
    inputs = tmp_path / "in.csv"
    inputs.write_bytes(text.encode())
    run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", ["car.speed"], step=0.1)
    assert run.returncode == 3
    assert f"csv_host: {inputs}:{line}: {says}" in run.stderr, run.stderr
    assert not (tmp_path / "out.csv").exists()


def test_wrong_binary_guid_and_parameter_are_refused(host, natives, tmp_path):
    """An FMI 2 binary run as FMI 3 (missing symbols, each named); a GUID that is not the FMU's
    (fmi2Instantiate fails with the FMU's message); a bad parameter value (initialisation fails
    with the FMU's message naming it, exit status 2)."""
    fmu2, fmu3 = natives["RailCar", 2], natives["RailCar", 3]
    inputs = write_inputs(tmp_path / "in.csv", fmu2, RAILCAR_INPUTS, [0.0], [[0.0] * 4])
    params = write_params(tmp_path / "params.csv", fmu2, {})
    as_fmi3 = dataclasses.replace(fmu3, binary=fmu2.binary)
    run = run_host(host, as_fmi3, params, inputs, tmp_path / "out.csv", ["car.speed"], step=0.1)
    assert run.returncode == 3
    assert f"csv_host: {fmu2.binary}: no symbol fmi3InstantiateCoSimulation" in run.stderr
    assert f"{fmu2.binary}: 14 FMI 3.0 co-simulation function(s) missing" in run.stderr

    wrong = dataclasses.replace(fmu2, token="{00000000-0000-0000-0000-000000000000}")
    run = run_host(host, wrong, params, inputs, tmp_path / "out.csv", ["car.speed"], step=0.1)
    assert run.returncode == 2
    assert "fmi2Instantiate returned Error: " in run.stderr and fmu2.token in run.stderr
    assert not (tmp_path / "out.csv").exists()

    for fmu in (fmu2, fmu3):
        params = write_params(tmp_path / "bad.csv", fmu, {"car.mass": -1.0})
        run = run_host(host, fmu, params, inputs, tmp_path / "out.csv", ["car.speed"], step=0.1)
        assert run.returncode == 2
        errors = run.messages("Error")
        assert len(errors) == 1 and "initialisation failed: " in errors[0], run.stderr
        assert "car.mass" in errors[0].split("initialisation failed: ", 1)[1]
        assert f"fmi{fmu.version}ExitInitializationMode returned Error" in run.stderr


def test_resources_in_a_folder_with_a_space_and_percent(host, natives, railcar_runs, tmp_path):
    """The resources/ folder under a path with ' ' and '%' (FMI 2: percent-encoded into the
    file: URI; FMI 3: the plain path) and a grade profile named relative to it: the same outputs
    as the scenario's absolute profile path."""
    sc, ref = railcar_runs("steep_grades")
    times, rows = replay_inputs(sc, ref)
    times, rows = times[:400], rows[:400]
    assert Path(sc.parameters["track.grade_profile"]).name == "steep_grades.csv"
    for version in (2, 3):
        fmu = natives["RailCar", version]
        moved_root = tmp_path / f"a b%20c {version}"
        shutil.copytree(fmu.root, moved_root)
        moved = dataclasses.replace(
            fmu, root=moved_root, binary=moved_root / fmu.binary.relative_to(fmu.root),
            resources=moved_root / "resources")
        relative = {**sc.parameters, "track.grade_profile": "profiles/steep_grades.csv"}
        a_params = write_params(tmp_path / "abs.csv", fmu, sc.parameters)
        b_params = write_params(tmp_path / "rel.csv", fmu, relative)
        inputs = write_inputs(tmp_path / "in.csv", fmu, RAILCAR_INPUTS, times, rows)
        a = run_host(host, fmu, a_params, inputs, tmp_path / "a.csv", fmu.outputs, step=sc.step_s)
        b = run_host(host, moved, b_params, inputs, tmp_path / "b.csv", fmu.outputs,
                     step=sc.step_s)
        assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
        assert_same(a.columns, b.columns, f"moved FMI {version}")
        assert np.any(a.columns["car.grade"] != 0.0)
        assert_same({n: ref.signals[n][:401] for n in fmu.outputs}, a.columns, "steep_grades")
