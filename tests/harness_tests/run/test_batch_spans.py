"""Span scenarios (the ATO drives) on the C batch engine (harness.run.batch, models/core/span_driver.c)
equal to the Python loop (harness.run.driver.run_on_chain with harness.run.span_scenario.AtoDriver):
every output and input array bit for bit, the row count (the early end once the last span stands),
every AtoStep the driver recorded and its log lines; a run that logs more than the C side keeps
goes to the Python loop; the refusals name the run and the value.
"""
from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

from harness.run import batch as harness_batch
from harness.run.batch import run_batch, run_chains, span_script_of
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario, scenario_from_dict
from models import batch

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ROOT / "scenarios" / "library"
SPAN_SCENARIOS = sorted(p.stem for p in LIBRARY.glob("ato_*.toml"))
SEEDS = (3, 11)



def differences(expected, got) -> list[str]:
    """What differs between two RunResults of one span run (empty: equal bit for bit)."""
    out = []
    if expected.time.tobytes() != got.time.tobytes():
        return [f"time: {len(expected.time)} rows != {len(got.time)}"]
    if set(expected.signals) != set(got.signals):
        out.append("signal names")
    for name, a in expected.signals.items():
        b = got.signals.get(name)
        if b is None or a.dtype != b.dtype or a.tobytes() != b.tobytes():
            out.append(name)
    for name, a in expected.inputs.items():
        if a.tobytes() != got.inputs[name].tobytes():
            out.append(f"input {name}")
    if expected.driver_steps != got.driver_steps:
        out.append("driver_steps")
    if expected.driver_log != got.driver_log:
        out.append("driver_log")
    return out


def span_variant(name: str, parameters: dict, ato: dict, line: bool = False):
    """ato_nominal (or ato_line's spans) with other parameters and [ato] tuning: runs that log."""
    source = load_scenario(LIBRARY / ("ato_line.toml" if line else "ato_nominal.toml"))
    data = copy.deepcopy(tomllib.loads(Path(source.path).read_text()))
    data["name"] = name
    data["parameters"].update(parameters)
    data["ato"] = {**data.get("ato", {}), **ato}
    return scenario_from_dict(data, f"<{name}>", LIBRARY)


LOGGING = {
    # est.* further than est_gate sigmas from a configured resistance stated this sure: logged once
    "gate": ({"car.A0": 2.0}, {"est_gate": 1.0, "config_resistance_std": 0.01,
                               "config_mass_std": 0.001, "car": {"A0": 0.89}}, False),
    # a supervisor with no gap under a noisy speed: full-brake interventions, each logged
    "overspeed": ({"sensor.speed_std": 0.4}, {"limit_margin": 0.0, "supervisor_gap": 0.0,
                                              "k_sigma": 0.5, "gap_sigma": 0.0}, False),
    "overspeed_line": ({"sensor.speed_std": 0.4}, {"limit_margin": 0.0, "supervisor_gap": 0.0,
                                                   "k_sigma": 0.5, "gap_sigma": 0.0}, True),
}


@pytest.mark.parametrize("name", SPAN_SCENARIOS)
def test_every_library_span_scenario_runs_in_c_equal_to_the_python_loop(name):
    scenario = load_scenario(LIBRARY / f"{name}.toml")
    assert scenario.ato is not None
    assert harness_batch.not_covered(scenario) is None
    overrides = [{"seed": s} for s in SEEDS]
    before = harness_batch.ENGINES["c"]
    got = run_batch([scenario] * len(SEEDS), overrides)
    assert harness_batch.ENGINES["c"] - before == len(SEEDS)        # none fell back to Python
    for ov, result in zip(overrides, got):
        expected = run_on_chain(scenario, ov)
        assert differences(expected, result) == [], (name, ov)
        early = len(result.time) < int(round(scenario.duration_s / scenario.step_s)) + 1
        # a call per step, and when the run ends early the finishing call, not stepped
        assert len(result.driver_steps) == len(result.time) - (0 if early else 1)


def test_the_line_boards_at_its_dwells_and_ends_early_as_the_python_loop():
    scenario = load_scenario(LIBRARY / "ato_line.toml")
    [got] = run_batch([scenario])
    payloads = [s.payload_change for s in got.driver_steps if s.payload_change != 0.0]
    assert payloads == [4.0, -2.0]
    assert {s.span for s in got.driver_steps} == {0, 1, 2}
    assert any(s.dwell for s in got.driver_steps)
    assert len(got.time) < int(round(scenario.duration_s / scenario.step_s)) + 1
    assert np.unique(got.inputs["car.payload"]).tolist() == [0.0, 2.0, 4.0]


@pytest.mark.parametrize("variant", LOGGING)
def test_the_controllers_log_lines_are_the_python_drivers(variant):
    parameters, ato, line = LOGGING[variant]
    scenario = span_variant(variant, parameters, ato, line)
    expected = run_on_chain(scenario)
    assert expected.driver_log, f"{variant}: the Python run logged nothing: the test shows nothing"
    [got] = run_batch([scenario])
    assert differences(expected, got) == [] and got.engine == "c"
    assert all(line.startswith(f"{variant}: span ") for line in got.driver_log)
    if line:
        assert {ln.split(": ")[1] for ln in got.driver_log} >= {"span 1", "span 2"}


def test_a_run_logging_more_than_the_c_side_keeps_runs_on_the_python_loop(monkeypatch):
    scenario = span_variant("overspeed", *LOGGING["overspeed"])
    expected = run_on_chain(scenario)
    assert len(expected.driver_log) > 1
    monkeypatch.setattr(batch, "LOG_CAP", 1)
    before = dict(harness_batch.ENGINES)
    [got] = run_batch([scenario])
    assert harness_batch.ENGINES["python"] == before.get("python", 0) + 1
    assert harness_batch.ENGINES["c"] == before.get("c", 0)
    assert got.engine == "python" and expected.engine == ""
    assert differences(expected, got) == []


def _span_run(name: str):
    scenario = load_scenario(LIBRARY / f"{name}.toml")
    setup = scenario.chain_setup()
    return scenario, [setup.config, setup.grade, setup.speed, span_script_of(scenario)]


def test_refusals_name_the_run_and_the_value():
    scenario, run = _span_run("ato_nominal")
    with pytest.raises(ValueError, match=r"level_run: not a span scenario"):
        span_script_of(load_scenario(LIBRARY / "level_run.toml"))
    short = list(run)
    short[3] = run[3][:-1]
    with pytest.raises(ValueError, match=r"^run 1: span script: expected \d+ values for 1 spans "
                                         r"and 0 wind steps, got \d+$"):
        run_chains([tuple(run), tuple(short)], spans=True)
    bad_step = list(run)
    bad_step[3] = run[3].copy()
    bad_step[3][0] = 0.0
    with pytest.raises(ValueError, match=r"^run 0: step_s must be > 0 and finite, got 0\.0$"):
        run_chains([tuple(bad_step)], spans=True)
    _, line = _span_run("ato_line")
    script = line[3].copy()
    # the second span's dwell_s: after the header, the car, the tuning and span 0's fields and arrays
    at = batch.SPAN_HEADER + batch.SPAN_CAR_FIELDS + batch._batch.SPAN_TUNING_FIELDS
    nl, ng = int(script[at + 5]), int(script[at + 6])
    at += 7 + 2 * nl + 2 * ng
    assert script[at + 3] == 30.0                                   # span 2's dwell_s
    script[at + 3] = 0.0
    line[3] = script
    with pytest.raises(ValueError, match=r"^run 0: span 2: dwell_s = 0\.0 s: the standstill at the "
                                         r"station before it must be > 0$"):
        run_chains([tuple(line)], spans=True)


def test_the_span_script_carries_the_scenarios_ato():
    scenario = load_scenario(LIBRARY / "ato_mass_plus20.toml")
    script = span_script_of(scenario)
    assert script[:5].tolist() == [scenario.step_s, scenario.duration_s, 1.0, 0.0, 1.0]
    car = script[5:5 + batch.SPAN_CAR_FIELDS]
    assert car[0] == scenario.ato_setup().car.mass == 30.0          # the configured car, not the plant's
    assert scenario.parameter("car.mass") == 36.0
