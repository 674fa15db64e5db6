"""Kalman filters of speed and distance: the paper's linearised filter (13)-(19) and an EKF.

State (x, X): x = V - V_zad (speed deviation [m/s]) for the linearised filter, x = V for the
EKF; X distance from the previous station [m]. Measurements z = (V_meas - V_zad, X_meas)
(eq. (14), H = I), noise covariance Rm = diag(sigma_V^2, sigma_X^2).

The algebra -- the model (2), (13), the update (15), (17), (18), the prediction (16), (19) --
is pure functions in models/filtering/kalman.py on small tuples; ``MotionFilter`` runs them sample by
sample and keeps V_zad and the innovation gate. What differs between the kinds (filter.kind) is
one small class per kind (models/filtering/kinds.py), chosen once when the filter is built.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models import fpmath
from models.filtering.kinds import EKF, LINEARISED, PAPER, SINGER, filter_kind, kind_class  # noqa: F401
from models.fpmath import square
from models.plant.track import GradeProfile, SpeedProfile


@dataclass
class FilterConfig:
    dt: float = 0.1             # sampling period [s]
    speed_std: float = 0.05     # measurement noise of V [m/s]
    position_std: float = 1.0   # measurement noise of X [m]
    position_std_rel: float = 0.0  # plus this share of the distance [-] (odometry drift, ETCS)
    # Singer filter (Boynik et al.): acceleration correlation time and its mixed distribution
    singer_tau: float = 10.0          # [s]
    singer_p0: float = 0.3            # probability of zero acceleration [-]
    singer_p_plus: float = 0.1        # probability of the maximum acceleration [-]
    singer_p_minus: float = 0.1       # probability of the maximum deceleration [-]
    singer_w_max_plus: float = 1.3    # maximum acceleration [m/s^2]
    singer_w_max_minus: float = -1.5  # maximum deceleration, negative [m/s^2]
    gamma: float = 0.0          # rotating-mass factor assumed by the model [-]
    kind: int = 0               # 0 auto, 1 linearised (needs V_zad), 2 EKF, 3 paper, 4 Singer
    length: float = 0.0         # car length for grade averaging [m]
    speed_std_rel: float = 0.0  # plus this share of the speed [-] (Meleshin 2011: "within 2 %")

    def singer_params(self):
        """SingerParams from the filter.singer_* settings (ValueError names the bad one)."""
        from models.filtering.singer import SingerParams
        if not (self.singer_tau > 0 and math.isfinite(self.singer_tau)):
            raise ValueError(f"filter.singer_tau must be > 0, got {self.singer_tau}")
        try:
            return SingerParams.from_mixture(self.singer_tau, self.singer_p0, self.singer_p_plus,
                                             self.singer_p_minus, self.singer_w_max_plus,
                                             self.singer_w_max_minus)
        except ValueError as e:
            raise ValueError(f"filter.singer_*: {e}") from None

    def position_noise_std(self, distance: float) -> float:
        """Std of the measured distance [m] at ``distance`` [m]: position_std + rel * |X|."""
        return self.position_std + self.position_std_rel * abs(distance)

    def speed_noise_std(self, speed: float) -> float:
        """Std of the measured speed [m/s] at ``speed`` [m/s]: speed_std + rel * |V|."""
        return self.speed_std + self.speed_std_rel * abs(speed)

    def validate(self, has_speed_profile: bool) -> None:
        if not (self.position_std_rel >= 0 and math.isfinite(self.position_std_rel)):
            raise ValueError(f"sensor.position_std_rel must be >= 0, got {self.position_std_rel}")
        if not (self.speed_std_rel >= 0 and math.isfinite(self.speed_std_rel)):
            raise ValueError(f"sensor.speed_std_rel must be >= 0, got {self.speed_std_rel}")
        if not (self.length >= 0 and math.isfinite(self.length)):
            raise ValueError(f"car.length must be >= 0, got {self.length}")
        for name in ("speed_std", "position_std"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"sensor.{name} must be > 0 for the filter, got {v}")
        if self.kind != 0:                       # 0: auto, always possible
            kind_class(self.kind).check(self, has_speed_profile)


class MotionFilter:
    """Sample-by-sample filter of (V, X); restarts exactly at a station (P~[0] = 0).

    Call ``update`` with each measurement and ``predict`` with the forces applied until the
    next one. ``speed``/``position`` and their stds are the posterior after ``update``;
    ``predicted_speed``/``predicted_position`` the one-step prediction after ``predict``.
    State (models/filtering/kalman.py's shapes): the prediction ``x_bar``, ``M`` and the posterior
    ``x_hat``, ``P``, x = (speed part, distance) and covariances ((c00, c01), (c01, c11));
    ``R`` = (sigma_V^2, sigma_X^2), the diagonal of R (with sensor.speed_std_rel or
    sensor.position_std_rel > 0 the gate and the updates take ``speed_variance`` /
    ``position_variance`` at the measurement instead); ``vzad_hat``, ``vzad_bar`` V_zad at the
    posterior's and the prediction's instant (0 for the kinds on absolute speed). This class
    keeps the gate and the bookkeeping; the steps that differ between the kinds are
    ``algorithm``'s, the kind object of models/filtering/kinds.py (``kind`` is its number). Pass
    ``algorithm`` to run a kind object of your own instead of cfg.kind's.
    """

    def __init__(self, cfg: FilterConfig, grade_profile: GradeProfile,
                 speed_profile: SpeedProfile | None, algorithm=None):
        cfg.validate(speed_profile is not None)
        self.cfg = cfg
        self.grade_profile = grade_profile
        self.speed_profile = speed_profile
        self.algorithm = algorithm or filter_kind(cfg, grade_profile, speed_profile)
        self.kind = self.algorithm.kind
        self.R = (square(cfg.speed_std), square(cfg.position_std))
        self.rejected = 0             # measurements (speeds and distances) the gate refused
        self.speed_run = self.position_run = 0   # ... in a row, up to now
        self.reacquired = 0           # restarts from the measurements after REACQUIRE of them
        self.speed_fit = True         # the last gated speed may be identified (FIT_SIGMAS)
        self._use_speed = self._use_position = True   # what the next update takes (gate)
        self._reacquire = 0           # REACQUIRE_BOTH / _DISTANCE: the next update restarts
        self.restart()

    @property
    def Rm(self) -> np.ndarray:
        return np.diag(self.R)

    def start_from_measurement(self, speed_meas: float, position_meas: float) -> None:
        """A run that does not start at a station: state = first measurement, P = its noise."""
        self.restart()
        self.algorithm.start(self, speed_meas, position_meas)

    def restart(self) -> None:
        """The car stands at the station: V = 0, X = 0 known exactly (P~[0] = 0)."""
        self.x_bar = self.x_hat = (0.0, 0.0)
        self.M = self.P = ((0.0, 0.0), (0.0, 0.0))
        self.speed_run = self.position_run = 0
        self._use_speed = self._use_position = True
        self._reacquire = 0
        self.vzad_hat = self.vzad_bar = self.algorithm.vzad(0.0)
        self.algorithm.restart(self)

    # Innovation gate, per measurement. The speed (the distance) is an outlier -- a spike, a
    # dropout, a stuck sensor -- when its innovation nu = z - x_bar exceeds GATE_SIGMAS standard
    # deviations of nu (sqrt of M + R's diagonal): a good one does so once in 5e8 samples (two-
    # sided Gaussian tail at 6 sigma, 2e-9; the library's filters have NEES up to ~2: there once
    # in ~1e5). A refused speed leaves the distance to update the filter alone and vice versa
    # (a speed dropout no longer drags the filter). The identification is pickier
    # (speed_fit: within FIT_SIGMAS, 7e-6 of good samples dropped): a stuck reading under full
    # traction drifts off the prediction slowly, and its first zero-acceleration pairs alone ran
    # the mass up by 40 %. After REACQUIRE refusals of the distance in a row it has jumped, or the
    # filter lost the car (a model far off): the distance restarts from its measurement, the whole
    # filter when the speed is refused too. A refused speed alone does not restart anything: the
    # distance taken meanwhile vouches for the filter (a stuck speed sensor stays refused).
    GATE_SIGMAS = 6.0
    FIT_SIGMAS = 4.5
    REACQUIRE = 50                                     # samples (5 s at 0.1 s)
    REACQUIRE_BOTH, REACQUIRE_DISTANCE = 1, 2          # what the next update restarts from

    def position_variance(self, position_meas: float) -> float:
        """Variance of the measured distance [m^2] at ``position_meas`` [m]."""
        return square(self.cfg.position_noise_std(position_meas)) if self.cfg.position_std_rel else self.R[1]

    def speed_variance(self, speed_meas: float) -> float:
        """Variance of the measured speed [(m/s)^2] at ``speed_meas`` [m/s] (R_v; sensor.speed_std_rel)."""
        return square(self.cfg.speed_noise_std(speed_meas)) if self.cfg.speed_std_rel else self.R[0]

    def gate(self, speed_meas: float, position_meas: float) -> tuple[bool, bool]:
        """(use the speed, use the distance) [m/s, m] at this sample, against the prediction;
        counts refusals in ``rejected``, sets ``speed_fit`` (the speed may be identified) and
        what the next ``update`` takes. The REACQUIRE-th refusal in a row of the distance is
        taken instead, and the next ``update`` restarts the distance from it -- the whole filter
        when the speed is refused too (counted in ``reacquired``)."""
        vzad = self.vzad_bar
        r1 = self.position_variance(position_meas)
        r0 = self.speed_variance(speed_meas)
        (xb0, xb1), ((m00, _), (_, m11)) = self.x_bar, self.M
        e0, e1 = speed_meas - vzad - xb0, position_meas - xb1
        s00, s11 = m00 + r0, m11 + r1
        g2 = self.GATE_SIGMAS * self.GATE_SIGMAS
        use_v, use_x = e0 * e0 <= g2 * s00, e1 * e1 <= g2 * s11     # False for NaN
        self.speed_fit = use_v and e0 * e0 <= self.FIT_SIGMAS * self.FIT_SIGMAS * s00
        self.speed_run = 0 if use_v else self.speed_run + 1
        self.position_run = 0 if use_x else self.position_run + 1
        if self.position_run >= self.REACQUIRE:
            # the distance has jumped (or the filter lost the car): take it again; the speed too
            # if it is refused now. A refused speed alone never triggers this: while the distance
            # is taken, it keeps the filter on the car, and the speed sensor is the one at fault.
            self.position_run = 0
            if use_v:
                self._reacquire = self.REACQUIRE_DISTANCE
            else:
                self.speed_run = 0
                self._reacquire = self.REACQUIRE_BOTH
                self.speed_fit = False
            return True, True
        self.rejected += (not use_v) + (not use_x)
        self._use_speed, self._use_position = use_v, use_x
        return use_v, use_x

    def hold(self) -> None:
        """No measurement used at this sample: the posterior is the prediction."""
        self.algorithm.hold(self)

    def update(self, speed_meas: float, position_meas: float) -> None:
        """Eqs. (15), (17), (18) with z = (V_meas - V_zad, X_meas) [m/s, m], H = I (or the Singer
        kind's update): the measurements ``gate`` let through (both, without a gate)."""
        if self._reacquire:
            what, self._reacquire = self._reacquire, 0
            self.reacquired += 1
            if what == self.REACQUIRE_BOTH:
                self.start_from_measurement(speed_meas, position_meas)
            else:
                self.algorithm.reacquire_distance(self, speed_meas, position_meas)
            return
        use_v, use_x = self._use_speed, self._use_position
        self._use_speed = self._use_position = True
        self.algorithm.update(self, speed_meas, position_meas, use_v, use_x)

    def update_speed(self, speed_meas: float, variance: float) -> None:
        """An extra speed-only measurement [m/s] of the current instant (e.g. two track
        sensors, Boynik et al.), noise variance [(m/s)^2]: H = [1 0]."""
        self.algorithm.update_speed(self, speed_meas, variance)

    @property
    def acceleration(self) -> float | None:
        """The filter's own acceleration estimate [m/s^2] (Singer only), else None."""
        return self.algorithm.acceleration()

    def predict(self, traction: float, brake: float, theta, q: float, dt: float) -> None:
        """Eqs. (16), (19) (or the kind's own) over dt [s] with forces [N] held, process noise q [(m/s)^2]."""
        self.algorithm.predict(self, traction, brake, theta, q, dt)

    def cap_predicted_speed(self, v_max: float, dt: float) -> None:
        """After ``predict`` over dt [s]: the predicted speed at most v_max [m/s] (>= 0), the
        state as a brake holding the car back would leave it (the kind's cap_predicted_speed;
        OnlineEstimator.propagate's virtual holding brake)."""
        self.algorithm.cap_predicted_speed(self, v_max, dt)

    @property
    def speed(self) -> float:
        """Filtered speed [m/s] at the last measurement."""
        v = self.x_hat[0] + self.vzad_hat
        return v if v > 0.0 else 0.0

    @property
    def position(self) -> float:
        """Filtered distance [m] at the last measurement."""
        return self.x_hat[1]

    @property
    def speed_std(self) -> float:
        """Std of the filtered speed [m/s]."""
        p00 = self.P[0][0]
        return math.sqrt(p00) if p00 > 0.0 else 0.0

    @property
    def position_std(self) -> float:
        """Std of the filtered distance [m]."""
        p11 = self.P[1][1]
        return math.sqrt(p11) if p11 > 0.0 else 0.0

    @property
    def predicted_speed(self) -> float:
        """One-step predicted speed [m/s]."""
        v = self.x_bar[0] + self.vzad_bar
        return v if v > 0.0 else 0.0

    @property
    def predicted_position(self) -> float:
        """One-step predicted distance [m]."""
        return self.x_bar[1]

    @property
    def predicted_speed_std(self) -> float:
        m00 = self.M[0][0]
        return math.sqrt(m00) if m00 > 0.0 else 0.0

    @property
    def predicted_position_std(self) -> float:
        m11 = self.M[1][1]
        return math.sqrt(m11) if m11 > 0.0 else 0.0


class ProcessNoiseBank:
    """sigma^2, the process-noise variance per sample [(m/s)^2], from the innovation likelihood of
    a bank of scalar speed filters (est.sigma2_method = 1): multiple-model adaptive estimation
    (D. T. Magill, "Optimal adaptive estimation of sampled stochastic processes", IEEE Trans.
    Automatic Control 10(4), 1965), one filter per candidate q_j on a log grid.

    Each member predicts with the learning filter's own speed increment, adds q_j and the
    parameter-uncertainty term the learning filter adds, and takes the measured speed (variance
    R [(m/s)^2]); its innovations' log-likelihood accumulates while the car moves. The estimate
    is the posterior's geometric mean over the grid (prior: log-normal, ``prior_decades`` wide,
    centred on q0 = est.sigma2_initial). Why: the LS's LAG sums give sigma^2 as a small
    difference of two noisy sums (studies/filter_gap.py: 0.00-1.75x the truth at the end of the
    library's runs); the likelihood uses the innovations' whole correlation structure.
    """

    # A member whose posterior weight is below e^-45 (2.9e-20) of the best's is left out of the
    # mean: its term cannot move a sum of negative log_q's whose largest is 1 (< 1e-18 against a
    # half-ulp of >= 4e-16), and its exp was ~8 % of a native step with the bank converged.
    NEGLIGIBLE = -45.0

    def __init__(self, q0: float, R: float, decades=(-2.0, 1.0), n: int = 13, prior_decades: float = 1.0,
                 variance_at=None):
        if not (q0 > 0 and math.isfinite(q0) and R > 0 and math.isfinite(R)):
            raise ValueError(f"est.sigma2_method 1 (the likelihood bank) needs est.sigma2_initial > 0 "
                             f"and a speed measurement variance > 0 (sensor.speed_std), got "
                             f"est.sigma2_initial = {q0}, sensor.speed_std^2 = {R}")
        self.variance_at = variance_at   # z [m/s] -> R at that measurement (sensor.speed_std_rel)
        # scalar loops in a fixed order with models.fpmath: models/core/estimator.c repeats them
        # bit for bit (numpy's exp/log/linspace/sum are neither CPU-independent nor C's order)
        ln10, log_q0 = fpmath.log(10.0), fpmath.log(q0)
        lo, hi = decades
        self.log_q = [log_q0 + ln10 * (lo + (hi - lo) * j / (n - 1)) for j in range(n)]
        self.q = [fpmath.exp(lq) for lq in self.log_q]
        width = prior_decades * ln10
        self.log_prior = [-0.5 * square((lq - log_q0) / width) for lq in self.log_q]
        self.log_lik = [0.0] * n
        self.R = R
        self.x = None                 # members' speeds [m/s]; None while the car stands
        self.P = [0.0] * n
        self._estimate = q0

    def predict(self, dv: float, q_param: float) -> None:
        """Speed increment dv [m/s] of the learning filter's prediction, its parameter term
        q_param [(m/s)^2]."""
        if self.x is not None:
            for j in range(len(self.q)):
                self.x[j] = self.x[j] + dv
                self.P[j] = self.P[j] + self.q[j] + q_param

    def update(self, z: float) -> None:
        """A measured speed z [m/s] of a moving car (the first one starts the members)."""
        R = self.R if self.variance_at is None else self.variance_at(z)
        n = len(self.q)
        if self.x is None:
            self.x, self.P = [z] * n, [R] * n
            return
        for j in range(n):
            S = self.P[j] + R
            nu = z - self.x[j]
            self.log_lik[j] += -0.5 * (fpmath.log(S) + nu * nu / S)
            K = self.P[j] / S
            self.x[j] = self.x[j] + K * nu
            self.P[j] = self.P[j] * (1.0 - K)
        w = [self.log_lik[j] + self.log_prior[j] for j in range(n)]
        top = max(w)
        num = den = 0.0
        for j in range(n):                 # the posterior's geometric mean over the grid
            if w[j] - top < self.NEGLIGIBLE:
                continue
            e = fpmath.exp(w[j] - top)
            num += e * self.log_q[j]
            den += e
        self._estimate = fpmath.exp(num / den)

    def stand(self) -> None:
        """The car stands: the members stop (the model (2) does not hold at rest)."""
        self.x = None

    def estimate(self) -> float:
        """sigma^2 [(m/s)^2]: q0 until the first moving pair."""
        return self._estimate
