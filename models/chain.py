"""The whole RailCar chain without FMI: plant -> sensors -> online estimator.

``RailCarChain.do_step(t, h, ...)`` is what the FMU's doStep does. Truth is integrated on the
plant's fixed grid; sensors sample every ``sample_period`` [s] on their own grid (sample j at
j * sample_period), so results do not depend on the host's communication step beyond the
integrator's error. Between samples the sensors and estimates hold their last values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from models.plant.dynamics import CarPlant, VehicleParams
from models.estimation.online import OnlineEstimator, StationConfig
from models.filtering.motion_filter import FilterConfig
from models.estimation.identification import IdentifierConfig
from models.plant.noise import noise_streams
from models.plant.track import GradeProfile, SpeedProfile
from models.units import G


class StepRejected(ValueError):
    """An input or step size the chain refuses; nothing was changed. Names the variable."""


def check_force(name: str, value: float) -> None:
    """Raise StepRejected unless ``value`` [N] is finite and >= 0."""
    if not math.isfinite(value) or value < 0.0:
        raise StepRejected(f"{name} must be finite and >= 0 [N], got {value!r}")


def check_finite(name: str, value: float, unit: str) -> None:
    if not math.isfinite(value):
        raise StepRejected(f"{name} must be finite [{unit}], got {value!r}")


MAX_STEP = 3600.0
"""Longest communication step [s] accepted: a step costs time in proportion to its length
(RailCar integrates on its own grid), so a mistyped h = 1e6 s would block the host for a minute."""
FORCE_LIMIT_FACTOR = 10.0   # a force above this many times the car's limit is not physics
MAX_WIND = 100.0            # [m/s] |wind_speed| accepted (the strongest gusts measured: ~110 m/s)
MAX_MEASURED_SPEED = 200.0  # [m/s] |sensor.speed| accepted by RailCarEstimator (720 km/h)
MAX_MEASURED_DISTANCE = 1e7  # [m] |sensor.position| accepted (10,000 km from the last station)


def check_step(current_time: float, step_size: float) -> None:
    if not (math.isfinite(step_size) and step_size > 0.0):
        raise StepRejected(f"communication step size must be > 0 [s], got {step_size!r}")
    if step_size > MAX_STEP:
        raise StepRejected(f"communication step size must be <= {MAX_STEP:g} s, got {step_size!r}")
    if not math.isfinite(current_time):
        raise StepRejected(f"current time must be finite [s], got {current_time!r}")


def check_bounded(name: str, value: float, limit: float, unit: str, why: str) -> None:
    """Raise StepRejected unless |value| <= limit (a finite value far outside physics)."""
    if not abs(value) <= limit:
        raise StepRejected(f"{name} = {value!r} {unit} is beyond {limit:g} {unit} ({why})")


@dataclass
class TrackSensorConfig:
    """Pairs of point track sensors (Boynik et al., n.d.): speed = base / (t2 - t1) with a timer."""
    spacing: float = 0.0        # a pair every `spacing` metres from each station [m]; 0 = none
    base: float = 5.0           # distance between the two sensors of a pair [m]
    resolution: float = 1e-3    # timer resolution [s]
    jitter: float = 0.0         # detection-time noise std [s]

    def validate(self) -> None:
        for name in ("spacing", "jitter"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"sensor.track_{name} must be >= 0, got {v}")
        if not (self.base > 0 and math.isfinite(self.base)):
            raise ValueError(f"sensor.track_base must be > 0, got {self.base}")
        if not (self.resolution >= 0 and math.isfinite(self.resolution)):
            raise ValueError(f"sensor.track_resolution must be >= 0, got {self.resolution}")
        if self.spacing and self.spacing <= self.base:
            raise ValueError(f"sensor.track_spacing ({self.spacing}) must exceed sensor.track_base "
                             f"({self.base})")

    def speed_std(self, v: float) -> float:
        """Std of a measured speed [m/s] at speed v [m/s]: v^2/b sqrt(delta^2/6 + 2 jitter^2)."""
        from models.plant.track_sensors import track_sensor_speed_std
        return float(track_sensor_speed_std(v, self.base, self.resolution, self.jitter))


def _hermite_crossing(t0, x0, v0, t1, x1, v1, d) -> float:
    """Time in [t0, t1] [s] at which the cubic Hermite path through (x0, v0), (x1, v1)
    reaches the distance d [m] (bisection; the path is monotonic for v >= 0)."""
    h = t1 - t0

    def x_at(s):
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * x0 + (s3 - 2 * s2 + s) * h * v0
                + (-2 * s3 + 3 * s2) * x1 + (s3 - s2) * h * v1)
    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if x_at(mid) < d:
            lo = mid
        else:
            hi = mid
    return t0 + 0.5 * (lo + hi) * h


@dataclass
class ChainConfig:
    """Everything RailCar needs besides the profiles (names follow the FMU variables)."""
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    solver_step: float = 0.05          # plant's internal step [s]
    process_noise_psd: float = 1e-4    # [m^2/s^3]
    sample_period: float = 0.1         # sensors [s]
    seed: int = 1
    initial_speed: float = 0.0         # [m/s]; > 0 starts the car moving mid-line
    initial_position: float = 0.0      # [m] from the previous station
    station: StationConfig = field(default_factory=StationConfig)
    identifier: IdentifierConfig = field(default_factory=IdentifierConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)   # sensor noise and filter kind
    track: TrackSensorConfig = field(default_factory=TrackSensorConfig)

    def validate(self) -> None:
        self.vehicle.validate()
        self.track.validate()
        if not 0 <= int(self.seed) <= 2 ** 31 - 1:     # the FMU's seed is an fmi2Integer
            raise ValueError(f"seed must be in 0..2147483647 (a 32-bit fmi2Integer), got {self.seed}")
        if not (self.sample_period > 0 and math.isfinite(self.sample_period)):
            raise ValueError(f"sensor.sample_period must be > 0, got {self.sample_period}")
        for name in ("initial_speed", "initial_position"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"car.{name} must be >= 0, got {v}")
        if self.initial_speed > MAX_MEASURED_SPEED:     # 1e300 gave an infinite car.acceleration
            raise ValueError(f"car.initial_speed must be <= {MAX_MEASURED_SPEED:g} m/s (no rail car "
                             f"is that fast), got {self.initial_speed}")
        if self.sample_period + 1e-12 < self.solver_step:
            raise ValueError(f"solver.step ({self.solver_step}) must not exceed "
                             f"sensor.sample_period ({self.sample_period})")


def build_estimator(id_cfg: IdentifierConfig, filt: FilterConfig, station: StationConfig,
                    grade_profile: GradeProfile, speed_profile: SpeedProfile | None,
                    dt: float, method=None, noise=None) -> OnlineEstimator:
    """The estimator both FMUs run, sampling every dt [s] (private copies of the configs);
    ``method``, ``noise``: strategy objects instead of the configured ones (models/estimation/methods.py)."""
    id_cfg = replace(id_cfg, dt=dt, speed_std=filt.speed_std, speed_std_rel=filt.speed_std_rel)
    filt = replace(filt, dt=dt, gamma=id_cfg.gamma)
    return OnlineEstimator(id_cfg, filt, station, grade_profile, speed_profile, method, noise)


class RailCarChain:
    """Plant + sensors + estimator; one instance per FMU instance. The Python reference: the
    C core (models/compiled.py) is its bit-identical twin. ``method``, ``noise``: the
    estimator's strategy objects instead of the configured ones (an experiment, a study:
    models/estimation/methods.py)."""

    engine = "python"

    def __init__(self, cfg: ChainConfig, grade_profile: GradeProfile,
                 speed_profile: SpeedProfile | None = None, start_time: float = 0.0, *,
                 method=None, noise=None):
        cfg = replace(cfg, vehicle=replace(cfg.vehicle))
        cfg.validate()     # a private copy: payload changes the mass
        if not math.isfinite(start_time):
            raise ValueError(f"start time must be finite, got {start_time}")
        self.cfg = cfg
        self.start_time = start_time    # the host's time of the chain's internal t = 0 [s]
        streams = noise_streams(cfg.seed, ("process", "speed_sensor", "position_sensor", "track_sensor"))
        self._track_noise = streams["track_sensor"]
        self.track_speed = 0.0       # last track-sensor speed [m/s]
        self.track_time = 0.0        # its time stamp (second sensor, as the timer read it) [s]
        self._track_t1 = None        # true passage time at the first sensor of the pair [s]
        self._speed_noise = streams["speed_sensor"]
        self._position_noise = streams["position_sensor"]
        self.base_mass = cfg.vehicle.mass
        # demands above these are refused (StepRejected); 1 N floors a limit configured as 0
        self._traction_limit = FORCE_LIMIT_FACTOR * max(cfg.vehicle.traction_force_max, 1.0)
        self._brake_limit = FORCE_LIMIT_FACTOR * max(cfg.vehicle.brake_force_max, 1.0)
        self._payload_limit = FORCE_LIMIT_FACTOR * cfg.vehicle.mass    # [t]
        self.plant = CarPlant(cfg.vehicle, grade_profile, step=cfg.solver_step,
                              noise_psd=cfg.process_noise_psd, station_dwell=cfg.station.dwell,
                              normal_draws=streams["process"])
        self.plant.state.speed = cfg.initial_speed
        self.plant.state.position = cfg.initial_position
        self.plant.refresh_outputs()
        filt = replace(cfg.filter, length=cfg.vehicle.length)
        self.estimator = build_estimator(cfg.identifier, filt, cfg.station, grade_profile,
                                         speed_profile, cfg.sample_period, method, noise)
        self._pending_track = None
        self._sample_index = 0
        # the forces the estimator's last propagate() received: the plant's impulse over the
        # last sample interval / sample_period [N] (0 before the first interval ends)
        self.traction_force_mean = 0.0
        self.brake_force_mean = 0.0
        self.sensor_speed = 0.0
        self.sensor_position = 0.0
        self._take_sample()

    def _take_sample(self) -> None:
        s = self.plant.state
        f = self.cfg.filter
        self.sensor_speed = s.speed + f.speed_noise_std(s.speed) * self._speed_noise()
        self.sensor_position = s.position + f.position_noise_std(s.position) * self._position_noise()
        self.estimator.measure(self.sensor_speed, self.sensor_position)
        if self._pending_track is not None:
            v, age = self._pending_track
            self.estimator.measure_track_speed(v, age, self.cfg.track.speed_std(v), self.cfg.track.base)
            self._pending_track = None

    def _track_passages(self, t0: float, x0: float, v0: float) -> None:
        """Track sensors passed since (t0, x0, v0): a pair's second sensor yields a speed."""
        s = self.plant.state
        t1, x1, v1 = self.plant.time, s.position, s.speed
        if x1 < x0:                          # the distance restarted at a station
            self._track_t1 = None
            return
        tc = self.cfg.track
        k = math.floor(x0 / tc.spacing)
        while True:                          # sensors at k*spacing (first) and +base (second)
            for d, second in ((k * tc.spacing, False), (k * tc.spacing + tc.base, True)):
                if k >= 1 and x0 < d <= x1:
                    t = _hermite_crossing(t0, x0, v0, t1, x1, v1, d)
                    if not second:
                        self._track_t1 = t
                    elif self._track_t1 is not None:
                        self._track_reading(self._track_t1, t)
                        self._track_t1 = None
            k += 1
            if k * tc.spacing > x1:
                return

    def _track_reading(self, t_first: float, t_second: float) -> None:
        from models.plant.track_sensors import quantise_time, speed_from_times
        tc = self.cfg.track
        j1, j2 = tc.jitter * self._track_noise(), tc.jitter * self._track_noise()
        v = float(speed_from_times(t_first, t_second, tc.base, tc.resolution, 0.0, j1, j2))
        stamp = float(quantise_time(t_second + j2, tc.resolution)) if tc.resolution else t_second + j2
        if not math.isfinite(v):
            return                           # both stamps on one tick: no reading
        self.track_speed, self.track_time = v, stamp + self.start_time
        self._pending_track = (v, self.plant.time - stamp)

    def _check_inputs(self, current_time: float, step_size: float, traction_demand: float,
                      brake_demand: float, wind_speed: float, payload: float) -> None:
        """Raise StepRejected naming the first input that is bad or beyond physics (do_step's
        one comparison chain found one; NaN fails every comparison: a NaN time used to send the
        sample loop on for ever)."""
        check_step(current_time, step_size)
        check_force("traction_force_demand", traction_demand)
        check_force("brake_force_demand", brake_demand)
        check_bounded("traction_force_demand", traction_demand, self._traction_limit, "N",
                      f"{FORCE_LIMIT_FACTOR:g} x car.traction_force_max")
        check_bounded("brake_force_demand", brake_demand, self._brake_limit, "N",
                      f"{FORCE_LIMIT_FACTOR:g} x car.brake_force_max")
        check_finite("wind_speed", wind_speed, "m/s")
        check_bounded("wind_speed", wind_speed, MAX_WIND, "m/s", "no wind blows that hard")
        check_finite("car.payload", payload, "t")
        check_bounded("car.payload", payload, self._payload_limit, "t",
                      f"{FORCE_LIMIT_FACTOR:g} x car.mass")

    def next_sample_time(self) -> float:
        return (self._sample_index + 1) * self.cfg.sample_period

    def do_step(self, current_time: float, step_size: float, traction_demand: float,
                brake_demand: float, wind_speed: float, payload: float = 0.0) -> None:
        """Advance from ``current_time`` by ``step_size`` [s] with demands [N], wind [m/s] and
        payload [t] (passengers on top of car.mass) held.

        Raises StepRejected (naming the variable) before changing anything on bad input.
        """
        if not (0.0 < step_size <= MAX_STEP and 0.0 <= traction_demand <= self._traction_limit
                and 0.0 <= brake_demand <= self._brake_limit and -MAX_WIND <= wind_speed <= MAX_WIND
                and -self._payload_limit <= payload <= self._payload_limit
                and -math.inf < current_time < math.inf):
            self._check_inputs(current_time, step_size, traction_demand, brake_demand, wind_speed,
                               payload)
        current_time -= self.start_time          # internal time starts at 0
        mass = self.base_mass + payload
        if mass <= 0.0:
            raise StepRejected(f"car.payload {payload!r} t leaves a mass <= 0 (car.mass {self.base_mass} t)")
        self.plant.p.mass = mass
        t_end = current_time + step_size
        eps = 1e-9 * max(1.0, abs(t_end))
        if abs(current_time - self.plant.time) > eps:
            raise StepRejected(f"current time {current_time + self.start_time!r} s does not continue "
                               f"the FMU's time {self.plant.time + self.start_time!r} s")
        while True:
            t_sample = self.next_sample_time()
            if t_sample > t_end + eps:
                if self.plant.time < t_end - eps:
                    self.plant.advance(t_end, traction_demand, brake_demand, wind_speed)
                return
            before = (self.plant.time, self.plant.state.position, self.plant.state.speed)
            self.plant.advance(t_sample, traction_demand, brake_demand, wind_speed)
            if self.cfg.track.spacing:
                self._track_passages(*before)
            # forces applied over the last sample interval, then the new measurement
            ts = self.cfg.sample_period
            self.traction_force_mean = self.plant.traction_impulse / ts
            self.brake_force_mean = self.plant.brake_impulse / ts
            self.estimator.propagate(self.traction_force_mean, self.brake_force_mean, ts)
            self.plant.traction_impulse = self.plant.brake_impulse = 0.0
            self._sample_index += 1
            self._take_sample()

    def outputs(self) -> dict[str, float]:
        """Truth (car.*), measurements (sensor.*), estimates (est.*, filter.*), then the forces
        the estimator was last fed (car.traction_force_mean, car.brake_force_mean [N])."""
        s = self.plant.state
        out = {
            "car.speed": s.speed, "car.position": s.position, "car.acceleration": s.acceleration,
            "car.traction_force": s.traction_force, "car.brake_force": s.brake_force,
            "car.grade": s.grade, "car.mode": s.mode, "car.total_mass": self.plant.p.mass,
            "sensor.speed": self.sensor_speed, "sensor.position": self.sensor_position,
            "sensor.track_speed": self.track_speed, "sensor.track_time": self.track_time,
        }
        out.update(self.estimator.outputs())
        out["car.traction_force_mean"] = self.traction_force_mean
        out["car.brake_force_mean"] = self.brake_force_mean
        return out


class EstimatorChain:
    """RailCarEstimator without FMI: one measurement per communication step.

    At doStep(t, h) the inputs are the measurements at t and the forces applied over
    [t, t+h]; the outputs after the step are the estimates for t + h (the filter's one-step
    prediction) and the identification up to t. The estimator is built at the first step,
    whose size h is the nominal sampling period.
    """

    engine = "python"

    def __init__(self, identifier: IdentifierConfig, filt: FilterConfig, station: StationConfig,
                 grade_profile: GradeProfile, speed_profile: SpeedProfile | None = None,
                 track: TrackSensorConfig | None = None):
        self.track = track or TrackSensorConfig()
        self.track.validate()
        self._last_track_time = -math.inf
        self._args = (identifier, filt, station, grade_profile, speed_profile)
        # The estimator knows no force limit of the car: it refuses a force that would accelerate
        # the heaviest car it accepts (OnlineEstimator.MASS_RANGE x est.mass_initial) at over
        # FORCE_LIMIT_FACTOR x the adhesion limit (0.4 g) [N]
        heaviest = OnlineEstimator.MASS_RANGE * identifier.mass_initial * 1000.0   # [kg]
        self._force_limit = FORCE_LIMIT_FACTOR * 0.4 * G * heaviest
        self._force_why = (f"{FORCE_LIMIT_FACTOR:g} x the adhesion limit 0.4 g of "
                           f"{OnlineEstimator.MASS_RANGE:g} x est.mass_initial")
        build_estimator(*self._args, dt=1.0)   # validates every setting now, at initialisation
        self.estimator: OnlineEstimator | None = None
        self.time = None

    def do_step(self, current_time: float, step_size: float, traction: float, brake: float,
                speed_meas: float, position_meas: float, track_speed: float = 0.0,
                track_time: float = 0.0) -> None:
        """Raises StepRejected (naming the variable) before changing anything on bad input.

        A track-sensor speed [m/s] is taken when its time stamp ``track_time`` [s] is new
        (later than the last one taken and not after ``current_time``).
        """
        check_step(current_time, step_size)
        check_finite("sensor.track_speed", track_speed, "m/s")
        check_finite("sensor.track_time", track_time, "s")
        check_force("traction_force", traction)
        check_force("brake_force", brake)
        check_bounded("traction_force", traction, self._force_limit, "N", self._force_why)
        check_bounded("brake_force", brake, self._force_limit, "N", self._force_why)
        check_finite("sensor.speed", speed_meas, "m/s")
        check_finite("sensor.position", position_meas, "m")
        check_bounded("sensor.speed", speed_meas, MAX_MEASURED_SPEED, "m/s", "no rail car is that fast")
        check_bounded("sensor.position", position_meas, MAX_MEASURED_DISTANCE, "m",
                      "no line is that long")
        if self.time is not None and abs(current_time - self.time) > 1e-9 * max(1.0, abs(current_time)):
            raise StepRejected(f"current time {current_time!r} s does not continue the FMU's "
                               f"time {self.time!r} s")
        if self.estimator is None:
            self.estimator = build_estimator(*self._args, dt=step_size)
        self.estimator.measure(speed_meas, position_meas)
        if self._last_track_time < track_time <= current_time + 1e-9 and track_speed > 0.0:
            self.estimator.measure_track_speed(track_speed, current_time - track_time,
                                               self.track.speed_std(track_speed), self.track.base)
            self._last_track_time = track_time
        self.estimator.propagate(traction, brake, step_size)
        self.time = current_time + step_size

    def outputs(self) -> dict[str, float]:
        if self.estimator is None:
            return {}
        return self.estimator.outputs(predicted=True)
