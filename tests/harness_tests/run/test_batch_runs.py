"""The batch engine (harness.run.batch, models.batch, models/core/scenario_driver.c) against the
Python loop: whole scripted runs in C give run_on_chain's RunResult bit for bit.

Every scripted library scenario (scenarios/library/*.toml without [span]) on its own seed and two
others, and two made-up scenarios that reach every phase action and option (forces given and
defaulted, each until_*, cruise, a payload boarded, wind changes, running on after the last phase)
and a time table (before its first row, between rows, after its last), all in ONE run_batch call:
every output of every row, every input, the times, the dtypes and the number of rows (the early
end) equal run_on_chain's exactly. Bad scripts are refused naming the value; a step the chain
rejects names the run and the step; what the C engine does not cover runs in Python. The one-ulp
mutation test of the C driver is tests/model_tests/core/test_core_scenario_driver.py.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.run.batch import ENGINES, chain_arrays, not_covered, run_batch, run_chains, script_of
from harness.run.driver import ChainStepper, drive, run_on_chain
from harness.run.scenario import load_scenario, scenario_from_dict
from models import batch
from models.chain import StepRejected

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ROOT / "scenarios" / "library"
SCRIPTED = sorted(p.stem for p in LIBRARY.glob("*.toml") if load_scenario(p, check_ato=False).ato is None)
SEEDS = (None, {"seed": 101}, {"seed": 20260})     # None: the scenario's own seed

ALL_PHASES = {
    "name": "all_phases", "step_s": 0.1, "duration_s": 300.0, "stop_after_last_phase": False,
    "parameters": {"car.mass": 31.0, "track.grade_profile": "../profiles/demo_grade.csv", "seed": 5},
    "driver": [
        {"action": "traction", "force_N": 30000.0, "until_time_s": 15.0},
        {"action": "traction", "until_speed_kmh": 50.0},
        {"action": "cruise", "target_speed_kmh": 45.0, "until_distance_m": 700.0},
        {"action": "brake", "force_N": 15000.0, "until_speed_mps": 10.0},
        {"action": "brake", "until_speed_mps": 8.0},
        {"action": "coast", "until_brake_curve": True},
        {"action": "brake_to_stop", "stop_at_m": 1300.0, "decel_mps2": 0.7},
        {"action": "hold", "until_time_s": 10.0, "mass_change_t": 2.5},
        {"action": "traction", "until_speed_mps": 6.0},
        {"action": "cruise", "target_speed_mps": 4.0, "until_time_s": 30.0},
        {"action": "coast", "until_time_s": 5.0},
    ],
    "wind": [{"time_s": 30.0, "speed_mps": 4.0}, {"time_s": 100.0, "speed_mps": -3.0},
             {"time_s": 150.05, "speed_mps": 7.5}],
}
"""Every action, forces given and defaulted, every until_*, a payload, three wind changes (one
between steps), and running on after the last phase (stop_after_last_phase false)."""

TIME_TABLE = {
    "name": "time_table", "step_s": 0.1, "duration_s": 120.0,
    "parameters": {"car.mass": 29.0, "seed": 8},
    "driver_table": {"time_s": [5.0, 20.0, 60.5, 90.0], "traction_N": [20000.0, 35000.0, 0.0, 0.0],
                     "brake_N": [0.0, 0.0, 0.0, 30000.0]},
    "wind": [{"time_s": 0.0, "speed_mps": 2.0}, {"time_s": 50.0, "speed_mps": 6.0}],
}
"""Demands before the first row, interpolated between rows (one not on the step grid), after the
last; wind from t = 0."""


def made_up(data: dict):
    return scenario_from_dict(data, f"<{data['name']}>", LIBRARY)


def cases() -> list[tuple[str, object, dict | None]]:
    out = [(f"{name}-{'own' if ov is None else ov['seed']}", load_scenario(LIBRARY / f"{name}.toml"), ov)
           for name in SCRIPTED for ov in SEEDS]
    out += [(f"{d['name']}-{'own' if ov is None else ov['seed']}", made_up(d), ov)
            for d in (ALL_PHASES, TIME_TABLE) for ov in SEEDS[:2]]
    return out


CASES = cases()


@pytest.fixture(scope="module")
def batched() -> dict:
    """Every case in one run_batch call (many scenarios, profiles and lengths per call)."""
    assert batch.available(), "models._batch is not compiled: setup.py build_ext --inplace"
    before = ENGINES.copy()
    results = run_batch([sc for _, sc, _ in CASES], [ov for _, _, ov in CASES])
    assert ENGINES["c"] - before["c"] == len(CASES) and ENGINES["python"] == before["python"]
    return {cid: r for (cid, _, _), r in zip(CASES, results)}


def assert_same(expected, got, what: str) -> None:
    """Same names, dtypes, lengths and bits (times, outputs, inputs)."""
    assert got.time.dtype == expected.time.dtype and got.time.tobytes() == expected.time.tobytes(), \
        f"{what}: time differs ({len(got.time)} rows, expected {len(expected.time)})"
    assert list(got.signals) == list(expected.signals), what
    for name, a in expected.signals.items():
        b = got.signals[name]
        assert b.dtype == a.dtype, f"{what}: {name} is {b.dtype}, expected {a.dtype}"
        if b.tobytes() != a.tobytes():
            rows = np.nonzero(a.view(np.uint64) != b.view(np.uint64))[0] if a.dtype == float \
                else np.nonzero(a != b)[0]
            pytest.fail(f"{what}: {name} differs first at row {rows[0]} of {len(a)}")
    assert list(got.inputs) == list(expected.inputs), what
    for name, a in expected.inputs.items():
        assert got.inputs[name].tobytes() == a.tobytes(), f"{what}: input {name} differs"
    assert got.driver_steps is None and got.driver_log == list(expected.driver_log) == []
    assert got.scenario is expected.scenario and got.units == expected.units and got.fmu == ""


def test_the_library_has_the_scripted_scenarios_we_expect():
    assert len(SCRIPTED) >= 12 and "station_day" in SCRIPTED
    for name in SCRIPTED:    # every one of them is run by the C engine, not by the fallback
        assert not_covered(load_scenario(LIBRARY / f"{name}.toml")) is None, name


@pytest.mark.parametrize("cid", [c[0] for c in CASES])
def test_batch_run_equals_run_on_chain_bit_for_bit(cid, batched):
    _, scenario, overrides = next(c for c in CASES if c[0] == cid)
    expected = run_on_chain(scenario, overrides)
    assert_same(expected, batched[cid], cid)


def test_made_up_scenarios_reach_every_phase_and_both_table_ends():
    sc = made_up(ALL_PHASES)
    driver = sc.new_driver()
    trace = drive(ChainStepper(sc.chain_setup().open()), sc, driver)
    assert driver.finished and not trace.finished          # ran on after the last phase
    assert len(trace.outputs) == round(sc.duration_s / sc.step_s) + 1
    payload = np.array(trace.inputs)[:, 3]
    assert payload.max() == 2.5 and payload[0] == 0.0
    cruise = np.array(trace.inputs)[:, :2]
    assert np.any((cruise[:, 0] > 0) & (cruise[:, 0] < 40000.0) & (cruise[:, 0] != 30000.0))
    table = made_up(TIME_TABLE).time_table
    assert table.at(0.0) == (20000.0, 0.0) and table.at(100.0) == (0.0, 30000.0)


def test_early_end_rows_and_finished_flag_match_drive():
    names = ("station_day", "level_run", "coasting_rusich_row3")
    scenarios = [load_scenario(LIBRARY / f"{n}.toml") for n in names] + [made_up(ALL_PHASES)]
    runs = []
    for sc in scenarios:
        setup = sc.chain_setup()
        runs.append((setup.config, setup.grade, setup.speed, script_of(sc)))
    done = run_chains(runs)
    for r, sc in enumerate(scenarios):
        trace = drive(ChainStepper(sc.chain_setup().open()), sc)
        assert done.rows[r] == len(trace.outputs), sc.name
        assert bool(done.finished[r]) == trace.finished, sc.name
    assert done.finished.tolist() == [True, True, True, False]
    assert done.outputs.shape[1] == round(900.0 / 0.1) + 1      # sized for the longest script


# ---------------------------------------------------------------- refused input

def level_script() -> tuple:
    sc = load_scenario(LIBRARY / "level_run.toml")
    setup = sc.chain_setup()
    return sc, setup, script_of(sc)


def phase_value(script: np.ndarray, phase: int, field: str) -> int:
    """The index of a phase's field in a flat script."""
    return batch.HEADER + batch.PHASE_FIELDS.index(field) + len(batch.PHASE_FIELDS) * phase


def bad_scripts(script: np.ndarray) -> list[tuple[np.ndarray, str]]:
    def changed(index: int, value: float) -> np.ndarray:
        s = script.copy()
        s[index] = value
        return s
    phases = int(script[7])
    first_action = batch.ACTIONS[int(script[batch.HEADER])]
    return [
        (changed(1, 0.0), "step_s must be > 0 and finite, got 0.0"),
        (changed(2, math.inf), "duration_s must be >= 0 and finite, got inf"),
        (changed(0, 2.0), "script kind must be 0 (phases) or 1 (time table), got 2.0"),
        (changed(6, math.nan), "the driver's car.brake_force_max must be >= 0 and finite, got nan"),
        (changed(3, 0.5), "stop_after_last_phase must be 0 or 1, got 0.5"),
        (changed(7, phases + 1.0), f"script: expected {len(script) + 10} values for {phases + 1} phases"),
        (changed(phase_value(script, 0, "action"), 9.0), "driver[0].action must be a code 0..5"),
        (changed(phase_value(script, 0, "force_N"), math.inf),
         f"driver[0] ({first_action}).force_N must be finite or NaN (not given), got inf"),
        (changed(phase_value(script, 0, "force_N"), -1.0), f"driver[0] ({first_action}).force_N must be >= 0, got -1.0"),
        (changed(phase_value(script, 0, "decel_mps2"), math.nan),
         f"driver[0] ({first_action}).decel_mps2 must be finite, got nan"),
        (changed(phase_value(script, 0, "mass_change_t"), 1.0),
         f"driver[0] ({first_action}).mass_change_t: passengers board only in a hold phase"),
        (changed(phase_value(script, 0, "decel_mps2"), 0.0), f"driver[0] ({first_action}).decel_mps2 must be > 0, got 0.0"),
        (changed(phase_value(script, 0, "target_speed_mps"), -2.0),
         f"driver[0] ({first_action}).target_speed_mps must be > 0, got -2.0"),
        (changed(8, 0.5), "script: the number of table rows must be a whole number in 0..10000000, got 0.5"),
        (changed(2, 1e12), "duration_s / step_s must round to at most 1e9 steps, got 10000000000000.0"),
        (script[:-1], "script: expected"),
        (script[:9], "script: expected at least 10 values (the header), got 9"),
        (np.concatenate([changed(8, 1.0), [0.0, 1.0, 0.0]]),
         "script: a phase script needs phases and no time table (got 4 phases, 1 table rows)"),
    ]


def test_the_python_side_knows_the_c_layout():
    c = batch._batch
    assert (c.OUTPUTS, c.INPUTS, c.HEADER, c.PHASE_FIELDS, c.MAX_STEPS) == \
        (batch.OUTPUTS, batch.INPUTS, batch.HEADER, len(batch.PHASE_FIELDS), batch.MAX_STEPS)


def test_bad_scripts_are_refused_naming_the_value():
    sc, setup, script = level_script()
    assert batch.ACTIONS[int(script[batch.HEADER])] == "traction"
    for bad, message in bad_scripts(script):
        with pytest.raises(ValueError) as e:
            run_chains([(setup.config, setup.grade, setup.speed, script), (setup.config, setup.grade, setup.speed, bad)])
        assert str(e.value).startswith(f"run 1: {message}"), (message, str(e.value))


def test_bad_phases_and_tables_are_refused_naming_them():
    base = dict(step_s=0.1, duration_s=10.0, stop_after_last_phase=True, mass_t=30.0,
                traction_force_max=40000.0, brake_force_max=45000.0)
    sc, setup, _ = level_script()
    def phase(action, **given):
        return {"action": action, "until_brake_curve": False, "decel_mps2": 0.8, "mass_change_t": 0.0,
                **given}
    bad = [
        (dict(phases=[phase("traction"), phase("hold")]),
         "driver[1] (hold).until_time_s: hold needs it (the dwell)"),
        (dict(phases=[phase("brake_to_stop")]), "driver[0] (brake_to_stop).stop_at_m: brake_to_stop needs it"),
        (dict(phases=[phase("cruise", until_time_s=3.0)]), "driver[0] (cruise).target_speed_mps: cruise needs it"),
        (dict(phases=[phase("coast", until_brake_curve=2)]),
         "driver[0] (coast).until_brake_curve must be 0 or 1, got 2.0"),
        (dict(phases=[phase("brake", stop_at_m=-5.0)]), "driver[0] (brake).stop_at_m must be > 0, got -5.0"),
        (dict(table=([0.0, 5.0, 5.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0])),
         "driver_table row 3: time_s must increase, got 5.0"),
        (dict(table=([0.0, 5.0], [1.0, -2.0], [0.0, 0.0])), "driver_table row 2: traction_N must be >= 0, got -2.0"),
        (dict(table=([0.0, 5.0], [1.0, 2.0], [0.0, math.inf])), "driver_table row 2: brake_N must be finite, got inf"),
        (dict(table=([0.0], [1.0], [0.0]), wind=[(0.0, 1.0), (math.nan, 2.0)]),
         "wind[1].time_s must be finite, got nan"),
    ]
    for extra, message in bad:
        with pytest.raises(ValueError) as e:
            run_chains([(setup.config, setup.grade, setup.speed, batch.script_values(**base, **extra))])
        assert str(e.value).startswith(f"run 0: {message}"), (message, str(e.value))
    with pytest.raises(ValueError, match=r"driver\[0\].action: must be one of traction"):
        batch.script_values(**base, phases=[{"action": "sprint"}])
    with pytest.raises(ValueError, match=r"driver\[0\] \(coast\).decel_mps2: missing"):
        batch.script_values(**base, phases=[{"action": "coast", "until_brake_curve": True}])
    with pytest.raises(ValueError, match="give phases or a time table"):
        batch.script_values(**base)


def test_a_rejected_step_names_the_run_and_the_step_as_the_python_loop_rejects_it():
    sc = load_scenario(LIBRARY / "level_run.toml")
    too_strong = replace(sc, phases=(replace(sc.phases[0], force_N=1e9),) + sc.phases[1:])
    with pytest.raises(StepRejected) as python:
        run_on_chain(too_strong)
    with pytest.raises(StepRejected) as c:
        run_batch([sc, too_strong])
    assert str(c.value) == f"run 1: step 0: {python.value}"
    assert "traction_force_demand" in str(c.value)


def test_bad_arrays_are_refused():
    sc, setup, script = level_script()
    arrays = (*chain_arrays(setup.config, setup.grade, setup.speed), script)
    steps = batch.steps_of(script)
    out, inp = np.empty((1, steps + 1, batch.OUTPUTS)), np.empty((1, steps, batch.INPUTS))
    with pytest.raises(ValueError, match="outputs must be float64"):
        batch._batch.run([arrays], np.zeros(out.shape, dtype=np.float32), inp, StepRejected)
    with pytest.raises(ValueError, match=r"outputs must be runs x \(steps \+ 1\)"):
        batch._batch.run([arrays], out[:, :-1], inp, StepRejected)
    short = np.empty((1, steps, batch.OUTPUTS)), np.empty((1, steps - 1, batch.INPUTS))
    with pytest.raises(ValueError, match=f"run 0: {steps} steps, the arrays have room for {steps - 1}"):
        batch._batch.run([arrays], *short, StepRejected)
    with pytest.raises(ValueError, match="run 0: grades must be a C-contiguous float64 array"):
        batch._batch.run([(arrays[0], arrays[1], list(arrays[2]), *arrays[3:])], out, inp, StepRejected)
    with pytest.raises(ValueError, match="run 0: config: the C core takes"):
        batch._batch.run([(arrays[0][:-2], *arrays[1:])], out, inp, StepRejected)
    with pytest.raises(TypeError, match="error must be an exception class"):
        batch._batch.run([arrays], out, inp, "not a class")


# ---------------------------------------------------------------- what the C engine leaves to Python

def test_uncovered_runs_fall_back_to_the_python_loop(monkeypatch):
    sc = load_scenario(LIBRARY / "coasting_rusich_row3.toml")
    method1 = {"est.method": 1}
    assert not_covered(sc, sc.chain_setup(method1)) == "est.method 1 or 3"
    with pytest.raises(ValueError, match="run 0: the C core does not cover est.method 1 or 3"):
        setup = sc.chain_setup(method1)
        run_chains([(setup.config, setup.grade, setup.speed, script_of(sc))])
    before = ENGINES.copy()
    fallback, covered_run = run_batch([sc, sc], [method1, None])
    assert (ENGINES["c"] - before["c"], ENGINES["python"] - before["python"]) == (1, 1)
    assert (fallback.engine, covered_run.engine) == ("python", "c")
    assert_same(run_on_chain(sc, method1), fallback, "est.method 1")
    assert_same(run_on_chain(sc), covered_run, "est.method 2")
    monkeypatch.setenv("RAILCAR_PURE_PYTHON", "1")
    assert not_covered(sc).startswith("the C core is switched off (RAILCAR_PURE_PYTHON)")
    monkeypatch.delenv("RAILCAR_PURE_PYTHON")
    span = load_scenario(LIBRARY / "ato_nominal.toml")
    assert not_covered(span) is None          # span scenarios run in C too (test_batch_spans.py)
    with pytest.raises(ValueError, match="ato_nominal: the batch engine runs scripted scenarios"):
        script_of(span)
