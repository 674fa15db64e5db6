"""The filter kinds (``filter.kind``): one small class per kind, chosen once by ``filter_kind``.

``MotionFilter`` (models/filtering/motion_filter.py) keeps what every kind shares -- the prediction x_bar, M and
the posterior x_hat, P of (speed part, distance), the reference speed V_zad, the innovation gate
-- and hands the kind-specific steps to its kind object, through these hooks (f the filter):

    vzad(x)                               V_zad [m/s] at distance x [m] (0: absolute speed)
    restart(f)                            the car stands at the station (after f's own reset)
    start(f, speed, position)             state = the measurements, P = their noise
    hold(f)                               no measurement taken: the posterior is the prediction
    update(f, speed, position, use_v, use_x)   the measurements the gate let through
    reacquire_distance(f, speed, position)     the distance restarts from its measurement
    update_speed(f, speed, variance)      an extra speed of the current instant (track sensors)
    acceleration()                        the kind's own acceleration estimate, or None
    predict(f, traction, brake, theta, q, dt)  eqs. (16), (19) or the kind's own
    cap_predicted_speed(f, v_max, dt)     the prediction's speed at most v_max (a holding brake)

The three Kalman kinds run models/filtering/kalman.py's pure functions on f's state; the Singer kind runs
models/filtering/singer.py's filter on [w, v, r] and publishes its (v, r) block as f's state. A kind object
belongs to one filter (the Singer one holds that filter's 3-state). The arithmetic is written as
models/core/filter.c and singer.c repeat it: change them together.
"""
from __future__ import annotations

import math

from models.filtering import kalman as kalman2
from models.fpmath import square

LINEARISED, EKF, PAPER, SINGER = 1, 2, 3, 4
"""Values of ``filter.kind``: 0 = automatic (LINEARISED when a speed profile is given, else EKF);
LINEARISED = linearised around V_zad, eq. (13), with the trapezoid distance update and
white-acceleration process noise; EKF = eq. (2) relinearised at the estimate, same distance
update; PAPER = eqs. (13)-(19) verbatim (Euler distance, Q = diag(sigma^2, 0)), the baseline;
SINGER = Boynik et al.'s model-free filter on [acceleration, speed, distance]
(models/filtering/singer.py), which uses neither the forces nor the identified parameters."""


class EKFKind:
    """filter.kind 2: x = (V, X), eq. (2) linearised at the estimate (kalman2.ekf_model), the
    trapezoid distance update (kalman2.predict). Also the base of the other Kalman kinds: the
    updates (15), (17), (18) are the same for all three."""
    kind = EKF

    def __init__(self, cfg, grade_profile, speed_profile=None):
        self.cfg = cfg
        self.grade_profile = grade_profile
        self.speed_profile = speed_profile

    @staticmethod
    def check(cfg, has_speed_profile: bool) -> None:
        """Raise ValueError naming the setting this kind cannot run with."""

    def vzad(self, x: float) -> float:
        return 0.0

    def restart(self, f) -> None:
        pass

    def start(self, f, speed_meas: float, position_meas: float) -> None:
        vzad = self.vzad(position_meas)
        f.vzad_hat = f.vzad_bar = vzad
        f.x_hat = (max(speed_meas, 0.0) - vzad, position_meas)
        f.P = ((f.speed_variance(speed_meas), 0.0), (0.0, square(self.cfg.position_noise_std(position_meas))))

    def hold(self, f) -> None:
        f.x_hat, f.P = f.x_bar, f.M
        f.vzad_hat = f.vzad_bar

    def update(self, f, speed_meas: float, position_meas: float, use_v: bool, use_x: bool) -> None:
        """Eqs. (18), (17), (15), z = (V_meas - V_zad, X_meas), H = I; one row when only one
        measurement is taken, none (``hold``) when neither is."""
        if not (use_v and use_x):
            if use_v or use_x:
                self._update_one(f, speed_meas, position_meas, use_v)
            else:
                self.hold(f)
            return
        vzad = f.vzad_bar
        R = (f.speed_variance(speed_meas), f.position_variance(position_meas))
        x, f.P = kalman2.update(f.x_bar, f.M, (speed_meas - vzad, position_meas), R)
        f.x_hat = kalman2.forward(x, vzad)
        f.vzad_hat = vzad

    def _update_one(self, f, speed_meas: float, position_meas: float, speed: bool) -> None:
        """The update with the speed alone (H = [1 0]) or the distance alone (H = [0 1])."""
        vzad = f.vzad_bar
        if speed:
            x, f.P = kalman2.update_one(f.x_bar, f.M, speed_meas - vzad, f.speed_variance(speed_meas), 0)
        else:
            x, f.P = kalman2.update_one(f.x_bar, f.M, position_meas, f.position_variance(position_meas), 1)
        f.x_hat = kalman2.forward(x, vzad)
        f.vzad_hat = vzad

    def reacquire_distance(self, f, speed_meas: float, position_meas: float) -> None:
        """The update with the speed, then the distance restarted from its measurement
        (uncorrelated with the speed, its noise's variance; when that overflows, P[1][1] stays
        as models/core/filter.c leaves it)."""
        self._update_one(f, speed_meas, position_meas, True)
        f.x_hat = (f.x_hat[0], position_meas)
        (p00, _), (_, p11) = f.P
        f.P = ((p00, 0.0), (0.0, p11))
        f.P = ((p00, 0.0), (0.0, f.position_variance(position_meas)))

    def update_speed(self, f, speed_meas: float, variance: float) -> None:
        x, f.P = kalman2.update_one(f.x_hat, f.P, speed_meas - f.vzad_hat, variance, 0)
        f.x_hat = kalman2.forward(x, f.vzad_hat)

    def acceleration(self) -> float | None:
        return None

    def _vzad_hat(self, f) -> float:
        """V_zad [m/s] the prediction starts from (0: this kind runs on absolute speed)."""
        return 0.0

    def cap_predicted_speed(self, f, v_max: float, dt: float) -> None:
        """The prediction over dt [s] with its speed at most v_max [m/s] (>= 0): the speed row
        capped, the distance integrated with the capped speed by the trapezoid of
        kalman2.predict -- what an unknown brake holding the car back would leave. M is left
        as predicted: the cap moves the estimate towards the truth it bounds, so M stays a
        conservative error covariance (as the Singer kind's clip, singer._project)."""
        if not f.x_bar[0] + f.vzad_bar > v_max:
            return
        xh0, x_pos = f.x_hat
        v_hat = xh0 + self._vzad_hat(f)
        f.x_bar = (v_max - f.vzad_bar, x_pos + 0.5 * dt * (v_hat + v_max))

    def _grade(self, f) -> float:
        return self.grade_profile.average(f.x_hat[1], self.cfg.length)

    @staticmethod
    def _trapezoid(f, dv: float, v0: float, dt: float, q: float, vzad_hat: float, vzad_bar: float) -> None:
        """kalman2.predict on absolute speed V' = v0 + dv V, the trapezoid distance."""
        xh0, x_pos = f.x_hat
        (v_pred, x_next), f.M = kalman2.predict((xh0 + vzad_hat, x_pos), f.P, dv, v0, dt, q)
        f.x_bar = (v_pred - vzad_bar, x_next)

    def predict(self, f, traction: float, brake: float, theta, q: float, dt: float) -> None:
        speed_hat = f.speed
        grade = self._grade(f)
        v_next, dv = kalman2.ekf_model(speed_hat, traction, brake, grade, theta, dt, self.cfg.gamma)
        self._trapezoid(f, dv, v_next - dv * speed_hat, dt, q, 0.0, 0.0)


class LinearisedKind(EKFKind):
    """filter.kind 1: x = (V - V_zad, X), eq. (13) around the speed profile, the trapezoid
    distance update and white-acceleration process noise (kalman2.predict)."""
    kind = LINEARISED

    @staticmethod
    def check(cfg, has_speed_profile: bool) -> None:
        if not has_speed_profile:
            raise ValueError(f"filter.kind = {cfg.kind} (linearised around V_zad, eq. (13)) "
                             f"needs track.speed_profile")

    def vzad(self, x: float) -> float:
        return self.speed_profile.at(x)

    def _vzad_hat(self, f) -> float:
        return f.vzad_hat

    def _model(self, f, traction: float, brake: float, theta, dt: float):
        """(a, c, C) of eq. (13) from V_zad now to V_zad where the car will be, which becomes
        the prediction's V_zad."""
        speed_hat = f.speed
        grade = self._grade(f)
        vzad_next = self.vzad(f.x_hat[1] + speed_hat * dt)
        a, c, C = kalman2.linearised_model(f.vzad_hat, vzad_next, traction, brake, grade, theta, dt,
                                           self.cfg.gamma)
        f.vzad_bar = vzad_next
        return a, c, C

    def predict(self, f, traction: float, brake: float, theta, q: float, dt: float) -> None:
        a, c, C = self._model(f, traction, brake, theta, dt)
        # kalman2.predict works on absolute speed: V' = c + V_zad' + a (V - V_zad)
        self._trapezoid(f, a, c + f.vzad_bar - a * f.vzad_hat, dt, q, f.vzad_hat, f.vzad_bar)


class PaperKind(LinearisedKind):
    """filter.kind 3: eqs. (13)-(19) verbatim (Euler distance, Q = diag(sigma^2, 0)), the
    baseline (kalman2.predict_paper)."""
    kind = PAPER

    def predict(self, f, traction: float, brake: float, theta, q: float, dt: float) -> None:
        a, c, C = self._model(f, traction, brake, theta, dt)
        x, f.M = kalman2.predict_paper(f.x_hat, f.P, a, c, C, dt, q)
        f.x_bar = kalman2.forward(x, f.vzad_bar)

    def cap_predicted_speed(self, f, v_max: float, dt: float) -> None:
        """As EKFKind's, but the distance is Euler's X + V dt (eq. (16)), which the predicted
        speed does not enter: only the speed row is capped."""
        if f.x_bar[0] + f.vzad_bar > v_max:
            f.x_bar = (v_max - f.vzad_bar, f.x_bar[1])


class SingerKind:
    """filter.kind 4: Boynik et al.'s model-free filter on [w, v, r] (models/filtering/singer.py
    SingerFilter, held in ``singer``); after each step its (v, r) block is published as f's
    posterior (or prediction), so the gate and the outputs read it as any other kind's."""
    kind = SINGER

    def __init__(self, cfg, grade_profile=None, speed_profile=None):
        self.cfg = cfg
        self.params = cfg.singer_params()
        self.singer = None

    @staticmethod
    def check(cfg, has_speed_profile: bool) -> None:
        cfg.singer_params()           # validates the Singer settings

    def vzad(self, x: float) -> float:
        return 0.0

    def _publish(self, f, posterior: bool) -> None:
        """The Singer filter's (v, r) block into f's posterior (or prediction)."""
        x, P = self.singer._x, self.singer._P        # [w, v, r]; 3x3 row-major
        xy, C = (x[1], x[2]), ((P[4], P[5]), (P[5], P[8]))
        if posterior:
            f.x_hat, f.P = xy, C
        else:
            f.x_bar, f.M = xy, C

    def _restart(self, f, speed: float = 0.0, position: float = 0.0, p_v: float = 0.0,
                 p_x: float = 0.0) -> None:
        from models.filtering.singer import SingerFilter
        sp = self.params
        self.singer = SingerFilter(sp, x0=(sp.m_w, speed, position),
                                   P0=(square(sp.sigma_w), 0.0, 0.0, 0.0, p_v, 0.0, 0.0, 0.0, p_x))
        self._publish(f, posterior=True)
        self._publish(f, posterior=False)

    def restart(self, f) -> None:
        self._restart(f)

    def start(self, f, speed_meas: float, position_meas: float) -> None:
        self._restart(f, max(speed_meas, 0.0), position_meas, f.speed_variance(speed_meas),
                      square(self.cfg.position_noise_std(position_meas)))

    def hold(self, f) -> None:
        self._publish(f, posterior=True)

    def update(self, f, speed_meas: float, position_meas: float, use_v: bool, use_x: bool) -> None:
        s, cfg = self.singer, self.cfg
        # the speed's std at the measured speed (sensor.speed_std_rel); speed_std itself when
        # rel is 0, whatever the measurement (a NaN one too, as before rel existed)
        std_v = cfg.speed_noise_std(speed_meas) if cfg.speed_std_rel else cfg.speed_std
        if use_v and use_x:
            s.update_speed_distance(speed_meas, position_meas, std_v,
                                    cfg.position_noise_std(position_meas))
        elif use_v:
            s.update_speed(speed_meas, std_v)
        elif use_x:
            s.update_distance(position_meas, cfg.position_noise_std(position_meas))
        self._publish(f, posterior=True)

    def reacquire_distance(self, f, speed_meas: float, position_meas: float) -> None:
        f.start_from_measurement(speed_meas, position_meas)     # the whole filter restarts

    def update_speed(self, f, speed_meas: float, variance: float) -> None:
        self.singer.update_speed(speed_meas, math.sqrt(variance))
        self._publish(f, posterior=True)

    def acceleration(self) -> float:
        return self.singer.acceleration

    def predict(self, f, traction: float, brake: float, theta, q: float, dt: float) -> None:
        """Model-free: the forces, Theta and q are not used."""
        self.singer.predict(dt)
        self._publish(f, posterior=False)

    def cap_predicted_speed(self, f, v_max: float, dt: float) -> None:
        """The Singer state's speed v at most v_max [m/s], by the estimate projection of its own
        clip at 0 (singer._project): if v > v_max, x_i - (P[i, v] / P[v, v]) (v - v_max) for
        i = w, r when P[v, v] > 0, and v = v_max -- a brake held the car back, so the
        acceleration and the distance move with their correlation to v; P unchanged.
        models/core/filter.c repeats it."""
        s = self.singer
        x, P = s._x, s._P                        # [w, v, r]; 3x3 row-major
        if not x[1] > v_max:
            return
        excess = x[1] - v_max
        pvv = P[4]
        if pvv > 0.0:
            s._x = [x[0] - P[1] / pvv * excess, v_max, x[2] - P[7] / pvv * excess]
        else:
            s._x = [x[0], v_max, x[2]]
        self._publish(f, posterior=False)


KINDS = {LINEARISED: LinearisedKind, EKF: EKFKind, PAPER: PaperKind, SINGER: SingerKind}


def kind_class(kind: int) -> type:
    """The class of ``filter.kind`` (1-4); ValueError naming the values it may take."""
    try:
        return KINDS[kind]
    except (KeyError, TypeError):
        raise ValueError(f"filter.kind must be 0 (auto), 1 (linearised), 2 (EKF), 3 "
                         f"(paper verbatim) or 4 (Singer), got {kind}") from None


def filter_kind(cfg, grade_profile, speed_profile):
    """The kind object of ``cfg.kind`` for one filter; 0 (auto) is LINEARISED with a speed
    profile, else EKF."""
    kind = cfg.kind or (LINEARISED if speed_profile is not None else EKF)
    return kind_class(kind)(cfg, grade_profile, speed_profile)
