"""Span scenarios: the ATO (models.ato.controller.AtoController) as a scenario's driver.

A scenario with a ``[span]`` table (one span) or ``[[span]]`` tables (a line of spans) instead
of ``[[driver]]`` phases is driven by the ATO through the one loop (harness.run.driver.drive), on
the RailCar FMU and on the models chain alike:

    [parameters]
    "track.grade_profile" = "../profiles/ato_span_grade.csv"   # the span's grade: one source

    [span]
    stop_m = 2150.0            # stop mark, from the previous station [m]
    schedule_s = 135.0         # running time from departure to rest at the mark [s]
    length_m = 2200.0          # optional, default stop_m
    limit_kmh = [[0, 80], [900, 60], [1300, 80]]   # [distance_m, km/h] from each distance on
    # (or limit_mps = [[0, 22.22], ...])

    [ato]                      # optional: models.ato.controller.AtoTuning fields by name
    replan_period = 2.0
    [ato.car]                  # optional: the car the ATO is configured with (CarTraction
    mass = 30.0                # fields), where it differs from the plant's (a disturbance)

**The configured car** (the car the ATO plans with, ``AtoSetup.car``) is the plant's car unless
the scenario says otherwise: each CarTraction field that is a RailCar parameter (``PLANT_CAR_FIELDS``:
mass, A0, A1, A2, gamma, length, traction_force_max, traction_power_max, brake_force_max,
adhesion_mass_fraction, adhesion_factor) takes the value ``car.<field>`` has in [parameters] (else
the FMU's default), and a field given in [ato.car] wins. The other fields (regen_*, mech_force_max,
eta_f, eta) are CarTraction's defaults unless [ato.car] gives them. The estimator's prior mass
``est.mass_initial``, when [parameters] does not set it, is the configured car's mass (the prior
coefficients est.A0_initial .. est.A2_initial keep the FMU's defaults: a deliberately rough prior
with wide standard deviations, not a car). So a user who changes the plant drives that car.

A *disturbance* (the true car differs from the one the ATO is configured for) is said explicitly:
the plant's value in [parameters], the configured one in [ato.car], e.g. ato_mass_plus20:
``"car.mass" = 36.0`` and ``[ato.car] mass = 30.0``. Wind and sensor noise ([[wind]],
sensor.*) are never part of the configured car: the ATO does not see them, it sees the
estimator's outputs.

**A line** is one continuous run over several spans, each with its own stop mark, limits and
schedule, standing ``dwell_s`` at each intermediate station (passengers boarding ``boarding_t``
at its start). Why one run and not a sequence of runs each starting from the previous run's
identified values (est.*_initial): the plant and the estimator were built for station stops
(the distance restarts at 0 on departure, the filter restarts from the station, the mass is
identified again after boarding, the resistance carries over), so one run exercises exactly
what the estimates exist for, through the same loop, and stays one library scenario that the
regression and the FMU-vs-chain checks run as they run the others. The price: the plant keys
its grade profile by the distance from the previous station, so every span of a line runs over
the same profile, from 0 to its own stop mark. The line's logic (dwells, boarding, the
filter.position shift after a departure, a span's end on the controller's own standstill
decision) is models.ato.line.LineController, the one the AtoController FMU runs too, so a line is
also a system (``python -m harness system build``, docs/systems.md "A line").
"""
from __future__ import annotations

import logging
import math
from contextlib import contextmanager
from dataclasses import dataclass, fields, replace
from typing import Callable, Mapping

from models.ato.controller import AtoController
from models.ato.interface import AtoTuning
from models.ato.line import READS as LINE_READS
from models.ato.line import LineController, LineSpan, LineStep
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile
from models.units import kmh_to_mps

from fmu_src.variables import RAILCAR, variables_for
from harness.run.phases import Demands

SPAN_KEYS = ("stop_m", "schedule_s", "length_m", "limit_kmh", "limit_mps", "dwell_s", "boarding_t")
LINE_ONLY = ("dwell_s", "boarding_t")     # the station before a span of a line, not the first
END_MARGIN_S = 60.0    # [s] default duration_s: the schedules and dwells plus this
PRIOR_MASS = "est.mass_initial"     # the estimator's prior mass: the configured car's unless set

_RAILCAR_NAMES = frozenset(v.name for v in variables_for(RAILCAR) if v.causality == "parameter")
PLANT_CAR_FIELDS = tuple(f.name for f in fields(CarTraction) if f.init and f"car.{f.name}" in _RAILCAR_NAMES)
"""The CarTraction fields that are RailCar parameters (``car.<field>``, same unit): the configured
car takes the plant's value of each unless [ato.car] gives it (module docstring)."""


def configured_car(plant: Mapping[str, float] | None, given: Mapping[str, float]) -> CarTraction:
    """The car the ATO is configured with: the [ato.car] values ``given`` (CarTraction fields), and
    for each PLANT_CAR_FIELDS field not given the plant's ``car.<field>`` from ``plant`` (every
    RailCar parameter by name; None: CarTraction's defaults). ValueError from CarTraction."""
    from_plant = {} if plant is None else {
        f: float(plant[f"car.{f}"]) for f in PLANT_CAR_FIELDS if f not in given and f"car.{f}" in plant}
    return CarTraction(**{**from_plant, **given})


@dataclass(frozen=True)
class AtoSetup:
    """The ATO side of a span scenario: the spans in order, the tuning, the configured car."""
    spans: tuple[LineSpan, ...]
    tuning: AtoTuning
    car: CarTraction
    grade_profile: str = ""      # the track.grade_profile value the spans' grade was read from
    car_given: tuple[str, ...] = ()   # the CarTraction fields [ato.car] set (the others follow the plant)

    def controllers(self) -> list[AtoController]:
        return [AtoController(s.span, self.car, self.tuning) for s in self.spans]

    def with_grade(self, grade: GradeProfile, grade_profile: str) -> "AtoSetup":
        """The same spans over another grade (read from ``grade_profile``)."""
        spans = tuple(replace(s, span=Span(s.span.length, s.span.schedule, s.span.stop, grade,
                                           s.span.limit_distances, s.span.limit_speeds))
                      for s in self.spans)
        return replace(self, spans=spans, grade_profile=grade_profile)

    def with_plant(self, plant: Mapping[str, float]) -> "AtoSetup":
        """The same ATO configured for the plant ``plant`` (every RailCar parameter by name): the
        fields [ato.car] did not give follow its car.* (``configured_car``); self if unchanged."""
        kept = [f.name for f in fields(CarTraction)
                if f.init and (f.name in self.car_given or f.name not in PLANT_CAR_FIELDS)]
        car = configured_car(plant, {name: getattr(self.car, name) for name in kept})
        return self if car == self.car else replace(self, car=car)

    @property
    def scheduled_s(self) -> float:
        """[s] the schedules and the dwells: the run's least duration."""
        return sum(s.span.schedule + s.dwell_s for s in self.spans)

    @property
    def default_duration_s(self) -> float:
        return self.scheduled_s + END_MARGIN_S


def _num(value, where: str, error) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise error(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _limits(raw: dict, where: str, error) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """limit_kmh or limit_mps: [[distance_m, speed], ...] -> (distances [m], speeds [m/s])."""
    given = [k for k in ("limit_kmh", "limit_mps") if k in raw]
    if len(given) != 1:
        raise error(f"{where}: give the speed limits as limit_kmh or limit_mps "
                    f"([[distance_m, speed], ...]), {'not both' if given else 'none given'}")
    key = given[0]
    rows = raw[key]
    if not isinstance(rows, list) or not rows:
        raise error(f"{where}.{key}: expected a non-empty array of [distance_m, speed], got {rows!r}")
    d, v = [], []
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 2:
            raise error(f"{where}.{key}[{i}]: expected [distance_m, speed], got {row!r}")
        x = _num(row[0], f"{where}.{key}[{i}][0]", error)
        s = _num(row[1], f"{where}.{key}[{i}][1]", error)
        if s <= 0:
            raise error(f"{where}.{key}[{i}][1]: a speed limit must be > 0, got {s}")
        d.append(x)
        v.append(kmh_to_mps(s) if key == "limit_kmh" else s)
    if d[0] != 0.0:
        raise error(f"{where}.{key}[0]: the first limit must start at distance 0, got {d[0]}")
    for i in range(1, len(d)):
        if d[i] <= d[i - 1]:
            raise error(f"{where}.{key}[{i}]: distances must increase ({d[i]} after {d[i - 1]})")
    return tuple(d), tuple(v)


def parse_span(raw, where: str, grade: GradeProfile, first: bool, error) -> LineSpan:
    """One [span] table -> LineSpan (models.planning.span.Span over ``grade``); ``error`` names ``where``."""
    if not isinstance(raw, dict):
        raise error(f"{where}: expected a table, got {raw!r}")
    for key in raw:
        if key not in SPAN_KEYS:
            raise error(f"{where}: unknown key '{key}' (known: {', '.join(SPAN_KEYS)})")
        if first and key in LINE_ONLY:
            raise error(f"{where}.{key}: only for the second and later spans of a line (the "
                        f"station before them)")
    for key in ("stop_m", "schedule_s"):
        if key not in raw:
            raise error(f"{where}: {key} is missing")
    stop = _num(raw["stop_m"], f"{where}.stop_m", error)
    schedule = _num(raw["schedule_s"], f"{where}.schedule_s", error)
    length = _num(raw["length_m"], f"{where}.length_m", error) if "length_m" in raw else stop
    if stop <= 0:
        raise error(f"{where}.stop_m: must be > 0, got {stop}")
    if stop > length:
        raise error(f"{where}.stop_m: {stop} m is beyond the span (length_m = {length} m)")
    if schedule <= 0:
        raise error(f"{where}.schedule_s: must be > 0, got {schedule}")
    d, v = _limits(raw, where, error)
    for i, x in enumerate(d):
        if x >= length:
            raise error(f"{where}: speed limit {i} starts at {x} m, not inside the span [0, {length}) m")
    dwell = _num(raw.get("dwell_s", 0.0), f"{where}.dwell_s", error)
    boarding = _num(raw.get("boarding_t", 0.0), f"{where}.boarding_t", error)
    if not first and dwell <= 0:
        raise error(f"{where}.dwell_s: the standstill at the station before this span is missing "
                    f"or <= 0 (it must be at least track.station_dwell)")
    try:
        span = Span(length, schedule, stop=stop, grade=grade, limit_distances=d, limit_speeds=v)
    except ValueError as e:
        raise error(f"{where}: {e}") from None
    return LineSpan(span, dwell, boarding)


def _typed_fields(cls, raw: dict, where: str, error, skip=()) -> dict:
    """The fields of dataclass ``cls`` given in ``raw``: known names, true/false for a bool
    field, a number for the others (the dataclass checks the values)."""
    types = {f.name: f.type for f in fields(cls) if f.init}
    out = {}
    for key, value in raw.items():
        if key in skip:
            continue
        if key not in types:
            raise error(f"{where}: unknown key '{key}' (known: {', '.join(list(types) + list(skip))})")
        if types[key] == "bool":
            if not isinstance(value, bool):
                raise error(f"{where}.{key}: expected true or false, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise error(f"{where}.{key}: expected a number, got {value!r}")
        out[key] = value
    return out


def parse_ato(data: dict, source: str, grade: GradeProfile, station_dwell: float, error,
              grade_profile: str = "", plant: Mapping[str, float] | None = None,
              check: bool = True) -> AtoSetup:
    """The [span] / [[span]] and [ato] tables of a scenario -> AtoSetup. Every controller is
    built once here, so that an infeasible schedule, a limit the brakes cannot keep or bad
    tuning (AtoController's ValueError) is invalid input naming the file and the span.
    ``plant``: every RailCar parameter by name (the scenario's, else the default): the configured
    car follows it where [ato.car] is silent (``configured_car``); None: CarTraction's defaults.
    ``check`` False builds no controller (``harness span-info`` describes a span the ATO refuses)."""
    raw_ato = data.get("ato", {})
    if not isinstance(raw_ato, dict):
        raise error(f"{source}: ato: expected a table [ato], got {raw_ato!r}")
    try:
        tuning = AtoTuning(**_typed_fields(AtoTuning, raw_ato, f"{source}: ato", error, skip=("car",)))
    except ValueError as e:      # "tuning.<field> must ..."
        raise error(f"{source}: ato: {e}") from None
    except TypeError as e:
        raise error(f"{source}: ato: {e}") from None
    raw_car = raw_ato.get("car", {})
    if not isinstance(raw_car, dict):
        raise error(f"{source}: ato.car: expected a table [ato.car], got {raw_car!r}")
    given = _typed_fields(CarTraction, raw_car, f"{source}: ato.car", error)
    try:
        car = configured_car(plant, given)
    except ValueError as e:      # "car.<field> must ..."
        followed = [f for f in PLANT_CAR_FIELDS if f not in given]
        raise error(f"{source}: ato.car: {e} (the configured car: [ato.car] and, for "
                    f"{', '.join(followed) or 'no field'}, the plant's car.* parameters)") from None
    raw = data["span"]
    line = isinstance(raw, list)
    tables = raw if line else [raw]
    if not tables:
        raise error(f"{source}: span: no spans given")
    spans = []
    for i, t in enumerate(tables):
        where = f"{source}: span[{i}]" if line else f"{source}: span"
        s = parse_span(t, where, grade, i == 0, error)
        if i > 0 and s.dwell_s < station_dwell:
            raise error(f"{where}.dwell_s: {s.dwell_s} s is shorter than track.station_dwell = "
                        f"{station_dwell} s: the plant and the estimator would not see a station")
        try:
            if check:
                AtoController(s.span, car, tuning)
        except ValueError as e:
            raise error(f"{where}: the ATO cannot run this span: {e}") from None
        spans.append(s)
    return AtoSetup(tuple(spans), tuning, car, grade_profile, tuple(given))


# ------------------------------------------------------------------------------ the driver

AtoStep = LineStep
"""What the ATO did at one call (models.ato.line.LineStep): t [s], the span (0-based), the command,
whether it was a station dwell between spans (the holding brake), the payload change [t]."""


class _ControllerLog(logging.Handler):
    """Takes models.ato.controller's log records while an AtoDriver calls a controller (``into``)
    and appends them to that driver's lines; the logger neither propagates to the root nor
    reaches Python's last-resort stderr handler meanwhile. The model keeps its logger (a host
    without this harness still sees the warnings); the harness decides where they go."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.logger = logging.getLogger("models.ato.controller")
        self.sink: list[str] | None = None
        self.prefix: Callable[[], str] = str

    def emit(self, record: logging.LogRecord) -> None:
        if self.sink is not None:
            self.sink.append(self.prefix() + record.getMessage())

    @contextmanager
    def into(self, sink: list[str], prefix: Callable[[], str]):
        """``prefix()`` at each record: the span that logs (a call can switch spans)."""
        log, was = self.logger, self.logger.propagate
        self.sink, self.prefix = sink, prefix
        log.addHandler(self)
        log.propagate = False
        try:
            yield
        finally:
            log.removeHandler(self)
            log.propagate = was
            self.sink = None


_CONTROLLER_LOG = _ControllerLog()


class AtoDriver:
    """A harness.run.driver Driver over a span scenario's spans: models.ato.line.LineController
    (one AtoController per span, a holding brake of ``dwell_s`` between them, ``boarding_t``
    boarding at its start), the same line logic the AtoController FMU runs. It records every
    call (``steps``: AtoStep) for the metrics and the report.

    It reads what an ATO can read, the estimator's outputs (``reads``: models.ato.interface.INPUTS
    and est.station_stops), never the plant's truth: a span ends when its controller has decided
    that the car stands (models.ato.line). ``finished``: the last span's controller stands at
    its mark.

    What the controllers log (models.ato.controller's logger: "ATO at t = 10.70 s: estimates not
    usable ...") goes to ``log_lines``, "<scenario>: span k: ..." (RunResult.driver_log), not to
    stderr: the command that wants it prints it, naming the scenario."""

    reads = LINE_READS

    def __init__(self, setup: AtoSetup, name: str = ""):
        self.setup = setup
        self.name = name                       # the scenario's, first on every log line
        self.line = LineController(setup.spans, setup.car, setup.tuning)
        self.controllers = self.line.controllers
        self.steps: list[AtoStep] = []
        self.log_lines: list[str] = []         # the controllers' log (module docstring of _ControllerLog)

    @property
    def departures(self) -> list[float]:
        """[s] each span's first command."""
        return self.line.departures

    @property
    def finished(self) -> bool:
        return self.line.finished

    def _log_prefix(self) -> str:
        return f"{self.name or 'ATO'}: span {self.line.k + 1}: "

    def demands(self, t: float, outputs: Mapping[str, float]) -> Demands:
        with _CONTROLLER_LOG.into(self.log_lines, self._log_prefix):
            step = self.line.demands(t, outputs)
        self.steps.append(step)
        return Demands(step.command.traction, step.command.brake, step.payload_change)

    def events(self) -> list[tuple[int, float, str]]:
        """(span, t [s], text) of every controller's events."""
        return self.line.events()


def replay_steps(scenario, result) -> AtoDriver:
    """A fresh AtoDriver fed the outputs a run of ``scenario`` recorded (``result``, every row
    but the last, as the loop fed them): the controllers read nothing but those outputs, so this
    gives the run's commands again (tests check them equal to the run's own, bit for bit; the
    run's own are in ``result.driver_steps``, the reports read those)."""
    driver = AtoDriver(scenario.ato_setup(), scenario.name)
    names = [n for n in driver.reads if n in result.signals]
    missing = set(driver.reads) - set(names)
    if missing:
        raise ValueError(f"{scenario.name}: the run did not record {', '.join(sorted(missing))}")
    cols = [result.signals[n] for n in names]
    for j in range(len(result.time)):
        driver.demands(float(result.time[j]), {n: float(c[j]) for n, c in zip(names, cols)})
        if driver.finished:
            break
    return driver
