"""A line: the ATO (models.ato.controller.AtoController) over several spans in one continuous run.

One controller per span; between two spans the car stands ``dwell_s`` at the station on a
holding brake, and the passengers boarding there (``boarding_t`` [t], leaving: < 0) board at the
dwell's start. ``LineController`` reads only what an ATO can read, the estimator's outputs
(models.ato.interface.ALL_INPUTS and est.station_stops), never the plant's truth:

- a span ends when its controller has decided that the car stands at the mark (its
  ``finished``: the filtered speed at or below tuning.stand_speed for tuning.stand_time, then the
  holding brake);
- after a departure the estimator's filter still counts the distance from the previous station
  until it has recognised the station stop (est.station_stops grows), so until then the next
  controller gets filter.position less the distance at departure.

The harness's span scenarios (harness.run.span_scenario.AtoDriver) and the AtoController FMU
(fmu_src/ato_controller.py, parameter line.profile) both run a line through this one class.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Mapping, Sequence

from models.ato.controller import AtoController
from models.ato.interface import ALL_INPUTS, AtoCommand, AtoMode, AtoTuning
from models.planning.span import CarTraction, Span

STATION_STOPS = "est.station_stops"
READS = tuple(ALL_INPUTS) + (STATION_STOPS,)
"""The estimator's outputs a LineController reads, by their FMU names."""


class LineError(ValueError):
    """A span a line cannot run; ``span``: which (1-based), ``reason``: why (the message less
    its "span k: " head)."""

    def __init__(self, span: int, reason: str):
        super().__init__(f"span {span}: {reason}")
        self.span, self.reason = span, reason


@dataclass(frozen=True)
class LineSpan:
    """One span of a line: models.planning.span.Span, and for the second and later spans the
    standstill at the station before departure [s] and the passengers boarding there [t]."""
    span: Span
    dwell_s: float = 0.0
    boarding_t: float = 0.0


@dataclass(frozen=True)
class LineStep:
    """What the line's ATO did at one call (time t [s]): the span (0-based), the command, whether
    it was a station dwell between spans (the command is then the holding brake), and the
    passengers boarding now [t] (at a dwell's first call; leaving: < 0)."""
    t: float
    span: int
    command: AtoCommand
    dwell: bool = False
    payload_change: float = 0.0


def _finite(x) -> float | None:
    """``x`` as a finite float, else None (missing, not a number, NaN or infinite)."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


class _Shifted(Mapping):
    """The outputs with filter.position less ``offset`` [m] (module docstring)."""

    def __init__(self, outputs: Mapping[str, float], offset: float):
        self._o, self._offset = outputs, offset

    def __getitem__(self, name):
        v = self._o[name]
        return v - self._offset if name == "filter.position" else v

    def __iter__(self) -> Iterator[str]:
        return iter(self._o)

    def __len__(self) -> int:
        return len(self._o)


class LineController:
    """The ATO over the spans ``spans`` in order (module docstring): ``demands(t, outputs)`` gives
    each step's LineStep. ``finished``: the last span's controller stands at its mark.
    ``departures``: [s] each span's first command. ValueError (AtoController's, or a dwell or
    boarding that is not a finite number, a dwell <= 0 before a second or later span) is a
    LineError naming the span (1-based)."""

    reads = READS

    def __init__(self, spans: Sequence[LineSpan], car: CarTraction, tuning: AtoTuning | None = None):
        self.spans = tuple(spans)
        if not self.spans:
            raise ValueError("a line needs at least one span")
        for i, s in enumerate(self.spans):
            if not (math.isfinite(s.dwell_s) and math.isfinite(s.boarding_t)):
                raise LineError(i + 1, f"dwell_s = {s.dwell_s!r} s and boarding_t = "
                                       f"{s.boarding_t!r} t must be finite")
            if i > 0 and s.dwell_s <= 0.0:
                raise LineError(i + 1, f"dwell_s = {s.dwell_s!r} s: the standstill at the "
                                       f"station before it must be > 0")
        self.controllers: list[AtoController] = []
        for i, s in enumerate(self.spans):
            try:
                self.controllers.append(AtoController(s.span, car, tuning))
            except ValueError as e:
                raise LineError(i + 1, str(e)) from None
        self.k = 0                              # the span running or (dwell) just finished
        self.departures: list[float] = []
        self.finished = False
        self._dwell_from: float | None = None   # [s] the finished span's last call
        self._boarded = False
        self._offset: float | None = None       # [m] filter.position at the departure
        self._stops0: float | None = None       # est.station_stops at the first call

    @property
    def controller(self) -> AtoController:
        """The span's controller now (during a dwell: the finished span's)."""
        return self.controllers[self.k]

    @property
    def dwelling(self) -> bool:
        return self._dwell_from is not None

    def _restarted(self, outputs: Mapping[str, float]) -> bool:
        """Whether the estimator has recognised the station stops up to span k's departure (a
        missing or non-finite est.station_stops: not yet, the shift stays)."""
        stops = outputs.get(STATION_STOPS)
        if stops is None or not math.isfinite(stops) or self._stops0 is None:
            return False
        return stops - self._stops0 >= self.k

    def demands(self, t: float, outputs: Mapping[str, float]) -> LineStep:
        """The step at time ``t`` [s] from the estimator's ``outputs`` (by FMU name)."""
        if self._stops0 is None:
            stops = outputs.get(STATION_STOPS)
            if stops is not None and math.isfinite(stops):
                self._stops0 = float(stops)
        ctrl = self.controllers[self.k]
        if self._dwell_from is not None:             # standing at a station between spans
            nxt = self.spans[self.k + 1]
            hold = AtoCommand(0.0, ctrl.tuning.hold_brake * ctrl.car.brake_force_max,
                              int(AtoMode.HOLD), 0.0)
            if t - self._dwell_from < nxt.dwell_s - 1e-9:
                boarding = 0.0 if self._boarded else nxt.boarding_t
                self._boarded = True
                return LineStep(t, self.k, hold, dwell=True, payload_change=boarding)
            position = _finite(outputs.get("filter.position") if hasattr(outputs, "get") else None)
            if position is None:       # the shift needs a position: no departure until one
                return LineStep(t, self.k, hold, dwell=True, payload_change=0.0)
            self._dwell_from, self._boarded = None, False
            self.k += 1
            ctrl = self.controllers[self.k]
            self._offset = position
        view = outputs
        if self._offset is not None:
            if self._restarted(outputs):
                self._offset = None
            else:
                view = _Shifted(outputs, self._offset)
        if len(self.departures) == self.k:
            self.departures.append(t)
        cmd = ctrl.demands(t, view)
        if ctrl.finished and not self.finished:
            if self.k == len(self.controllers) - 1:
                self.finished = True
            else:
                self._dwell_from = t
        return LineStep(t, self.k, cmd)

    def events(self) -> list[tuple[int, float, str]]:
        """(span, t [s], text) of every controller's events."""
        return [(k, t, e) for k, c in enumerate(self.controllers) for t, e in c.events]
