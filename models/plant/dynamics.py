"""Car dynamics: forces, eq. (1)-(2) of Gorbachev et al. (2015), and a fixed-step plant with
process noise.

Units: speed [m/s], distance [m], force [N], mass [t], specific force [N/kN], grade [permille].
The equation of motion (Gorbachev et al.'s eq. (2) in continuous time, with Meleshin's (2011)
rotating-mass factor gamma):

    dV/dt = g/1000 / (1 + gamma) * ( (F - B)/(P g) - w0(V) - i(X) )      [m/s^2]
    dX/dt = V                                                             [m/s]

With gamma = 0 this is exactly the paper's model; with gamma > 0 an estimator built on (2)
alone identifies the effective mass P (1 + gamma) (docs/model.md, Forces on the car).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from models.plant.track import GradeProfile
from models.units import G, mps_to_kmh

STANDSTILL, TRACTION, COASTING, BRAKING = 0, 1, 2, 3
"""Values of ``car.mode``."""


@dataclass
class VehicleParams:
    """True vehicle parameters.

    Defaults: resistance from Meleshin's (2011) Table 1 row 1 (Rusich, a*=0.89 kgf/t,
    b*=0.008 kgf/t/(km/h), c*=0.00081 kgf/t/(km/h)^2) converted to V in m/s; mass, drive and
    brake are those of a 30 t car with a 40 kN / 400 kW two-zone drive (Meleshin's constant
    force, then constant power).
    """
    mass: float = 30.0                 # P, car mass with passengers [t]
    A0: float = 0.89                   # [N/kN]
    A1: float = 0.0288                 # [N/kN/(m/s)]
    A2: float = 0.010498               # [N/kN/(m/s)^2]
    gamma: float = 0.0                 # rotating-mass factor [-] (Meleshin divides by 1 + gamma)
    length: float = 0.0                # car/train length for grade averaging [m]; 0 = point mass
    traction_force_max: float = 40e3   # constant-force zone [N]
    traction_power_max: float = 400e3  # constant-power zone: F <= P_max / V [W]
    brake_force_max: float = 45e3      # emergency brake limit [N]
    adhesion_mass_fraction: float = 1.0  # share of the mass on driven axles [-]
    adhesion_factor: float = 1.0       # scales the dry-rail adhesion coefficient (wet rail ~0.5) [-]

    def validate(self, prefix: str = "car.") -> None:
        """Raise ValueError naming the first invalid parameter."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v):
                raise ValueError(f"{prefix}{f.name} must be finite, got {v}")
        positive = ("mass", "traction_force_max", "traction_power_max", "brake_force_max")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"{prefix}{name} must be > 0, got {getattr(self, name)}")
        for name in ("gamma", "length", "A0", "A1", "A2"):
            if getattr(self, name) < 0:
                raise ValueError(f"{prefix}{name} must be >= 0, got {getattr(self, name)}")
        if not 0 < self.adhesion_mass_fraction <= 1:
            raise ValueError(f"{prefix}adhesion_mass_fraction must be in (0, 1], "
                             f"got {self.adhesion_mass_fraction}")
        if not 0 < self.adhesion_factor <= 1.5:
            raise ValueError(f"{prefix}adhesion_factor must be in (0, 1.5], got {self.adhesion_factor}")


def adhesion_coefficient(v: float) -> float:
    """Dry-rail adhesion coefficient psi_k(V) [-] for speed ``v`` [m/s].

    Curtius & Kniffler (1950), "Neue Erkenntnisse ueber die Haftung zwischen Treibrad und
    Schiene", Elektrische Bahnen 20: psi = 0.161 + 7.5 / (V + 44), V in km/h.
    """
    return 0.161 + 7.5 / (mps_to_kmh(abs(v)) + 44.0)


def adhesion_force_limit(v: float, p: VehicleParams) -> float:
    """Largest wheel-rail force [N]: P_adh g psi_k(V), P_adh = mass on driven axles [t]."""
    return 1000.0 * p.mass * p.adhesion_mass_fraction * G * adhesion_coefficient(v) * p.adhesion_factor


def traction_force_limit(v: float, p: VehicleParams) -> float:
    """Traction characteristic F_max(V) [N]: constant force, then constant power, then adhesion."""
    f = p.traction_force_max
    if v > 0.0:
        f = min(f, p.traction_power_max / v)
    return min(f, adhesion_force_limit(v, p))


def brake_force_limit(v: float, p: VehicleParams) -> float:
    """Brake limit [N]: the emergency limit, bounded by adhesion on all axles."""
    adh_all_axles = adhesion_force_limit(v, p) / p.adhesion_mass_fraction
    return min(p.brake_force_max, adh_all_axles)


def applied_forces(v: float, traction_demand: float, brake_demand: float,
                   p: VehicleParams) -> tuple[float, float]:
    """Forces actually applied (F, B) [N] for demands [N] >= 0.

    A brake demand cuts traction (interlock); each force is clipped to its limit at speed ``v``.
    """
    if brake_demand > 0.0:
        return 0.0, min(brake_demand, brake_force_limit(v, p))
    return min(traction_demand, traction_force_limit(v, p)), 0.0


# ------------------------------------------------------- eqs. (1) and (2): the one Python copy
# The span planners (models/planning/engine.py), the output-error fit and the coasting EKF
# (models/estimation/) and the ATO (models/ato/) call these. Copies kept on purpose, each saying
# why: the C core's mirrors, held_input_dynamics below (models/core/plant.c) and
# models/filtering/kalman.py (models/core/filter.c); and the ATO re-planner's PlanCar.accel, w0 and
# coast_step (models/ato/motion.py: its own operand order keeps the ATO's results bit-identical).

def acceleration_gain(gamma: float) -> float:
    """g/1000/(1 + gamma) [m/s^2 per N/kN]: eq. (2)'s factor from a specific force to dV/dt,
    with Meleshin's (2011) rotating-mass factor gamma [-] (the paper's eq. (2): gamma = 0)."""
    return G / 1000.0 / (1.0 + gamma)


def resistance_eq1(v, A0: float, A1: float, A2: float, wind=0.0):
    """Specific main resistance w0 [N/kN], eq. (1): A0 + A1 V + A2 (V + Vw)|V + Vw| for a speed
    ``v`` [m/s] (a float or an array) and a wind ``wind`` [m/s] (headwind > 0).

    The V^2 term is air drag, so the wind acts on it. For V + Vw > 0 this is eq. (1) with
    A0 + A2 Vw^2, A1 + 2 A2 Vw, A2 (docs/model.md, Forces on the car: wind moves all three).
    """
    va = v + wind
    return A0 + A1 * v + A2 * va * abs(va)


def acceleration_eq2(specific_force, w0, grade, gain: float):
    """dV/dt [m/s^2] of a moving car, eq. (2) in continuous time: gain (f - w0 - i), with the
    specific net force f = (F - B)/(P g) [N/kN], the resistance w0 [N/kN] (eq. (1)), the grade
    i [permille] and gain = ``acceleration_gain(gamma)``. Floats or arrays."""
    return gain * (specific_force - w0 - grade)


def specific_force_eq2(accel, w0, grade, gain: float):
    """Eq. (2) solved for the specific net force (F - B)/(P g) [N/kN] that gives dV/dt = ``accel``
    [m/s^2] against the resistance w0 [N/kN] and the grade [permille]."""
    return accel / gain + w0 + grade


def acceleration_polynomial(theta, net_force, grade, gain: float):
    """Eq. (2) as a quadratic in the speed, dV/dt = c0 - c1 V - c2 V^2 (V >= 0, no wind), for the
    paper's parameters Theta = (1/(P g), A0, A1, A2) [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]:
    returns (c0, c1, c2), c0 = gain (Theta1 (F - B) - A0 - i) for the net force F - B [N] and the
    grade i [permille] (floats or arrays: one c0 per sample interval), c1 = gain A1, c2 = gain A2."""
    th1, a0, a1, a2 = (float(x) for x in theta)
    return gain * (th1 * net_force - a0 - grade), gain * a1, gain * a2


def main_resistance(v: float, wind: float, p: VehicleParams) -> float:
    """Specific main resistance w0 [N/kN] of the car ``p``, eq. (1) (``resistance_eq1``)."""
    return resistance_eq1(v, p.A0, p.A1, p.A2, wind)


def acceleration(v: float, f: float, b: float, grade: float, wind: float, p: VehicleParams) -> float:
    """dV/dt [m/s^2] of a moving car (v > 0) under applied forces F, B [N] on grade [permille]:
    eq. (2) (``acceleration_eq2``) for the car ``p``."""
    return acceleration_eq2((f - b) / (p.mass * G), main_resistance(v, wind, p), grade,
                            acceleration_gain(p.gamma))


@dataclass
class PlantState:
    """Truth of the car at one instant."""
    speed: float = 0.0          # [m/s]
    position: float = 0.0       # distance from the previous station [m]
    acceleration: float = 0.0   # [m/s^2]
    traction_force: float = 0.0  # applied [N]
    brake_force: float = 0.0    # applied [N]
    grade: float = 0.0          # under the car [permille]
    mode: int = STANDSTILL
    still_time: float = 0.0     # time at rest so far [s]
    stops: int = 0              # station stops completed (departures after a dwell)


def rk4_step(v: float, x: float, h: float, traction_demand: float, brake_demand: float,
             wind: float, p: VehicleParams, grade_profile: GradeProfile) -> tuple[float, float]:
    """One deterministic RK4 step of length h [s] with inputs held; returns (V, X) [m/s, m].

    A car that comes to rest inside the step stops there (linear interpolation of the instant)
    and stays at rest: speed never goes negative.
    """
    return _rk4(v, x, h, held_input_dynamics(p, grade_profile, traction_demand, brake_demand, wind)[1])


def _rk4(v: float, x: float, h: float, accel) -> tuple[float, float]:
    """``rk4_step`` with a prepared accel(v, x) (same arithmetic, fewer calls)."""
    if v <= 0.0 and accel(0.0, x) <= 0.0:
        return 0.0, x
    k1v = accel(v if v > 0.0 else 0.0, x)
    v2 = v + 0.5 * h * k1v
    k2v = accel(v2 if v2 > 0.0 else 0.0, x + 0.5 * h * v)
    v3 = v + 0.5 * h * k2v
    k3v = accel(v3 if v3 > 0.0 else 0.0, x + 0.5 * h * v2)
    v4 = v + h * k3v
    k4v = accel(v4 if v4 > 0.0 else 0.0, x + h * v3)
    v_new = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    x_new = x + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
    if v_new < 0.0:
        t_stop = h * v / (v - v_new)          # comes to rest inside the step
        return 0.0, x + 0.5 * v * t_stop
    return v_new, x_new


def held_input_dynamics(p: VehicleParams, grade_profile: GradeProfile, traction_demand: float,
                        brake_demand: float, wind: float):
    """Fast closures for inputs held over a step: (forces(v) -> (F, B), accel(v, x) -> dV/dt).

    Mirrors models/core/plant.c operation for operation: bit-identity, tests/model_tests/core/test_core_plant.py.

    The same physics as ``applied_forces`` and ``acceleration`` (tests check they agree),
    with the parameters bound once instead of looked up at every evaluation.
    """
    k_adh = 1000.0 * p.mass * p.adhesion_mass_fraction * G * p.adhesion_factor   # [N] per unit psi
    frac = p.adhesion_mass_fraction
    f_max, p_max, b_max = p.traction_force_max, p.traction_power_max, p.brake_force_max
    a0, a1, a2 = p.A0, p.A1, p.A2
    inv_weight = 1.0 / (p.mass * G)
    k_acc = G / 1000.0 / (1.0 + p.gamma)
    length = p.length
    average = grade_profile.average
    braking = brake_demand > 0.0

    def forces(v):
        adh = k_adh * (0.161 + 7.5 / (abs(v) * 3.6 + 44.0))    # Curtius-Kniffler psi_k
        if braking:
            lim = adh / frac
            return 0.0, (brake_demand if brake_demand < lim and brake_demand < b_max
                         else (lim if lim < b_max else b_max))
        lim = f_max
        if v > 0.0 and p_max / v < lim:
            lim = p_max / v
        if adh < lim:
            lim = adh
        return (traction_demand if traction_demand < lim else lim), 0.0

    def accel(v, x):
        f, b = forces(v)
        va = v + wind
        spec = (f - b) * inv_weight - (a0 + a1 * v + a2 * va * abs(va)) - average(x, length)
        a = k_acc * spec
        return a if (v > 0.0 or a > 0.0) else 0.0     # at rest: no backward roll (docs/model.md, Equation of motion)

    return forces, accel


class CarPlant:
    """The true car: fixed internal step with process noise, station stops, truth outputs.

    Process noise is white noise on the acceleration with power spectral density
    ``noise_psd`` [m^2/s^3]: over an internal step h the speed receives N(0, noise_psd * h),
    so the physics is the same at every step size (eq. (2)'s sigma^2 per step dt is
    noise_psd * dt). Noise is added on the internal grid t_k = k h only, so a run's truth does
    not depend on where the host's communication points fall.
    """

    def __init__(self, params: VehicleParams, grade_profile: GradeProfile, *, step: float,
                 noise_psd: float, station_dwell: float, normal_draws):
        params.validate()
        if not (step > 0 and math.isfinite(step)):
            raise ValueError(f"solver.step must be > 0, got {step}")
        if not (noise_psd >= 0 and math.isfinite(noise_psd)):
            raise ValueError(f"car.process_noise_psd must be >= 0, got {noise_psd}")
        self.p = params
        self.grade_profile = grade_profile
        self.h = step
        self.noise_std = math.sqrt(noise_psd * step)
        self.station_dwell = station_dwell
        self._normal = normal_draws   # callable returning one standard normal draw
        self.state = PlantState()
        self.time = 0.0
        self._grid_index = 0          # internal grid point k: t_k = k h
        self.traction_impulse = 0.0   # integral of the applied traction force [N s], reset by the caller
        self.brake_impulse = 0.0      # integral of the applied brake force [N s]
        self._update_outputs(0.0, 0.0, 0.0)

    def _update_outputs(self, traction_demand, brake_demand, wind, dynamics=None):
        s = self.state
        forces, accel = dynamics or held_input_dynamics(self.p, self.grade_profile, traction_demand,
                                                        brake_demand, wind)
        f, b = forces(s.speed)
        a = accel(s.speed, s.position)
        grade = self.grade_profile.average(s.position, self.p.length)
        s.acceleration, s.traction_force, s.brake_force, s.grade = a, f, b, grade
        if s.speed <= 0.0 and a <= 0.0:
            s.mode = STANDSTILL
        elif b > 0.0:
            s.mode = BRAKING
        elif f > 0.0:
            s.mode = TRACTION
        else:
            s.mode = COASTING

    def refresh_outputs(self, traction_demand: float = 0.0, brake_demand: float = 0.0,
                        wind: float = 0.0) -> None:
        """Recompute acceleration, forces, grade and mode after the state was set."""
        self._update_outputs(traction_demand, brake_demand, wind)

    def next_grid_time(self) -> float:
        return (self._grid_index + 1) * self.h

    def advance(self, t_end: float, traction_demand: float, brake_demand: float, wind: float) -> None:
        """Integrate from the current time to ``t_end`` [s] (> current) with inputs held.

        Steps are cut at the internal grid; noise is added at each grid point reached.
        """
        s = self.state
        eps = 1e-9 * max(1.0, abs(t_end))
        forces, accel = held_input_dynamics(self.p, self.grade_profile, traction_demand, brake_demand, wind)
        while self.time < t_end - eps:
            t_grid = self.next_grid_time()
            t_next = t_grid if t_grid <= t_end + eps else t_end
            h = t_next - self.time
            was_still = s.speed <= 0.0
            if was_still and s.still_time >= self.station_dwell and s.position != 0.0:
                # departure after a station stop: distance counts from this station
                if accel(0.0, s.position) > 0.0:
                    s.position = 0.0
                    s.stops += 1
            f0, b0 = forces(s.speed)
            s.speed, s.position = _rk4(s.speed, s.position, h, accel)
            f1, b1 = forces(s.speed)
            self.traction_impulse += 0.5 * (f0 + f1) * h
            self.brake_impulse += 0.5 * (b0 + b1) * h
            self.time = t_next
            if abs(t_next - t_grid) <= eps:
                self._grid_index += 1
                self.time = self._grid_index * self.h
                if s.speed > 0.0 and self.noise_std > 0.0:
                    s.speed = max(0.0, s.speed + self.noise_std * self._normal())
            if s.speed <= 0.0:
                s.still_time = s.still_time + h if was_still else 0.0
            else:
                s.still_time = 0.0
        self._update_outputs(traction_demand, brake_demand, wind, (forces, accel))
