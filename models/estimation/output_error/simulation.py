"""The output-error fit's model and data (models/estimation/output_error/): a segment's inputs per
sample interval (net force, reference track, grade), the measurement noise from second
differences, and eq. (2) simulated deterministically, one RK4 step per sample interval, with the
exact forward sensitivities of that recursion (``simulate``, vectorised from the stored stage
speeds).

The physics is models.plant.dynamics's eq. (2) as a quadratic in V (``acceleration_polynomial``),
evaluated here in a scalar loop and differentiated in closed form. Units: time [s], speed [m/s],
distance [m], force [N], grade [permille], Theta as in models/estimation/output_error/priors.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.plant.dynamics import acceleration_gain, acceleration_polynomial
from models.plant.track import GradeProfile


def net_force_per_interval(traction, brake, n_intervals: int) -> np.ndarray:
    """F - B [N] per sample interval: arrays of n_intervals (or n_intervals + 1, last ignored)."""
    f = np.zeros(n_intervals) if traction is None else np.asarray(traction, dtype=float)[:n_intervals]
    b = np.zeros(n_intervals) if brake is None else np.asarray(brake, dtype=float)[:n_intervals]
    if f.shape != (n_intervals,) or b.shape != (n_intervals,):
        raise ValueError(f"traction and brake need {n_intervals} (or {n_intervals + 1}) values, "
                         f"one per sample interval")
    return f - b


def reference_track(time: np.ndarray, speed: np.ndarray, distance: np.ndarray | None,
                    distance0: float = 0.0) -> np.ndarray:
    """Distance [m] at the samples: trapezoid integral of the measured speed [m/s], anchored to
    the measured distances [m] by least squares (or starting at ``distance0`` without them).

    Its error is the integrated speed noise (sigma_V dt sqrt(n), ~0.1 m over minutes) plus the
    anchor's sigma_X / sqrt(n): far below a grade profile's resolution.
    """
    h = np.diff(time)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * h * (speed[1:] + speed[:-1]))])
    if distance is None:
        return cum + distance0
    return cum + float(np.mean(np.asarray(distance) - cum))


def grade_per_interval(track: np.ndarray, grade_profile: GradeProfile | None,
                       length: float = 0.0) -> np.ndarray:
    """(n-1,) grade [permille] of each sample interval: the mean of the grade over the distance
    [X_k, X_k+1] the car covers along the reference track ``track`` [m], for a car of ``length``
    [m] (``GradeProfile.average``).

    Held over the interval, it integrates the grade's work exactly (to the speed's variation
    within one sample): a piecewise-constant grade evaluated at RK4 stage points instead gives
    an O(h) error at each grade break (~4 mm/s per 25 permille step at 0.1 s, measured).
    length = 0: the exact interval mean, GradeProfile.average(X_k+1, X_k+1 - X_k); length > 0:
    Simpson's rule on the (continuous, piecewise-linear) train-averaged grade.
    """
    n = len(track)
    if grade_profile is None:
        return np.zeros(n - 1)
    avg = grade_profile.average
    x = [float(v) for v in track]
    out = np.empty(n - 1)
    if length <= 0.0:
        for k in range(n - 1):
            d = x[k + 1] - x[k]
            out[k] = avg(x[k + 1], d) if d > 1e-9 else avg(x[k], 0.0)
        return out
    at = [avg(v, length) for v in x]
    for k in range(n - 1):
        out[k] = (at[k] + 4.0 * avg(0.5 * (x[k] + x[k + 1]), length) + at[k + 1]) / 6.0
    return out


def rk4_stages(v: float, k1: float, g: float, b1: float, b2: float, hh: float, h: float):
    """Stages 2-4 of one RK4 step of dV/dt = g - b1 V - b2 V^2 from V = v [m/s] with the first
    slope k1, half step hh and step h [s]; stage speeds are clamped at 0 (no backward roll).
    Returns (w2, w3, w4, k2, k3, k4): stage speeds [m/s] and slopes [m/s^2]."""
    w2 = v + hh * k1
    c2 = w2 if w2 > 0.0 else 0.0
    k2 = g - b1 * c2 - b2 * c2 * c2
    w3 = v + hh * k2
    c3 = w3 if w3 > 0.0 else 0.0
    k3 = g - b1 * c3 - b2 * c3 * c3
    w4 = v + h * k3
    c4 = w4 if w4 > 0.0 else 0.0
    k4 = g - b1 * c4 - b2 * c4 * c4
    return w2, w3, w4, k2, k3, k4


def _rk4_pass(theta, v0: float, h: np.ndarray, fnet: np.ndarray, grade: np.ndarray, k: float):
    """Deterministic RK4 of eq. (2), one step per interval. Returns (v (n,), stages (n-1, 4),
    rest (n-1,) bool: the car stood or came to rest in the interval).

    At rest the car does not roll backwards (as ``models.plant.dynamics._rk4``): stage speeds are
    clamped at 0 and a step that would end below 0 ends at 0.
    """
    c0, b1, b2 = acceleration_polynomial(theta, fnet, grade, k)   # dV/dt = c0 - b1 V - b2 V^2
    gl = c0.tolist()
    hl = h.tolist()
    n = len(hl)
    v_out = [0.0] * (n + 1)
    w_out = [0.0] * (4 * n)
    rest = [False] * n
    v = float(v0)
    v_out[0] = v
    for j in range(n):
        hj = hl[j]
        hh = 0.5 * hj
        w1 = v if v > 0.0 else 0.0
        gj = gl[j]
        k1 = gj - b1 * w1 - b2 * w1 * w1
        if v <= 0.0 and k1 <= 0.0:                       # standing, forces do not break away
            rest[j] = True
            v = 0.0
            v_out[j + 1] = 0.0
            continue
        w2, w3, w4, k2, k3, k4 = rk4_stages(v, k1, gj, b1, b2, hh, hj)
        r = 4 * j
        w_out[r] = v
        w_out[r + 1] = w2
        w_out[r + 2] = w3
        w_out[r + 3] = w4
        v = v + hj / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if v < 0.0:
            v = 0.0
            rest[j] = True
        v_out[j + 1] = v
    return np.array(v_out), np.array(w_out).reshape(n, 4), np.array(rest, dtype=bool)


def linear_recurrence(a: np.ndarray, b: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """s[0] = s0, s[n+1] = a[n] s[n] + b[n] for vectors s (b: (n, p)); returns (n+1, p).

    Vectorised by cumulative products when they stay well scaled (a ~ 1 - 1e-3 here), else a loop.
    """
    n = len(a)
    out = np.empty((n + 1, len(s0)))
    out[0] = s0
    if n == 0:
        return out
    c = np.concatenate([[1.0], np.cumprod(a)])
    if np.all(a > 0.1) and c[-1] > 1e-100:
        acc = np.cumsum(b / c[1:, None], axis=0)
        out[1:] = c[1:, None] * (s0[None, :] + acc)
        return out
    s = np.array(s0, dtype=float)
    for j in range(n):
        s = a[j] * s + b[j]
        out[j + 1] = s
    return out


def step_derivatives(theta, h: np.ndarray, fnet: np.ndarray, W: np.ndarray, rest: np.ndarray,
                      k: float):
    """Exact derivatives of the RK4 steps at their stage speeds W (n-1, 4) (vectorised):
    a = dV[n+1]/dV[n], cx = dX[n+1]/dV[n], Bv = dV[n+1]/dTheta, Bx = dX[n+1]/dTheta (n-1, 4).
    Steps at rest (``rest``) pass no sensitivity (the car is held, the no-roll-back rule)."""
    th1, a0, a1, a2 = (float(t) for t in theta)
    Wc = np.maximum(W, 0.0)
    fv = -k * (a1 + 2.0 * a2 * Wc)                        # d(dV/dt)/dV at each stage
    n = len(h)
    fp = np.empty((n, 4, 4))                               # d(dV/dt)/dTheta at each stage
    fp[:, :, 0] = k * fnet[:, None]
    fp[:, :, 1] = -k
    fp[:, :, 2] = -k * Wc
    fp[:, :, 3] = -k * Wc * Wc
    hh = 0.5 * h
    h6 = h / 6.0
    # derivative of the RK4 step with respect to V[n] (scalar per interval)
    dk1 = fv[:, 0]
    dw2 = 1.0 + hh * dk1
    dk2 = fv[:, 1] * dw2
    dw3 = 1.0 + hh * dk2
    dk3 = fv[:, 2] * dw3
    dw4 = 1.0 + h * dk3
    dk4 = fv[:, 3] * dw4
    a = 1.0 + h6 * (dk1 + 2.0 * dk2 + 2.0 * dk3 + dk4)
    cx = h6 * (1.0 + 2.0 * dw2 + 2.0 * dw3 + dw4)
    # ... and with respect to Theta (V[n] held)
    Dk1 = fp[:, 0]
    Dw2 = hh[:, None] * Dk1
    Dk2 = fp[:, 1] + fv[:, 1, None] * Dw2
    Dw3 = hh[:, None] * Dk2
    Dk3 = fp[:, 2] + fv[:, 2, None] * Dw3
    Dw4 = h[:, None] * Dk3
    Dk4 = fp[:, 3] + fv[:, 3, None] * Dw4
    Bv = h6[:, None] * (Dk1 + 2.0 * Dk2 + 2.0 * Dk3 + Dk4)
    Bx = h6[:, None] * (2.0 * Dw2 + 2.0 * Dw3 + Dw4)
    if rest.any():                                         # at rest: no sensitivity flows
        a = np.where(rest, 0.0, a)
        cx = np.where(rest, 0.0, cx)
        Bv[rest] = 0.0
        Bx[rest] = 0.0
    return a, cx, Bv, Bx


@dataclass
class Trajectory:
    """Simulated speed [m/s] and distance [m] at the samples, with their sensitivities to
    p = (Theta1, A0, A1, A2, V0): dv (n, 5), dx (n, 5) (X0 enters X with derivative 1)."""
    speed: np.ndarray
    distance: np.ndarray
    dv: np.ndarray
    dx: np.ndarray
    a: np.ndarray          # dV[n+1]/dV[n] of the RK4 step (n-1,)
    cx: np.ndarray         # dX[n+1]/dV[n] of the RK4 step (n-1,)


def simulate(theta, v0: float, x0: float, time, fnet, grade, gamma: float = 0.0,
             sensitivities: bool = True) -> Trajectory:
    """Deterministic eq. (2) from (V0 [m/s], X0 [m]) at the sample times [s], with the net
    force F - B [N] and the grade [permille] held per interval ((n-1,) each, e.g.
    ``grade_per_interval``); Theta in seed-001 units; gamma the rotating-mass factor [-]."""
    time = np.asarray(time, dtype=float)
    h = np.diff(time)
    k = acceleration_gain(gamma)
    fnet = np.asarray(fnet, dtype=float)
    v, W, rest = _rk4_pass(theta, v0, h, fnet, np.asarray(grade, dtype=float), k)
    h6 = h / 6.0
    dxs = h6 * (W[:, 0] + 2.0 * W[:, 1] + 2.0 * W[:, 2] + W[:, 3])
    x = x0 + np.concatenate([[0.0], np.cumsum(dxs)])
    if not sensitivities:
        return Trajectory(v, x, None, None, None, None)
    a, cx, Bv, Bx = step_derivatives(theta, h, fnet, W, rest, k)
    n = len(h)
    Bv5 = np.concatenate([Bv, np.zeros((n, 1))], axis=1)
    s0 = np.array([0.0, 0.0, 0.0, 0.0, 1.0])
    dv = linear_recurrence(a, Bv5, s0)
    Bx5 = np.concatenate([Bx, np.zeros((n, 1))], axis=1)
    dx = np.concatenate([np.zeros((1, 5)), np.cumsum(cx[:, None] * dv[:-1] + Bx5, axis=0)])
    return Trajectory(v, x, dv, dx, a, cx)


def noise_std_from_differences(y: np.ndarray) -> float:
    """Std of white measurement noise on a smooth signal from its second differences:
    var(y[n+1] - 2 y[n] + y[n-1]) = 6 sigma^2 when the signal's curvature is negligible
    (|dV/dt| changes little within two samples). Median-based (robust to the odd jump):
    sigma = 1.4826 MAD / sqrt(6)."""
    y = np.asarray(y, dtype=float)
    if len(y) < 5:
        return float("nan")
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


@dataclass
class Segment:
    """One segment's data as fitted. time [s] (n,); speed [m/s] (n,) measured; distance [m]
    (n,) measured or None (not fitted); fnet = F - B [N] and grade [permille] per interval
    (n-1,); gamma [-]; measurement-noise stds speed_std [m/s], distance_std [m] (nan: none)."""
    time: np.ndarray
    speed: np.ndarray
    distance: np.ndarray | None
    fnet: np.ndarray
    grade: np.ndarray
    gamma: float
    speed_std: float
    distance_std: float

    @property
    def k(self) -> float:
        """g/1000/(1 + gamma): [m/s^2] per N/kN."""
        return acceleration_gain(self.gamma)
