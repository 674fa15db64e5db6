"""Kalman filters of speed and distance: the paper's linearised filter (13)-(19) and an EKF.

State (x, X): x = V - V_zad (speed deviation [m/s]) for the linearised filter, x = V for the
EKF; X distance from the previous station [m]. Measurements z = (V_meas - V_zad, X_meas)
(eq. (14), H = I), noise covariance Rm = diag(sigma_V^2, sigma_X^2).

The algebra -- the model (2), (13), the update (15), (17), (18), the prediction (16), (19) --
is pure functions in models/kalman2.py on small tuples; ``MotionFilter`` runs them sample by
sample and keeps V_zad, the innovation gate and the Singer kind (models/singer.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kalman2
from .track import GradeProfile, SpeedProfile

LINEARISED, EKF, PAPER, SINGER = 1, 2, 3, 4
"""Values of ``filter.kind``: 0 = automatic (LINEARISED when a speed profile is given, else EKF);
LINEARISED = linearised around V_zad, eq. (13), with the trapezoid distance update and
white-acceleration process noise; EKF = eq. (2) relinearised at the estimate, same distance
update; PAPER = eqs. (13)-(19) verbatim (Euler distance, Q = diag(sigma^2, 0)), the baseline;
SINGER = seed 002's model-free filter on [acceleration, speed, distance] (models/singer.py),
which uses neither the forces nor the identified parameters."""


@dataclass
class FilterConfig:
    dt: float = 0.1             # sampling period [s]
    speed_std: float = 0.05     # measurement noise of V [m/s]
    position_std: float = 1.0   # measurement noise of X [m]
    position_std_rel: float = 0.0  # plus this share of the distance [-] (odometry drift, ETCS)
    # Singer filter (seed 002): acceleration correlation time and its mixed distribution
    singer_tau: float = 10.0          # [s]
    singer_p0: float = 0.3            # probability of zero acceleration [-]
    singer_p_plus: float = 0.1        # probability of the maximum acceleration [-]
    singer_p_minus: float = 0.1       # probability of the maximum deceleration [-]
    singer_w_max_plus: float = 1.3    # maximum acceleration [m/s^2]
    singer_w_max_minus: float = -1.5  # maximum deceleration, negative [m/s^2]
    gamma: float = 0.0          # rotating-mass factor assumed by the model [-]
    kind: int = 0               # 0 auto, 1 linearised (needs V_zad), 2 EKF
    length: float = 0.0         # car length for grade averaging [m]

    def singer_params(self):
        """SingerParams from the filter.singer_* settings (ValueError names the bad one)."""
        from .singer import SingerParams
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

    def validate(self, has_speed_profile: bool) -> None:
        if not (self.position_std_rel >= 0 and math.isfinite(self.position_std_rel)):
            raise ValueError(f"sensor.position_std_rel must be >= 0, got {self.position_std_rel}")
        if not (self.length >= 0 and math.isfinite(self.length)):
            raise ValueError(f"car.length must be >= 0, got {self.length}")
        for name in ("speed_std", "position_std"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"sensor.{name} must be > 0 for the filter, got {v}")
        if self.kind not in (0, LINEARISED, EKF, PAPER, SINGER):
            raise ValueError(f"filter.kind must be 0 (auto), 1 (linearised), 2 (EKF), 3 "
                             f"(paper verbatim) or 4 (Singer), got {self.kind}")
        if self.kind == SINGER:
            self.singer_params()      # validates the Singer settings
        if self.kind in (LINEARISED, PAPER) and not has_speed_profile:
            raise ValueError(f"filter.kind = {self.kind} (linearised around V_zad, eq. (13)) "
                             f"needs track.speed_profile")


class MotionFilter:
    """Sample-by-sample filter of (V, X); restarts exactly at a station (P~[0] = 0).

    Call ``update`` with each measurement and ``predict`` with the forces applied until the
    next one. ``speed``/``position`` and their stds are the posterior after ``update``;
    ``predicted_speed``/``predicted_position`` the one-step prediction after ``predict``.
    State (models/kalman2.py's shapes): the prediction ``x_bar``, ``M`` and the posterior
    ``x_hat``, ``P``, x = (speed part, distance) and covariances ((c00, c01), (c01, c11));
    ``R`` = (sigma_V^2, sigma_X^2), the diagonal of R. The algebra is kalman2's; this class
    keeps V_zad, the gate and the Singer kind.
    """

    def __init__(self, cfg: FilterConfig, grade_profile: GradeProfile,
                 speed_profile: SpeedProfile | None):
        cfg.validate(speed_profile is not None)
        self.cfg = cfg
        self.grade_profile = grade_profile
        self.speed_profile = speed_profile
        self.kind = cfg.kind or (LINEARISED if speed_profile is not None else EKF)
        self.R = (cfg.speed_std ** 2, cfg.position_std ** 2)
        self._singer_params = cfg.singer_params() if self.kind == SINGER else None
        self._singer = None
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

    def _singer_restart(self, speed: float = 0.0, position: float = 0.0, p_v: float = 0.0,
                        p_x: float = 0.0) -> None:
        from .singer import SingerFilter
        sp = self._singer_params
        self._singer = SingerFilter(sp, x0=(sp.m_w, speed, position),
                                    P0=(sp.sigma_w ** 2, 0.0, 0.0, 0.0, p_v, 0.0, 0.0, 0.0, p_x))
        self._singer_copy(posterior=True)
        self._singer_copy(posterior=False)

    def _singer_copy(self, posterior: bool) -> None:
        """The Singer filter's (v, r) block into the posterior (or the prediction)."""
        x, P = self._singer._x, self._singer._P        # [w, v, r]; 3x3 row-major
        xy, C = (x[1], x[2]), ((P[4], P[5]), (P[5], P[8]))
        if posterior:
            self.x_hat, self.P = xy, C
        else:
            self.x_bar, self.M = xy, C

    def start_from_measurement(self, speed_meas: float, position_meas: float) -> None:
        """A run that does not start at a station: state = first measurement, P = its noise."""
        self.restart()
        if self.kind == SINGER:
            self._singer_restart(max(speed_meas, 0.0), position_meas, self.cfg.speed_std ** 2,
                                 self.cfg.position_noise_std(position_meas) ** 2)
            return
        vzad = self._vzad(position_meas) if self.kind in (LINEARISED, PAPER) else 0.0
        self.vzad_hat = self.vzad_bar = vzad
        self.x_hat = (max(speed_meas, 0.0) - vzad, position_meas)
        self.P = ((self.cfg.speed_std ** 2, 0.0),
                  (0.0, self.cfg.position_noise_std(position_meas) ** 2))

    def restart(self) -> None:
        """The car stands at the station: V = 0, X = 0 known exactly (P~[0] = 0)."""
        self.x_bar = self.x_hat = (0.0, 0.0)
        self.M = self.P = ((0.0, 0.0), (0.0, 0.0))
        self.speed_run = self.position_run = 0
        self._use_speed = self._use_position = True
        self._reacquire = 0
        # V_zad at the posterior's / the prediction's instant [m/s]; 0 for the EKF (absolute speed)
        self.vzad_hat = self.vzad_bar = self._vzad(0.0) if self.kind in (LINEARISED, PAPER) else 0.0
        if self.kind == SINGER:
            self._singer_restart()

    def _vzad(self, x: float) -> float:
        return self.speed_profile.at(x) if self.speed_profile is not None else 0.0

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

    def _vzad_predicted(self) -> float:
        """V_zad at the prediction's instant [m/s]: 0 for the filters of absolute speed."""
        return self.vzad_bar if self.kind in (LINEARISED, PAPER) else 0.0

    def _position_variance(self, position_meas: float) -> float:
        """Variance of the measured distance [m^2] at ``position_meas`` [m]."""
        return self.cfg.position_noise_std(position_meas) ** 2 if self.cfg.position_std_rel else self.R[1]

    def gate(self, speed_meas: float, position_meas: float) -> tuple[bool, bool]:
        """(use the speed, use the distance) [m/s, m] at this sample, against the prediction;
        counts refusals in ``rejected``, sets ``speed_fit`` (the speed may be identified) and
        what the next ``update`` takes. The REACQUIRE-th refusal in a row of the distance is
        taken instead, and the next ``update`` restarts the distance from it -- the whole filter
        when the speed is refused too (counted in ``reacquired``)."""
        vzad = self._vzad_predicted()
        r1 = self._position_variance(position_meas)
        (xb0, xb1), ((m00, _), (_, m11)) = self.x_bar, self.M
        e0, e1 = speed_meas - vzad - xb0, position_meas - xb1
        s00, s11 = m00 + self.R[0], m11 + r1
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
        if self.kind == SINGER:
            self._singer_copy(posterior=True)
            return
        self.x_hat, self.P = self.x_bar, self.M
        self.vzad_hat = self._vzad_predicted()

    def _update_one(self, speed_meas: float, position_meas: float, speed: bool) -> None:
        """The update with the speed alone (H = [1 0]) or the distance alone (H = [0 1])."""
        vzad = self._vzad_predicted()
        if speed:
            x, self.P = kalman2.update_one(self.x_bar, self.M, speed_meas - vzad, self.R[0], 0)
        else:
            r1 = self._position_variance(position_meas)
            x, self.P = kalman2.update_one(self.x_bar, self.M, position_meas, r1, 1)
        self.x_hat = kalman2.forward(x, vzad)
        self.vzad_hat = vzad

    def update(self, speed_meas: float, position_meas: float) -> None:
        """Eqs. (15), (17), (18) with z = (V_meas - V_zad, X_meas) [m/s, m], H = I: the
        measurements ``gate`` let through (both, without a gate)."""
        if self._reacquire:
            what, self._reacquire = self._reacquire, 0
            self.reacquired += 1
            if what == self.REACQUIRE_BOTH or self.kind == SINGER:
                self.start_from_measurement(speed_meas, position_meas)
                return
            # the distance alone: the update with the speed, then the distance restarted from
            # its measurement (uncorrelated with the speed, its noise's variance; when that
            # overflows, P[1][1] stays as models/core/filter.c leaves it)
            self._update_one(speed_meas, position_meas, True)
            self.x_hat = (self.x_hat[0], position_meas)
            (p00, _), (_, p11) = self.P
            self.P = ((p00, 0.0), (0.0, p11))
            self.P = ((p00, 0.0), (0.0, self._position_variance(position_meas)))
            return
        use_v, use_x = self._use_speed, self._use_position
        if not (use_v and use_x):
            self._use_speed = self._use_position = True
            if self.kind == SINGER:
                if use_v:
                    self._singer.update_speed(speed_meas, self.cfg.speed_std)
                elif use_x:
                    self._singer.update_distance(position_meas,
                                                 self.cfg.position_noise_std(position_meas))
                self._singer_copy(posterior=True)
            elif use_v or use_x:
                self._update_one(speed_meas, position_meas, use_v)
            else:
                self.hold()
            return
        if self.kind == SINGER:
            self._singer.update_speed_distance(speed_meas, position_meas, self.cfg.speed_std,
                                               self.cfg.position_noise_std(position_meas))
            self._singer_copy(posterior=True)
            return
        vzad = self._vzad_predicted()
        R = (self.R[0], self._position_variance(position_meas))
        x, self.P = kalman2.update(self.x_bar, self.M, (speed_meas - vzad, position_meas), R)
        self.x_hat = kalman2.forward(x, vzad)
        self.vzad_hat = vzad

    def update_speed(self, speed_meas: float, variance: float) -> None:
        """An extra speed-only measurement [m/s] of the current instant (e.g. two track
        sensors, seed 002), noise variance [(m/s)^2]: H = [1 0]."""
        if self.kind == SINGER:
            self._singer.update_speed(speed_meas, math.sqrt(variance))
            self._singer_copy(posterior=True)
            return
        x, self.P = kalman2.update_one(self.x_hat, self.P, speed_meas - self.vzad_hat, variance, 0)
        self.x_hat = kalman2.forward(x, self.vzad_hat)

    @property
    def acceleration(self) -> float | None:
        """The filter's own acceleration estimate [m/s^2] (Singer only), else None."""
        return self._singer.acceleration if self.kind == SINGER else None

    def predict(self, traction: float, brake: float, theta, q: float, dt: float) -> None:
        """Eqs. (16), (19) (or the EKF's) over dt [s] with forces [N] held, process noise q [(m/s)^2]."""
        if self.kind == SINGER:                  # model-free: forces and Theta are not used
            self._singer.predict(dt)
            self._singer_copy(posterior=False)
            return
        speed_hat = self.speed
        xh0, x_pos = self.x_hat
        grade = self.grade_profile.average(x_pos, self.cfg.length)
        if self.kind in (LINEARISED, PAPER):
            vzad = self.vzad_hat
            vzad_next = self._vzad(x_pos + speed_hat * dt)
            a, c, C = kalman2.linearised_model(vzad, vzad_next, traction, brake, grade, theta, dt,
                                               self.cfg.gamma)
            self.vzad_bar = vzad_next
            if self.kind == PAPER:                          # eqs. (16), (19) verbatim
                x, self.M = kalman2.predict_paper(self.x_hat, self.P, a, c, C, dt, q)
                self.x_bar = kalman2.forward(x, vzad_next)
                return
            dv, v0 = a, c + vzad_next - a * vzad            # V' = c + V_zad' + a (V - V_zad)
        else:
            v_next, dv = kalman2.ekf_model(speed_hat, traction, brake, grade, theta, dt,
                                           self.cfg.gamma)
            v0 = v_next - dv * speed_hat
        # kalman2.predict works on absolute speed: V' = v0 + dv V, the trapezoid distance
        vzad_hat = self.vzad_hat if self.kind == LINEARISED else 0.0
        vzad_bar = self.vzad_bar if self.kind == LINEARISED else 0.0
        (v_pred, x_next), self.M = kalman2.predict((xh0 + vzad_hat, x_pos), self.P, dv, v0, dt, q)
        self.x_bar = (v_pred - vzad_bar, x_next)

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

    def __init__(self, q0: float, R: float, decades=(-2.0, 1.0), n: int = 13, prior_decades: float = 1.0):
        if not (q0 > 0 and math.isfinite(q0) and R > 0 and math.isfinite(R)):
            raise ValueError(f"ProcessNoiseBank needs q0 > 0 and R > 0, got {q0}, {R}")
        self.log_q = math.log(q0) + math.log(10.0) * np.linspace(*decades, n)
        self.q = np.exp(self.log_q)
        self.log_prior = -0.5 * ((self.log_q - math.log(q0)) / (prior_decades * math.log(10.0))) ** 2
        self.log_lik = np.zeros(n)
        self.R = R
        self.x = None                 # members' speeds [m/s]; None while the car stands
        self.P = np.zeros(n)
        self._estimate = q0

    def predict(self, dv: float, q_param: float) -> None:
        """Speed increment dv [m/s] of the learning filter's prediction, its parameter term
        q_param [(m/s)^2]."""
        if self.x is not None:
            self.x = self.x + dv
            self.P = self.P + self.q + q_param

    def update(self, z: float) -> None:
        """A measured speed z [m/s] of a moving car (the first one starts the members)."""
        if self.x is None:
            self.x, self.P = np.full(len(self.q), z), np.full(len(self.q), self.R)
            return
        S = self.P + self.R
        nu = z - self.x
        self.log_lik += -0.5 * (np.log(S) + nu * nu / S)
        K = self.P / S
        self.x = self.x + K * nu
        self.P = self.P * (1.0 - K)
        w = self.log_lik + self.log_prior
        w = np.exp(w - w.max())
        self._estimate = float(np.exp(np.sum(w * self.log_q) / w.sum()))

    def stand(self) -> None:
        """The car stands: the members stop (the model (2) does not hold at rest)."""
        self.x = None

    def estimate(self) -> float:
        """sigma^2 [(m/s)^2]: q0 until the first moving pair."""
        return self._estimate
