"""The estimator's prior bounds (identification.PRIOR_BOUNDS, MAX_BATCH_SIZE, MAX_SLOPE_WINDOW):
a value just outside is refused naming the parameter, and at each bound a run stays alive --
every estimator output finite and the filter on the car (issue 29: est.sigma2_initial = 1e300 or
est.mass_std_initial = 1e-300 were accepted, then the filter refused every measurement and
stood at 0 m/s while the car ran at 17 m/s). Runs level_run (400 s) on the chain (C core)."""
import math
import re
from pathlib import Path

import numpy as np
import pytest

from harness.run.driver import chain_result
from harness.run.scenario import load_scenario
from models.estimation.identification import (MAX_BATCH_SIZE, MAX_SLOPE_WINDOW, PRIOR_BOUNDS,
                                              IdentifierConfig)

LIBRARY = Path(__file__).resolve().parents[3] / "scenarios" / "library"

OUTPUTS = ("filter.speed", "filter.position", "filter.speed_std", "est.mass", "est.mass_std",
           "est.A0", "est.A1", "est.A2", "est.A0_std", "est.sigma2")
CONFIGS = {"paper": {}, "slopes+likelihood": {"est.method": 2, "est.sigma2_method": 1}}
FILTER_ON_CAR_MPS = 1.0
"""[m/s] largest |filter.speed - car.speed| that counts as "on the car": the library's filters
stay within 0.13 m/s at every bound below; the stuck filter of the issue was 16.7 m/s off."""

# A prior mass far above the car's is no longer one the data overrule quickly: the filter
# predicts too little acceleration and runs ~9 m/s off the car for a while (1000 t for
# level_run's 34 t car). Bounded for the arithmetic only: finite outputs are asserted there.
FINITE_ONLY = {("mass_initial", 1000.0)}


@pytest.fixture(scope="module")
def level_run():
    return load_scenario(LIBRARY / "level_run.toml")


def _run(scenario, overrides):
    result = chain_result(scenario.chain_setup(overrides).open(), scenario)
    return result


def _bound_cases():
    for name, low, high, _ in PRIOR_BOUNDS:
        for value in (low, high):
            yield name, value


@pytest.mark.parametrize("config", sorted(CONFIGS))
@pytest.mark.parametrize("name,value", list(_bound_cases()), ids=lambda x: str(x))
def test_a_run_at_each_prior_bound_stays_alive(level_run, config, name, value):
    result = _run(level_run, {**CONFIGS[config], f"est.{name}": value})
    for column in OUTPUTS:
        assert np.all(np.isfinite(result[column])), (name, value, column)
    off = float(np.max(np.abs(result["filter.speed"] - result["car.speed"])))
    if (name, value) not in FINITE_ONLY:
        assert off <= FILTER_ON_CAR_MPS, (name, value, off)


@pytest.mark.parametrize("overrides", [{"est.batch_size": MAX_BATCH_SIZE},
                                       {"est.method": 2, "est.slope_window": MAX_SLOPE_WINDOW}],
                         ids=["batch", "window"])
def test_the_largest_sizes_run(level_run, overrides):
    result = _run(level_run, overrides)
    assert np.all(np.isfinite(result["est.mass"])) and np.all(np.isfinite(result["filter.speed"]))
    assert float(np.max(np.abs(result["filter.speed"] - result["car.speed"]))) <= FILTER_ON_CAR_MPS


@pytest.mark.parametrize("name,low,high,rule", PRIOR_BOUNDS, ids=[b[0] for b in PRIOR_BOUNDS])
def test_just_outside_each_bound_is_refused_by_name(name, low, high, rule):
    for outside in (math.nextafter(low, -math.inf), math.nextafter(high, math.inf)):
        with pytest.raises(ValueError, match=rf"est\.{name} must be .*got {re.escape(repr(outside))}$"):
            IdentifierConfig(**{name: outside}).validate()
    IdentifierConfig(**{name: low}).validate()
    IdentifierConfig(**{name: high}).validate()


def test_the_issues_priors_are_refused():
    for name, value in (("sigma2_initial", 1e300), ("mass_std_initial", 1e-300)):
        with pytest.raises(ValueError, match=rf"est\.{name} must be in"):
            IdentifierConfig(**{name: value}).validate()
    for name, value, rule in (("batch_size", 2 ** 31 - 1, "<= 100000"),
                              ("slope_window", 2 ** 31 - 1, "<= 1000")):
        with pytest.raises(ValueError, match=rf"est\.{name} must be {rule}"):
            IdentifierConfig(**{name: value}).validate()
