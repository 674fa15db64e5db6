"""Output-error (trajectory) identification of the resistance and the mass from one segment.

The paper's least squares (seed 001, eqs. (3)-(12), ``models.identification``) regresses the
*differenced measured* speed: its target y(n) carries ~sqrt(2) sigma_V 1000/(g dt) of noise
(MODEL.md section 4), far above a resistance of a few N/kN, so the A's are lost. Output-error
fitting instead simulates eq. (2) deterministically from a fitted initial state and fits the
*simulated* trajectory to the measured one: measurement noise then enters only as white noise
on the residuals, never in the regressors, and the estimator is consistent.

Method (cited): output-error method of system identification, Maine & Iliff (1986), "Application
of parameter estimation to aircraft stability and control: the output-error approach", NASA
RP-1168; Jategaonkar (2015), "Flight Vehicle System Identification", 2nd ed., AIAA, ch. 4
(Gauss-Newton on the simulated-minus-measured outputs, sensitivities of the simulated states,
Cramer-Rao covariance (J^T J)^-1 s^2). The model is eq. (2) of seed 001 in continuous time
with seed 003's rotating-mass factor gamma (as ``models.dynamics``):

    dV/dt = g/1000 / (1 + gamma) * ( Theta1 (F - B) - A0 - A1 V - A2 V^2 - i )     [m/s^2]
    dX/dt = V                                                                    [m/s]
    Theta = (1/(P g), A0, A1, A2)          [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]

with the applied forces F, B [N] held between samples (their mean over the interval) and the
grade i [permille] known. Integrated by one classical RK4 step per sample interval (the plant
``models.dynamics.rk4_step`` uses the same scheme); the Jacobian is the exact derivative of
that RK4 recursion (forward sensitivities, computed vectorised from the stored stage speeds).

Grade: the grade is a known input, held per sample interval: its mean over the distance the
car covers in the interval along a reference track built from the measurements (the trapezoid
integral of the measured speed, anchored to the measured distance by least squares: its error
is ~0.1 m over minutes), averaged over the car ``length`` as in ``GradeProfile.average``. The
fitted trajectory therefore depends on Theta only through V, as in the paper's eq. (2) where
i[n] is a known input.

Fitted parameters: Theta (or only the A's when the segment has no force excitation, F = B = 0,
e.g. a coast: 1/(Pg) is then unobservable and is held, its value irrelevant), the initial
speed V0 [m/s] and, when distances are fitted, the initial distance X0 [m]. Optional Gaussian
priors (mean and information per parameter, seed-001 Theta units) enter as extra whitened
residuals (Bayesian maximum a posteriori, e.g. Jategaonkar 2015, sec. 4.13 "a priori
information"), which keeps A0, A2 physical on short or narrow-speed-range segments.

Covariance. With white measurement noise only, (J^T J)^-1 s^2 is the Cramer-Rao bound
(``cov_white``). A real car also has *process* noise (our plant: white acceleration noise of
density q [m^2/s^3], ``car.process_noise_psd``): the true speed then random-walks away from any
deterministic trajectory, the residuals are correlated over the whole segment, and the white
formula is overconfident (several times on a two-minute coast). ``cov`` is therefore the
sandwich H^-1 (H + M_q) H^-1 (Huber 1967 / White 1982 robust covariance; Jategaonkar 2015,
sec. 4.18 on correlated residuals), H = J^T J of the whitened problem and
M_q = sum_m q h_m u_m u_m^T the information the residuals' random-walk part takes away
(u_m = the sensitivity of the weighted normal equations to the process-noise kick in interval
m, computed by one backward recursion through the linearised dynamics). q is given, or
estimated by ``estimate_process_noise_psd`` from the residuals of several fits.

Across station stops (seed 001: "the mass is constant between two stations; A0..A2 drift
slowly"): ``fuse_estimates`` combines several segments' A-estimates information-weighted, with
optional forgetting between runs, and ``ResistanceCarryOver`` does it sequentially (the A's
carry over from run to run as the next fit's prior while the mass restarts at each stop).

Units: time [s], speed [m/s], distance [m], force [N], mass [t], grade [permille],
Theta as above. Pure numpy/scipy, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .track import GradeProfile
from .units import G

THETA_NAMES = ("theta1", "A0", "A1", "A2")
"""Names of Theta's components: 1/(P g) [1/kN], A0 [N/kN], A1 [N/kN/(m/s)], A2 [N/kN/(m/s)^2]."""

DEFAULT_THETA = np.array([1.0 / (G * 30.0), 1.0, 0.03, 0.01])
"""Starting point when no prior is given: 30 t and the estimator's default est.A*_initial."""


# ------------------------------------------------------------------------- priors

@dataclass(frozen=True)
class Prior:
    """Gaussian prior on Theta = (1/(P g), A0, A1, A2) in information form.

    ``mean`` (4,) in Theta units; ``info`` (4, 4) the inverse covariance, with zero rows and
    columns for components that have no prior (e.g. the mass of a fresh run).
    """
    mean: np.ndarray
    info: np.ndarray

    @classmethod
    def from_std(cls, mean, std) -> "Prior":
        """Independent priors: std[j] = inf, nan or None means no prior on component j."""
        mean = np.asarray(mean, dtype=float).reshape(4)
        info = np.zeros((4, 4))
        for j, s in enumerate(std):
            if s is not None and math.isfinite(s) and s > 0.0:
                info[j, j] = 1.0 / (s * s)
        return cls(mean, info)

    @classmethod
    def from_A(cls, A, cov_A, mass: float | None = None, mass_std: float | None = None) -> "Prior":
        """Prior with A = (A0, A1, A2) of covariance ``cov_A`` (3x3, correlations kept) and an
        optional independent mass prior mass [t] +- mass_std [t] (delta method on 1/(P g))."""
        mean = np.empty(4)
        info = np.zeros((4, 4))
        mean[1:] = np.asarray(A, dtype=float)
        info[1:, 1:] = np.linalg.inv(np.asarray(cov_A, dtype=float))
        mean[0] = 1.0 / (G * mass) if mass else DEFAULT_THETA[0]
        if mass and mass_std and math.isfinite(mass_std) and mass_std > 0.0:
            th1_std = mass_std / (G * mass * mass)
            info[0, 0] = 1.0 / th1_std ** 2
        return cls(mean, 0.5 * (info + info.T))

    def A_info(self) -> np.ndarray:
        """Marginal information of (A0, A1, A2) (the mass integrated out) (3x3)."""
        I = self.info
        if I[0, 0] > 0.0:
            return I[1:, 1:] - np.outer(I[1:, 0], I[0, 1:]) / I[0, 0]
        return I[1:, 1:].copy()

    def whitener(self, idx: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(L, mean) with L^T L = info restricted to Theta components ``idx`` (rows of zero
        information dropped): the prior residual is L (theta - mean)."""
        I = self.info[np.ix_(idx, idx)]
        w, U = np.linalg.eigh(0.5 * (I + I.T))
        keep = w > 1e-12 * max(float(w.max()), 1e-300) if w.size else np.zeros(0, bool)
        L = (np.sqrt(w[keep])[:, None] * U[:, keep].T) if keep.any() else np.zeros((0, len(idx)))
        return L, self.mean[idx]


def mass_prior_std_theta1(mass: float, mass_std: float) -> float:
    """Std of Theta1 = 1/(P g) [1/kN] for a mass prior mass +- mass_std [t] (delta method)."""
    return mass_std / (G * mass * mass)


# ------------------------------------------------------------------------- simulation core

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


def _rk4_pass(theta, v0: float, h: np.ndarray, fnet: np.ndarray, grade: np.ndarray, k: float):
    """Deterministic RK4 of eq. (2), one step per interval. Returns (v (n,), stages (n-1, 4),
    rest (n-1,) bool: the car stood or came to rest in the interval).

    At rest the car does not roll backwards (as ``models.dynamics._rk4``): stage speeds are
    clamped at 0 and a step that would end below 0 ends at 0.
    """
    th1, a0, a1, a2 = (float(x) for x in theta)
    b1, b2 = k * a1, k * a2
    gl = (k * (th1 * fnet - a0 - grade)).tolist()        # speed-independent part of dV/dt
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
        w2 = v + hh * k1
        c2 = w2 if w2 > 0.0 else 0.0
        k2 = gj - b1 * c2 - b2 * c2 * c2
        w3 = v + hh * k2
        c3 = w3 if w3 > 0.0 else 0.0
        k3 = gj - b1 * c3 - b2 * c3 * c3
        w4 = v + hj * k3
        c4 = w4 if w4 > 0.0 else 0.0
        k4 = gj - b1 * c4 - b2 * c4 * c4
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


def _linear_recurrence(a: np.ndarray, b: np.ndarray, s0: np.ndarray) -> np.ndarray:
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
    k = G / 1000.0 / (1.0 + gamma)
    fnet = np.asarray(fnet, dtype=float)
    v, W, rest = _rk4_pass(theta, v0, h, fnet, np.asarray(grade, dtype=float), k)
    h6 = h / 6.0
    dxs = h6 * (W[:, 0] + 2.0 * W[:, 1] + 2.0 * W[:, 2] + W[:, 3])
    x = x0 + np.concatenate([[0.0], np.cumsum(dxs)])
    if not sensitivities:
        return Trajectory(v, x, None, None, None, None)
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
    Bv5 = np.concatenate([Bv, np.zeros((n, 1))], axis=1)
    s0 = np.array([0.0, 0.0, 0.0, 0.0, 1.0])
    dv = _linear_recurrence(a, Bv5, s0)
    Bx5 = np.concatenate([Bx, np.zeros((n, 1))], axis=1)
    dx = np.concatenate([np.zeros((1, 5)), np.cumsum(cx[:, None] * dv[:-1] + Bx5, axis=0)])
    return Trajectory(v, x, dv, dx, a, cx)


# ------------------------------------------------------------------------- noise levels

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


# ------------------------------------------------------------------------- the fit

@dataclass
class OutputErrorFit:
    """Result of ``fit_segment``. Units: Theta as THETA_NAMES, speed [m/s], distance [m]."""
    theta: np.ndarray              # (4,) Theta-hat (Theta1 held if not fit_mass)
    cov: np.ndarray                # (4, 4) covariance of Theta-hat (sandwich with process noise)
    cov_white: np.ndarray          # (4, 4) (J^T J)^-1 s^2: white-residual Cramer-Rao covariance
    v0: float                      # fitted initial speed [m/s]
    v0_std: float
    x0: float                      # fitted initial distance [m] (nan if distances not fitted)
    fit_mass: bool
    n: int                         # samples
    speed_std: float               # measurement-noise std used for the speed residuals [m/s]
    distance_std: float            # ... for the distance residuals [m] (nan if not fitted)
    process_noise_psd: float       # q used in ``cov`` [m^2/s^3] (nan: white covariance)
    s2: float                      # residual variance of the whitened data residuals [-]
    speed_rms: float               # RMS of simulated - measured speed [m/s]
    distance_rms: float            # ... distance [m]
    speed_sim: np.ndarray          # simulated speed at the samples [m/s]
    distance_sim: np.ndarray       # simulated distance [m]
    speed_residual: np.ndarray     # measured - simulated speed [m/s]
    time: np.ndarray               # sample times [s]
    prior: Prior | None
    nfev: int
    success: bool
    message: str
    diagnostics: dict = field(default_factory=dict)

    @property
    def A(self) -> np.ndarray:
        """(A0, A1, A2) [N/kN, N/kN/(m/s), N/kN/(m/s)^2]."""
        return self.theta[1:].copy()

    @property
    def cov_A(self) -> np.ndarray:
        """Covariance of (A0, A1, A2): the mass and the initial state integrated out (3x3)."""
        return self.cov[1:, 1:].copy()

    @property
    def mass(self) -> float:
        """P-hat [t] (the effective mass P (1 + gamma) if gamma is set to 0 for a car with
        rotating masses, MODEL.md section 2)."""
        return 1.0 / (G * self.theta[0]) if self.theta[0] > 0 else float("inf")

    @property
    def mass_std(self) -> float:
        """Std of P-hat [t], delta method: std(Theta1) / (g Theta1^2); 0 when the mass is held."""
        return math.sqrt(max(self.cov[0, 0], 0.0)) / (G * self.theta[0] ** 2)

    def w0(self, v) -> np.ndarray:
        """Identified w0(V) [N/kN] at speeds v [m/s], eq. (1)."""
        v = np.asarray(v, dtype=float)
        return self.theta[1] + self.theta[2] * v + self.theta[3] * v * v

    def w0_std(self, v) -> np.ndarray:
        """Std of the identified w0(V) [N/kN] at speeds v [m/s]."""
        v = np.atleast_1d(np.asarray(v, dtype=float))
        phi = np.column_stack([np.ones_like(v), v, v * v])
        return np.sqrt(np.einsum("ij,jk,ik->i", phi, self.cov_A, phi))

    def A_data_information(self) -> tuple[np.ndarray, np.ndarray]:
        """(J_d, h_d): the information on the A's this segment's data added to the prior, and
        the matching information vector, so that fusing fits does not count a prior twice:
        J_d = cov_A^-1 - J_prior, h_d = cov_A^-1 A - J_prior A_prior (linearised)."""
        J_post = np.linalg.inv(self.cov_A)
        h_post = J_post @ self.A
        if self.prior is None:
            return J_post, h_post
        J_pr = self.prior.A_info()
        return J_post - J_pr, h_post - J_pr @ self.prior.mean[1:]


def _theta_start(prior: Prior | None, theta0, mass: float | None) -> np.ndarray:
    th = DEFAULT_THETA.copy()
    if prior is not None:
        has = np.diag(prior.info) > 0.0
        th[has] = prior.mean[has]
    if mass:
        th[0] = 1.0 / (G * mass)
    if theta0 is not None:
        th = np.asarray(theta0, dtype=float).copy()
    return th


def fit_segment(time, speed, traction=None, brake=None, *, distance=None,
                grade_profile: GradeProfile | None = None, grade=None, length: float = 0.0,
                gamma: float = 0.0, fit_mass: bool | None = None, mass: float | None = None,
                prior: Prior | None = None, use_distance: bool = True,
                speed_std: float | None = None, distance_std: float | None = None,
                process_noise_psd: float | None = None, theta0=None,
                max_nfev: int = 50) -> OutputErrorFit:
    """Output-error fit of Theta (and V0, X0) to one segment of samples.

    time [s] (n,) sample instants; speed [m/s] (n,) measured; traction, brake [N] applied over
    each interval [t_k, t_k+1] (n-1 values, or n with the last ignored; None = 0); distance [m]
    (n,) measured, or None; grade: a ``grade_profile`` evaluated along the reference track
    (``reference_track``) averaged over ``length`` [m], or ``grade`` (n-1,) [permille] per
    interval, or neither (level); gamma the rotating-mass factor [-].

    fit_mass: None = automatic (fitted iff some interval has F - B != 0); when not fitted,
    Theta1 is held at 1/(g mass) (or the prior's / default value; irrelevant when F = B = 0).
    prior: Gaussian prior on Theta (``Prior``). speed_std [m/s], distance_std [m]: measurement
    noise; None = estimated from second differences (``noise_std_from_differences``).
    process_noise_psd q [m^2/s^3]: None = ``cov`` is the white formula (J^T J)^-1 s^2; a number
    >= 0 = the sandwich with that random-walk process noise (see the module docstring).
    """
    t = np.asarray(time, dtype=float)
    v_meas = np.asarray(speed, dtype=float)
    n = len(t)
    if n < 3 or v_meas.shape != (n,):
        raise ValueError("fit_segment needs >= 3 samples and one speed per sample time")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("sample times must increase")
    fnet = net_force_per_interval(traction, brake, n - 1)
    x_meas = None if distance is None else np.asarray(distance, dtype=float)
    if grade is not None:
        grade_iv = np.asarray(grade, dtype=float)[: n - 1]
        if grade_iv.shape != (n - 1,):
            raise ValueError(f"grade needs {n - 1} values, one per sample interval")
    else:
        track = reference_track(t, v_meas, x_meas)
        grade_iv = grade_per_interval(track, grade_profile, length)
    if fit_mass is None:
        fit_mass = bool(np.any(fnet != 0.0))
    use_x = use_distance and x_meas is not None
    sv = speed_std if speed_std is not None else noise_std_from_differences(v_meas)
    sv = max(float(sv), 1e-9)
    sx = float("nan")
    if use_x:
        sx = distance_std if distance_std is not None else noise_std_from_differences(x_meas)
        sx = max(float(sx), 1e-9)

    th_start = _theta_start(prior, theta0, mass)
    th_idx = [0, 1, 2, 3] if fit_mass else [1, 2, 3]
    n_th = len(th_idx)
    L_pr, mu_pr = prior.whitener(th_idx) if prior is not None else (np.zeros((0, n_th)), np.zeros(n_th))
    # parameter vector p = (Theta[th_idx], V0[, X0])
    p0 = np.concatenate([th_start[th_idx], [float(np.mean(v_meas[:3]))]])
    if use_x:
        p0 = np.concatenate([p0, [float(x_meas[0])]])
    cols = th_idx + [4]                                   # columns of Trajectory.dv / dx used

    def unpack(p):
        th = th_start.copy()
        th[th_idx] = p[:n_th]
        v0 = p[n_th]
        x0 = p[n_th + 1] if use_x else 0.0
        return th, v0, x0

    cache = {}

    def traj(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            th, v0, x0 = unpack(p)
            cache[key] = simulate(th, v0, x0, t, fnet, grade_iv, gamma)
        return cache[key]

    def residuals(p):
        tr = traj(p)
        parts = [(tr.speed - v_meas) / sv]
        if use_x:
            parts.append((tr.distance - x_meas) / sx)
        parts.append(L_pr @ (p[:n_th] - mu_pr))
        return np.concatenate(parts)

    def jacobian(p):
        tr = traj(p)
        Jv = tr.dv[:, cols] / sv
        if use_x:
            Jv = np.concatenate([Jv, np.zeros((n, 1))], axis=1)
            Jx = np.concatenate([tr.dx[:, cols], np.ones((n, 1))], axis=1) / sx
            blocks = [Jv, Jx]
        else:
            blocks = [Jv]
        Jp = np.zeros((L_pr.shape[0], len(p)))
        Jp[:, :n_th] = L_pr
        blocks.append(Jp)
        return np.concatenate(blocks, axis=0)

    scale = np.concatenate([np.array([DEFAULT_THETA[0], 1.0, 0.03, 0.01])[th_idx], [0.1],
                            [1.0] if use_x else []])
    sol = least_squares(residuals, p0, jac=jacobian, method="lm", x_scale=scale,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
    p = sol.x
    th, v0, x0 = unpack(p)
    tr = traj(p)
    J = jacobian(p)
    m_data = n * (2 if use_x else 1)
    Jd, Jp = J[:m_data], J[m_data:]
    r = residuals(p)
    rd = r[:m_data]
    dof = max(m_data - len(p), 1)
    s2 = float(rd @ rd) / dof
    H = Jd.T @ Jd + Jp.T @ Jp
    Hw = Jd.T @ Jd / s2 + Jp.T @ Jp
    cov_w_p = np.linalg.inv(Hw)
    if process_noise_psd is None:
        cov_p = cov_w_p
        q = float("nan")
    else:
        q = float(process_noise_psd)
        Hi = np.linalg.inv(H)
        M = _process_noise_meat(tr, Jd, n, use_x, q, t, sv, sx)
        cov_p = Hi @ (H + M) @ Hi
    cov4 = np.zeros((4, 4))
    cov4w = np.zeros((4, 4))
    cov4[np.ix_(th_idx, th_idx)] = cov_p[:n_th, :n_th]
    cov4w[np.ix_(th_idx, th_idx)] = cov_w_p[:n_th, :n_th]
    res_v = v_meas - tr.speed
    return OutputErrorFit(
        theta=th, cov=cov4, cov_white=cov4w, v0=float(v0),
        v0_std=math.sqrt(max(cov_p[n_th, n_th], 0.0)),
        x0=float(x0) if use_x else float("nan"), fit_mass=fit_mass, n=n, speed_std=sv,
        distance_std=sx, process_noise_psd=q, s2=s2,
        speed_rms=float(np.sqrt(np.mean(res_v ** 2))),
        distance_rms=float(np.sqrt(np.mean((x_meas - tr.distance) ** 2))) if use_x else float("nan"),
        speed_sim=tr.speed, distance_sim=tr.distance, speed_residual=res_v, time=t, prior=prior,
        nfev=int(sol.nfev), success=bool(sol.success), message=str(sol.message),
        diagnostics={"cost": float(sol.cost), "optimality": float(sol.optimality),
                     "n_params": len(p), "cov_params": cov_p, "grade_mean": float(grade_iv.mean())})


def _process_noise_meat(tr: Trajectory, Jd: np.ndarray, n: int, use_x: bool, q: float,
                        t: np.ndarray, sv: float, sx: float) -> np.ndarray:
    """M_q = sum_m q h_m u_m u_m^T: Jd^T W Sigma_q W Jd for the random-walk residual part.

    A process-noise kick w_m ~ N(0, q h_m) at the end of interval m moves the true speed at
    every later sample k > m by Phi(k, m+1) w_m (Phi the product of the RK4 step derivatives
    a) and the distance by sum_j cx_j Phi(j, m+1) w_m. So u_m = sum_{k > m} dV_k/dw_m Jv_k +
    dX_k/dw_m Jx_k, computed backwards: U_k = z_k + a_k U_{k+1} with z_k = Jv_k + cx_k T_{k+1},
    T_k = sum_{j >= k} Jx_j, and u_m = U_{m+1}.
    """
    h = np.diff(t)
    Jv = Jd[:n]
    T = np.zeros_like(Jv)
    if use_x:
        Jx = Jd[n:2 * n]
        T = np.cumsum(Jx[::-1], axis=0)[::-1]              # T_k = sum_{j >= k} Jx_j
        T = np.concatenate([T, np.zeros((1, Jv.shape[1]))])
    z = Jv / sv                                            # k = 0..n-1
    if use_x:
        z[:-1] += tr.cx[:, None] * T[1:n] / sx
    # backward: U_{n-1} = z_{n-1}; U_k = z_k + a_k U_{k+1}
    a = tr.a
    rev = _linear_recurrence(a[::-1], z[-2::-1], z[-1])    # rev[j] = U_{n-1-j}
    U = rev[::-1]                                          # U[k], k = 0..n-1
    u = U[1:]                                              # u_m = U_{m+1}, m = 0..n-2
    return q * (u * h[:, None]).T @ u


# ------------------------------------------------------------------------- process noise

def estimate_process_noise_psd(fits, max_lag_s: float = 10.0) -> float:
    """Random-walk process-noise density q [m^2/s^3] from output-error speed residuals.

    The residual r = V_meas - V_sim holds white measurement noise plus the integrated process
    noise: its variogram D(L) = E (r[k+L] - r[k])^2 = 2 sigma_V^2 + q L dt for lags short
    against the segment (the fit absorbs only the slow part). q is the least-squares slope of
    the pooled variogram over lags up to ``max_lag_s`` [s] (the classical variogram estimator,
    Matheron 1962; for a random walk plus white noise see e.g. Box & Jenkins, IMA(1,1)).
    Pooling several fits (a day's runs) is what makes it usable: one two-minute coast gives q
    within a factor ~2.
    """
    lags, vals, weights = [], [], []
    for f in fits:
        r = np.asarray(f.speed_residual, dtype=float)
        dt = float(np.median(np.diff(f.time)))
        L_max = max(2, min(int(round(max_lag_s / dt)), len(r) // 4))
        for L in range(1, L_max + 1):
            d = r[L:] - r[:-L]
            lags.append(L * dt)
            vals.append(float(np.mean(d * d)))
            weights.append(len(d))
    if len(lags) < 2:
        return float("nan")
    x = np.asarray(lags)
    y = np.asarray(vals)
    w = np.asarray(weights, dtype=float)
    A = np.column_stack([np.ones_like(x), x]) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(A, y * np.sqrt(w), rcond=None)
    return max(float(coef[1]), 0.0)


# ------------------------------------------------------------------------- across runs

def fuse_estimates(fits, forgetting: float = 0.0, prior: Prior | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted fusion of several segments' (A0, A1, A2): returns (A, cov_A).

    ``fits``: OutputErrorFit objects (their own priors are removed first, so a prior common
    to all fits is not counted n times: ``A_data_information``) or (A, cov_A) pairs (taken as
    pure data). Runs are taken in order; before each run the information so far is multiplied
    by (1 - forgetting) (exponential forgetting, the constant-mu0 forgetting of seed 001 eq.
    (8)-(11) applied per run instead of per sample), so slowly drifting A's are followed.
    ``prior``: added once at the start (its A-block, mass integrated out).
    """
    J = np.zeros((3, 3))
    hv = np.zeros(3)
    if prior is not None:
        J = prior.A_info()
        hv = J @ prior.mean[1:]
    lam = 1.0 - forgetting
    for f in fits:
        if isinstance(f, OutputErrorFit):
            Jd, hd = f.A_data_information()
        else:
            A, C = f
            Jd = np.linalg.inv(np.asarray(C, dtype=float))
            hd = Jd @ np.asarray(A, dtype=float)
        J = lam * J + Jd
        hv = lam * hv + hd
    cov = np.linalg.inv(0.5 * (J + J.T))
    return cov @ hv, cov


class ResistanceCarryOver:
    """Sequential identification across station stops (thin stateful wrapper).

    The A's carry over from run to run: each run's fit gets the A's learnt so far as its prior
    (covariance inflated by 1 / (1 - forgetting) per run, for slow drift) and a fresh, weak
    mass prior (passengers boarded at the stop, seed 001: "P is constant between two
    stations"); the fit's posterior A's are the new state.
    """

    def __init__(self, A0: float = 1.0, A1: float = 0.03, A2: float = 0.01,
                 A_std=(1.0, 0.03, 0.01), forgetting: float = 0.0):
        self.A = np.array([A0, A1, A2], dtype=float)
        self.cov_A = np.diag(np.asarray(A_std, dtype=float) ** 2)
        self.forgetting = float(forgetting)
        self.runs = 0
        self.fits: list[OutputErrorFit] = []

    def prior(self, mass: float | None = None, mass_std: float | None = None) -> Prior:
        """The prior for the next run: the A's so far (forgetting applied) and a mass prior."""
        cov = self.cov_A / (1.0 - self.forgetting) if self.runs else self.cov_A
        return Prior.from_A(self.A, cov, mass, mass_std)

    def fit(self, *args, mass: float | None = None, mass_std: float | None = None,
            **kwargs) -> OutputErrorFit:
        """``fit_segment(*args, prior=self.prior(mass, mass_std), **kwargs)``, then update."""
        f = fit_segment(*args, prior=self.prior(mass, mass_std), mass=mass, **kwargs)
        self.update(f)
        return f

    def update(self, f: OutputErrorFit) -> None:
        """Take a fit made with ``self.prior(...)`` as its prior: its posterior is the new state."""
        self.A = f.A
        self.cov_A = 0.5 * (f.cov_A + f.cov_A.T)
        self.runs += 1
        self.fits.append(f)
