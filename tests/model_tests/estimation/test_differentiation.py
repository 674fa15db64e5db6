"""Tests of models.estimation.differentiation (Sidorenko 1997, MODEL.md section 8) and of
Sidorenko's claims.

Times [s]; speed samples [m/s] (derivative: acceleration [m/s^2]) or distance samples [m]
(derivatives: speed [m/s], acceleration [m/s^2]). All randomness is seeded.
"""
from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from models.estimation.differentiation import (
    WINDOW, LSDifferentiator, fuse_sensors, ls_derivatives, ls_noise_std, ls_weights,
    merge_streams, zero_order_hold,
)

ROOT = Path(__file__).resolve().parents[3]


def load_benchmark():
    """benchmarks/sensor_claims.py is a script, not a package: load it by path, so that the
    test asserts exactly what the benchmark prints."""
    spec = importlib.util.spec_from_file_location("sensor_claims", ROOT / "benchmarks" / "sensor_claims.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod          # dataclasses look their module up while decorating
    spec.loader.exec_module(mod)
    return mod


def unequal_times(rng, n, start=100.0, span=0.6):
    t = start + np.sort(rng.uniform(0.0, span, n))
    assert np.unique(t).size == n
    return t


# ------------------------------------------------------------------ functional core

@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_exact_on_polynomials_of_the_fitted_order(order):
    """Noise-free samples of a polynomial of degree ``order`` at unequal times ~100 s (absolute
    times: the fit centres and scales them): every derivative at the newest sample and at an
    extrapolated instant is exact up to rounding. Bound: 1e-12 * sum_i |W_ki x_i| — rounding
    the data by eps moves the k-th derivative by at most eps * sum |W_ki x_i|; measured
    <= 5e-14 of it."""
    rng = np.random.default_rng(order)
    for n in (order + 1, WINDOW, 10):
        for _ in range(30):
            t = unequal_times(rng, n)
            c = rng.uniform(-10, 10, order + 1)
            t0 = 100.3
            x = sum(c[k] * (t - t0) ** k for k in range(order + 1))
            for te in (t[-1], t[-1] + 0.05):
                d = ls_derivatives(t, x, order, te)
                W = ls_weights(t, order, te)
                for j in range(order + 1):
                    true = sum(c[k] * math.factorial(k) / math.factorial(k - j) * (te - t0) ** (k - j)
                               for k in range(j, order + 1))
                    assert abs(d[j] - true) <= 1e-12 * (np.abs(W[j]) @ np.abs(x)), (n, j)


def test_derivative_of_a_line_is_its_slope():
    """x = 250 m + 15 m/s * t at six unequal times around 100 s: the slope is 15 m/s to 1e-12
    relative with a first- and a second-order fit (whose second derivative is 0 to 1e-9 m/s^2:
    rounding of x ~ 1750 m by 2e-13 m over a 0.6 s window)."""
    rng = np.random.default_rng(42)
    t = unequal_times(rng, WINDOW)
    x = 250.0 + 15.0 * t
    assert ls_derivatives(t, x, 1)[1] == pytest.approx(15.0, rel=1e-12)
    d2 = ls_derivatives(t, x, 2)
    assert d2[1] == pytest.approx(15.0, rel=1e-12)
    assert abs(d2[2]) < 1e-9
    assert ls_derivatives(t, x, 1)[0] == pytest.approx(250.0 + 15.0 * t[-1], rel=1e-14)
    # a parabola is not fitted exactly by a line: the fit must show it (the check can fail)
    xq = 0.5 * 1.0 * (t - 100.0) ** 2
    assert abs(ls_derivatives(t, xq, 1)[1] - (t[-1] - 100.0)) > 1e-3


def test_weights_and_noise_std_closed_form():
    """Six equally spaced samples (period T), order 1: the slope's noise std is
    sigma / sqrt(sum (t - tbar)^2) = sigma / (T sqrt(17.5)) and the value at the newest sample
    sigma sqrt(1/6 + (2.5 T)^2 / (17.5 T^2)) (textbook regression variances; rounding 1e-12).
    The weights reproduce 1 and t (moment conditions)."""
    T, sigma = 0.1, 0.05
    t = 7.0 + T * np.arange(6)
    s = ls_noise_std(t, 1, sigma)
    assert s[1] == pytest.approx(sigma / (T * math.sqrt(17.5)), rel=1e-12)
    assert s[0] == pytest.approx(sigma * math.sqrt(1 / 6 + 2.5 ** 2 / 17.5), rel=1e-12)
    W = ls_weights(t, 1)
    assert W[0].sum() == pytest.approx(1.0, abs=1e-13)
    assert W[1].sum() == pytest.approx(0.0, abs=1e-10)
    assert W[1] @ (t - t[-1]) == pytest.approx(1.0, rel=1e-12)
    with pytest.raises(ValueError):
        ls_weights([1.0, 1.0, 1.0], 1)        # one distinct time cannot give a slope


def test_streaming_differentiator_equals_the_batch_fit():
    """push() returns None until two distinct times, then ls_derivatives over the last six
    samples (bit-identical: same computation); at() evaluates at another instant; times may
    repeat (two sensors read together) but not decrease."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.0, 0.05, 20))
    t[5] = t[4]
    x = rng.standard_normal(20)
    d = LSDifferentiator(order=1)
    assert d.push(t[0], x[0]) is None
    for k in range(1, 20):
        out = d.push(t[k], x[k])
        lo = max(0, k + 1 - WINDOW)
        np.testing.assert_array_equal(out, ls_derivatives(t[lo:k + 1], x[lo:k + 1], 1))
    np.testing.assert_array_equal(d.at(t[-1] + 0.03), ls_derivatives(t[-6:], x[-6:], 1, t[-1] + 0.03))
    with pytest.raises(ValueError):
        d.push(t[-1] - 1.0, 0.0)
    d2 = LSDifferentiator(order=2, window=6)       # distance samples -> speed, acceleration
    tt = np.arange(10) * 0.1
    for tk in tt:
        out = d2.push(tk, 3.0 + 12.0 * tk - 0.4 * tk * tk)
    np.testing.assert_allclose(out[1:], [12.0 - 0.8 * tt[-1], -0.8], rtol=1e-12)


# ---------------------------------------------------------------- several sensors

def three_sensors(profile, offsets=(0.0, 0.037, 0.071), period=0.1, t_end=5.0):
    times = [np.arange(o, t_end, period) for o in offsets]
    return times, [profile(t) for t in times]


def test_fusion_is_exact_on_a_linear_speed_and_aligns_times():
    """Three unsynchronised noise-free sensors of v = 3 + 0.8 t: the fused speed at every tick is
    exact and the acceleration 0.8 (rounding 1e-12). With read delays (each sample stamped
    d_k late), passing the delays restores exactness; ignoring them biases the speed by
    -0.8 * (a mean delay) — the alignment matters."""
    v = lambda t: 3.0 + 0.8 * t
    times, values = three_sensors(v)
    ticks = np.arange(0.05, 5.0, 0.1)
    est = fuse_sensors(times, values, ticks)
    ok = np.isfinite(est.value)
    assert ok.sum() >= ticks.size - 2                 # the window fills after 6 samples
    np.testing.assert_allclose(est.value[ok], v(ticks[ok]), rtol=1e-12)
    np.testing.assert_allclose(est.rate[ok], 0.8, rtol=1e-12)
    delays = (0.02, 0.0, 0.045)
    stamped = [t + d for t, d in zip(times, delays)]
    aligned = fuse_sensors(stamped, values, ticks + 0.05, delays=delays)
    ok = np.isfinite(aligned.value)
    np.testing.assert_allclose(aligned.value[ok], v(ticks[ok] + 0.05), rtol=1e-12)
    naive = fuse_sensors(stamped, values, ticks + 0.05)
    ok = np.isfinite(naive.value)
    assert np.all(naive.value[ok] - v(ticks[ok] + 0.05) < -1e-3)


def test_fusion_equals_the_streaming_fit_on_the_merged_stream():
    """fuse_sensors (vectorised) = LSDifferentiator fed with the merged stream, evaluated at each
    tick (rounding 1e-12), on noisy data."""
    rng = np.random.default_rng(8)
    times, values = three_sensors(lambda t: 10.0 + np.sin(t) + 0.05 * rng.standard_normal(t.size))
    ticks = np.arange(0.05, 5.0, 0.1)
    est = fuse_sensors(times, values, ticks)
    t, x, src = merge_streams(times, values)
    assert np.all(np.diff(t) >= 0) and set(src) == {0, 1, 2}
    d, j = LSDifferentiator(order=1), 0
    for k, tick in enumerate(ticks):
        while j < t.size and t[j] <= tick:
            d.push(t[j], x[j])
            j += 1
        if j >= WINDOW:
            np.testing.assert_allclose([est.value[k], est.rate[k]], d.at(tick), rtol=1e-12, atol=1e-12)
        else:
            assert math.isnan(est.value[k])


def test_zero_order_hold_baseline():
    """ZOH: the latest merged sample at or before each tick; acceleration = difference of
    consecutive held speeds over the tick."""
    times = [np.array([0.0, 0.1, 0.2]), np.array([0.05, 0.15])]
    values = [np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0])]
    z = zero_order_hold(times, values, np.array([-0.01, 0.0, 0.07, 0.12, 0.3]))
    np.testing.assert_array_equal(z.value[1:], [1.0, 10.0, 2.0, 3.0])
    assert math.isnan(z.value[0])
    assert z.rate[3] == pytest.approx((2.0 - 10.0) / 0.05)


# ---------------------------------------------------------------- Sidorenko's claims

BENCH = load_benchmark()


def test_ls_beats_zero_order_hold_on_the_metro_run():
    """Sidorenko's claim on our data (benchmarks/sensor_claims.py, BASE: 3 sensors at 10 Hz with
    phase offsets, noise 0.05 m/s, tick 0.1 s, metro run; 50 seeded runs, median ratios).
    Direction: LS beats ZOH in all four statistics. Values: we measure speed max 1.26x, RMS
    1.26x, acceleration max 1.99x, RMS 1.97x against the claimed 1.5x, 2x, 3x, 7x. Tolerances
    from the spread of the medians over five other seeds (RMS ratios +-1.5 %, max ratios
    +-6 %): 4 % and 12 %. The claimed acceleration gains are not reached here (asserted: a
    change that reproduces them should revisit this test and the report)."""
    r = BENCH.run_config(BENCH.BASE)["ratios"]
    assert all(v > 1.15 for v in r.values()), r
    assert r["speed_rms"] == pytest.approx(1.26, rel=0.04)
    assert r["accel_rms"] == pytest.approx(1.97, rel=0.04)
    assert r["speed_max"] == pytest.approx(1.26, rel=0.12)
    assert r["accel_max"] == pytest.approx(1.99, rel=0.12)
    assert r["speed_rms"] < BENCH.CLAIMS["speed_rms"] and r["accel_rms"] < 0.5 * BENCH.CLAIMS["accel_rms"]


def test_single_sensor_comes_closest_to_the_claimed_acceleration_gain():
    """One sensor at 10 Hz: the six-sample window spans 0.5 s instead of ~0.17 s, so the LS slope
    is ~3x less noisy while the ZOH difference is not: acceleration RMS 5.3x, max 4.7x (claims
    7x, 3x); speed 1.4x (claims 1.5x max, 2x RMS). Same tolerances as above."""
    r = BENCH.run_config(BENCH.SENSITIVITY[1])["ratios"]
    assert "1 sensor" in BENCH.SENSITIVITY[1].label
    assert r["accel_rms"] == pytest.approx(5.29, rel=0.04)
    assert r["accel_max"] == pytest.approx(4.68, rel=0.12)
    assert r["speed_rms"] == pytest.approx(1.43, rel=0.04)
    assert r["accel_max"] > BENCH.CLAIMS["accel_max"]


def test_measured_errors_agree_with_the_noise_theory():
    """The benchmark's RMS errors are noise-dominated and follow from the weights: ZOH
    acceleration sqrt(2) sigma / tick (two independent samples), LS speed and acceleration
    sqrt(mean ||W_k||^2) sigma over the actual windows (ls_noise_std). Within 2 %: the RMS over
    ~37000 ticks (50 runs) has a sampling error ~0.5 % (consecutive ticks share samples), and
    the lag error at the jerk-limited transitions is below 0.1 %; measured agreement 0.3 %.
    So the ratios are set by the window geometry, not by the profile."""
    cfg = BENCH.BASE
    res = BENCH.run_config(cfg)
    profile = BENCH.metro_profile()
    times, _ = BENCH.simulate_sensors(profile, cfg, np.random.default_rng(0))
    t, _, _ = merge_streams(times, [np.zeros(tk.size) for tk in times])
    ticks = np.arange(cfg.tick_offset, profile.duration, cfg.tick)
    n_in = np.searchsorted(t, ticks, side="right")
    var = np.array([ls_noise_std(t[n - WINDOW:n], 1, cfg.noise, tick) ** 2
                    for n, tick in zip(n_in, ticks) if n >= WINDOW])
    assert res["stats"]["ls_v"][1] == pytest.approx(math.sqrt(np.mean(var[:, 0])), rel=0.02)
    assert res["stats"]["ls_a"][1] == pytest.approx(math.sqrt(np.mean(var[:, 1])), rel=0.02)
    assert res["stats"]["zoh_a"][1] == pytest.approx(math.sqrt(2) * cfg.noise / cfg.tick, rel=0.02)
