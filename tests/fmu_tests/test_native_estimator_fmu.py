"""The native RailCarEstimator FMU (issue 18, fmu_src/build/native.py + fmu_src/c/native_estimator.c):
the C core's rc_estchain behind our FMI 2.0 glue, no Python. Built once per module from the
current sources, next to a fresh pythonfmu RailCarEstimator.fmu (conftest's session build), and
compared with it bit for bit: both are fed a RailCar run's sensor outputs (library scenarios,
track-sensor speeds, station stops, spikes), every output after every step, every status and
every log line equal.
"""
from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.validation import validate_fmu

from conftest import DISCARD, ERROR, OK, ROOT, FmuFile, Slave
from fmu_src.build import native, toolchain
from fmu_src.variables import ESTIMATOR, FORMER_DEFAULTS, variables_for
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario

LIBRARY = ROOT / "scenarios" / "library"
INPUTS = native.ESTIMATOR_SPEC.inputs
PARAMETERS = {v.name for v in variables_for(ESTIMATOR) if v.causality == "parameter"}


@pytest.fixture(scope="module")
def native_fmu(native_fmus) -> Path:
    return native_fmus["RailCarEstimatorNative"]


@pytest.fixture(scope="module")
def pair(built_fmus, native_fmu, tmp_path_factory) -> dict[str, FmuFile]:
    """"py": the pythonfmu RailCarEstimator.fmu, "c": the native one."""
    out = {}
    for key, path in (("py", built_fmus["RailCarEstimator"]), ("c", native_fmu)):
        unzipdir = extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"unzip_nest_{key}")))
        out[key] = FmuFile("RailCarEstimator", path, read_model_description(str(path)), unzipdir)
    return out


@pytest.fixture(scope="module")
def railcar_runner(built_fmus):
    r = FmuRunner(built_fmus["RailCar"])
    yield r
    r.close()


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


# ------------------------------------------------------------------------------- the header

def test_both_table_headers_are_current():
    proc = subprocess.run([sys.executable, "-m", "fmu_src.build.native", "--check"], cwd=ROOT,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "native_estimator_table.h is up to date" in proc.stdout


def test_check_fails_on_a_stale_estimator_header(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "native_estimator_table.h"
    text = native.generate_estimator_header()
    assert "/* 24 */ 33,   /* filter.kind */" in text
    stale.write_text(text.replace("/* 24 */ 33,", "/* 24 */ 34,"))
    monkeypatch.setattr(native, "ESTIMATOR_TABLE_HEADER", stale)
    assert native.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert "native_estimator_table.h is out of date" in err
    assert "native_railcar_table.h" not in err


def test_the_flat_configuration_is_compiled_estimator_chains():
    """native.estimator_config_values is what CompiledEstimatorChain hands the C core (before
    est.slope_window): caught on its way to models._railcar.Estimator for random parameters."""
    from fmu_src.adapter import estimator_settings, track_settings
    from models import compiled
    from models.plant.track import GradeProfile
    caught = []

    class Spy(compiled._railcar.Estimator):
        def __init__(self, values, *rest):
            caught.append(list(values))
            super().__init__(values, *rest)

    class Capture(compiled.CompiledEstimatorChain, Spy):
        pass

    rng = np.random.default_rng(18)
    table = variables_for(ESTIMATOR)
    for _ in range(5):
        values = {v.name: v.start for v in table}
        for name in ("sensor.speed_std", "sensor.position_std", "sensor.position_std_rel",
                     "sensor.speed_std_rel",
                     "sensor.track_base", "sensor.track_resolution", "car.length",
                     "track.station_dwell", "est.forgetting", "est.gamma", "est.mass_initial",
                     "est.mass_std_initial", "est.A0_initial", "est.A1_std_initial",
                     "est.sigma2_initial", "est.run_forgetting"):
            values[name] = float(rng.uniform(0.001, 0.9)) * (100.0 if "mass" in name else 1.0)
        values["filter.kind"] = int(rng.choice([0, 2]))
        values["est.batch_size"] = int(rng.integers(10, 100))
        ident, filt, station = estimator_settings(values)
        caught.clear()
        Capture(ident, filt, station, GradeProfile.level(), None, track_settings(values))
        # the flat configuration, then est.slope_window (models/core/config.c's optional value,
        # which the native FMU appends the same way: fmu_src/c/native_common.c)
        assert caught == [[*native.estimator_config_values(values), values["est.slope_window"]]]
        # and each index is the parameter the generated table says
        sources, constants = native.config_sources(native.ESTIMATOR_SPEC)
        for k, s in enumerate(sources):
            assert s != native.CONFIG_START_TIME
            want = constants[k] if s == native.CONFIG_CONSTANT else values[table[s].name]
            assert caught[0][k] == want, (k, s)


# ------------------------------------------------------------------------------ the package

def test_binary_needs_no_python(native_fmu, tmp_path):
    with zipfile.ZipFile(native_fmu) as z:
        so = tmp_path / "RailCarEstimator.so"
        so.write_bytes(z.read("binaries/linux64/RailCarEstimator.so"))
        names = z.namelist()
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(so)], capture_output=True,
                               text=True, check=True).stdout
    python = [line for line in undefined.splitlines()
              if line.split()[-1].startswith(("Py", "_Py"))]
    assert not python, python
    ldd = subprocess.run(["ldd", str(so)], capture_output=True, text=True).stdout
    assert "python" not in ldd.lower(), ldd
    assert b"native C core backend" in so.read_bytes()
    assert not [n for n in names if n.endswith(".py") or "/models/" in n], names
    assert "sources/native_estimator.c" in names and "sources/native_railcar.c" not in names


def test_validates_and_describes_the_same_variables(native_fmu, built_fmus, tmp_path):
    assert validate_fmu(str(native_fmu)) == []
    md_c = read_model_description(str(native_fmu))
    md_py = read_model_description(str(built_fmus["RailCarEstimator"]))
    assert md_c.guid != md_py.guid
    assert md_c.coSimulation.modelIdentifier == "RailCarEstimator"
    assert ([(v.name, v.valueReference, v.type, v.causality, v.variability, v.start, v.unit)
             for v in md_c.modelVariables]
            == [(v.name, v.valueReference, v.type, v.causality, v.variability, v.start, v.unit)
                for v in md_py.modelVariables])
    listed = md_c.buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert {s.name for s in native.c_sources(native.ESTIMATOR_SPEC)} == set(listed)
    # sources/ builds flat
    with zipfile.ZipFile(native_fmu) as z:
        z.extractall(tmp_path)
    src = tmp_path / "sources"
    cmd = [*toolchain.find_compiler(), "-std=c99", "-O2", "-ffp-contract=off", "-fPIC", "-shared",
           "-pthread", "-Wl,--no-undefined", "-I", str(src), "-I", str(toolchain.fmi_headers()),
           *[str(src / f) for f in listed], "-o", str(tmp_path / "flat.so"), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# ---------------------------------------------------------------- bit for bit with pythonfmu

def _drive(fmu: FmuFile, parameters: dict, rows: np.ndarray, times: np.ndarray,
           steps: np.ndarray):
    """Outputs (bit patterns and integers) before and after initialisation and after every
    step; statuses; the log. Step k is doStep(times[k], steps[k]) with inputs rows[k] (INPUTS)."""
    reals = [v.name for v in fmu.md.modelVariables if v.causality == "output" and v.type == "Real"]
    ints = [v.name for v in fmu.md.modelVariables
            if v.causality == "output" and v.type == "Integer"]
    rvr, ivr = [fmu.vr[n] for n in reals], [fmu.vr[n] for n in ints]
    in_vr = [fmu.vr[n] for n in INPUTS]
    with Slave(fmu, "drive") as s:
        s.setup(parameters)
        out = [tuple(bits(s.fmu.getReal(rvr))) + tuple(s.fmu.getInteger(ivr))]
        assert s.exit_init() == OK, s.log_text()
        out.append(tuple(bits(s.fmu.getReal(rvr))) + tuple(s.fmu.getInteger(ivr)))
        statuses = []
        for k in range(len(rows)):
            s.fmu.setReal(in_vr, [float(x) for x in rows[k]])
            statuses.append(s.do_step(float(times[k]), float(steps[k])))
            out.append(tuple(bits(s.fmu.getReal(rvr))) + tuple(s.fmu.getInteger(ivr)))
        return out, statuses, [str(m) for m in s.messages]


def _compare(pair, parameters, rows, times, steps):
    a = _drive(pair["py"], parameters, rows, times, steps)
    b = _drive(pair["c"], parameters, rows, times, steps)
    assert a[1] == b[1]
    for k, (ra, rb) in enumerate(zip(a[0], b[0])):
        assert ra == rb, f"output row {k} differs"
    assert a[2] == b[2]
    return b


_RUNS: dict = {}


def _railcar_run(runner, stem: str, extra: dict | None = None):
    """A RailCar run of a library scenario (optionally with parameters changed), as the
    estimator's inputs: row k = the measurements at t_k and the forces applied over the step."""
    key = (stem, tuple(sorted((extra or {}).items())))
    if key not in _RUNS:
        sc = load_scenario(LIBRARY / f"{stem}.toml")
        if extra:
            sc = dataclasses.replace(sc, parameters={**sc.parameters, **extra})
        r = runner.run(sc)
        t, sig = r.time, r.signals
        rows = np.column_stack([sig["car.traction_force"][1:], sig["car.brake_force"][1:],
                                sig["sensor.speed"][:-1], sig["sensor.position"][:-1],
                                sig["sensor.track_speed"][:-1], sig["sensor.track_time"][:-1]])
        params = {n: v for n, v in sc.parameters.items() if n in PARAMETERS}
        _RUNS[key] = (params, rows, t[:-1], np.diff(t))
    return _RUNS[key]


SCENARIOS = ["station_day", "steep_grades", "etcs_noisy_sensors", "coasting_rusich_row1",
             "low_adhesion", "crush_load"]


@pytest.mark.parametrize("stem", SCENARIOS)
def test_replay_of_a_railcar_run_bit_identical(pair, railcar_runner, stem):
    params, rows, times, steps = _railcar_run(railcar_runner, stem)
    out, statuses, _ = _compare(pair, params, rows, times, steps)
    assert statuses == [OK] * len(rows)
    if stem == "station_day":
        with Slave(pair["c"], "stops") as s:
            s.initialize(params)
            in_vr = [pair["c"].vr[n] for n in INPUTS]
            for k in range(len(rows)):
                s.fmu.setReal(in_vr, [float(x) for x in rows[k]])
                assert s.do_step(float(times[k]), float(steps[k])) == OK
            assert s.get("est.station_stops") >= 3


def test_track_sensor_speeds_singer_filter_and_spikes(pair, railcar_runner):
    """Track sensors every 150 m (their speeds and time stamps are inputs), the Singer filter,
    a grade profile, and measurement spikes the innovation gate refuses (warnings)."""
    extra = {"sensor.track_spacing": 150.0, "sensor.track_jitter": 1e-3}
    params, rows, times, steps = _railcar_run(railcar_runner, "station_day", extra)
    assert np.count_nonzero(np.diff(rows[:, 5])) > 10            # new track-sensor stamps
    rows = rows.copy()
    rng = np.random.default_rng(7)
    spikes = rng.choice(np.arange(100, len(rows)), size=30, replace=False)
    rows[spikes[:15], 2] += 8.0                                   # speed spikes [m/s]
    rows[spikes[15:], 3] -= 300.0                                 # position spikes [m]
    params = {**params, "filter.kind": 4, "sensor.track_jitter": 1e-3, "car.length": 20.0,
              "sensor.position_std_rel": 0.002}
    out, statuses, log = _compare(pair, params, rows, times, steps)
    assert statuses == [OK] * len(rows)
    warnings = [m for m in log if m.startswith("[warning]")]
    assert len(warnings) >= 10 and "refused by the innovation gate" in warnings[0]


@pytest.mark.parametrize("kind", [0, 4])
def test_relative_speed_noise(pair, railcar_runner, kind):
    """sensor.speed_std_rel 2 % in the RailCar run that makes the measurements and in the
    estimator (its R_v at each measured speed), the EKF and the Singer filter, with speed spikes
    the gate refuses: the native estimator == the pythonfmu one, every output, every step."""
    extra = {"sensor.speed_std_rel": 0.02, "sensor.speed_std": 0.01}
    params, rows, times, steps = _railcar_run(railcar_runner, "station_day", extra)
    rows = rows.copy()
    rng = np.random.default_rng(17)
    rows[rng.choice(np.arange(100, len(rows)), size=10, replace=False), 2] += 8.0
    params = {**params, **extra, "filter.kind": kind}
    out, statuses, log = _compare(pair, params, rows, times, steps)
    assert statuses == [OK] * len(rows)
    assert any("refused by the innovation gate" in m for m in log)


def test_speed_profile_and_nan_free_faults(pair, railcar_runner):
    """A speed profile (linearised filter), forgetting and the carried A's drift, a stuck speed
    sensor and a position sensor that drops to zero for a while: faults without NaN, all steps OK."""
    params, rows, times, steps = _railcar_run(railcar_runner, "steep_grades")
    rows = rows.copy()
    n = len(rows)
    rows[n // 3:n // 3 + 300, 2] = rows[n // 3, 2]                # stuck speed
    rows[2 * n // 3:2 * n // 3 + 100, 3] = 0.0                    # position dropout
    params = {**params, "track.speed_profile": "profiles/default_speed.csv", "filter.kind": 0,
              "est.forgetting": 0.01, "est.run_forgetting": 0.002,
              "est.A0_drift_std": 0.04, "est.A1_drift_std": 0.03}
    _, statuses, _ = _compare(pair, params, rows, times, steps)
    assert statuses == [OK] * len(rows)


@pytest.mark.parametrize("column, value, named", [
    (2, float("nan"), "sensor.speed"),
    (3, float("inf"), "sensor.position"),
    (0, -5.0, "traction_force"),
    (1, 1e12, "brake_force"),
    (4, float("nan"), "sensor.track_speed"),
    (5, float("-inf"), "sensor.track_time"),
    (2, 1e4, "sensor.speed"),
])
def test_bad_input_is_discarded_as_python_does(pair, column, value, named):
    """Step 30 has one bad input: discarded with the same message; step 31 retries its time
    with good inputs and the run goes on identically."""
    n = 80
    rows = np.zeros((n, 6))
    rows[:, 0] = 20e3
    rows[:, 2] = np.linspace(0.0, 8.0, n)
    rows[:, 3] = np.cumsum(rows[:, 2]) * 0.1
    rows[30, column] = value
    times = np.array([0.1 * k for k in range(31)] + [0.1 * (k - 1) for k in range(31, n)])
    steps = np.full(n, 0.1)
    _, statuses, log = _compare(pair, {}, rows, times, steps)
    assert statuses[30] == DISCARD and statuses.count(DISCARD) == 1
    discards = [m for m in log if m.startswith("[discard]")]
    assert len(discards) == 1 and discards[0].startswith("[discard] step discarded: ")
    assert named in discards[0]


def test_time_that_does_not_continue_is_discarded(pair):
    n = 20
    rows = np.zeros((n, 6))
    times = np.array([0.1 * k for k in range(n)])
    times[10] += 0.5
    _, statuses, log = _compare(pair, {}, rows, times, np.full(n, 0.1))
    assert statuses[10] == DISCARD and "does not continue" in "\n".join(log)


def _init_failure(fmu: FmuFile, parameters: dict) -> tuple[int, str]:
    with Slave(fmu, "bad") as s:
        s.setup(parameters)
        status = s.exit_init()
        text = [m.message for m in s.messages if m.status == ERROR]
        assert s.reset() == OK                  # the instance stays usable
        s.initialize({})
        s.step_to(0.1)
    text = text[0].split("initialisation failed: ", 1)[1] if text else ""
    return status, text.replace(str(Path(fmu.unzipdir).resolve()), "<FMU>")


@pytest.mark.parametrize("parameters, named", [
    ({"est.mass_initial": -1.0}, "est.mass_initial"),
    ({"est.batch_size": 0}, "est.batch_size"),
    ({"est.slope_window": 0}, "est.slope_window"),
    ({"sensor.speed_std": float("nan")}, "speed_std"),   # Python says est.speed_std
    ({"sensor.track_resolution": -1.0}, "sensor.track_resolution"),
    ({"sensor.speed_std_rel": float("nan")}, "sensor.speed_std_rel"),
    ({"filter.kind": 9}, "filter.kind"),
    ({"filter.singer_p0": 0.95, "filter.kind": 4}, "filter.singer_*"),
    ({"track.station_dwell": -2.0}, "track.station_dwell"),
    ({"track.grade_profile": "no/such/file.csv"}, "track.grade_profile"),
    ({"track.grade_profile": "/dev/zero"}, "it is a device, not a regular file"),
    ({"track.speed_profile": "profiles/steep_grades.csv"}, "track.speed_profile"),
    ({"track.grade_profile": "profiles/default_speed.csv"}, "track.grade_profile"),
])
def test_bad_parameter_is_an_error_naming_it_as_python_does(pair, parameters, named):
    status_py, text_py = _init_failure(pair["py"], parameters)
    status_c, text_c = _init_failure(pair["c"], parameters)
    assert status_c == status_py == ERROR
    assert named in text_c, text_c
    assert text_c == text_py.splitlines()[0]


def test_bad_profile_file_as_python_words_it(pair, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("distance_m,grade_permille\n0,1\n5,x\n", encoding="utf-8")
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"distance_m,grade_permille\n\xff\xfe\n")
    for p in (bad, binary, tmp_path):
        status_py, text_py = _init_failure(pair["py"], {"track.grade_profile": str(p)})
        status_c, text_c = _init_failure(pair["c"], {"track.grade_profile": str(p)})
        assert status_c == status_py == ERROR
        assert text_c == text_py.splitlines()[0] and str(p) in text_c


@pytest.mark.parametrize("option", [{"est.method": 1}, {"est.method": 3}])
def test_an_option_only_python_runs_is_refused_naming_it(pair, option):
    status, text = _init_failure(pair["c"], option)
    (name, value), = option.items()
    assert status == ERROR
    assert name in text and str(value) in text and "RailCarEstimator.fmu" in text
    assert _init_failure(pair["py"], option) == (OK, "")      # Python runs it


def test_physical_runs_natively_bit_identical(pair, railcar_runner):
    """est.physical 1 (A0, A2 >= 0 by projection) in the native FMU: accepted, and a replay of
    coasting_rusich_row3, where the paper's free LS's A0 or A2 goes negative, bit for bit the
    pythonfmu FMU's, with no negative A0, A2 reported."""
    params, rows, times, steps = _railcar_run(railcar_runner, "coasting_rusich_row3")
    params = {**params, **FORMER_DEFAULTS}
    free, _, _ = _compare(pair, params, rows, times, steps)
    out, statuses, _ = _compare(pair, {**params, "est.physical": 1}, rows, times, steps)
    assert statuses == [OK] * len(rows)
    assert out != free                                     # the projection acted
    with Slave(pair["c"], "physical") as s:
        s.initialize({**params, "est.physical": 1})
        in_vr = [pair["c"].vr[n] for n in INPUTS]
        for k in range(len(rows)):
            s.fmu.setReal(in_vr, [float(x) for x in rows[k]])
            assert s.do_step(float(times[k]), float(steps[k])) == OK
            assert s.get("est.A0") >= 0.0 and s.get("est.A2") >= 0.0, k


@pytest.mark.parametrize("stem,option", [
    ("station_day", {"est.method": 2}),
    ("station_day", {"est.method": 2, "est.slope_window": 6}),
    ("coasting_rusich_row3", {"est.method": 2, "est.slope_window": 6, "est.physical": 1}),
    ("station_day", {"est.sigma2_method": 1}),
    ("station_day", {"est.method": 2, "est.sigma2_method": 1}),
])
def test_slope_ls_runs_natively_bit_identical(pair, railcar_runner, stem, option):
    """est.method 2 (LS on Sidorenko's slopes; the default window, a non-default one, and with
    est.physical 1) and est.sigma2_method 1 (the likelihood bank) in the native FMU: a replay
    bit for bit the pythonfmu FMU's."""
    params, rows, times, steps = _railcar_run(railcar_runner, stem)
    _, statuses, _ = _compare(pair, {**params, **option}, rows, times, steps)
    assert statuses == [OK] * len(rows)


def test_slope_window_reaches_the_native_core(pair, railcar_runner):
    """The control for the comparison above: the native FMU's outputs with est.slope_window 6
    and 10 differ (the parameter is what the core uses), and est.method 2's differ from 0's."""
    params, rows, times, steps = _railcar_run(railcar_runner, "station_day")
    out = {key: _drive(pair["c"], {**params, **option}, rows, times, steps)[0]
           for key, option in (("m0", {"est.method": 0}),
                               ("w10", {"est.method": 2, "est.slope_window": 10}),
                               ("w6", {"est.method": 2, "est.slope_window": 6}))}
    assert out["w6"] != out["w10"] and out["w10"] != out["m0"]


def test_not_initialised_and_outputs_before_the_first_step(pair):
    """Outputs keep their start values through initialisation (EstimatorChain has none before
    its first step); the same after a reset; strings read back."""
    for key in ("py", "c"):
        with Slave(pair[key], "starts") as s:
            s.initialize({"track.grade_profile": "profiles/steep_grades.csv"})
            assert s.get("est.mass") == 30.0 and s.get("est.samples") == 0
            assert s.get("track.grade_profile") in ("profiles/steep_grades.csv",
                                                    b"profiles/steep_grades.csv")
            s.step_to(0.1)
            assert s.get("filter.speed_std") > 0.0          # outputs after the first step
            assert s.reset() == OK
            s.initialize({})
            assert s.get("track.grade_profile") in ("", b"") and s.get("filter.speed_std") == 0.0


def test_the_comparison_sees_a_difference(pair, railcar_runner):
    """One measurement one ulp off on one side: the outputs differ (the equality above is not
    vacuous)."""
    params, rows, times, steps = _railcar_run(railcar_runner, "crush_load")
    rows, other = rows[:400], rows[:400].copy()
    other[200, 2] = math.nextafter(other[200, 2], math.inf)
    a = _drive(pair["py"], params, rows, times, steps)
    b = _drive(pair["c"], params, other, times, steps)
    assert a[0][:202] == b[0][:202] and a[0][-1] != b[0][-1]


COVARIANCES = ("est.cov_A0_A1", "est.cov_A0_A2", "est.cov_A1_A2")


def test_covariance_outputs_compared_and_seen_to_the_ulp(pair, railcar_runner):
    """est.cov_* (the A's covariances, appended to the table) are among the outputs _drive
    compares, identified (not 0) by the end and bit-identical; one ulp off in any is a difference."""
    params, rows, times, steps = _railcar_run(railcar_runner, "crush_load")
    a = _drive(pair["py"], params, rows[:600], times, steps)
    b = _drive(pair["c"], params, rows[:600], times, steps)
    assert a[0] == b[0] and a[1] == b[1] == [OK] * 600
    reals = [v.name for v in pair["c"].md.modelVariables
             if v.causality == "output" and v.type == "Real"]
    assert reals[-3:] == list(COVARIANCES)           # the table's end: earlier vrs unchanged
    for name in COVARIANCES:
        k = reals.index(name)
        x = float(np.int64(b[0][-1][k]).view(np.float64))
        assert x != 0.0 and math.isfinite(x), name
        off = list(b[0][-1])
        off[k] = int(bits([math.nextafter(x, math.copysign(math.inf, x))])[0])
        assert tuple(a[0][-1]) != tuple(off), name

