"""models.ato.line.LineController: a line's dwell, boarding, filter.position shift and span end,
first with stand-in span controllers (the line logic alone, exact), then closed around the
compiled RailCar chain (the span end and the shift without the plant's truth)."""
from __future__ import annotations

import re

import pytest

from models.ato.interface import ALL_INPUTS, INPUTS, AtoCommand, AtoMode, AtoTuning
from models.ato.line import READS, LineController, LineSpan
from models.planning.span import CarTraction, Span

CAR = CarTraction()
TUNING = AtoTuning()
STEP = 0.1                                    # [s]
SHORT = Span(900.0, 75.0, stop=850.0)         # level, 80 km/h: 900 m in 75 s is easy
NEXT = Span(700.0, 65.0, stop=650.0)


class StandIn:
    """A span controller stand-in: finished once it has seen filter.position >= ``stop`` at
    filter.speed 0; records what it saw."""

    def __init__(self, stop: float):
        self.stop, self.finished, self.events = stop, False, []
        self.tuning, self.car = TUNING, CAR
        self.seen: list[tuple[float, float]] = []      # (t, filter.position)

    def demands(self, t, outputs):
        self.seen.append((t, outputs["filter.position"]))
        if outputs["filter.speed"] == 0.0 and outputs["filter.position"] >= self.stop:
            self.finished = True
        mode = AtoMode.HOLD if self.finished else AtoMode.TG
        return AtoCommand(0.0 if self.finished else 1000.0, 500.0 if self.finished else 0.0,
                          int(mode), 0.0)


def _outputs(speed: float, position: float, stops: int, **extra) -> dict:
    out = {n: 0.0 for n in INPUTS}
    out.update({"filter.speed": speed, "filter.position": position, "est.station_stops": stops,
                "est.mass": 30.0, **extra})
    return out


def _stand_in_line(dwell: float = 3.0, boarding: float = 4.0) -> tuple[LineController, list[StandIn]]:
    line = LineController([LineSpan(SHORT), LineSpan(NEXT, dwell, boarding)], CAR, TUNING)
    stand_ins = [StandIn(850.0), StandIn(650.0)]
    line.controllers[:] = stand_ins
    return line, stand_ins


def test_reads_are_the_estimators_outputs_only():
    """The line reads the controller's inputs (ALL_INPUTS: the estimates and their stated
    uncertainty) and est.station_stops, nothing of the plant."""
    assert READS == tuple(ALL_INPUTS) + ("est.station_stops",)
    assert not any(n.startswith("car.") for n in READS)


def test_dwell_boarding_and_departure_follow_the_controllers_finish():
    """The span ends at the call where its controller finishes (a car.speed in the outputs saying
    the car moves changes nothing); the next calls are the holding brake for dwell_s, the
    boarding at the first of them only; the next span's first command comes at dwell_s after
    the finish, and that is its departure."""
    line, (first, second) = _stand_in_line(dwell=3.0, boarding=4.0)
    steps = [line.demands(0.0, _outputs(0.0, 0.0, 0))]
    steps.append(line.demands(0.1, _outputs(10.0, 400.0, 0, **{"car.speed": 10.0})))
    steps.append(line.demands(0.2, _outputs(0.0, 850.0, 0, **{"car.speed": 0.3})))   # finishes
    assert first.finished and not line.finished and line.dwelling
    t = 0.3
    while t < 0.2 + 3.0 - 1e-9:
        steps.append(line.demands(t, _outputs(0.0, 850.0, 0)))
        t = round(t + STEP, 10)
    dwell = [s for s in steps if s.dwell]
    assert len(dwell) == 29                       # 0.3 .. 3.1 s
    assert all(s.command.mode == AtoMode.HOLD and s.command.traction == 0.0 for s in dwell)
    assert dwell[0].command.brake == TUNING.hold_brake * CAR.brake_force_max
    assert [s.payload_change for s in dwell] == [4.0] + [0.0] * 28
    assert [s.span for s in dwell] == [0] * 29
    assert len(second.seen) == 0
    depart = line.demands(3.2, _outputs(0.0, 850.0, 0))
    assert not depart.dwell and depart.span == 1 and depart.payload_change == 0.0
    assert line.departures == [0.0, 3.2]
    assert sum(s.payload_change for s in steps) == 4.0


def test_position_is_shifted_until_the_estimator_recognises_the_station():
    """After departure the next controller sees filter.position less the distance at departure
    until est.station_stops has grown by the span's index (counted from the first call's value),
    then the filter's own distance; the first span never sees a shift."""
    line, (first, second) = _stand_in_line(dwell=0.3)
    line.demands(0.0, _outputs(0.0, 0.0, 2))      # the estimator had counted 2 stops before
    line.demands(0.1, _outputs(0.0, 850.0, 2))     # finishes
    line.demands(0.2, _outputs(0.0, 850.5, 2))
    line.demands(0.3, _outputs(0.0, 850.5, 2))
    line.demands(0.4, _outputs(0.0, 850.5, 2))     # departs at 850.5 m
    line.demands(0.5, _outputs(1.0, 851.0, 2))
    line.demands(0.6, _outputs(1.0, 0.7, 3))       # recognised: the filter restarted at 0
    line.demands(0.7, _outputs(1.0, 0.8, 3))
    assert first.seen == [(0.0, 0.0), (0.1, 850.0)]
    assert second.seen == [(0.4, 0.0), (0.5, 0.5), (0.6, 0.7), (0.7, 0.8)]


def test_a_missing_station_count_keeps_the_shift():
    """Without est.station_stops (missing or NaN) the shift stays: never a jump back by a
    station's distance on a guess."""
    line, (_, second) = _stand_in_line(dwell=0.2)
    line.demands(0.0, _outputs(0.0, 850.0, 0))
    line.demands(0.1, _outputs(0.0, 850.0, 0))     # the one dwell call
    line.demands(0.2, _outputs(0.0, 850.0, 0))     # departs
    out = _outputs(2.0, 870.0, 0)
    out["est.station_stops"] = float("nan")
    line.demands(0.3, out)
    del out["est.station_stops"]
    line.demands(0.4, out)
    assert second.seen == [(0.2, 0.0), (0.3, 20.0), (0.4, 20.0)]


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), None, "x"])
def test_no_departure_without_a_position_to_shift_by(bad):
    """filter.position missing or not a finite number when the dwell ends: the line holds the
    car (HOLD, no boarding again) until a position comes, then departs from it; it once took a
    NaN as the shift (the safe brake for ever, the line never finished) or raised KeyError."""
    line, (_, second) = _stand_in_line(dwell=0.2, boarding=4.0)
    line.demands(0.0, _outputs(0.0, 850.0, 0))       # finishes
    assert line.demands(0.1, _outputs(0.0, 850.0, 0)).payload_change == 4.0   # the dwell call
    for t in (0.2, 0.3):
        out = _outputs(0.0, 850.0, 0)
        if bad is None:
            del out["filter.position"]
        else:
            out["filter.position"] = bad
        step = line.demands(t, out)
        assert step.dwell and step.span == 0 and step.payload_change == 0.0
        assert step.command.mode == AtoMode.HOLD and step.command.traction == 0.0
    depart = line.demands(0.4, _outputs(0.0, 850.5, 0))
    assert not depart.dwell and depart.span == 1 and line.departures == [0.0, 0.4]
    line.demands(0.5, _outputs(1.0, 851.0, 0))
    assert second.seen == [(0.4, 0.0), (0.5, 0.5)]


def test_the_last_span_finishes_the_line_and_a_one_span_line_is_one_controller():
    """One span: the line's commands are a bare AtoController's, and the line is finished
    exactly when the controller is."""
    from models.ato.controller import AtoController
    line = LineController([LineSpan(SHORT)], CAR, TUNING)
    bare = AtoController(SHORT, CAR, TUNING)
    for k, (v, s) in enumerate([(0.0, 0.0), (3.0, 1.0), (5.0, 10.0)]):
        out = _outputs(v, s, 0)
        assert line.demands(k * STEP, out).command == bare.demands(k * STEP, out)
    assert not line.finished


@pytest.mark.parametrize("spans, message", [
    ([], "a line needs at least one span"),
    ([LineSpan(SHORT), LineSpan(NEXT, 0.0)], "span 2: dwell_s = 0.0 s"),
    ([LineSpan(SHORT), LineSpan(NEXT, 30.0, float("nan"))], "span 2: dwell_s = 30.0 s and boarding_t = nan"),
    ([LineSpan(SHORT), LineSpan(Span(700.0, 20.0, stop=650.0), 30.0)], "span 2: "),
])
def test_bad_lines_are_refused_naming_the_span(spans, message):
    """No span, a dwell <= 0 or a non-finite boarding before a later span, a schedule the
    ATO cannot run: ValueError naming the span (1-based)."""
    with pytest.raises(ValueError, match="^" + re.escape(message)):
        LineController(spans, CAR, TUNING)


def test_closed_loop_line_ends_each_span_without_the_truth():
    """Two spans on the compiled RailCar chain, the line reading only its READS: each span
    ends standing within 0.3 m (Sidorenko 1997) of its own mark, counted in the plant's
    distance from the station it left; the boarding reaches the plant's mass; the second span
    departs dwell_s after the first span's finish."""
    from fmu_src.adapter import chain_config
    from harness.run.scenario import railcar_values
    from models.compiled import open_chain
    chain = open_chain(chain_config(railcar_values({"seed": 3})), SHORT.grade)
    line = LineController([LineSpan(SHORT), LineSpan(NEXT, 30.0, 3.0)], CAR, TUNING)
    out, payload, t, k = chain.outputs(), 0.0, 0.0, 0
    stops_at: list[float] = []        # the plant's distance where each span finished
    finished_at: list[float] = []
    while not line.finished and k < 4000:
        seen = {n: out[n] for n in READS}
        step = line.demands(t, seen)
        payload += step.payload_change
        if line.controllers[len(finished_at)].finished and len(finished_at) == step.span:
            finished_at.append(t)
            stops_at.append(out["car.position"])
        chain.do_step(t, STEP, step.command.traction, step.command.brake, 0.0, payload)
        k += 1
        t = k * STEP
        out = chain.outputs()
    assert line.finished
    assert abs(stops_at[0] - SHORT.stop) < 0.3
    assert abs(stops_at[1] - NEXT.stop) < 0.3
    assert out["car.total_mass"] == pytest.approx(CAR.mass + 3.0, abs=1e-12)
    assert line.departures[1] == pytest.approx(finished_at[0] + 30.0, abs=1e-9)
    assert out["est.station_stops"] >= 1
