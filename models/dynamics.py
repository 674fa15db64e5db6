"""Car dynamics: forces, eq. (1)-(2) of seed 001, and a fixed-step plant with process noise.

Units: speed [m/s], distance [m], force [N], mass [t], specific force [N/kN], grade [permille].
The equation of motion (seed 001 eq. (2) in continuous time, with seed 003's rotating-mass
factor gamma):

    dV/dt = g/1000 / (1 + gamma) * ( (F - B)/(P g) - w0(V) - i(X) )      [m/s^2]
    dX/dt = V                                                             [m/s]

With gamma = 0 this is exactly the paper's model; with gamma > 0 an estimator built on (2)
alone identifies the effective mass P (1 + gamma) (MODEL.md section 2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from .track import GradeProfile
from .units import G, mps_to_kmh

STANDSTILL, TRACTION, COASTING, BRAKING = 0, 1, 2, 3
"""Values of ``car.mode``."""


@dataclass
class VehicleParams:
    """True vehicle parameters.

    Defaults: resistance from seed 003 Table 1 row 1 (Rusich, a*=0.89 kgf/t, b*=0.008 kgf/t/(km/h),
    c*=0.00081 kgf/t/(km/h)^2) converted to V in m/s; mass, drive and brake are those of a
    30 t car with a 40 kN / 400 kW two-zone drive (seed 003's constant force, then constant power).
    """
    mass: float = 30.0                 # P, car mass with passengers [t]
    A0: float = 0.89                   # [N/kN]
    A1: float = 0.0288                 # [N/kN/(m/s)]
    A2: float = 0.010498               # [N/kN/(m/s)^2]
    gamma: float = 0.0                 # rotating-mass factor [-] (seed 003 divides by 1 + gamma)
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


def main_resistance(v: float, wind: float, p: VehicleParams) -> float:
    """Specific main resistance w0 [N/kN], eq. (1), with wind ``wind`` [m/s] (headwind > 0).

    The V^2 term is air drag, so the wind acts on it: A2 (V + Vw)|V + Vw|. For V + Vw > 0 this
    is eq. (1) with A0 + A2 Vw^2, A1 + 2 A2 Vw, A2 (MODEL.md section 2: wind moves all three).
    """
    va = v + wind
    return p.A0 + p.A1 * v + p.A2 * va * abs(va)


def acceleration(v: float, f: float, b: float, grade: float, wind: float, p: VehicleParams) -> float:
    """dV/dt [m/s^2] of a moving car (v > 0) under applied forces F, B [N] on grade [permille]."""
    specific = (f - b) / (p.mass * G) - main_resistance(v, wind, p) - grade
    return G / 1000.0 / (1.0 + p.gamma) * specific


def breakaway_acceleration(f: float, b: float, grade: float, wind: float, p: VehicleParams) -> float:
    """Acceleration [m/s^2] of a car at rest; 0 unless the forces overcome resistance forwards.

    A car at rest never rolls backwards (static friction / holding brake, MODEL.md section 3).
    """
    a = acceleration(0.0, f, b, grade, wind, p)
    return a if a > 0.0 else 0.0


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


def _derivative(v, x, traction_demand, brake_demand, wind, p, grade_profile):
    """(dV/dt, applied F, applied B, grade) of a car that moves or is at rest."""
    f, b = applied_forces(v, traction_demand, brake_demand, p)
    grade = grade_profile.average(x, p.length)
    if v > 0.0:
        a = acceleration(v, f, b, grade, wind, p)
    else:
        a = breakaway_acceleration(f, b, grade, wind, p)
    return a, f, b, grade


def rk4_step(v: float, x: float, h: float, traction_demand: float, brake_demand: float,
             wind: float, p: VehicleParams, grade_profile: GradeProfile) -> tuple[float, float]:
    """One deterministic RK4 step of length h [s] with inputs held; returns (V, X) [m/s, m].

    A car that comes to rest inside the step stops there (linear interpolation of the instant)
    and stays at rest: speed never goes negative.
    """
    def accel(vv, xx):
        return _derivative(max(vv, 0.0), xx, traction_demand, brake_demand, wind, p, grade_profile)[0]

    if v <= 0.0 and accel(0.0, x) <= 0.0:
        return 0.0, x
    k1v = accel(v, x)
    k1x = v
    k2v = accel(v + 0.5 * h * k1v, x + 0.5 * h * k1x)
    k2x = v + 0.5 * h * k1v
    k3v = accel(v + 0.5 * h * k2v, x + 0.5 * h * k2x)
    k3x = v + 0.5 * h * k2v
    k4v = accel(v + h * k3v, x + h * k3x)
    k4x = v + h * k3v
    v_new = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    x_new = x + h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
    if v_new < 0.0:
        t_stop = h * v / (v - v_new)          # comes to rest inside the step
        return 0.0, x + 0.5 * v * t_stop
    return v_new, x_new


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

    def _update_outputs(self, traction_demand, brake_demand, wind):
        s = self.state
        a, f, b, grade = _derivative(s.speed, s.position, traction_demand, brake_demand, wind,
                                     self.p, self.grade_profile)
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
        while self.time < t_end - eps:
            t_grid = self.next_grid_time()
            t_next = t_grid if t_grid <= t_end + eps else t_end
            h = t_next - self.time
            was_still = s.speed <= 0.0
            if was_still and s.still_time >= self.station_dwell and s.position != 0.0:
                # departure after a station stop: distance counts from this station
                a0 = _derivative(0.0, s.position, traction_demand, brake_demand, wind,
                                 self.p, self.grade_profile)[0]
                if a0 > 0.0:
                    s.position = 0.0
                    s.stops += 1
            f0, b0 = applied_forces(s.speed, traction_demand, brake_demand, self.p)
            s.speed, s.position = rk4_step(s.speed, s.position, h, traction_demand, brake_demand,
                                           wind, self.p, self.grade_profile)
            f1, b1 = applied_forces(s.speed, traction_demand, brake_demand, self.p)
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
        self._update_outputs(traction_demand, brake_demand, wind)
