"""RailCar and RailCarEstimator run through fmpy: scripted runs, determinism, step-size
independence, bad inputs and parameters, several instances, reset, and the estimator FMU fed
with the RailCar's measurements.

fmpy facts these tests rely on (measured, fmpy 0.3.32 + pythonfmu 0.7.0):
- ``simulate_fmu`` ignores ``step_size`` for co-simulation: ``output_interval`` is the
  communication step. Communication points are ``start + n * output_interval``.
- Low level, ``FMU2Slave.doStep`` raises ``FMICallException`` with ``status == 2`` on
  fmi2Discard and ``status == 4`` on fmi2Fatal (any status > fmi2Warning raises).
- ``simulate_fmu`` on fmi2Discard asks fmi2GetBooleanStatus(fmi2Terminated); pythonfmu answers
  True, so fmpy stops *silently* at fmi2LastSuccessfulTime: always check the last time.
"""
from __future__ import annotations

import math
from pathlib import Path

import fmpy
import numpy as np
import pytest

from conftest import DISCARD, ERROR, FATAL, OK, Slave, run

STOP = 70.0
TRACTION, COAST_FROM, BRAKE_FROM = 40e3, 20.0, 40.0
PARAMS = {"car.mass": 36.0, "seed": 3}


def input_array(fmu, rows: list[tuple[float, dict]]) -> np.ndarray:
    """fmpy input signals for *all* inputs of ``fmu`` (start values unless given in ``rows``)."""
    names = fmu.names("input")
    start = {n: float(fmu.variables[n].start or 0.0) for n in names}
    data = [(t, *[values.get(n, start[n]) for n in names]) for t, values in rows]
    return np.array(data, dtype=[("time", float)] + [(n, float) for n in names])


def scripted_input(fmu, stop: float = STOP) -> np.ndarray:
    """Traction 40 kN for 20 s, coast 20 s, brake 30 kN until the end (the car stops ~60 s).

    Repeated time points make the steps discontinuities (fmpy applies the value after the event).
    """
    trac = {"traction_force_demand": TRACTION, "brake_force_demand": 0.0}
    coast = {"traction_force_demand": 0.0, "brake_force_demand": 0.0}
    brake = {"traction_force_demand": 0.0, "brake_force_demand": 30e3}
    return input_array(fmu, [(0.0, trac), (COAST_FROM, trac), (COAST_FROM, coast),
                             (BRAKE_FROM, coast), (BRAKE_FROM, brake), (stop, brake)])


def scripted_demands(t: float) -> dict:
    """The same script for the low-level helper (inputs held over [t, t + h))."""
    eps = 1e-9
    if t < COAST_FROM - eps:
        return {"traction_force_demand": TRACTION, "brake_force_demand": 0.0}
    if t < BRAKE_FROM - eps:
        return {"traction_force_demand": 0.0, "brake_force_demand": 0.0}
    return {"traction_force_demand": 0.0, "brake_force_demand": 30e3}


def simulate(fmu, *, stop=STOP, output_interval=0.1, start_values=None, outputs=None, inp=None):
    result = fmpy.simulate_fmu(fmu.unzipdir, model_description=fmu.md, stop_time=stop,
                               output_interval=output_interval,
                               start_values=dict(PARAMS if start_values is None else start_values),
                               input=scripted_input(fmu, stop) if inp is None else inp,
                               output=outputs)
    # fmpy stops silently on fmi2Discard: the run must reach the stop time
    assert result["time"][-1] == pytest.approx(stop, abs=1e-9), \
        f"simulation ended at {result['time'][-1]} instead of {stop}"
    assert len(result) == round(stop / output_interval) + 1
    return result


RAILCAR_OUT = ["car.speed", "car.position", "car.acceleration", "car.traction_force",
               "car.brake_force", "car.mode", "sensor.speed", "sensor.position", "est.mass",
               "est.mass_std", "est.A0", "est.sigma2", "filter.speed", "filter.position"]


# ------------------------------------------------------------------ 2. scripted run, seeds

@pytest.fixture(scope="module")
def scripted_run(railcar):
    return simulate(railcar, outputs=RAILCAR_OUT)


def test_scripted_run_accelerates_coasts_and_brakes_to_standstill(scripted_run):
    r = scripted_run
    t, v = r["time"], r["car.speed"]
    assert np.all(v >= 0.0)
    assert v[0] == 0.0
    v20 = v[np.isclose(t, COAST_FROM)][0]
    v40 = v[np.isclose(t, BRAKE_FROM)][0]
    assert v20 > 15.0                        # 40 kN then 400 kW on 36 t for 20 s
    assert np.all(np.diff(v[t <= COAST_FROM]) > -0.01)   # rises (process noise aside)
    assert 0.0 < v40 < v20                   # coasting loses speed
    assert v[-1] == 0.0 and r["car.mode"][-1] == 0
    stopped = t[(t > BRAKE_FROM) & (v == 0.0)]
    assert stopped.size and stopped[0] < STOP - 5.0
    assert np.all(v[t >= stopped[0]] == 0.0)  # a stopped car stays at rest
    traction = r["car.traction_force"]
    assert np.all((traction >= 0.0) & (traction <= TRACTION))
    braking = (t > BRAKE_FROM) & (v > 0.0)
    # (fmpy interpolates the input linearly between its points: 30 kN up to round-off)
    assert np.allclose(r["car.brake_force"][braking], 30e3, rtol=1e-12, atol=0)
    assert np.all(r["car.mode"][braking] == 3)
    assert r["car.position"][-1] > 500.0
    assert r["est.mass"][-1] == pytest.approx(PARAMS["car.mass"], rel=0.05)   # identified


def test_likelihood_noise_and_physical_coefficients_run_through_the_fmu(railcar):
    """est.sigma2_method and est.physical set through fmpy reach the estimator (the paper's LS,
    est.method 0): with est.sigma2_method 1 est.sigma2 leaves est.sigma2_initial once the car
    moves and differs from the LAG estimate (est.sigma2_method 0), A0 and A2 stay >= 0 at every
    step with est.physical 1, and the mass (the paper's LS's, untouched by both) is the same."""
    paper = {**PARAMS, "est.method": 0}
    lag = simulate(railcar, start_values={**paper, "est.sigma2_method": 0, "est.physical": 0},
                   outputs=RAILCAR_OUT)
    r = simulate(railcar, start_values={**paper, "est.sigma2_method": 1, "est.physical": 1},
                 outputs=RAILCAR_OUT + ["est.A2"])
    s2 = r["est.sigma2"]
    assert np.all(np.isfinite(s2)) and np.all(s2 > 0.0)
    assert s2[-1] != pytest.approx(1e-4, rel=1e-3)              # moved off est.sigma2_initial
    assert s2[-1] != pytest.approx(lag["est.sigma2"][-1], rel=1e-3)
    assert r["est.A0"].min() >= 0.0 and r["est.A2"].min() >= 0.0
    assert np.array_equal(r["est.mass"], lag["est.mass"])


def test_scripted_run_has_sensor_noise_of_the_configured_size(scripted_run):
    r = scripted_run
    # output interval == sensor.sample_period: every row is a fresh sample of the truth there
    dv = r["sensor.speed"] - r["car.speed"]
    dx = r["sensor.position"] - r["car.position"]
    assert np.std(dv) == pytest.approx(0.05, rel=0.15)     # sensor.speed_std default
    assert np.std(dx) == pytest.approx(1.0, rel=0.15)      # sensor.position_std default
    assert abs(np.mean(dv)) < 0.01 and abs(np.mean(dx)) < 0.2
    assert len(np.unique(dv)) > 0.9 * len(dv)


def test_same_seed_bit_identical_different_seed_differs(railcar, scripted_run):
    again = simulate(railcar, outputs=RAILCAR_OUT)
    for name in RAILCAR_OUT:
        assert np.array_equal(again[name], scripted_run[name]), f"{name} differs for the same seed"
    other = simulate(railcar, start_values={**PARAMS, "seed": 4}, outputs=RAILCAR_OUT)
    assert not np.array_equal(other["sensor.speed"], scripted_run["sensor.speed"])
    assert np.mean(np.abs(other["sensor.speed"] - scripted_run["sensor.speed"])) > 0.02


def test_fmpy_simulate_stops_silently_at_a_discarded_step(railcar):
    """Documents fmpy's handling of fmi2Discard (why every run checks its last time)."""
    inp = input_array(railcar, [(0.0, {"traction_force_demand": 1e3}),
                                (1.0, {"traction_force_demand": 1e3}),
                                (1.0, {"traction_force_demand": math.nan}),
                                (2.0, {"traction_force_demand": math.nan})])
    r = fmpy.simulate_fmu(railcar.unzipdir, model_description=railcar.md, stop_time=2.0,
                          output_interval=0.1, input=inp, output=["car.speed"])
    assert r["time"][-1] == pytest.approx(1.0)      # no exception, result truncated at 1 s
    assert r["time"][-2] == pytest.approx(1.0)      # the discarded step's sample is repeated


# ------------------------------------------------------- 3. communication step independence

SHARED_OUT = ["car.speed", "car.position", "sensor.speed", "est.mass", "filter.speed"]


def _at_shared_instants(r, base_times):
    idx = np.searchsorted(r["time"], base_times - 1e-9)
    assert np.allclose(r["time"][idx], base_times, atol=1e-9, rtol=0)
    return r[idx]


@pytest.fixture(scope="module")
def runs_by_interval(railcar):
    return {h: simulate(railcar, stop=60.0, output_interval=h, outputs=SHARED_OUT)
            for h in (0.2, 0.1, 0.05, 0.04, 0.025)}


def test_truth_and_estimates_do_not_depend_on_the_communication_step(runs_by_interval):
    """Output intervals 0.2, 0.1 and 0.05 s: the same values at multiples of 0.2 s.

    Tolerance 1e-9: solver.step is 0.05 s, so every communication point is on the plant's
    internal grid, the plant takes the same RK4 steps with the same noise draws, the sensors
    sample on their own 0.1 s grid and the demands change only at shared instants (20 s, 40 s).
    What remains is float round-off in time bookkeeping and force-impulse sums (measured
    <= 1.5e-14); a genuine dependence, e.g. noise drawn per communication step (sigma * sqrt(h)
    ~ 2e-3 m/s), would exceed it by orders of magnitude.
    """
    base = runs_by_interval[0.2]
    for h in (0.1, 0.05):
        r = _at_shared_instants(runs_by_interval[h], base["time"])
        for name in SHARED_OUT:
            scale = max(1.0, float(np.max(np.abs(base[name]))))
            err = float(np.max(np.abs(r[name] - base[name])))
            assert err <= 1e-9 * scale, f"{name}: output_interval {h} differs by {err}"


def test_off_grid_communication_steps_differ_only_by_integration_error(runs_by_interval):
    """Output intervals 0.04 and 0.025 s cut the plant's 0.05 s RK4 steps: results differ by
    the integrator's error only (measured ~6e-6 m/s, 1.5e-4 m, 6e-5 t), not by noise."""
    base = runs_by_interval[0.2]
    tol = {"car.speed": 1e-4, "car.position": 5e-3, "sensor.speed": 1e-4, "est.mass": 2e-3,
           "filter.speed": 2e-4}
    for h in (0.04, 0.025):
        r = _at_shared_instants(runs_by_interval[h], base["time"])
        for name in SHARED_OUT:
            err = float(np.max(np.abs(r[name] - base[name])))
            assert err <= tol[name], f"{name}: output_interval {h} differs by {err}"


START_CASES = {
    "RailCar": ({**PARAMS, "traction_force_demand": 30e3},
                ["car.speed", "car.position", "sensor.speed", "est.mass", "filter.speed"]),
    "RailCarEstimator": ({"traction_force": 20e3, "sensor.speed": 1.0, "sensor.position": 5.0},
                         ["est.mass", "filter.speed", "filter.position"]),
}


@pytest.mark.parametrize("name", ["RailCar", "RailCarEstimator"])
def test_a_run_may_start_at_a_nonzero_start_time(fmus, name):
    """FMI 2.0 lets the master choose tStart in fmi2SetupExperiment and then step from there.
    Nothing in either model depends on absolute time, so a run over [5, 15] s must reach its
    stop time and repeat the run over [0, 10] s (to round-off in the step sizes fmpy computes)."""
    fmu = fmus[name]
    start_values, outputs = START_CASES[name]
    runs = {}
    for t0 in (0.0, 5.0):
        r = fmpy.simulate_fmu(fmu.unzipdir, model_description=fmu.md, start_time=t0,
                              stop_time=t0 + 10.0, output_interval=0.1,
                              start_values=start_values, output=outputs)
        assert r["time"][-1] == pytest.approx(t0 + 10.0, abs=1e-9), \
            f"started at {t0} s, the run ended at {r['time'][-1]} s (steps discarded)"
        runs[t0] = r
    for n in outputs:
        np.testing.assert_allclose(runs[5.0][n], runs[0.0][n], rtol=1e-9, atol=1e-9, err_msg=n)


# ------------------------------------------------------------------ track profiles (paths)

def test_profile_paths_resolve_in_resources_then_working_directory(railcar, tmp_path, monkeypatch):
    outputs = ["car.grade", "car.speed", "est.mass"]
    sv = {**PARAMS, "track.grade_profile": "profiles/demo_grade.csv"}
    const = input_array(railcar, [(0.0, {"traction_force_demand": 30e3}),
                                  (60.0, {"traction_force_demand": 30e3})])
    in_resources = simulate(railcar, stop=60.0, start_values=sv, outputs=outputs, inp=const)
    assert set(np.unique(in_resources["car.grade"])) == {0.0, 15.0, -10.0}

    profile = (Path(railcar.unzipdir) / "resources" / "profiles" / "demo_grade.csv").read_text()
    (tmp_path / "my_grade.csv").write_text(profile)
    absolute = simulate(railcar, stop=60.0, outputs=outputs, inp=const,
                        start_values={**sv, "track.grade_profile": str(tmp_path / "my_grade.csv")})
    monkeypatch.chdir(tmp_path)
    from_cwd = simulate(railcar, stop=60.0, outputs=outputs, inp=const,
                        start_values={**sv, "track.grade_profile": "my_grade.csv"})
    for name in outputs:
        assert np.array_equal(absolute[name], in_resources[name])
        assert np.array_equal(from_cwd[name], in_resources[name])


# ------------------------------------------------------------------ 5. bad input never crashes

STEP = 0.1
CHECK_OUT = ["car.speed", "car.position", "sensor.speed", "est.mass", "filter.speed",
             "filter.position"]
VALID = {"traction_force_demand": 20e3, "brake_force_demand": 0.0, "wind_speed": 0.0}


@pytest.fixture(scope="module")
def clean_reference(railcar):
    return run(railcar, PARAMS, CHECK_OUT, STEP, 20, inputs=lambda k, t: VALID)


@pytest.mark.parametrize("bad", [
    {"traction_force_demand": math.nan},
    {"traction_force_demand": -1.0},
    {"brake_force_demand": math.inf},
    {"wind_speed": math.nan},
], ids=lambda d: "{}={}".format(*next(iter(d.items()))))
def test_railcar_bad_input_is_discarded_and_the_instance_stays_usable(railcar, slave_factory,
                                                                      clean_reference, bad):
    name, value = next(iter(bad.items()))
    s = slave_factory(railcar)
    s.initialize(PARAMS)
    rows = [s.get_reals(CHECK_OUT)]
    for k in range(10):
        s.set(VALID)
        assert s.do_step(k * STEP, STEP) == OK
        rows.append(s.get_reals(CHECK_OUT))
    t = 10 * STEP
    before = s.get_reals(CHECK_OUT)
    s.set(bad)
    assert s.do_step(t, STEP) == DISCARD                       # fmpy: FMICallException, status 2
    assert not s.fatal
    discard_logs = [m for m in s.messages if m.status == DISCARD]
    assert discard_logs and name in discard_logs[-1].message, s.log_text()
    assert s.get_reals(CHECK_OUT) == before                    # nothing changed
    s.set(VALID)
    assert s.do_step(t, STEP) == OK                            # same current time, now valid
    rows.append(s.get_reals(CHECK_OUT))
    for k in range(11, 20):
        assert s.do_step(k * STEP, STEP) == OK                 # time continues
        rows.append(s.get_reals(CHECK_OUT))
    # the discarded step left no trace: bit-identical to a run that never saw the bad input
    assert np.array_equal(np.array(rows), clean_reference[:, 1:])


@pytest.mark.parametrize("h", [0.0, -0.1, math.nan])
def test_railcar_bad_step_size_is_discarded(railcar, slave_factory, clean_reference, h):
    s = slave_factory(railcar)
    s.initialize(PARAMS)
    s.set(VALID)
    rows = [s.get_reals(CHECK_OUT)]
    for k in range(5):
        assert s.do_step(k * STEP, STEP) == OK
        rows.append(s.get_reals(CHECK_OUT))
    assert s.do_step(5 * STEP, h) == DISCARD
    assert "step size" in s.messages[-1].message, s.log_text()
    assert s.do_step(7 * STEP, STEP) == DISCARD                # time must continue from 0.5 s
    assert "does not continue" in s.messages[-1].message
    for k in range(5, 20):
        assert s.do_step(k * STEP, STEP) == OK
        rows.append(s.get_reals(CHECK_OUT))
    assert np.array_equal(np.array(rows), clean_reference[:, 1:])


EST_OUT = ["est.mass", "est.A0", "filter.speed", "filter.position", "filter.speed_std"]


def _estimator_inputs(k: int) -> dict:
    """A plausible measured run: 20 kN on a 30 t car from rest, noisy speed."""
    t = k * STEP
    v = 0.6 * t + 0.05 * math.sin(7.0 * k)
    return {"traction_force": 20e3, "brake_force": 0.0, "sensor.speed": v,
            "sensor.position": 0.3 * t * t}


@pytest.mark.parametrize("bad_at", [0, 10])
@pytest.mark.parametrize("bad", [
    {"sensor.speed": math.nan},
    {"sensor.position": math.inf},
    {"traction_force": -1.0},
    {"brake_force": math.nan},
], ids=lambda d: "{}={}".format(*next(iter(d.items()))))
def test_estimator_bad_input_is_discarded_and_the_instance_stays_usable(estimator, slave_factory,
                                                                        bad, bad_at):
    name = next(iter(bad))
    n = 80          # beyond est.batch_size (50) so that identification has run
    reference = run(estimator, {}, EST_OUT, STEP, n, inputs=lambda k, t: _estimator_inputs(k))
    s = slave_factory(estimator)
    s.initialize({})
    rows = [s.get_reals(EST_OUT)]
    for k in range(n):
        if k == bad_at:
            before = s.get_reals(EST_OUT)
            s.set({**_estimator_inputs(k), **bad})
            assert s.do_step(k * STEP, STEP) == DISCARD
            assert not s.fatal
            assert name in s.messages[-1].message, s.log_text()
            assert s.get_reals(EST_OUT) == before
        s.set(_estimator_inputs(k))
        assert s.do_step(k * STEP, STEP) == OK, s.log_text()
        rows.append(s.get_reals(EST_OUT))
    assert np.array_equal(np.array(rows), reference[:, 1:])
    assert 20.0 < rows[-1][0] < 45.0    # the estimator did identify something


def test_a_speed_spike_is_refused_with_a_warning_and_counted(estimator, slave_factory):
    """A +100 m/s spike at one sample of a plausible run (it sent est.mass to inf before): the
    step is OK, the FMU warns, filter.rejected counts it, est.mass stays finite and plausible."""
    from conftest import WARNING
    s = slave_factory(estimator)
    s.initialize({})
    for k in range(120):
        inputs = _estimator_inputs(k)
        if k == 90:
            inputs["sensor.speed"] += 100.0
        s.set(inputs)
        assert s.do_step(k * STEP, STEP) == OK, s.log_text()
        if k == 90:
            assert s.messages and s.messages[-1].status == WARNING
            assert "refused by the innovation gate" in s.messages[-1].message
    assert s.get("filter.rejected") == 1
    assert 20.0 < s.get("est.mass") < 45.0 and math.isfinite(s.get("est.mass_std"))


def test_estimator_bad_step_size_is_discarded(estimator, slave_factory):
    s = slave_factory(estimator)
    s.initialize({})
    for h in (0.0, -0.1):
        s.set(_estimator_inputs(0))
        assert s.do_step(0.0, h) == DISCARD
    for k in range(5):
        s.set(_estimator_inputs(k))
        assert s.do_step(k * STEP, STEP) == OK


# ------------------------------------------------------------------ 6. bad parameters

BAD_CSV = "distance_m,grade_permille\n0,0\n300,fifteen\n800,-10\n"   # line 3 is bad
BAD_SPEED_CSV = "distance_m,speed_mps\n0,10\n500,-3\n"                  # line 3 is bad


# further invalid values (variables.py gives min 0 for all of these; seed seeds numpy's
# SeedSequence, which needs a non-negative integer)
MORE_BAD = [("seed", -1, ("RailCar",)),
            ("est.gamma", -1.0, ("RailCar", "RailCarEstimator")),
            ("car.length", -1.0, ("RailCar", "RailCarEstimator")),
            ("sensor.speed_std", 0.0, ("RailCar", "RailCarEstimator")),
            ("sensor.sample_period", 0.0, ("RailCar",)),
            ("solver.step", 0.2, ("RailCar",)),           # longer than sensor.sample_period
            ("track.station_dwell", math.nan, ("RailCar", "RailCarEstimator")),
            ("filter.kind", 7, ("RailCar", "RailCarEstimator")),
            ("est.sigma2_method", 2, ("RailCar", "RailCarEstimator")),
            ("est.physical", 3, ("RailCar", "RailCarEstimator")),
            ("est.run_forgetting", 1.0, ("RailCar", "RailCarEstimator"))]


def _bad_parameter_cases():
    cases = []
    for fmu in ("RailCar", "RailCarEstimator"):
        if fmu == "RailCar":
            cases.append((fmu, "car.mass", -1.0, None))
        cases += [(fmu, "est.batch_size", 2, None),
                  (fmu, "est.forgetting", 1.0, None),
                  (fmu, "track.grade_profile", "no/such/grade_profile.csv", "missing"),
                  (fmu, "track.grade_profile", BAD_CSV, "csv"),
                  (fmu, "track.speed_profile", "no/such/speed_profile.csv", "missing"),
                  (fmu, "track.speed_profile", BAD_SPEED_CSV, "csv")]
        cases += [(fmu, name, value, None) for name, value, where in MORE_BAD if fmu in where]
    return [pytest.param(*c, id=f"{c[0]}-{c[1]}-{c[3] or c[2]}") for c in cases]


@pytest.mark.parametrize("fmu_name, parameter, value, kind", _bad_parameter_cases())
def test_bad_parameter_fails_initialisation_with_a_message(fmus, slave_factory, tmp_path,
                                                           fmu_name, parameter, value, kind):
    fmu = fmus[fmu_name]
    csv_path = None
    if kind == "csv":
        csv_path = tmp_path / "bad_profile.csv"
        csv_path.write_text(value)
        value = str(csv_path)
    survivor = slave_factory(fmu, "survivor")      # created before the failure
    survivor.initialize({})
    assert survivor.do_step(0.0, STEP) == OK

    s = slave_factory(fmu, "bad")
    s.setup({parameter: value})
    status = s.exit_init()
    # our binary (fmu_src/c) turns the exception raised in exit_initialization_mode into
    # fmi2Error; the instance is in the error state, where terminate, reset and free are safe
    assert status == ERROR, f"initialisation accepted {parameter} = {value!r}:\n{s.log_text()}"

    # a new instance of the same FMU in the same process still runs fine, and so does the
    # instance that already existed
    good = slave_factory(fmu, "good")
    good.initialize({})
    for k in range(10):
        assert good.do_step(k * STEP, STEP) == OK
        assert survivor.do_step((k + 1) * STEP, STEP) == OK
    assert all(math.isfinite(x) for x in good.get_reals(["est.mass", "filter.speed"]))
    assert all(math.isfinite(x) for x in survivor.get_reals(["est.mass", "filter.speed"]))

    # the log names the parameter (and the file, and the line for a malformed CSV)
    text = s.log_text()
    assert any(m.status >= 3 for m in s.messages), f"no error logged:\n{text}"
    problems = []
    if parameter not in text:
        problems.append(f"does not name the parameter {parameter}")
    if kind == "missing" and value not in text:
        problems.append(f"does not name the file {value}")
    if kind == "csv" and not (str(csv_path) in text and "line 3" in text):
        problems.append("does not name the file and line 3")
    assert not problems, "the log " + "; ".join(problems) + f":\n{text}"


# ------------------------------------------------------- 7. several instances, reset

TWIN_OUT = ["car.speed", "car.position", "sensor.speed", "sensor.position", "est.mass",
            "est.A0", "filter.speed", "filter.position_std"]
N_TWIN = 300
TWIN_PARAMS = ({"seed": 1, "car.mass": 30.0}, {"seed": 2, "car.mass": 45.0})


def _twin_inputs(k, t):
    return scripted_demands(t * 2.0)    # the script, twice as fast


def test_two_instances_stepped_alternately_equal_their_solo_runs(railcar, slave_factory):
    solo = [run(railcar, p, TWIN_OUT, STEP, N_TWIN, inputs=_twin_inputs) for p in TWIN_PARAMS]
    assert not np.array_equal(solo[0], solo[1])
    a, b = slave_factory(railcar, "a"), slave_factory(railcar, "b")
    a.initialize(TWIN_PARAMS[0])
    b.initialize(TWIN_PARAMS[1])
    rows = ([a.get_reals(TWIN_OUT)], [b.get_reals(TWIN_OUT)])
    for k in range(N_TWIN):
        for s, out in ((a, rows[0]), (b, rows[1])):
            s.set(_twin_inputs(k, k * STEP))
            assert s.do_step(k * STEP, STEP) == OK
            out.append(s.get_reals(TWIN_OUT))
    for i in range(2):
        assert np.array_equal(np.array(rows[i]), solo[i][:, 1:]), f"instance {i} differs"


def test_reset_then_new_initialisation_repeats_the_run(railcar, slave_factory):
    s = slave_factory(railcar)
    runs = []
    for attempt in range(3):
        if attempt:
            assert s.reset() == OK
        s.initialize(TWIN_PARAMS[1])
        rows = [s.get_reals(TWIN_OUT)]
        for k in range(N_TWIN):
            s.set(_twin_inputs(k, k * STEP))
            assert s.do_step(k * STEP, STEP) == OK
            rows.append(s.get_reals(TWIN_OUT))
        runs.append(np.array(rows))
    assert np.array_equal(runs[1], runs[0])
    assert np.array_equal(runs[2], runs[0])
    fresh = run(railcar, TWIN_PARAMS[1], TWIN_OUT, STEP, N_TWIN, inputs=_twin_inputs)
    assert np.array_equal(fresh[:, 1:], runs[0])


# -------------------------------------------- 8. RailCarEstimator fed with RailCar's outputs

def test_estimator_fmu_replaying_railcar_measurements_matches_railcar_estimate(railcar, estimator):
    n = round(STOP / STEP)
    out = ["sensor.speed", "sensor.position", "car.traction_force", "car.brake_force",
           "car.speed", "est.mass"]
    col = {name: 1 + i for i, name in enumerate(out)}
    rc = run(railcar, PARAMS, out, STEP, n, inputs=lambda k, t: scripted_demands(t))

    # Alignment. RailCar takes sample k at t_k = k * 0.1 s (its outputs at t_k), and its
    # identification uses the forces *applied over* [t_k, t_k+1] (their mean, integrated on
    # the plant grid). RailCarEstimator's doStep(t_k, h) takes the measurements at t_k and the
    # forces applied over [t_k, t_k + h]. The recorded car.traction_force / car.brake_force at
    # t_k+1 is the force at the end of that interval under that interval's demand, so step k
    # is fed sensor.* from row k and forces from row k + 1. It equals the interval mean
    # wherever the force is constant over the interval (constant-force zone, braking); in the
    # constant-power zone (F = P / V) and at demand switches it is only close.
    # Outputs: after doStep(t_k, h) RailCarEstimator reports the identification up to sample k
    # (its filter outputs are the one-step prediction for t_k+1), so its est.mass after step k
    # is compared with RailCar's est.mass at t_k.
    est = []
    with Slave(estimator, "replay") as s:
        s.initialize({})
        for k in range(n):
            s.set({"sensor.speed": rc[k, col["sensor.speed"]],
                   "sensor.position": rc[k, col["sensor.position"]],
                   "traction_force": rc[k + 1, col["car.traction_force"]],
                   "brake_force": rc[k + 1, col["car.brake_force"]]})
            assert s.do_step(k * STEP, STEP) == OK, s.log_text()
            est.append(s.get("est.mass"))
    est = np.array(est)
    rc_mass = rc[:n, col["est.mass"]]

    # constant-force zone: 40 kN is below the 400 kW power limit up to 10 m/s, so until then
    # the data are the same and so is the estimate (batch solve at 50 moving samples included)
    v = rc[:n, col["car.speed"]]
    const = np.arange(n) < np.argmax(v > 9.5)
    assert np.count_nonzero(rc_mass[const] != 30.0) > 10          # identification started
    assert np.allclose(est[const], rc_mass[const], rtol=1e-12, atol=0)
    # afterwards only the end-point force approximation differs (measured <= 0.05 t)
    assert np.max(np.abs(est - rc_mass)) < 0.2
    assert est[-1] == pytest.approx(rc_mass[-1], abs=0.1)
    assert est[-1] == pytest.approx(PARAMS["car.mass"], rel=0.03)
