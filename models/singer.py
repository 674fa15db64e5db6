"""Singer-type motion model and its Kalman filter (seed 002, MODEL.md section 6).

State z = [w, v, r]: acceleration w [m/s^2], speed v [m/s], distance r [m]. Seed 002 models
the acceleration as a Gauss-Markov process with mean m_w [m/s^2], std sigma_w [m/s^2] and
correlation function K(t) = sigma_w^2 exp(-|t|/tau) (seed 002 eq. (7)), tau [s] the mean
duration of a constant-acceleration phase. In continuous time, alpha = 1/tau [1/s]:

    dw/dt = -alpha (w - m_w) + n(t),   dv/dt = w,   dr/dt = v,

n white with spectral density 2 alpha sigma_w^2 [(m/s^2)^2/Hz] (so that var(w) = sigma_w^2 in
the stationary state; Singer 1970, seed 002 ref. [3]).

Discretisation over a step dt [s], x = alpha dt [-], rho = exp(-x):

- ``singer_transition`` is the exact Phi = expm(A dt):
  [[rho, 0, 0], [dt phi1(-x), 1, 0], [dt^2 phi2(-x), dt, 1]],
  phi1(z) = (e^z - 1)/z, phi2(z) = (e^z - 1 - z)/z^2.
- ``singer_process_noise`` is the exact Q = int_0^dt Phi(s) b b^T Phi(s)^T ds with
  b b^T = diag(2 alpha sigma_w^2, 0, 0).  Q[w, w] = sigma_w^2 (1 - rho^2).

Relation to the seed's recursion (seed 002 eqs. (8)-(14), MODEL.md section 6):
w[n] = rho w[n-1] + q xi[n-1], rho = exp(-dt/tau) (9), q = sqrt(1 - rho^2) (10; the OCR shows
1 - rho^2, the square root keeps var(w) = sigma_w^2), xi of variance sigma_w^2. The exact model
has the same w row: Phi[w, w] = rho and Q[w, w] = sigma_w^2 q^2. The seed's speed and distance
rows (11)-(13) are Euler steps (v gets w dt, r gets v dt) without their own noise; the exact
Phi and Q differ from them by O(dt^2) (``seed002_transition`` keeps them verbatim as a
baseline). The exact form is used by the filter: it is right for any step, also for the
unequal steps between track-sensor passages.

Numerics: the textbook closed form of Q (Singer 1970) subtracts O(1) terms to get results of
order x^3..x^5 and loses all digits for alpha dt ~ 1e-4 in double precision. Here every entry is
written as sigma_w^2 2x dt^(i+j) J_ij(x) with J_ij(0) = 1, 1/2, 1/6, 1/3, 1/8, 1/20 (the white-
acceleration limit), and J_ij is evaluated by its Taylor series for x < ``SERIES_SWITCH`` and
by the closed form above it (where the cancellation costs at most ~2 digits). The series
coefficients are exact rationals derived at import time from the closed forms (and checked to
cancel the low orders exactly). Accuracy, per element against a 60-digit reference: Q within
1.3e-15 for alpha dt in [1e-6, 1e3]; Phi within ~1e-15 for alpha dt <= 10 (beyond, rho =
e^(-x) inherits the x * 1e-16 relative rounding of x = alpha dt). tests/test_singer.py asserts
1e-12. (scipy's expm-based Van Loan method is as good for alpha dt <= 1 but loses 1e-11..1e-8
at alpha dt = 10, so it serves only as a cross-check in the tests.)

Filter: ``singer_predict`` / ``singer_update`` are pure (filterpy style, they return new x, P);
``SingerFilter`` is the thin stateful wrapper. Measurements: speed only (``H_SPEED``) or speed
and distance (``H_SPEED_DISTANCE``), e.g. from two point track sensors (seed 002 eqs. (15),
(16): y = [0 1 0] z + eta) and an odometer. A non-zero mean m_w is handled in the prediction:
the centred part w - m_w decays with rho and the mean m_w acts as a known input. The speed is
never negative: a negative speed estimate is projected onto v = 0 (see ``project_speed``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from math import factorial

import numpy as np

I_W, I_V, I_R = 0, 1, 2
"""Indices of acceleration [m/s^2], speed [m/s], distance [m] in the state."""

H_SPEED = np.array([[0.0, 1.0, 0.0]])
"""Observation of speed only (seed 002 eq. (16), C = [0 1 0])."""

H_SPEED_DISTANCE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
"""Observation of speed and distance."""

SERIES_SWITCH = 1.5
"""alpha dt [-] below which the Taylor series is used (where both forms cost < ~2 digits)."""

_SERIES_TERMS = 40   # x < 1.5: the omitted terms are below 3^40/40! ~ 1e-29 of the sum


# --------------------------------------------------------------------------- mixture moments

def singer_mixture_moments(p0: float, p_plus: float, p_minus: float, w_max_plus: float,
                           w_max_minus: float) -> tuple[float, float]:
    """Mean m_w [m/s^2] and std sigma_w [m/s^2] of seed 002's acceleration distribution.

    The acceleration is 0 with probability ``p0`` (uniform motion), ``w_max_plus`` [m/s^2] (> 0,
    maximum traction) with probability ``p_plus``, ``w_max_minus`` [m/s^2] (< 0, maximum
    braking: give it negative) with probability ``p_minus``, and uniform on
    [w_max_minus, w_max_plus] with density h = (1 - P0 - P+ - P-)/(w_max+ - w_max-) [s^2/m]
    (seed 002 eq. (3), Fig. 1). Then (eqs. (4)-(6), rewritten for a signed w_max-):

        m_w       = P+ w+ + P- w- + h (w+^2 - w-^2) / 2
        sigma_w^2 = P0 m_w^2 + P+ (w+ - m_w)^2 + P- (w- - m_w)^2
                    + h ((w+ - m_w)^3 - (w- - m_w)^3) / 3

    The seed then replaces this distribution by the normal one with the same m_w and sigma_w.
    """
    a, b = float(w_max_plus), float(w_max_minus)
    probs = (float(p0), float(p_plus), float(p_minus))
    if not all(math.isfinite(p) and p >= 0.0 for p in probs):
        raise ValueError(f"probabilities must be finite and >= 0, got {probs}")
    rest = 1.0 - sum(probs)
    if rest < -1e-12:
        raise ValueError(f"P0 + P+ + P- must be <= 1, got {sum(probs)}")
    rest = max(rest, 0.0)
    if not (math.isfinite(a) and math.isfinite(b) and b <= 0.0 <= a and a > b):
        raise ValueError(f"need w_max_minus <= 0 <= w_max_plus and w_max_minus < w_max_plus "
                         f"[m/s^2], got {w_max_minus}, {w_max_plus}")
    h = rest / (a - b)                                                        # eq. (3)
    m = probs[1] * a + probs[2] * b + 0.5 * h * (a * a - b * b)               # eq. (4)
    var = (probs[0] * m * m + probs[1] * (a - m) ** 2 + probs[2] * (b - m) ** 2
           + h * ((a - m) ** 3 - (b - m) ** 3) / 3.0)                         # eqs. (5), (6)
    return m, math.sqrt(max(var, 0.0))


@dataclass(frozen=True)
class SingerParams:
    """Parameters of the acceleration process (seed 002 eqs. (7)-(10)).

    tau [s]: correlation time (mean duration of a constant-acceleration phase), alpha = 1/tau;
    sigma_w [m/s^2]: stationary std of the acceleration; m_w [m/s^2]: its mean.
    """
    tau: float
    sigma_w: float
    m_w: float = 0.0

    def __post_init__(self):
        if not (self.tau > 0.0 and math.isfinite(self.tau)):
            raise ValueError(f"tau must be > 0 and finite [s], got {self.tau}")
        if not (self.sigma_w >= 0.0 and math.isfinite(self.sigma_w)):
            raise ValueError(f"sigma_w must be >= 0 and finite [m/s^2], got {self.sigma_w}")
        if not math.isfinite(self.m_w):
            raise ValueError(f"m_w must be finite [m/s^2], got {self.m_w}")

    @property
    def alpha(self) -> float:
        """1/tau [1/s]."""
        return 1.0 / self.tau

    @classmethod
    def from_mixture(cls, tau: float, p0: float, p_plus: float, p_minus: float,
                     w_max_plus: float, w_max_minus: float) -> "SingerParams":
        """tau [s] and the mixture of ``singer_mixture_moments`` (w_max [m/s^2], w_max- < 0)."""
        m, s = singer_mixture_moments(p0, p_plus, p_minus, w_max_plus, w_max_minus)
        return cls(tau=tau, sigma_w=s, m_w=m)


# ------------------------------------------------------------------ exact discretisation

# Each function f(x) = B(x) / (d x^p), B a sum of terms c x^m e^(-k x) (k = 0: polynomial).
# phi1, phi2: the transition; J_ij: the process noise (see the module docstring).
_TERMS = {
    "phi1": ([(1, 0, 0), (-1, 0, 1)], 1, 1),                    # (1 - e^-x) / x
    "phi2": ([(1, 1, 0), (-1, 0, 0), (1, 0, 1)], 2, 1),         # (x - 1 + e^-x) / x^2
    # (1 - x + x^2/2 - e^-x) / x^3
    "phi3": ([(1, 0, 0), (-1, 1, 0), (Fraction(1, 2), 2, 0), (-1, 0, 1)], 3, 1),
    "ww": ([(1, 0, 0), (-1, 0, 2)], 1, 2),                      # (1 - e^-2x) / 2x
    "wv": ([(1, 0, 0), (-2, 0, 1), (1, 0, 2)], 2, 2),           # (1 - e^-x)^2 / 2x^2
    "wr": ([(1, 0, 0), (-1, 0, 2), (-2, 1, 1)], 3, 2),          # (1 - e^-2x - 2x e^-x) / 2x^3
    "vv": ([(2, 1, 0), (-3, 0, 0), (4, 0, 1), (-1, 0, 2)], 3, 2),   # (2x - 3 + 4e^-x - e^-2x) / 2x^3
    "vr": ([(1, 2, 0), (-2, 1, 0), (1, 0, 0), (-2, 0, 1), (2, 1, 1), (1, 0, 2)], 4, 2),
    "rr": ([(Fraction(2, 3), 3, 0), (-2, 2, 0), (2, 1, 0), (1, 0, 0), (-1, 0, 2), (-4, 1, 1)], 5, 2),
}


def _series_coefficients(terms, p: int, d: int, n: int = _SERIES_TERMS) -> tuple[float, ...]:
    """Taylor coefficients of B(x)/(d x^p), exact in rationals, then rounded once."""
    b = []
    for order in range(n + p):
        s = Fraction(0)
        for c, m, k in terms:
            if k == 0:
                s += Fraction(c) if order == m else 0
            elif order >= m:
                s += Fraction(c) * Fraction((-k) ** (order - m), factorial(order - m))
        b.append(s)
    if any(v != 0 for v in b[:p]):     # the closed form must vanish to order p at x = 0
        raise AssertionError("Singer series: closed form does not cancel at x = 0")
    return tuple(float(v / d) for v in b[p:])


_COEFFS = {name: _series_coefficients(*spec) for name, spec in _TERMS.items()}


def _series(name: str, x: float) -> float:
    acc = 0.0
    for c in reversed(_COEFFS[name]):     # Horner
        acc = acc * x + c
    return acc


def _closed(name: str, x: float) -> float:
    """Closed forms for x >= SERIES_SWITCH (and the expm1 ones, accurate for every x > 0)."""
    e1, e2 = math.exp(-x), math.exp(-2.0 * x)
    if name == "phi1":
        return -math.expm1(-x) / x
    if name == "phi2":
        return (x + math.expm1(-x)) / (x * x)
    if name == "phi3":
        return (1.0 - x + 0.5 * x * x - e1) / (x ** 3)
    if name == "ww":
        return -math.expm1(-2.0 * x) / (2.0 * x)
    if name == "wv":
        return math.expm1(-x) ** 2 / (2.0 * x * x)
    if name == "wr":
        return (-math.expm1(-2.0 * x) - 2.0 * x * e1) / (2.0 * x ** 3)
    if name == "vv":
        return (2.0 * x - 3.0 + 4.0 * e1 - e2) / (2.0 * x ** 3)
    if name == "vr":
        return (x * x - 2.0 * x + 1.0 - 2.0 * e1 + 2.0 * x * e1 + e2) / (2.0 * x ** 4)
    if name == "rr":
        return (2.0 * x ** 3 / 3.0 - 2.0 * x * x + 2.0 * x + 1.0 - e2 - 4.0 * x * e1) / (2.0 * x ** 5)
    raise KeyError(name)


_ALWAYS_CLOSED = ("phi1", "ww", "wv")   # expm1 forms: no cancellation at any x


def _f(name: str, x: float) -> float:
    if x >= SERIES_SWITCH or (x > 0.0 and name in _ALWAYS_CLOSED):
        return _closed(name, x)
    return _series(name, x)


def _check_step(alpha: float, dt: float) -> float:
    if not (alpha > 0.0 and math.isfinite(alpha)):
        raise ValueError(f"alpha = 1/tau must be > 0 and finite [1/s], got {alpha}")
    if not (dt >= 0.0 and math.isfinite(dt)):
        raise ValueError(f"dt must be >= 0 and finite [s], got {dt}")
    return alpha * dt


def singer_transition(alpha: float, dt: float) -> np.ndarray:
    """Exact 3x3 transition Phi = expm(A dt) of z = [w, v, r] ([m/s^2], [m/s], [m]).

    A = [[-alpha, 0, 0], [1, 0, 0], [0, 1, 0]], alpha = 1/tau [1/s], dt [s]. With x = alpha dt:
    Phi = [[rho, 0, 0], [dt phi1(-x), 1, 0], [dt^2 phi2(-x), dt, 1]], rho = exp(-x) (seed 002
    eq. (9)); for x -> 0 it tends to the constant-acceleration [[1,0,0],[dt,1,0],[dt^2/2,dt,1]].
    """
    x = _check_step(alpha, dt)
    return np.array([[math.exp(-x), 0.0, 0.0],
                     [dt * _f("phi1", x), 1.0, 0.0],
                     [dt * dt * _f("phi2", x), dt, 1.0]])


def singer_process_noise(alpha: float, dt: float, sigma_w: float) -> np.ndarray:
    """Exact 3x3 process-noise covariance Q of z = [w, v, r] over dt [s].

    Q = int_0^dt Phi(s) diag(2 alpha sigma_w^2, 0, 0) Phi(s)^T ds for a stationary acceleration
    std ``sigma_w`` [m/s^2], alpha = 1/tau [1/s]. Units: Q[w,w] [(m/s^2)^2], Q[v,v] [(m/s)^2],
    Q[r,r] [m^2], off-diagonals the products. Q[w,w] = sigma_w^2 (1 - rho^2) = (sigma_w q)^2 with
    the seed's q = sqrt(1 - rho^2) (seed 002 eq. (10)). Accurate to ~1e-15 relative per element
    for every alpha dt >= 0 (series below ``SERIES_SWITCH``, see the module docstring).
    """
    x = _check_step(alpha, dt)
    if not (sigma_w >= 0.0 and math.isfinite(sigma_w)):
        raise ValueError(f"sigma_w must be >= 0 and finite [m/s^2], got {sigma_w}")
    scale = [1.0, dt, dt * dt]
    names = (("ww", "wv", "wr"), ("wv", "vv", "vr"), ("wr", "vr", "rr"))
    k = 2.0 * x * sigma_w * sigma_w
    Q = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            Q[i, j] = Q[j, i] = k * scale[i] * scale[j] * _f(names[i][j], x)
    return Q


def seed002_transition(alpha: float, dt: float) -> np.ndarray:
    """Seed 002 eq. (13) verbatim: Phi = [[rho, 0, 0], [dt, 1, 0], [0, dt, 1]] (Euler rows).

    A baseline only. Note the OCR'd (13) has r[n] = r[n-1] + v[n-1] dt, while eq. (12) writes
    v[n] dt; both are first-order in dt. alpha [1/s], dt [s].
    """
    x = _check_step(alpha, dt)
    return np.array([[math.exp(-x), 0.0, 0.0], [dt, 1.0, 0.0], [0.0, dt, 1.0]])


def seed002_process_noise(alpha: float, dt: float, sigma_w: float) -> np.ndarray:
    """Seed 002 eqs. (8), (10), (14): Q = G G^T sigma_w^2, G = [q, 0, 0]^T, q = sqrt(1 - rho^2).

    Only w is excited [(m/s^2)^2]; alpha [1/s], dt [s], sigma_w [m/s^2].
    """
    x = _check_step(alpha, dt)
    Q = np.zeros((3, 3))
    Q[0, 0] = -math.expm1(-2.0 * x) * sigma_w * sigma_w
    return Q


def singer_mean_input(alpha: float, dt: float, m_w: float) -> np.ndarray:
    """Contribution u of the mean acceleration m_w [m/s^2] over dt [s] to the prediction.

    With w = m_w + w~ (seed 002: w normal with mean m_w, eq. (7)), the centred part w~ decays
    with rho while m_w acts as a constant known input:
    z_pred = Phi (z - m_w e_w) + m_w [1, dt, dt^2/2] = Phi z + u,
    u = m_w [1 - rho, dt x phi2(-x), dt^2 x phi3(-x)] ([m/s^2], [m/s], [m]), x = alpha dt,
    phi3(z) = (e^z - 1 - z - z^2/2)/z^3 (the same expressions without cancellation).
    """
    x = _check_step(alpha, dt)
    return m_w * np.array([-math.expm1(-x), dt * x * _f("phi2", x), dt * dt * x * _f("phi3", x)])


# ------------------------------------------------------------------------------- filter

def project_speed(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Clip the speed at 0: a state with v < 0 [m/s] is replaced by its projection onto v = 0.

    The projection is the minimum-variance one (Simon & Chia 2002, "estimate projection"):
    x - P[:, v] v / P[v, v], i.e. the conditional mean given v = 0, so w and r move with their
    correlation to v (a car found at rest was braking less than predicted); if P[v, v] = 0 only
    v is set to 0. The covariance is left unchanged (conservative). ``x`` may be (3,) or (N, 3)
    (N states sharing P); rows with v >= 0 are returned unchanged. A new array is returned.
    """
    x = np.array(x, dtype=float, copy=True)
    v = x[..., I_V]
    neg = v < 0.0
    if not np.any(neg):
        return x
    pvv = P[I_V, I_V]
    gain = P[:, I_V] / pvv if pvv > 0.0 else np.eye(3)[I_V]
    if x.ndim == 1:
        x = x - gain * v
        x[I_V] = 0.0
    else:
        x[neg] -= np.outer(v[neg], gain)
        x[neg, I_V] = 0.0
    return x


@lru_cache(maxsize=256)
def _discretisation(alpha: float, dt: float, sigma_w: float, m_w: float):
    """(Phi, Q, u) cached: a filter run at a constant step computes them once."""
    out = (singer_transition(alpha, dt), singer_process_noise(alpha, dt, sigma_w),
           singer_mean_input(alpha, dt, m_w))
    for a in out:
        a.setflags(write=False)
    return out


def singer_predict(x: np.ndarray, P: np.ndarray, dt: float, params: SingerParams,
                   clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Predict z = [w, v, r] ([m/s^2], [m/s], [m]) and its covariance over dt [s].

    x_pred = Phi (x - m_w e_w) + m_w [1, dt, dt^2/2], P_pred = Phi P Phi^T + Q (exact Phi, Q of
    this module; seed 002 eqs. (8)-(14) in exact form). ``x`` may be (3,) or (N, 3). With
    ``clip`` a negative predicted speed is projected onto 0 (``project_speed``).
    """
    Phi, Q, u = _discretisation(params.alpha, float(dt), params.sigma_w, params.m_w)
    x = np.asarray(x, dtype=float)
    x_pred = x @ Phi.T + u
    P_pred = Phi @ P @ Phi.T + Q
    P_pred = 0.5 * (P_pred + P_pred.T)
    return (project_speed(x_pred, P_pred) if clip else x_pred), P_pred


def innovation(x: np.ndarray, P: np.ndarray, z, H: np.ndarray, R) -> tuple[np.ndarray, np.ndarray]:
    """Innovation y = z - H x and its covariance S = H P H^T + R (units of z)."""
    H = np.atleast_2d(np.asarray(H, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    y = np.asarray(z, dtype=float) - np.asarray(x, dtype=float) @ H.T
    return y, H @ P @ H.T + R


def singer_update(x: np.ndarray, P: np.ndarray, z, H: np.ndarray, R,
                  clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with measurement z = H [w, v, r] + eta, cov(eta) = R.

    H: ``H_SPEED`` (z = speed [m/s], R [(m/s)^2]) or ``H_SPEED_DISTANCE`` (z = [speed [m/s],
    distance [m]], R 2x2), or any m x 3. Gain K = P H^T S^-1; the covariance in Joseph form
    (I - K H) P (I - K H)^T + K R K^T (symmetric, positive semi-definite in floating point).
    ``x`` may be (3,) with z (m,), or (N, 3) with z (N, m). With ``clip`` a negative speed is
    projected onto 0 (``project_speed``).
    """
    H = np.atleast_2d(np.asarray(H, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    y, S = innovation(x, P, z, H, R)
    K = np.linalg.solve(S, H @ P).T          # P H^T S^-1 (S, P symmetric)
    x_new = np.asarray(x, dtype=float) + y @ K.T
    IKH = np.eye(3) - K @ H
    P_new = IKH @ P @ IKH.T + K @ R @ K.T
    P_new = 0.5 * (P_new + P_new.T)
    return (project_speed(x_new, P_new) if clip else x_new), P_new


class SingerFilter:
    """Stateful wrapper of ``singer_predict`` / ``singer_update`` for z = [w, v, r].

    ``x0`` defaults to [m_w, 0, 0] (at rest at the origin, acceleration at its mean) and ``P0``
    to diag(sigma_w^2, 0, 0) (rest known exactly, as the paper's P~[0] = 0; acceleration from
    its stationary distribution). Units [m/s^2], [m/s], [m], [s].
    """

    def __init__(self, params: SingerParams, x0=None, P0=None, clip: bool = True):
        self.params = params
        self.clip = clip
        self.x = (np.array([params.m_w, 0.0, 0.0]) if x0 is None
                  else np.array(x0, dtype=float).reshape(3))
        self.P = (np.diag([params.sigma_w ** 2, 0.0, 0.0]) if P0 is None
                  else np.array(P0, dtype=float).reshape(3, 3))
        if clip:
            self.x = project_speed(self.x, self.P)
        self.nis = math.nan   # normalised innovation squared of the last update [-]

    def predict(self, dt: float) -> None:
        """Advance by dt [s]."""
        self.x, self.P = singer_predict(self.x, self.P, dt, self.params, self.clip)

    def update(self, z, H, R) -> None:
        """Take measurement z = H z + eta, cov R (see ``singer_update``)."""
        y, S = innovation(self.x, self.P, z, H, R)
        self.nis = float(y @ np.linalg.solve(S, y))
        self.x, self.P = singer_update(self.x, self.P, z, H, R, self.clip)

    def update_speed(self, speed: float, speed_std: float) -> None:
        """Speed measurement [m/s] with noise std [m/s] (e.g. two track sensors)."""
        self.update(np.array([speed]), H_SPEED, np.array([[speed_std ** 2]]))

    def update_speed_distance(self, speed: float, distance: float, speed_std: float,
                              distance_std: float) -> None:
        """Speed [m/s] and distance [m] with independent noise stds [m/s], [m]."""
        self.update(np.array([speed, distance]), H_SPEED_DISTANCE,
                    np.diag([speed_std ** 2, distance_std ** 2]))

    @property
    def acceleration(self) -> float:
        """Estimated acceleration [m/s^2]."""
        return float(self.x[I_W])

    @property
    def speed(self) -> float:
        """Estimated speed [m/s], >= 0 when ``clip``."""
        return float(self.x[I_V])

    @property
    def distance(self) -> float:
        """Estimated distance [m]."""
        return float(self.x[I_R])

    @property
    def acceleration_std(self) -> float:
        """[m/s^2]"""
        return math.sqrt(max(self.P[I_W, I_W], 0.0))

    @property
    def speed_std(self) -> float:
        """[m/s]"""
        return math.sqrt(max(self.P[I_V, I_V], 0.0))

    @property
    def distance_std(self) -> float:
        """[m]"""
        return math.sqrt(max(self.P[I_R, I_R], 0.0))


def singer_step(z: np.ndarray, dt: float, params: SingerParams, xi: np.ndarray) -> np.ndarray:
    """One exact step of the Singer process (a simulator): z' = Phi z + u + chol(Q) xi.

    z = [w, v, r] ([m/s^2], [m/s], [m]), dt [s], xi three standard normal draws [-] (or (N, 3)
    for N independent trajectories). No clipping: this is the model, not the filter.
    """
    Phi, Q, u = _discretisation(params.alpha, float(dt), params.sigma_w, params.m_w)
    L = np.linalg.cholesky(Q) if Q[0, 0] > 0.0 else np.zeros((3, 3))
    return np.asarray(z, dtype=float) @ Phi.T + u + np.asarray(xi, dtype=float) @ L.T
