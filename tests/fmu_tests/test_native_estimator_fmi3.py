"""The native RailCarEstimator FMU for FMI 3.0 (fmu_src/build/native_fmi3.py, ESTIMATOR_SPEC): the
backend of the native FMI 2 RailCarEstimator (fmu_src/c/native_estimator.c) behind the FMI 3
glue, run through fmpy's FMU3Slave and compared bit for bit with the native FMI 2 FMU (itself
compared with the pythonfmu RailCarEstimator.fmu in tests/fmu_tests/test_native_estimator_fmu.py).

The drivers are tests/fmu_tests/test_native_estimator_fmu.py's (_drive, _railcar_run, _init_failure and
its fixtures): its ``Slave`` is swapped, for these tests only, for one that opens an FMI 3 FMU
through FMU3Slave (test_native_fmi3.Fmi3AsFmi2 under conftest.Slave's methods).
"""
from __future__ import annotations

import math
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.validation import validate_fmu

import test_native_estimator_fmu as est2
from conftest import DISCARD, ERROR, OK, ROOT, FmuFile, Slave
from fmu_src.build import native_fmi3
from fmu_src.variables import ESTIMATOR, variables_for
from test_native_estimator_fmu import native_fmu, railcar_runner  # noqa: F401  (fixtures)
from test_native_fmi3 import Slave3, _Md3

SCENARIOS = tuple(sorted(p.stem for p in (ROOT / "scenarios" / "library").glob("*.toml")))


def _any_slave(fmu: FmuFile, *args, **kwargs) -> Slave:
    return (Slave3 if fmu.md.fmiVersion == "3.0" else Slave)(fmu, *args, **kwargs)


@pytest.fixture(autouse=True)
def fmi3_aware_drivers(monkeypatch):
    """test_native_estimator_fmu's drivers open FMI 3 FMUs with Slave3 (these tests only)."""
    monkeypatch.setattr(est2, "Slave", _any_slave)


@pytest.fixture(scope="module")
def fmu3(native_fmus) -> Path:
    return native_fmus["RailCarEstimatorNative3"]


@pytest.fixture(scope="module")
def pair(native_fmu, fmu3, tmp_path_factory) -> dict[str, FmuFile]:  # noqa: F811
    """"c2": the native FMI 2 RailCarEstimator, "c3": the FMI 3 one."""
    out = {}
    for key, path in (("c2", native_fmu), ("c3", fmu3)):
        unzipdir = extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"unzip_e3_{key}")))
        md = read_model_description(str(path))
        out[key] = FmuFile("RailCarEstimator", path, _Md3(md) if key == "c3" else md, unzipdir)
    return out


def not_debug(log: list[str]) -> list[str]:
    """Warnings and worse (the debug messages name the FMI version's functions)."""
    return [m for m in log if not m.startswith("[ok]")]


def _compare(pair, parameters, rows, times, steps):
    a = est2._drive(pair["c2"], parameters, rows, times, steps)
    b = est2._drive(pair["c3"], parameters, rows, times, steps)
    assert a[1] == b[1]
    assert len(a[0]) == len(b[0]) == len(rows) + 2
    for k, (ra, rb) in enumerate(zip(a[0], b[0])):
        assert ra == rb, f"output row {k} differs"
    assert not_debug(a[2]) == not_debug(b[2])
    return b[0], b[1], not_debug(b[2])


# ------------------------------------------------------------------------------ the package

def test_validates_and_describes_the_estimator_in_fmi3(fmu3, native_fmu):  # noqa: F811
    assert validate_fmu(str(fmu3)) == []
    md3, md2 = read_model_description(str(fmu3)), read_model_description(str(native_fmu))
    assert md3.fmiVersion == "3.0" and md3.coSimulation.modelIdentifier == "RailCarEstimator"
    assert md3.modelName == "RailCarEstimator" and md3.guid != md2.guid
    table = variables_for(ESTIMATOR)
    v3 = md3.modelVariables
    assert [v.name for v in v3] == [v.name for v in md2.modelVariables] + ["time"]
    assert v3[-1].causality == "independent" and v3[-1].valueReference == len(table)
    fmi3_type = {"Real": "Float64", "Integer": "Int32", "String": "String"}
    for a, b, var in zip(v3, md2.modelVariables, table):
        assert (a.valueReference, a.causality, a.variability) == (
            b.valueReference, b.causality, b.variability), a.name
        assert a.type == fmi3_type[var.type]
        if var.causality == "output":
            assert a.initial == "calculated" and a.start is None
        if var.type == "Real":
            assert a.unit == b.unit == var.unit
    outputs = [v.valueReference for v in v3 if v.causality == "output"]
    assert [u.variable.valueReference for u in md3.outputs] == outputs


def test_binary_needs_no_python(fmu3, tmp_path):
    with zipfile.ZipFile(fmu3) as z:
        names = z.namelist()
        so = tmp_path / "RailCarEstimator.so"
        so.write_bytes(z.read("binaries/x86_64-linux/RailCarEstimator.so"))
        listed = z.read("sources/buildDescription.xml").decode()
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(so)], capture_output=True,
                               text=True, check=True).stdout
    assert not [ln for ln in undefined.splitlines() if ln.split()[-1].startswith(("Py", "_Py"))]
    assert "python" not in subprocess.run(["ldd", str(so)], capture_output=True,
                                          text=True).stdout.lower()
    defined = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True,
                             text=True, check=True).stdout.split()
    assert "fmi3InstantiateCoSimulation" in defined and "fmi3DoStep" in defined
    assert not [s for s in defined if s.startswith(("fmi2", "glue_", "model_", "rc_"))]
    assert not [n for n in names if n.endswith(".py") or "linux64" in n]
    assert "sources/native_estimator.c" in names and "sources/native_railcar.c" not in names
    assert 'modelIdentifier="RailCarEstimator"' in listed
    assert "resources/profiles/steep_grades.csv" in names


# ---------------------------------------------------------------- bit for bit with FMI 2

@pytest.mark.parametrize("stem", SCENARIOS)
def test_replay_of_a_railcar_run_bit_identical_to_fmi2(pair, railcar_runner, stem):  # noqa: F811
    params, rows, times, steps = est2._railcar_run(railcar_runner, stem)
    out, statuses, _ = _compare(pair, params, rows, times, steps)
    assert statuses == [OK] * len(rows) and len(rows) > 100
    assert out[-1] != out[1]                     # the estimate moved


@pytest.mark.parametrize("stem,option", [
    ("station_day", {"est.method": 2}),
    ("station_day", {"est.method": 2, "est.slope_window": 6}),
    ("coasting_rusich_row3", {"est.method": 2, "est.slope_window": 6, "est.physical": 1}),
    ("station_day", {"est.sigma2_method": 1}),
])
def test_slope_ls_bit_identical_to_fmi2(pair, railcar_runner, stem, option):  # noqa: F811
    """est.method 2 (LS on Sidorenko's slopes; the default window, a non-default one, and with
    est.physical 1): FMI 3 == FMI 2 (itself == pythonfmu, test_native_estimator_fmu.py)."""
    params, rows, times, steps = est2._railcar_run(railcar_runner, stem)
    out, statuses, _ = _compare(pair, {**params, **option}, rows, times, steps)
    assert statuses == [OK] * len(rows) and out[-1] != out[1]


def test_slope_window_reaches_the_fmi3_core(pair, railcar_runner):  # noqa: F811
    """The control for the comparison above: est.slope_window 6 and 10 give different outputs
    in the FMI 3 FMU."""
    params, rows, times, steps = est2._railcar_run(railcar_runner, "station_day")
    a, b = (est2._drive(pair["c3"], {**params, "est.method": 2, "est.slope_window": w}, rows,
                        times, steps)[0] for w in (6, 10))
    assert a != b


def test_relative_speed_noise_bit_identical_to_fmi2(pair, railcar_runner):  # noqa: F811
    """sensor.speed_std_rel 2 % in the run and in the estimator (Singer filter): FMI 3 == FMI 2."""
    extra = {"sensor.speed_std_rel": 0.02, "sensor.speed_std": 0.01}
    params, rows, times, steps = est2._railcar_run(railcar_runner, "steep_grades", extra)
    out, statuses, _ = _compare(pair, {**params, **extra, "filter.kind": 4}, rows, times, steps)
    assert statuses == [OK] * len(rows) and len(rows) > 100


def test_the_comparison_sees_a_difference(pair, railcar_runner):  # noqa: F811
    params, rows, times, steps = est2._railcar_run(railcar_runner, "station_day")
    rows, other = rows[:300], rows[:300].copy()
    other[150, 2] = math.nextafter(other[150, 2], math.inf)
    a = est2._drive(pair["c2"], params, rows, times, steps)
    b = est2._drive(pair["c3"], params, other, times, steps)
    assert a[0][:152] == b[0][:152] and a[0][-1] != b[0][-1]


def test_covariance_outputs_bit_identical_to_fmi2_and_seen_to_the_ulp(pair, railcar_runner):  # noqa: F811
    """est.cov_* (appended to the table; FMI 3's time moved after them): FMI 3 == FMI 2,
    identified (not 0) by the end; one ulp off in any is a difference."""
    params, rows, times, steps = est2._railcar_run(railcar_runner, "crush_load")
    a = est2._drive(pair["c2"], params, rows[:600], times, steps)
    b = est2._drive(pair["c3"], params, rows[:600], times, steps)
    assert a[0] == b[0] and a[1] == b[1] == [OK] * 600
    reals = [v.name for v in pair["c3"].md.modelVariables
             if v.causality == "output" and v.type == "Real"]
    assert reals[-3:] == list(est2.COVARIANCES)
    for name in est2.COVARIANCES:
        k = reals.index(name)
        x = float(np.int64(b[0][-1][k]).view(np.float64))
        assert x != 0.0 and math.isfinite(x), name
        off = list(b[0][-1])
        off[k] = int(est2.bits([math.nextafter(x, math.copysign(math.inf, x))])[0])
        assert tuple(a[0][-1]) != tuple(off), name


@pytest.mark.parametrize("column, value, named", [
    (2, float("nan"), "sensor.speed"),
    (0, -5.0, "traction_force"),
    (5, float("-inf"), "sensor.track_time"),
])
def test_bad_input_is_discarded_with_the_message(pair, column, value, named):
    """Step 30 has one bad input: discarded with the FMI 2 FMU's message; step 31 retries its
    time with good inputs and the run goes on identically."""
    n = 80
    rows = np.zeros((n, 6))
    rows[:, 0] = 20e3
    rows[:, 2] = np.linspace(0.0, 8.0, n)
    rows[:, 3] = np.cumsum(rows[:, 2]) * 0.1
    rows[30, column] = value
    times = np.array([0.1 * k for k in range(31)] + [0.1 * (k - 1) for k in range(31, n)])
    out, statuses, log = _compare(pair, {}, rows, times, np.full(n, 0.1))
    assert statuses[30] == DISCARD and statuses.count(DISCARD) == 1
    assert out[32] == out[31]      # out[k + 2]: after step k; the discarded step changed nothing
    discards = [m for m in log if m.startswith("[discard]")]
    assert len(discards) == 1 and discards[0].startswith("[discard] step discarded: ")
    assert named in discards[0]


@pytest.mark.parametrize("parameters, named", [
    ({"est.mass_initial": -1.0}, "est.mass_initial"),
    ({"filter.kind": 9}, "filter.kind"),
    ({"sensor.speed_std_rel": -1.0}, "sensor.speed_std_rel"),
    ({"track.grade_profile": "no/such/file.csv"}, "track.grade_profile"),
    ({"est.method": 1}, "est.method"),
    ({"est.method": 3}, "est.method"),
])
def test_bad_parameter_fails_initialisation_with_the_message(pair, parameters, named):
    status2, text2 = est2._init_failure(pair["c2"], parameters)
    status3, text3 = est2._init_failure(pair["c3"], parameters)
    assert status3 == status2 == ERROR
    assert named in text3, text3
    assert text3 == text2
