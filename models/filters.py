"""Kalman filters of speed and distance: the paper's linearised filter (13)-(19) and an EKF.

State (x, X): x = V - V_zad (speed deviation [m/s]) for the linearised filter, x = V for the
EKF; X distance from the previous station [m]. Measurements z = (V_meas - V_zad, X_meas)
(eq. (14), H = I), noise covariance Rm = diag(sigma_V^2, sigma_X^2).

Functional core: ``linearised_model`` (13), ``kf_update`` (15), (17), (18), ``kf_predict``
(16), (19), ``ekf_model`` (eq. (2) and its Jacobian). ``MotionFilter`` runs them sample by
sample. Matrices are 2x2 numpy arrays.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .track import GradeProfile, SpeedProfile
from .units import G

LINEARISED, EKF, PAPER = 1, 2, 3
"""Values of ``filter.kind``: 0 = automatic (LINEARISED when a speed profile is given, else EKF);
LINEARISED = linearised around V_zad, eq. (13), with the trapezoid distance update and
white-acceleration process noise; EKF = eq. (2) relinearised at the estimate, same distance
update; PAPER = eqs. (13)-(19) verbatim (Euler distance, Q = diag(sigma^2, 0)), the baseline."""


def specific_net_force(traction: float, brake: float, speed: float, grade: float,
                       theta: np.ndarray) -> float:
    """(F-B)/(Pg) - A0 - A1 V - A2 V^2 - i [N/kN] with Theta = (1/(Pg), A0, A1, A2)."""
    return theta[0] * (traction - brake) - theta[1] - theta[2] * speed - theta[3] * speed * speed - grade


def linearised_model(vzad: float, vzad_next: float, traction: float, brake: float, grade: float,
                     theta: np.ndarray, dt: float, gamma: float = 0.0) -> tuple[float, float, float]:
    """(a[n], c[n], C[n]) of eq. (13) around the reference speeds V_zad[n], V_zad[n+1] [m/s]."""
    k = G / 1000.0 / (1.0 + gamma) * dt
    c = vzad - vzad_next + k * specific_net_force(traction, brake, vzad, grade, theta)
    a = 1.0 - k * (theta[2] + 2.0 * theta[3] * vzad)
    return a, c, vzad * dt


def kf_update(x_bar: np.ndarray, M: np.ndarray, z: np.ndarray, Rm: np.ndarray):
    """Eqs. (15), (17), (18) with H = I: returns (x_hat, P, K).

    P = M - M (M + R)^-1 M (18), K = P R^-1 (17), x_hat = x_bar + K (z - x_bar) (15).
    """
    P = M - M @ np.linalg.solve(M + Rm, M)
    P = 0.5 * (P + P.T)
    K = P @ np.linalg.inv(Rm)
    return x_bar + K @ (z - x_bar), P, K


def kf_predict(x_hat: np.ndarray, P: np.ndarray, Phi: np.ndarray, u: np.ndarray, q: float):
    """Eqs. (16), (19): x_bar = u + Phi x_hat, M = Phi P Phi^T + diag(q, 0)."""
    M = Phi @ P @ Phi.T
    M[0, 0] += q
    return u + Phi @ x_hat, M


def ekf_model(speed: float, traction: float, brake: float, grade: float, theta: np.ndarray,
              dt: float, gamma: float = 0.0) -> tuple[float, float]:
    """Eq. (2) without noise for a moving car: (V[n+1], dV[n+1]/dV[n]), V >= 0."""
    k = G / 1000.0 / (1.0 + gamma) * dt
    v_next = speed + k * specific_net_force(traction, brake, speed, grade, theta)
    dv = 1.0 - k * (theta[2] + 2.0 * theta[3] * speed)
    return max(v_next, 0.0), dv


@dataclass
class FilterConfig:
    dt: float = 0.1             # sampling period [s]
    speed_std: float = 0.05     # measurement noise of V [m/s]
    position_std: float = 1.0   # measurement noise of X [m]
    position_std_rel: float = 0.0  # plus this share of the distance [-] (odometry drift, ETCS)
    gamma: float = 0.0          # rotating-mass factor assumed by the model [-]
    kind: int = 0               # 0 auto, 1 linearised (needs V_zad), 2 EKF
    length: float = 0.0         # car length for grade averaging [m]

    def position_noise_std(self, distance: float) -> float:
        """Std of the measured distance [m] at ``distance`` [m]: position_std + rel * |X|."""
        return self.position_std + self.position_std_rel * abs(distance)

    def validate(self, has_speed_profile: bool) -> None:
        if not (self.position_std_rel >= 0 and math.isfinite(self.position_std_rel)):
            raise ValueError(f"sensor.position_std_rel must be >= 0, got {self.position_std_rel}")
        if not (self.length >= 0 and math.isfinite(self.length)):
            raise ValueError(f"car.length must be >= 0, got {self.length}")
        for name in ("speed_std", "position_std"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"sensor.{name} must be > 0 for the filter, got {v}")
        if self.kind not in (0, LINEARISED, EKF, PAPER):
            raise ValueError(f"filter.kind must be 0 (auto), 1 (linearised), 2 (EKF) or 3 "
                             f"(paper verbatim), got {self.kind}")
        if self.kind in (LINEARISED, PAPER) and not has_speed_profile:
            raise ValueError(f"filter.kind = {self.kind} (linearised around V_zad, eq. (13)) "
                             f"needs track.speed_profile")


class MotionFilter:
    """Sample-by-sample filter of (V, X); restarts exactly at a station (P~[0] = 0).

    Call ``update`` with each measurement and ``predict`` with the forces applied until the
    next one. ``speed``/``position`` and their stds are the posterior after ``update``;
    ``predicted_speed``/``predicted_position`` the one-step prediction after ``predict``.
    """

    def __init__(self, cfg: FilterConfig, grade_profile: GradeProfile,
                 speed_profile: SpeedProfile | None):
        cfg.validate(speed_profile is not None)
        self.cfg = cfg
        self.grade_profile = grade_profile
        self.speed_profile = speed_profile
        self.kind = cfg.kind or (LINEARISED if speed_profile is not None else EKF)
        self.Rm = np.diag([cfg.speed_std ** 2, cfg.position_std ** 2])
        self.restart()

    def start_from_measurement(self, speed_meas: float, position_meas: float) -> None:
        """A run that does not start at a station: state = first measurement, P = its noise."""
        self.restart()
        vzad = self._vzad(position_meas) if self.kind in (LINEARISED, PAPER) else 0.0
        self.vzad_hat = self.vzad_bar = vzad
        self.x_hat = np.array([max(speed_meas, 0.0) - vzad, position_meas])
        self.P = np.diag([self.cfg.speed_std ** 2, self.cfg.position_noise_std(position_meas) ** 2])

    def restart(self) -> None:
        """The car stands at the station: V = 0, X = 0 known exactly (P~[0] = 0)."""
        self.x_bar = np.zeros(2)
        self.M = np.zeros((2, 2))
        self.x_hat = np.zeros(2)
        self.P = np.zeros((2, 2))
        # V_zad at the posterior's / the prediction's instant [m/s]; 0 for the EKF (absolute speed)
        self.vzad_hat = self.vzad_bar = self._vzad(0.0) if self.kind in (LINEARISED, PAPER) else 0.0

    def _vzad(self, x: float) -> float:
        return self.speed_profile.at(x) if self.speed_profile is not None else 0.0

    def update(self, speed_meas: float, position_meas: float) -> None:
        """Eqs. (15), (17), (18) with z = (V_meas - V_zad, X_meas) [m/s, m]."""
        vzad = self.vzad_bar if self.kind in (LINEARISED, PAPER) else 0.0
        z = np.array([speed_meas - vzad, position_meas])
        if self.cfg.position_std_rel:
            self.Rm[1, 1] = self.cfg.position_noise_std(position_meas) ** 2
        self.x_hat, self.P, _ = kf_update(self.x_bar, self.M, z, self.Rm)
        if self.x_hat[0] + vzad < 0.0:            # a car never moves backwards
            self.x_hat[0] = -vzad
        self.vzad_hat = vzad

    def predict(self, traction: float, brake: float, theta: np.ndarray, q: float, dt: float) -> None:
        """Eqs. (16), (19) (or the EKF's) over dt [s] with forces [N] held, process noise q [(m/s)^2]."""
        speed_hat = self.speed
        x_pos = float(self.x_hat[1])
        grade = self.grade_profile.average(x_pos, self.cfg.length)
        if self.kind in (LINEARISED, PAPER):
            vzad = self.vzad_hat
            vzad_next = self._vzad(x_pos + speed_hat * dt)
            a, c, C = linearised_model(vzad, vzad_next, traction, brake, grade, theta, dt, self.cfg.gamma)
            self.vzad_bar = vzad_next
            if self.kind == PAPER:                          # eqs. (16), (19) verbatim
                Phi = np.array([[a, 0.0], [dt, 1.0]])
                self.x_bar, self.M = kf_predict(self.x_hat, self.P, Phi, np.array([c, C]), q)
                if self.x_bar[0] + vzad_next < 0.0:
                    self.x_bar[0] = -vzad_next
                return
            dv, v_next_minus_dv_v = a, c + vzad_next - a * vzad     # V' = c + V_zad' + a (V - V_zad)
        else:
            v_next, dv = ekf_model(speed_hat, traction, brake, grade, theta, dt, self.cfg.gamma)
            v_next_minus_dv_v = v_next - dv * speed_hat
        # speed row in absolute terms: V' = v0 + dv V. Distance by the trapezoid rule,
        # X' = X + dt (V + V') / 2, and the process noise as white acceleration noise over the
        # step, which moves the distance too: the paper's X' = X + V dt with Q = diag(sigma^2, 0)
        # lags under acceleration and makes the distance's covariance over-confident.
        vzad_hat = self.vzad_hat if self.kind == LINEARISED else 0.0
        vzad_bar = self.vzad_bar if self.kind == LINEARISED else 0.0
        v_hat = float(self.x_hat[0]) + vzad_hat
        v_pred = max(v_next_minus_dv_v + dv * v_hat, 0.0)
        Phi = np.array([[dv, 0.0], [0.5 * dt * (1.0 + dv), 1.0]])
        self.x_bar = np.array([v_pred - vzad_bar, float(self.x_hat[1]) + 0.5 * dt * (v_hat + v_pred)])
        Q = q * np.array([[1.0, 0.5 * dt], [0.5 * dt, dt * dt / 3.0]])
        self.M = Phi @ self.P @ Phi.T + Q

    @property
    def speed(self) -> float:
        """Filtered speed [m/s] at the last measurement."""
        return max(float(self.x_hat[0]) + self.vzad_hat, 0.0)

    @property
    def position(self) -> float:
        """Filtered distance [m] at the last measurement."""
        return float(self.x_hat[1])

    @property
    def speed_std(self) -> float:
        """Std of the filtered speed [m/s]."""
        return math.sqrt(max(self.P[0, 0], 0.0))

    @property
    def position_std(self) -> float:
        """Std of the filtered distance [m]."""
        return math.sqrt(max(self.P[1, 1], 0.0))

    @property
    def predicted_speed(self) -> float:
        """One-step predicted speed [m/s]."""
        return max(float(self.x_bar[0]) + self.vzad_bar, 0.0)

    @property
    def predicted_position(self) -> float:
        """One-step predicted distance [m]."""
        return float(self.x_bar[1])

    @property
    def predicted_speed_std(self) -> float:
        return math.sqrt(max(self.M[0, 0], 0.0))

    @property
    def predicted_position_std(self) -> float:
        return math.sqrt(max(self.M[1, 1], 0.0))
