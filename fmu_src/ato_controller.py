"""AtoController FMU: the train operation of one span or a line (models.ato.line) closed around the estimator.

Each doStep(t, h) reads the estimator's outputs at t (inputs of the same names), asks
models.ato.line.LineController (one models.ato.controller.AtoController per span) for the command
and holds it as the outputs for the next step: in a system the car applies it one communication
step later (an actuator delay of h). After initialisation the outputs are a holding brake.

A line: the first span is span.*, the later ones line.profile's rows (stop mark, length,
schedule, the dwell at the station before and the passengers boarding there), their limits in
line.speed_limit_profile, every span over span.grade_profile from its station (as RailCar keys
its grade by the distance from the previous station). Between two spans the FMU holds the brake
for the dwell; ato.payload (connect it to RailCar's car.payload) adds the boarding at the dwell's
start; ato.span says which span runs. The estimator's est.station_stops must be connected: until
it grows after a departure, the next span's controller gets filter.position less the distance
at departure. Empty line.profile (the default): one span, as before.

Bad parameters fail exitInitializationMode with a message naming them (an infeasible or too
long schedule, a stop mark that is not a positive distance or lies beyond the span, a limit the
brakes cannot keep, a re-planning grid too fine for the span, a tuning value out of its bounds,
a profile file that cannot be read, a line file with a bad row: its parameter, file and line). A step whose size or time is bad is discarded as RailCar's
is (models.chain.check_step: h finite, > 0 and <= 3600 s; the time finite and continuing the
last step's end), logged, and nothing changes. Bad inputs never fail a step: an input that is
missing, not finite, outside physics or inconsistent with the others gives the safe brake
(ato.mode 9) and a warning naming the input and its value (models/ato/supervision.py).
"""
import math
import re
from dataclasses import dataclass

from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

from fmu_src.adapter import (ParameterError, initialise, not_initialised, open_ato,
                             read_profile_text, register_variables, resolve_profile_path)
from fmu_src.variables import ATO, variables_for
from models.ato.interface import AtoMode
from models.ato.line import LineController, LineError, LineSpan
from models.chain import StepRejected, check_step
from models.plant.track import ProfileError, csv_number_rows

READS = tuple(v.name for v in variables_for(ATO) if v.causality == "input")
PROFILE_PARAMETERS = ("span.grade_profile", "span.speed_limit_profile", "line.profile",
                      "line.speed_limit_profile")
LINE_COLUMNS = ("stop_m", "length_m", "schedule_s", "dwell_s", "boarding_t")
LINE_LIMIT_COLUMNS = ("span", "distance_m", "speed_limit_mps")


@dataclass(frozen=True)
class LineRow:
    """One row of line.profile: a span after the first, and the file line it came from."""
    stop: float          # [m]
    length: float        # [m] 0: stop
    schedule: float      # [s]
    dwell: float         # [s]
    boarding: float      # [t]
    line: int            # 1-based line of the file


def _csv_rows(text: str, where: str, columns: tuple[str, ...]):
    """(line number, finite floats) of each data row of a CSV with exactly the header ``columns``
    (models.plant.track.csv_number_rows, the profiles' reader); ParameterError names ``where``
    (parameter: file) and the line."""
    try:
        yield from csv_number_rows(text, where, columns)
    except ProfileError as e:
        raise ParameterError(str(e)) from None


def read_line_profile(text: str, path: str) -> list[LineRow]:
    """line.profile's rows (LINE_COLUMNS), each checked: stop_m > 0, length_m 0 or >= stop_m,
    schedule_s > 0, dwell_s > 0. ParameterError names line.profile, the file and the line."""
    where = f"line.profile: {path}"
    rows = []
    for lineno, (stop, length, schedule, dwell, boarding) in _csv_rows(text, where, LINE_COLUMNS):
        if stop <= 0.0:
            raise ParameterError(f"{where}: line {lineno}: stop_m must be > 0, got {stop}")
        if length != 0.0 and length < stop:
            raise ParameterError(f"{where}: line {lineno}: length_m = {length} m is shorter than "
                                 f"stop_m = {stop} m (0: stop_m)")
        if schedule <= 0.0:
            raise ParameterError(f"{where}: line {lineno}: schedule_s must be > 0, got {schedule}")
        if dwell <= 0.0:
            raise ParameterError(f"{where}: line {lineno}: dwell_s must be > 0 (the standstill at "
                                 f"the station before the span), got {dwell}")
        rows.append(LineRow(stop, length, schedule, dwell, boarding, lineno))
    if not rows:
        raise ParameterError(f"{where}: no span: give a row per span after the first, or leave "
                             f"line.profile empty for one span")
    return rows


def read_line_limits(text: str, path: str, spans: int) -> dict[int, tuple[list[float], list[float]]]:
    """line.speed_limit_profile: {span (2 ..): (distances [m], limits [m/s])}; spans in
    increasing order, each's distances from 0 increasing, limits > 0, a span 2 .. ``spans``.
    ParameterError names line.speed_limit_profile, the file and the line."""
    where = f"line.speed_limit_profile: {path}"
    out: dict[int, tuple[list[float], list[float]]] = {}
    last = 1
    for lineno, (span, distance, limit) in _csv_rows(text, where, LINE_LIMIT_COLUMNS):
        k = int(span)
        if k != span or not 2 <= k <= spans:
            raise ParameterError(f"{where}: line {lineno}: span must be one of line.profile's "
                                 f"spans, 2 .. {spans}, got {span:g}")
        if k < last:
            raise ParameterError(f"{where}: line {lineno}: span {k} after span {last}: give each "
                                 f"span's rows together, in span order")
        d, v = out.setdefault(k, ([], []))
        if not d and distance != 0.0:
            raise ParameterError(f"{where}: line {lineno}: span {k}'s first limit must start at "
                                 f"distance_m 0, got {distance}")
        if d and distance <= d[-1]:
            raise ParameterError(f"{where}: line {lineno}: distance_m must increase within a span "
                                 f"({distance} after {d[-1]})")
        if limit <= 0.0:
            raise ParameterError(f"{where}: line {lineno}: speed_limit_mps must be > 0, got {limit}")
        d.append(distance)
        v.append(limit)
        last = k
    return out


def open_line(v: dict, resources) -> LineController:
    """AtoController's parameter values -> models.ato.line.LineController: span.* (open_ato: its
    checks and messages) and line.profile's spans over span.grade_profile. ParameterError names
    the parameter, and for a line file's row its file and line (a span the ATO cannot run too)."""
    from models.planning.span import Span
    first = open_ato(v, resources)
    spans = [LineSpan(first.span)]
    rows: list[LineRow] = []
    line_src = read_profile_text(v, "line.profile", resources)
    limits_src = read_profile_text(v, "line.speed_limit_profile", resources)
    if line_src is None:
        if limits_src is not None:
            raise ParameterError(f"line.speed_limit_profile: {limits_src[1]}: given without "
                                 f"line.profile (the spans it limits)")
        return LineController(spans, first.car, first.tuning)
    rows = read_line_profile(*line_src)
    limits = read_line_limits(*limits_src, len(rows) + 1) if limits_src else {}
    grade = first.span.grade
    for k, row in enumerate(rows, start=2):
        d, lim = limits.get(k, ([0.0], [v["span.speed_limit"]]))
        where = f"line.profile: {line_src[1]}: line {row.line} (span {k})"
        try:
            span = Span(row.length or row.stop, row.schedule, row.stop, grade, tuple(d), tuple(lim))
        except ValueError as e:
            raise ParameterError(f"{where}: {_line_names(str(e), k, k in limits)}") from None
        spans.append(LineSpan(span, row.dwell, row.boarding))
    try:
        return LineController(spans, first.car, first.tuning)
    except LineError as e:         # AtoController's: an infeasible schedule, a limit too low, ..
        row = rows[e.span - 2]
        raise ParameterError(f"line.profile: {line_src[1]}: line {row.line} (span {e.span}): the "
                             f"ATO cannot run this span: "
                             f"{_line_names(e.reason, e.span, e.span in limits)}") from None


def _line_names(message: str, span: int, limited: bool) -> str:
    """models' messages say tuning.x and span.limit_speeds[k]: name the FMU's parameters."""
    def limit(m):
        return (f"line.speed_limit_profile span {span} row {int(m.group(2)) + 1}" if limited
                else "span.speed_limit")
    message = re.sub(r"span\.limit_(speeds|distances)\[(\d+)\]", limit, message)
    return message.replace("tuning.", "ato.")


def check_span_parameters(v: dict, resources) -> None:
    """The span.* values open_ato combines (span.length 0 stands for span.stop), each checked
    under its own name first; the profile file names resolved (a name the file system refuses,
    too long or with a NUL, names the parameter). Raises ParameterError."""
    stop, length, schedule = v["span.stop"], v["span.length"], v["span.schedule"]
    if not (math.isfinite(stop) and stop > 0.0):
        raise ParameterError(f"span.stop = {stop!r} m must be finite and > 0 (the stop mark's "
                             f"distance from the departure station)")
    if not (math.isfinite(length) and length >= 0.0):
        raise ParameterError(f"span.length = {length!r} m must be finite and >= 0 (0: span.stop)")
    if not (math.isfinite(schedule) and schedule > 0.0):
        raise ParameterError(f"span.schedule = {schedule!r} s must be finite and > 0")
    for name in PROFILE_PARAMETERS:
        raw = v[name]
        if not raw:
            continue
        try:
            path = resolve_profile_path(raw, resources)
            path.is_file()
        except (OSError, ValueError) as e:
            shown = raw if len(raw) <= 80 else f"{raw[:60]}...({len(raw)} characters)"
            reason = getattr(e, "strerror", None) or str(e)
            raise ParameterError(f"{name}: cannot use '{shown}' as a file name: {reason}") from None


class AtoController(Fmi2Slave):
    author = "rail-car FMU team"
    description = ("Train operation for one span: energy-efficient running-time regulator, targeted "
                   "stopping with relay-staged EP brake, speed supervision (Meleshin 2011, Sidorenko 1997)")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = register_variables(self, ATO)
        self.line: LineController | None = None
        self.logged = 0           # the line's events logged so far
        self.start_time = 0.0
        self.time = None          # [s] the end of the last step taken (the next one starts there)

    @property
    def controller(self):
        """The span's models.ato.controller.AtoController now (None before initialisation)."""
        return None if self.line is None else self.line.controller

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.start_time = float(start_time)

    def _build(self):
        check_span_parameters(self.values, self.resources)
        line = open_line(self.values, self.resources)
        ctrl = line.controller
        hold = ctrl.tuning.hold_brake * ctrl.car.brake_force_max
        self.values["ato.payload"], self.values["ato.span"] = 0.0, 1
        self._publish(ctrl, 0.0, hold, int(AtoMode.HOLD), 0.0, 0)
        return line

    def exit_initialization_mode(self):
        self.line = initialise(self._build)
        self.time = self.start_time

    def _publish(self, ctrl, traction, brake, mode, planned, stage):
        v = self.values
        v["traction_force_demand"], v["brake_force_demand"] = float(traction), float(brake)
        v["ato.mode"], v["ato.planned_speed"], v["ato.ep_stage"] = int(mode), float(planned), int(stage)
        v["ato.finished"] = bool(ctrl.finished)
        v["ato.replans"] = int(ctrl.replans)
        v["ato.using_estimates"] = ctrl.using_estimates
        v["ato.predicted_arrival"] = float(ctrl.plan.arrival)

    def _check_step(self, current_time, step_size) -> None:
        """RailCar's rules (models.chain): raise StepRejected naming the bad size or time."""
        check_step(current_time, step_size)
        if abs(current_time - self.time) > 1e-9 * max(1.0, abs(current_time)):
            raise StepRejected(f"current time {current_time!r} s does not continue the FMU's "
                               f"time {self.time!r} s")

    def do_step(self, current_time, step_size):
        """True, or Fmi2Status.warning (also true) when the command is the safe brake for a bad
        input; False (fmi2Discard) for a bad step size or time, with nothing changed."""
        line = self.line
        if line is None:
            return not_initialised(self)
        try:
            self._check_step(current_time, step_size)
        except StepRejected as e:
            self.log(f"step discarded: {e}", Fmi2Status.discard)
            return False
        try:
            step = line.demands(current_time, {n: self.values[n] for n in READS})
            cmd = step.command
            self.values["ato.payload"] += step.payload_change
            self.values["ato.span"] = step.span + 1
            self._publish(line.controller, cmd.traction, cmd.brake, cmd.mode, cmd.planned_speed,
                          cmd.ep_stage)
        except Exception as e:   # models.ato never raises here; if it did, brake, never crash
            self.log(f"t = {current_time:.3f} s: {type(e).__name__}: {e}: safe brake", Fmi2Status.error)
            ctrl = line.controller
            safe = ctrl.tuning.safe_brake * ctrl.car.brake_force_max
            self._publish(ctrl, 0.0, safe, int(AtoMode.SAFE), 0.0, 0)
        events = line.events()
        many = len(line.controllers) > 1
        for k, t, reason in events[self.logged:]:
            self.log(f"t = {t:.3f} s: {f'span {k + 1}: ' if many else ''}{reason}", Fmi2Status.warning)
        self.logged = len(events)
        self.time = current_time + step_size
        return Fmi2Status.warning if self.values["ato.mode"] == AtoMode.SAFE else True
