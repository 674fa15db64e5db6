"""The online estimator: station detection, identification and filter, driven by measurements.

Shared by both FMUs. Per sample n: ``measure(V_meas, X_meas)`` (identification of the pair
n-1, n and the filter's update), then ``propagate(F, B, dt)`` with the forces applied until
sample n+1 (the filter's prediction). Forces [N], speeds [m/s], distances [m], dt [s].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.filtering.motion_filter import FilterConfig, MotionFilter
from models.estimation.identification import IdentifierConfig, ParameterIdentifier, project_physical
from models.estimation.methods import identification_method, noise_model
from models.fpmath import square
from models.plant.track import GradeProfile, SpeedProfile
from models.units import G


@dataclass
class StationConfig:
    dwell: float = 20.0              # standstill at least this long is a station stop [s]
    speed_threshold: float = 0.0     # |V_meas| below it counts as still [m/s]; 0 = automatic
    position_threshold: float = 0.0  # X_meas below it counts as "restarted near 0" [m]; 0 = auto

    def validate(self) -> None:
        if not (self.dwell > 0 and math.isfinite(self.dwell)):
            raise ValueError(f"track.station_dwell must be > 0, got {self.dwell}")


class StationDetector:
    """Recognises standstill and station stops from measurements alone.

    A sample is *moving* when it and the two before it exceed the speed threshold (3 sigma of
    the sensor, one-sided: a car does not move backwards). With two in a row, a noise pair at
    standstill (p = 2e-6 per sample) ended one of the 300 standstills of a 100-seed Monte Carlo
    of station_day early, so that the stop was missed; three make it p = 2.5e-9. One slow sample
    while moving only pauses identification for three pairs, which would contain it. A
    standstill of at least ``dwell`` is a station stop; the stop is *confirmed* when the
    measured distance restarts near 0 (the contract of ``track.station_dwell``).
    """
    MOVING_RUN = 3

    def __init__(self, cfg: StationConfig, speed_std: float, position_std: float):
        cfg.validate()
        self.v_thr = cfg.speed_threshold or max(3.0 * speed_std, 0.05)
        self.x_thr = cfg.position_threshold or max(5.0 * position_std, 2.0)
        self.dwell = cfg.dwell
        self.still_time = 0.0
        self._fast_run = 0            # consecutive samples above the threshold
        self.moving = False
        self._restarted = False

    @property
    def standing(self) -> bool:
        """The last sample was at or below the speed threshold (so not ``moving`` either): the
        car stands, or has only just started (OnlineEstimator.propagate's holding brake)."""
        return self._fast_run == 0

    def observe(self, speed_meas: float, position_meas: float, dt: float) -> bool:
        """Take one sample; True when a station stop is confirmed at this sample."""
        self._fast_run = self._fast_run + 1 if speed_meas > self.v_thr else 0
        self.moving = self._fast_run >= self.MOVING_RUN
        if self.moving:
            self.still_time = 0.0
            self._restarted = False
            return False
        self.still_time += dt
        if (self.still_time >= self.dwell and not self._restarted
                and abs(position_meas) < self.x_thr):
            self._restarted = True
            return True
        return False


class OnlineEstimator:
    """Identification (eqs. (3)-(12)) feeding the filter ((13)-(19) or EKF), sample by sample.

    ``est.method`` (IdentifierConfig.method) chooses what identifies the resistance, an object
    of models/estimation/methods.py held in ``method``:
      0  PaperLS: the paper's recursive LS on differenced measured speed, eqs. (3)-(12), exactly;
      1  RefitLS: as 0, plus a filter-error refit of each finished run at the next station, the
         A's carried over between runs (models/estimation/output_error/);
      2  SlopeLS: the same LS fed with Sidorenko's (1997) speed and acceleration (a first-order fit over
         the last est.slope_window samples, docs/estimation.md): no errors-in-variables bias;
      3  CoastLS: LS for the mass, Meleshin's (2011) coasting EKF (state [V, A0, A1, A2], docs/estimation.md) for the A's, over every coasting interval (F = B = 0).

    Independent of the method: ``est.physical`` 1 reports (and predicts with) Theta-hat projected
    onto A0, A2 >= 0 (identification.project_physical); ``est.sigma2_method`` chooses the noise
    model held in ``noise`` (models/estimation/methods.py): 0 the LS's residuals, 1 the innovation
    likelihood of a bank of speed filters (filters.ProcessNoiseBank). ``method``, ``noise`` and
    the filter's kind object (``algorithm``, models/filtering/kinds.py) may be passed instead of
    the configured ones (an experiment, a study).
    """

    def __init__(self, id_cfg: IdentifierConfig, filt_cfg: FilterConfig, station_cfg: StationConfig,
                 grade_profile: GradeProfile, speed_profile: SpeedProfile | None,
                 method=None, noise=None, algorithm=None):
        self.ident = ParameterIdentifier(id_cfg)
        self.method = method or identification_method(id_cfg, filt_cfg)
        self.noise = noise or noise_model(id_cfg, filt_cfg)
        self.physical = bool(id_cfg.physical)
        self.filter = MotionFilter(filt_cfg, grade_profile, speed_profile, algorithm)
        self.station = StationDetector(station_cfg, filt_cfg.speed_std, filt_cfg.position_std)
        self.grade_profile = grade_profile
        self.length = filt_cfg.length
        self.gamma = id_cfg.gamma
        self.dt_nominal = id_cfg.dt
        self.station_stops = 0
        self.track_speeds = 0        # track-sensor speeds taken
        self._prev = None            # (V_meas, X_meas) of the previous sample
        self._pair_used = False      # the pair ending at the previous sample was identified
        self._forces = (0.0, 0.0)    # forces applied since the previous sample [N]
        self._dt = id_cfg.dt         # length of that interval [s]
        self._prev_fit = True        # the previous speed may be identified (MotionFilter.gate)
        self._net_force = 0.0        # low-passed F - B [N] (_excited)
        self._steady_speed = 0.0     # where the current steady state began [m/s], [N]
        self._steady_force = 0.0
        self._steady_time = 0.0      # how long it has lasted [s]
        self._force_band = self.STEADY_FORCE * id_cfg.mass_initial * G   # [N]
        self._mass_initial = id_cfg.mass_initial
        self._mass_low = id_cfg.mass_initial / self.MASS_RANGE    # [t] est.mass reported within
        self._mass_high = id_cfg.mass_initial * self.MASS_RANGE
        self._mass_std_initial = id_cfg.mass_std_initial
        self._last_good = None       # the last finite, plausible est.* values (finish_outputs)

    def measure(self, speed_meas: float, position_meas: float) -> None:
        """Sample n: identification on the pair (n-1, n), station logic, filter update.

        The filter's innovation gate (MotionFilter.gate) decides which of the two measurements
        the filter takes (a spike, a dropout is refused); a speed outside its tighter FIT_SIGMAS
        is not identified, in neither pair it belongs to. Station detection sees every
        measurement (it needs MOVING_RUN in a row)."""
        dt = self._dt
        moving_before = self.station.moving
        stop = self.station.observe(speed_meas, position_meas, dt)
        prev = self._prev
        if stop or prev is None:       # the station logic restarts the filter (restart_filter)
            use_v = use_x = fit = True
        else:
            use_v, use_x = self.filter.gate(speed_meas, position_meas)
            fit = self.filter.speed_fit
        self.method.record_sample(self, dt, speed_meas, position_meas, use_v, use_x)
        if prev is None and not (abs(speed_meas) < self.station.v_thr
                                 and abs(position_meas) < self.station.x_thr):
            # the run starts away from a station (a log cut mid-line, a car already moving)
            self.filter.start_from_measurement(speed_meas, position_meas)
            self._prev = (speed_meas, position_meas)
            return
        excited = self._excited(dt)
        used = (prev is not None and fit and self._prev_fit and excited
                and moving_before and self.station.moving
                and position_meas >= prev[1] - 10.0 * self.filter.cfg.position_std - 1.0)
        if used:
            traction, brake = self._forces
            grade = self.grade_profile.average(prev[1], self.length)
            self.method.identify(self, traction, brake, prev[0], speed_meas, grade, dt,
                                 self._pair_used)
        else:
            self.method.skip(self)
        self._pair_used = used
        # a refused distance would pick the next pair's grade: its prediction stands in
        self._prev = (speed_meas, position_meas if use_x else self.filter.predicted_position)
        self._prev_fit = fit
        self.noise.observe(self, speed_meas, use_v)
        if stop:
            self.station_stops += 1
            self.method.station_stop(self)
            self.ident.restart_mass()
            self.restart_filter(speed_meas, position_meas)
        else:
            self.filter.update(speed_meas, position_meas)

    # Information cap per operating point. At a steady speed and force every regressor phi is the
    # same vector: it tells nothing new about the mass, nor how the resistance splits into A0, A1,
    # A2, while the paper's rows carry the measured speed's error in phi and in y alike (errors in
    # variables, docs/model.md, Identification), a bias that then piles up along the unexcited directions with
    # every row. On a 2 h cruise at 60 km/h A0 walked from 0.89 to -10 N/kN and the mass crept
    # +1.1 % with est.mass_std at 0.12 t (seed 3; with wind changes the issue saw 34 -> 573 t).
    # So one steady state feeds at most STEADY_TIME of rows: the filter's speed within
    # STEADY_SPEED of where the state began and the smoothed net force F - B within STEADY_FORCE
    # N/kN of the configured weight. A grade change at cruise speed changes F - B and starts a
    # new state, so each grade still tells its part of the mass (steep_grades).
    STEADY_SPEED = 0.1      # [m/s]: with STEADY_TIME, below 0.005 m/s^2 (a coast on the level
                            # decelerates at >= ~0.008: A0 >= 0.8 N/kN)
    STEADY_FORCE = 2.0      # [N/kN] of est.mass_initial's weight
    STEADY_TIME = 20.0      # [s]
    FORCE_SMOOTHING = 10.0  # [s] time constant of the net force's low-pass: a cruise controller
                            # answering process noise moves F - B by ~120 N at 2 s, ~50 N at 10 s

    def _excited(self, dt: float) -> bool:
        """Track the steady state at this sample [dt s after the last]; False once the car has
        been in one for more than STEADY_TIME (its pairs are then not identified)."""
        net = self._forces[0] - self._forces[1]
        self._net_force += dt / (self.FORCE_SMOOTHING + dt) * (net - self._net_force)
        v = self.filter.speed
        if (not self.station.moving or abs(v - self._steady_speed) > self.STEADY_SPEED
                or abs(self._net_force - self._steady_force) > self._force_band):
            self._steady_speed = v
            self._steady_force = self._net_force
            self._steady_time = 0.0
            return True
        self._steady_time += dt
        return self._steady_time <= self.STEADY_TIME

    def restart_filter(self, speed_meas: float, position_meas: float) -> None:
        """Restart the filter at a confirmed station stop, then take this sample.

        A stop is confirmed at the first sample whose measured distance has restarted, i.e.
        once the car has left: at the previous sample it stood at the station, V = 0 and X = 0
        exactly. So the filter restarts there (P = 0), predicts over the last interval with
        its forces [N], and updates with this sample's measurement [m/s, m]. Restarting at
        this sample instead asserted V = 0 for a car already rolling at ~0.1 m/s, with P = 0:
        the oracle filter then lagged 0.1 m/s for a second after every departure.
        """
        self.filter.restart()
        traction, brake = self._forces
        self.filter.predict(traction, brake, self.model_theta(), self.process_noise(traction, brake, self._dt),
                            self._dt)
        self.filter.gate(speed_meas, position_meas)    # a spike at departure is refused too
        self.filter.update(speed_meas, position_meas)

    ACCEL_STD = 0.1   # [m/s^2] uncertainty of the acceleration used to carry a speed over its age

    def measure_track_speed(self, speed_meas: float, age: float, speed_std: float,
                            base: float = 0.0) -> None:
        """A track-sensor speed [m/s] stamped ``age`` [s] before the current sample, std [m/s].

        b / (t2 - t1) is the mean speed over the base [m], i.e. the speed at the middle of the
        passage, base / (2 v) before the stamp t2. It is carried to the current instant with
        the acceleration over the last interval (the filter's own for Singer, the identified
        model's otherwise) and its variance grows by (ACCEL_STD * age)^2.
        """
        if not (math.isfinite(speed_meas) and speed_meas > 0.0 and age >= 0.0):
            return
        age += 0.5 * base / speed_meas
        accel = self.filter.acceleration
        if accel is None:
            traction, brake = self._forces
            v = self.filter.speed
            th = self.ident.model_theta
            accel = G / 1000.0 / (1.0 + self.gamma) * (
                th[0] * (traction - brake) - th[1] - th[2] * v - th[3] * v * v
                - self.grade_profile.average(self.filter.position, self.length))
        var = square(speed_std) + square(self.ACCEL_STD * age)
        self.filter.update_speed(max(speed_meas + accel * age, 0.0), var)
        self.track_speeds += 1

    def sigma2(self) -> float:
        """Process-noise variance per sample [(m/s)^2] the filter uses and est.sigma2 reports:
        the noise model's (the LS's, eq. (12) on LAG sums, or the likelihood bank's)."""
        return self.noise.sigma2(self)

    def propagate(self, traction: float, brake: float, dt: float) -> None:
        """Forces [N] applied from this sample over the next dt [s]: the filter's prediction,
        held by a virtual holding brake while the car stands (``holding``)."""
        theta = self.model_theta()
        q = self.process_noise(traction, brake, dt)
        self.method.record_forces(traction, brake)
        before = self.filter.speed
        self.filter.predict(traction, brake, theta, q, dt)
        if self.holding(traction):
            self.filter.cap_predicted_speed(before, dt)
        self.noise.predicted(self, before, q, dt)
        self._forces = (traction, brake)
        self._dt = dt

    def holding(self, traction: float) -> bool:
        """True when the prediction over the next interval, with this traction [N], may not speed
        the car up: the car stands (StationDetector.standing: the last measured speed at or below
        the threshold) and no traction is applied (traction <= 0).

        A car standing at a platform is held by a brake. A recorded log may leave that brake out
        (issue 27: a 25-40 s dwell on -12..-27 permille with brake_force 0): eq. (2) then rolls
        the filter downhill at ~0.25 m/s^2, the measured 0 m/s soon falls outside the innovation
        gate (MotionFilter.gate) and filter.speed climbed to 2-3 m/s, filter.position ~13 m
        off, for the whole dwell. So while holding, an unknown brake holds the car: the predicted
        speed is at most the filtered speed before the prediction (the filter's kind caps it,
        MotionFilter.cap_predicted_speed). With the brake recorded, eq. (2) already predicts no
        speed-up at rest and nothing changes. Traction ends the hold at once (a departure is not
        delayed); a car released downhill without traction is followed from its first sample
        above the threshold on. The likelihood bank (est.sigma2_method 1) follows the filter
        only while the car moves (LikelihoodNoise.predicted): never a held prediction."""
        return self.station.standing and traction <= 0.0

    def theta(self) -> np.ndarray:
        """Theta reported (est.*): the running LS's, with the method's A's once it has any
        (RefitLS, CoastLS); with est.physical, projected onto A0, A2 >= 0
        (identification.project_physical)."""
        m = self.method
        th = m.with_resistance(self.ident.theta)
        if self.physical and (th[1] < 0.0 or th[3] < 0.0):
            th = project_physical(th, m.with_resistance_covariance(self.ident.covariance()))
        return th

    def model_theta(self) -> np.ndarray:
        """Theta the filter predicts with: as theta(), but before the first batch the running
        estimate instead of the configured values (ParameterIdentifier.model_theta), and as the
        method's filter_theta has it."""
        m = self.method
        th = m.with_resistance(self.ident.model_theta)
        if self.physical and (th[1] < 0.0 or th[3] < 0.0):
            th = project_physical(th, m.with_resistance_covariance(self.ident.model_covariance()))
        return m.filter_theta(self, th)

    def process_noise(self, traction: float, brake: float, dt: float) -> float:
        """Filter's process noise per step [(m/s)^2]: the noise model's, by default the
        identified sigma^2 plus parameter_noise."""
        return self.noise.process_noise(self, traction, brake, dt)

    def parameter_noise(self, traction: float, brake: float, dt: float) -> float:
        """The model's prediction error over dt [s] from an uncertain Theta [(m/s)^2]:
        k phi^T cov(Theta) phi k, k = g dt / 1000 / (1 + gamma); adding it to the process noise
        keeps the filter honest while Theta is learnt."""
        v = self.filter.speed
        k = G * dt / 1000.0 / (1.0 + self.gamma)
        phi = (traction - brake, -1.0, -v, -v * v)
        return k * k * self.method.variance_along(self, phi)

    def outputs(self, predicted: bool = False) -> dict[str, float]:
        """est.* and filter.* values: the filter's posterior at the last measurement, or with
        ``predicted`` its one-step prediction (the estimate for the next sample's instant)."""
        f = self.filter
        th = self.theta()
        sd = self.method.with_resistance_stds(self.ident.stds())
        out = {
            "est.mass": self.ident.mass, "est.mass_std": self.ident.mass_std(),
            "est.A0": float(th[1]), "est.A1": float(th[2]), "est.A2": float(th[3]),
            "est.A0_std": float(sd[1]), "est.A1_std": float(sd[2]), "est.A2_std": float(sd[3]),
            "est.sigma2": self.sigma2(),
            "est.samples": self.ident.samples, "est.station_stops": self.station_stops,
        }
        if predicted:
            out.update({"filter.speed": f.predicted_speed, "filter.position": f.predicted_position,
                        "filter.speed_std": f.predicted_speed_std,
                        "filter.position_std": f.predicted_position_std})
        else:
            out.update({"filter.speed": f.speed, "filter.position": f.position,
                        "filter.speed_std": f.speed_std, "filter.position_std": f.position_std})
        out = self.finish_outputs(out)
        out.update(self.resistance_covariances())   # after est.status: they never degrade it
        return out

    A_COVARIANCES = (("est.cov_A0_A1", 1, 2), ("est.cov_A0_A2", 1, 3), ("est.cov_A1_A2", 2, 3))
    """The off-diagonal outputs of the A's covariance: name, row and column in Theta."""

    def resistance_covariances(self) -> dict[str, float]:
        """est.cov_A0_A1 [(N/kN)^2/(m/s)], est.cov_A0_A2 [(N/kN)^2/(m/s)^2], est.cov_A1_A2
        [(N/kN)^2/(m/s)^3]: the off-diagonal of the covariance whose diagonal est.A0_std ..
        est.A2_std are the roots of (the LS's sandwich, or the method's carried A's), so that
        w0(V)'s variance phi^T C phi, phi = (1, V, V^2), follows from the outputs alone. As a std
        is 0 where its variance is not > 0, a covariance is 0 where either variance is not > 0,
        or where it is not finite itself: never NaN or inf. The C twin is
        rc_estimator_resistance_covariances (models/core/estimator.c)."""
        c = self.method.with_resistance_covariance(self.ident.covariance())
        out = {}
        for name, i, j in self.A_COVARIANCES:
            cij = float(c[i, j])
            out[name] = cij if c[i, i] > 0.0 and c[j, j] > 0.0 and math.isfinite(cij) else 0.0
        return out

    MASS_RANGE = 5.0   # est.mass is reported while within a factor 5 of est.mass_initial
    PRIOR, IDENTIFYING, HOLDING, DEGRADED = 0, 1, 2, 3   # est.status

    def finish_outputs(self, out: dict) -> dict:
        """Add est.status and filter.rejected, and keep every value finite and est.mass plausible.

        Right after a mass restart the first sample pair alone decides 1/(Pg): one pair's
        differenced speed noise (+-72 N/kN at 0.05 m/s and 0.1 s) against 120 N/kN of traction
        makes 1/(Pg) <= 0 in ~5 % of departures for a sample or two (est.mass was inf). An
        estimate outside [m0 / MASS_RANGE, MASS_RANGE m0] (m0 = est.mass_initial), or not
        finite, is not reported: est.mass keeps its last good value with at least
        est.mass_std_initial, est.status = DEGRADED. A non-finite value of any other output
        (none is known to occur) is replaced by its last good value the same way. ``out`` is
        changed in place and returned."""
        if (self._mass_low <= out["est.mass"] <= self._mass_high
                and math.isfinite(sum(out.values()))):        # the usual case, in one test
            out["est.status"] = (self.IDENTIFYING if self._pair_used
                                 else self.HOLDING if self.ident.samples else self.PRIOR)
            self._last_good = out
        else:
            good, m0 = self._last_good, self._mass_initial
            if not (self._mass_low <= out["est.mass"] <= self._mass_high
                    and math.isfinite(out["est.mass_std"])):
                out["est.mass"] = good["est.mass"] if good else m0
                out["est.mass_std"] = max(good["est.mass_std"] if good else 0.0, self._mass_std_initial)
            for k, v in out.items():
                if not math.isfinite(v):
                    out[k] = good[k] if good else 0.0
            out["est.status"] = self.DEGRADED
        out["filter.rejected"] = self.filter.rejected
        return out
