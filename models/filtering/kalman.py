"""The paper's Kalman filter of (speed, distance) as pure functions, eqs. (13)-(19) (docs/model.md, Kalman filters).

State x = (x0, X): x0 the speed part [m/s] (V - V_zad for the linearised filter, V for the
EKF), X the distance from the previous station [m]. Covariances are symmetric 2x2 matrices held
as nested tuples ((c00, c01), (c01, c11)) (``np.array`` of one is the matrix). Measurements
z = (V_meas - V_zad, X_meas), H = I (14), noise R = diag(r0, r1) held as (r0, r1).

Each function takes a state and returns the new one (filterpy style); the running filter's
bookkeeping (the gate, reacquiring, V_zad, the Singer kind) lives in models/filtering/motion_filter.py
(MotionFilter), which calls these. The arithmetic is scalar Python with a fixed operation
order: models/core/filter.c repeats every expression in the same order and gives the same
doubles (tests/model_tests/core/test_core_filter.py). Rewriting an expression, even into an algebraically equal
one, changes the bits; change filter.c with it.
"""
from __future__ import annotations

from models.units import G


# ---------------------------------------------------------------- the car's model, eqs. (2), (13)
# eq. (2) mirrors models/core/filter.c operation for operation: bit-identity, tests/model_tests/core/test_core_filter.py

def specific_net_force(traction: float, brake: float, speed: float, grade: float, theta) -> float:
    """(F-B)/(Pg) - A0 - A1 V - A2 V^2 - i [N/kN] with Theta = (1/(Pg), A0, A1, A2)."""
    return theta[0] * (traction - brake) - theta[1] - theta[2] * speed - theta[3] * speed * speed - grade


def linearised_model(vzad: float, vzad_next: float, traction: float, brake: float, grade: float,
                     theta, dt: float, gamma: float = 0.0) -> tuple[float, float, float]:
    """(a[n], c[n], C[n]) of eq. (13) around the reference speeds V_zad[n], V_zad[n+1] [m/s]."""
    k = G / 1000.0 / (1.0 + gamma) * dt
    c = vzad - vzad_next + k * specific_net_force(traction, brake, vzad, grade, theta)
    a = 1.0 - k * (theta[2] + 2.0 * theta[3] * vzad)
    return a, c, vzad * dt


def ekf_model(speed: float, traction: float, brake: float, grade: float, theta,
              dt: float, gamma: float = 0.0) -> tuple[float, float]:
    """Eq. (2) without noise for a moving car: (V[n+1], dV[n+1]/dV[n]), V >= 0."""
    k = G / 1000.0 / (1.0 + gamma) * dt
    v_next = speed + k * specific_net_force(traction, brake, speed, grade, theta)
    dv = 1.0 - k * (theta[2] + 2.0 * theta[3] * speed)
    return max(v_next, 0.0), dv


# ---------------------------------------------------------------- the filter, eqs. (15)-(19)

def gain(P, R):
    """K = P R^-1, eq. (17), for R = diag(r0, r1)."""
    (p00, p01), (_, p11) = P
    r0, r1 = R
    return (p00 / r0, p01 / r1), (p01 / r0, p11 / r1)


def update(x_bar, M, z, R):
    """Eqs. (18), (17), (15) with H = I: (x_hat, P) from the prediction (x_bar, M).

    P = M - M (M + R)^-1 M, symmetrised (18); K = P R^-1 (17); x_hat = x_bar + K (z - x_bar)
    (15). Python's ZeroDivisionError when M + R is singular.
    """
    (m00, m01), (_, m11) = M
    r0, r1 = R
    s00, s11 = m00 + r0, m11 + r1                     # M + R and its inverse
    det = s00 * s11 - m01 * m01
    i00, i01, i11 = s11 / det, -m01 / det, s00 / det
    a00 = m00 * i00 + m01 * i01                       # A = M (M + R)^-1
    a01 = m00 * i01 + m01 * i11
    a10 = m01 * i00 + m11 * i01
    a11 = m01 * i01 + m11 * i11
    p00 = m00 - (a00 * m00 + a01 * m01)               # (18) P = M - A M
    p01 = m01 - 0.5 * ((a00 * m01 + a01 * m11) + (a10 * m00 + a11 * m01))
    p11 = m11 - (a10 * m01 + a11 * m11)
    P = (p00, p01), (p01, p11)
    e0, e1 = z[0] - x_bar[0], z[1] - x_bar[1]
    (k00, k01), (k10, k11) = gain(P, R)               # (17)
    return (x_bar[0] + k00 * e0 + k01 * e1, x_bar[1] + k10 * e0 + k11 * e1), P   # (15)


def update_one(x, C, z: float, r: float, i: int):
    """The update with one measurement z of x[i] (H = e_i), noise variance r: (x', C').

    k = C h / (h^T C h + r), x' = x + k (z - x[i]), C' = C - k (C h)^T.
    """
    (c00, c01), (_, c11) = C
    ch0, ch1 = C[0][i], C[1][i]                       # C h
    s = C[i][i] + r
    k0, k1 = ch0 / s, ch1 / s
    e = z - x[i]
    p01 = c01 - k0 * ch1
    return (x[0] + k0 * e, x[1] + k1 * e), ((c00 - k0 * ch0, p01), (p01, c11 - k1 * ch1))


def forward(x, vzad: float):
    """x with the speed V = x0 + V_zad clipped at 0: a car never moves backwards."""
    return (-vzad, x[1]) if x[0] + vzad < 0.0 else x


def predict_paper(x_hat, P, a: float, c: float, C: float, dt: float, q: float):
    """Eqs. (16), (19) verbatim: x_bar = u + Phi x_hat, M = Phi P Phi^T + diag(q, 0) with
    Phi = [[a, 0], [dt, 1]] and u = (c, C) of eq. (13) (Euler distance)."""
    xh0, xh1 = x_hat
    (p00, p01), (_, p11) = P
    m01 = a * (dt * p00 + p01)
    return ((c + a * xh0, C + dt * xh0 + xh1),
            ((a * a * p00 + q, m01), (m01, dt * dt * p00 + 2.0 * dt * p01 + p11)))


def predict(x_hat, P, dv: float, v0: float, dt: float, q: float):
    """The filter's own prediction on absolute speed, x_hat = (V, X) [m/s, m]: the speed row
    V' = max(v0 + dv V, 0) (eq. (13) or the EKF's (2) linearised at the estimate), the distance
    by the trapezoid rule X' = X + dt (V + V') / 2, so Phi = [[dv, 0], [dt (1 + dv) / 2, 1]], and
    the process noise as white acceleration noise over the step, which moves the distance too:
    Q = q [[1, dt/2], [dt/2, dt^2/3]]. (The paper's X' = X + V dt with Q = diag(q, 0) lags under
    acceleration and makes the distance's covariance over-confident.)"""
    v_hat, x_pos = x_hat
    (p00, p01), (_, p11) = P
    v_pred = max(v0 + dv * v_hat, 0.0)
    f10 = 0.5 * dt * (1.0 + dv)                       # Phi = [[dv, 0], [f10, 1]]
    m01 = dv * (f10 * p00 + p01) + q * 0.5 * dt
    return ((v_pred, x_pos + 0.5 * dt * (v_hat + v_pred)),
            ((dv * dv * p00 + q, m01), (m01, f10 * f10 * p00 + 2.0 * f10 * p01 + p11 + q * dt * dt / 3.0)))
