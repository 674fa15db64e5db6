"""sensor.speed_std_rel: a speed sensor whose noise is relative to the speed (Meleshin's (2011)
"within 2 %"): std = sensor.speed_std + sensor.speed_std_rel x |V|, in the plant's sensor and in
every place the estimator takes the speed's noise (docs/model.md, "Relative speed noise").

The C core's bit-identity with it set is in tests/model_tests/core/test_core_filter.py, test_core_singer.py and
test_core_chain.py (variants); the native FMUs' in test_native_fmu.py, test_native_fmi3.py and
test_native_estimator_fmu.py.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from models.fpmath import square
from models.chain import ChainConfig, RailCarChain
from models.estimation.coast_ekf import CoastEKF, CoastEKFConfig
from models.compiled import CompiledChain, enabled
from models.plant.dynamics import VehicleParams
from models.filtering.motion_filter import FilterConfig, MotionFilter, ProcessNoiseBank
from models.plant.track import GradeProfile
from models.units import G

LEVEL = GradeProfile((0.0,), (0.0,))
ENGINES = [RailCarChain] + ([CompiledChain] if enabled() else [])


def sensor_errors(engine, speed: float, rel: float, n: int, seed: int = 11):
    """(sensor.speed - car.speed, car.speed) [m/s] over n samples of a car held at ``speed``
    [m/s] on a level track: no process noise, traction = the main resistance at that speed."""
    car = VehicleParams(mass=30.0)
    cfg = ChainConfig(vehicle=car, process_noise_psd=0.0, seed=seed, initial_speed=speed,
                      filter=FilterConfig(speed_std=0.01, speed_std_rel=rel))
    chain = engine(cfg, LEVEL)
    traction = (car.A0 + car.A1 * speed + car.A2 * speed * speed) * car.mass * G   # [N/kN] x [kN]
    err, truth = np.empty(n), np.empty(n)
    t = 0.0
    for k in range(n):
        chain.do_step(t, 0.1, traction, 0.0, 0.0)
        t += 0.1
        out = chain.outputs()
        err[k], truth[k] = out["sensor.speed"] - out["car.speed"], out["car.speed"]
    return err, truth


@pytest.mark.parametrize("engine", ENGINES, ids=lambda e: e.engine)
def test_the_sensors_noise_sd_is_speed_std_plus_rel_times_the_speed(engine):
    """At rest and at 25 m/s (90 km/h), 10,000 samples each, speed_std 0.01 m/s, rel 2 %: the
    sample sd of sensor.speed - car.speed is 0.01 and 0.51 m/s. The sample sd of n independent
    normal draws has a relative standard error of 1/sqrt(2n) = 0.71 %: the tolerance, 4 %, is
    5.6 of those (and the absolute-only sensor, 0.01 m/s at 25 m/s, is 98 % off). The mean error is
    within 5 sd/sqrt(n)."""
    n, std, rel = 10_000, 0.01, 0.02
    for speed in (0.0, 25.0):
        err, truth = sensor_errors(engine, speed, rel, n)
        assert np.ptp(truth) < 1e-3 * max(speed, 1.0)            # the car held its speed
        want = std + rel * speed
        assert abs(err.std(ddof=1) / want - 1.0) < 0.04, (speed, err.std(ddof=1), want)
        assert abs(err.mean()) < 5.0 * want / math.sqrt(n)


@pytest.mark.parametrize("engine", ENGINES, ids=lambda e: e.engine)
def test_rel_zero_draws_the_same_noise_and_rel_scales_the_same_draws(engine):
    """The same stream, scaled: with rel = 0 the errors are speed_std x xi, with rel > 0 the
    same xi times speed_std + rel |V| (to rounding)."""
    e0, v0 = sensor_errors(engine, 20.0, 0.0, 200)
    e1, v1 = sensor_errors(engine, 20.0, 0.03, 200)
    xi0 = e0 / 0.01
    xi1 = e1 / (0.01 + 0.03 * v1)
    np.testing.assert_allclose(xi1, xi0, rtol=1e-9, atol=1e-9)


def test_validation_names_the_setting():
    for bad in (-0.1, math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match=r"^sensor\.speed_std_rel must be >= 0, got "):
            FilterConfig(speed_std_rel=bad).validate(False)
        with pytest.raises(ValueError, match=r"sensor\.speed_std_rel must be >= 0"):
            RailCarChain(ChainConfig(filter=FilterConfig(speed_std_rel=bad)), LEVEL)
    FilterConfig(speed_std_rel=0.0).validate(False)
    FilterConfig(speed_std_rel=-0.0).validate(False)


def test_the_filters_speed_variance_is_at_the_measured_speed():
    """R_v = (speed_std + rel |V_meas|)^2, as the distance's R_x = (position_std + rel |X_meas|)^2;
    with rel = 0 exactly R[0] (speed_std ** 2), whatever the measurement (NaN too)."""
    f = MotionFilter(FilterConfig(speed_std=0.05, speed_std_rel=0.02), LEVEL, None)
    assert f.speed_variance(20.0) == (0.05 + 0.02 * 20.0) ** 2
    assert f.speed_variance(-20.0) == f.speed_variance(20.0)
    assert f.speed_variance(0.0) == f.R[0] == 0.05 ** 2
    g = MotionFilter(FilterConfig(speed_std=0.05), LEVEL, None)
    assert g.speed_variance(20.0) == g.speed_variance(math.nan) == g.R[0]
    # the gate: a 4 m/s innovation at 25 m/s is 5.1 sigma (M + R_v, each ~0.55^2) with rel: taken
    # (GATE_SIGMAS 6); 57 sigma without: refused
    for filt, use in ((f, True), (g, False)):
        filt.start_from_measurement(25.0, 100.0)
        filt.predict(0.0, 0.0, np.array([1.0 / (30.0 * G), 0.0, 0.0, 0.0]), 0.0, 0.1)
        v_pred = filt.predicted_speed
        assert bool(filt.gate(v_pred + 4.0, filt.predicted_position)[0]) is use
    # the start takes the first measurement's variance
    assert f.P[0][0] == square(0.05 + 0.02 * 25.0)


def test_the_likelihood_bank_and_the_coasting_ekf_take_the_measurements_variance():
    """est.sigma2_method 1 and est.method 3: R at each measured speed z."""
    bank = ProcessNoiseBank(1e-4, square(0.05), variance_at=lambda z: square(0.05 + 0.02 * abs(z)))
    bank.update(20.0)
    assert bank.P == [square(0.05 + 0.02 * 20.0)] * len(bank.q)
    cfg = CoastEKFConfig(speed_std=0.05, speed_std_rel=0.02)
    assert cfg.noise_std(20.0) == 0.05 + 0.02 * 20.0
    assert CoastEKFConfig(speed_std=0.05).noise_std(20.0) == 0.05
    ekf = CoastEKF(cfg)
    ekf.start(20.0)
    assert ekf.P[0, 0] == square(0.05 + 0.02 * 20.0)
    with pytest.raises(ValueError, match="speed_std_rel"):
        CoastEKF(CoastEKFConfig(speed_std_rel=-1.0))
