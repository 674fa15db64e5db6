"""Targeted stopping for the ATO (models/ato/controller.py): the braking curve to the stop mark and
Sidorenko's (1997) multi-stage relay control of the electro-pneumatic brake at the end of it.

Sidorenko (1997, ch. 4): braking follows a programmed speed-vs-distance curve to the
stop mark; the electro-pneumatic stage at the end used to run open-loop; switching that brake on
and off in several stages by comparing the actual and the programmed speed reaches a stop within
0.3 m without longer braking. Meleshin (2011, ch. 2): the electric brake works above
~7 km/h, the electro-pneumatic brake from 0 to 7 km/h.

Our reading, in three parts:

1. above ``v_relay`` (7 km/h, CarTraction.regen_fade_speed) the car follows the re-planner's
   braking curve U(s) (the service brake, models/ato/planner.py) with a continuous force:
   ``track_force`` (feed-forward of the curve's deceleration, the resistance and the grade with
   the identified mass, plus a proportional speed term; models/ato/controller.py adds an integral term);
2. below it, the programmed curve is V_p(s) = sqrt(2 a_ep (stop - s)) (constant deceleration
   a_ep, the curve the re-planner ends with) and the brake force is a whole number of stages of
   car.mech_force_max / n_stages. The relay starts with the stages the feed-forward needs
   (identified mass, resistance, grade) and switches one more stage on whenever the actual
   speed is more than ``hysteresis`` above V_p, one off whenever it is as much below (one
   more per further ``stage_speed`` of error), at most once per ``dwell`` (an EP valve's
   response): Sidorenko's "on and off by comparing actual and programmed speed", multi-stage.
   Each stage switched for a lasting error acts as an integrator, so a mass the feed-forward
   gets wrong is taken out without a speed offset. Sidorenko gives neither the number of stages
   nor the thresholds: ours are tuning values (models/ato/controller.py AtoTuning);
3. at rest within ``stop_window`` of the aim point (the mark, or short of it by
   models/ato/controller.py's aim offset where the filter is uncertain): the holding brake. A car that
   stops short of that window creeps on (a small traction at most ``creep_speed``), which
   Sidorenko does not describe: without it a car stopped 0.5 m short would stay there. The
   creep is a PI on the speed (the feed-forward's mass may be wrong: on an ascent a heavier
   car crept at a third of creep_speed with the proportional term alone).

Units: s [m], V [m/s], force [N], mass [t].
"""
from __future__ import annotations

import math

from models.ato.interface import AtoTuning
from models.ato.motion import PlanCar
from models.planning.span import CarTraction
from models.units import G

A_PROG_MIN = 0.3   # the programmed deceleration is at least this share of a_ep (a slower entry
#                    creeps on instead of taking tens of seconds)


def track_force(car: PlanCar, v: float, v_ref: float, a_ref: float, grade: float,
                gain: float) -> float:
    """Net force [N] (traction > 0, brake < 0) that gives the car the acceleration a_ref [m/s^2]
    of a reference plus ``gain`` [1/s] times the speed error v_ref - v [m/s], against the
    resistance w0(v) and the grade [permille] (eq. (2) solved for F - B)."""
    return car.m_in * (a_ref + gain * (v_ref - v)) + car.pg * (car.w0(v) + grade)


class RelayBrake:
    """Sidorenko's (1997) multi-stage relay control of the electro-pneumatic brake (module
    docstring, part 2 and 3) for one stop mark ``stop`` [m].

    ``command(t, s, v, car, grade)`` -> (traction [N], brake [N], stage, programmed speed
    [m/s]); stage -1 means creeping (traction)."""

    def __init__(self, stop: float, a_ep: float, stage_force: float, n_stages: int,
                 hysteresis: float, stage_speed: float, dwell: float, creep_speed: float,
                 creep_accel: float, stop_window: float):
        self.stop, self.a_ep = stop, a_ep
        self.stage_force, self.n_stages = stage_force, n_stages
        self.hysteresis, self.stage_speed, self.dwell = hysteresis, stage_speed, dwell
        self.creep_speed, self.creep_accel = creep_speed, creep_accel
        self.stop_window = stop_window
        self.stage = None        # stages on; None until the first command
        self._switched = -math.inf
        self.a_prog = a_ep       # the programmed deceleration [m/s^2] (set at the first command)
        self._creep_int = 0.0    # the creep's integral term [m/s^2]
        self._t_creep = None     # [s] the last creeping command's time

    def programmed_speed(self, s: float) -> float:
        """V_p(s) = sqrt(2 a_prog (stop - s)), 0 at and past the mark [m/s]."""
        d = self.stop - s
        return math.sqrt(2.0 * self.a_prog * d) if d > 0.0 else 0.0

    def command(self, t: float, s: float, v: float, car: PlanCar, grade: float):
        d = self.stop - s
        if self.stage is None and d > 0.0 and v > 0.0:
            # a car that comes in below V_p (its aim moved towards the mark) gets the curve
            # through where it is, v^2 / (2 d), not a_ep: else the relay lets it coast and creep
            self.a_prog = min(max(v * v / (2.0 * d), A_PROG_MIN * self.a_ep), self.a_ep)
        v_p = self.programmed_speed(s)
        if d <= 0.0:
            self.stage = self.n_stages
            return 0.0, self.n_stages * self.stage_force, self.n_stages, 0.0
        err = v - v_p
        if self.stage is None:
            # the stages the feed-forward needs for a_ep with the identified mass, rounded; for
            # v^2 / (2 d) where the car comes in above V_p (it must stop at the aim all the same)
            a = max(self.a_prog, v * v / (2.0 * d))
            need = car.m_in * a - car.pg * (car.w0(v) + grade)
            self.stage = min(max(int(round(need / self.stage_force)), 0), self.n_stages)
            self._switched = t
        elif abs(err) > self.hysteresis and t - self._switched >= self.dwell - 1e-9:
            # one stage on (off) above (below) the programmed speed, one more per stage_speed
            n = 1 + int((abs(err) - self.hysteresis) / self.stage_speed)
            stage = min(max(self.stage + (n if err > 0.0 else -n), 0), self.n_stages)
            if stage != self.stage:
                self.stage, self._switched = stage, t
        if (self.stage == 0 and err < -self.hysteresis and v < self.creep_speed
                and d > self.stop_window):
            # short of the mark and too slow: creep on, at most creep_speed
            target = min(v_p, self.creep_speed)
            gain = self.creep_accel / self.creep_speed           # creep_accel from rest [1/s]
            # with an integral term (gain^2): a car heavier than the feed-forward's on an
            # ascent (+30 permille, 15 % more mass: 1.4 kN short) crept at a third of
            # creep_speed with the proportional term alone, 12 s for 0.9 m
            dt = t - self._t_creep if self._t_creep is not None else 0.0
            self._creep_int = min(max(self._creep_int + gain * gain * (target - v) * dt, 0.0),
                                  self.creep_accel)
            self._t_creep = t
            f = track_force(car, v, target, self._creep_int, grade, gain)
            return max(f, 0.0), 0.0, -1, v_p
        self._t_creep = None
        return 0.0, self.stage * self.stage_force, self.stage, v_p


def ep_deceleration(car: CarTraction, tuning: AtoTuning, grade: float) -> float:
    """The EP stage's programmed deceleration [m/s^2] for a stop mark on ``grade`` [permille]:
    tuning.a_ep, lowered where a car (1 + mass_reserve) heavier than configured would need more
    than all but one of the ep_stages for it (a descent takes the relay's reserve: at -30
    permille a 25 % heavier car needed all six stages for 1 m/s^2, and one more stage for a
    speed error was not there, so the stop ran 0.44 m past). At least half of tuning.a_ep."""
    m = car.mass * (1.0 + tuning.mass_reserve)                       # [t]
    n = tuning.ep_stages
    spare = max(n - 1, 1) / n
    force = spare * car.mech_force_max + m * G * (car.A0 + grade)     # [N] net retarding
    a = force / (1000.0 * m * (1.0 + car.gamma))
    return min(tuning.a_ep, max(a, 0.5 * tuning.a_ep))
