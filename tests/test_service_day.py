"""studies/service_day.py in short: one seeded hour of service (stops, boarding, wind changes,
the faulty stream's spikes and dropouts) through both estimators, against the study's targets.

The thresholds are the issue's targets. The 24 h day (python studies/service_day.py, ~2 min)
meets them too: mass within 3 sigma 99.85 / 99.99 % (clean / faulty), stops within 1 % 98.0 /
96.4 %, no non-finite output, RSS +0.34 MB after the first hour. ~5 s, so not marked slow.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "studies"))

import service_day as sd  # noqa: E402

HOURS = 1.0
SEED = 1
RSS_EVERY_S = 600.0
# RSS growth from the 10-min reading (after the warm-up: +1.3 MB within the first 5 min) to the
# end of the hour, 30,000 steps. Measured: 4-12 kB. 512 kB is 17 B per step: keeping one float per
# step (32 B with its list slot, 0.96 MB) fails it, an outputs dict per step (~1.2 kB, 36 MB) by far;
# and it leaves 40x the allocator noise measured.
RSS_GROWTH_LIMIT_KB = 512


@pytest.fixture(scope="module")
def day():
    return sd.run_day(HOURS, SEED, rss_every_s=RSS_EVERY_S)


def test_the_hour_is_a_service_day(day):
    """Not vacuous: every step ran, the car made its stops and the faulty stream had faults."""
    assert day["steps"] == round(HOURS * 3600 / 0.1)
    d = day["day"]
    assert d["stops"] >= 15
    assert 28.0 - 1e-9 <= d["total_mass_range_t"][0] <= d["total_mass_range_t"][1] <= 44.0 + 1e-9
    assert d["faults"]["speed"] >= 1 and d["faults"]["zero"] + d["faults"]["hold"] >= 1
    for e in day["estimators"].values():
        assert e["stops"] == d["stops"]            # every arrival scored
        assert e["sigma3_samples"] > 0.5 * day["steps"]


def test_same_seed_same_day():
    """Seeded and reproducible: a shorter run twice gives the same figures."""
    a, b = (sd.run_day(0.1, SEED, rss_every_s=3600.0) for _ in range(2))
    for name in sd.ESTIMATORS:
        ea, eb = a["estimators"][name], b["estimators"][name]
        assert ea["speed_rmse_mps"] == eb["speed_rmse_mps"]
        assert ea["stop_mass_errors"] == eb["stop_mass_errors"]


@pytest.mark.parametrize("name", sd.ESTIMATORS)
def test_no_non_finite_output(day, name):
    e = day["estimators"][name]
    assert e["nonfinite"] == 0, f"first at {e['nonfinite_first']}, by output {e['nonfinite_names']}"


def test_memory_is_flat(day):
    readings = day["rss_kb"]
    assert readings[0][1] > 0, "VmRSS not readable"
    assert readings[1][0] == pytest.approx(RSS_EVERY_S)
    assert day["rss_growth_kb"] == readings[-1][1] - readings[1][1]
    assert day["rss_growth_kb"] <= RSS_GROWTH_LIMIT_KB, readings


@pytest.mark.parametrize("name", sd.ESTIMATORS)
def test_mass_within_three_sigma(day, name):
    """>= 99 % of the moving samples after each run's first batch within 3 est.mass_std."""
    share = day["estimators"][name]["sigma3_share"]
    assert share >= sd.TARGET_SIGMA3_SHARE == 0.99


@pytest.mark.parametrize("name", sd.ESTIMATORS)
def test_mass_at_stops_within_one_percent(day, name):
    """>= 95 % of the stops with the mass within 1 % at the arrival."""
    e = day["estimators"][name]
    errs = np.array(e["stop_mass_errors"])
    assert np.all(np.isfinite(errs))
    assert e["stops_within_share"] >= sd.TARGET_STOP_SHARE == 0.95, \
        f"errors at stops [%]: {np.round(100 * errs, 2).tolist()}"


def test_arrivals_are_the_harness_stops():
    """The study scores the arrivals harness.metrics.estimation.stop_indices finds (its definition, applied
    step by step): the same count on the stored speed trace of a short day."""
    from harness.metrics.estimation import stop_indices
    trace = []
    s = sd.run_day(0.25, SEED, rss_every_s=3600.0, speed_trace=trace)
    assert len(trace) == s["steps"]
    assert len(stop_indices(np.array([0.0] + trace))) == s["estimators"]["clean"]["stops"] >= 3
    assert not math.isnan(s["estimators"]["clean"]["stop_worst"])
