"""The batch drivers' shared script checks and wind schedule (models/core/script_common.c): both
drivers (scenario_driver.c, span_driver.c) refuse a bad run timing, count or wind entry with the
same message, and a one-ulp change of Scenario.wind_at in script_common.c changes the wind every
user reads (a scripted run's and a span run's wind input, the coast times in the wind), so the
bit-identity tests of those users cover the shared copy.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from harness.metrics import estimation
from harness.run import batch as harness_batch
from harness.run.batch import chain_arrays, script_of, span_script_of
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario
from models import batch

from batch_build import CORE, ONE_ULP, ROOT, build_batch, compile_objects

SOURCE = CORE / "script_common.c"
LIBRARY = ROOT / "scenarios" / "library"
WIND_AT = "            w = steps[2 * k + 1];"
"""The value Scenario.wind_at returns, in script_common.c."""


def _run(name: str) -> tuple:
    """The library scenario ``name`` and its C chain arrays (config and profiles)."""
    scenario = load_scenario(LIBRARY / f"{name}.toml")
    setup = scenario.chain_setup()
    return scenario, chain_arrays(setup.config, setup.grade, setup.speed)


def _refusal(run, arrays, script) -> str:
    with pytest.raises(ValueError) as e:
        run([(*arrays, np.ascontiguousarray(script, dtype=float))])
    return str(e.value)


def test_both_drivers_refuse_the_shared_checks_with_one_message():
    scenario, arrays = _run("headwind_change")
    span_scenario, span_arrays = _run("ato_headwind")
    script, span_script = script_of(scenario), span_script_of(span_scenario)
    assert script[9] == span_script[3] == 1                   # one wind step each, at the end
    # (timing or count index in the scripted header, in the span header, bad value, message)
    cases = [(1, 0, math.nan, "step_s must be > 0 and finite, got nan"),
             (1, 0, -0.0, "step_s must be > 0 and finite, got -0.0"),
             (2, 1, -math.inf, "duration_s must be >= 0 and finite, got -inf"),
             (3, 2, 0.5, "stop_after_last_phase must be 0 or 1, got 0.5"),
             (2, 1, 2e9 * script[1], "duration_s / step_s must round to at most 1e9 steps, got 2000000000.0")]
    for at, span_at, value, message in cases:
        bad, span_bad = script.copy(), span_script.copy()
        bad[at], span_bad[span_at] = value, value
        assert _refusal(batch.run_scripts, arrays, bad) == f"run 0: {message}"
        assert _refusal(batch.run_spans, span_arrays, span_bad) == f"run 0: {message}"
    bad, span_bad = script.copy(), span_script.copy()
    bad[9], span_bad[3] = 1e7 + 1, 2.5
    assert _refusal(batch.run_scripts, arrays, bad) == \
        "run 0: script: the number of wind steps must be a whole number in 0..10000000, got 10000001.0"
    assert _refusal(batch.run_spans, span_arrays, span_bad) == \
        "run 0: span script: the number of wind steps must be a whole number in 0..10000000, got 2.5"
    for column, message in ((-2, "wind[0].time_s must be finite, got nan"),
                            (-1, "wind[0].speed_mps must be finite, got nan")):
        bad, span_bad = script.copy(), span_script.copy()
        bad[column], span_bad[column] = math.nan, math.nan
        assert _refusal(batch.run_scripts, arrays, bad) == f"run 0: {message}"
        assert _refusal(batch.run_spans, span_arrays, span_bad) == f"run 0: {message}"


# ---------------------------------------------------------------- one ulp in the wind schedule

@pytest.fixture(scope="module")
def objects(tmp_path_factory) -> list[Path]:
    """The batch binding and every core source but script_common.c, compiled once."""
    return compile_objects(tmp_path_factory.mktemp("script_common_objects"), (SOURCE,))


def _wind_users(module, monkeypatch) -> dict:
    """What reads the wind schedule, with ``module`` as models._batch: a scripted run's and a span
    run's wind input [m/s] (headwind_change, ato_headwind) and the coast times in the wind of
    headwind_change (its truth re-run in its wind), as arrays."""
    scripted = load_scenario(LIBRARY / "headwind_change.toml")
    span = load_scenario(LIBRARY / "ato_headwind.toml")
    with monkeypatch.context() as m:
        m.setattr(batch, "_batch", module)
        assert estimation.c_metrics() is batch, "the C run metrics are not compiled here"
        scripted_run, span_run = harness_batch.run_batch([scripted, span])
        car = scripted.chain_setup().config.vehicle
        coasts = estimation.coast_time_errors(scripted_run, lambda last: (car.A0, car.A1, car.A2),
                                              still_air=True)
    return {"scripted wind": scripted_run.inputs["wind_speed"], "span wind": span_run.inputs["wind_speed"],
            "coasts in the wind": np.array(coasts)}


def _differing(a: dict, b: dict) -> list[str]:
    return [name for name in a if a[name].tobytes() != b[name].tobytes()]


def test_one_ulp_in_the_wind_schedule_is_caught(objects, tmp_path, monkeypatch):
    text = SOURCE.read_text()
    assert text.count(WIND_AT) == 1, f"{WIND_AT!r} is not once in {SOURCE.name}"
    unchanged = _wind_users(build_batch(objects, {SOURCE.name: text}, tmp_path / "unchanged"), monkeypatch)
    assert len(unchanged["coasts in the wind"]) >= 1, "headwind_change has no coast to re-run"
    python = run_on_chain(load_scenario(LIBRARY / "headwind_change.toml"))
    assert unchanged["scripted wind"].tobytes() == python.inputs["wind_speed"].tobytes()
    assert np.any(unchanged["span wind"] != 0.0) and np.any(unchanged["scripted wind"] != 0.0)
    changed = text.replace(WIND_AT, f"            w = steps[2 * k + 1] * {ONE_ULP};")
    mutated = _wind_users(build_batch(objects, {SOURCE.name: changed}, tmp_path / "one_ulp"), monkeypatch)
    assert _differing(unchanged, mutated) == ["scripted wind", "span wind", "coasts in the wind"]
