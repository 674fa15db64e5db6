"""Scenarios: small versioned TOML files (profiles as CSV) -> validated dataclasses.

A scenario names FMU parameters by their contract names (one source of truth: the variable
table of ``fmu_src/variables.py``, units as there, SI), the driving script and the wind
schedule, and the run's step and duration. Every error names the file, the key and the reason.

    name = "default"
    purpose = "one line"
    step_s = 0.1
    duration_s = 200.0
    stop_after_last_phase = true      # the run ends when the driver's last phase is done

    [parameters]                      # RailCar parameters, contract names, SI units
    "car.mass" = 34.0
    "track.grade_profile" = "profiles/demo_grade.csv"   # relative to this file

    [[driver]]                        # phases, in order (see harness/driver.py)
    action = "traction"
    until_speed_mps = 16.7

    [[wind]]                          # piecewise constant from each time on
    time_s = 60.0
    speed_mps = 5.0
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from fmu_src.variables import RAILCAR, variables_for

from .driver import DriverPhase, TimeTable, parse_phase, parse_time_table

PATH_PARAMETERS = ("track.grade_profile", "track.speed_profile")


class ScenarioError(ValueError):
    """A scenario that cannot run; the message names the file, the key and the reason."""


@dataclass(frozen=True)
class WindStep:
    time_s: float       # from this time on [s]
    speed_mps: float    # headwind > 0 [m/s]


@dataclass(frozen=True)
class Scenario:
    name: str
    purpose: str
    path: Path | None
    parameters: dict = field(default_factory=dict)      # FMU parameter name -> value
    phases: tuple[DriverPhase, ...] = ()
    time_table: TimeTable | None = None
    wind: tuple[WindStep, ...] = ()
    step_s: float = 0.1
    duration_s: float = 200.0
    stop_after_last_phase: bool = True

    def parameter(self, name: str):
        """The scenario's value of an FMU parameter, or the FMU's default."""
        if name in self.parameters:
            return self.parameters[name]
        return _PARAMETER_TABLE[name].start

    def wind_at(self, t: float) -> float:
        """Wind speed [m/s] at time t [s]."""
        w = 0.0
        for step in self.wind:
            if t + 1e-9 >= step.time_s:
                w = step.speed_mps
        return w


_PARAMETER_TABLE = {v.name: v for v in variables_for(RAILCAR) if v.causality == "parameter"}


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def parse_parameters(raw: dict, where: str, base_dir: Path | None) -> dict:
    """Check names and types against the variable table; resolve profile paths."""
    out = {}
    for name, value in raw.items():
        key = f"{where}.\"{name}\""
        var = _PARAMETER_TABLE.get(name)
        if var is None:
            raise ScenarioError(f"{key}: not a RailCar parameter (see fmu_src/variables.py)")
        if var.type == "Real":
            out[name] = _number(value, key)
        elif var.type == "Integer":
            if isinstance(value, bool) or not isinstance(value, int):
                raise ScenarioError(f"{key}: expected an integer, got {value!r}")
            out[name] = value
        else:
            if not isinstance(value, str):
                raise ScenarioError(f"{key}: expected a string, got {value!r}")
            if name in PATH_PARAMETERS and value:
                p = Path(value)
                if not p.is_absolute() and base_dir is not None:
                    p = base_dir / p
                if not p.is_file():
                    raise ScenarioError(f"{key}: file not found: {p}")
                value = str(p.resolve())
            out[name] = value
    return out


def scenario_from_dict(data: dict, source: str, base_dir: Path | None = None) -> Scenario:
    """Build and validate a Scenario from parsed TOML; ``source`` names the file in errors."""
    known = {"name", "purpose", "step_s", "duration_s", "stop_after_last_phase", "parameters",
             "driver", "driver_table", "wind"}
    for key in data:
        if key not in known:
            raise ScenarioError(f"{source}: unknown key '{key}' (known: {', '.join(sorted(known))})")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{source}: 'name' must be a non-empty string")
    step = _number(data.get("step_s", 0.1), f"{source}: step_s")
    duration = _number(data.get("duration_s", 200.0), f"{source}: duration_s")
    if step <= 0:
        raise ScenarioError(f"{source}: step_s must be > 0, got {step}")
    if duration < step:
        raise ScenarioError(f"{source}: duration_s must be >= step_s, got {duration}")
    params = parse_parameters(data.get("parameters", {}), f"{source}: parameters", base_dir)
    phases = tuple(parse_phase(p, f"{source}: driver[{i}]", ScenarioError)
                   for i, p in enumerate(data.get("driver", [])))
    table = None
    if "driver_table" in data:
        table = parse_time_table(data["driver_table"], f"{source}: driver_table", base_dir, ScenarioError)
    if phases and table is not None:
        raise ScenarioError(f"{source}: give either [[driver]] phases or [driver_table], not both")
    if not phases and table is None:
        raise ScenarioError(f"{source}: no driving script: add [[driver]] phases or a [driver_table]")
    wind = []
    for i, w in enumerate(data.get("wind", [])):
        where = f"{source}: wind[{i}]"
        wind.append(WindStep(_number(w.get("time_s"), f"{where}.time_s"),
                             _number(w.get("speed_mps"), f"{where}.speed_mps")))
    stop_after = data.get("stop_after_last_phase", True)
    if not isinstance(stop_after, bool):
        raise ScenarioError(f"{source}: stop_after_last_phase must be true or false")
    return Scenario(name=name, purpose=str(data.get("purpose", "")),
                    path=Path(source) if base_dir is not None else None, parameters=params,
                    phases=phases, time_table=table, wind=tuple(sorted(wind, key=lambda w: w.time_s)),
                    step_s=step, duration_s=duration, stop_after_last_phase=stop_after)


def read_toml(path: Path, error=None) -> dict:
    """Parse a TOML file; ``error`` (default ScenarioError) names the file and the reason."""
    error = error or ScenarioError
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML: {e}") from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    path = Path(path)
    return scenario_from_dict(read_toml(path), str(path), path.parent)
