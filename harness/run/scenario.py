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

    [[driver]]                        # phases, in order (see harness/run/phases.py)
    action = "traction"
    until_speed_mps = 16.7

    [[wind]]                          # piecewise constant from each time on
    time_s = 60.0
    speed_mps = 5.0

Instead of a driving script, a ``[span]`` table (or ``[[span]]`` tables: a line) makes the ATO
(models.ato.controller.AtoController) the driver; ``[ato]`` tunes it (harness/run/span_scenario.py, docs/ato.md).
The ATO is configured for the plant's car (car.* above) and the estimator's prior mass is that
car's, unless ``[ato.car]`` (a disturbance) or est.mass_initial says otherwise.
"""
from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from fmu_src.variables import RAILCAR, variables_for

from harness.run.phases import DriverPhase, PhaseDriver, TimeTable, parse_phase, parse_time_table
from harness.run.span_scenario import PRIOR_MASS, AtoDriver, AtoSetup, parse_ato
from harness.textio import InputError, did_you_mean, read_text

if TYPE_CHECKING:       # fmu_src.adapter imports pythonfmu: loaded when a setup is resolved, not before
    from fmu_src.adapter import ChainSetup

PATH_PARAMETERS = ("track.grade_profile", "track.speed_profile")
ROOT = Path(__file__).resolve().parents[2]
# build.py bundles scenarios/profiles as the FMUs' resources/profiles: a relative profile path the
# FMU looks up in its resources first is looked up here, for the checks, below this folder
BUNDLED_RESOURCES = ROOT / "scenarios"
INT32_MIN, INT32_MAX = -2 ** 31, 2 ** 31 - 1       # an fmi2Integer is a 32-bit int
SEED_MIN, SEED_MAX = 0, INT32_MAX                   # the FMU's `seed` (an fmi2Integer, >= 0)


class ScenarioError(InputError):
    """A scenario that cannot run; the message names the file, the key and the reason."""


@dataclass(frozen=True)
class WindStep:
    time_s: float       # from this time on [s]
    speed_mps: float    # headwind > 0 [m/s]


@dataclass(frozen=True)
class ScenarioSetup:
    """A scenario's RailCar resolved once, as the FMU will build it at initialisation, without
    building it: every parameter's value, the chain's configuration and track profiles
    (fmu_src.adapter.ChainSetup: ``.open()`` gives a models chain), and a span scenario's ATO over
    the grade those parameters name."""
    values: dict                 # every RailCar parameter by FMU name: the scenario's, else the default
    chain: ChainSetup
    ato: AtoSetup | None = None

    @property
    def vehicle(self):
        """The true car (models.plant.dynamics.VehicleParams)."""
        return self.chain.config.vehicle


@dataclass(frozen=True)
class Scenario:
    """A validated scenario; ``setup`` is its RailCar and ATO resolved once (``ScenarioSetup``:
    at loading, or at first use for a copy made with other parameters)."""
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
    ato: AtoSetup | None = None  # a span scenario's ATO over the file's grade, else None

    @cached_property
    def setup(self) -> ScenarioSetup:
        """This scenario's ScenarioSetup. load_scenario resolves it while checking the file; a
        copy with other parameters (dataclasses.replace: a sweep's, a test's) resolves its own
        on first use, ScenarioError naming the parameter if the FMU would refuse them."""
        return resolve_setup(self.parameters, f"{self.path or self.name}: parameters", self.ato)

    def parameter(self, name: str):
        """The scenario's value of an FMU parameter, or the FMU's default."""
        if name in self.parameters:
            return self.parameters[name]
        return RAILCAR_PARAMETERS[name].start

    def railcar_parameters(self, overrides: dict | None = None) -> dict:
        """Every RailCar parameter by FMU name: the scenario's value, else the FMU's default, with
        ``overrides`` on top (ValueError for a name RailCar does not have)."""
        return railcar_values({**self.parameters, **_known(overrides or {})})

    def chain_setup(self, overrides: dict | None = None) -> ChainSetup:
        """The models chain's configuration and profiles (fmu_src.adapter.ChainSetup), as the
        RailCar FMU builds them at initialisation: the resolved ``setup.chain``, or with
        ``overrides`` (by FMU name) a new one (a relative profile path looked up where the FMU
        looks: its resources, then the working directory). ``.open()`` gives the chain."""
        if not overrides:
            return self.setup.chain
        from fmu_src.adapter import chain_setup
        return chain_setup(self.railcar_parameters(overrides), str(BUNDLED_RESOURCES))

    def new_driver(self, mass_t: float | None = None):
        """A fresh driver of this scenario's script (harness.run.phases): a PhaseDriver of its phases
        for a car of ``mass_t`` [t] (default car.mass; it sizes the cruise and brake_to_stop
        demands) and the car's force limits, or its time table; for a span scenario a fresh
        harness.run.span_scenario.AtoDriver (the ATO, one controller per span)."""
        if self.ato is not None:
            return AtoDriver(self.ato_setup(), self.name)
        if not self.phases:
            return self.time_table
        return PhaseDriver(self.phases, self.parameter("car.mass") if mass_t is None else mass_t,
                           self.parameter("car.traction_force_max"), self.parameter("car.brake_force_max"))

    def ato_setup(self) -> AtoSetup | None:
        """A span scenario's ATO (harness.run.span_scenario.AtoSetup) over the grade its parameters
        name now: a copy of the scenario with another track.grade_profile (a sweep's, a test's)
        gets its spans over that grade, never the file's (one source). None if not a span
        scenario."""
        return None if self.ato is None else self.setup.ato

    def wind_at(self, t: float) -> float:
        """Wind speed [m/s] at time t [s]."""
        w = 0.0
        for step in self.wind:
            if t + 1e-9 >= step.time_s:
                w = step.speed_mps
        return w


RAILCAR_PARAMETERS = {v.name: v for v in variables_for(RAILCAR) if v.causality == "parameter"}
"""RailCar's parameters (fmu_src.variables.Var: type, unit, default ``start``) by FMU name: the one
place the harness reads them from the variable table."""


def railcar_values(parameters: dict) -> dict:
    """Every RailCar parameter by FMU name: the value in ``parameters``, else the FMU's default."""
    return {n: parameters.get(n, var.start) for n, var in RAILCAR_PARAMETERS.items()}


VARIABLES_DOC = "docs/variables.md"


def unknown_parameter(name: str, known, what: str = "a RailCar parameter") -> str:
    """The message for a parameter name that is not ``what``: where the names are listed
    (docs/variables.md, the variable table) and the closest known names (difflib). One message
    for scenarios, overrides and sweeps."""
    return f"not {what} (see {VARIABLES_DOC}){did_you_mean(name, known, n=2, cutoff=0.8, ignore_case=True)}"


def _known(overrides: dict) -> dict:
    for name in overrides:
        if name not in RAILCAR_PARAMETERS:
            raise ValueError(f"{name}: {unknown_parameter(name, RAILCAR_PARAMETERS)}")
    return overrides


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def integer_range(name: str) -> tuple[int, int]:
    """The values an Integer FMU parameter can take: an fmi2Integer is 32-bit (a larger value would
    wrap silently in the FMI call); ``seed`` must also be >= 0."""
    return (SEED_MIN, SEED_MAX) if name == "seed" else (INT32_MIN, INT32_MAX)


def check_integer(name: str, value, key: str, error=None) -> int:
    """An Integer FMU parameter's value, or ``error`` (default ScenarioError) naming ``key`` and the range."""
    error = error or ScenarioError
    if isinstance(value, bool) or not isinstance(value, int):
        raise error(f"{key}: expected an integer, got {value!r}")
    lo, hi = integer_range(name)
    if not lo <= value <= hi:
        why = "the FMU's seed is a 32-bit fmi2Integer" if name == "seed" else "an fmi2Integer is 32-bit"
        raise error(f"{key}: must be in {lo}..{hi} ({why}), got {value}")
    return value


def profile_file(value: str, base_dir: Path | None) -> Path:
    """The file a profile parameter names: relative to ``base_dir`` (a scenario's folder), else where
    the FMU looks (its resources, then the working directory: fmu_src.adapter.resolve_profile_path)."""
    p = Path(value)
    if p.is_absolute():
        return p
    if base_dir is not None:
        return base_dir / p
    from fmu_src.adapter import resolve_profile_path
    return resolve_profile_path(value, str(BUNDLED_RESOURCES))


def read_profile(name: str, path: Path, key: str, error=None):
    """Parse a track profile file as the FMU does (models.plant.track), so that a bad one is reported
    before the FMU runs, naming the file and the line; returns the GradeProfile / SpeedProfile."""
    from fmu_src.adapter import PROFILE_MAX_BYTES
    from models.plant.track import GradeProfile, SpeedProfile
    error = error or ScenarioError
    if not os.path.lexists(path):
        raise error(f"{key}: file not found: {path}")
    cls = GradeProfile if name == "track.grade_profile" else SpeedProfile
    try:
        # the FMU reads the file itself (models.plant.track skips a BOM, as read_text does), and
        # only a regular file of at most its PROFILE_MAX_BYTES: a FIFO is refused here, unopened
        return cls.from_csv_text(read_text(path, InputError, reader="the FMU", limit=PROFILE_MAX_BYTES), str(path))
    except ValueError as e:             # InputError, models.plant.track.ProfileError
        raise error(f"{key}: {e}") from None


def parse_parameters(raw: dict, where: str, base_dir: Path | None) -> dict:
    """Check names, types, integer ranges and profile files against the variable table (the
    profiles are parsed as the FMU parses them); resolve profile paths against ``base_dir``."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: expected a table of \"name\" = value, got {raw!r}")
    out = {}
    for name, value in raw.items():
        key = f"{where}.\"{name}\""
        var = RAILCAR_PARAMETERS.get(name)
        if var is None:
            raise ScenarioError(f"{key}: {unknown_parameter(name, RAILCAR_PARAMETERS)}")
        if var.type == "Real":
            out[name] = _number(value, key)
        elif var.type == "Integer":
            out[name] = check_integer(name, value, key)
        else:
            if not isinstance(value, str):
                raise ScenarioError(f"{key}: expected a string, got {value!r}")
            if name in PATH_PARAMETERS and value:
                p = profile_file(value, base_dir)
                read_profile(name, p, key)
                if base_dir is not None:
                    value = str(p.resolve())
            out[name] = value
    return out


def named_parameter(message: str, names) -> str | None:
    """The first of ``names`` (FMU parameters) that a models error message names (they start with it)."""
    found = [(m.start(), n) for n in names
             for m in [re.search(rf"(?<![\w.]){re.escape(n)}(?![\w.])", message)] if m]
    return min(found)[1] if found else None


def resolve_setup(parameters: dict, where: str, ato: AtoSetup | None = None, error=None) -> ScenarioSetup:
    """Resolve and check a scenario's RailCar parameters with the FMU's own rules, before any
    FMU runs and without building a chain: the profiles are read as the FMU reads them, the
    configuration is made as RailCar makes it at initialisation (fmu_src.adapter.chain_config)
    and checked by the models' validate() in the order RailCarChain meets them
    (models.compiled.validate). ``ato``: a span scenario's ATO, moved onto the grade the
    parameters name, its configured car following their car.* where [ato.car] is silent. ``error`` (default ScenarioError) names ``where`` and the parameter."""
    from fmu_src.adapter import ChainSetup, chain_config
    from models.compiled import validate
    from models.plant.track import GradeProfile
    error = error or ScenarioError
    v = railcar_values(parameters)
    profiles = {}
    for n in PATH_PARAMETERS:
        if v[n]:
            profiles[n] = read_profile(n, profile_file(v[n], None), f"{where}.\"{n}\"", error)
    grade = profiles.get("track.grade_profile") or GradeProfile.level()
    speed = profiles.get("track.speed_profile")
    try:
        config = chain_config(v)
        validate(config, speed, 0.0)
    except (ValueError, ArithmeticError) as e:
        name = named_parameter(str(e), RAILCAR_PARAMETERS)
        if name is None:
            raise error(f"{where}: {e}") from None
        note = "" if name in parameters else f" (not set: the FMU's default {RAILCAR_PARAMETERS[name].start!r})"
        raise error(f"{where}.\"{name}\"{note}: {e}") from None
    if ato is not None and v["track.grade_profile"] != ato.grade_profile:
        ato = ato.with_grade(grade, v["track.grade_profile"])
    if ato is not None:         # the configured car follows the plant where [ato.car] is silent
        try:
            ato = ato.with_plant(v)
        except ValueError as e:
            raise error(f"{where}: the ATO's configured car: {e}") from None
    return ScenarioSetup(v, ChainSetup(config, grade, speed), ato)


def check_fmu_parameters(parameters: dict, where: str, error=None) -> None:
    """Check RailCar parameters with the FMU's own rules (``resolve_setup``); ``error`` (default
    ScenarioError) names ``where`` and the parameter."""
    resolve_setup(parameters, where, None, error)


def _table_list(data: dict, key: str, source: str) -> list:
    """An array of tables ([[driver]], [[wind]]): each entry a table."""
    raw = data.get(key, [])
    if not isinstance(raw, list):
        raise ScenarioError(f"{source}: {key}: expected an array of tables [[{key}]], got {raw!r}")
    for i, entry in enumerate(raw):
        if not isinstance(entry, dict):
            raise ScenarioError(f"{source}: {key}[{i}]: expected a table ([[{key}]]), got {entry!r}")
    return raw


_TABLE_KEYS = ("time_s", "traction_N", "brake_N")


def _time_table(raw, where: str, base_dir: Path | None) -> TimeTable:
    """[driver_table]: the shapes and types checked here, the file checked as text, then
    harness.run.driver.parse_time_table (which reads the file and checks the values)."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: expected a table with file = \"demands.csv\" or the arrays "
                            f"{', '.join(_TABLE_KEYS)}, got {raw!r}")
    for key in raw:
        if key not in ("file",) + _TABLE_KEYS:
            raise ScenarioError(f"{where}: unknown key '{key}' (known: file, {', '.join(_TABLE_KEYS)})")
    if "file" in raw:
        if len(raw) > 1:
            raise ScenarioError(f"{where}: give file or the arrays {', '.join(_TABLE_KEYS)}, not both")
        if not isinstance(raw["file"], str) or not raw["file"]:
            raise ScenarioError(f"{where}.file: expected a file name, got {raw['file']!r}")
    else:
        for key in _TABLE_KEYS:
            col = raw.get(key, [])
            if not isinstance(col, list):
                raise ScenarioError(f"{where}.{key}: expected an array of numbers, got {col!r}")
            for i, x in enumerate(col):
                _number(x, f"{where}.{key}[{i}]")
    return parse_time_table(raw, where, base_dir, ScenarioError)


def scenario_from_dict(data: dict, source: str, base_dir: Path | None = None,
                       check_ato: bool = True) -> Scenario:
    """Build and validate a Scenario from parsed TOML; ``source`` names the file in errors.
    ``check_ato`` False: a span scenario's spans are not checked by building the ATO on them
    (span-info describes the spans the ATO would refuse); such a scenario is not for running.

    The RailCar parameters are checked with the FMU's own rules (``check_fmu_parameters``), so that
    a scenario the FMU would refuse to initialise is invalid input here, before any FMU runs."""
    known = {"name", "purpose", "step_s", "duration_s", "stop_after_last_phase", "parameters",
             "driver", "driver_table", "wind", "span", "ato"}
    for key in data:
        if key not in known:
            raise ScenarioError(f"{source}: unknown key '{key}' (known: {', '.join(sorted(known))})")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{source}: 'name' must be a non-empty string")
    purpose = data.get("purpose", "")
    if not isinstance(purpose, str):
        raise ScenarioError(f"{source}: purpose: expected a string, got {purpose!r}")
    step = _number(data.get("step_s", 0.1), f"{source}: step_s")
    if step <= 0:
        raise ScenarioError(f"{source}: step_s must be > 0, got {step}")
    params = parse_parameters(data.get("parameters", {}), f"{source}: parameters", base_dir)
    phases = tuple(parse_phase(p, f"{source}: driver[{i}]", ScenarioError)
                   for i, p in enumerate(_table_list(data, "driver", source)))
    table = None
    if "driver_table" in data:
        table = _time_table(data["driver_table"], f"{source}: driver_table", base_dir)
    scripts = [k for k, given in (("[[driver]]", bool(phases)), ("[driver_table]", table is not None),
                                  ("[span]", "span" in data)) if given]
    if len(scripts) > 1:
        raise ScenarioError(f"{source}: give one of [[driver]] phases, [driver_table] or [span], "
                            f"not {' and '.join(scripts)}")
    if not scripts:
        raise ScenarioError(f"{source}: no driving script: add [[driver]] phases, a [driver_table] "
                            f"or a [span] (the ATO drives)")
    if "ato" in data and "span" not in data:
        raise ScenarioError(f"{source}: ato: tunes the ATO of a [span] scenario; this one has none")
    wind = []
    for i, w in enumerate(_table_list(data, "wind", source)):
        where = f"{source}: wind[{i}]"
        for key in w:
            if key not in ("time_s", "speed_mps"):
                raise ScenarioError(f"{where}: unknown key '{key}' (known: speed_mps, time_s)")
        wind.append(WindStep(_number(w.get("time_s"), f"{where}.time_s"),
                             _number(w.get("speed_mps"), f"{where}.speed_mps")))
    stop_after = data.get("stop_after_last_phase", True)
    if not isinstance(stop_after, bool):
        raise ScenarioError(f"{source}: stop_after_last_phase must be true or false")
    setup = resolve_setup(params, f"{source}: parameters")
    ato = _ato(data, source, setup, check_ato) if "span" in data else None
    if ato is not None and PRIOR_MASS not in params and setup.values[PRIOR_MASS] != ato.car.mass:
        # the estimator's prior mass is the configured car's (harness/run/span_scenario.py)
        params = {**params, PRIOR_MASS: ato.car.mass}
        setup = resolve_setup(params, f"{source}: parameters")
    default_duration = ato.default_duration_s if ato is not None else 200.0
    duration = _number(data.get("duration_s", default_duration), f"{source}: duration_s")
    if duration < step:
        raise ScenarioError(f"{source}: duration_s must be >= step_s, got {duration}")
    if ato is not None and duration < ato.scheduled_s:
        raise ScenarioError(f"{source}: duration_s: {duration} s ends before the schedules and dwells "
                            f"({ato.scheduled_s:g} s); leave it out for them and a minute more")
    scenario = Scenario(name=name, purpose=purpose,
                        path=Path(source) if base_dir is not None else None, parameters=params,
                        phases=phases, time_table=table, wind=tuple(sorted(wind, key=lambda w: w.time_s)),
                        step_s=step, duration_s=duration, stop_after_last_phase=stop_after, ato=ato)
    # the setup resolved by the checks above is the scenario's: nothing is read or built again
    scenario.__dict__["setup"] = ScenarioSetup(setup.values, setup.chain, ato)
    return scenario


def _ato(data: dict, source: str, setup: ScenarioSetup, check: bool = True) -> AtoSetup:
    """The ATO of a span scenario (harness.run.span_scenario.parse_ato): the span's grade is the
    RailCar parameter track.grade_profile, as the resolved setup read it (one source)."""
    v = setup.values
    return parse_ato(data, source, setup.chain.grade, float(v["track.station_dwell"]), ScenarioError,
                     v["track.grade_profile"], plant=v, check=check)


def read_toml(path: Path, error=None) -> dict:
    """Parse a TOML file (UTF-8 text, a BOM skipped: harness.textio); ``error`` (default
    ScenarioError) names the file and the reason."""
    error = error or ScenarioError
    text = read_text(path, error)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML: {e}") from None


def load_scenario(path: str | Path, check_ato: bool = True) -> Scenario:
    """Read and validate a scenario TOML file (``check_ato``: see scenario_from_dict)."""
    path = Path(path)
    return scenario_from_dict(read_toml(path), str(path), path.parent, check_ato)
