"""Tests of models.plant.track_sensors: speed from two point track sensors (eq. (15) of
Boynik et al.).

Speeds [m/s], base [m], times, resolution and jitter [s]. Monte Carlo tests are seeded; their
tolerances are from the standard error of the statistic (stated in each test).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from models.plant.track_sensors import (
    TrackSensorPair, interval_error_variance, interval_quantisation_variance, passage_times,
    quantise_time, speed_from_times, track_sensor_speed, track_sensor_speed_bias,
    track_sensor_speed_error_bound, track_sensor_speed_std,
)

BASE = 5.0           # [m]
DELTA = 1e-3         # timer resolution [s]
JITTER = 1e-4        # detection jitter std [s]
N = 200_000


def mc_error_std(v_nominal, pair, rng, n=N, spread=0.02):
    """Std of (v_meas - v) normalised to v_nominal (factor v_nominal^2/v^2), speeds uniform in
    +-spread around v_nominal: b/(v delta) then spans many ticks, so the fractional part of the
    interval in ticks is uniform (the averaging behind delta^2/6)."""
    v = v_nominal * (1.0 + spread * rng.uniform(-1.0, 1.0, n))
    meas, _ = pair.measure(v, rng)
    return float(np.std((meas - v) * (v_nominal / v) ** 2))


def test_exact_without_quantisation_and_midpoint_speed_under_acceleration():
    """No timer error: b / (t2 - t1) is the speed (rounding 1e-12); with constant acceleration
    it is exactly the speed at the midpoint time (t1 + t2)/2."""
    for v in (0.5, 7.0, 33.0):
        assert track_sensor_speed(v, BASE) == pytest.approx(v, rel=1e-12)
    for v in (4.0, 7.0, 33.0):                    # v^2 > 2 * 1.2 * b: reaches sensor 2
        for a in (-1.2, 0.3, 1.0):
            t1, t2 = passage_times(v, BASE, t1=3.0, accel=a)
            assert v * (t2 - t1) + 0.5 * a * (t2 - t1) ** 2 == pytest.approx(BASE, rel=1e-12)
            v_mid = v + a * 0.5 * (t2 - t1)
            assert track_sensor_speed(v, BASE, accel=a, t1=3.0) == pytest.approx(v_mid, rel=1e-12)
    with pytest.raises(ValueError):
        passage_times(1.0, BASE, accel=-0.2)      # stops before sensor 2: 1 - 2 * 0.2 * 5 < 0
    with pytest.raises(ValueError):
        track_sensor_speed(10.0, 0.0)


def test_quantised_stamps_and_worst_case_bound():
    """Stamps are multiples of delta from the timer's phase, at or before the true time; over
    10^5 random phases and speeds the error never exceeds v^2 delta / (b - v delta), and the
    bound is nearly attained (> 90 % of it)."""
    rng = np.random.default_rng(7)
    t = rng.uniform(0, 100, 1000)
    phase = 0.00037
    s = quantise_time(t, DELTA, phase)
    assert np.all(s <= t) and np.all(t - s < DELTA)
    np.testing.assert_allclose((s - phase) / DELTA, np.round((s - phase) / DELTA), atol=1e-6)
    v = rng.uniform(1.0, 40.0, 100_000)
    ph = rng.uniform(0.0, DELTA, v.size)
    t1, t2 = passage_times(v, BASE, t1=rng.uniform(0, 10, v.size))
    meas = speed_from_times(t1, t2, BASE, DELTA, ph)
    bound = track_sensor_speed_error_bound(v, BASE, DELTA)
    ratio = np.abs(meas - v) / bound
    assert ratio.max() <= 1.0 + 1e-9
    assert ratio.max() > 0.9
    assert math.isinf(speed_from_times(0.0, 0.5e-3, BASE, DELTA, 0.0))   # same tick: no speed


@pytest.mark.parametrize("v", [5.0, 10.0, 20.0, 30.0])
def test_monte_carlo_std_matches_formula(v):
    """sigma_v = v^2/b sqrt(delta^2/6 + 2 jitter^2) vs the std of 2e5 simulated passages
    (random timer phase, jitter and speed within +-2 %). Tolerance 2 %: the sample std's
    relative standard error is <= 1/sqrt(2N) = 0.16 % (kurtosis <= 3 for a triangular plus
    normal error), and the first-order formula's neglected terms are O(sigma_e / T) < 0.3 % at
    30 m/s (T = 0.17 s, sigma_e = 0.43 ms)."""
    rng = np.random.default_rng(int(v * 100))
    pair = TrackSensorPair(BASE, DELTA, JITTER)
    formula = track_sensor_speed_std(v, BASE, DELTA, JITTER)
    assert mc_error_std(v, pair, rng) == pytest.approx(formula, rel=0.02)


def test_error_grows_with_the_square_of_speed():
    """The absolute error grows like v^2 (relative error like v delta / b): the Monte Carlo std
    at 30 m/s is 9x the one at 10 m/s within 3 % (two 0.16 % standard errors and the 0.3 %
    second-order term); and 4x from 10 to 20 m/s."""
    rng = np.random.default_rng(30)
    pair = TrackSensorPair(BASE, DELTA, 0.0)
    s10, s20, s30 = (mc_error_std(v, pair, rng) for v in (10.0, 20.0, 30.0))
    assert s30 / s10 == pytest.approx(9.0, rel=0.03)
    assert s20 / s10 == pytest.approx(4.0, rel=0.03)
    ratio = track_sensor_speed_std(30.0, BASE, DELTA) / track_sensor_speed_std(10.0, BASE, DELTA)
    assert ratio == pytest.approx(9.0, rel=1e-14)


def test_fixed_speed_quantisation_variance_depends_on_the_interval():
    """At one exact speed the interval error is not triangular: its variance is delta^2 f (1 - f),
    f the fractional part of b/(v delta). f = 0 (b/v a whole number of ticks): every measurement
    is exact; f = 1/2: delta^2/4, 1.5x the averaged delta^2/6. Monte Carlo over the timer phase
    (2e5 draws) within 2 % (the error takes two values: the variance's standard error is ~0.3 %)."""
    rng = np.random.default_rng(9)
    n = N
    v_whole = BASE / (250 * DELTA)           # T = 250 ticks exactly (20 m/s)
    t1, t2 = passage_times(np.full(n, v_whole), BASE, t1=rng.uniform(0, 10, n))
    meas = speed_from_times(t1, t2, BASE, DELTA, rng.uniform(0, DELTA, n))
    assert np.max(np.abs(meas - v_whole)) < 1e-9
    assert interval_quantisation_variance(v_whole, BASE, DELTA) < 1e-12 * DELTA ** 2
    v_half = BASE / (250.5 * DELTA)
    t1, t2 = passage_times(np.full(n, v_half), BASE, t1=rng.uniform(0, 10, n))
    meas = speed_from_times(t1, t2, BASE, DELTA, rng.uniform(0, DELTA, n))
    interval_err = BASE / meas - BASE / v_half
    assert np.var(interval_err) == pytest.approx(DELTA ** 2 / 4, rel=0.02)
    assert interval_quantisation_variance(v_half, BASE, DELTA) == pytest.approx(DELTA ** 2 / 4, rel=1e-6)
    fs = rng.uniform(0, 1, 100_000)   # averaged over f: delta^2/6
    assert np.mean(DELTA ** 2 * fs * (1 - fs)) == pytest.approx(interval_error_variance(DELTA), rel=0.01)


def test_measurement_reads_high_by_the_second_order_bias():
    """E[b/(T + e)] = v (1 + sigma_e^2/T^2 + ...): the measurement is biased high by
    v^3 sigma_e^2 / b^2. A coarse 5 ms timer at 30 m/s (bias 4.5 mm/s, std 0.37 m/s): the mean
    error of 10^6 passages is positive and within 4 standard errors (0.37 mm/s) of the bias."""
    rng = np.random.default_rng(12)
    pair = TrackSensorPair(BASE, 5e-3, 0.0)
    v = 30.0 * (1 + 0.05 * rng.uniform(-1, 1, 1_000_000))
    meas, _ = pair.measure(v, rng)
    err = meas - v
    se = err.std() / math.sqrt(err.size)
    bias = float(np.mean(track_sensor_speed_bias(v, BASE, 5e-3)))
    assert bias > 10 * se
    assert abs(err.mean() - bias) < 4 * se


def test_time_stamp_is_the_unbiased_midpoint():
    """TrackSensorPair.measure's time stamp: midpoint of the stamps + delta/2 estimates the true
    midpoint without bias (mean within 4 standard errors; std ~delta/sqrt(6)/sqrt(N))."""
    rng = np.random.default_rng(13)
    pair = TrackSensorPair(BASE, DELTA, JITTER)
    v = rng.uniform(5, 30, N)
    t1 = rng.uniform(0, 100, N)
    _, stamp = pair.measure(v, rng, t1=t1)
    _, t2 = passage_times(v, BASE, t1)
    err = stamp - 0.5 * (t1 + t2)
    assert abs(err.mean()) < 4 * err.std() / math.sqrt(N)
    assert err.std() < DELTA


def test_validation():
    for bad in [dict(base=0.0, resolution=1e-3), dict(base=5.0, resolution=-1e-3),
                dict(base=5.0, resolution=1e-3, jitter_std=-1.0)]:
        with pytest.raises(ValueError):
            TrackSensorPair(**bad)
    expected = 20.0 ** 2 / 5.0 * DELTA / math.sqrt(6)
    assert TrackSensorPair(5.0, 1e-3).speed_std(20.0) == pytest.approx(expected, rel=1e-14)
