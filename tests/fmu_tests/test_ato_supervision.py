"""The catalogue of issue 29 for AtoController.fmu: every bad input, step and parameter a user
found accepted silently, run through the FMU in a subprocess (one process for all cases:
fmpy loads the pythonfmu binary, whose Python must not share a process with pytest's copy of
the sources; see conftest.py), and what each must give:

- a bad input (outside physics, inconsistent with the others, not finite, absurd estimates,
  left unconnected):
  the safe brake (no traction, brake >= ato.safe_brake x car.brake_force_max, ato.mode 9) and
  a warning naming the input and its value; doStep returns fmi2Warning, never a failed step;
- a bad step size or time (h <= 0, NaN, +-inf, > 3600 s, time going back or jumping): fmi2Discard
  with a message, the outputs and fmi2LastSuccessfulTime unchanged (finite), the instance
  usable (the next proper step is ok);
- a bad parameter: exitInitializationMode -> fmi2Error naming it, within 2 s (the grid and span
  cases took 34-125 s before).

The subprocess prints one JSON record per case; the tests assert on them.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STEP = 0.1                 # [s]
BRAKE_MAX = 45e3           # [N] car.brake_force_max (the default)
SAFE_MODE = 9

# (case, inputs of the bad step, words the warning must contain); the steps before it are a
# sane run at 10 m/s from filter.position 100 m (the position advancing with the speed)
BAD_INPUTS = [
    ("speed NaN", {"filter.speed": math.nan}, ["filter.speed = nan"]),
    ("speed -0.5", {"filter.speed": -0.5}, ["filter.speed = -0.5"]),
    ("speed -20", {"filter.speed": -20.0}, ["filter.speed = -20.0"]),
    ("speed 500", {"filter.speed": 500.0}, ["filter.speed = 500.0"]),
    ("position -100", {"filter.position": -100.0}, ["filter.position = -100.0"]),
    ("speed std negative", {"filter.speed_std": -0.1}, ["filter.speed_std = -0.1"]),
    ("position std negative", {"filter.position_std": -1.0}, ["filter.position_std = -1.0"]),
    ("speed std 0 moving", {"filter.speed_std": 0.0}, ["filter.speed_std = 0"]),
    ("position std inf", {"filter.position_std": math.inf}, ["filter.position_std = inf"]),
    ("A0 1e300", {"est.A0": 1e300}, ["est.A0 = 1e+300"]),
    ("A2 -50", {"est.A2": -50.0}, ["est.A2 = -50.0"]),
    ("mass 0", {"est.mass": 0.0}, ["est.mass = 0.0"]),
    ("mass in kg", {"est.mass": 30000.0}, ["est.mass = 30000.0"]),
    ("samples 2^31-1", {"est.samples": 2**31 - 1}, ["est.samples = 2147483647"]),
    ("samples -1", {"est.samples": -1}, ["est.samples = -1"]),
    ("status 7", {"est.status": 7}, ["est.status = 7"]),
    ("all inputs 0", {n: 0.0 for n in ("filter.speed", "filter.position", "filter.speed_std",
                                       "filter.position_std", "est.mass", "est.A0", "est.A1",
                                       "est.A2", "est.status", "est.samples")}, ["est.mass = 0.0"]),
]
# the speed cut to 0 while the car runs on at 10 m/s (the position keeps advancing): found
# within 3 s, naming both
STUCK_SPEED = ("speed 0 while moving", ["filter.speed and filter.position disagree",
                                         "filter.speed (now 0.0 m/s)"])

BAD_STEPS = [   # (case, current time relative to the proper one [s], step size [s], words)
    ("h = 0", 0.0, 0.0, "communication step size must be > 0 [s], got 0.0"),
    ("h = -0.1", 0.0, -0.1, "communication step size must be > 0 [s], got -0.1"),
    ("h = NaN", 0.0, math.nan, "communication step size must be > 0 [s], got nan"),
    ("h = inf", 0.0, math.inf, "communication step size must be > 0 [s], got inf"),
    ("h = -inf", 0.0, -math.inf, "communication step size must be > 0 [s], got -inf"),
    ("h = 1e300", 0.0, 1e300, "communication step size must be <= 3600 s, got 1e+300"),
    ("time back", -0.5, STEP, "does not continue the FMU's time"),
    ("time jump 1000 s", 1000.0, STEP, "does not continue the FMU's time"),
]

BAD_PARAMETERS = [   # (parameters, words of the refusal)
    ({"ato.safe_brake": 0.0}, ["ato.safe_brake must be > 0"]),
    ({"ato.hold_brake": 0.0}, ["ato.hold_brake must be > 0"]),
    ({"ato.creep_accel": 0.0}, ["ato.creep_accel must be > 0"]),
    ({"ato.ep_stages": 2**31 - 1}, ["ato.ep_stages must be in [1, 32]"]),
    ({"ato.mass_band": 50.0}, ["ato.mass_band must be in [1, 5]"]),
    ({"ato.grid_step": 1e-3}, ["ato.grid_step = 0.001 m puts", "at most 10000"]),
    ({"span.stop": 1e7, "span.schedule": 1e6}, ["ato.grid_step = 10 m puts 1e+06 nodes",
                                                "span.stop = 1e+07 m"]),
    ({"span.stop": -100.0}, ["span.stop = -100.0 m must be finite and > 0"]),
    ({"span.stop": 0.0}, ["span.stop = 0.0 m must be finite and > 0"]),
    ({"span.stop": math.nan}, ["span.stop = nan m must be finite and > 0"]),
    ({"span.length": -5.0}, ["span.length = -5.0 m must be finite and >= 0"]),
    ({"span.schedule": 1e20}, ["span.schedule = 1e+20 s is too long"]),
    ({"span.schedule": math.inf}, ["span.schedule = inf s must be finite and > 0"]),
    ({"span.grade_profile": "g" * 300 + ".csv"}, ["span.grade_profile: cannot use", "(304 characters)"]),
    ({"span.speed_limit_profile": "no_such_limits.csv"}, ["span.speed_limit_profile: cannot read "
                                                           "'no_such_limits.csv'"]),
    ({"span.grade_profile": "<a directory>"}, ["span.grade_profile: cannot read"]),
]


def _moving(k: int) -> dict:
    """Sane inputs at step k of a run at 10 m/s from 100 m."""
    return {"filter.speed": 10.0, "filter.position": 100.0 + 10.0 * k * STEP,
            "filter.speed_std": 0.05, "filter.position_std": 0.1, "est.mass": 30.0,
            "est.A0": 1.0, "est.A1": 0.03, "est.A2": 0.01, "est.status": 1, "est.samples": 50 + k}


# ------------------------------------------------------------------ the subprocess
def _catalogue(fmu_path: str, unzipdir: str, workdir: str) -> list[dict]:
    import time
    sys.path.insert(0, str(HERE.parent))
    from fmpy import read_model_description
    from conftest import FmuFile, Slave
    fmu = FmuFile("AtoController", Path(fmu_path), read_model_description(fmu_path), unzipdir)
    outputs = ["traction_force_demand", "brake_force_demand", "ato.mode"]
    records = []

    def started(n_good: int) -> Slave:
        s = Slave(fmu, "catalogue")
        s.initialize({"span.stop": 2000.0, "span.schedule": 125.0})
        for k in range(n_good):
            s.set(_moving(k))
            assert s.do_step(k * STEP, STEP) == 0, s.log_text()
        return s

    def raw_do_step(s: Slave, t: float, h: float) -> int:
        """fmi2DoStep's own status (fmpy's doStep raises above a warning but returns nothing)."""
        import ctypes
        f = s.fmu.dll.fmi2DoStep
        f.argtypes, f.restype = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int], ctypes.c_int
        return f(s.fmu.component, t, h, 1)

    for case, bad, _ in BAD_INPUTS:
        with started(3) as s:
            s.set({**_moving(3), **bad})
            status = raw_do_step(s, 3 * STEP, STEP)
            records.append({"kind": "input", "case": case, "status": status, "log": s.log_text(),
                            "out": [s.get(n) for n in outputs]})
    with started(3) as s:                       # the speed cut to 0, the car running on
        found = None
        for k in range(3, 60):
            s.set({**_moving(k), "filter.speed": 0.0})
            status = s.do_step(k * STEP, STEP)
            if s.get("ato.mode") == SAFE_MODE:
                found = k * STEP
                break
        records.append({"kind": "stuck", "case": STUCK_SPEED[0], "status": status, "found": found,
                        "log": s.log_text(), "out": [s.get(n) for n in outputs]})
    with started(0) as s:                       # nothing connected: the inputs' start values
        found = None
        for k in range(60):
            status = s.do_step(k * STEP, STEP)
            if s.get("ato.mode") == SAFE_MODE:
                found = k * STEP
                break
        records.append({"kind": "unconnected", "case": "unconnected", "status": status,
                        "found": found, "log": s.log_text(), "out": [s.get(n) for n in outputs]})
    for case, dt, h, _ in BAD_STEPS:
        with started(3) as s:
            before = [s.get(n) for n in outputs]
            s.set(_moving(3))
            status = s.do_step(3 * STEP + dt, h)
            after = [s.get(n) for n in outputs]
            last = s.fmu.getRealStatus(2)        # fmi2LastSuccessfulTime
            retry = s.do_step(3 * STEP, STEP)    # the proper step: the instance is usable
            records.append({"kind": "step", "case": case, "status": status, "log": s.log_text(),
                            "unchanged": before == after, "last": last, "retry": retry})
    for parameters, _ in BAD_PARAMETERS:
        values = dict(parameters)
        if values.get("span.grade_profile") == "<a directory>":
            values["span.grade_profile"] = workdir
        s = Slave(fmu, "catalogue")
        t0 = time.perf_counter()
        s.setup(values)
        status = s.exit_init()
        seconds = time.perf_counter() - t0
        reset = s.reset()
        s.initialize({})
        usable = s.do_step(0.0, STEP)
        s.close()
        records.append({"kind": "parameter", "case": json.dumps(parameters), "status": status,
                        "seconds": seconds, "log": s.log_text(), "reset": reset, "usable": usable})
    return records


if __name__ == "__main__":
    print(json.dumps(_catalogue(*sys.argv[1:4])))
    sys.stdout.flush()
    os._exit(0)                 # the FMU's embedded Python: no interpreter teardown


# ------------------------------------------------------------------ the tests
@pytest.fixture(scope="module")
def records(ato_fmu, tmp_path_factory) -> dict:
    work = tmp_path_factory.mktemp("supervision")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(HERE.parent)]))
    proc = subprocess.run([sys.executable, str(Path(__file__)), str(ato_fmu.path),
                           str(ato_fmu.unzipdir), str(work)], cwd=work, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    return {(r["kind"], r["case"]): r for r in out}


@pytest.mark.parametrize("case, words", [(c, w) for c, _, w in BAD_INPUTS])
def test_a_bad_input_gives_the_safe_brake_and_a_warning_naming_it(records, case, words):
    r = records[("input", case)]
    traction, brake, mode = r["out"]
    assert r["status"] == 1, r["log"]             # fmi2Warning
    assert (traction, mode) == (0.0, SAFE_MODE) and brake >= 1.0 * BRAKE_MAX, r
    warnings = [line for line in r["log"].splitlines() if line.startswith("[warning]")]
    assert any(all(w in line for w in words) for line in warnings), \
        f"no warning with {words}:\n{r['log']}"


def test_a_speed_stuck_at_zero_while_the_car_moves_is_found_within_3_s(records):
    r = records[("stuck", STUCK_SPEED[0])]
    assert r["found"] is not None and r["found"] <= 0.3 + 3.0, r
    traction, brake, mode = r["out"]
    assert (traction, mode) == (0.0, SAFE_MODE) and brake >= BRAKE_MAX
    assert all(w in r["log"] for w in STUCK_SPEED[1]), r["log"]


def test_inputs_left_unconnected_are_found_after_3_s_of_traction(records):
    """Their start values are a car at rest, which every single check accepts; the car does
    not respond to 3 s of traction (models.ato.supervision.RESPONSE_TIME)."""
    r = records[("unconnected", "unconnected")]
    assert r["found"] == pytest.approx(3.0), r
    traction, brake, mode = r["out"]
    assert (traction, mode) == (0.0, SAFE_MODE) and brake >= BRAKE_MAX
    assert "have not moved in 3 s of traction" in r["log"] and "not connected" in r["log"], r["log"]


@pytest.mark.parametrize("case, words", [(c, w) for c, _, _, w in BAD_STEPS])
def test_a_bad_step_is_discarded_with_a_message_and_changes_nothing(records, case, words):
    r = records[("step", case)]
    assert r["status"] == 2, r["log"]              # fmi2Discard
    assert words in r["log"] and "step discarded" in r["log"], r["log"]
    assert r["unchanged"]
    assert r["last"] == pytest.approx(0.3, abs=1e-12)   # fmi2LastSuccessfulTime: the last good end
    assert r["retry"] == 0, r["log"]


@pytest.mark.parametrize("parameters, words", BAD_PARAMETERS,
                         ids=[json.dumps(p)[:40] for p, _ in BAD_PARAMETERS])
def test_a_bad_parameter_is_refused_naming_it_and_quickly(records, parameters, words):
    r = records[("parameter", json.dumps(parameters))]
    assert r["status"] == 3, r["log"]              # fmi2Error
    for w in words:
        assert w in r["log"], f"{w!r} not in:\n{r['log']}"
    errors = [line for line in r["log"].splitlines() if line.startswith("[error]")]
    assert not any("OSError" in line or "Traceback" in line for line in errors), errors
    assert r["seconds"] < 2.0, r["seconds"]
    assert r["reset"] == 0 and r["usable"] == 0, r["log"]
