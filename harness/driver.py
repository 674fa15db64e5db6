"""Scripted drivers: phases triggered by speed, distance or time, or a time table of demands.

A phase driver sees the true speed [m/s] and distance [m] (the ideal odometry of an ATO
test bench, so that driving decisions do not depend on sensor noise) and returns the
traction and brake demands [N]. Phases (TOML ``[[driver]]`` entries):

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

brake_to_stop ends when the car stands; hold (a holding brake) ends by until_time_s.
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.units import kmh_to_mps

ACTIONS = ("traction", "coast", "cruise", "brake", "brake_to_stop", "hold")
CRUISE_GAIN = 0.5   # [1/s] the cruise controller's demand: mass * gain * (target - speed)
_PHASE_KEYS = {"action", "force_N", "until_speed_mps", "until_speed_kmh", "until_distance_m",
               "until_time_s", "until_brake_curve", "stop_at_m", "decel_mps2", "mass_change_t",
               "target_speed_mps", "target_speed_kmh"}


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
        if key not in _PHASE_KEYS:
            raise error(f"{where}: unknown key '{key}' (known: {', '.join(sorted(_PHASE_KEYS))})")
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

    def demands(self, t: float, speed: float, position: float) -> tuple[float, float, float]:
        """(traction [N], brake [N], mass change [t] to apply now) for the true speed and distance."""
        mass_change = 0.0
        while not self.finished and self._phase_done(self.phases[self.index], t, speed, position):
            self.index += 1
            self._phase_start = t
            if not self.finished and self.phases[self.index].mass_change_t:
                mass_change += self.phases[self.index].mass_change_t
        if self.finished:
            return 0.0, (0.3 * self.b_max if speed <= self.STOPPED else 0.0), mass_change
        p = self.phases[self.index]
        if p.action == "traction":
            return (p.force_N if p.force_N is not None else self.f_max), 0.0, mass_change
        if p.action == "coast":
            return 0.0, 0.0, mass_change
        if p.action == "brake":
            return 0.0, (p.force_N if p.force_N is not None else 0.6 * self.b_max), mass_change
        if p.action == "hold":
            return 0.0, 0.3 * self.b_max, mass_change
        if p.action == "cruise":
            demand = 1000.0 * self.mass_t * CRUISE_GAIN * (p.target_speed_mps - speed)
            if demand >= 0.0:
                return min(demand, self.f_max), 0.0, mass_change
            return 0.0, min(-demand, self.b_max), mass_change
        # brake_to_stop: the deceleration needed to stop at stop_at_m, as a force
        left = p.stop_at_m - position
        if speed <= self.STOPPED or left <= 0.05:
            return 0.0, 0.3 * self.b_max, mass_change
        need = speed * speed / (2.0 * left)
        return 0.0, min(self.b_max, 1000.0 * self.mass_t * need), mass_change


@dataclass(frozen=True)
class TimeTable:
    """Time-scripted demands, piecewise linear in time: t [s], traction [N], brake [N]."""
    time_s: tuple[float, ...]
    traction_N: tuple[float, ...]
    brake_N: tuple[float, ...]

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
        from .textio import read_text      # UTF-8 text, a BOM skipped; names the file
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


def run_on_chain(scenario, overrides: dict | None = None):
    """The scenario on a models chain built as the RailCar FMU builds it (its parameters, with
    ``overrides`` by FMU name, e.g. {"est.method": 2, "seed": 5}): ``chain_result``. Raises
    ValueError, naming the parameter, if the configuration rejects one."""
    from fmu_src.adapter import chain_config, load_profiles
    from fmu_src.variables import RAILCAR, variables_for
    from models.compiled import open_chain
    v = {x.name: scenario.parameter(x.name) for x in variables_for(RAILCAR) if x.causality == "parameter"}
    v.update(overrides or {})
    return chain_result(open_chain(chain_config(v), *load_profiles(v, None)), scenario)


def chain_result(chain, scenario):
    """Drive a models chain through the scenario (``drive_chain``) and return a
    ``harness.runner.RunResult`` of its outputs, with the inputs applied over each step as its
    inputs (the demands [N] are what ``harness.metrics.oracle_filter`` needs; wind [m/s] and
    payload [t] complete harness.runner.INPUTS), as the FMU runner's would be."""
    from .runner import INPUTS, RunResult
    demands: list = []
    rows = drive_chain(chain, scenario, demands=demands)
    demands.append(demands[-1])
    d = np.array(demands)
    return RunResult(scenario, np.arange(len(rows)) * scenario.step_s,
                     {k: np.array([r[k] for r in rows]) for k in rows[0]}, {},
                     inputs={name: d[:, j] for j, name in enumerate(INPUTS)})


def drive_chain(chain, scenario, max_steps: int | None = None,
                demands: list | None = None) -> list[dict]:
    """Run a models chain (``models.chain.RailCarChain``, no FMI) through the scenario's scripted
    phases, one communication step of ``scenario.step_s`` [s] at a time, as
    ``harness.runner.FmuRunner.run`` drives the FMU; returns ``chain.outputs()`` at t = 0 and
    after every step (at most ``max_steps`` steps). ``demands``, when given, receives each
    step's inputs in harness.runner.INPUTS order: traction and brake demand [N], wind [m/s],
    payload [t]."""
    driver = PhaseDriver(scenario.phases, scenario.parameter("car.mass"),
                         scenario.parameter("car.traction_force_max"),
                         scenario.parameter("car.brake_force_max"))
    h, payload = scenario.step_s, 0.0
    rows = [chain.outputs()]
    steps = int(round(scenario.duration_s / h))
    for k in range(steps if max_steps is None else min(steps, max_steps)):
        t = k * h
        last = rows[-1]        # the truth the closed loop sees (the car's own speed and distance)
        traction, brake, dm = driver.demands(t, last["car.speed"], last["car.position"])
        payload += dm
        if driver.finished and scenario.stop_after_last_phase:
            break
        wind = scenario.wind_at(t)
        chain.do_step(t, h, traction, brake, wind, payload)
        rows.append(chain.outputs())
        if demands is not None:
            demands.append((traction, brake, wind, payload))
    return rows
