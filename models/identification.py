"""Least-squares identification of P, A0, A1, A2 and sigma^2 from measured motion, eqs. (3)-(12).

Regression form of eq. (2) (MODEL.md section 4), generalised by a known rotating-mass factor
gamma (gamma = 0 is the paper exactly):

    Theta = (1/(P g), A0, A1, A2)         [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]
    phi(n) = (F[n] - B[n], -1, -V[n], -V[n]^2)
    y(n)   = 1000 (1 + gamma) (V[n+1] - V[n]) / (g dt) + i[n]          [N/kN]   (4)

The functional core (``regressor``, ``regression_target``, ``batch_ls``, ``rls_step``,
``sigma2_from_residual``) is the paper's algorithm verbatim. ``ParameterIdentifier`` wraps it
for a running car and adds what a product needs and the paper leaves open:

- a weak Gaussian prior on Theta (the configured initial values), added to Phi^T Phi at the
  batch start, so coasting-only data (F = B = 0: 1/(Pg) unobservable) still gives the A's
  while the mass keeps its prior, instead of a singular matrix;
- regularised forgetting: with a constant mu0 the prior information is re-added each step
  (R <- R + mu0^2 J0), so S cannot wind up in unexcited directions;
- no update while the car stands (the model (2) does not hold at rest);
- mass restart after a station stop: 1/(Pg) is marginalised out of the information matrix and
  reopened with its prior, so the A's keep what they learnt;
- the covariance of Theta-hat, cov = s^2 S / n_eff (n_eff = n for mu = 1/n, (2 - mu0)/mu0 for
  exponential forgetting), from which est.mass_std follows by the delta method.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .units import G


# ---------------------------------------------------------------- functional core (paper)

def regressor(traction: float, brake: float, speed: float) -> np.ndarray:
    """phi(n) = (F - B, -1, -V, -V^2) for forces [N] and speed [m/s], eq. (4)."""
    return np.array([traction - brake, -1.0, -speed, -speed * speed])


def regression_target(speed: float, speed_next: float, grade: float, dt: float,
                      gamma: float = 0.0) -> float:
    """y(n) = 1000 (1+gamma) (V[n+1] - V[n]) / (g dt) + i[n]  [N/kN], eq. (4)."""
    return 1000.0 * (1.0 + gamma) * (speed_next - speed) / (G * dt) + grade


def batch_ls(phi_rows: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Theta(N) = (Phi^T Phi)^-1 Phi^T Y and R(N) = Phi^T Phi / N (eqs. after (7), (10))."""
    phi_rows = np.asarray(phi_rows, dtype=float)
    info = phi_rows.T @ phi_rows
    theta = np.linalg.solve(info, phi_rows.T @ np.asarray(y, dtype=float))
    return theta, info / len(phi_rows)


def rls_step(theta: np.ndarray, S: np.ndarray, phi: np.ndarray, y: float,
             mu: float) -> tuple[np.ndarray, np.ndarray]:
    """One recursive step, eqs. (8), (9), (11): returns Theta(n), S(n) = R(n)^-1.

    ``mu`` = 1/n gives ordinary least squares; a constant mu0 forgets with factor 1 - mu0.
    """
    S_phi = S @ phi
    phi_S_phi = float(phi @ S_phi)
    K = S_phi / (1.0 + mu * (phi_S_phi - 1.0))                                  # (9)
    theta_new = theta + mu * K * (y - float(theta @ phi))                       # (8)
    S_new = (S - np.outer(S_phi, S_phi) / ((1.0 - mu) / mu + phi_S_phi)) / (1.0 - mu)  # (11)
    return theta_new, S_new


def residual_variance(q_e: float, n: int) -> float:
    """s^2 = Q_e / (n - 4), the residual variance of e(n) [(N/kN)^2]."""
    return q_e / (n - 4)


def sigma2_from_residual(s2: float, dt: float, gamma: float = 0.0) -> float:
    """sigma^2 = g^2 dt^2 / 10^6 * s^2 / (1+gamma)^2  [(m/s)^2], eq. (12)."""
    return G * G * dt * dt / 1e6 * s2 / (1.0 + gamma) ** 2


def mass_from_theta(theta1: float) -> float:
    """P-hat = 1 / (g Theta1) [t]."""
    return 1.0 / (G * theta1)


def theta_from_params(mass: float, a0: float, a1: float, a2: float) -> np.ndarray:
    """Theta for mass [t] and resistance coefficients."""
    return np.array([1.0 / (G * mass), a0, a1, a2])


# ---------------------------------------------------------------- stateful wrapper

@dataclass
class IdentifierConfig:
    """Settings of the running identification (names follow the FMU parameters est.*)."""
    dt: float = 0.1                  # sampling period [s]
    batch_size: int = 50             # N, samples of the first batch (>= 4)
    forgetting: float = 0.0          # mu0 in [0, 1); 0 = mu(n) = 1/n (ordinary LS)
    gamma: float = 0.0               # rotating-mass factor assumed by the estimator [-]
    mass_initial: float = 30.0       # [t]
    mass_std_initial: float = 10.0   # [t]
    A0_initial: float = 1.0          # [N/kN]
    A1_initial: float = 0.03         # [N/kN/(m/s)]
    A2_initial: float = 0.01         # [N/kN/(m/s)^2]
    A0_std_initial: float = 5.0      # [N/kN]
    A1_std_initial: float = 0.1      # [N/kN/(m/s)]
    A2_std_initial: float = 0.02     # [N/kN/(m/s)^2]
    sigma2_initial: float = 1e-4     # process-noise variance per step [(m/s)^2]
    speed_std: float = 0.0           # measurement noise of V [m/s]: scales the prior's weight
    frozen: bool = False             # keep the initial values (an oracle that knows the truth)

    def validate(self) -> None:
        """Raise ValueError naming the first invalid setting."""
        if int(self.batch_size) < 4:
            raise ValueError(f"est.batch_size must be >= 4 (4 parameters), got {self.batch_size}")
        if not 0.0 <= self.forgetting < 1.0:
            raise ValueError(f"est.forgetting must be in [0, 1), got {self.forgetting}")
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"sampling period must be > 0, got {self.dt}")
        for name in ("mass_initial", "mass_std_initial", "A0_std_initial", "A1_std_initial",
                     "A2_std_initial", "sigma2_initial"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"est.{name} must be > 0, got {v}")
        for name in ("A0_initial", "A1_initial", "A2_initial", "gamma", "speed_std"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"est.{name} must be finite, got {v}")
        if self.gamma < 0:
            raise ValueError(f"est.gamma must be >= 0, got {self.gamma}")


class ParameterIdentifier:
    """Running identification of Theta and sigma^2 (thin stateful wrapper of the core above)."""

    def __init__(self, cfg: IdentifierConfig):
        cfg.validate()
        self.cfg = cfg
        self.theta0 = theta_from_params(cfg.mass_initial, cfg.A0_initial, cfg.A1_initial,
                                        cfg.A2_initial)
        self._scale = 1000.0 * (1.0 + cfg.gamma) / (G * cfg.dt)   # y per (m/s) of speed change
        # expected variance of e(n) before any data: measurement and process noise, eq. (5)
        s2_ref = self._scale ** 2 * max(2.0 * cfg.speed_std ** 2 + cfg.sigma2_initial, 1e-12)
        theta1_std = cfg.mass_std_initial / (G * cfg.mass_initial ** 2)
        prior_std = np.array([theta1_std, cfg.A0_std_initial, cfg.A1_std_initial, cfg.A2_std_initial])
        self.J0 = np.diag(s2_ref / prior_std ** 2)    # prior information, in Phi^T Phi units
        self.s2_ref = s2_ref
        self.reset()

    def reset(self) -> None:
        """Back to the configured initial values (a new instance, in effect)."""
        self.theta = self.theta0.copy()
        self.S = None                 # R^-1 once the batch is done
        self.n = 0                    # samples used
        self.q_e = 0.0                # residual sum of squares (mu = 1/n) [(N/kN)^2]
        self.s2 = self.s2_ref         # residual variance of e(n)
        self._batch_phi: list[np.ndarray] = []
        self._batch_y: list[float] = []
        self._batch_contiguous: list[bool] = []
        self.mass_restarts = 0
        # honest covariance (see covariance()): information J (with the prior), white-noise
        # meat W, differenced-noise meat D (closed runs; the open run's end is _last_phi),
        # lag-0/lag-1 autocovariance of the residuals
        self.J = self.J0.copy()
        self.W = np.zeros((4, 4))
        self.D = np.zeros((4, 4))
        self._last_phi = None
        self._last_err = None
        self.c0 = self.s2_ref
        self.c1 = 0.0
        self._n_c1 = 0

    @property
    def samples(self) -> int:
        """Sample pairs used so far (including those waiting for the first batch)."""
        return self.n if self.S is not None else len(self._batch_y)

    @property
    def ready(self) -> bool:
        """True once the first batch has been solved."""
        return self.S is not None

    def _accumulate(self, phi: np.ndarray, contiguous: bool, lam: float) -> None:
        """Add one regressor to J, W and D (weights of exponential forgetting lam = 1 - mu0)."""
        outer = np.outer(phi, phi)
        if lam < 1.0:
            self.J = lam * (self.J - self.J0) + self.J0
            self.W *= lam * lam
            self.D *= lam * lam
        self.J += outer
        self.W += outer
        last = self._last_phi
        if contiguous and last is not None:
            d = phi - last
            self.D += np.outer(d, d)
        else:
            if last is not None:
                self.D += np.outer(last, last)      # close the previous run
            self.D += outer                         # open a new one
        self._last_phi = phi

    def _residual_stats(self, err: float, contiguous: bool, mu: float) -> None:
        self.c0 += mu * (err * err - self.c0)
        if contiguous and self._last_err is not None:
            self._n_c1 += 1
            w = mu if self.cfg.forgetting > 0.0 else 1.0 / self._n_c1
            self.c1 += w * (err * self._last_err - self.c1)
        self._last_err = err

    def update(self, traction: float, brake: float, speed: float, speed_next: float,
               grade: float, dt: float | None = None, contiguous: bool = True) -> None:
        """Use the sample pair n, n+1: forces [N] applied between them, measured speeds [m/s],
        grade [permille] at n, their spacing dt [s] (default: the configured period).
        ``contiguous``: this pair directly follows the last one used (they share a sample)."""
        if self.cfg.frozen:
            return
        phi = regressor(traction, brake, speed)
        y = regression_target(speed, speed_next, grade, dt or self.cfg.dt, self.cfg.gamma)
        if self.S is None:
            self._batch_phi.append(phi)
            self._batch_y.append(y)
            self._batch_contiguous.append(contiguous)
            if len(self._batch_y) >= self.cfg.batch_size:
                self._solve_batch()
            return
        n = self.n + 1
        mu = self.cfg.forgetting if self.cfg.forgetting > 0.0 else 1.0 / n
        pred_err = y - float(self.theta @ phi)
        gain_den = 1.0 + mu / (1.0 - mu) * float(phi @ self.S @ phi)
        self.theta, self.S = rls_step(self.theta, self.S, phi, y, mu)
        self._accumulate(phi, contiguous, 1.0 - self.cfg.forgetting)
        self._residual_stats(pred_err / math.sqrt(gain_den), contiguous, mu)
        if self.cfg.forgetting > 0.0:
            # regularised forgetting: keep the prior's information (anti-windup)
            self.S = np.linalg.inv(np.linalg.inv(self.S) + mu * mu * self.J0)
            self.s2 = (1.0 - mu) * self.s2 + mu * pred_err ** 2 / gain_den
        else:
            self.q_e += pred_err ** 2 / gain_den
            self.s2 = residual_variance(self.q_e, n) if n > 4 else self.s2_ref
        self.n = n

    def _solve_batch(self) -> None:
        phi = np.array(self._batch_phi)
        y = np.array(self._batch_y)
        n = len(y)
        info = phi.T @ phi + self.J0
        self.theta = np.linalg.solve(info, phi.T @ y + self.J0 @ self.theta)
        self.S = np.linalg.inv(info / n)
        resid = y - phi @ self.theta
        self.q_e = float(resid @ resid)
        self.s2 = residual_variance(self.q_e, n) if n > 4 else self.s2_ref
        for k in range(n):
            self._accumulate(phi[k], self._batch_contiguous[k], 1.0)
        self.c0 = self.q_e / max(n - 4, 1)
        lagged = [resid[k] * resid[k - 1] for k in range(1, n) if self._batch_contiguous[k]]
        self._n_c1 = len(lagged)
        self.c1 = float(np.mean(lagged)) if lagged else 0.0
        self._last_err = float(resid[-1])
        self.n = n
        self._batch_phi, self._batch_y, self._batch_contiguous = [], [], []

    def restart_mass(self) -> None:
        """New passengers: reopen 1/(Pg) with its prior; the A's keep what they learnt."""
        self.mass_restarts += 1
        if self.S is None or self.cfg.frozen:
            return
        R = np.linalg.inv(self.S)
        r00 = R[0, 0]
        R[1:, 1:] -= np.outer(R[1:, 0], R[0, 1:]) / r00       # marginalise Theta1 out
        R[0, 1:] = 0.0
        R[1:, 0] = 0.0
        R[0, 0] = self.J0[0, 0] / self._n_eff()
        self.S = np.linalg.inv(R)
        J = self.J
        J[1:, 1:] -= np.outer(J[1:, 0], J[0, 1:]) / J[0, 0]
        J[0, 1:] = J[1:, 0] = 0.0
        J[0, 0] = self.J0[0, 0]
        for meat in (self.W, self.D):
            meat[0, :] = meat[:, 0] = 0.0
        self._last_phi = None

    def _n_eff(self) -> float:
        mu0 = self.cfg.forgetting
        if mu0 > 0.0:
            return min(float(self.n), (2.0 - mu0) / mu0)
        return float(max(self.n, 1))

    # ------------------------------------------------------------ outputs

    def noise_split(self) -> tuple[float, float]:
        """(a, b) [(N/kN)^2]: e(n) = u(n+1) - u(n) + p(n) with var(u) = a (the differenced
        speed measurement) and var(p) = b (process noise), from the residuals' lag-0 and lag-1
        autocovariance c0 = 2a + b, c1 = -a. Needs no knowledge of the sensor's noise."""
        a = max(-self.c1, 0.0)
        b = max(self.c0 - 2.0 * a, 1e-12 * self.c0)
        return a, b

    def covariance(self) -> np.ndarray:
        """Covariance of Theta-hat [Theta units^2], a sandwich J^-1 M J^-1.

        The paper's s^2 (Phi^T Phi)^-1 assumes white e(n); but V is measured, so e(n) carries
        the *difference* of two measurement errors (MA(1), lag-1 correlation -1/2), whose sum
        telescopes: the white formula overstates the mass's std tens of times. The meat is
        M = a D + b W + s2_ref J0, with D = sum over runs of consecutive samples of the
        differenced regressors (plus the runs' ends), W = sum phi phi^T, and the prior's own.
        """
        if self.cfg.frozen:
            return np.zeros((4, 4))
        Jinv = np.linalg.inv(self.J)
        if self.S is None:
            return self.s2_ref * Jinv @ self.J0 @ Jinv
        a, b = self.noise_split()
        D = self.D if self._last_phi is None else self.D + np.outer(self._last_phi, self._last_phi)
        meat = a * D + b * self.W + self.s2_ref * self.J0
        cov = Jinv @ meat @ Jinv
        return 0.5 * (cov + cov.T)

    @property
    def mass(self) -> float:
        """P-hat [t]."""
        return mass_from_theta(self.theta[0]) if self.theta[0] > 0 else float("inf")

    def mass_std(self) -> float:
        """Std of P-hat [t], delta method: std(Theta1) / (g Theta1^2)."""
        var = self.covariance()[0, 0]
        return math.sqrt(max(var, 0.0)) / (G * self.theta[0] ** 2)

    def sigma2(self) -> float:
        """Process-noise variance per step [(m/s)^2], eq. (12) applied to the process share b.

        V is measured, so the residual variance c0 of eq. (12) also holds 2a of differenced
        measurement noise (see noise_split); only b is process noise. It is floored at one
        standard error of c0 (c0 sqrt(2/n)) so the filter never gets a zero process noise.
        """
        if self.S is None:
            return self.cfg.sigma2_initial
        a, b = self.noise_split()
        b = max(b, self.c0 * math.sqrt(2.0 / self._n_eff()))
        return sigma2_from_residual(b, self.cfg.dt, self.cfg.gamma)

    def sigma2_paper(self) -> float:
        """sigma^2 exactly as eq. (12): g^2 dt^2 / 10^6 * Q_e / (n - 4) [(m/s)^2]."""
        return sigma2_from_residual(self.s2, self.cfg.dt, self.cfg.gamma)
