"""Main-resistance identification during coasting with an extended Kalman filter (Meleshin 2011).

Meleshin (2011; docs/estimation.md) identifies the main resistance of the Rusich
train on coasting runs with an EKF whose state is [v, a + w_grade, b, c], w0 = a + b v + c v^2,
only the speed measured. The source works with v in km/h and forces in kgf/t; here everything
is SI as in the rest of ``models`` (docs/model.md, Units):

    state  x = (V, alpha, A1, A2)      [m/s, N/kN, N/kN/(m/s), N/kN/(m/s)^2]
    dV/dt  = -g/1000 / (1 + gamma) * ( alpha + A1 V + A2 V^2 + i_known )      [m/s^2]
    dalpha/dt = dA1/dt = dA2/dt = 0 (+ optional random walks)
    z      = V_meas = V + nu,   nu ~ N(0, speed_std^2)

Coefficients in Meleshin's units (a [kgf/t], b [kgf/t/(km/h)], c [kgf/t/(km/h)^2]) are converted
at the edge with ``models.units.resistance_kmh_to_si`` (1 kgf/t = 1 N/kN, docs/model.md, Units);
``to_kmh`` converts back.

The grade: Meleshin lumps the grade into the state's second component, alpha = a + w_grade,
because the grade of the line studied was not given to the filter (it then drifts with the grade and
needs a random walk, ``grade_known=False``). When the grade is known (our coasting logs: the
track profile is given), its specific resistance i [permille = N/kN] enters the prediction as
a known input and the state's second component is a itself: estimating a directly by
subtracting i (``grade_known=True``, the default). Either way A0 is reported as alpha (with an
unknown grade it is a + w_grade of the last stretch; subtract the grade there if known later).

Discretisation: the mean is propagated by one classical RK4 step over each interval (as
``models.plant.dynamics``), the covariance with the Jacobian of the step linearised at the interval's
midpoint speed (error O(dt^2 K A2) ~ 1e-7 relative at dt = 0.2 s); process noise is white
acceleration of density ``process_noise_psd`` [m^2/s^3] on V (the plant's
``car.process_noise_psd``), plus optional random-walk densities for alpha, A1, A2. EKF
equations: Jazwinski (1970), "Stochastic Processes and Filtering Theory", ch. 8; Simon (2006),
"Optimal State Estimation", sec. 13.2.

Functional core ``predict`` / ``update`` (pure functions on numpy arrays) and the thin stateful
wrapper ``CoastEKF``. No I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.fpmath import square
from models.plant.dynamics import acceleration_eq2, acceleration_gain, resistance_eq1
from models.units import resistance_kmh_to_si


def from_kmh(a: float, b: float, c: float) -> tuple[float, float, float]:
    """(a [kgf/t], b [kgf/t/(km/h)], c [kgf/t/(km/h)^2]) in Meleshin's (2011) units -> (A0 [N/kN],
    A1 [N/kN/(m/s)], A2 [N/kN/(m/s)^2]) (``models.units.resistance_kmh_to_si``)."""
    return resistance_kmh_to_si(a, b, c)


def to_kmh(A0: float, A1: float, A2: float) -> tuple[float, float, float]:
    """SI coefficients -> Meleshin's (2011) units (inverse of ``from_kmh``)."""
    return A0, A1 / 3.6, A2 / (3.6 * 3.6)


# ------------------------------------------------------------------------- functional core

def _accel(v: float, alpha: float, a1: float, a2: float, grade: float, k: float) -> float:
    """dV/dt [m/s^2] while coasting: eq. (2) with F = B = 0 and alpha in place of A0
    (V >= 0 clamped: a coasting car does not roll back); k = ``acceleration_gain(gamma)``."""
    vc = v if v > 0.0 else 0.0
    return acceleration_eq2(0.0, resistance_eq1(vc, alpha, a1, a2), grade, k)


def predict(x: np.ndarray, P: np.ndarray, dt: float, grade: float = 0.0,
            process_noise_psd: float = 0.0, param_psd=(0.0, 0.0, 0.0),
            gamma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction over dt [s] of the coasting model (module docstring).

    x = (V [m/s], alpha [N/kN], A1, A2) and its covariance P (4x4); grade [permille] known over
    the interval (0 when ``grade_known=False``: it is then inside alpha); process_noise_psd
    [m^2/s^3] white acceleration noise on V; param_psd densities of random walks on
    (alpha, A1, A2) [(unit)^2/s]. Returns (x_pred, P_pred).
    """
    k = acceleration_gain(gamma)
    v, alpha, a1, a2 = (float(c) for c in x)
    k1 = _accel(v, alpha, a1, a2, grade, k)
    k2 = _accel(v + 0.5 * dt * k1, alpha, a1, a2, grade, k)
    k3 = _accel(v + 0.5 * dt * k2, alpha, a1, a2, grade, k)
    k4 = _accel(v + dt * k3, alpha, a1, a2, grade, k)
    v_new = v + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    if v_new < 0.0:
        v_new = 0.0
    vm = max(0.5 * (v + v_new), 0.0)          # linearisation point: the interval's midpoint
    F = np.eye(4)
    F[0, 0] = 1.0 - k * dt * (a1 + 2.0 * a2 * vm)
    F[0, 1] = -k * dt
    F[0, 2] = -k * dt * vm
    F[0, 3] = -k * dt * vm * vm
    Q = np.zeros((4, 4))
    Q[0, 0] = process_noise_psd * dt
    Q[1, 1], Q[2, 2], Q[3, 3] = (float(s) * dt for s in param_psd)
    P_new = F @ P @ F.T + Q
    x_new = np.array([v_new, alpha, a1, a2])
    return x_new, 0.5 * (P_new + P_new.T)


def update(x: np.ndarray, P: np.ndarray, speed_meas: float, speed_std: float
           ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """EKF update with one speed measurement [m/s] of noise std speed_std [m/s] (H = e_V).

    Returns (x, P, innovation [m/s], innovation variance S [(m/s)^2]). Joseph form for P
    (stays symmetric positive definite with a tiny speed_std, e.g. noise-free data).
    """
    S = float(P[0, 0]) + speed_std * speed_std
    K = P[:, 0] / S
    nu = float(speed_meas - x[0])
    x_new = x + K * nu
    I_KH = np.eye(4)
    I_KH[:, 0] -= K
    P_new = I_KH @ P @ I_KH.T + speed_std * speed_std * np.outer(K, K)
    return x_new, 0.5 * (P_new + P_new.T), nu, S


# ------------------------------------------------------------------------- stateful wrapper

@dataclass
class CoastEKFConfig:
    """Settings (SI). Prior: the standard coefficients and their stds; noise levels."""
    A0: float = 1.0                    # prior a (or a + w_grade) [N/kN]
    A1: float = 0.03                   # prior b [N/kN/(m/s)]
    A2: float = 0.01                   # prior c [N/kN/(m/s)^2]
    A0_std: float = 1.0                # [N/kN]
    A1_std: float = 0.03               # [N/kN/(m/s)]
    A2_std: float = 0.01               # [N/kN/(m/s)^2]
    speed_std: float = 0.1 / 3.6       # speed measurement noise [m/s] (Meleshin 2011: 0.1 km/h)
    process_noise_psd: float = 1e-4    # white acceleration noise on V [m^2/s^3]
    param_psd: tuple = (0.0, 0.0, 0.0)  # random walks of (alpha, A1, A2) [(unit)^2/s]
    grade_known: bool = True           # known grade as input (alpha = a) or inside alpha
    gamma: float = 0.0                 # rotating-mass factor [-]
    speed_std_rel: float = 0.0         # plus this share of the speed [-] (sensor.speed_std_rel)

    def noise_std(self, speed_meas: float) -> float:
        """Std of a measured speed [m/s] at speed_meas [m/s]: speed_std + rel * |V_meas|."""
        return self.speed_std + self.speed_std_rel * abs(speed_meas) if self.speed_std_rel else self.speed_std

    def validate(self) -> None:
        for name in ("A0_std", "A1_std", "A2_std", "speed_std"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be > 0, got {v}")
        if not (self.speed_std_rel >= 0 and math.isfinite(self.speed_std_rel)):
            raise ValueError(f"speed_std_rel must be >= 0, got {self.speed_std_rel}")
        if not (self.process_noise_psd >= 0 and math.isfinite(self.process_noise_psd)):
            raise ValueError(f"process_noise_psd must be >= 0, got {self.process_noise_psd}")
        if len(self.param_psd) != 3 or any(not (s >= 0) for s in self.param_psd):
            raise ValueError(f"param_psd must be three values >= 0, got {self.param_psd}")
        if not (self.gamma >= 0):
            raise ValueError(f"gamma must be >= 0, got {self.gamma}")

    @classmethod
    def from_seed003(cls, a: float, b: float, c: float, a_std: float, b_std: float,
                     c_std: float, **kwargs) -> "CoastEKFConfig":
        """Prior in Meleshin's (2011) units (kgf/t, V in km/h), converted to SI at the edge."""
        A = resistance_kmh_to_si(a, b, c)
        S = resistance_kmh_to_si(a_std, b_std, c_std)
        return cls(A0=A[0], A1=A[1], A2=A[2], A0_std=S[0], A1_std=S[1], A2_std=S[2], **kwargs)


class CoastEKF:
    """Meleshin's (2011) coasting EKF, sample by sample (thin wrapper of ``predict`` / ``update``).

    ``start(V_meas)`` at the first coasting sample, then ``step(dt, V_meas, grade)`` per sample:
    prediction over dt [s] with the grade [permille] under the car during the interval (ignored
    when the grade is not known), then the update with the new measurement [m/s].
    """

    def __init__(self, cfg: CoastEKFConfig | None = None):
        self.cfg = cfg or CoastEKFConfig()
        self.cfg.validate()
        self.x: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.samples = 0
        self.nis_sum = 0.0           # sum of normalised innovations squared (~ samples if honest)

    def start(self, speed_meas: float) -> None:
        """First coasting sample: V from the measurement, the A's from the prior."""
        c = self.cfg
        self.x = np.array([speed_meas, c.A0, c.A1, c.A2], dtype=float)
        self.P = np.diag([square(c.noise_std(speed_meas)), square(c.A0_std), square(c.A1_std), square(c.A2_std)])
        self.samples = 1
        self.nis_sum = 0.0

    def carry_over(self, speed_meas: float) -> None:
        """Start a new coast keeping the A's and their covariance (the next coast of the same
        car): V restarts from the measurement, uncorrelated with the A's."""
        if self.x is None:
            self.start(speed_meas)
            return
        self.x[0] = speed_meas
        self.P[0, :] = 0.0
        self.P[:, 0] = 0.0
        self.P[0, 0] = square(self.cfg.noise_std(speed_meas))

    def step(self, dt: float, speed_meas: float, grade: float = 0.0) -> None:
        """Predict over dt [s] (grade [permille] held), update with speed_meas [m/s]."""
        if self.x is None:
            raise RuntimeError("CoastEKF.step before start")
        c = self.cfg
        g = grade if c.grade_known else 0.0
        self.x, self.P = predict(self.x, self.P, dt, g, c.process_noise_psd, c.param_psd, c.gamma)
        self.x, self.P, nu, S = update(self.x, self.P, speed_meas, c.noise_std(speed_meas))
        self.nis_sum += nu * nu / S
        self.samples += 1

    def run(self, time, speed, grade=None) -> "CoastEKF":
        """Filter a whole coasting log: time [s] (n,), measured speed [m/s] (n,), grade
        [permille] per interval (n-1,) or None (level). Starts from the first sample."""
        t = np.asarray(time, dtype=float)
        v = np.asarray(speed, dtype=float)
        gr = np.zeros(len(t) - 1) if grade is None else np.asarray(grade, dtype=float)
        self.start(float(v[0]))
        for j in range(len(t) - 1):
            self.step(float(t[j + 1] - t[j]), float(v[j + 1]), float(gr[j]))
        return self

    # ------------------------------------------------------------ outputs

    @property
    def speed(self) -> float:
        """Filtered speed [m/s]."""
        return float(self.x[0])

    @property
    def A(self) -> np.ndarray:
        """(A0, A1, A2) [N/kN, N/kN/(m/s), N/kN/(m/s)^2] (A0 = a + w_grade if the grade is not
        known)."""
        return self.x[1:].copy()

    @property
    def cov_A(self) -> np.ndarray:
        """Covariance of (A0, A1, A2) (3x3)."""
        return self.P[1:, 1:].copy()

    def A_kmh(self) -> tuple[float, float, float]:
        """(a [kgf/t], b [kgf/t/(km/h)], c [kgf/t/(km/h)^2]), Meleshin's (2011) units."""
        return to_kmh(*self.A)

    def w0(self, v) -> np.ndarray:
        """Identified w0(V) [N/kN] at speeds v [m/s]."""
        return resistance_eq1(np.asarray(v, dtype=float), *self.A)

    def w0_std(self, v) -> np.ndarray:
        """Std of w0(V) [N/kN] at speeds v [m/s]."""
        v = np.atleast_1d(np.asarray(v, dtype=float))
        phi = np.column_stack([np.ones_like(v), v, v * v])
        return np.sqrt(np.einsum("ij,jk,ik->i", phi, self.cov_A, phi))

    def nis(self) -> float:
        """Mean normalised innovation squared [-]: ~1 when the noise levels are right."""
        return self.nis_sum / max(self.samples - 1, 1)
