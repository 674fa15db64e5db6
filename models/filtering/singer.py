"""Singer-type motion model and its Kalman filter (Boynik et al., n.d.; docs/filters.md).

State z = [w, v, r]: acceleration w [m/s^2], speed v [m/s], distance r [m]. Boynik et al.
model the acceleration as a Gauss-Markov process with mean m_w [m/s^2], std sigma_w [m/s^2] and
correlation function K(t) = sigma_w^2 exp(-|t|/tau) (their eq. (7)), tau [s] the mean
duration of a constant-acceleration phase. In continuous time, alpha = 1/tau [1/s]:

    dw/dt = -alpha (w - m_w) + n(t),   dv/dt = w,   dr/dt = v,

n white with spectral density 2 alpha sigma_w^2 [(m/s^2)^2/Hz] (so that var(w) = sigma_w^2 in
the stationary state; Singer 1970, ref. [3] of Boynik et al.).

Discretisation over a step dt [s], x = alpha dt [-], rho = exp(-x):

- ``singer_transition`` is the exact Phi = expm(A dt):
  [[rho, 0, 0], [dt phi1(-x), 1, 0], [dt^2 phi2(-x), dt, 1]],
  phi1(z) = (e^z - 1)/z, phi2(z) = (e^z - 1 - z)/z^2.
- ``singer_process_noise`` is the exact Q = int_0^dt Phi(s) b b^T Phi(s)^T ds with
  b b^T = diag(2 alpha sigma_w^2, 0, 0).  Q[w, w] = sigma_w^2 (1 - rho^2).

Relation to the recursion of Boynik et al. (their eqs. (8)-(14), docs/filters.md):
w[n] = rho w[n-1] + q xi[n-1], rho = exp(-dt/tau) (9), q = sqrt(1 - rho^2) (10; the OCR shows
1 - rho^2, the square root keeps var(w) = sigma_w^2), xi of variance sigma_w^2. The exact model
has the same w row: Phi[w, w] = rho and Q[w, w] = sigma_w^2 q^2. Boynik et al.'s speed and
distance rows (11)-(13) are Euler steps (v gets w dt, r gets v dt) without their own noise;
the exact Phi and Q differ from them by O(dt^2) (``seed002_transition`` keeps them verbatim as
a baseline). The exact form is used by the filter: it is right for any step, also for the
unequal steps between track-sensor passages.

Numerics: the textbook closed form of Q (Singer 1970) subtracts O(1) terms to get results of
order x^3..x^5 and loses all digits for alpha dt ~ 1e-4 in double precision. Here every entry is
written as sigma_w^2 2x dt^(i+j) J_ij(x) with J_ij(0) = 1, 1/2, 1/6, 1/3, 1/8, 1/20 (the white-
acceleration limit), and J_ij is evaluated by its Taylor series for x < ``SERIES_SWITCH`` and
by the closed form above it (where the cancellation costs at most ~2 digits). The series
coefficients are exact rationals derived at import time from the closed forms (and checked to
cancel the low orders exactly). Accuracy, per element against a 60-digit reference: Q within
1.3e-15 for alpha dt in [1e-6, 1e3]; Phi within ~1e-15 for alpha dt <= 10 (beyond, rho =
e^(-x) inherits the x * 1e-16 relative rounding of x = alpha dt). tests/model_tests/filtering/test_singer.py asserts
1e-12. (scipy's expm-based Van Loan method is as good for alpha dt <= 1 but loses 1e-11..1e-8
at alpha dt = 10, so it serves only as a cross-check in the tests.)

Filter: ``singer_predict`` / ``singer_update`` are pure (filterpy style, they return new x, P);
``SingerFilter`` is the stateful filter (models.filtering.motion_filter.MotionFilter's kind 4). One state runs
on a scalar path (``_predict``, ``_update``, ``_project``: plain floats, every sum in a fixed
order, no BLAS/LAPACK), which models/core/singer.c mirrors bit for bit; numpy serves (N, 3)
batches only. Measurements: speed only (``H_SPEED``) or speed
and distance (``H_SPEED_DISTANCE``), e.g. from two point track sensors (eqs. (15), (16)
of Boynik et al.: y = [0 1 0] z + eta) and an odometer. A non-zero mean m_w is handled in the
prediction: the centred part w - m_w decays with rho and the mean m_w acts as a known input. The
speed is never negative: a negative speed estimate is projected onto v = 0 (see ``project_speed``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from math import factorial

import numpy as np

from models import fpmath
from models.fpmath import cube, fifth, fourth, square

I_W, I_V, I_R = 0, 1, 2
"""Indices of acceleration [m/s^2], speed [m/s], distance [m] in the state."""

H_SPEED = np.array([[0.0, 1.0, 0.0]])
"""Observation of speed only (eq. (16) of Boynik et al., C = [0 1 0])."""

H_SPEED_DISTANCE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
"""Observation of speed and distance."""

SERIES_SWITCH = 1.5
"""alpha dt [-] below which the Taylor series is used (where both forms cost < ~2 digits)."""

_SERIES_TERMS = 40   # x < 1.5: the omitted terms are below 3^40/40! ~ 1e-29 of the sum


# --------------------------------------------------------------------------- mixture moments

def singer_mixture_moments(p0: float, p_plus: float, p_minus: float, w_max_plus: float,
                           w_max_minus: float) -> tuple[float, float]:
    """Mean m_w [m/s^2] and std sigma_w [m/s^2] of Boynik et al.'s acceleration distribution.

    The acceleration is 0 with probability ``p0`` (uniform motion), ``w_max_plus`` [m/s^2] (> 0,
    maximum traction) with probability ``p_plus``, ``w_max_minus`` [m/s^2] (< 0, maximum
    braking: give it negative) with probability ``p_minus``, and uniform on
    [w_max_minus, w_max_plus] with density h = (1 - P0 - P+ - P-)/(w_max+ - w_max-) [s^2/m]
    (Boynik et al., eq. (3), Fig. 1). Then (eqs. (4)-(6), rewritten for a signed w_max-):

        m_w       = P+ w+ + P- w- + h (w+^2 - w-^2) / 2
        sigma_w^2 = P0 m_w^2 + P+ (w+ - m_w)^2 + P- (w- - m_w)^2
                    + h ((w+ - m_w)^3 - (w- - m_w)^3) / 3

    Boynik et al. then replace this distribution by the normal one with the same m_w and sigma_w.
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
    var = (probs[0] * m * m + probs[1] * square(a - m) + probs[2] * square(b - m)
           + h * (cube(a - m) - cube(b - m)) / 3.0)                         # eqs. (5), (6)
    return m, math.sqrt(max(var, 0.0))


@dataclass(frozen=True)
class SingerParams:
    """Parameters of the acceleration process (Boynik et al., eqs. (7)-(10)).

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
    e1, e2 = fpmath.exp(-x), fpmath.exp(-2.0 * x)
    if name == "phi1":
        return -fpmath.expm1(-x) / x
    if name == "phi2":
        return (x + fpmath.expm1(-x)) / (x * x)
    if name == "phi3":
        return (1.0 - x + 0.5 * x * x - e1) / cube(x)
    if name == "ww":
        return -fpmath.expm1(-2.0 * x) / (2.0 * x)
    if name == "wv":
        return square(fpmath.expm1(-x)) / (2.0 * x * x)
    if name == "wr":
        return (-fpmath.expm1(-2.0 * x) - 2.0 * x * e1) / (2.0 * cube(x))
    if name == "vv":
        return (2.0 * x - 3.0 + 4.0 * e1 - e2) / (2.0 * cube(x))
    if name == "vr":
        return (x * x - 2.0 * x + 1.0 - 2.0 * e1 + 2.0 * x * e1 + e2) / (2.0 * fourth(x))
    if name == "rr":
        return (2.0 * cube(x) / 3.0 - 2.0 * x * x + 2.0 * x + 1.0 - e2 - 4.0 * x * e1) / (2.0 * fifth(x))
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


def _transition(alpha: float, dt: float) -> tuple:
    """Phi of ``singer_transition`` as a flat row-major tuple of 9 floats."""
    x = _check_step(alpha, dt)
    return (fpmath.exp(-x), 0.0, 0.0,
            dt * _f("phi1", x), 1.0, 0.0,
            dt * dt * _f("phi2", x), dt, 1.0)


def _process_noise(alpha: float, dt: float, sigma_w: float) -> tuple:
    """Q of ``singer_process_noise`` as a flat row-major tuple of 9 floats: entry (i, j), j >= i,
    is ((k scale_i) scale_j) J_ij(x), k = (2 x) sigma_w sigma_w, scale = (1, dt, dt dt); (j, i)
    the same float."""
    x = _check_step(alpha, dt)
    if not (sigma_w >= 0.0 and math.isfinite(sigma_w)):
        raise ValueError(f"sigma_w must be >= 0 and finite [m/s^2], got {sigma_w}")
    scale = (1.0, dt, dt * dt)
    names = (("ww", "wv", "wr"), ("wv", "vv", "vr"), ("wr", "vr", "rr"))
    k = 2.0 * x * sigma_w * sigma_w
    Q = [0.0] * 9
    for i in range(3):
        for j in range(i, 3):
            Q[3 * i + j] = Q[3 * j + i] = k * scale[i] * scale[j] * _f(names[i][j], x)
    return tuple(Q)


def _mean_input(alpha: float, dt: float, m_w: float) -> tuple:
    """u of ``singer_mean_input`` as a tuple of 3 floats (m_w times each entry)."""
    x = _check_step(alpha, dt)
    return (m_w * -fpmath.expm1(-x), m_w * (dt * x * _f("phi2", x)),
            m_w * (dt * dt * x * _f("phi3", x)))


def singer_transition(alpha: float, dt: float) -> np.ndarray:
    """Exact 3x3 transition Phi = expm(A dt) of z = [w, v, r] ([m/s^2], [m/s], [m]).

    A = [[-alpha, 0, 0], [1, 0, 0], [0, 1, 0]], alpha = 1/tau [1/s], dt [s]. With x = alpha dt:
    Phi = [[rho, 0, 0], [dt phi1(-x), 1, 0], [dt^2 phi2(-x), dt, 1]], rho = exp(-x) (Boynik
    et al., eq. (9)); for x -> 0 it tends to the constant-acceleration
    [[1,0,0],[dt,1,0],[dt^2/2,dt,1]].
    """
    return np.array(_transition(alpha, dt)).reshape(3, 3)


def singer_process_noise(alpha: float, dt: float, sigma_w: float) -> np.ndarray:
    """Exact 3x3 process-noise covariance Q of z = [w, v, r] over dt [s].

    Q = int_0^dt Phi(s) diag(2 alpha sigma_w^2, 0, 0) Phi(s)^T ds for a stationary acceleration
    std ``sigma_w`` [m/s^2], alpha = 1/tau [1/s]. Units: Q[w,w] [(m/s^2)^2], Q[v,v] [(m/s)^2],
    Q[r,r] [m^2], off-diagonals the products. Q[w,w] = sigma_w^2 (1 - rho^2) = (sigma_w q)^2 with
    Boynik et al.'s q = sqrt(1 - rho^2) (their eq. (10)). Accurate to ~1e-15 relative per element
    for every alpha dt >= 0 (series below ``SERIES_SWITCH``, see the module docstring).
    """
    return np.array(_process_noise(alpha, dt, sigma_w)).reshape(3, 3)


def seed002_transition(alpha: float, dt: float) -> np.ndarray:
    """Eq. (13) of Boynik et al. verbatim: Phi = [[rho, 0, 0], [dt, 1, 0], [0, dt, 1]] (Euler rows).

    A baseline only. Note the OCR'd (13) has r[n] = r[n-1] + v[n-1] dt, while eq. (12) writes
    v[n] dt; both are first-order in dt. alpha [1/s], dt [s].
    """
    x = _check_step(alpha, dt)
    return np.array([[fpmath.exp(-x), 0.0, 0.0], [dt, 1.0, 0.0], [0.0, dt, 1.0]])


def seed002_process_noise(alpha: float, dt: float, sigma_w: float) -> np.ndarray:
    """Boynik et al., eqs. (8), (10), (14): Q = G G^T sigma_w^2, G = [q, 0, 0]^T,
    q = sqrt(1 - rho^2).

    Only w is excited [(m/s^2)^2]; alpha [1/s], dt [s], sigma_w [m/s^2].
    """
    x = _check_step(alpha, dt)
    Q = np.zeros((3, 3))
    Q[0, 0] = -fpmath.expm1(-2.0 * x) * sigma_w * sigma_w
    return Q


def singer_mean_input(alpha: float, dt: float, m_w: float) -> np.ndarray:
    """Contribution u of the mean acceleration m_w [m/s^2] over dt [s] to the prediction.

    With w = m_w + w~ (Boynik et al.: w normal with mean m_w, eq. (7)), the centred part w~ decays
    with rho while m_w acts as a constant known input:
    z_pred = Phi (z - m_w e_w) + m_w [1, dt, dt^2/2] = Phi z + u,
    u = m_w [1 - rho, dt x phi2(-x), dt^2 x phi3(-x)] ([m/s^2], [m/s], [m]), x = alpha dt,
    phi3(z) = (e^z - 1 - z - z^2/2)/z^3 (the same expressions without cancellation).
    """
    return np.array(_mean_input(alpha, dt, m_w))


# ------------------------------------------------------------------------------- filter
#
# The filter's arithmetic is scalar Python with a fixed operation order, so that the C core
# (models/core/singer.c) reproduces it bit for bit: numpy's matrix products and
# np.linalg.solve go through BLAS/LAPACK (fused multiply-adds, blocked sums), which C cannot
# reproduce. Matrices are flat row-major lists (3x3: 9 floats; H: m rows of 3; R: m x m),
# vectors lists. Every sum of products runs left to right starting with the first product
# (``_dot``: ((a0 b0 + a1 b1) + a2 b2)); the order of each step is written at its function.


def _dot(a, b) -> float:
    """a[0] b[0] + a[1] b[1] + ... left to right, starting with the first product."""
    s = a[0] * b[0]
    for i in range(1, len(a)):
        s += a[i] * b[i]
    return s


def _project(x: list, P) -> list:
    """``project_speed`` of one state x (3 floats), P flat: if v < 0, x_i - (P[i, v] / P[v, v]) v
    for i = w, v, r when P[v, v] > 0, then v = 0 (only v = 0 when P[v, v] is not > 0)."""
    v = x[I_V]
    if not v < 0.0:
        return x
    pvv = P[4]
    if pvv > 0.0:
        x = [x[0] - P[1] / pvv * v, x[1] - P[4] / pvv * v, x[2] - P[7] / pvv * v]
    else:
        x = list(x)
    x[I_V] = 0.0
    return x


def _symmetric(M: list) -> list:
    """0.5 (M + M^T) of a flat 3x3: entry (i, j) is 0.5 * (M[i, j] + M[j, i])."""
    return [0.5 * (M[3 * i + j] + M[3 * j + i]) for i in range(3) for j in range(3)]


def _predict(x: list, P, Phi, Q, u, clip: bool) -> tuple[list, list]:
    """x' = Phi x + u (entry i: _dot(Phi row i, x) + u_i); P' = sym((Phi P) Phi^T + Q) with
    (Phi P)[i, j] = _dot(Phi row i, P column j), ((Phi P) Phi^T)[i, j] = _dot((Phi P) row i,
    Phi row j), Q added entry by entry; then the clip (``_project``) when ``clip``."""
    xp = [_dot(Phi[3 * i:3 * i + 3], x) + u[i] for i in range(3)]
    T = [_dot(Phi[3 * i:3 * i + 3], P[j::3]) for i in range(3) for j in range(3)]
    M = [_dot(T[3 * i:3 * i + 3], Phi[3 * j:3 * j + 3]) + Q[3 * i + j]
         for i in range(3) for j in range(3)]
    Pp = _symmetric(M)
    return (_project(xp, Pp) if clip else xp), Pp


def _update(x: list, P, z, H, R, clip: bool) -> tuple[list, list, float]:
    """Kalman update with m = 1 or 2 measurements z = H [w, v, r] + eta, cov(eta) = R (flat
    m x m). Returns (x', P', NIS). Order:

    - G = P H^T (3 x m): G[i, a] = _dot(P row i, H row a);
      S = H G + R: S[a, b] = _dot(H row a, G column b) + R[a, b]; y_a = z_a - _dot(H row a, x);
    - m = 1: K_i = G_i / S, NIS = y (y / S);
      m = 2: det = S00 S11 - S01 S10, S^-1 = (S11/det, -S01/det, -S10/det, S00/det),
      K[i, a] = _dot(G row i, S^-1 column a), NIS = _dot(y, S^-1 y) (S^-1 y by rows);
    - x'_i = x_i + _dot(K row i, y);
    - Joseph form: A = I - K H (A[i, j] = delta_ij - _dot(K row i, H column j)),
      P' = sym((A P) A^T + (K R) K^T), each product as in ``_predict``, the two sums entry by
      entry; then the clip (``_project``).

    A singular S (S = 0, det = 0) raises ZeroDivisionError before anything is returned.
    """
    m = len(z)
    G = [_dot(P[3 * i:3 * i + 3], H[a]) for i in range(3) for a in range(m)]
    S = [_dot(H[a], G[b::m]) + R[m * a + b] for a in range(m) for b in range(m)]
    y = [z[a] - _dot(H[a], x) for a in range(m)]
    if m == 1:
        s = S[0]
        K = [G[0] / s, G[1] / s, G[2] / s]
        nis = y[0] * (y[0] / s)
    elif m == 2:
        det = S[0] * S[3] - S[1] * S[2]
        inv = [S[3] / det, -S[1] / det, -S[2] / det, S[0] / det]
        K = [_dot(G[2 * i:2 * i + 2], inv[a::2]) for i in range(3) for a in range(2)]
        nis = _dot(y, [_dot(inv[0:2], y), _dot(inv[2:4], y)])
    else:
        raise ValueError(f"the Singer filter takes 1 or 2 measurements at a time, got {m}")
    xn = [x[i] + _dot(K[m * i:m * i + m], y) for i in range(3)]
    A = [(1.0 if i == j else 0.0) - _dot(K[m * i:m * i + m], [H[a][j] for a in range(m)])
         for i in range(3) for j in range(3)]
    T = [_dot(A[3 * i:3 * i + 3], P[j::3]) for i in range(3) for j in range(3)]
    KR = [_dot(K[m * i:m * i + m], R[b::m]) for i in range(3) for b in range(m)]
    Pn = [_dot(T[3 * i:3 * i + 3], A[3 * j:3 * j + 3]) + _dot(KR[m * i:m * i + m], K[m * j:m * j + m])
          for i in range(3) for j in range(3)]
    Pn = _symmetric(Pn)
    return (_project(xn, Pn) if clip else xn), Pn, nis


def project_speed(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Clip the speed at 0: a state with v < 0 [m/s] is replaced by its projection onto v = 0.

    The projection is the minimum-variance one (Simon & Chia 2002, "estimate projection"):
    x - P[:, v] v / P[v, v], i.e. the conditional mean given v = 0, so w and r move with their
    correlation to v (a car found at rest was braking less than predicted); if P[v, v] = 0 only
    v is set to 0. The covariance is left unchanged (conservative). ``x`` (3,), P (3, 3); a
    state with v >= 0 is returned unchanged, as a new array (``_project``).
    """
    return np.array(_project(np.asarray(x, dtype=float).reshape(3).tolist(),
                             np.asarray(P, dtype=float).reshape(9).tolist()))


@lru_cache(maxsize=256)
def _discretisation_flat(alpha: float, dt: float, sigma_w: float, m_w: float):
    """(Phi, Q, u) as flat tuples, cached: a filter run at a constant step computes them once."""
    return (_transition(alpha, dt), _process_noise(alpha, dt, sigma_w),
            _mean_input(alpha, dt, m_w))


@lru_cache(maxsize=256)
def _discretisation(alpha: float, dt: float, sigma_w: float, m_w: float):
    """(Phi, Q, u) as read-only numpy arrays, for the simulator ``singer_step``."""
    Phi, Q, u = _discretisation_flat(alpha, dt, sigma_w, m_w)
    out = (np.array(Phi).reshape(3, 3), np.array(Q).reshape(3, 3), np.array(u))
    for a in out:
        a.setflags(write=False)
    return out


def _flat_state(x, P) -> tuple[list, list]:
    return (np.asarray(x, dtype=float).reshape(3).tolist(),
            np.asarray(P, dtype=float).reshape(9).tolist())


def _flat_measurement(z, H, R) -> tuple[list, list, list]:
    H = np.atleast_2d(np.asarray(H, dtype=float))
    m = H.shape[0]
    return (np.asarray(z, dtype=float).reshape(m).tolist(), H.reshape(m, 3).tolist(),
            np.atleast_2d(np.asarray(R, dtype=float)).reshape(m * m).tolist())


def singer_predict(x: np.ndarray, P: np.ndarray, dt: float, params: SingerParams,
                   clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Predict z = [w, v, r] ([m/s^2], [m/s], [m]) and its covariance over dt [s].

    x_pred = Phi (x - m_w e_w) + m_w [1, dt, dt^2/2], P_pred = Phi P Phi^T + Q (exact Phi, Q of
    this module; eqs. (8)-(14) of Boynik et al. in exact form), computed by ``_predict``. With
    ``clip`` a negative predicted speed is projected onto 0 (``project_speed``).
    """
    Phi, Q, u = _discretisation_flat(params.alpha, float(dt) + 0.0, params.sigma_w, params.m_w)
    xs, Ps = _predict(*_flat_state(x, P), Phi, Q, u, clip)
    return np.array(xs), np.array(Ps).reshape(3, 3)


def singer_update(x: np.ndarray, P: np.ndarray, z, H: np.ndarray, R,
                  clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with measurement z = H [w, v, r] + eta, cov(eta) = R, computed by ``_update``.

    H: ``H_SPEED`` (z = speed [m/s], R [(m/s)^2]) or ``H_SPEED_DISTANCE`` (z = [speed [m/s],
    distance [m]], R 2x2). Gain K = P H^T S^-1; the covariance in Joseph form
    (I - K H) P (I - K H)^T + K R K^T (symmetric, positive semi-definite in floating point).
    With ``clip`` a negative speed is projected onto 0 (``project_speed``).
    """
    xs, Ps, _ = _update(*_flat_state(x, P), *_flat_measurement(z, H, R), clip)
    return np.array(xs), np.array(Ps).reshape(3, 3)


H_DISTANCE_ROW = (0.0, 0.0, 1.0)
H_SPEED_ROW = (0.0, 1.0, 0.0)


class SingerFilter:
    """Stateful filter of z = [w, v, r] on the scalar path (``_predict``, ``_update``).

    ``x0`` defaults to [m_w, 0, 0] (at rest at the origin, acceleration at its mean) and ``P0``
    to diag(sigma_w^2, 0, 0) (rest known exactly, as the paper's P~[0] = 0; acceleration from
    its stationary distribution). Units [m/s^2], [m/s], [m], [s]. The state is held as plain
    floats (``_x``: 3, ``_P``: 9 row-major); ``x`` and ``P`` give numpy copies (and set them).
    """

    def __init__(self, params: SingerParams, x0=None, P0=None, clip: bool = True):
        self.params = params
        self.clip = clip
        self._x = ([params.m_w, 0.0, 0.0] if x0 is None
                   else np.asarray(x0, dtype=float).reshape(3).tolist())
        self._P = ([square(params.sigma_w), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] if P0 is None
                   else np.asarray(P0, dtype=float).reshape(9).tolist())
        if clip:
            self._x = _project(self._x, self._P)
        self.nis = math.nan   # normalised innovation squared of the last update [-]

    @property
    def x(self) -> np.ndarray:
        """[w, v, r] ([m/s^2], [m/s], [m]), a copy."""
        return np.array(self._x)

    @x.setter
    def x(self, value) -> None:
        self._x = np.asarray(value, dtype=float).reshape(3).tolist()

    @property
    def P(self) -> np.ndarray:
        """3x3 covariance of x, a copy."""
        return np.array(self._P).reshape(3, 3)

    @P.setter
    def P(self, value) -> None:
        self._P = np.asarray(value, dtype=float).reshape(9).tolist()

    def predict(self, dt: float) -> None:
        """Advance by dt [s]."""
        p = self.params
        # + 0.0 turns a step of -0.0 into 0.0: the cache holds them as one key (they compare
        # equal), so -0.0 would get whichever came first (a zero's sign in Phi and u)
        Phi, Q, u = _discretisation_flat(p.alpha, float(dt) + 0.0, p.sigma_w, p.m_w)
        self._x, self._P = _predict(self._x, self._P, Phi, Q, u, self.clip)

    def _take(self, z, H, R) -> None:
        self._x, self._P, self.nis = _update(self._x, self._P, z, H, R, self.clip)

    def update(self, z, H, R) -> None:
        """Take measurement z = H z + eta, cov R (m = 1 or 2 rows; see ``singer_update``)."""
        self._take(*_flat_measurement(z, H, R))

    def update_speed(self, speed: float, speed_std: float) -> None:
        """Speed measurement [m/s] with noise std [m/s] (e.g. two track sensors)."""
        self._take([float(speed)], [H_SPEED_ROW], [square(speed_std)])

    def update_distance(self, distance: float, distance_std: float) -> None:
        """Distance measurement [m] with noise std [m] (H = [0 0 1])."""
        self._take([float(distance)], [H_DISTANCE_ROW], [square(distance_std)])

    def update_speed_distance(self, speed: float, distance: float, speed_std: float,
                              distance_std: float) -> None:
        """Speed [m/s] and distance [m] with independent noise stds [m/s], [m]."""
        self._take([float(speed), float(distance)], [H_SPEED_ROW, H_DISTANCE_ROW],
                   [square(speed_std), 0.0, 0.0, square(distance_std)])

    @property
    def acceleration(self) -> float:
        """Estimated acceleration [m/s^2]."""
        return self._x[I_W]

    @property
    def speed(self) -> float:
        """Estimated speed [m/s], >= 0 when ``clip``."""
        return self._x[I_V]

    @property
    def distance(self) -> float:
        """Estimated distance [m]."""
        return self._x[I_R]

    @property
    def acceleration_std(self) -> float:
        """[m/s^2]"""
        return math.sqrt(max(self._P[0], 0.0))

    @property
    def speed_std(self) -> float:
        """[m/s]"""
        return math.sqrt(max(self._P[4], 0.0))

    @property
    def distance_std(self) -> float:
        """[m]"""
        return math.sqrt(max(self._P[8], 0.0))


def singer_step(z: np.ndarray, dt: float, params: SingerParams, xi: np.ndarray) -> np.ndarray:
    """One exact step of the Singer process (a simulator): z' = Phi z + u + chol(Q) xi.

    z = [w, v, r] ([m/s^2], [m/s], [m]), dt [s], xi three standard normal draws [-] (or (N, 3)
    for N independent trajectories). No clipping: this is the model, not the filter.
    """
    Phi, Q, u = _discretisation(params.alpha, float(dt), params.sigma_w, params.m_w)
    L = np.linalg.cholesky(Q) if Q[0, 0] > 0.0 else np.zeros((3, 3))
    return np.asarray(z, dtype=float) @ Phi.T + u + np.asarray(xi, dtype=float) @ L.T
