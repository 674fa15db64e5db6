"""Tests of models.filtering.singer: Boynik et al.'s Singer-type model (MODEL.md section 6) and
its filter.

State z = [w, v, r]: acceleration [m/s^2], speed [m/s], distance [m]; tau, dt [s];
alpha = 1/tau [1/s]; sigma_w, m_w [m/s^2].

Accuracy criterion for Phi and Q: per element, relative to the element itself. Every element of
Q is positive (an integral of products of the non-negative impulse responses e^(-alpha s),
(1 - e^(-alpha s))/alpha, (alpha s - 1 + e^(-alpha s))/alpha^2), so none is small by cancellation,
while the diagonal spans many orders of magnitude in different units (Q[r,r]/Q[w,w] ~ dt^4/20):
a criterion relative to the largest element would be unit-dependent and would accept a Q[r,r]
with no correct digit. The zeros of Phi must be exactly zero.
"""
from __future__ import annotations

import math
from decimal import Decimal, getcontext

import numpy as np
import pytest
from scipy.integrate import quad, quad_vec
from scipy.linalg import expm, solve_discrete_are
from scipy.stats import chi2

from models.filtering import singer
from models.filtering.singer import (
    H_SPEED, H_SPEED_DISTANCE, SERIES_SWITCH, SingerFilter, SingerParams, project_speed,
    seed002_process_noise, seed002_transition, singer_mean_input, singer_mixture_moments,
    singer_predict, singer_process_noise, singer_step, singer_transition, singer_update,
)

X_GRID = (1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0)   # alpha * dt [-]
SIGMA = 0.3                                     # [m/s^2]


def continuous_A(alpha):
    return np.array([[-alpha, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


# ------------------------------------------------------------------ independent references

def reference_decimal(alpha: float, dt: float, sigma: float, digits: int = 60):
    """Phi and Q from the closed forms (Singer 1970, reordered to [w, v, r]) in 60-digit decimal
    arithmetic: the cancellation of O(1) terms to O(x^5) at x = 1e-4 costs 20 digits, 40 remain.
    Inputs are converted exactly from their binary values."""
    getcontext().prec = digits
    a, T, s2 = Decimal(float(alpha)), Decimal(float(dt)), Decimal(float(sigma)) ** 2
    x = a * T
    r, r2 = (-x).exp(), (-2 * x).exp()
    Q = {
        (0, 0): s2 * (1 - r2),
        (0, 1): s2 * (1 - r) ** 2 / a,
        (0, 2): s2 / a ** 2 * (1 - r2 - 2 * x * r),
        (1, 1): s2 / a ** 2 * (2 * x - 3 + 4 * r - r2),
        (1, 2): s2 / a ** 3 * (x * x - 2 * x + 1 - 2 * r + 2 * x * r + r2),
        (2, 2): s2 / a ** 4 * (2 * x ** 3 / 3 - 2 * x * x + 2 * x + 1 - r2 - 4 * x * r),
    }
    Qf = np.empty((3, 3))
    for (i, j), val in Q.items():
        Qf[i, j] = Qf[j, i] = float(val)
    Phi = np.array([[float(r), 0.0, 0.0], [float((1 - r) / a), 1.0, 0.0],
                    [float((x - 1 + r) / a ** 2), float(T), 1.0]])
    return Phi, Qf


def reference_quad(alpha: float, dt: float, sigma: float):
    """Q by its definition, int_0^dt expm(A s) b b^T expm(A s)^T ds, b b^T = diag(2 alpha sigma^2,
    0, 0), with scipy's quad_vec (max-norm tolerance 1e-14 on the dt-scaled, O(1) entries)."""
    A = continuous_A(alpha)
    D = np.array([1.0, dt, dt * dt])

    def f(s):
        g = expm(A * s)[:, 0] / D
        return np.outer(g, g)

    J, _ = quad_vec(f, 0.0, dt, epsabs=0.0, epsrel=1e-14, norm="max")
    return 2.0 * alpha * sigma ** 2 * J * np.outer(D, D)


def van_loan(alpha: float, dt: float, sigma: float):
    """Van Loan (1978): expm([[-A, b b^T], [0, A^T]] dt) = [[., G12], [0, G22]], Phi = G22^T,
    Q = Phi G12."""
    A = continuous_A(alpha)
    M = np.zeros((6, 6))
    M[:3, :3], M[3:, 3:] = -A, A.T
    M[0, 3] = 2.0 * alpha * sigma ** 2
    F = expm(M * dt)
    Phi = F[3:, 3:].T
    Q = Phi @ F[:3, 3:]
    return Phi, 0.5 * (Q + Q.T)


def naive_closed_form(alpha: float, dt: float, sigma: float) -> np.ndarray:
    """The textbook closed form in double precision (Singer 1970), for the negative control."""
    a, T, s2 = alpha, dt, sigma * sigma
    x = a * T
    r, r2 = math.exp(-x), math.exp(-2 * x)
    Q = np.empty((3, 3))
    vals = {(0, 0): s2 * (1 - r2), (0, 1): s2 * (1 - r) ** 2 / a,
            (0, 2): s2 / a ** 2 * (1 - r2 - 2 * x * r),
            (1, 1): s2 / a ** 2 * (2 * x - 3 + 4 * r - r2),
            (1, 2): s2 / a ** 3 * (x * x - 2 * x + 1 - 2 * r + 2 * x * r + r2),
            (2, 2): s2 / a ** 4 * (2 * x ** 3 / 3 - 2 * x * x + 2 * x + 1 - r2 - 4 * x * r)}
    for (i, j), val in vals.items():
        Q[i, j] = Q[j, i] = val
    return Q


def rel_err(M, M_ref):
    """Max per-element relative error; zeros of the reference must be matched exactly."""
    M, M_ref = np.asarray(M), np.asarray(M_ref)
    nz = M_ref != 0.0
    assert np.all(M[~nz] == 0.0)
    return float(np.max(np.abs(M[nz] - M_ref[nz]) / np.abs(M_ref[nz])))


# -------------------------------------------------------------------- mixture moments (3)-(6)

@pytest.mark.parametrize("p0, pp, pm, wp, wm", [
    (0.5, 0.2, 0.15, 1.0, -1.2),
    (0.0, 0.0, 0.0, 1.0, -1.0),      # uniform on [-1, 1]
    (0.3, 0.3, 0.4, 0.8, -1.1),      # no uniform part
    (0.1, 0.05, 0.6, 1.3, -0.9),     # mostly braking: negative mean
    (0.6, 0.1, 0.1, 1.0, 0.0),       # w_max- = 0 (no braking phase)
])
def test_mixture_moments_match_numerical_integration(p0, pp, pm, wp, wm):
    """Boynik et al., eqs. (3)-(6): mean and variance of P0 delta(0) + P+ delta(w+) + P- delta(w-) + h
    on [w-, w+], integrated numerically with scipy.quad (a polynomial integrand: exact to
    rounding, so 1e-12)."""
    m, s = singer_mixture_moments(p0, pp, pm, wp, wm)
    h = (1.0 - p0 - pp - pm) / (wp - wm)
    mass = p0 + pp + pm + quad(lambda w: h, wm, wp, epsabs=1e-14, epsrel=1e-13)[0]
    assert mass == pytest.approx(1.0, abs=1e-12)
    mean = pp * wp + pm * wm + quad(lambda w: w * h, wm, wp, epsabs=1e-14, epsrel=1e-13)[0]
    var = (p0 * mean ** 2 + pp * (wp - mean) ** 2 + pm * (wm - mean) ** 2
           + quad(lambda w: (w - mean) ** 2 * h, wm, wp, epsabs=1e-14, epsrel=1e-13)[0])
    assert m == pytest.approx(mean, rel=1e-12, abs=1e-14)
    assert s == pytest.approx(math.sqrt(var), rel=1e-12)


def test_mixture_special_cases_and_params():
    assert singer_mixture_moments(0, 0, 0, 1.0, -1.0) == pytest.approx((0.0, math.sqrt(1 / 3)), abs=1e-15)
    assert singer_mixture_moments(1.0, 0, 0, 1.0, -1.0) == (0.0, 0.0)
    # two atoms +-a with probability 1/2 each: mean 0, std a
    assert singer_mixture_moments(0, 0.5, 0.5, 0.7, -0.7) == pytest.approx((0.0, 0.7), abs=1e-15)
    p = SingerParams.from_mixture(12.0, 0.5, 0.2, 0.15, 1.0, -1.2)
    assert (p.m_w, p.sigma_w) == singer_mixture_moments(0.5, 0.2, 0.15, 1.0, -1.2)
    assert p.alpha == 1.0 / 12.0
    for bad in [(0.5, 0.5, 0.1, 1.0, -1.0), (-0.1, 0, 0, 1.0, -1.0), (0, 0, 0, 1.0, 0.5),
                (0, 0, 0, -1.0, -2.0)]:
        with pytest.raises(ValueError):
            singer_mixture_moments(*bad)
    with pytest.raises(ValueError):
        SingerParams(tau=0.0, sigma_w=1.0)


# -------------------------------------------------------------------- exact discretisation

@pytest.mark.parametrize("x", X_GRID)
@pytest.mark.parametrize("dt", [0.1, 2.0])
def test_transition_and_noise_match_60_digit_reference(x, dt):
    """Phi and Q within 1e-12 per element of the 60-digit closed form, for alpha dt in 1e-4..10
    (measured: <= ~1.3e-15 for Q, ~1e-16 for Phi; 1e-12 is the requirement)."""
    alpha = x / dt
    Phi_ref, Q_ref = reference_decimal(alpha, dt, SIGMA)
    assert rel_err(singer_transition(alpha, dt), Phi_ref) < 1e-12
    assert rel_err(singer_process_noise(alpha, dt, SIGMA), Q_ref) < 1e-12


@pytest.mark.parametrize("x", X_GRID)
def test_noise_matches_its_definition_by_quadrature_and_van_loan(x):
    """Independent of the closed forms: Q = int expm(A s) b b^T expm(A s)^T ds by quad_vec,
    Phi = expm(A dt), and (for alpha dt <= 1) Van Loan's block exponential. Measured agreement
    <= 5e-14 (quad_vec's expm integrand), so 1e-12. This also validates the 60-digit
    reference's formulas."""
    dt = 0.5
    alpha = x / dt
    Q_quad = reference_quad(alpha, dt, SIGMA)
    assert rel_err(singer_process_noise(alpha, dt, SIGMA), Q_quad) < 1e-12
    assert rel_err(reference_decimal(alpha, dt, SIGMA)[1], Q_quad) < 1e-12
    Phi = singer_transition(alpha, dt)
    assert np.max(np.abs(Phi - expm(continuous_A(alpha) * dt)) / np.maximum(np.abs(Phi), 1e-300)
                  * (Phi != 0)) < 1e-12
    assert np.all(np.triu(Phi, 1) == 0.0)
    if x <= 1.0:   # Van Loan via scipy's expm: measured 1e-15 here, but 1e-11 at x = 10
        Phi_vl, Q_vl = van_loan(alpha, dt, SIGMA)
        assert rel_err(singer_process_noise(alpha, dt, SIGMA), Q_vl) < 1e-12
        assert np.allclose(Phi_vl, Phi, rtol=1e-12, atol=0)


def test_naive_closed_form_loses_accuracy_at_small_alpha_dt():
    """Negative control: in double precision the textbook closed form has no correct digit in
    Q[r, r] at alpha dt = 1e-4 (O(1) terms cancel to ~1e-21), while this module keeps 1e-12.
    At alpha dt = 1 the same formula is fine, so the failure is the cancellation."""
    dt = 0.1
    alpha = 1e-4 / dt
    _, Q_ref = reference_decimal(alpha, dt, SIGMA)
    naive = naive_closed_form(alpha, dt, SIGMA)
    assert abs(naive[2, 2] - Q_ref[2, 2]) / Q_ref[2, 2] > 1e-2
    assert rel_err(singer_process_noise(alpha, dt, SIGMA), Q_ref) < 1e-12
    alpha = 1.0 / dt
    assert rel_err(naive_closed_form(alpha, dt, SIGMA), reference_decimal(alpha, dt, SIGMA)[1]) < 1e-12


def test_series_and_closed_form_agree_at_the_switch():
    """Both branches of every entry are evaluated at SERIES_SWITCH and must agree to 1e-14 (a
    wrong series coefficient or closed form would show here)."""
    for name in singer._TERMS:
        a, b = singer._series(name, SERIES_SWITCH), singer._closed(name, SERIES_SWITCH)
        assert a == pytest.approx(b, rel=1e-14), name


def test_limits_white_acceleration_and_zero_step():
    """x -> 0: Phi -> constant-acceleration kinematics and Q / (2 alpha sigma^2) -> the integrated
    white-acceleration covariance [[T, T^2/2, T^3/6], [., T^3/3, T^4/8], [., ., T^5/20]]
    (to O(x) = 1e-9 relative). dt = 0: Phi = I, Q = 0."""
    dt, alpha = 0.7, 1e-9 / 0.7
    T = dt
    white = np.array([[T, T ** 2 / 2, T ** 3 / 6], [T ** 2 / 2, T ** 3 / 3, T ** 4 / 8],
                      [T ** 3 / 6, T ** 4 / 8, T ** 5 / 20]])
    Q = singer_process_noise(alpha, dt, SIGMA) / (2 * alpha * SIGMA ** 2)
    np.testing.assert_allclose(Q, white, rtol=1e-8)
    np.testing.assert_allclose(singer_transition(alpha, dt),
                               [[1, 0, 0], [T, 1, 0], [T * T / 2, T, 1]], rtol=1e-8)
    assert np.array_equal(singer_transition(0.3, 0.0), np.eye(3))
    assert np.array_equal(singer_process_noise(0.3, 0.0, SIGMA), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        singer_transition(0.3, -0.1)


def test_semigroup_and_covariance_composition():
    """Exactness over unequal steps: Phi(a + b) = Phi(b) Phi(a) and Q(a + b) = Phi(b) Q(a)
    Phi(b)^T + Q(b) (rounding only: 1e-13)."""
    alpha = 0.25
    for a, b in [(0.03, 0.11), (1.0, 2.5), (7.0, 0.001)]:
        Pa, Pb = singer_transition(alpha, a), singer_transition(alpha, b)
        np.testing.assert_allclose(Pb @ Pa, singer_transition(alpha, a + b), rtol=1e-13, atol=0)
        Qa, Qb = singer_process_noise(alpha, a, SIGMA), singer_process_noise(alpha, b, SIGMA)
        assert rel_err(Pb @ Qa @ Pb.T + Qb, singer_process_noise(alpha, a + b, SIGMA)) < 1e-13


def test_relation_to_the_seed_recursion():
    """Boynik et al., eqs. (9), (10): Phi[w, w] = rho = exp(-dt/tau), Q[w, w] = sigma_w^2 q^2,
    q = sqrt(1 - rho^2) — the same as the exact model. Their speed/distance rows (13) are
    Euler steps: their error against the exact Phi is O(dt^2) (ratio 4 when dt halves)."""
    tau = 6.0
    for dt in (0.05, 0.5, 5.0):
        rho = math.exp(-dt / tau)
        q = math.sqrt(1 - rho * rho)
        Phi, Q = singer_transition(1 / tau, dt), singer_process_noise(1 / tau, dt, SIGMA)
        assert Phi[0, 0] == pytest.approx(rho, rel=1e-15)
        assert Q[0, 0] == pytest.approx((SIGMA * q) ** 2, rel=1e-14)
        assert seed002_process_noise(1 / tau, dt, SIGMA)[0, 0] == pytest.approx(Q[0, 0], rel=1e-14)
    errs = [np.max(np.abs(seed002_transition(1 / tau, dt) - singer_transition(1 / tau, dt)))
            for dt in (0.02, 0.01)]
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.02)


def test_stationary_acceleration_variance():
    """The discrete recursion keeps var(w) = sigma_w^2: from 0 it tends to it (constant dt), from
    sigma_w^2 it stays there for any unequal steps (exact discretisation; rounding 1e-13), and a
    Monte Carlo of 40000 independent trajectories (seeded) has var(w) within 4 standard errors
    (sqrt(2/N) relative = 0.7 %) of sigma_w^2 (1 - rho^(2n))."""
    alpha, dt = 1 / 5.0, 0.1
    Phi, Q = singer_transition(alpha, dt), singer_process_noise(alpha, dt, SIGMA)
    P = np.zeros((3, 3))
    for _ in range(2000):                     # 200 s = 40 tau: rho^(2n) = e^-80
        P = Phi @ P @ Phi.T + Q
    assert P[0, 0] == pytest.approx(SIGMA ** 2, rel=1e-12)
    rng = np.random.default_rng(2)
    pww = SIGMA ** 2
    for step in rng.uniform(0.001, 3.0, 200):
        pww = singer_transition(alpha, step)[0, 0] ** 2 * pww + singer_process_noise(alpha, step, SIGMA)[0, 0]
    assert pww == pytest.approx(SIGMA ** 2, rel=1e-13)
    params = SingerParams(tau=5.0, sigma_w=SIGMA)
    z = np.zeros((40000, 3))
    n = 30
    for _ in range(n):
        z = singer_step(z, dt, params, rng.standard_normal(z.shape))
    expected = SIGMA ** 2 * (1 - math.exp(-2 * alpha * dt * n))
    assert np.var(z[:, 0]) == pytest.approx(expected, rel=4 * math.sqrt(2 / z.shape[0]))


def test_mean_acceleration_in_the_prediction():
    """With sigma_w = 0 the prediction is the exact solution of dw/dt = -alpha (w - m_w),
    dv/dt = w, dr/dt = v: w = m + (w0 - m) e^(-alpha t), v = v0 + m t + (w0 - m)(1 - e^(-alpha t))
    /alpha, r = r0 + v0 t + m t^2/2 + (w0 - m)(t - (1 - e^(-alpha t))/alpha)/alpha — in one step or
    in 10 unequal ones (rounding: 1e-12). Ignoring m_w (w decaying to 0) misses
    u = m_w [1 - rho, t x phi2(-x), t^2 x phi3(-x)]."""
    p = SingerParams(tau=4.0, sigma_w=0.0, m_w=0.35)
    a, m = p.alpha, p.m_w
    x0 = np.array([-0.2, 12.0, 100.0])
    t = 3.7

    def exact(t):
        e = math.exp(-a * t)
        return np.array([m + (x0[0] - m) * e,
                         x0[1] + m * t + (x0[0] - m) * (1 - e) / a,
                         x0[2] + x0[1] * t + m * t * t / 2 + (x0[0] - m) * (t - (1 - e) / a) / a])

    x1, P1 = singer_predict(x0, np.zeros((3, 3)), t, p)
    np.testing.assert_allclose(x1, exact(t), rtol=1e-12)
    assert np.all(P1 == 0.0)
    x = x0
    steps = np.random.default_rng(3).dirichlet(np.ones(10)) * t
    for s in steps:
        x, _ = singer_predict(x, np.zeros((3, 3)), s, p)
    np.testing.assert_allclose(x, exact(t), rtol=1e-12)
    u = singer_mean_input(a, t, m)
    x_without_mean = singer_transition(a, t) @ x0         # w decaying to 0 instead of to m_w
    np.testing.assert_allclose(x_without_mean + u, exact(t), rtol=1e-12)
    assert abs(x_without_mean[1] - exact(t)[1]) > 0.4     # m t x phi2(-x) = 0.44 m/s missing
    assert abs(x_without_mean[2] - exact(t)[2]) > 0.5     # m t^2 x phi3(-x) = 0.60 m missing


# ------------------------------------------------------------------------------ the filter

def test_update_is_the_kalman_update():
    """singer_update: K = P H^T (H P H^T + R)^-1, x + K (z - H x), P - K H P (Joseph form equals
    it to rounding: 1e-12)."""
    rng = np.random.default_rng(5)
    for H, m in [(H_SPEED, 1), (H_SPEED_DISTANCE, 2)]:
        A = rng.standard_normal((3, 3))
        P = A @ A.T + 0.1 * np.eye(3)
        R = np.diag(rng.uniform(0.01, 1.0, m))
        x = np.array([0.1, 10.0, 50.0]) + rng.standard_normal(3)
        z = x @ H.T + rng.standard_normal(m)
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x_new, P_new = singer_update(x, P, z, H, R, clip=False)
        np.testing.assert_allclose(x_new, x + K @ (z - H @ x), rtol=1e-12)
        np.testing.assert_allclose(P_new, P - K @ H @ P, rtol=1e-10, atol=1e-12)


def test_speed_is_never_negative():
    """Braking to a stop, then at rest, with noisy speed measurements (std 0.1 m/s, seeded,
    many negative): the filter's speed is >= 0 after every predict and update, while the same
    filter without clipping goes negative (so the clip matters). A negative speed is projected
    as the conditional mean given v = 0: x - P[:, v] v / P[v, v]."""
    p = SingerParams(tau=3.0, sigma_w=0.5, m_w=0.0)
    rng = np.random.default_rng(11)
    dt = 0.1
    t = np.arange(0, 20, dt)
    v_true = np.maximum(8.0 - 1.0 * t, 0.0)
    z = v_true + 0.1 * rng.standard_normal(t.size)
    assert np.sum(z < 0) > 20
    f = SingerFilter(p, x0=[-1.0, 8.0, 0.0], P0=np.diag([0.25, 0.01, 1.0]))
    g = SingerFilter(p, x0=[-1.0, 8.0, 0.0], P0=np.diag([0.25, 0.01, 1.0]), clip=False)
    speeds, unclipped = [], []
    for zk in z:
        for filt, out in ((f, speeds), (g, unclipped)):
            filt.update_speed(zk, 0.1)
            out.append(filt.speed)
            filt.predict(dt)
            out.append(filt.speed)
    assert min(speeds) >= 0.0
    assert min(unclipped) < -0.01
    P = np.array([[0.3, 0.1, 0.0], [0.1, 0.2, 0.05], [0.0, 0.05, 1.0]])
    x = np.array([-0.4, -0.1, 5.0])
    np.testing.assert_allclose(project_speed(x, P), x - P[:, 1] * (-0.1) / 0.2, rtol=1e-15, atol=1e-15)
    assert project_speed(x, P)[1] == 0.0


N_DARE = 4000   # steps: the distance block converges to ~1e-9 by 2000, ~1e-13 by 4000


@pytest.mark.parametrize("x_dt", [1e-3, 0.02, 1.0])
def test_steady_state_covariance_is_the_dare_solution(x_dt):
    """Constant dt: the predicted covariance converges to solve_discrete_are(Phi^T, H^T, Q, R)
    (speed and distance measured). With speed only, r is unobservable, but the (w, v) block
    converges to the DARE of the (w, v) subsystem (P is block-triangular there). Measured
    agreement after N_DARE steps ~1e-13 relative; asserted 1e-10."""
    dt = 0.1
    p = SingerParams(tau=dt / x_dt, sigma_w=0.4)
    Phi = singer_transition(p.alpha, dt)
    Q = singer_process_noise(p.alpha, dt, p.sigma_w)
    R2 = np.diag([0.05 ** 2, 1.0 ** 2])
    f = SingerFilter(p, x0=[0.0, 10.0, 0.0], P0=np.diag([0.16, 1.0, 10.0]))
    for _ in range(N_DARE):
        f.update(np.array([10.0, 0.0]), H_SPEED_DISTANCE, R2)
        f.predict(dt)
    M = solve_discrete_are(Phi.T, H_SPEED_DISTANCE.T, Q, R2)
    np.testing.assert_allclose(f.P, M, rtol=1e-10)
    g = SingerFilter(p, x0=[0.0, 10.0, 0.0], P0=np.diag([0.16, 1.0, 10.0]))
    R1 = np.array([[0.05 ** 2]])
    for _ in range(N_DARE):
        g.update(np.array([10.0]), H_SPEED, R1)
        g.predict(dt)
    M2 = solve_discrete_are(Phi[:2, :2].T, H_SPEED[:, :2].T, Q[:2, :2], R1)
    np.testing.assert_allclose(g.P[:2, :2], M2, rtol=1e-10)


def _nees_run(filter_params: SingerParams, truth_params: SingerParams, seed: int,
              n_runs: int = 400, n_steps: int = 300):
    """N seeded trajectories of the truth at unequal steps (0.05..0.3 s, e.g. track-sensor
    passages), filtered with speed (0.05 m/s) and distance (1 m) measurements. All runs share the
    steps, so one covariance serves the (N, 3) batch, filtered here with numpy's Kalman equations
    on the module's Phi, Q and u (the product's filter is the scalar SingerFilter, checked
    against these equations in test_update_is_the_kalman_update; this test checks the model's
    discretisation against its simulator). Returns NEES [N, steps] and min true speed."""
    ss = np.random.SeedSequence(seed).spawn(4)
    r_dt, r_x0, r_proc, r_meas = (np.random.default_rng(s) for s in ss)
    steps = r_dt.uniform(0.05, 0.3, n_steps)
    R = np.diag([0.05 ** 2, 1.0 ** 2])
    x_hat = np.array([truth_params.m_w, 30.0, 0.0])
    P = np.diag([truth_params.sigma_w ** 2, 0.5 ** 2, 2.0 ** 2])
    truth = x_hat + r_x0.standard_normal((n_runs, 3)) @ np.linalg.cholesky(P).T
    X = np.tile(x_hat, (n_runs, 1))
    nees = np.empty((n_runs, n_steps))
    v_min = np.inf
    for k, dt in enumerate(steps):
        truth = singer_step(truth, dt, truth_params, r_proc.standard_normal((n_runs, 3)))
        v_min = min(v_min, truth[:, 1].min())
        a = filter_params.alpha
        Phi = singer_transition(a, dt)
        X = X @ Phi.T + singer_mean_input(a, dt, filter_params.m_w)
        P = Phi @ P @ Phi.T + singer_process_noise(a, dt, filter_params.sigma_w)
        Z = truth @ H_SPEED_DISTANCE.T + r_meas.standard_normal((n_runs, 2)) * np.sqrt(np.diag(R))
        H = H_SPEED_DISTANCE
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        X = X + (Z - X @ H.T) @ K.T
        IKH = np.eye(3) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        e = truth - X
        nees[:, k] = np.einsum("ni,ij,nj->n", e, np.linalg.inv(P), e)
    return nees, v_min


def test_filter_tracks_a_singer_trajectory_with_consistent_nees():
    """NEES consistency (Bar-Shalom): at 10 check times (every 30 steps) the sum of NEES over
    N = 400 independent runs is chi-square with 3N dof; each must lie in its two-sided
    99.9 % interval (Bonferroni: all 10 jointly at >= 99 %). The average over all runs and
    steps (NEES per dof ~ 1) must be 3 within 5 %: its standard error, from the spread of the
    400 run means, is ~1.2 % (the terms of one run are correlated), so 5 % is ~4 SE. The truth has
    m_w = 0.2 m/s^2 and stays far from v = 0 (asserted), so the clip never acts. Negative
    control: the same filter with sigma_w a third of the truth's is inconsistent (NEES mean
    > 4.5), so the test can fail."""
    truth = SingerParams(tau=5.0, sigma_w=0.3, m_w=0.2)
    nees, v_min = _nees_run(truth, truth, seed=2024)
    assert v_min > 5.0
    n = nees.shape[0]
    lo, hi = chi2.ppf(0.0005, 3 * n), chi2.ppf(0.9995, 3 * n)
    checks = nees[:, 29::30].sum(axis=0)
    assert np.all((checks > lo) & (checks < hi)), (checks / n, lo / n, hi / n)
    assert nees.mean() == pytest.approx(3.0, rel=0.05)
    wrong = SingerParams(tau=5.0, sigma_w=0.1, m_w=0.2)
    nees_wrong, _ = _nees_run(wrong, truth, seed=2024)
    assert nees_wrong.mean() > 4.5
