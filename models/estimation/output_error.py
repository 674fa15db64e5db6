"""Output-error (trajectory) identification of the resistance and the mass from one segment.

The paper's least squares (seed 001, eqs. (3)-(12), ``models.estimation.identification``) regresses the
*differenced measured* speed: its target y(n) carries ~sqrt(2) sigma_V 1000/(g dt) of noise
and the regressors V, V^2 are noisy too (docs/model.md, Identification), so the A's are lost. Output-error
fitting instead simulates eq. (2) deterministically from a fitted initial state and fits the
*simulated* trajectory to the measured one: measurement noise enters only the residuals, never
the regressors, and the estimator is consistent.

Method (cited): the output-error method, Maine & Iliff (1986), "Application of parameter
estimation to aircraft stability and control: the output-error approach", NASA RP-1168;
Jategaonkar (2015), "Flight Vehicle System Identification", 2nd ed., AIAA, chapter "Output error
method" (Gauss-Newton / Levenberg-Marquardt on simulated-minus-measured outputs, sensitivities
of the simulated states, Cramer-Rao covariance (J^T J)^-1 s^2). The model is eq. (2) of seed 001
in continuous time with seed 003's rotating-mass factor gamma (as ``models.plant.dynamics``):

    dV/dt = g/1000 / (1 + gamma) * ( Theta1 (F - B) - A0 - A1 V - A2 V^2 - i )     [m/s^2]
    dX/dt = V                                                                    [m/s]
    Theta = (1/(P g), A0, A1, A2)          [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]

with the applied forces F, B [N] held between samples (their mean over the interval, what
``models.chain`` gives the estimator) and the grade i [permille] known. Integrated by one
classical RK4 step per sample interval (the plant ``models.plant.dynamics.rk4_step`` uses the same
scheme); the Jacobian is the exact derivative of that RK4 recursion (forward sensitivities,
vectorised from the stored stage speeds; a 2000-sample segment fits in ~20 ms).

Grade: a known input held per sample interval: its mean over the distance covered in the
interval, along a reference track built from the measurements (the trapezoid integral of the
measured speed anchored to the measured distances by least squares, error ~0.1 m over minutes),
averaged over the car ``length`` as ``GradeProfile.average`` does. The fitted trajectory
therefore depends on Theta only through V, as in eq. (2) where i[n] is a known input.

Fitted parameters: Theta (or only the A's when the segment has no force excitation, F = B = 0,
e.g. a coast: 1/(Pg) is then unobservable and held, its value irrelevant), the initial speed
V0 [m/s] and, when distances are fitted, the initial distance X0 [m]. Gaussian priors on Theta
(``Prior``: mean and information) enter as extra whitened residuals (maximum a posteriori),
which keeps A0, A2 physical on short or narrow-speed-range segments (``physical_prior``).

Process noise, and why the white covariance is not enough. The brief's premise "measurement
noise is white in output-error form" holds for the measurement noise, but a real car (and our
plant, ``car.process_noise_psd``: white acceleration noise of density q [m^2/s^3]) also has
process noise: the true speed random-walks away from any deterministic trajectory, residuals
are correlated over the whole segment, and (J^T J)^-1 s^2 (``cov_white``) is 4-14 times too
small in std on a station-to-station run (measured). Two honest options, both given q:

- ``method="output_error"``, ``process_noise_psd=q``: the same estimate, covariance the sandwich
  H^-1 (H + M_q) H^-1 (Huber 1967, White 1982), M_q = sum_m q h_m u_m u_m^T the random walk's
  share of the normal equations (u_m by one backward recursion through the linearised
  dynamics, ``_process_noise_meat``).
- ``method="filter_error"``: the filter-error method (Maine & Iliff 1985, "Identification of
  dynamic systems: theory and formulation", NASA RP-1138; Jategaonkar 2015, chapter "Filter
  error method"): the residuals are the whitened innovations of a Kalman filter around eq. (2)
  (gains at the output-error solution, then held), i.e. maximum likelihood under process plus
  measurement noise. Residuals are white again, so (J^T J)^-1 s^2 is honest, and it is
  efficient: on a station-to-station run the std of w0 at 2 m/s is 0.22 N/kN against output
  error's 0.40 (the generalised-least-squares Cramer-Rao bound is 0.23, measured).

q itself is estimated by restricted maximum likelihood over several fits
(``estimate_process_noise_psd``), given the sensors' configured noise stds.

Across station stops (seed 001: "P is constant between two stations; A0..A2 drift slowly"):
each fit exports its data information on the A's with the mass and initial state integrated out
(``OutputErrorFit.A_data_information``); ``fuse_estimates`` adds them up information-weighted
with optional forgetting between runs, ``ResistanceCarryOver`` does it run by run: the A's carry
over while the mass restarts at each stop.

Units: time [s], speed [m/s], distance [m], force [N], mass [t], grade [permille],
Theta as above. Pure numpy/scipy, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from models.plant.track import GradeProfile
from models.units import G

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


def _rk4_stages(v: float, k1: float, g: float, b1: float, b2: float, hh: float, h: float):
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
        w2, w3, w4, k2, k3, k4 = _rk4_stages(v, k1, gj, b1, b2, hh, hj)
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


def _step_derivatives(theta, h: np.ndarray, fnet: np.ndarray, W: np.ndarray, rest: np.ndarray,
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
    k = G / 1000.0 / (1.0 + gamma)
    fnet = np.asarray(fnet, dtype=float)
    v, W, rest = _rk4_pass(theta, v0, h, fnet, np.asarray(grade, dtype=float), k)
    h6 = h / 6.0
    dxs = h6 * (W[:, 0] + 2.0 * W[:, 1] + 2.0 * W[:, 2] + W[:, 3])
    x = x0 + np.concatenate([[0.0], np.cumsum(dxs)])
    if not sensitivities:
        return Trajectory(v, x, None, None, None, None)
    a, cx, Bv, Bx = _step_derivatives(theta, h, fnet, W, rest, k)
    n = len(h)
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
    cov: np.ndarray                # (4, 4) covariance of Theta-hat: output error with q: the
    #                                sandwich; filter error, or no q given: (J^T J)^-1 s^2
    cov_white: np.ndarray          # (4, 4) (J^T J)^-1 s^2 of the method's own residuals
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
    method: str = "output_error"   # or "filter_error"
    segment: "Segment | None" = None   # the data as fitted (for estimate_process_noise_psd)
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
        rotating masses, docs/model.md, Forces on the car)."""
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
        """(J_d, h_d): the information on the A's that this segment's data (with its own
        mass prior) carries, without the prior on the A's, and the matching information vector
        (h_d = J_d A_d for the data-only estimate A_d): what ``fuse_estimates`` adds up, so a
        prior common to several fits is not counted several times.

        Computed in ``fit_segment`` from the honest (sandwich) covariance of the estimator
        without the A-prior, J_loc = H (H + M)^-1 H (H the local Gauss-Newton information, M
        the process-noise meat), then the mass and the initial state marginalised out (Schur
        complement): positive semi-definite by construction.
        """
        return self.diagnostics["A_info_data"].copy(), self.diagnostics["A_h_data"].copy()


def _remember_last(fn):
    """fn(p) for a parameter vector p, kept for the last p only: least_squares asks for the
    residuals and the Jacobian at the same p, and both need the same trajectory."""
    last: dict = {}

    def remembered(p):
        key = p.tobytes()
        if key not in last:
            last.clear()
            last[key] = fn(p)
        return last[key]
    return remembered


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
        return G / 1000.0 / (1.0 + self.gamma)


# ------------------------------------------------------------------------- filter error

def _riccati(seg: Segment, a: np.ndarray, cx: np.ndarray, q: float):
    """Kalman gains and innovation Cholesky factors along the segment (scalar loop, 2 states).

    State (V, X), transition [[a, 0], [cx, 1]] of the RK4 step, white-acceleration process
    noise of density q [m^2/s^3] (Q = q [[h, h^2/2], [h^2/2, h^3/3]]), measurement V (and X)
    with R = diag(speed_std^2, distance_std^2). The initial state is a fitted parameter: P = 0
    at the first sample. Returns lists K11, K12, K21, K22, l11, l21, l22 and sum log det S.
    """
    n = len(seg.time)
    h = np.diff(seg.time).tolist()
    al, cl = a.tolist(), cx.tolist()
    rv = seg.speed_std ** 2
    use_x = seg.distance is not None
    rx = seg.distance_std ** 2 if use_x else 0.0
    K11, K12, K21, K22 = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
    l11, l21, l22 = [0.0] * n, [0.0] * n, [1.0] * n
    p11 = p12 = p22 = 0.0
    logdet = 0.0
    for j in range(n):
        if use_x:
            s11, s12, s22 = p11 + rv, p12, p22 + rx
            det = s11 * s22 - s12 * s12
            k11 = (p11 * s22 - p12 * s12) / det
            k12 = (p12 * s11 - p11 * s12) / det
            k21 = (p12 * s22 - p22 * s12) / det
            k22 = (p22 * s11 - p12 * s12) / det
            q11 = p11 - (k11 * p11 + k12 * p12)
            q12 = p12 - (k11 * p12 + k12 * p22)
            q22 = p22 - (k21 * p12 + k22 * p22)
            a11 = math.sqrt(s11)
            a21 = s12 / a11
            a22 = math.sqrt(max(s22 - a21 * a21, 1e-300))
            logdet += 2.0 * (math.log(a11) + math.log(a22))
            K11[j], K12[j], K21[j], K22[j] = k11, k12, k21, k22
            l11[j], l21[j], l22[j] = a11, a21, a22
        else:
            s11 = p11 + rv
            k11 = p11 / s11
            k21 = p12 / s11
            q11 = p11 - k11 * p11
            q12 = p12 - k11 * p12
            q22 = p22 - k21 * p12
            a11 = math.sqrt(s11)
            logdet += 2.0 * math.log(a11)
            K11[j], K21[j] = k11, k21
            l11[j] = a11
        if j < n - 1:
            hj, aj, cj = h[j], al[j], cl[j]
            p11 = aj * aj * q11 + q * hj
            p12 = aj * (cj * q11 + q12) + 0.5 * q * hj * hj
            p22 = cj * cj * q11 + 2.0 * cj * q12 + q22 + q * hj * hj * hj / 3.0
    return (K11, K12, K21, K22, l11, l21, l22), logdet


def _filter_pass(theta, v0: float, x0: float, seg: Segment, gains):
    """Eq. (2) as a predictor-corrector with fixed gains (scalar loop): RK4 prediction from
    the corrected state, correction by the gains. Returns the whitened innovations e (m, n)
    (m = 2 with distances), the stage speeds W (n-1, 4), the rest flags and the corrected V."""
    K11, K12, K21, K22, l11, l21, l22 = gains
    th1, a0, a1, a2 = (float(x) for x in theta)
    k = seg.k
    b1, b2 = k * a1, k * a2
    gl = (k * (th1 * seg.fnet - a0 - seg.grade)).tolist()
    hl = np.diff(seg.time).tolist()
    vm = seg.speed.tolist()
    use_x = seg.distance is not None
    xm = seg.distance.tolist() if use_x else None
    n = len(vm)
    e1, e2 = [0.0] * n, [0.0] * n
    w_out = [0.0] * (4 * (n - 1))
    rest = [False] * (n - 1)
    vhat = [0.0] * n
    v, x = float(v0), float(x0)
    for j in range(n):
        nv = vm[j] - v
        if use_x:
            nx = xm[j] - x
            v, x = v + K11[j] * nv + K12[j] * nx, x + K21[j] * nv + K22[j] * nx
            u1 = nv / l11[j]
            e1[j] = u1
            e2[j] = (nx - l21[j] * u1) / l22[j]
        else:
            v, x = v + K11[j] * nv, x + K21[j] * nv
            e1[j] = nv / l11[j]
        vhat[j] = v
        if j == n - 1:
            break
        hj = hl[j]
        hh = 0.5 * hj
        gj = gl[j]
        w1 = v if v > 0.0 else 0.0
        k1 = gj - b1 * w1 - b2 * w1 * w1
        r = 4 * j
        if v <= 0.0 and k1 <= 0.0:
            rest[j] = True
            v = 0.0
            continue
        w2, w3, w4, k2, k3, k4 = _rk4_stages(v, k1, gj, b1, b2, hh, hj)
        w_out[r], w_out[r + 1], w_out[r + 2], w_out[r + 3] = v, w2, w3, w4
        x = x + hj / 6.0 * (v + 2.0 * w2 + 2.0 * w3 + w4)
        v = v + hj / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if v < 0.0:
            v = 0.0
            rest[j] = True
    e = np.array([e1, e2]) if use_x else np.array([e1])
    return e, np.array(w_out).reshape(n - 1, 4), np.array(rest, dtype=bool), np.array(vhat)


def _filter_jacobian(theta, seg: Segment, gains, W, rest, cols, n_par: int) -> np.ndarray:
    """d e / d p (m n, n_par) of the whitened innovations, gains held (the filter-error
    method's usual simplification: here the gains depend on Theta only through the step
    derivative a = 1 - O(1e-4)). p = (Theta[cols of 0..3], V0, X0)."""
    K11, K12, K21, K22, l11, l21, l22 = (np.asarray(g) for g in gains)
    h = np.diff(seg.time)
    a, cx, Bv, Bx = _step_derivatives(theta, h, seg.fnet, W, rest, seg.k)
    n = len(seg.time)
    use_x = seg.distance is not None
    # sensitivities of the predicted state: s[j+1] = A_j (I - K_j H) s[j] + B_j
    Mt = np.zeros((n - 1, 2, 2))
    if use_x:
        i11, i12, i21, i22 = 1.0 - K11[:-1], -K12[:-1], -K21[:-1], 1.0 - K22[:-1]
    else:
        i11, i12, i21, i22 = 1.0 - K11[:-1], np.zeros(n - 1), -K21[:-1], np.ones(n - 1)
    Mt[:, 0, 0] = a * i11
    Mt[:, 0, 1] = a * i12
    Mt[:, 1, 0] = cx * i11 + i21
    Mt[:, 1, 1] = cx * i12 + i22
    Bf = np.zeros((n - 1, 2, n_par))
    th_cols = [c for c in cols if c < 4]
    Bf[:, 0, :len(th_cols)] = Bv[:, th_cols]
    Bf[:, 1, :len(th_cols)] = Bx[:, th_cols]
    S = np.empty((n, 2, n_par))
    s = np.zeros((2, n_par))
    s[0, len(th_cols)] = 1.0                    # V0
    if n_par > len(th_cols) + 1:
        s[1, len(th_cols) + 1] = 1.0            # X0
    S[0] = s
    for j in range(n - 1):
        s = Mt[j] @ s + Bf[j]
        S[j + 1] = s
    de1 = -S[:, 0, :] / l11[:, None]
    if not use_x:
        return de1
    de2 = (-S[:, 1, :] - l21[:, None] * de1) / l22[:, None]
    return np.concatenate([de1, de2])


# ------------------------------------------------------------------------- the fit

def fit_segment(time, speed, traction=None, brake=None, *, distance=None,
                grade_profile: GradeProfile | None = None, grade=None, length: float = 0.0,
                gamma: float = 0.0, fit_mass: bool | None = None, mass: float | None = None,
                prior: Prior | None = None, use_distance: bool = True,
                speed_std: float | None = None, distance_std: float | None = None,
                process_noise_psd: float | None = None, method: str = "output_error",
                theta0=None, max_nfev: int = 50) -> OutputErrorFit:
    """Fit Theta (and V0, X0) to one segment of samples by output error (or filter error).

    time [s] (n,) sample instants; speed [m/s] (n,) measured; traction, brake [N] applied over
    each interval [t_k, t_k+1] (n-1 values, or n with the last ignored; None = 0); distance [m]
    (n,) measured, or None; grade: a ``grade_profile`` evaluated along the reference track
    (``reference_track``) averaged over ``length`` [m], or ``grade`` (n-1,) [permille] per
    interval, or neither (level); gamma the rotating-mass factor [-].

    fit_mass: None = automatic (fitted iff some interval has F - B != 0); when not fitted,
    Theta1 is held at 1/(g mass) (or the prior's / default value; irrelevant when F = B = 0).
    prior: Gaussian prior on Theta (``Prior``). speed_std [m/s], distance_std [m]: measurement
    noise; None = estimated from second differences (``noise_std_from_differences``).
    process_noise_psd q [m^2/s^3]: for method "output_error", None = ``cov`` is the white
    formula (J^T J)^-1 s^2, a number >= 0 = the sandwich with that random-walk process noise.

    method: "output_error" (deterministic simulation, the default) or "filter_error" (needs
    q > 0): the output-error solution refined by the filter-error method, Maine & Iliff (1986)
    NASA RP-1168 / Jategaonkar (2015) ch. 5: the residuals are the whitened innovations of a
    Kalman filter around eq. (2) (gains at the output-error solution, then held), i.e. the
    maximum-likelihood estimate under process plus measurement noise. Its residuals are white,
    so (J^T J)^-1 s^2 is honest; it does not chase the process noise's random walk (about 1.7
    times smaller std of w0 at low speed on a station-to-station run), but its A's therefore
    reproduce one particular coast less closely than output error's.
    """
    if method not in ("output_error", "filter_error"):
        raise ValueError(f"method must be 'output_error' or 'filter_error', got {method!r}")
    if method == "filter_error" and not (process_noise_psd and process_noise_psd > 0.0):
        raise ValueError("method 'filter_error' needs process_noise_psd > 0 [m^2/s^3]")
    t = np.asarray(time, dtype=float)
    v_meas = np.asarray(speed, dtype=float)
    n = len(t)
    if n < 3 or v_meas.shape != (n,):
        raise ValueError("fit_segment needs >= 3 samples and one speed per sample time")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("sample times must increase")
    fnet = net_force_per_interval(traction, brake, n - 1)
    x_meas = None if distance is None else np.asarray(distance, dtype=float)
    if x_meas is not None and x_meas.shape != (n,):
        raise ValueError("distance needs one value per sample time")
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
    seg = Segment(t, v_meas, x_meas if use_x else None, fnet, grade_iv, float(gamma), sv, sx)

    th_start = _theta_start(prior, theta0, mass)
    th_idx = [0, 1, 2, 3] if fit_mass else [1, 2, 3]
    n_th = len(th_idx)
    L_pr, mu_pr = prior.whitener(th_idx) if prior is not None else (np.zeros((0, n_th)), np.zeros(n_th))
    # parameter vector p = (Theta[th_idx], V0[, X0])
    p0 = np.concatenate([th_start[th_idx], [float(np.mean(v_meas[:3]))]])
    if use_x:
        p0 = np.concatenate([p0, [float(x_meas[0])]])
    n_par = len(p0)
    cols = th_idx + [4]                                   # columns of Trajectory.dv / dx used

    def unpack(p):
        th = th_start.copy()
        th[th_idx] = p[:n_th]
        v0 = p[n_th]
        x0 = p[n_th + 1] if use_x else 0.0
        return th, v0, x0

    def prior_jac():
        Jp = np.zeros((L_pr.shape[0], n_par))
        Jp[:, :n_th] = L_pr
        return Jp

    # ---- output error
    traj = _remember_last(lambda p: simulate(*unpack(p), t, fnet, grade_iv, gamma))

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
        blocks.append(prior_jac())
        return np.concatenate(blocks, axis=0)

    scale = np.concatenate([np.array([DEFAULT_THETA[0], 1.0, 0.03, 0.01])[th_idx], [0.1],
                            [1.0] if use_x else []])
    sol = least_squares(residuals, p0, jac=jacobian, method="lm", x_scale=scale,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
    nfev = int(sol.nfev)
    p = sol.x
    th, v0, x0 = unpack(p)
    tr = traj(p)
    m_data = n * (2 if use_x else 1)
    M = None
    diag = {}
    if method == "output_error":
        J = jacobian(p)
        r = residuals(p)
        q = float("nan") if process_noise_psd is None else float(process_noise_psd)
    else:
        # ---- filter error, starting from the output-error solution
        q = float(process_noise_psd)
        gains, _ = _riccati(seg, tr.a, tr.cx, q)
        def _fpass(pp):
            thp, v0p, x0p = unpack(pp)
            return _filter_pass(thp, v0p, x0p if use_x else 0.0, seg, gains)
        fpass = _remember_last(_fpass)

        def f_residuals(pp):
            e = fpass(pp)[0]
            return np.concatenate([e.ravel(), L_pr @ (pp[:n_th] - mu_pr)])

        def f_jacobian(pp):
            _, W, rest, _ = fpass(pp)
            thp = unpack(pp)[0]
            Je = _filter_jacobian(thp, seg, gains, W, rest, cols, n_par)
            return np.concatenate([Je, prior_jac()])

        sol = least_squares(f_residuals, p, jac=f_jacobian, method="lm", x_scale=scale,
                            xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
        nfev += int(sol.nfev)
        p = sol.x
        th, v0, x0 = unpack(p)
        tr = traj(p)
        J = f_jacobian(p)
        r = f_residuals(p)
        diag["innovations"] = fpass(p)[0]
    Jd, Jp = J[:m_data], J[m_data:]
    rd = r[:m_data]
    dof = max(m_data - n_par, 1)
    s2 = float(rd @ rd) / dof
    H = Jd.T @ Jd + Jp.T @ Jp
    Hw = Jd.T @ Jd / s2 + Jp.T @ Jp
    cov_w_p = np.linalg.inv(Hw)
    if method == "output_error" and process_noise_psd is not None:
        Hi = np.linalg.inv(H)
        M = _process_noise_meat(tr, Jd, n, use_x, q, t, sv, sx)
        cov_p = Hi @ (H + M) @ Hi
    else:
        cov_p = cov_w_p
    A_info, A_h = _data_information(Jd, Jp, s2, M, p, prior, th_idx, fit_mass)
    cov4 = np.zeros((4, 4))
    cov4w = np.zeros((4, 4))
    cov4[np.ix_(th_idx, th_idx)] = cov_p[:n_th, :n_th]
    cov4w[np.ix_(th_idx, th_idx)] = cov_w_p[:n_th, :n_th]
    res_v = v_meas - tr.speed
    diag.update({"cost": float(sol.cost), "optimality": float(sol.optimality),
                 "cov_params": cov_p, "grade_mean": float(grade_iv.mean()),
                 "A_info_data": A_info, "A_h_data": A_h, "step_a": tr.a, "step_cx": tr.cx,
                 "cols": cols, "n_params": n_par})
    return OutputErrorFit(
        theta=th, cov=cov4, cov_white=cov4w, v0=float(v0),
        v0_std=math.sqrt(max(cov_p[n_th, n_th], 0.0)),
        x0=float(x0) if use_x else float("nan"), fit_mass=fit_mass, n=n, speed_std=sv,
        distance_std=sx, process_noise_psd=q, s2=s2,
        speed_rms=float(np.sqrt(np.mean(res_v ** 2))),
        distance_rms=float(np.sqrt(np.mean((x_meas - tr.distance) ** 2))) if use_x else float("nan"),
        speed_sim=tr.speed, distance_sim=tr.distance, speed_residual=res_v, time=t, prior=prior,
        nfev=nfev, success=bool(sol.success), message=str(sol.message), method=method,
        segment=seg, diagnostics=diag)


def fit_initial_state(theta, time, speed, traction=None, brake=None, *, distance=None,
                      grade_profile: GradeProfile | None = None, grade=None, length: float = 0.0,
                      gamma: float = 0.0, speed_std: float | None = None,
                      distance_std: float | None = None) -> tuple[float, float]:
    """(V0 [m/s], X0 [m]) that best fit the segment with Theta held: the initial state of the
    recomputed run of a given model (seed 003 re-runs each coast with the identified
    coefficients; this is the start that run needs). Arguments as ``fit_segment``; X0 is nan
    without distances."""
    t = np.asarray(time, dtype=float)
    v_meas = np.asarray(speed, dtype=float)
    n = len(t)
    fnet = net_force_per_interval(traction, brake, n - 1)
    x_meas = None if distance is None else np.asarray(distance, dtype=float)
    if grade is not None:
        grade_iv = np.asarray(grade, dtype=float)[: n - 1]
    else:
        grade_iv = grade_per_interval(reference_track(t, v_meas, x_meas), grade_profile, length)
    sv = max(float(speed_std if speed_std is not None else noise_std_from_differences(v_meas)), 1e-9)
    sx = float("nan")
    if x_meas is not None:
        sx = max(float(distance_std if distance_std is not None
                       else noise_std_from_differences(x_meas)), 1e-9)
    theta = np.asarray(theta, dtype=float)

    def res_jac(p):
        tr = simulate(theta, p[0], p[1] if x_meas is not None else 0.0, t, fnet, grade_iv, gamma)
        r = [(tr.speed - v_meas) / sv]
        J = [np.column_stack([tr.dv[:, 4], np.zeros(n)])[:, :len(p)] / sv]
        if x_meas is not None:
            r.append((tr.distance - x_meas) / sx)
            J.append(np.column_stack([tr.dx[:, 4], np.ones(n)]) / sx)
        return np.concatenate(r), np.concatenate(J)

    p0 = [float(np.mean(v_meas[:3]))] + ([float(x_meas[0])] if x_meas is not None else [])
    sol = least_squares(lambda p: res_jac(p)[0], np.array(p0), jac=lambda p: res_jac(p)[1],
                        method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return float(sol.x[0]), (float(sol.x[1]) if x_meas is not None else float("nan"))


def _data_information(Jd, Jp, s2, M, p, prior, th_idx, fit_mass):
    """(J_A, h_A) of the segment's data without the A-prior (see A_data_information).

    Linearised at the optimum p: with H_loc = Jd^T Jd + (the prior's mass block) and the prior
    on the A's J_pA, the local estimate satisfies H_loc p_loc = H p - J_pA mu (H the full
    Gauss-Newton information); its robust covariance is H_loc^-1 (H_loc + M) H_loc^-1, so its
    information is H_loc (H_loc + M)^-1 H_loc. Without process noise M = (s2 - 1) Jd^T Jd
    (the white formula (J^T J)^-1 s2).
    """
    n_p = len(p)
    Hd = Jd.T @ Jd
    Jpr = Jp.T @ Jp
    a_idx = [1, 2, 3] if fit_mass else [0, 1, 2]
    JpA = np.zeros((n_p, n_p))
    JpA[np.ix_(a_idx, a_idx)] = Jpr[np.ix_(a_idx, a_idx)]
    Jpn = Jpr - JpA                  # the mass prior (and any mass-A cross term) stays local
    mu = np.zeros(n_p)
    if prior is not None:
        mu[:len(th_idx)] = prior.mean[th_idx]
    H = Hd + Jpr
    H_loc = Hd + Jpn
    if M is None:
        M = (s2 - 1.0) * Hd
    G_ = np.linalg.solve(H_loc + M, H_loc)           # (H_loc + M)^-1 H_loc
    I_loc = H_loc @ G_
    I_loc = 0.5 * (I_loc + I_loc.T)
    h_loc = G_.T @ (H @ p - JpA @ mu)
    n_idx = [j for j in range(n_p) if j not in a_idx]
    Inn = I_loc[np.ix_(n_idx, n_idx)]
    IAn = I_loc[np.ix_(a_idx, n_idx)]
    K = np.linalg.solve(Inn, IAn.T).T                 # I_An I_nn^-1
    J_A = I_loc[np.ix_(a_idx, a_idx)] - K @ IAn.T
    h_A = h_loc[a_idx] - K @ h_loc[n_idx]
    return 0.5 * (J_A + J_A.T), h_A


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

def process_noise_nll(fits, q: float, restricted: bool = True) -> float:
    """-2 log-likelihood (up to a constant) of the fits' data under process noise density q
    [m^2/s^3], each fit's parameters held: the sum of log det S_k + e_k^T e_k over the
    innovations of the Kalman filter around eq. (2) (the filter-error likelihood).

    ``restricted``: plus log det(J^T J + prior information) of each fit's parameters (restricted
    / residual maximum likelihood, Patterson & Thompson 1971, Biometrika 58: the parameters'
    degrees of freedom are not charged to the noise): the fitted parameters absorb part of the
    random walk, and without this term q comes out ~13 % low on ten station-to-station runs
    (measured; with it within ~5 %).
    """
    tot = 0.0
    for f in fits:
        seg = f.segment
        gains, logdet = _riccati(seg, f.diagnostics["step_a"], f.diagnostics["step_cx"], q)
        x0 = f.x0 if seg.distance is not None else 0.0
        e, W, rest, _ = _filter_pass(f.theta, f.v0, x0, seg, gains)
        tot += logdet + float(np.sum(e * e))
        if restricted:
            cols = f.diagnostics["cols"]
            th_idx = [c for c in cols if c < 4]
            n_par = f.diagnostics["n_params"]
            J = _filter_jacobian(f.theta, seg, gains, W, rest, cols, n_par)
            H = J.T @ J
            if f.prior is not None:
                H[:len(th_idx), :len(th_idx)] += f.prior.info[np.ix_(th_idx, th_idx)]
            d = np.sqrt(np.maximum(np.diag(H), 1e-300))
            _, ld = np.linalg.slogdet(H / np.outer(d, d))
            tot += ld + 2.0 * float(np.sum(np.log(d)))
    return tot


def estimate_process_noise_psd(fits, bounds=(1e-7, 1e-2), restricted: bool = True) -> float:
    """Process-noise density q [m^2/s^3] pooled over several fits, by (restricted) maximum
    likelihood: ``process_noise_nll`` minimised over log q in ``bounds`` (the noise-parameter
    step of the filter-error method, Maine & Iliff 1985). Measurement-noise stds are the fits'
    own (give the sensor's configured stds to ``fit_segment``: the likelihood trades q against
    R, so a few % error in an estimated R moves q by tens of %). One two-minute segment pins q
    down only to a factor ~1.5; pooling a day's runs is what makes it usable (ten runs: ~10 %).
    """
    fits = [f for f in fits if f.segment is not None]
    if not fits:
        return float("nan")
    lo, hi = math.log10(bounds[0]), math.log10(bounds[1])
    res = minimize_scalar(lambda lq: process_noise_nll(fits, 10.0 ** lq, restricted),
                          bounds=(lo, hi), method="bounded", options={"xatol": 0.01})
    return float(10.0 ** res.x)


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

    The A's carry over from run to run while the mass restarts at each stop (seed 001: "P is
    constant between two stations; A0..A2 drift slowly"). Each run is fitted on its own, with
    only the weak ``base_prior`` (physical A's, a fresh mass prior), and its *data*
    information on the A's (``OutputErrorFit.A_data_information``: the mass and the initial
    state integrated out, the base prior removed) is added to the state, whose information is
    first multiplied by (1 - forgetting) per run.

    Why not use the A's learnt so far as the next fit's prior: under process noise an
    output-error fit weighs its data by J^T J (white residuals assumed), several times their
    true information (the sandwich ``cov``); the carried prior would be drowned and the state
    would follow the last run (measured on ten station-to-station runs: w0 error 6-31 % against
    1-3.5 % with this fusion). Information fusion with the honest covariance weighs every run
    correctly. (With method="filter_error" both ways agree: its residuals are white.) So with
    output error and q given, the state after one run is not the fit's own (prior-weighted)
    estimate but the better-weighted combination of the same data and prior.
    """

    def __init__(self, base_prior: Prior | None = None, forgetting: float = 0.0):
        self.base_prior = base_prior if base_prior is not None else physical_prior()
        self.forgetting = float(forgetting)
        self._J = self.base_prior.A_info()
        self._h = self._J @ self.base_prior.mean[1:]
        self.runs = 0
        self.fits: list[OutputErrorFit] = []

    @property
    def A(self) -> np.ndarray:
        """(A0, A1, A2) learnt so far [N/kN, N/kN/(m/s), N/kN/(m/s)^2]."""
        return self.cov_A @ self._h

    @property
    def cov_A(self) -> np.ndarray:
        """Their covariance (3x3)."""
        return np.linalg.inv(0.5 * (self._J + self._J.T))

    def prior(self, mass: float | None = None, mass_std: float | None = None) -> Prior:
        """The weak prior each run is fitted with: the base prior's A's and a fresh mass prior
        mass [t] +- mass_std [t] (none if not given)."""
        bp = self.base_prior
        mean = bp.mean.copy()
        info = bp.info.copy()
        info[0, :] = 0.0
        info[:, 0] = 0.0
        if mass:
            mean[0] = 1.0 / (G * mass)
            if mass_std:
                info[0, 0] = 1.0 / mass_prior_std_theta1(mass, mass_std) ** 2
        return Prior(mean, info)

    def fit(self, *args, mass: float | None = None, mass_std: float | None = None,
            **kwargs) -> OutputErrorFit:
        """``fit_segment(*args, prior=self.prior(mass, mass_std), mass=mass, **kwargs)``, then
        ``update`` with it; returns the run's fit (its own A's, not the fused ones)."""
        f = fit_segment(*args, prior=self.prior(mass, mass_std), mass=mass, **kwargs)
        self.update(f)
        return f

    def update(self, f: OutputErrorFit) -> None:
        """Add one run's data information on the A's (forgetting the old by 1 - forgetting)."""
        Jd, hd = f.A_data_information()
        lam = 1.0 - self.forgetting if self.runs else 1.0
        J0 = self.base_prior.A_info()
        h0 = J0 @ self.base_prior.mean[1:]
        # forgetting acts on the data information only: the base prior is never forgotten
        # (regularised forgetting, as models.estimation.identification does against wind-up)
        self._J = J0 + lam * (self._J - J0) + Jd
        self._h = h0 + lam * (self._h - h0) + hd
        self.runs += 1
        self.fits.append(f)


def physical_prior(mass: float | None = None, mass_std: float | None = None) -> Prior:
    """A weak prior that keeps the A's physical: A0 = 1 +- 1 N/kN, A1 = 0.03 +- 0.03
    N/kN/(m/s), A2 = 0.01 +- 0.01 N/kN/(m/s)^2 (1 sigma), independent.

    Centred on the estimator's default est.A*_initial; one sigma spans the resistance of metro
    and suburban cars in m/s units (seed 003 Table 1: A0 0.11-0.89, A1 0.004-0.029, A2
    0.004-0.012), so the truth lies within 1-2 sigma for all four rows. Plus an optional mass
    prior mass [t] +- mass_std [t].
    """
    std = [None, 1.0, 0.03, 0.01]
    mean = [DEFAULT_THETA[0], 1.0, 0.03, 0.01]
    if mass:
        mean[0] = 1.0 / (G * mass)
        if mass_std:
            std[0] = mass_prior_std_theta1(mass, mass_std)
    return Prior.from_std(mean, std)
