"""Tests of models.filtering.motion_filter and models.filtering.kalman: eqs. (13)-(19) of MODEL.md, their steady state
(DARE), the EKF.

State (x, X): speed deviation or speed [m/s], distance [m]; dt [s]; process noise q [(m/s)^2].
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from models.plant.dynamics import CarPlant, VehicleParams
from models.filtering.motion_filter import EKF, LINEARISED, PAPER, FilterConfig, MotionFilter
from models.filtering.kalman import ekf_model, gain, linearised_model, predict_paper, update, update_one
from models.estimation.least_squares import theta_from_params
from models.plant.track import GradeProfile, SpeedProfile
from models.units import G

DT = 0.1
THETA_FAST = theta_from_params(30.0, 0.89, 0.3, 0.02)   # larger A1, A2: a visibly below 1
RM = np.diag([0.05 ** 2, 1.0 ** 2])                       # sigma_V = 0.05 m/s, sigma_X = 1 m


# ----------------------------------------------------------------- functional core

def test_linearised_model_is_eq13_with_exact_quadratic_remainder():
    """Eq. (2) is quadratic in V, so around V_zad: V[n+1] = V_zad[n+1] + c + a x - k A2 x^2
    exactly, with a, c, C of eq. (13) and k = g dt / 1000 / (1 + gamma)."""
    rng = np.random.default_rng(13)
    for _ in range(50):
        vz, vz_next = rng.uniform(0, 20, size=2)
        F, B, i = rng.uniform(0, 3e4), rng.uniform(0, 1e4), rng.uniform(-10, 10)
        gamma = rng.uniform(0, 0.2)
        x = rng.uniform(-3, 3)
        a, c, C = linearised_model(vz, vz_next, F, B, i, THETA_FAST, DT, gamma)
        k = G / 1000.0 / (1 + gamma) * DT
        v = vz + x
        eq2 = v + k * (THETA_FAST[0] * (F - B) - THETA_FAST[1] - THETA_FAST[2] * v
                       - THETA_FAST[3] * v * v - i)
        # O(1..20) m/s values combined in a different order: rounding ~1e-14
        assert vz_next + c + a * x - k * THETA_FAST[3] * x * x == pytest.approx(eq2, abs=1e-12)
        assert a == pytest.approx(1 - k * (THETA_FAST[2] + 2 * THETA_FAST[3] * vz), rel=1e-14)  # rounding
        assert C == vz * DT


def _sym(A: np.ndarray):
    """A symmetric 2x2 array as kalman2's nested tuple."""
    return (float(A[0, 0]), float(A[0, 1])), (float(A[0, 1]), float(A[1, 1]))


def test_kalman2_update_is_eqs_15_17_18():
    """P = M - M (M+R)^-1 M = (M^-1 + R^-1)^-1, K = P R^-1 = M (M+R)^-1, x = x_bar + K (z - x_bar)
    (R diagonal: the sensors' noises are independent)."""
    rng = np.random.default_rng(15)
    for _ in range(20):
        A = rng.standard_normal((2, 2))
        M = A @ A.T + 0.1 * np.eye(2)
        R = np.diag(rng.chisquare(2, 2) + 0.1)
        x_bar, z = rng.standard_normal(2), rng.standard_normal(2)
        x_hat, P = update(tuple(x_bar), _sym(M), tuple(z), tuple(np.diag(R)))
        K = np.array(gain(P, tuple(np.diag(R))))
        x_hat, P = np.array(x_hat), np.array(P)
        # 2x2 SPD with cond <= ~1e3: inversions agree to ~1e-12
        np.testing.assert_allclose(P, np.linalg.inv(np.linalg.inv(M) + np.linalg.inv(R)), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(K, M @ np.linalg.inv(M + R), rtol=1e-9, atol=1e-12)  # same
        np.testing.assert_allclose(x_hat, x_bar + K @ (z - x_bar), rtol=1e-12, atol=1e-12)  # same ops


def test_kalman2_update_one_is_the_update_with_one_measurement():
    """update_one(x, C, z, r, i) is the update with H = e_i: the limit of ``update`` when the
    other measurement's noise grows without bound."""
    rng = np.random.default_rng(16)
    for i in (0, 1):
        A = rng.standard_normal((2, 2))
        C = _sym(A @ A.T + 0.1 * np.eye(2))
        x, z, r = (1.0, 2.0), (0.5, -1.0), [0.3, 0.3]
        r[1 - i] = 1e12
        want_x, want_P = update(x, C, z, tuple(r))
        got_x, got_P = update_one(x, C, z[i], r[i], i)
        # 1e12 against O(1) entries: the limit within ~1e-11; rounding ~1e-15
        np.testing.assert_allclose(got_x, want_x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got_P, want_P, rtol=1e-9, atol=1e-9)


def _paper_matrices(a, q):
    A = np.array([[a, 0.0], [DT, 1.0]])
    Q = np.diag([q, 0.0])
    return A, Q


def test_linearised_filter_covariance_converges_to_dare():
    """Constant a (constant V_zad, fixed Theta): iterating (18), (19) from P~[0] = 0 drives the
    prediction covariance M to the DARE solution with A = [[a,0],[dt,1]], Q = diag(sigma^2, 0),
    H = I; P and K follow from it by (18), (17)."""
    vz, q = 12.0, 1e-3
    a, c, C = linearised_model(vz, vz, 20e3, 0.0, 0.0, THETA_FAST, DT)
    assert a < 1.0                                   # stable speed deviation
    A, Q = _paper_matrices(a, q)
    # Q is singular in X, so solve for the *prediction* covariance:
    # M = A M A^T - A M (M + R)^-1 M A^T + Q  <=>  solve_discrete_are(A^T, H^T, Q, R), H = I
    M_star = solve_discrete_are(A.T, np.eye(2), Q, RM)
    R = tuple(np.diag(RM))
    x_bar, M = (0.0, 0.0), ((0.0, 0.0), (0.0, 0.0))
    for _ in range(3000):
        x_hat, P = update(x_bar, M, (0.0, 0.0), R)
        x_bar, M = predict_paper(x_hat, P, a, c, C, DT, q)
    # the slowest mode (distance) contracts by ~0.99 per step: after 3000 steps the transient is
    # ~1e-13 relative (measured 2e-13), so 1e-9 leaves room for rounding only
    np.testing.assert_allclose(M, M_star, rtol=1e-9)
    P_star = M_star - M_star @ np.linalg.solve(M_star + RM, M_star)
    x_hat, P = update(x_bar, M, (0.0, 0.0), R)
    K = gain(P, R)
    np.testing.assert_allclose(P, P_star, rtol=1e-9)                    # same argument
    np.testing.assert_allclose(K, P_star @ np.linalg.inv(RM), rtol=1e-9)  # same argument


def test_paper_kind_motion_filter_reaches_dare():
    """MotionFilter(kind=PAPER), eqs. (13)-(19) verbatim, at constant V_zad reaches the same DARE
    steady state; also its reported stds are the square roots of that steady state."""
    vz, q = 12.0, 1e-3
    sp = SpeedProfile((0.0,), (vz,))
    f = MotionFilter(FilterConfig(dt=DT, speed_std=0.05, position_std=1.0, kind=PAPER),
                     GradeProfile.level(), sp)
    a, _, _ = linearised_model(vz, vz, 20e3, 0.0, 0.0, THETA_FAST, DT)
    A, Q = _paper_matrices(a, q)
    M_star = solve_discrete_are(A.T, np.eye(2), Q, RM)
    for n in range(3000):
        f.update(vz, n * DT * vz)
        f.predict(20e3, 0.0, THETA_FAST, q, DT)
    np.testing.assert_allclose(f.M, M_star, rtol=1e-9)      # as in the kalman2 test above
    assert f.predicted_speed_std == pytest.approx(np.sqrt(M_star[0, 0]), rel=1e-9)     # same
    assert f.predicted_position_std == pytest.approx(np.sqrt(M_star[1, 1]), rel=1e-9)  # same


def test_linearised_kind_motion_filter_reaches_its_dare():
    """MotionFilter(kind=LINEARISED) uses the trapezoid distance update
    Phi = [[a,0],[dt(1+a)/2,1]] and white-acceleration noise Q = q [[1, dt/2],[dt/2, dt^2/3]];
    at constant V_zad its M converges to the DARE with those matrices."""
    vz, q = 12.0, 1e-3
    sp = SpeedProfile((0.0,), (vz,))
    f = MotionFilter(FilterConfig(dt=DT, kind=LINEARISED), GradeProfile.level(), sp)
    a, _, _ = linearised_model(vz, vz, 20e3, 0.0, 0.0, THETA_FAST, DT)
    Phi = np.array([[a, 0.0], [0.5 * DT * (1 + a), 1.0]])
    Q = q * np.array([[1.0, DT / 2], [DT / 2, DT * DT / 3]])
    M_star = solve_discrete_are(Phi.T, np.eye(2), Q, RM)
    for n in range(3000):
        f.update(vz, n * DT * vz)
        f.predict(20e3, 0.0, THETA_FAST, q, DT)
    np.testing.assert_allclose(f.M, M_star, rtol=1e-9)      # as in the kalman2 test above


def test_ekf_model_is_eq2_and_its_derivative():
    """ekf_model: V' = V + k (Theta^T phi - i), dV'/dV = 1 - k (A1 + 2 A2 V), clipped at 0."""
    th = THETA_FAST
    v, F, B, i = 8.0, 12e3, 0.0, 3.0
    k = G / 1000.0 * DT
    v_next, dv = ekf_model(v, F, B, i, th, DT)
    # rounding only
    assert v_next == pytest.approx(v + k * (th[0] * F - th[1] - th[2] * v - th[3] * v * v - i), rel=1e-14)
    assert dv == pytest.approx(1 - k * (th[2] + 2 * th[3] * v), rel=1e-14)   # rounding only
    h = 1e-4
    fd = (ekf_model(v + h, F, B, i, th, DT)[0] - ekf_model(v - h, F, B, i, th, DT)[0]) / (2 * h)
    assert dv == pytest.approx(fd, rel=1e-8)    # central difference is exact for a quadratic; rounding ~1e-12/h
    assert ekf_model(0.05, 0.0, 45e3, 0.0, th, DT)[0] == 0.0     # hard braking: no negative speed


# ----------------------------------------------------------------- MotionFilter on a trajectory

GRADE = GradeProfile((0.0, 150.0, 400.0), (0.0, 10.0, -5.0))


def _schedule(t):
    """Traction 20 kN (below every limit up to 18 m/s), coasting, then service braking to rest."""
    if t < 25.0:
        return 20e3, 0.0
    if t < 55.0:
        return 0.0, 0.0
    return 0.0, 15e3


def _track(kind, speed_noise, position_noise, seed, speed_profile=None, n=900):
    """Run the continuous plant (RK4, h = 0.01 s, no process noise) and the filter on its samples."""
    rng = np.random.default_rng(seed)
    p = VehicleParams()
    theta = theta_from_params(p.mass, p.A0, p.A1, p.A2)
    plant = CarPlant(p, GRADE, step=0.01, noise_psd=0.0, station_dwell=1e9, normal_draws=None)
    f = MotionFilter(FilterConfig(dt=DT, speed_std=0.05, position_std=1.0, kind=kind), GRADE,
                     speed_profile)
    out = []
    for k in range(n):
        zv = plant.state.speed + speed_noise * rng.standard_normal()
        zx = plant.state.position + position_noise * rng.standard_normal()
        f.update(zv, zx)
        out.append((plant.state.speed, plant.state.position, zv, f.speed, f.position))
        F, B = _schedule(k * DT)
        plant.advance((k + 1) * DT, F, B, 0.0)
        f.predict(plant.traction_impulse / DT, plant.brake_impulse / DT, theta, 1e-6, DT)
        plant.traction_impulse = plant.brake_impulse = 0.0
        assert f.predicted_speed >= 0.0
    return np.array(out)


def test_ekf_tracks_noise_free_trajectory():
    """EKF (eq. (2) with the true Theta) on exact measurements of the continuous plant stays on
    the trajectory: traction, coasting over grade breaks, braking to rest."""
    out = _track(EKF, 0.0, 0.0, seed=1)
    v, x, _, v_f, x_f = out.T
    assert v.max() > 15.0 and v[-1] == 0.0         # the run did accelerate and stop
    # Eq. (2) holds i[n] over a step; crossing a grade break (|jump| <= 15 permille) mid-step
    # costs at most g/1000 * 15 * dt = 0.0147 m/s of prediction error, which the measurement
    # update only reduces; the Euler/RK4 mismatch elsewhere is ~1e-5 m/s per step
    assert np.max(np.abs(v_f - v)) <= G / 1000 * 15 * DT
    # distance: that worst-case speed error sustained for 3 s (the filter corrects it within a
    # few steps) is 0.044 m; 0.05 m
    assert np.max(np.abs(x_f - x)) <= 0.05
    assert np.sqrt(np.mean((v_f - v) ** 2)) <= 0.002   # typical error: ~10x below the worst case


def test_ekf_filters_noisy_measurements():
    """With seeded measurement noise (0.05 m/s, 1 m) the EKF's errors are well below the
    measurement noise after the first 10 s."""
    out = _track(EKF, 0.05, 1.0, seed=2)
    v, x, zv, v_f, x_f = out.T
    rms_meas = np.sqrt(np.mean((zv - v) ** 2))
    rms_v = np.sqrt(np.mean((v_f[100:] - v[100:]) ** 2))
    rms_x = np.sqrt(np.mean((x_f[100:] - x[100:]) ** 2))
    # a correct model with q = 1e-6 averages over many samples: measured 0.008 m/s and 0.08 m;
    # half the measurement noise is a loose bound that a broken gain or model would exceed
    assert rms_v <= 0.5 * rms_meas
    assert rms_x <= 0.5 * 1.0


@pytest.mark.parametrize("kind", [EKF, LINEARISED, PAPER])
def test_motion_filter_never_outputs_negative_speed(kind):
    """Noisy measurements (std 0.5 m/s, many negative) around standstill and a braking stop:
    filtered and predicted speeds are never negative and the predicted distance never goes
    back, for every filter kind."""
    sp = SpeedProfile((0.0, 100.0, 700.0, 850.0), (0.0, 15.0, 15.0, 0.0))
    rng = np.random.default_rng(42)
    p = VehicleParams()
    theta = theta_from_params(p.mass, p.A0, p.A1, p.A2)
    f = MotionFilter(FilterConfig(dt=DT, speed_std=0.05, position_std=1.0, kind=kind), GRADE,
                     sp if kind != EKF else None)
    negative_meas = 0
    for k in range(600):
        if k < 300:
            v_true = 0.0                                    # standing at the station
            F, B = 0.0, 0.0
        else:
            v_true = max(0.0, 2.0 - 0.02 * (k - 300))       # creeping, then braking to rest
            F, B = 0.0, 40e3
        zv = v_true + 0.5 * rng.standard_normal()
        negative_meas += zv < 0
        f.update(zv, 5.0 + rng.standard_normal())
        assert f.speed >= 0.0
        f.predict(F, B, theta, 1e-3, DT)
        assert f.predicted_speed >= 0.0
        # the distance prediction never moves backwards either (1e-12 m: rounding of X + V dt)
        assert f.predicted_position >= f.position - 1e-12
        assert f.speed_std >= 0.0 and f.predicted_speed_std >= 0.0
    assert negative_meas > 100                              # the case really exercises the clip


def test_ekf_ignores_speed_profile():
    """The EKF works on absolute speed: giving it a speed profile (even one with V_zad(0) > 0)
    changes none of its outputs."""
    runs = []
    for sp in (None, SpeedProfile((0.0,), (10.0,))):
        f = MotionFilter(FilterConfig(dt=DT, kind=EKF), GRADE, sp)
        trace = []
        for k in range(50):
            f.update(0.5 * k * DT, 0.25 * (k * DT) ** 2)
            f.predict(15e3, 0.0, THETA_FAST, 1e-4, DT)
            trace.append((f.speed, f.position, f.predicted_speed, f.predicted_position))
        runs.append(trace)
    assert runs[0] == runs[1]


def test_restart_resets_to_station_exactly():
    """restart(): V = 0, X = 0 with zero covariance (P~[0] = 0)."""
    f = MotionFilter(FilterConfig(dt=DT, kind=EKF), GradeProfile.level(), None)
    f.update(3.0, 40.0)
    f.predict(1e4, 0.0, THETA_FAST, 1e-3, DT)
    f.restart()
    assert (f.speed, f.position, f.speed_std, f.position_std) == (0.0, 0.0, 0.0, 0.0)
    assert (f.predicted_speed, f.predicted_position) == (0.0, 0.0)


# ----------------------------------------------------------------- the kinds (models/filtering/kinds.py)

from models.filtering.kinds import (  # noqa: E402
    KINDS, SINGER, EKFKind, LinearisedKind, PaperKind, SingerKind, filter_kind,
)

RAMP = SpeedProfile((0.0, 100.0, 700.0, 850.0), (0.0, 15.0, 15.0, 0.0))


def test_each_kind_number_makes_its_class_and_a_bad_one_the_configs_error():
    """filter.kind 0 (auto: linearised with a speed profile, else EKF) and 1-4 build their
    classes; a number outside 0-4 raises, from the factory, FilterConfig.validate's message."""
    assert set(KINDS) == {LINEARISED, EKF, PAPER, SINGER}
    for kind, profile, cls in ((0, None, EKFKind), (0, RAMP, LinearisedKind), (1, RAMP, LinearisedKind),
                               (2, None, EKFKind), (2, RAMP, EKFKind), (3, RAMP, PaperKind),
                               (4, None, SingerKind)):
        f = MotionFilter(FilterConfig(dt=DT, kind=kind), GRADE, profile)
        assert type(f.algorithm) is cls and f.kind == cls.kind
    for bad in (5, -1, 2.5):
        with pytest.raises(ValueError) as made:
            filter_kind(FilterConfig(kind=bad), GRADE, None)
        with pytest.raises(ValueError) as checked:
            FilterConfig(kind=bad).validate(False)
        assert str(made.value) == str(checked.value)
        assert str(made.value).startswith("filter.kind must be 0 (auto)") and str(made.value).endswith(f"got {bad}")


def _run_filters(filters, n=600, seed=4):
    """The same measurements and predictions (a car ramping up along RAMP) through each filter;
    (speed, position, their stds) per step and filter, as an array of float64."""
    rng = np.random.default_rng(seed)
    v = x = 0.0
    out = []
    for k in range(n):
        zv, zx = v + 0.05 * rng.standard_normal(), x + rng.standard_normal()
        row = []
        for f in filters:
            f.gate(zv, zx)
            f.update(zv, zx)
            f.predict(2e4 if k < 300 else 0.0, 0.0, THETA_FAST, 1e-5, DT)
            row += [f.speed, f.position, f.speed_std, f.predicted_speed, f.predicted_position]
        out.append(row)
        a = 0.4 if k < 300 else -0.1
        x += v * DT + 0.5 * a * DT * DT
        v = max(v + a * DT, 0.0)
    return np.array(out)


def test_an_injected_kind_object_runs_instead_of_the_configured_kind():
    """MotionFilter(kind 0, no speed profile, algorithm=PaperKind(... RAMP)) is the paper's
    filter: bit for bit the trajectory of MotionFilter(kind 3, RAMP); the configured kind alone
    (auto without a profile: EKF) gives another one."""
    cfg_auto, cfg_paper = FilterConfig(dt=DT, kind=0), FilterConfig(dt=DT, kind=PAPER)
    injected = MotionFilter(cfg_auto, GRADE, None, algorithm=PaperKind(cfg_auto, GRADE, RAMP))
    assert injected.kind == PAPER
    runs = _run_filters([injected, MotionFilter(cfg_paper, GRADE, RAMP), MotionFilter(cfg_auto, GRADE, None)])
    ours, paper, auto = runs[:, :5], runs[:, 5:10], runs[:, 10:]
    assert np.array_equal(ours.view(np.uint64), paper.view(np.uint64))
    assert np.abs(ours[:, 0] - auto[:, 0]).max() > 1e-3


from models.filtering.motion_filter import ProcessNoiseBank  # noqa: E402


@pytest.mark.parametrize("q_true", [1e-5, 3e-5])
def test_the_process_noise_bank_recovers_a_random_walks_variance(q_true):
    """A random walk of known increment variance q [(m/s)^2] measured with 0.05 m/s noise (the
    library's sensor), 20,000 samples, seeded: the bank's estimate is within half a grid step
    (10^0.125 = 1.33x) of q, starting from a prior centred 3-10x away (est.sigma2_initial 1e-4)."""
    rng = np.random.default_rng(7)
    bank = ProcessNoiseBank(1e-4, 0.05 ** 2)
    v = 0.0
    for _ in range(20_000):
        v += rng.normal() * q_true ** 0.5
        bank.predict(0.0, 0.0)
        bank.update(v + 0.05 * rng.normal())
    assert 1 / 1.34 <= bank.estimate() / q_true <= 1.34
