"""Driver protocols and the scripted drivers: phases (``[[driver]]``) and time tables (``[driver_table]``).

A *driver* turns the outputs after the previous step into one step's demands; a *stepper* (a
RailCar FMU, a models chain) advances with them. The loop that connects the two is
harness.run.driver.drive; the ATO driver of a span scenario is harness.run.span_scenario.AtoDriver.

    Stepper: outputs() -> Mapping[str, float];  do_step(t, h, inputs)    (inputs in INPUTS order)
    Driver:  demands(t, outputs) -> Demands(traction [N], brake [N], payload change [t]);  finished

Of a driver's demands the loop reads ``traction`` and ``brake``, and ``payload_change_t`` where
there is one (models.ato.controller's AtoCommand plugs in as it is). A driver may list the outputs it reads
(``reads``): an FMU stepper then reads those and the recorded ones, no more.

**Phase drivers** see the true speed [m/s] and distance [m] (the ideal odometry of an ATO test
bench, so that driving decisions do not depend on sensor noise). Phases (TOML ``[[driver]]``):

    action = "traction" | "coast" | "cruise" | "brake" | "brake_to_stop" | "hold"
    force_N = 40000          # traction/brake demand; default: the car's limit / a service brake
    until_speed_mps = 16.7   # (or until_speed_kmh) traction: reached from below; others: from above
    until_distance_m = 800   # distance from the previous station reached
    until_time_s = 25        # time spent in the phase
    until_brake_curve = true # the braking curve of the next brake_to_stop phase is reached
    stop_at_m = 1500         # brake_to_stop: where to stop
    decel_mps2 = 0.8         # brake_to_stop: planned deceleration
    mass_change_t = 3.0      # hold: passengers boarding (the car's mass changes by this) [t]
    target_speed_kmh = 50    # (or target_speed_mps) cruise: hold this speed with traction/brake

brake_to_stop ends when the car stands; hold (a holding brake) ends by until_time_s. A **time
table** ([driver_table]) gives the demands as piecewise-linear functions of time instead.

This module imports nothing of harness.run: the scenario, the span scenario and the loop import it.
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, NamedTuple, Protocol, Sequence

from models.units import kmh_to_mps

INPUTS = ("traction_force_demand", "brake_force_demand", "wind_speed", "car.payload")
"""A stepper's inputs, in this order: traction and brake demand [N], wind [m/s], payload [t]."""


class Demands(NamedTuple):
    """One step's demands."""
    traction: float                 # [N]
    brake: float                    # [N]
    payload_change_t: float = 0.0   # [t] passengers boarding now (leaving: < 0)


class Driver(Protocol):
    """Demands from the time [s] and the outputs after the last step, by FMU name."""

    @property
    def finished(self) -> bool: ...

    def demands(self, t: float, outputs: Mapping[str, float]) -> Demands: ...


class Stepper(Protocol):
    """A RailCar to drive: its outputs by FMU name, and one step with the inputs held."""

    def outputs(self) -> Mapping[str, float]: ...

    def do_step(self, t: float, h: float, inputs: Sequence[float]) -> None: ...


ACTIONS = ("traction", "coast", "cruise", "brake", "brake_to_stop", "hold")
CRUISE_GAIN = 0.5   # [1/s] the cruise controller's demand: mass * gain * (target - speed)
PHASE_KEYS = {"action", "force_N", "until_speed_mps", "until_speed_kmh", "until_distance_m",
               "until_time_s", "until_brake_curve", "stop_at_m", "decel_mps2", "mass_change_t",
               "target_speed_mps", "target_speed_kmh"}
_PHASE_KEYS = PHASE_KEYS   # the name harness.sweep.spec imports


@dataclass(frozen=True)
class DriverPhase:
    action: str
    force_N: float | None = None
    until_speed_mps: float | None = None
    until_distance_m: float | None = None
    until_time_s: float | None = None
    until_brake_curve: bool = False
    stop_at_m: float | None = None
    decel_mps2: float = 0.8
    mass_change_t: float = 0.0
    target_speed_mps: float | None = None


def parse_phase(raw: dict, where: str, error=ValueError) -> DriverPhase:
    """Validate one TOML phase table; ``error`` is the exception class to raise."""
    for key in raw:
        if key not in PHASE_KEYS:
            raise error(f"{where}: unknown key '{key}' (known: {', '.join(sorted(PHASE_KEYS))})")
    action = raw.get("action")
    if action not in ACTIONS:
        raise error(f"{where}.action: must be one of {', '.join(ACTIONS)}, got {action!r}")

    def num(key, positive=False):
        if key not in raw:
            return None
        v = raw[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise error(f"{where}.{key}: expected a finite number, got {v!r}")
        if positive and v <= 0:
            raise error(f"{where}.{key}: must be > 0, got {v}")
        return float(v)

    speed = num("until_speed_mps")
    if "until_speed_kmh" in raw:
        if speed is not None:
            raise error(f"{where}: give until_speed_mps or until_speed_kmh, not both")
        speed = kmh_to_mps(num("until_speed_kmh"))
    target = num("target_speed_mps", positive=True)
    if "target_speed_kmh" in raw:
        if target is not None:
            raise error(f"{where}: give target_speed_mps or target_speed_kmh, not both")
        target = kmh_to_mps(num("target_speed_kmh", positive=True))
    if action == "cruise" and target is None:
        raise error(f"{where}: cruise needs target_speed_kmh or target_speed_mps")
    force = num("force_N")
    if force is not None and force < 0:
        raise error(f"{where}.force_N: must be >= 0, got {force}")
    phase = DriverPhase(action=action, force_N=force, until_speed_mps=speed,
                        until_distance_m=num("until_distance_m"), until_time_s=num("until_time_s"),
                        until_brake_curve=bool(raw.get("until_brake_curve", False)),
                        stop_at_m=num("stop_at_m", positive=True),
                        decel_mps2=num("decel_mps2", positive=True) or 0.8,
                        mass_change_t=num("mass_change_t") or 0.0, target_speed_mps=target)
    if action == "brake_to_stop" and phase.stop_at_m is None:
        raise error(f"{where}: brake_to_stop needs stop_at_m")
    if action == "hold" and phase.until_time_s is None:
        raise error(f"{where}: hold needs until_time_s (the dwell)")
    if phase.mass_change_t and action != "hold":
        raise error(f"{where}.mass_change_t: passengers board only in a hold phase")
    return phase


class PhaseDriver:
    """Runs the phases in order; ``demands`` is called once per communication step."""

    STOPPED = 1e-6   # [m/s] below this the car stands
    reads = ("car.speed", "car.position")   # the truth, not the sensors

    def __init__(self, phases: tuple[DriverPhase, ...], mass_t: float, traction_force_max: float,
                 brake_force_max: float):
        self.phases = phases
        self.mass_t = mass_t
        self.f_max = traction_force_max
        self.b_max = brake_force_max
        self.index = 0
        self._phase_start = 0.0

    @property
    def finished(self) -> bool:
        return self.index >= len(self.phases)

    def _next_brake_phase(self) -> DriverPhase | None:
        for p in self.phases[self.index + 1:]:
            if p.action == "brake_to_stop":
                return p
        return None

    def _phase_done(self, p: DriverPhase, t: float, v: float, x: float) -> bool:
        if p.until_time_s is not None and t - self._phase_start >= p.until_time_s - 1e-9:
            return True
        if p.until_speed_mps is not None:
            if p.action == "traction" and v >= p.until_speed_mps:
                return True
            if p.action != "traction" and v <= p.until_speed_mps:
                return True
        if p.until_distance_m is not None and x >= p.until_distance_m:
            return True
        if p.until_brake_curve:
            nb = self._next_brake_phase()
            if nb is not None and v * v / (2.0 * max(nb.stop_at_m - x, 1e-3)) >= nb.decel_mps2:
                return True
        if p.action == "brake_to_stop" and v <= self.STOPPED and t > self._phase_start:
            return True
        return False

    def demands(self, t: float, outputs, position: float | None = None) -> Demands:
        """The demands for the outputs after the last step (their car.speed and car.position);
        ``demands(t, speed, position)`` with the two numbers is the same call."""
        if position is None:
            return self.at(t, outputs["car.speed"], outputs["car.position"])
        return self.at(t, outputs, position)

    def at(self, t: float, speed: float, position: float) -> Demands:
        """(traction [N], brake [N], mass change [t] to apply now) for the true speed [m/s] and
        distance [m]."""
        mass_change = 0.0
        while not self.finished and self._phase_done(self.phases[self.index], t, speed, position):
            self.index += 1
            self._phase_start = t
            if not self.finished and self.phases[self.index].mass_change_t:
                mass_change += self.phases[self.index].mass_change_t
        if self.finished:
            return Demands(0.0, 0.3 * self.b_max if speed <= self.STOPPED else 0.0, mass_change)
        p = self.phases[self.index]
        if p.action == "traction":
            return Demands(p.force_N if p.force_N is not None else self.f_max, 0.0, mass_change)
        if p.action == "coast":
            return Demands(0.0, 0.0, mass_change)
        if p.action == "brake":
            return Demands(0.0, p.force_N if p.force_N is not None else 0.6 * self.b_max, mass_change)
        if p.action == "hold":
            return Demands(0.0, 0.3 * self.b_max, mass_change)
        if p.action == "cruise":
            demand = 1000.0 * self.mass_t * CRUISE_GAIN * (p.target_speed_mps - speed)
            if demand >= 0.0:
                return Demands(min(demand, self.f_max), 0.0, mass_change)
            return Demands(0.0, min(-demand, self.b_max), mass_change)
        # brake_to_stop: the deceleration needed to stop at stop_at_m, as a force
        left = p.stop_at_m - position
        if speed <= self.STOPPED or left <= 0.05:
            return Demands(0.0, 0.3 * self.b_max, mass_change)
        need = speed * speed / (2.0 * left)
        return Demands(0.0, min(self.b_max, 1000.0 * self.mass_t * need), mass_change)


@dataclass(frozen=True)
class TimeTable:
    """Time-scripted demands, piecewise linear in time: t [s], traction [N], brake [N]. As a
    driver it reads no output and never finishes (the run goes on to duration_s)."""
    time_s: tuple[float, ...]
    traction_N: tuple[float, ...]
    brake_N: tuple[float, ...]
    reads = ()
    finished = False

    def demands(self, t: float, outputs=None) -> Demands:
        return Demands(*self.at(t))

    def at(self, t: float) -> tuple[float, float]:
        k = bisect_right(self.time_s, t)
        if k == 0:
            return self.traction_N[0], self.brake_N[0]
        if k == len(self.time_s):
            return self.traction_N[-1], self.brake_N[-1]
        t0, t1 = self.time_s[k - 1], self.time_s[k]
        w = (t - t0) / (t1 - t0)
        return (self.traction_N[k - 1] + w * (self.traction_N[k] - self.traction_N[k - 1]),
                self.brake_N[k - 1] + w * (self.brake_N[k] - self.brake_N[k - 1]))


def parse_time_table(raw: dict, where: str, base_dir: Path | None, error=ValueError) -> TimeTable:
    """``{file = "demands.csv"}`` (header time_s,traction_N,brake_N) or inline equal-length arrays."""
    if "file" in raw:
        path = Path(raw["file"])
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        if not path.is_file():
            raise error(f"{where}.file: cannot read {path}: no such file")
        from harness.textio import read_text      # UTF-8 text, a BOM skipped; names the file
        try:
            lines = read_text(path, ValueError).splitlines()
        except ValueError as e:
            raise error(f"{where}.file: {e}") from None
        header = [c.strip().strip('"') for c in lines[0].split(",")] if lines else []
        if header != ["time_s", "traction_N", "brake_N"]:
            raise error(f"{path}: line 1: header must be 'time_s,traction_N,brake_N'")
        cols: list[list[float]] = [[], [], []]
        for lineno, line in enumerate(lines[1:], start=2):
            if not line.strip():
                continue
            try:
                vals = [float(c) for c in line.split(",")]
            except ValueError:
                raise error(f"{path}: line {lineno}: not a number: '{line}'") from None
            if len(vals) != 3:
                raise error(f"{path}: line {lineno}: expected 3 values")
            for c, v in zip(cols, vals):
                c.append(v)
        where = str(path)
    else:
        cols = [list(raw.get(k, [])) for k in ("time_s", "traction_N", "brake_N")]
    if not cols[0] or len({len(c) for c in cols}) != 1:
        raise error(f"{where}: time_s, traction_N and brake_N must be non-empty and of equal length")
    for k in range(len(cols[0])):
        if any(not math.isfinite(c[k]) for c in cols):
            raise error(f"{where}: row {k + 1}: non-finite value")
        if cols[1][k] < 0 or cols[2][k] < 0:
            raise error(f"{where}: row {k + 1}: demands must be >= 0")
        if k and cols[0][k] <= cols[0][k - 1]:
            raise error(f"{where}: row {k + 1}: time_s must increase")
    return TimeTable(tuple(cols[0]), tuple(cols[1]), tuple(cols[2]))
