"""A span between two stations and the car's traction/brake characteristic, for train operation.

Units (MODEL.md section 1): distance [m], speed [m/s], time [s], force [N], power [W], mass [t],
grade [permille, +uphill], specific force [N/kN]. Speeds in km/h appear only in the defaults'
comments.

The forces the planner uses are those of the plant (models.plant.dynamics), imported, not copied:
main resistance ``main_resistance`` (eq. (1)), the equation of motion ``acceleration`` (eq. (2)
with Meleshin's (2011) rotating-mass factor), adhesion ``adhesion_force_limit`` and the total brake
limit ``brake_force_limit``; the grade is ``GradeProfile.average`` (point mass or Meleshin's
"inextensible string" over ``CarTraction.length``). What the plant does not have is added here:

- regenerative brake r_max(V): the drive's two-zone characteristic (constant force, then
  constant power), fading below ~7 km/h where the electro-pneumatic brake takes over (Meleshin
  2011, ch. 2: "electric brake above 7 km/h, electro-pneumatic from 0 to 7 km/h");
- the mechanical (electro-pneumatic) brake b_max, a constant;
- traction efficiency eta_f (taken constant: Meleshin, ch. 3, found the error of that assumption
  small) and the share eta of regenerated energy the network takes back (Meleshin, ch. 3).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field, fields

import numpy as np

from models.plant.dynamics import VehicleParams, adhesion_force_limit, brake_force_limit, main_resistance
from models.plant.track import MAX_GRADE, MAX_SPEED, GradeProfile
from models.units import G, kmh_to_mps

_TINY_SPEED = 1e-9   # [m/s] P/V at V = 0 is taken at this speed (so the force limit wins)


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value}")
    return v


@dataclass(frozen=True)
class CarTraction:
    """The car as the planner sees it: mass, resistance, traction and brake characteristics.

    Defaults are the RailCar FMU's (fmu_src/variables.py: car.mass, car.A0..A2 = Meleshin's (2011)
    Table 1 row 1 in m/s units, 40 kN / 400 kW two-zone drive, 45 kN brake limit). Meleshin gives
    the *shape* of the Rusich characteristics (two-zone traction; electric brake above 7 km/h,
    electro-pneumatic below) but no numbers in the summary we have, so the others are ours:
    the regenerative brake uses the same drive limits as traction (40 kN, 400 kW: the
    asynchronous drive runs as a generator within the same inverter ratings) and fades linearly
    from ``regen_fade_speed`` (7 km/h, Meleshin) to zero at ``regen_off_speed`` (5 km/h: a ramp,
    not a step, keeps the force continuous for the integrator); eta_f = 0.9 (an asynchronous
    drive's inverter-motor-gear chain); eta = 0.6 (the value in Meleshin's Fig. 3 legend).

    The effective mass is mass (1 + gamma) (MODEL.md section 2); forces are total car forces.
    """
    mass: float = 30.0                   # P, car mass with passengers [t]
    A0: float = 0.89                     # [N/kN]
    A1: float = 0.0288                   # [N/kN/(m/s)]
    A2: float = 0.010498                 # [N/kN/(m/s)^2]
    gamma: float = 0.0                   # rotating-mass factor [-]
    length: float = 0.0                  # grade averaged over this length [m]; 0 = point mass
    traction_force_max: float = 40e3     # f_max in the constant-force zone [N]
    traction_power_max: float = 400e3    # f_max <= P / V in the constant-power zone [W]
    brake_force_max: float = 45e3        # total brake limit of the plant (regen + mechanical) [N]
    regen_force_max: float = 40e3        # r_max, constant-force zone [N]
    regen_power_max: float = 400e3       # r_max <= P / V [W]
    regen_fade_speed: float = kmh_to_mps(7.0)   # full regen at and above this speed [m/s]
    regen_off_speed: float = kmh_to_mps(5.0)    # no regen at and below this speed [m/s]
    mech_force_max: float = 45e3         # b_max, electro-pneumatic brake [N]
    adhesion_mass_fraction: float = 1.0  # share of the mass on driven axles [-]
    adhesion_factor: float = 1.0         # scales the dry-rail adhesion coefficient [-]
    eta_f: float = 0.9                   # traction efficiency: wheel energy / network energy [-]
    eta: float = 0.6                     # share of the regenerated energy the network takes [-]
    _vehicle: VehicleParams = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        for f in fields(self):
            if f.init:
                object.__setattr__(self, f.name, _finite(f"car.{f.name}", getattr(self, f.name)))
        for name in ("regen_force_max", "regen_power_max", "mech_force_max"):
            if getattr(self, name) < 0 or (name == "regen_power_max" and self.regen_power_max == 0):
                raise ValueError(f"car.{name} must be {'> 0' if name == 'regen_power_max' else '>= 0'}, "
                                 f"got {getattr(self, name)}")
        if not 0.0 <= self.regen_off_speed <= self.regen_fade_speed:
            raise ValueError(f"car.regen_off_speed must be in [0, car.regen_fade_speed = "
                             f"{self.regen_fade_speed}], got {self.regen_off_speed}")
        if not 0.0 < self.eta_f <= 1.0:
            raise ValueError(f"car.eta_f must be in (0, 1], got {self.eta_f}")
        if not 0.0 <= self.eta <= 1.0:
            raise ValueError(f"car.eta must be in [0, 1], got {self.eta}")
        vehicle = VehicleParams(
            mass=self.mass, A0=self.A0, A1=self.A1, A2=self.A2, gamma=self.gamma,
            length=self.length, traction_force_max=self.traction_force_max,
            traction_power_max=self.traction_power_max, brake_force_max=self.brake_force_max,
            adhesion_mass_fraction=self.adhesion_mass_fraction, adhesion_factor=self.adhesion_factor)
        vehicle.validate("car.")
        object.__setattr__(self, "_vehicle", vehicle)

    @classmethod
    def from_vehicle(cls, p: VehicleParams, **extra) -> "CarTraction":
        """The planner's car for the plant's parameters ``p`` plus the regen/efficiency fields."""
        shared = {f.name: getattr(p, f.name) for f in fields(VehicleParams)}
        return cls(**shared, **extra)

    @property
    def vehicle(self) -> VehicleParams:
        """The same car as models.plant.dynamics sees it (for its force functions)."""
        return self._vehicle

    @property
    def weight_kn(self) -> float:
        """P g [kN]: a force [N] divided by it is a specific force [N/kN]."""
        return self.mass * G

    @property
    def inertial_mass_kg(self) -> float:
        """m (1 + gamma) [kg]: force [N] / this = acceleration [m/s^2]."""
        return 1000.0 * self.mass * (1.0 + self.gamma)

    # ---- characteristics; v [m/s] may be a float or a numpy array (same arithmetic) ----

    def f_max(self, v):
        """Traction characteristic f_max(V) [N]: constant force, then constant power, then adhesion.

        The arithmetic of models.plant.dynamics.traction_force_limit (tests check bit-identity), in a
        form that also takes arrays.
        """
        mn = np.minimum if isinstance(v, np.ndarray) else min
        vp = np.maximum(v, _TINY_SPEED) if isinstance(v, np.ndarray) else max(v, _TINY_SPEED)
        return mn(mn(self.traction_force_max, self.traction_power_max / vp),
                  adhesion_force_limit(v, self._vehicle))

    def r_max(self, v):
        """Regenerative brake characteristic r_max(V) [N]: two-zone, adhesion-limited, zero at and
        below regen_off_speed, rising linearly to full at regen_fade_speed (Meleshin 2011:
        electric brake above ~7 km/h)."""
        arr = isinstance(v, np.ndarray)
        mn, mx = (np.minimum, np.maximum) if arr else (min, max)
        vp = mx(v, _TINY_SPEED)
        full = mn(mn(self.regen_force_max, self.regen_power_max / vp),
                  adhesion_force_limit(v, self._vehicle))
        width = self.regen_fade_speed - self.regen_off_speed
        if width > 0.0:
            share = mn(mx((v - self.regen_off_speed) / width, 0.0), 1.0)
        else:
            share = (v >= self.regen_fade_speed) * 1.0
        return full * share

    def brake_total_max(self, v):
        """Total brake limit [N] (regen + mechanical): models.plant.dynamics.brake_force_limit, the
        plant's clip (brake_force_max and adhesion on all axles)."""
        if isinstance(v, np.ndarray):
            adh = adhesion_force_limit(v, self._vehicle) / self.adhesion_mass_fraction
            return np.minimum(self.brake_force_max, adh)
        return brake_force_limit(v, self._vehicle)

    def service_brake(self, v):
        """The braking curve's force [N]: full regen, the electro-pneumatic brake filling in what
        the fading regen loses below regen_fade_speed so the brake force stays at the regen's
        level at that speed (Meleshin 2011: electric brake above 7 km/h, electro-pneumatic below),
        never above the total limit. Returns (regen [N], mechanical [N])."""
        arr = isinstance(v, np.ndarray)
        mn, mx = (np.minimum, np.maximum) if arr else (min, max)
        r = mn(self.r_max(v), self.brake_total_max(v))
        level = mn(self.r_max(self.regen_fade_speed), self.brake_total_max(v))
        below = (v < self.regen_fade_speed) * 1.0
        mech = mn(mx(level - r, 0.0), self.mech_force_max) * below
        return r, mech

    def hold_speed_regen(self, v_hold: float) -> float:
        """V_r [m/s], the speed an energy-optimal run holds by regenerative braking when it holds
        V_c by traction: V_r^2 w0'(V_r) = V_c^2 w0'(V_c) / (eta eta_f).

        From the maximum principle with the cost of MODEL.md section 9: on a singular arc p is
        constant and dH/dV = 0 gives lambda = V^2 W'(V) / eta_f for traction holding (p = 1) and
        lambda = eta V^2 W'(V) for regen holding (p = eta eta_f), W' = dW/dV the resistance
        force's slope (docs in models/planning/trajectory.py). Returns inf if eta = 0 (no regen holding).
        """
        if self.eta == 0.0:
            return math.inf
        target = v_hold * v_hold * (self.A1 + 2.0 * self.A2 * v_hold) / (self.eta * self.eta_f)
        if self.A2 == 0.0:
            return math.sqrt(target / self.A1) if self.A1 > 0 else math.inf
        # V^2 (A1 + 2 A2 V) is increasing for V > 0: solve the cubic by Newton from above
        v = max(v_hold, (target / (2.0 * self.A2)) ** (1.0 / 3.0))
        for _ in range(60):
            fv = v * v * (self.A1 + 2.0 * self.A2 * v) - target
            dv = fv / (2.0 * v * self.A1 + 6.0 * self.A2 * v * v)
            v -= dv
            if abs(dv) <= 1e-13 * v:
                break
        return v


@dataclass(frozen=True)
class Span:
    """One span: grade profile, speed limits, stop mark and scheduled running time.

    ``grade``: models.plant.track.GradeProfile, grade i(s) [permille, +uphill], the profile the plant
    reads. ``limit_distances`` [m] / ``limit_speeds`` [m/s]: the speed limit V_lim(s), piecewise
    constant from each distance on (the first distance must be 0). ``stop`` [m]: the stop mark,
    where the car must come to rest (<= ``length``). ``schedule`` [s]: the running time from
    departure at s = 0 to rest at the stop mark.
    """
    length: float
    schedule: float
    stop: float | None = None
    grade: GradeProfile = field(default_factory=GradeProfile.level)
    limit_distances: tuple[float, ...] = (0.0,)
    limit_speeds: tuple[float, ...] = (kmh_to_mps(80.0),)

    def __post_init__(self):
        length = _finite("span.length", self.length)
        if length <= 0:
            raise ValueError(f"span.length must be > 0, got {length}")
        stop = length if self.stop is None else _finite("span.stop", self.stop)
        if stop <= 0:
            raise ValueError(f"span.stop must be > 0, got {stop}")
        if stop > length:
            raise ValueError(f"span.stop = {stop} m is beyond the span (span.length = {length} m)")
        schedule = _finite("span.schedule", self.schedule)
        if schedule <= 0:
            raise ValueError(f"span.schedule must be > 0, got {schedule}")
        d = tuple(_finite(f"span.limit_distances[{k}]", x) for k, x in enumerate(self.limit_distances))
        v = tuple(_finite(f"span.limit_speeds[{k}]", x) for k, x in enumerate(self.limit_speeds))
        if not d or len(d) != len(v):
            raise ValueError("span.limit_distances and span.limit_speeds must be non-empty and of "
                             f"equal length, got {len(d)} and {len(v)}")
        if d[0] != 0.0:
            raise ValueError(f"span.limit_distances[0] must be 0, got {d[0]}")
        for k in range(1, len(d)):
            if not d[k - 1] < d[k] < length:
                raise ValueError(f"span.limit_distances[{k}] = {d[k]} must increase and lie "
                                 f"inside the span [0, {length})")
        for k, x in enumerate(v):
            if not 0.0 < x <= MAX_SPEED:
                raise ValueError(f"span.limit_speeds[{k}] = {x} m/s (from s = {d[k]} m) must be "
                                 f"in (0, {MAX_SPEED}]")
        for k, g in enumerate(self.grade.grades):
            g = _finite(f"span.grade.grades[{k}]", g)
            if abs(g) > MAX_GRADE:
                raise ValueError(f"span.grade.grades[{k}] = {g} permille must be within "
                                 f"+-{MAX_GRADE:g}")
        for k, x in enumerate(self.grade.distances):
            _finite(f"span.grade.distances[{k}]", x)
        object.__setattr__(self, "length", length)
        object.__setattr__(self, "stop", stop)
        object.__setattr__(self, "schedule", schedule)
        object.__setattr__(self, "limit_distances", d)
        object.__setattr__(self, "limit_speeds", v)

    def v_lim(self, s: float) -> float:
        """V_lim(s) [m/s]: the limit in force from the last limit distance <= s."""
        k = bisect_right(self.limit_distances, s) - 1
        return self.limit_speeds[k if k >= 0 else 0]

    def v_lim_at_node(self, s: float) -> float:
        """The limit a car exactly at s must obey: the lower of the limits either side of s."""
        k = bisect_right(self.limit_distances, s) - 1
        k = k if k >= 0 else 0
        if k > 0 and self.limit_distances[k] == s:
            return min(self.limit_speeds[k], self.limit_speeds[k - 1])
        return self.limit_speeds[k]

    def breakpoints(self, car_length: float = 0.0) -> list[float]:
        """Distances [m] in (0, stop) where the grade under the car or the limit changes."""
        pts = set(self.limit_distances[1:])
        for x in self.grade.distances:
            pts.add(x)
            if car_length > 0:
                pts.add(x + car_length)
        return sorted(p for p in pts if 0.0 < p < self.stop)

    def with_schedule(self, schedule: float) -> "Span":
        """The same span with another scheduled running time [s]."""
        return Span(self.length, schedule, self.stop, self.grade, self.limit_distances,
                    self.limit_speeds)


def check_span_for_car(span: Span, car: CarTraction) -> None:
    """Raise ValueError if ``car`` cannot run ``span`` at all, naming the place and the value.

    - the car cannot start: at s = 0, f_max(0) must exceed the resistance A0 + grade;
    - a speed limit that cannot be met: holding V_lim on the steepest descent of its section
      needs more brake force than the total brake limit.
    (A climb the car stalls on is found by the minimum-time run, which names it.)
    """
    w = car.weight_kn
    i0 = span.grade.average(0.0, car.length)
    if car.f_max(0.0) <= w * (car.A0 + i0):
        raise ValueError(f"the car cannot start at s = 0: f_max(0) = {car.f_max(0.0):.0f} N <= "
                         f"resistance {w * (car.A0 + i0):.0f} N on span.grade {i0} permille")
    d, lim = span.limit_distances, span.limit_speeds
    for k, v in enumerate(lim):
        lo, hi = d[k], (d[k + 1] if k + 1 < len(d) else span.stop)
        grades = [span.grade.average(lo, car.length)]
        grades += [span.grade.average(x, car.length) for x in span.breakpoints(car.length) if lo <= x < hi]
        steepest = min(grades)
        need = -w * (main_resistance(v, 0.0, car.vehicle) + steepest)   # brake force to hold v [N]
        have = min(car.r_max(v) + car.mech_force_max, car.brake_total_max(v))
        if need > have:
            raise ValueError(
                f"span.limit_speeds[{k}] = {v} m/s (from s = {lo} m) cannot be met: holding it on "
                f"the {steepest} permille grade needs {need:.0f} N of brake, the car has {have:.0f} N")
