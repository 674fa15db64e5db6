"""The paper's least squares as pure functions, eqs. (3)-(12), plus the sandwich covariance.

Regression form of eq. (2) (docs/model.md, Identification), generalised by a known rotating-mass factor
gamma (gamma = 0 is the paper exactly):

    Theta = (1/(P g), A0, A1, A2)         [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]
    phi(n) = (F[n] - B[n], -1, -V[n], -V[n]^2)
    y(n)   = 1000 (1 + gamma) (V[n+1] - V[n]) / (g dt) + i[n]          [N/kN]   (4)

Each function takes a state and returns the new one (filterpy style); the running car's state
and the product's additions live in models/estimation/identification.py (ParameterIdentifier), which calls
these. 4x4 matrices are flat row-major lists of 16 floats, entry (i, j) at [4 i + j], as in
models/linalg4.py. The arithmetic is scalar Python with a fixed operation order:
models/core/ident.c repeats every expression in the same order and gives the same doubles
(tests/model_tests/core/test_core_ident.py). Rewriting an expression, even into an algebraically equal one,
changes the bits; change ident.c with it.
"""
from __future__ import annotations

import math

import numpy as np

from models import linalg4
from models.fpmath import square
from models.units import G

LAG = 50
"""Residuals summed for the process-noise estimate (ParameterIdentifier.sigma2)."""


# ---------------------------------------------------------------- 4x4 kernels

def plus_outer(M, u) -> list[float]:
    """M + u u^T for a flat row-major 4x4 M (a new list): entry (i, j) is M[i, j] + u[i] u[j]."""
    u0, u1, u2, u3 = u
    return [M[0] + u0 * u0, M[1] + u0 * u1, M[2] + u0 * u2, M[3] + u0 * u3,
            M[4] + u1 * u0, M[5] + u1 * u1, M[6] + u1 * u2, M[7] + u1 * u3,
            M[8] + u2 * u0, M[9] + u2 * u1, M[10] + u2 * u2, M[11] + u2 * u3,
            M[12] + u3 * u0, M[13] + u3 * u1, M[14] + u3 * u2, M[15] + u3 * u3]


def quadratic4(c: list, phi) -> float:
    """phi^T C phi for a flat row-major 4x4 C."""
    p0, p1, p2, p3 = phi
    return (p0 * (c[0] * p0 + c[1] * p1 + c[2] * p2 + c[3] * p3)
            + p1 * (c[4] * p0 + c[5] * p1 + c[6] * p2 + c[7] * p3)
            + p2 * (c[8] * p0 + c[9] * p1 + c[10] * p2 + c[11] * p3)
            + p3 * (c[12] * p0 + c[13] * p1 + c[14] * p2 + c[15] * p3))


# ---------------------------------------------------------------- the paper's algorithm

def regressor(traction: float, brake: float, speed: float) -> tuple[float, float, float, float]:
    """phi(n) = (F - B, -1, -V, -V^2) for forces [N] and speed [m/s], eq. (4)."""
    return (traction - brake, -1.0, -speed, -speed * speed)


def regression_target(speed: float, speed_next: float, grade: float, dt: float,
                      gamma: float = 0.0) -> float:
    """y(n) = 1000 (1+gamma) (V[n+1] - V[n]) / (g dt) + i[n]  [N/kN], eq. (4)."""
    return 1000.0 * (1.0 + gamma) * (speed_next - speed) / (G * dt) + grade


def batch_ls(rows, y, j0=None, prior_mean=None) -> tuple[list[float], list[float]]:
    """Batch LS of the first N pairs (the equations after (7)): returns (Theta, J).

    Without a prior, J = Phi^T Phi and Theta = J^-1 Phi^T Y; R(N) = J / N (eq. (10)). With the
    prior information j0 (the diagonal of J0) centred on prior_mean, the regularised LS:
    J = Phi^T Phi + J0, Theta = J^-1 (Phi^T Y + J0 Theta0). Sums in row order (linalg4.gram,
    gram_t_vec), Gaussian elimination (linalg4.solve; SingularMatrixError when J is singular)."""
    info = linalg4.gram(rows)
    rhs = linalg4.gram_t_vec(rows, y)
    if j0 is not None:
        for i in range(4):
            info[5 * i] += j0[i]
        rhs = [rhs[i] + j0[i] * prior_mean[i] for i in range(4)]
    return linalg4.solve(info, rhs), info


def batch_residuals(rows, y, theta, contiguous) -> tuple[list[float], float, float, int]:
    """The batch's residuals e(k) = y(k) - Theta^T phi(k) (eq. (5)): returns (e, Q_e = sum e^2,
    the sum of e(k) e(k-1) over the pairs k contiguous with k-1, their number)."""
    n = len(y)
    resid = [y[k] - linalg4.dot(rows[k], theta) for k in range(n)]
    q_e = 0.0
    for r in resid:
        q_e += r * r
    lagged_sum, n_lagged = 0.0, 0
    for k in range(1, n):
        if contiguous[k]:
            lagged_sum += resid[k] * resid[k - 1]
            n_lagged += 1
    return resid, q_e, lagged_sum, n_lagged


def rls_step(theta, S, phi, y: float, mu: float, *, check: bool = True):
    """One recursive step, eqs. (8), (9), (11): returns (Theta(n), S(n), e, d), or None when
    ``check`` and phi^T S phi is not > 0 (S has lost positive definiteness to rounding: repair S
    and call again with check=False).

    S = R^-1 (eq. (10)); ``mu`` = 1/n gives ordinary least squares, a constant mu0 forgets with
    factor 1 - mu0. e = y - Theta(n-1)^T phi is the prediction error and d = 1 + mu/(1-mu)
    phi^T S(n-1) phi its variance in units of the residual variance (e / sqrt(d) has the
    variance of e(n); for mu = 1/n, d = 1 + phi^T (Phi^T Phi)^-1 phi):

        K(n)     = S(n-1) phi / (1 + mu (phi^T S(n-1) phi - 1))                        (9)
        Theta(n) = Theta(n-1) + mu K(n) e                                              (8)
        S(n)     = (S(n-1) - S phi phi^T S / ((1 - mu)/mu + phi^T S phi)) / (1 - mu)   (11)
    """
    p0, p1, p2, p3 = phi
    Sp = [S[0] * p0 + S[1] * p1 + S[2] * p2 + S[3] * p3,
          S[4] * p0 + S[5] * p1 + S[6] * p2 + S[7] * p3,
          S[8] * p0 + S[9] * p1 + S[10] * p2 + S[11] * p3,
          S[12] * p0 + S[13] * p1 + S[14] * p2 + S[15] * p3]
    pSp = p0 * Sp[0] + p1 * Sp[1] + p2 * Sp[2] + p3 * Sp[3]
    if check and not pSp > 0.0:
        return None
    th = theta
    e = y - (th[0] * p0 + th[1] * p1 + th[2] * p2 + th[3] * p3)
    g = mu * e / (1.0 + mu * (pSp - 1.0))                                      # (8), (9)
    theta_new = [th[0] + g * Sp[0], th[1] + g * Sp[1], th[2] + g * Sp[2], th[3] + g * Sp[3]]
    c = 1.0 / ((1.0 - mu) / mu + pSp)                                          # (11)
    inv = 1.0 / (1.0 - mu)
    S_new = [(S[4 * i + j] - Sp[i] * Sp[j] * c) * inv for i in range(4) for j in range(4)]
    return theta_new, S_new, e, 1.0 + mu / (1.0 - mu) * pSp


def regularised_forgetting(J, S, phi, mu: float, j0) -> tuple[list[float], list[float]]:
    """After a step with constant forgetting mu0 = ``mu``: returns (J(n), S(n)) with the prior's
    information kept (anti-windup). The information J = R / mu0 forgets its data's share,
    J(n) = (1 - mu0) (J - J0) + J0 + phi phi^T, and R = S^-1 (just updated by (11)) gets the
    prior back, R + mu0^2 J0 -- exactly so: S(n) = (S^-1 + mu0^2 J0)^-1 (linalg4.inverse)."""
    lam = 1.0 - mu
    J_new = []
    for i in range(4):
        for j in range(4):
            d = j0[i] if i == j else 0.0
            J_new.append(lam * (J[4 * i + j] - d) + d + phi[i] * phi[j])
    R = linalg4.inverse(S)
    for i in range(4):
        R[5 * i] += mu * mu * j0[i]
    return J_new, linalg4.inverse(R)


def residual_variance(q_e: float, n: int) -> float:
    """s^2 = Q_e / (n - 4), the residual variance of e(n) [(N/kN)^2]."""
    return q_e / (n - 4)


def sigma2_from_residual(s2: float, dt: float, gamma: float = 0.0) -> float:
    """sigma^2 = g^2 dt^2 / 10^6 * s^2 / (1+gamma)^2  [(m/s)^2], eq. (12)."""
    return G * G * dt * dt / 1e6 * s2 / square(1.0 + gamma)


def mass_from_theta(theta1: float) -> float:
    """P-hat = 1 / (g Theta1) [t]."""
    return 1.0 / (G * theta1)


def theta_from_params(mass: float, a0: float, a1: float, a2: float) -> np.ndarray:
    """Theta for mass [t] and resistance coefficients."""
    return np.array([1.0 / (G * mass), a0, a1, a2])


# ---------------------------------------------------------------- the covariance (sandwich)

def end_row(phi, end_weight: float):
    """A run's first or last regressor as it enters D: phi times end_weight (phi itself for 1)."""
    return phi if end_weight == 1.0 else [end_weight * x for x in phi]


def forget_meats(W, D, lam: float) -> tuple[list[float], list[float]]:
    """W and D weighted by lam^2 = (1 - mu0)^2 before one more row (exponential forgetting; as
    they are for lam = 1)."""
    if lam < 1.0:
        l2 = lam * lam
        W = [w * l2 for w in W]
        D = [d * l2 for d in D]
    return W, D


def accumulate_meats(W, D, phi, last_phi, contiguous: bool, lam: float,
                     end_weight: float) -> tuple[list[float], list[float]]:
    """The meats after one more regressor: returns (W, D).

    W = sum phi phi^T (white noise); D = sum over runs of consecutive pairs of the differenced
    regressors (phi(n) - phi(n-1)) (...)^T, plus each run's two ends, where one sample's
    measurement noise enters alone with weight end_weight (1 for the paper's differences; est.method
    2's slope rows take slope_noise_weight instead, ParameterIdentifier._accumulate_slope). A new
    run closes the previous one's end
    (last_phi) and opens its own. With forgetting, both are first weighted by lam^2 = (1 -
    mu0)^2 (forget_meats). ``contiguous``: phi's pair directly follows last_phi's (None: no open run)."""
    W, D = forget_meats(W, D, lam)
    if contiguous and last_phi is not None:
        last = last_phi
        D = plus_outer(D, (phi[0] - last[0], phi[1] - last[1], phi[2] - last[2], phi[3] - last[3]))
    else:
        if last_phi is not None:
            D = plus_outer(D, end_row(last_phi, end_weight))   # close the previous run
        D = plus_outer(D, end_row(phi, end_weight))            # open a new one
    return plus_outer(W, phi), D


def slope_noise_weight(rows, k) -> tuple[float, float, float, float]:
    """g = sum_i k[i] rows[-1 - i] (i < len(rows)): how the measurement error of one speed sample
    enters the score sum phi(n) e(n) of est.method 2's slope rows, rows[-1] the newest row that
    holds the sample at window position 0 (its slope weight times the step, k[0]), rows[-2] the
    row before (position 1), ... Fewer rows than k: a run's start (or, with k shifted, its end)."""
    g0 = g1 = g2 = g3 = 0.0
    for i in range(min(len(rows), len(k))):
        r = rows[-1 - i]
        w = k[i]
        g0 += w * r[0]
        g1 += w * r[1]
        g2 += w * r[2]
        g3 += w * r[3]
    return g0, g1, g2, g3


def slope_end_terms(M, rows, k, scale: float) -> list[float]:
    """M plus the score terms of the speed samples after the newest row (its window's later
    samples, which no later row of the run holds): sample d = 1 .. len(k) - 1 positions on, the
    rows' weights k[d + i]; each term times the noise std ``scale`` of the run's last row [N/kN]."""
    for d in range(1, len(k)):
        g = slope_noise_weight(rows, k[d:])
        M = plus_outer(M, (scale * g[0], scale * g[1], scale * g[2], scale * g[3]))
    return M


def meat(a: float, b: float, D, W, last_phi, end_weight: float, j0, s2) -> list[float]:
    """M = a D + b W (+ a times the open run's end, last_phi end_weight) + diag(s2) J0: the
    covariance of the score for measurement-noise variance a and process-noise variance b
    [(N/kN)^2], the prior's pseudo-observations (information j0 for noise s2) included."""
    M = [a * d + b * w for d, w in zip(D, W)]
    if last_phi is not None:                 # the open run's end
        sa = math.sqrt(a) * end_weight
        last = last_phi
        M = plus_outer(M, (sa * last[0], sa * last[1], sa * last[2], sa * last[3]))
    M[0] += s2[0] * j0[0]
    M[5] += s2[1] * j0[1]
    M[10] += s2[2] * j0[2]
    M[15] += s2[3] * j0[3]
    return M


def sandwich(Ji, M) -> list[float]:
    """cov(Theta-hat) = J^-1 M J^-1 for the estimator's information J (Ji = J^-1, symmetric) and
    the symmetric meat M (see ``meat``): flat row-major, unrolled; the result is symmetric."""
    (j00, j01, j02, j03, _, j11, j12, j13, _, _, j22, j23, _, _, _, j33) = Ji
    (m00, m01, m02, m03, _, m11, m12, m13, _, _, m22, m23, _, _, _, m33) = M
    t00 = m00 * j00 + m01 * j01 + m02 * j02 + m03 * j03
    t01 = m00 * j01 + m01 * j11 + m02 * j12 + m03 * j13
    t02 = m00 * j02 + m01 * j12 + m02 * j22 + m03 * j23
    t03 = m00 * j03 + m01 * j13 + m02 * j23 + m03 * j33
    t10 = m01 * j00 + m11 * j01 + m12 * j02 + m13 * j03
    t11 = m01 * j01 + m11 * j11 + m12 * j12 + m13 * j13
    t12 = m01 * j02 + m11 * j12 + m12 * j22 + m13 * j23
    t13 = m01 * j03 + m11 * j13 + m12 * j23 + m13 * j33
    t20 = m02 * j00 + m12 * j01 + m22 * j02 + m23 * j03
    t21 = m02 * j01 + m12 * j11 + m22 * j12 + m23 * j13
    t22 = m02 * j02 + m12 * j12 + m22 * j22 + m23 * j23
    t23 = m02 * j03 + m12 * j13 + m22 * j23 + m23 * j33
    t30 = m03 * j00 + m13 * j01 + m23 * j02 + m33 * j03
    t31 = m03 * j01 + m13 * j11 + m23 * j12 + m33 * j13
    t32 = m03 * j02 + m13 * j12 + m23 * j22 + m33 * j23
    t33 = m03 * j03 + m13 * j13 + m23 * j23 + m33 * j33
    c00 = j00 * t00 + j01 * t10 + j02 * t20 + j03 * t30
    c01 = j00 * t01 + j01 * t11 + j02 * t21 + j03 * t31
    c02 = j00 * t02 + j01 * t12 + j02 * t22 + j03 * t32
    c03 = j00 * t03 + j01 * t13 + j02 * t23 + j03 * t33
    c11 = j01 * t01 + j11 * t11 + j12 * t21 + j13 * t31
    c12 = j01 * t02 + j11 * t12 + j12 * t22 + j13 * t32
    c13 = j01 * t03 + j11 * t13 + j12 * t23 + j13 * t33
    c22 = j02 * t02 + j12 * t12 + j22 * t22 + j23 * t32
    c23 = j02 * t03 + j12 * t13 + j22 * t23 + j23 * t33
    c33 = j03 * t03 + j13 * t13 + j23 * t23 + j33 * t33
    return [c00, c01, c02, c03, c01, c11, c12, c13, c02, c12, c22, c23, c03, c13, c23, c33]


def noise_split_lag1(c0: float, c1: float) -> tuple[float, float]:
    """(a, b) [(N/kN)^2] from the residuals' lag-0 and lag-1 autocovariance: e(n) = u(n+1) -
    u(n) + p(n), var(u) = a, var(p) = b, gives c0 = 2a + b, c1 = -a; a >= 0, b >= 1e-12 c0."""
    a = max(-c1, 0.0)
    b = max(c0 - 2.0 * a, 1e-12 * c0)
    return a, b


def process_share_lag(a: float, cL: float, c0: float, end_factor: float, lag: int = LAG) -> float:
    """b [(N/kN)^2] from the mean square cL of sums of ``lag`` consecutive residuals: cL =
    end_factor a + lag b (the measurement part telescopes), floored at 1e-3 c0 / lag."""
    return max((cL - end_factor * a) / lag, 1e-3 * c0 / lag)


# ---------------------------------------------------------------- mass restart, repair

def marginalise_meat(M, t, lam: float) -> list[float]:
    """The meat of the A's estimator A - t Theta1 after 1/(Pg) is marginalised out (t = J_A0 /
    J_00, 3 entries): T M T^T with T = [-t, I], symmetrised, times lam (run-to-run forgetting);
    Theta1's row and column zero."""
    M = list(M)
    m00 = M[0]
    M_AA = [((M[4 * i + j] - t[i - 1] * M[j]) - M[4 * i] * t[j - 1]) + t[i - 1] * t[j - 1] * m00
            for i in (1, 2, 3) for j in (1, 2, 3)]          # 3x3, row-major
    for i in range(3):
        for j in range(3):
            M[4 * (i + 1) + j + 1] = 0.5 * (M_AA[3 * i + j] + M_AA[3 * j + i]) * lam
    for k in range(4):
        M[k] = 0.0
        M[4 * k] = 0.0
    return M


def marginalise_mass(R, lam: float, j0) -> list[float]:
    """An information matrix R with Theta1 marginalised out of the A's block (R_AA - R_A0 R_0A /
    R_00), the data's share of it forgotten (lam (R_AA - j0_A) + j0_A, when lam < 1), and Theta1
    reopened with its prior information j0[0] alone."""
    R = list(R)
    r00 = R[0]
    for i in (1, 2, 3):
        for j in (1, 2, 3):
            R[4 * i + j] -= R[4 * i] * R[j] / r00
    if lam < 1.0:
        for i in (1, 2, 3):
            for j in (1, 2, 3):
                d = j0[i] if i == j else 0.0
                R[4 * i + j] = lam * (R[4 * i + j] - d) + d
    for k in (1, 2, 3):
        R[k] = 0.0
        R[4 * k] = 0.0
    R[0] = j0[0]
    return R


def drift_meat(M, info, info_scale: float, j0, drift_var) -> list[float]:
    """M plus Jc diag(drift_var) Jc in its A block: the score's covariance from a random walk
    eps ~ N(0, diag(drift_var)) of the carried A0, A1 since their data were taken (a wind
    change moves A0 by A2 Vw^2 and A1 by 2 A2 Vw). Jc is the data's information on the A's as
    carried, info's A block (info_scale times it is J: n_info for R, 1 for J) symmetrised, the
    prior's j0 left out (the prior's std covers the truth's range already); the estimate's error
    gains J^-1 Jc eps. drift_var = (q0^2, q1^2) [(N/kN)^2, (N/kN/(m/s))^2]: A2 does not drift.
    Each entry (Jc_i0 Jc_j0) q0^2 + (Jc_i1 Jc_j1) q1^2, so the added block is exactly
    symmetric."""
    Jc = []
    for i in (1, 2, 3):
        for j in (1, 2, 3):
            d = j0[i] if i == j else 0.0
            Jc.append(0.5 * (info[4 * i + j] + info[4 * j + i]) * info_scale - d)
    v0, v1 = drift_var
    M = list(M)
    for i in range(3):
        for j in range(3):
            M[4 * (i + 1) + j + 1] += (Jc[3 * i] * Jc[3 * j]) * v0 + (Jc[3 * i + 1] * Jc[3 * j + 1]) * v1
    return M


def drift_covariance(cov, Ji, Dq) -> list[float]:
    """cov plus J^-1 Dq J^-1 for the drift meat Dq (drift_meat), with J^-1 symmetrised first:
    R from the recursive steps is ~30 % asymmetric in its mass-A terms after a day, and
    ``sandwich`` reads one triangle, which cancelled the mass's share of Dq to nothing (its std
    went to 0 on a service day in the first try)."""
    Js = [0.5 * (Ji[4 * i + j] + Ji[4 * j + i]) for i in range(4) for j in range(4)]
    c = sandwich(Js, Dq)
    return [x + y for x, y in zip(cov, c)]


def positive_definite_S(S, floor: float) -> list[float]:
    """S with R = S^-1 made positive definite: R symmetrised, its eigenvalues lifted to at least
    ``floor`` (Jacobi, linalg4.eigh), S = V diag(w)^-1 V^T."""
    R = linalg4.inverse(S)
    w, V = linalg4.eigh([0.5 * (R[4 * i + j] + R[4 * j + i]) for i in range(4) for j in range(4)])
    w = [max(x, floor) for x in w]
    return linalg4.inverse_from_eigen(w, V)
